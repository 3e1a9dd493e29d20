"""Versioned JSON model files: the envelope and the JSON helpers both model kinds use.

Every model file is a JSON object ``{"format": "selfcal-model", "version": 3,
"selfcal_version": "1.0.0", "kind": ...}`` plus the fields of its kind: ``version`` is the
file format's (what a reader checks), ``selfcal_version`` the release that wrote the file
(for people and bug reports; files written before 1.0.0 lack it and still load).
Version 2 adds the optional ``inverse_log_sigma`` of a response model (its confidence
band, :mod:`selfcal.response.bands`); version 1 files still load (without a band).
Version 3 adds a response model's ``frames_ignored``: the frames its calibration left
out, each ``{"source", "reason", "detail"}`` with a reason of
:data:`IGNORED_FRAME_REASONS`; for files of versions 1 and 2 the loader derives them from
the warnings (``ResponseModel.from_dict``, the one place that reads those words).
Version 4 adds a response model's optional ``vignetting`` (:class:`selfcal.lens.Vignetting`:
``coefficients`` 3×3, ``centre`` 2, ``source``, ``covariance`` 11×11 or null).  It also adds the
optional ``luminance`` (:class:`selfcal.lens.LuminanceScale`: ``scale`` > 0 in cd/m² per
unit of radiance, ``log_sigma``, ``source``, ``description``).  Loading validates the envelope (:func:`read_model_dict`) and
the content (:func:`check_response_content`, :func:`check_pipeline_content`: every field's
type, shape and range, so that a model that loads can be used), and raises
:class:`selfcal.errors.ModelFileError` naming the file and the field on anything wrong.
This module sits below both paths' models (which use it to write their files);
:func:`selfcal.load_model`, which dispatches to them, is in :mod:`selfcal.choose.loading` above them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TypeGuard

import numpy as np

from ..errors import ModelFileError
from ..version import __version__
from .images import write_bytes_atomic

FORMAT = "selfcal-model"
#: Written; every version from 1 up to it is read.
VERSION = 5
#: Why a response calibration ignored a frame (``frames_ignored[].reason`` of a response
#: model, :class:`selfcal.response.model.IgnoredFrame`).
IGNORED_FRAME_REASONS = ("clipped", "duplicate", "unchecked")


def jsonable(obj):
    """Plain JSON types: numpy scalars and arrays converted, non-finite floats -> None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def save_model_dict(path, content: dict, *, force: bool = False) -> Path:
    """Write ``content`` (which carries its ``kind``) in the versioned envelope, atomically."""
    doc = {"format": FORMAT, "version": VERSION, "selfcal_version": __version__, **content}
    data = json.dumps(doc, indent=1, allow_nan=False).encode()
    return write_bytes_atomic(path, data, force=force)


def read_model_dict(path) -> dict:
    """Read and check the envelope of a model file; return the parsed object."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise ModelFileError("no such model file", path) from None
    except UnicodeDecodeError as exc:
        raise ModelFileError(f"not a model file: not UTF-8 text (byte {exc.start})",
                             path) from None
    except OSError as exc:
        raise ModelFileError(f"cannot be read as a model file ({exc.strerror or exc})",
                             path) from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"not valid JSON (line {exc.lineno}: {exc.msg})", path) from None
    except ValueError:          # an integer of more digits than Python converts (4300)
        raise ModelFileError("not a model file: it holds a number thousands of digits long",
                             path) from None
    except RecursionError:
        raise ModelFileError("not a model file: its JSON is nested too deeply", path) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelFileError("not a selfcal model file (no 'format: selfcal-model')", path)
    version = doc.get("version")
    if not _is_int(version) or version > VERSION or version < 1:
        raise ModelFileError(
            f"model file version {_short(version)} is not supported (this selfcal reads "
            f"version {VERSION}); upgrade selfcal", path)
    return doc


# ------------------------------------------------------------------ content checks
#
# What a loaded model's methods rely on, checked on the parsed JSON before any model object
# is built: numbers are JSON numbers (not strings or booleans), arrays have their shapes,
# tables are finite and ranges sensible.  The model classes' loaders
# (``ResponseModel.from_dict``, ``PipelineModel.from_dict``) convert what these accept.

#: Largest lattice, Bernstein degree and baked-table size a model file may ask for (the
#: fits write 5, 7 and 49): bounds the memory and time that loading and using it take.
MAX_LATTICE_SIZE = 33
MAX_DEGREE = 31
MAX_BAKE_SIZE = 129
#: Largest magnitude of a table entry (curves, LUT nodes, matrices, RBF points; not
#: exposures): a model's values are of order 1, and the baked backward table and the
#: Bernstein evaluation must stay finite.
MAX_MAGNITUDE = 1e6

_ABSENT = object()


def _is_int(x: object) -> TypeGuard[int]:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _kind_of(x) -> str:
    """How a JSON value is named in messages."""
    names = {dict: "an object", list: "a list", str: "a string", bool: "a boolean",
             type(None): "null", int: "a number", float: "a number"}
    return names.get(type(x), type(x).__name__)


def _short(x, limit: int = 40) -> str:
    """``repr`` of a JSON value, cut short for messages."""
    text = repr(x) if not isinstance(x, (dict, list)) or len(x) < 8 else f"<{_kind_of(x)}>"
    return text if len(text) <= limit else text[:limit - 3] + "..."


class _Checker:
    """Checks the fields of one JSON object of a model file; raises ModelFileError.

    ``where`` names the object in messages ("response model", "pipeline model:
    forward_lut"); the error names the file.  A field may be absent only where
    ``optional``, and null only where ``nullable``; both then give None.
    """

    def __init__(self, obj, where: str, path):
        self.where, self.path = where, path
        if not isinstance(obj, dict):
            raise self.error(f"must be an object, not {_kind_of(obj)}")
        self.obj = obj

    def require(self, *keys):
        """Every one of ``keys`` is there (missing fields are named before wrong ones)."""
        for key in keys:
            self.get(key, nullable=True)

    def error(self, message: str, key=None) -> ModelFileError:
        name = "" if key is None else f" field {key!r}"
        return ModelFileError(f"{self.where}{name} {message}", self.path)

    def get(self, key, optional: bool = False, nullable: bool = False):
        """The field's value; None when absent (and optional) or null (and nullable)."""
        value = self.obj.get(key, _ABSENT)
        if value is _ABSENT:
            if not optional:
                raise self.error(f"lacks the field {key!r}")
            return None
        if value is None and not nullable:
            raise self.error("must not be null", key)
        return value

    def string(self, key, *, optional=False, choices=None):
        value = self.get(key, optional)
        if value is not None and not isinstance(value, str):
            raise self.error(f"must be a string, not {_kind_of(value)}", key)
        if value is not None and choices is not None and value not in choices:
            raise self.error(f"must be one of {', '.join(map(repr, choices))}, not "
                             f"{_short(value)}", key)
        return value

    def number(self, key, *, optional=False, nullable=False, low=None, high=None,
               low_open=False, words=()):
        """A finite JSON number in [low, high] ((low, high] with ``low_open``), or one of
        the strings ``words``."""
        value = self.get(key, optional, nullable)
        if value is None or (isinstance(value, str) and value in words):
            return value
        if not _is_number(value):
            raise self.error(f"must be a number, not {_kind_of(value)}", key)
        if not math.isfinite(value):
            raise self.error(f"must be a finite number, not {value!r}", key)
        if low is not None and (value < low or (low_open and value == low)):
            raise self.error(f"must be {'>' if low_open else '>='} {low}, not {value!r}", key)
        if high is not None and value > high:
            raise self.error(f"must be <= {high}, not {value!r}", key)
        return value

    def integer(self, key, *, optional=False, choices=None, low=None, high=None):
        value = self.get(key, optional)
        if value is None:
            return None
        if not _is_int(value):
            raise self.error(f"must be a whole number, not {_kind_of(value)} "
                             f"{_short(value)}", key)
        if choices is not None and value not in choices:
            raise self.error(f"must be {' or '.join(map(str, choices))}, not {_short(value)}",
                             key)
        if (low is not None and value < low) or (high is not None and value > high):
            raise self.error(f"must be between {low} and {high}, not {_short(value)}", key)
        return value

    def array(self, key, shape, *, optional=False, nullable=False, nulls=False,
              bound=MAX_MAGNITUDE):
        """A nested list of finite JSON numbers of ``shape`` (None: any length >= 1), as
        float64, none beyond ``bound`` in magnitude (None: no bound); with ``nulls``
        (1-D only), entries may be null (NaN in the array)."""
        value = self.get(key, optional, nullable)
        if value is None:
            return None

        leaf_types = (int, float, type(None)) if nulls else (int, float)   # bool excluded

        def walk(v, dims, at):
            if not isinstance(v, list):
                raise self.error(f"must be a list{' of lists' * (len(dims) - 1)} of "
                                 f"numbers, not {_kind_of(v)} (at {at or 'top'})", key)
            if len(v) == 0 or dims[0] not in (None, len(v)):
                raise self.error(f"must have {dims[0] or 'at least 1'} entries, not "
                                 f"{len(v)} (at {at or 'top'})", key)
            if len(dims) > 1:
                for i, item in enumerate(v):
                    walk(item, dims[1:], f"{at}[{i}]")
            elif not all(type(x) in leaf_types for x in v):
                i, x = next((i, x) for i, x in enumerate(v) if type(x) not in leaf_types)
                raise self.error(f"must hold numbers{' or null' if nulls else ''}, not "
                                 f"{_kind_of(x)} (at {at}[{i}])", key)

        walk(value, tuple(shape), "")
        try:
            arr = np.array([np.nan if x is None else x for x in value] if nulls else value,
                           dtype=np.float64)
        except (OverflowError, ValueError) as exc:
            # rows of different lengths; an integer too large for a float
            raise self.error(f"is not a table of numbers ({exc})", key) from None
        if not np.all(np.isfinite(arr) | (np.isnan(arr) & nulls)):
            raise self.error("holds NaN or infinite values", key)
        if bound is not None and np.any(np.abs(arr) > bound):
            raise self.error(f"holds values beyond ±{bound:g}", key)
        return arr

    def sub(self, key, *, optional=False, nullable=False):
        """A nested object's checker (None where absent or null, if allowed)."""
        value = self.get(key, optional, nullable)
        if value is None:
            return None
        if not isinstance(value, dict):
            raise self.error(f"must be an object, not {_kind_of(value)}", key)
        return _Checker(value, f"{self.where}: {key}", self.path)

    def string_list(self, key, *, optional=False, nullable=False):
        value = self.get(key, optional, nullable)
        if value is not None and not (isinstance(value, list)
                                      and all(isinstance(v, str) for v in value)):
            raise self.error("must be a list of strings", key)
        return value

    def scores(self, key, *, nullable=True, number_keys=True):
        """An optional object of validation scores: numbers by setting (keys that read as
        numbers where ``number_keys``)."""
        sub = self.sub(key, optional=True, nullable=nullable)
        for k in () if sub is None else sub.obj:
            sub.number(k)
            if number_keys:
                try:
                    float(k)
                except ValueError:
                    raise sub.error(f"has a key {_short(k)} that is not a number") from None


def check_response_content(doc: dict, path=None) -> None:
    """Check a response model's fields (kind ``"response"``); ModelFileError if wrong.

    What :class:`selfcal.response.ResponseModel` and its users rely on: the tables of f⁻¹
    (finite, non-negative, non-decreasing, on an increasing grid in [0, 1]), the
    coefficients of Eq. 7 (Lin et al., ICCV 2011), one exposure, time and source per frame,
    and the diagnostics the merge reads (warnings, frames used, contradicted times, stuck
    codes).  Ours: the model file format is selfcal's.
    """
    c = _Checker(doc, "response model", path)
    c.require("basis", "max_code", "intensity", "inverse_response", "coefficients",
              "sources", "exposures", "exposure_times")
    c.string("basis")
    c.integer("max_code", choices=(255, 65535))
    grid = c.array("intensity", (None,))
    if grid.size < 2 or np.any(np.diff(grid) <= 0) or grid[0] < 0 or grid[-1] > 1:
        raise c.error("is not increasing in [0, 1] (at least 2 values)", "intensity")
    inverse = c.array("inverse_response", (3, grid.size))
    if np.any(np.diff(inverse, axis=1) < 0):
        raise c.error("is not increasing (f⁻¹ per channel must not decrease)",
                      "inverse_response")
    if np.any(inverse < 0):
        raise c.error("holds negative values (f⁻¹ >= 0)", "inverse_response")
    c.array("coefficients", (3, None))
    sources = c.string_list("sources")
    if not sources:
        raise c.error("must name at least one frame", "sources")
    for key in ("exposures", "exposure_times"):
        values = c.array(key, (len(sources),), nulls=True, bound=None)
        if np.any(values[np.isfinite(values)] <= 0):
            raise c.error("must hold positive numbers (or null where unknown), one per "
                          "source", key)
    sigma = c.array("inverse_log_sigma", (3, grid.size), optional=True)   # version 2
    ignored = c.get("frames_ignored", optional=True, nullable=True)        # version 3
    if ignored is not None and not isinstance(ignored, list):
        raise c.error(f"must be a list, not {_kind_of(ignored)}", "frames_ignored")
    for i, item in enumerate(ignored or []):
        entry = _Checker(item, f"response model: frames_ignored[{i}]", path)
        if entry.string("source") not in sources:
            raise entry.error("names a frame that is not among the sources", "source")
        entry.string("reason", choices=IGNORED_FRAME_REASONS)
        entry.string("detail", optional=True)
    if sigma is not None and np.any(sigma < 0):
        raise c.error("holds negative values (a standard deviation)", "inverse_log_sigma")
    vignetting = c.sub("vignetting", optional=True, nullable=True)        # version 4
    if vignetting is not None:
        _check_vignetting(vignetting)
    luminance = c.sub("luminance", optional=True, nullable=True)          # version 4
    if luminance is not None:
        luminance.require("scale", "log_sigma", "source")
        luminance.number("scale", low=0, low_open=True)
        luminance.number("log_sigma", low=0)
        luminance.string("source", choices=("exif-convention", "reference"))
        luminance.string("description", optional=True)
    record = c.sub("exposure_record", optional=True, nullable=True)       # version 5
    if record is not None:
        _check_exposure_record(record, sources)
    diag = c.sub("diagnostics", optional=True)
    if diag is not None:
        _check_response_diagnostics(diag)


#: What a frame's used exposure may be (:class:`selfcal.exposure.FrameExposure`).
_USED_FROM = ("given", "solved", "measured")
_ORIGINS = ("given", "exif", "raw", "none")


def _check_exposure_record(r: "_Checker", sources: list) -> None:
    """A model's exposure record (:class:`selfcal.exposure.BracketExposures`, version 5)."""
    r.require("frames")
    r.string("rule", optional=True, choices=("measured", "held"))
    r.string("origin", optional=True, choices=("given", "exif", "raw", "unknown"))
    r.string("unit", optional=True, choices=("seconds", "relative"))
    frames = r.get("frames")
    if not isinstance(frames, list) or len(frames) != len(sources):
        raise r.error("must list one frame per source", "frames")
    for i, item in enumerate(frames):
        f = _Checker(item, f"{r.where}: frames[{i}]", r.path)
        if f.string("source") != sources[i]:
            raise f.error("does not name the source of its place", "source")
        f.string("origin", optional=True, choices=_ORIGINS)
        f.string("used_from", optional=True, choices=_USED_FROM)
        for key in ("given", "solved", "measured", "contradicted", "used"):
            f.number(key, optional=True, nullable=True, low=0, low_open=True)
    spread = r.sub("spread", optional=True, nullable=True)
    if spread is not None:
        spread.number("log_sigma", low=0)


def _check_vignetting(v: "_Checker") -> None:
    """A model's vignetting (:class:`selfcal.lens.Vignetting`), as its users rely on it."""
    v.require("coefficients", "centre", "source")
    v.array("coefficients", (3, 3), bound=None)
    v.array("centre", (2,), bound=None)
    v.string("source", choices=("self", "lens", "flat"))
    v.string("description", optional=True)
    v.array("covariance", (11, 11), optional=True, nullable=True, bound=None)
    v.number("log_sigma_floor", optional=True, low=0)
    v.number("aspect", optional=True, nullable=True, low=0)


def _check_response_diagnostics(diag: _Checker) -> None:
    """The diagnostics a loaded response model's users read (the merge)."""
    diag.string_list("warnings", optional=True)
    diag.string_list("frames_used", optional=True, nullable=True)
    refine = diag.get("refine_exposures", optional=True, nullable=True)
    if refine is not None and not isinstance(refine, bool):
        raise diag.error(f"must be true or false, not {_kind_of(refine)}", "refine_exposures")
    contra = diag.get("contradicting_times", optional=True, nullable=True)
    if contra is not None and not isinstance(contra, list):
        raise diag.error(f"must be a list, not {_kind_of(contra)}", "contradicting_times")
    for i, item in enumerate(contra or []):
        entry = _Checker(item, f"{diag.where}: contradicting_times[{i}]", diag.path)
        entry.string("frame")
        entry.number("estimated", optional=True, nullable=True)
    stuck = diag.sub("stuck_codes", optional=True, nullable=True)
    for key in () if stuck is None else ("floor", "ceiling"):
        levels = stuck.array(key, (3,))
        if np.any((levels < 0) | (levels > 1)):
            raise stuck.error("must be 3 normalised codes in [0, 1]", key)


def _check_polynomial(c: _Checker) -> None:
    """A MonotonePolynomial's dict: Bernstein coefficients, domain, optional top."""
    coefficients = c.array("coefficients", (3, None))
    degree = coefficients.shape[1] - 1
    if not 1 <= degree <= MAX_DEGREE:
        raise c.error(f"must hold 2 to {MAX_DEGREE + 1} coefficients per channel",
                      "coefficients")
    basis = c.string("basis", optional=True)
    if basis is not None and basis != f"bernstein{degree}":
        raise c.error(f"is {_short(basis)} but the coefficients are of degree {degree}",
                      "basis")
    domain = c.array("domain", (3, 2))
    if np.any(domain[:, 1] <= domain[:, 0]):
        raise c.error("must be 3 ranges [lo, hi] with lo < hi", "domain")
    c.array("top", (3,), optional=True, nullable=True)


def _check_lattice(c: _Checker) -> None:
    """A LatticeLUT's dict: size**3 finite nodes, a non-empty range, γ of g()."""
    size = c.integer("size", low=2, high=MAX_LATTICE_SIZE)
    c.array("nodes", (size ** 3, 3))
    if np.any(c.array("hi", (3,)) <= c.array("lo", (3,))):
        raise c.error("must lie above 'lo' in every channel", "hi")
    c.number("gamma", low=0, high=50, low_open=True)
    c.number("smoothness", optional=True, low=0)
    c.array("linear", (3, 3), optional=True)
    c.scores("validation")


def _check_points(c: _Checker, a: str, b: str, min_points: int) -> None:
    """Two finite (n, 3) tables of the same n >= min_points."""
    first = c.array(a, (None, 3))
    if first.shape[0] < min_points:
        raise c.error(f"must hold at least {min_points} points", a)
    c.array(b, first.shape)


def check_pipeline_content(doc: dict, path=None) -> None:
    """Check a pipeline model's fields (kind ``"pipeline"``); ModelFileError if wrong.

    What :class:`selfcal.pipeline.PipelineModel` relies on: a finite 3x3 colour matrix,
    the tone curves and their inverses (Gong et al. Eq. 9: Bernstein coefficients and
    domains), the forward and backward lattice LUTs (§3.4-3.5), the RBF h⁻¹ of Lin et al.
    Eq. 10 when the backward variant needs it, the clipped-pixel corrections, the training
    colours kept for the trust test (if any), and a bounded size of the baked backward
    table.  Ours: the model file format is selfcal's.
    """
    c = _Checker(doc, "pipeline model", path)
    c.require("matrix", "tone_curves", "forward_lut", "inverse_tone_curves", "backward_lut",
              "backward")
    if np.linalg.cond(c.array("matrix", (3, 3))) > 1e12:
        raise c.error("is singular (the backward model needs its inverse)", "matrix")
    for key in ("tone_curves", "inverse_tone_curves"):
        _check_polynomial(c.sub(key))
    for key in ("forward_lut", "backward_lut"):
        _check_lattice(c.sub(key))
    rbf = c.sub("rbf", optional=True, nullable=True)
    if rbf is not None:
        _check_points(rbf, "centres", "values", 4)      # degree-1 RBF in 3-D: >= 4 points
        rbf.number("smoothing", low=0)
        rbf.string("kernel", optional=True, choices=("linear",))
        rbf.integer("degree", optional=True, choices=(1,))
        rbf.scores("validation", nullable=False)
    if c.string("backward", choices=("lut", "rbf")) == "rbf" and rbf is None:
        raise c.error("is 'rbf' but the model has no RBF colour mapping", "backward")
    c.integer("bake_size", optional=True, low=2, high=MAX_BAKE_SIZE)
    corrections = c.sub("clipped_corrections", optional=True, nullable=True)
    for variant in () if corrections is None else corrections.obj:
        if variant not in ("lut", "rbf"):
            raise corrections.error(f"names an unknown backward variant {_short(variant)}")
        corr = corrections.sub(variant, nullable=True)
        if corr is not None:
            _check_points(corr, "points", "residuals", 1)
            corr.number("bandwidth", low=0, low_open=True, words=("inf",))
            corr.number("prior_weight", low=0, low_open=True)
            corr.scores("validation", number_keys=False)
    trust = c.sub("training_colours", optional=True, nullable=True)
    if trust is not None:       # the training colours kept for the "outside" test
        _check_points(trust, "raw", "rendered", 1)
        trust.number("raw_scale", low=1e-6, high=MAX_MAGNITUDE)
        trust.number("radius", low=0, low_open=True, high=MAX_MAGNITUDE)
    diag = c.sub("diagnostics", optional=True, nullable=True)
    if diag is not None:        # the model's repr shows it
        diag.number("forward_train_rmse", optional=True, nullable=True)
