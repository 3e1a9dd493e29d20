"""Calibrations other tools can read: ``.cube`` look-up tables (1D and 3D).

The file format is the *Cube LUT Specification* version 1.0 (Adobe, 2013), the format
DaVinci Resolve, ffmpeg (``lut1d`` / ``lut3d`` filters) and OpenColorIO (``FileTransform``)
read::

    # comments
    TITLE "text"
    LUT_1D_SIZE N   or   LUT_3D_SIZE N
    DOMAIN_MIN rmin gmin bmin
    DOMAIN_MAX rmax gmax bmax
    r g b           N (1D) or N³ (3D) rows of output values; in a 3D table the red
    ...             input index varies fastest, then green, then blue

What each direction writes (``direction``):

``"linearize"`` (a :class:`~selfcal.response.ResponseModel`)
    a 1D table, one column per channel: input ``code / max_code`` in ``[0, 1]``, output
    the linearised value ``f⁻¹`` (Lin et al. ICCV 2011 §5; ``f⁻¹(1) = 1``) -- what
    :meth:`~selfcal.response.ResponseModel.linearize` gives.  With the default size
    (``max_code + 1`` for 8-bit models) the nodes sit exactly on the codes.
``"to-raw"`` (a pipeline model)
    a 3D table: input the rendered (JPEG) value ``code / 255`` in ``[0, 1]``, output the
    linear camera raw in ``[0, 1]`` of :meth:`~selfcal.pipeline.PipelineModel.to_raw`.
``"render"`` (a pipeline model)
    a 3D table: input the linear camera raw **normalised to [0, 1]** (black level
    subtracted, divided by the white level: what ``selfcal render`` reads from a raw file
    and what :meth:`~selfcal.pipeline.PipelineModel.render` takes), output the rendered
    value in ``[0, 1]`` (× 255 for codes).

Both 3D directions write ``DOMAIN_MIN 0 0 0`` and ``DOMAIN_MAX 1 1 1`` (the values the
models take; the lines are the spec's defaults, written so that no reader has to assume
them).  A narrower domain (to leave out the last codes before clipping) is not written:
ffmpeg's ``lut3d`` (checked with 9.0.2) reads the lines but only ever shrinks its input,
scaling by ``min(1, 1 / (max - min))`` and ignoring ``DOMAIN_MIN``, so a table for
``[0, 0.98]`` would be read as one for ``[0, 1]``.

A 3D table is sampled on a uniform grid of its input, so it is coarse where the model
is steep: the ``render`` table in the darkest grid cells of linear raw (the tone curve
rises fastest there), the ``to-raw`` table in the last cell before code 255 (a camera's
``f⁻¹`` can climb a fifth of full scale over its last three codes).  A shaper LUT
fixes both: :mod:`selfcal.export.shaper` (a 1D shaper chosen from the model before the
3D table; Resolve ``.cube`` and CLF files, what ``selfcal export`` writes for a pipeline
model unless ``--no-shaper``).  The 3D-only table here is what ffmpeg's ``lut3d`` reads
alone; for it, a ``to-raw`` table can follow the model inside a range of codes and extrapolate
outside it (``code_range``; by default the codes the model was fitted on, when it says:
an NUS folder's 5-252): the cell holding code 252 then interpolates towards the model at
252, not at 255.  ``python3 -m bench.export_cube`` measures what is left, and prints the
one-dimensional evidence of it (the ``render`` table cannot be within 0.5 % in its
darkest cells whatever its node values).  The table holds the model at its nodes:
``to_raw`` / ``render`` of the model, or its exact evaluation where the model has one
that is not a table itself (``render_exact`` of an NUS model folder, whose ``render``
interpolates a table).

Ours: the choice of what each direction's input and output mean.  The writer is ours too
(~30 lines): colour-science's ``write_LUT`` writes the same table order but omits the
DOMAIN lines for the default domain and writes in place (not atomically), and
colour-science is not a dependency of selfcal; the tests read the files back with
colour-science's ``read_LUT`` and apply the 3D tables with ffmpeg's ``lut3d``.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import cast

import numpy as np

from ..errors import InputError
from ..pipeline.model import PipelineModel
from ..response.model import ResponseModel
from ..typing import PathLike
from ..io.images import atomic_output, check_output_path

__all__ = ["DIRECTIONS", "DEFAULT_3D_SIZE", "cube_table", "write_cube", "read_cube_header",
           "model_code_range"]

DIRECTIONS = ("linearize", "to-raw", "render")
#: Nodes per axis of a 3D table unless asked otherwise (33 and 65 are the usual sizes).
DEFAULT_3D_SIZE = 33
#: Sizes the Cube LUT Specification 1.0 allows.
SIZE_LIMITS = {1: (2, 65536), 3: (2, 256)}


def _kind(model) -> str:
    """``"response"`` (has ``linearize``) or ``"pipeline"`` (has ``to_raw`` and ``render``)."""
    if hasattr(model, "to_raw") and hasattr(model, "render"):
        return "pipeline"
    if hasattr(model, "linearize"):
        return "response"
    raise InputError(f"cannot export a {type(model).__name__}: not a selfcal model")


def default_direction(model) -> str:
    """``"linearize"`` for a response model, ``"to-raw"`` for a pipeline model."""
    return "linearize" if _kind(model) == "response" else "to-raw"


def default_size(model, direction: str) -> int:
    """Default table size: ``max_code + 1`` for 1D (at most 4096), 33 for 3D."""
    if direction == "linearize":
        return int(min(int(getattr(model, "max_code", 255)) + 1, 4096))
    return DEFAULT_3D_SIZE


def check_export(model, direction: str | None, size: int | None) -> tuple[str, int]:
    """The direction and size an export will use, or InputError saying what is wrong.

    A response model exports only ``"linearize"``; a pipeline model only ``"to-raw"`` and
    ``"render"``.  Sizes: 2 to 65536 (1D), 2 to 256 (3D), as the Cube LUT Specification
    allows.
    """
    kind = _kind(model)
    if direction is None:
        direction = default_direction(model)
    if direction not in DIRECTIONS:
        raise InputError(f"direction must be one of {', '.join(DIRECTIONS)}, not "
                         f"{direction!r}")
    if kind == "response" and direction != "linearize":
        raise InputError(f"a response model (JPEG-only path) exports only 'linearize', not "
                         f"{direction!r}: {direction} needs a RAW-path (pipeline) model")
    if kind == "pipeline" and direction == "linearize":
        raise InputError("a pipeline model (RAW path) exports 'to-raw' or 'render', not "
                         "'linearize' (a 1D table needs a response model)")
    if size is None:
        size = default_size(model, direction)
    dims = 1 if direction == "linearize" else 3
    lo, hi = SIZE_LIMITS[dims]
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not lo <= size <= hi:
        raise InputError(f"LUT_{dims}D_SIZE must be a whole number from {lo} to {hi}, not "
                         f"{size!r}")
    return direction, int(size)


def model_code_range(model: ResponseModel | PipelineModel) -> tuple[int, int] | None:
    """The codes a model was fitted on, when it says (an NUS folder's
    ``jpg2raw_validRange.txt``: ``diagnostics["valid_range"]``), else None."""
    diag = getattr(model, "diagnostics", None) or {}
    rng = diag.get("valid_range") if isinstance(diag, dict) else None
    if rng is None:
        return None
    return int(rng[0]), int(rng[1])


def check_code_range(code_range, direction: str) -> tuple[int, int] | None:
    """``(lo, hi)`` codes for a ``to-raw`` table, or InputError saying what is wrong."""
    if code_range is None:
        return None
    if direction != "to-raw":
        raise InputError(f"a code range applies to the to-raw direction (8-bit input), not "
                         f"{direction!r}")
    try:
        lo, hi = (int(v) for v in code_range)
    except (TypeError, ValueError):
        raise InputError(f"the code range must be two whole numbers, not {code_range!r}") \
            from None
    if not 0 <= lo < hi <= 255:
        raise InputError(f"the code range must satisfy 0 <= low < high <= 255, not "
                         f"{lo}-{hi}")
    return lo, hi


def _continue_outside(values: np.ndarray, x: np.ndarray, lo: float, hi: float):
    """Replace, along each of the first three axes, the values at nodes outside
    ``[lo, hi]`` (evaluated at ``lo`` / ``hi``) by the chord from the nearest inside node
    through that end value, continued to the node (ours; tensor product, so a corner
    outside on two axes is continued on both)."""
    strictly = np.flatnonzero((x > lo) & (x < hi))
    if strictly.size == 0:          # no node inside to draw a chord from: the ends' values
        return values
    top, bottom = strictly[-1], strictly[0]
    for axis in range(3):
        v = np.moveaxis(values, axis, 0)            # a view: edits land in ``values``
        for k in np.flatnonzero(x > hi):
            v[k] = v[top] + (v[k] - v[top]) * ((x[k] - x[top]) / (hi - x[top]))
        for k in np.flatnonzero(x < lo):
            v[k] = v[bottom] + (v[k] - v[bottom]) * ((x[bottom] - x[k]) / (x[bottom] - lo))
    return values


def cube_table(model: ResponseModel | PipelineModel, direction: str | None = None, *,
               size: int | None = None, code_range: tuple[int, int] | None = None
               ) -> tuple[np.ndarray, str, int]:
    """The rows of the ``.cube`` table of ``model`` (see the module docstring).

    Parameters
    ----------
    model, direction, size
        See :func:`write_cube`.
    code_range : (int, int), optional
        ``to-raw`` only: the codes inside which the table follows the model (see
        :func:`write_cube`); None keeps every node at the model's value.

    Returns
    -------
    rows : numpy.ndarray
        float64 ``(size, 3)`` (1D) or ``(size³, 3)`` (3D, red varying fastest).
    direction : str
    size : int
    """
    direction, size = check_export(model, direction, size)
    x = np.linspace(0.0, 1.0, size)
    if direction == "linearize":
        rows = cast(ResponseModel, model).linearize(np.repeat(x[:, None], 3, axis=1))
        return np.asarray(rows, dtype=np.float64), direction, size
    code_range = check_code_range(code_range, direction)
    lo, hi = (0.0, 1.0) if code_range is None else (code_range[0] / 255, code_range[1] / 255)
    # index [b, g, r] so that a C-order flattening varies red fastest; nodes outside the
    # code range are evaluated at its ends, then continued along the chords
    xc = np.clip(x, lo, hi)
    b, g, r = np.meshgrid(xc, xc, xc, indexing="ij")
    nodes = np.stack([r, g, b], axis=-1).reshape(-1, 3)
    if direction == "to-raw":
        rows = np.asarray(cast(PipelineModel, model).to_raw(nodes), dtype=np.float64)
        if lo > 0.0 or hi < 1.0:
            rows = _continue_outside(rows.reshape((size,) * 3 + (3,)), x, lo, hi)
            rows = rows.reshape(-1, 3)
    else:   # an NUS folder's render is itself a table: its nodes from the RBF
        render = getattr(model, "render_exact", cast(PipelineModel, model).render)
        rows = np.asarray(render(nodes))
    return np.asarray(rows, dtype=np.float64), direction, size


def cube_title(text: str) -> str:
    """``text`` as one line fit for a ``.cube`` file's ``TITLE "..."`` or comment: white
    space folded, double quotes made single, at most 200 characters."""
    return " ".join(str(text).replace('"', "'").split())[:200]


def write_cube(model: ResponseModel | PipelineModel, path: PathLike, *,
               direction: str | None = None, size: int | None = None,
               title: str | None = None, force: bool = False,
               inputs: Iterable[PathLike] = (),
               code_range: str | tuple[int, int] | None = "model") -> Path:
    """Write ``model`` as a ``.cube`` look-up table (Adobe Cube LUT Specification 1.0).

    Parameters
    ----------
    model : ResponseModel or PipelineModel
        A response model gives a 1D table (``direction="linearize"``); a pipeline model
        (including an NUS model folder loaded by :func:`selfcal.load_model`) a 3D table
        (``"to-raw"``: JPEG -> raw, the default; ``"render"``: raw -> JPEG).
    path : str or os.PathLike
        The ``.cube`` file; written atomically, never over an existing file unless
        ``force`` nor over one of ``inputs``.
    direction : {"linearize", "to-raw", "render"}, optional
        Default: ``"linearize"`` for a response model, ``"to-raw"`` for a pipeline model.
    size : int, optional
        ``LUT_1D_SIZE`` (default ``max_code + 1``, at most 4096) or ``LUT_3D_SIZE``
        (default 33; 65 for a finer table).
    title : str, optional
        The ``TITLE`` line (default names the direction).
    code_range : "model", (int, int) or None
        ``to-raw`` only: the codes ``(low, high)`` inside which the table follows the
        model.  Nodes outside them hold the chord from the nearest node inside through the
        model at ``low`` / ``high``, continued (ours): the cell holding ``high`` then
        interpolates the model up to ``high``, not towards its value at 255 (where an
        ``f⁻¹`` climbing a fifth of full scale over its last three codes makes a 33³
        table miss code 252 by 0.07), and codes outside the range are extrapolated.
        ``"model"`` (the default): the codes the model was fitted on when it says
        (:func:`model_code_range`: an NUS folder's 5-252), else every node holds the
        model, as with None.  Written as a comment line in the file.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    InputError
        A direction the model cannot export, a size outside the spec's range, or a code
        range that is not two codes ``0 <= low < high <= 255`` (or given for a direction
        other than ``to-raw``).
    OutputExistsError, OutputWriteError
        The output exists (without ``force``), is an input, or cannot be written.
    """
    path = Path(path)
    direction, size = check_export(model, direction, size)
    if isinstance(code_range, str) and code_range == "model":
        code_range = model_code_range(model) if direction == "to-raw" else None
    code_range = check_code_range(code_range, direction)
    check_output_path(path, force=force, inputs=inputs)
    rows, direction, size = cube_table(model, direction, size=size, code_range=code_range)
    dims = 1 if direction == "linearize" else 3
    what = {"linearize": "code/max_code -> linear (f^-1 per channel)",
            "to-raw": "rendered code/255 -> linear camera raw in [0, 1]",
            "render": "linear camera raw in [0, 1] (black 0, white 1) -> rendered "
                      "code/255"}[direction]
    head = [f"# selfcal {direction}: {what}",
            "# Adobe Cube LUT Specification 1.0" + ("" if dims == 1 else
                                                    "; red varies fastest"),
            f'TITLE "{cube_title(title or f"selfcal {direction}")}"',
            f"LUT_{dims}D_SIZE {size}",
            "DOMAIN_MIN 0.0 0.0 0.0",
            "DOMAIN_MAX 1.0 1.0 1.0"]
    if code_range is not None:
        head.insert(2, f"# follows the model for codes {code_range[0]}-{code_range[1]}; "
                       "nodes outside continue the chords from inside (extrapolated)")
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write("\n".join(head) + "\n")
            np.savetxt(fh, rows, fmt="%.7f")
    return path


def read_cube_header(path: PathLike) -> dict:
    """The keyword lines of a ``.cube`` file (``TITLE``, ``LUT_3D_SIZE``, ...) as strings.

    A small reader for checks and tests; it does not read the table.
    """
    out = {}
    for line in Path(path).read_text(encoding="ascii").splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        if not key[:1].isalpha():
            break
        out[key] = value.strip()
    return out
