"""Path choice: look at the inputs and take the calibration path(s) they support.

* Rendered frames (JPEG/PNG/TIFF) of one scene at two or more exposures → the JPEG-only
  **response path** (:func:`selfcal.calibrate_response`; Lin, Kim, Süsstrunk & Brown,
  *Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011 (paper 002),
  §5, Eq. 7-8).
* One or more RAW+JPEG pairs (a raw file and the rendered file of the same name in the same
  folder) → the **pipeline path** (:func:`selfcal.pipeline.fit_pipeline`; Gong et al.,
  *Rank-based radiometric calibration* (paper 000), §3; Lin et al. §6).
* A bracketed RAW+JPEG session → both, and the exposure ratios of the response path come
  from the raws (Lin et al. §5: "the exposure ratio can be directly computed by dividing
  the raw values between two images"), which fixes the shutter error and the exponential
  ambiguity of the response.

:func:`calibrate` returns a :class:`CalibrationResult` that says which path(s) were taken
and why; when neither applies it raises :class:`~selfcal.errors.CalibrationError` saying
exactly what is missing.
"""

from __future__ import annotations

import inspect
import math
import os
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import CalibrationError, InputError, SelfcalWarning
from .io import IMAGE_SUFFIXES, ExposureInfo, effective_exposure_times
from .raw import RAW_SUFFIXES, TIFF_SUFFIXES, is_linear_tiff, read_raw_exposure_info

__all__ = ["InputGroups", "CalibrationResult", "group_inputs", "calibrate",
           "calibrate_pipeline"]

RENDERED_SUFFIXES = frozenset(IMAGE_SUFFIXES)
#: Preference among rendered files of one name when pairing with a raw.
_RENDERED_PREFERENCE = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
#: Two exposures count as distinct when they differ by more than this factor.
DISTINCT_EXPOSURE_FACTOR = 1.05
#: Median code change (of 255) that counts as a visible exposure change between frames
#: without exposure times.
BRIGHTNESS_CHANGE_CODES = 2.0
#: Fewest samples for the pipeline fit, and per pair before a pair is reported as unusable.
MIN_PIPELINE_SAMPLES = 200
MIN_PAIR_SAMPLES = 50


# --------------------------------------------------------------------------------------
# grouping
# --------------------------------------------------------------------------------------

@dataclass
class InputGroups:
    """The inputs sorted by role.

    Attributes
    ----------
    rendered : list of pathlib.Path
        Every rendered frame (JPEG, PNG, TIFF that is not taken as a raw), in input order,
        including those paired with a raw.
    pairs : list of (pathlib.Path, pathlib.Path)
        ``(raw, rendered)`` pairs: same folder, same name up to case and suffix.
    unpaired_raws : list of pathlib.Path
        Raw files without a rendered file of the same name.
    ignored : list of (pathlib.Path, str)
        Files not used, with the reason (duplicates, a second raw of one name).
    """

    rendered: list = field(default_factory=list)
    pairs: list = field(default_factory=list)
    unpaired_raws: list = field(default_factory=list)
    ignored: list = field(default_factory=list)

    @property
    def raw_of(self) -> dict:
        """Map rendered path → its raw path."""
        return {j: r for r, j in self.pairs}


def _expand(paths) -> list[Path]:
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    out: list[Path] = []
    for p in paths:
        if not isinstance(p, (str, os.PathLike)):
            raise InputError(f"calibrate takes file paths; got {type(p).__name__} "
                             "(use calibrate_response / calibrate_pipeline for arrays)")
        p = Path(p)
        if p.is_dir():
            out.extend(sorted(q for q in p.iterdir() if q.is_file() and (
                q.suffix.lower() in RAW_SUFFIXES or q.suffix.lower() in RENDERED_SUFFIXES)))
        elif not p.exists():
            raise InputError("no such file", p)
        else:
            out.append(p)
    return out


def group_inputs(paths) -> InputGroups:
    """Sort input files into rendered frames, RAW+rendered pairs and unpaired raws.

    A raw file (suffix in :data:`selfcal.raw.RAW_SUFFIXES`) pairs with the rendered file
    (``.jpg``/``.jpeg``/``.png``/``.tif``/``.tiff``) of the same name -- case-insensitive,
    same folder; JPEG is preferred when several exist.  A 16-bit (or float) TIFF is taken as
    the raw of a pair when a rendered file of the same name is given and no camera raw is
    (``pair.tiff`` + ``pair.jpg``); otherwise a TIFF is a rendered frame.  Directories are
    expanded to their image and raw files (not recursively).  A file given twice is used
    once.

    Parameters
    ----------
    paths : str, os.PathLike or sequence of them

    Returns
    -------
    InputGroups

    Raises
    ------
    InputError
        For a missing file or a file that is neither an image nor a raw file.
    """
    files = _expand(paths)
    groups = InputGroups()
    seen: dict[Path, Path] = {}
    unique: list[Path] = []
    for p in files:
        key = p.resolve()
        if key in seen:
            groups.ignored.append((p, f"given twice (same file as {seen[key]})"))
            continue
        seen[key] = p
        suffix = p.suffix.lower()
        if suffix not in RAW_SUFFIXES and suffix not in RENDERED_SUFFIXES:
            raise InputError(
                "not an image or raw file selfcal reads (JPEG, PNG, TIFF, or a camera raw: "
                + ", ".join(sorted(s.lstrip(".").upper() for s in RAW_SUFFIXES)) + ")", p)
        unique.append(p)

    by_stem: dict[tuple, list[Path]] = {}
    for p in unique:
        # the folder as given (a symlink is not followed: its name is what pairs)
        by_stem.setdefault((Path(os.path.abspath(p)).parent, p.stem.lower()), []).append(p)

    raw_of: dict[Path, Path] = {}
    is_raw: set[Path] = set()
    for members in by_stem.values():
        raws = [p for p in members if p.suffix.lower() in RAW_SUFFIXES]
        others = [p for p in members if p.suffix.lower() not in RAW_SUFFIXES]
        if not raws and len(others) >= 2:
            tiffs = [p for p in others if p.suffix.lower() in TIFF_SUFFIXES
                     and is_linear_tiff(p)]
            if tiffs and len(tiffs) < len(others):
                raws = tiffs[:1]
                others = [p for p in others if p != raws[0]]
        for extra in raws[1:]:
            groups.ignored.append((extra, f"a second raw file named like {raws[0].name}; "
                                          f"only {raws[0].name} is used"))
        if raws:
            is_raw.update(raws)
            if others:
                partner = min(others, key=lambda q: (
                    _RENDERED_PREFERENCE.index(q.suffix.lower()), unique.index(q)))
                raw_of[partner] = raws[0]
            else:
                groups.unpaired_raws.append(raws[0])
    for p in unique:
        if p in is_raw:
            continue
        groups.rendered.append(p)
        if p in raw_of:
            groups.pairs.append((raw_of[p], p))
    ignored_raws = {p for p, _ in groups.ignored}
    groups.unpaired_raws = [p for p in unique if p in groups.unpaired_raws
                            and p not in ignored_raws]
    return groups


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------

@dataclass
class CalibrationResult:
    """What :func:`calibrate` did.

    Attributes
    ----------
    taken : tuple of str
        The paths taken: ``("response",)``, ``("pipeline",)`` or ``("response",
        "pipeline")``.
    reasons : list of str
        Human-readable: why each path was (or was not) taken, where the exposures came
        from.
    response : ResponseModel or None
        The JPEG-only model (Lin et al. §5).
    pipeline : PipelineModel or None
        The RAW-path model (Gong et al.; Lin et al. §6).
    groups : InputGroups
    response_frames : list of pathlib.Path
        The frames given to the response path.
    exposure_source : str or None
        Where the response path's exposures came from: ``"raw"`` (raw ratios, anchored to
        EXIF seconds where known), ``"raw+exif"`` (raw ratios for some frames, EXIF for
        others), ``"exif"``, ``"given"`` or ``"unknown"``.
    exposure_times : list or None
        The times passed to the response path (None: it read EXIF itself).
    raw_exposures : dict
        Per frame with a raw: ``{"raw_relative": ..., "exif": ...}`` -- the raw-derived
        relative exposure and the EXIF exposure (seconds at the first frame's ISO and
        aperture), for comparison.
    pairs : list of PairData
        Each RAW+JPEG pair's registration and sample counts.
    n_pipeline_samples : int
    warnings : list of str
        Everything also emitted as :class:`~selfcal.errors.SelfcalWarning`.
    """

    taken: tuple
    reasons: list
    response: object = None
    pipeline: object = None
    groups: InputGroups = field(default_factory=InputGroups)
    response_frames: list = field(default_factory=list)
    exposure_source: str | None = None
    exposure_times: list | None = None
    raw_exposures: dict = field(default_factory=dict)
    pairs: list = field(default_factory=list)
    n_pipeline_samples: int = 0
    warnings: list = field(default_factory=list)

    def summary_lines(self) -> list[str]:
        """Lines describing the result, for a front end to print."""
        lines = [f"paths taken: {' + '.join(self.taken)}"]
        lines += [f"  - {r}" for r in self.reasons]
        for p in self.pairs:
            reg, c = p.registration, p.samples.counts
            rej = ", ".join(f"{k} {c.get(k, 0)}" for k in
                            ("outside", "clipped_raw", "clipped_rendered", "high_gradient"))
            lines.append(
                f"pair {Path(p.raw_name).name} + {Path(p.rendered_name).name}: scale "
                f"{reg.scale:.4f}, shift ({reg.shift[0]:.1f}, {reg.shift[1]:.1f}) px, "
                f"residual {reg.residual:.3f}; {c.get('used', 0)} samples of "
                f"{c.get('total', 0)} blocks (rejected: {rej})")
        return lines


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------

def _fmt_time(t) -> str:
    if t is None or not math.isfinite(t):
        return "unknown"
    if t < 1:
        inv = 1.0 / t
        if abs(inv - round(inv)) < 0.02 * inv:
            return f"1/{round(inv)} s"
        return f"1/{inv:.3g} s"
    return f"{t:.3g} s"


def _noun(paths) -> str:
    kinds = {p.suffix.lower() for p in paths}
    if kinds <= {".jpg", ".jpeg"}:
        name = "JPEG"
    elif kinds <= {".png"}:
        name = "PNG"
    elif kinds <= {".tif", ".tiff"}:
        name = "TIFF"
    else:
        name = "image"
    return f"{len(paths)} {name}" + ("s" if len(paths) != 1 else "")


def _names(paths, limit=4) -> str:
    names = [Path(p).name for p in paths]
    if len(names) > limit:
        return ", ".join(names[:limit]) + f", … ({len(names)} in all)"
    return ", ".join(names)


def _frame_info(path: Path, raw_path: Path | None) -> ExposureInfo:
    from .io import read_exposure_info

    info = read_exposure_info(path)
    if raw_path is not None and (info.exposure_time is None or info.iso is None
                                 or info.f_number is None):
        rinfo = read_raw_exposure_info(raw_path)
        info = ExposureInfo(
            exposure_time=info.exposure_time if info.exposure_time is not None
            else rinfo.exposure_time,
            f_number=info.f_number if info.f_number is not None else rinfo.f_number,
            iso=info.iso if info.iso is not None else rinfo.iso)
    return info


def _distinct(values) -> int:
    """Number of distinct exposures among known values (factor DISTINCT_EXPOSURE_FACTOR)."""
    vals = sorted(v for v in values if v is not None)
    if not vals:
        return 0
    count, last = 1, vals[0]
    for v in vals[1:]:
        if v > last * DISTINCT_EXPOSURE_FACTOR:
            count += 1
            last = v
    return count


def _brightness_changes(paths) -> bool:
    """Do frames (same size) differ in brightness by a visible exposure change?

    Median code difference (8-bit scale) against the first frame over pixels unclipped in
    both, on DCT-reduced decodes.
    """
    from .io import read_image

    greys = []
    for p in paths:
        img = read_image(p, reduce=8)
        scale = 255.0 / (65535.0 if img.dtype == np.uint16 else 255.0)
        step = 1 if img.dtype == np.uint8 and p.suffix.lower() in (".jpg", ".jpeg") else 8
        greys.append(img[::step, ::step].astype(np.float32).mean(axis=2) * scale)
    ref = greys[0]
    for g in greys[1:]:
        if g.shape != ref.shape:
            continue
        ok = (ref > 5) & (ref < 250) & (g > 5) & (g < 250)
        if ok.sum() < 16:
            # nearly everything clipped in one of them: that is a big change
            return True
        if abs(float(np.median(g[ok] - ref[ok]))) >= BRIGHTNESS_CHANGE_CODES:
            return True
    return False


def _fit_pipeline_function():
    """``selfcal.pipeline.fit_pipeline``, or None when this installation lacks it."""
    try:
        from . import pipeline as _pipeline
    except ImportError:
        return None
    fn = getattr(_pipeline, "fit_pipeline", None)
    if fn is None:
        try:
            from .pipeline import fit_pipeline as fn  # noqa: F811  (lazy submodule)
        except ImportError:
            return None
    return fn


def _split_options(options: dict, response_options, pipeline_options):
    from .response.calibrate import calibrate_response

    resp = dict(response_options or {})
    pipe = dict(pipeline_options or {})
    resp_names = set(inspect.signature(calibrate_response).parameters) - {
        "images", "exposure_times", "progress"}
    fit = _fit_pipeline_function()
    pipe_names: set | None = None
    if fit is not None:
        params = inspect.signature(fit).parameters
        if not any(p.kind is p.VAR_KEYWORD for p in params.values()):
            pipe_names = set(params) - {"raw_samples", "rendered_samples", "progress"}
    unknown = []
    for key, value in options.items():
        if key in resp_names:
            resp[key] = value
        elif pipe_names is None or key in pipe_names:
            pipe[key] = value
        else:
            unknown.append(key)
    if unknown:
        raise TypeError(f"calibrate() got unknown option(s) {', '.join(sorted(unknown))} "
                        "(neither calibrate_response nor fit_pipeline takes them)")
    return resp, pipe


def _image_size(path: Path):
    from .io import read_image_size

    return read_image_size(path)


# --------------------------------------------------------------------------------------
# calibrate
# --------------------------------------------------------------------------------------

def calibrate(paths, *, progress=None, seed: int = 0, exposure_times=None,
              exposure_source: str = "auto", raw_half_size: bool = True,
              max_pair_samples: int = 20_000, block: int | None = None,
              response_options: dict | None = None, pipeline_options: dict | None = None,
              **options) -> CalibrationResult:
    """Calibrate a camera from whatever files are given, taking the path(s) they support.

    * Rendered frames of one size at ≥ 2 distinct exposures → the response path,
      :func:`selfcal.calibrate_response` (Lin et al., ICCV 2011, §5, Eq. 7-8).  Exposures
      are distinct when they differ by more than 5 % (EXIF time × ISO / N²); frames without
      times count as distinct when their brightness visibly differs.
    * ≥ 1 RAW+JPEG pair (see :func:`group_inputs`) → the pipeline path: every pair is read
      (:func:`selfcal.raw.read_raw_linear`), registered
      (:func:`selfcal.pairs.register_raw_jpeg`) and sampled
      (:func:`selfcal.pairs.pair_samples`), and the joined samples go to
      :func:`selfcal.pipeline.fit_pipeline` (Gong et al., rank-based radiometric
      calibration, §3; Lin et al. §6).
    * Both, for a bracketed RAW+JPEG session; the response path's exposures then come from
      the raws (:func:`selfcal.pairs.raw_exposure_ratios`, Lin et al. §5: median ratio of
      unclipped, well-exposed raw values), which removes the shutter error and the
      exponential ambiguity.  They are put in seconds by the geometric mean of the frames'
      EXIF times (scaled to the first frame's ISO and aperture) when those are known --
      less sensitive to one frame's shutter error than the first frame's time alone --
      and are relative to the first frame otherwise.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        Image files, raw files, or folders of them.
    progress : callable, optional
        ``progress(stage, done, total, detail)``; stages ``"pairs"`` and those of the two
        calibrations.
    seed : int
        Seeds every random choice (sampling, and both fits).
    exposure_times : sequence or mapping, optional
        Exposure times of the rendered frames (seconds; None for unknown), in the order the
        rendered frames appear in ``paths`` (raws not counted), or a mapping path → time.
        Overrides EXIF and raw ratios.
    exposure_source : {"auto", "raw", "exif", "unknown"}
        ``"auto"``: raw ratios when ≥ 2 response frames have raws, else EXIF.  ``"raw"``
        insists on raw ratios (error without them), ``"exif"`` ignores the raws for
        exposures, ``"unknown"`` solves all exposures jointly.
    raw_half_size : bool
        Read raws at half size (2×2 binned): faster, and plenty for block means.
    max_pair_samples : int
        Samples for the pipeline fit, shared among the pairs.
    block : int, optional
        Block side (rendered pixels) of the pair samples; default adaptive.
    response_options, pipeline_options : dict, optional
        Keyword arguments for :func:`selfcal.calibrate_response` and
        :func:`selfcal.pipeline.fit_pipeline`.
    **options
        Routed by name: those :func:`selfcal.calibrate_response` takes go there (e.g.
        ``refine_exposures``, ``saturation_threshold``), the others to ``fit_pipeline``.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError
        A missing or unreadable file (named), a raw LibRaw cannot read (named), a JPEG that
        does not match its raw (both named).
    CalibrationError
        When the inputs support neither path; the message says what is missing, e.g.
        ``"3 JPEGs all at 1/60 s and no raw files: need frames at ≥ 2 exposures, or a
        RAW+JPEG pair"``.
    """
    if exposure_source not in ("auto", "raw", "exif", "unknown"):
        raise InputError(f"exposure_source must be auto, raw, exif or unknown, got "
                         f"{exposure_source!r}")
    resp_opts, pipe_opts = _split_options(options, response_options, pipeline_options)
    resp_opts.setdefault("seed", seed)
    groups = group_inputs(paths)
    notes: list[str] = []
    reasons: list[str] = []

    def warn(msg):
        notes.append(msg)
        _warnings.warn(msg, SelfcalWarning, stacklevel=3)

    for p, why in groups.ignored:
        warn(f"{p}: ignored ({why})")
    for raw in groups.unpaired_raws:
        warn(f"{raw}: raw file without a rendered image of the same name "
             f"({raw.stem}.jpg) in its folder; not used")

    raw_of = groups.raw_of
    given_times = _given_times(exposure_times, groups.rendered)

    # ---- the response path: which frames, at how many exposures?
    sizes: dict[tuple, list[Path]] = {}
    for p in groups.rendered:
        sizes.setdefault(_image_size(p), []).append(p)
    infos = {p: _frame_info(p, raw_of.get(p)) for p in groups.rendered}
    eff = dict(zip(groups.rendered, effective_exposure_times([infos[p] for p in groups.rendered])))
    if given_times is not None:
        eff = dict(given_times)

    candidates = []
    for size, frames in sizes.items():
        known = [eff[p] for p in frames if eff[p] is not None]
        n_known = _distinct(known)
        unknown = [p for p in frames if eff[p] is None]
        with_raw = [p for p in frames if p in raw_of]
        if len(frames) < 2:
            status = "single"
        elif n_known >= 2:
            status = "ok"
        elif len(with_raw) >= 2 and exposure_source in ("auto", "raw") and \
                given_times is None:
            status = "raw?"   # decided by the raw ratios below
        elif unknown and _brightness_changes(frames):
            status = "ok"
        else:
            status = "same" if not unknown else "no_change"
        candidates.append((size, frames, status, known))
    usable = [c for c in candidates if c[2] in ("ok", "raw?")]
    usable.sort(key=lambda c: -len(c[1]))
    response_frames = list(usable[0][1]) if usable else []
    for c in usable[1:]:
        warn(f"{_noun(c[1])} of another size ({c[0][1]}x{c[0][0]}: {_names(c[1])}) not "
             "used by the response path (one scene per calibration)")

    want_pipeline = bool(groups.pairs)
    if not response_frames and not want_pipeline:
        raise CalibrationError(_missing_message(groups, candidates))

    # ---- read, register and sample the pairs (pipeline data and raw exposure ratios)
    from .pairs import collect_pair_samples

    pair_data = []
    samples = None
    if groups.pairs:
        samples, pair_data = collect_pair_samples(
            [r for r, _ in groups.pairs], [j for _, j in groups.pairs], seed=seed,
            max_samples=max_pair_samples, half_size=raw_half_size, block=block,
            progress=progress)
        for pd in pair_data:
            c = pd.samples.counts
            if c.get("valid", 0) < MIN_PAIR_SAMPLES:
                warn(f"{pd.rendered_name}: only {c.get('valid', 0)} usable samples against "
                     f"its raw ({c.get('clipped_raw', 0)} blocks clipped in the raw, "
                     f"{c.get('clipped_rendered', 0)} clipped in the JPEG, "
                     f"{c.get('high_gradient', 0)} high-gradient, of {c.get('total', 0)})")

    # ---- exposures for the response path
    times_for_response = None
    exposure_kind = None
    raw_decided = False
    raw_exposures: dict = {}
    if response_frames:
        pd_by_rendered = {Path(pd.rendered_name): pd for pd in pair_data}
        framed = [p for p in response_frames if p in pd_by_rendered]
        raw_rel = {}
        if len(framed) >= 2 and exposure_source in ("auto", "raw"):
            from .pairs import raw_exposure_ratios

            try:
                rel, rep = raw_exposure_ratios([pd_by_rendered[p].thumbnail for p in framed])
            except InputError as exc:
                rel, rep = None, None
                warn(f"exposure ratios from the raws failed ({exc}); using EXIF times")
            if rel is not None:
                comp = rep["component"]
                for p, e, cmp_ in zip(framed, rel, comp):
                    if cmp_ >= 0 and np.isfinite(e):
                        raw_rel[p] = (float(e), cmp_)
        status = next(c[2] for c in candidates if c[1] == usable[0][1])
        if status == "raw?":
            raw_decided = True
            n_raw = _distinct([v[0] for v in raw_rel.values()])
            if n_raw < 2:
                response_frames = []
                reasons.append(
                    f"no response path: the raws of {_noun(framed)} show no exposure "
                    "change between them")
        if response_frames:
            if given_times is not None:
                times_for_response = [given_times[p] for p in response_frames]
                exposure_kind = "given"
                reasons.append("exposure times: given by the caller")
            elif exposure_source == "unknown":
                times_for_response = [None] * len(response_frames)
                exposure_kind = "unknown"
                reasons.append("exposure times: unknown (solved jointly with the response)")
            elif raw_rel and exposure_source in ("auto", "raw") and len(raw_rel) >= 2:
                times_for_response, exposure_kind, raw_exposures = _times_from_raws(
                    response_frames, raw_rel, eff, warn)
                n_used = sum(1 for p in response_frames if p in raw_rel)
                dev = _exif_deviation(raw_exposures)
                reasons.append(
                    f"exposure ratios from the raws (Lin et al. 2011 §5: median ratio of "
                    f"unclipped, well-exposed raw values) for {n_used} of "
                    f"{len(response_frames)} frames"
                    + (f"; EXIF times differ from them by up to {100 * dev:.1f}%"
                       if dev is not None else "")
                    + ("; in seconds via the EXIF times" if any(
                        eff.get(p) is not None for p in raw_rel) else
                       "; relative to the first frame (no EXIF times)"))
            elif exposure_source == "raw":
                raise CalibrationError(
                    "exposure_source='raw' needs at least two response frames with raws "
                    f"(have {len(raw_rel)}: {_names(list(raw_rel)) or 'none'})")
            else:
                exposure_kind = "exif"
                if any(infos[p].exposure_time is None and eff.get(p) is not None
                       for p in response_frames):
                    times_for_response = [eff[p] for p in response_frames]
                missing = [p for p in response_frames if eff.get(p) is None]
                if len(missing) == len(response_frames):
                    exposure_kind = "unknown"
                    reasons.append(
                        "exposure times: none in EXIF; solved jointly with the response "
                        "(up to the exponential ambiguity of Lin et al. §5 -- raws of the "
                        "same frames would fix it)")
                else:
                    reasons.append("exposure times: EXIF" + (
                        f" ({len(missing)} frame(s) without: solved jointly)" if missing
                        else ""))
            shown = sorted({t for t in (eff.get(p) for p in response_frames)
                            if t is not None})
            span = (f" ({_fmt_time(shown[0])} … {_fmt_time(shown[-1])})"
                    if len(shown) >= 2 else "")
            n_exp = _distinct([eff.get(p) for p in response_frames])
            reasons.insert(0, (
                f"response path: {_noun(response_frames)} of one scene"
                + (f" at {n_exp} exposures{span}" if n_exp >= 2 else
                   " at different exposures")))

    if not response_frames and not raw_decided:
        why = _response_missing(groups, candidates)
        if why:
            reasons.append(f"no response path: {why}")
    if not response_frames and not want_pipeline:
        raise CalibrationError(_missing_message(groups, candidates))

    # ---- run the response path
    taken = []
    response_model = None
    if response_frames:
        from .response.calibrate import calibrate_response

        try:
            response_model = calibrate_response([str(p) for p in response_frames],
                                                times_for_response, progress=progress,
                                                **resp_opts)
            taken.append("response")
        except CalibrationError as exc:
            if not want_pipeline:
                raise
            warn(f"the response path failed: {exc}")
            reasons.append(f"response path failed: {exc}")

    # ---- run the pipeline path
    pipeline_model = None
    n_samples = 0 if samples is None else len(samples)
    if want_pipeline:
        fit = _fit_pipeline_function()
        problem = None
        if fit is None:
            problem = ("the RAW path (selfcal.pipeline.fit_pipeline) is not available in "
                       "this installation")
        elif n_samples < MIN_PIPELINE_SAMPLES:
            problem = (f"only {n_samples} usable raw/JPEG samples from "
                       f"{len(groups.pairs)} pair(s) (need ≥ {MIN_PIPELINE_SAMPLES}): "
                       "the pairs are clipped or too textured -- "
                       + "; ".join(f"{Path(pd.rendered_name).name}: " + ", ".join(
                           f"{k} {v}" for k, v in pd.samples.counts.items())
                                   for pd in pair_data))
        if problem is not None:
            if not taken:
                raise CalibrationError(problem)
            warn(f"pipeline path skipped: {problem}")
            reasons.append(f"pipeline path skipped: {problem}")
        else:
            pipe_opts.setdefault("seed", seed)
            pipeline_model = fit(samples.raw, samples.rendered, progress=progress,
                                 **pipe_opts)
            taken.append("pipeline")
            reasons.append(
                f"pipeline path: {len(groups.pairs)} RAW+JPEG pair(s) "
                f"({_names([j for _, j in groups.pairs], 3)}); {n_samples} samples")
    if not taken:
        raise CalibrationError("neither calibration path succeeded: " + "; ".join(reasons))
    # reasons: taken paths first
    return CalibrationResult(
        taken=tuple(taken), reasons=reasons, response=response_model,
        pipeline=pipeline_model, groups=groups, response_frames=list(response_frames),
        exposure_source=exposure_kind, exposure_times=times_for_response,
        raw_exposures=raw_exposures, pairs=pair_data, n_pipeline_samples=n_samples,
        warnings=notes)


def _given_times(exposure_times, rendered):
    if exposure_times is None:
        return None
    if isinstance(exposure_times, dict):
        lookup = {Path(k).resolve(): v for k, v in exposure_times.items()}
        out = {}
        for p in rendered:
            out[p] = lookup.get(p.resolve())
        return {p: (None if t is None else float(t)) for p, t in out.items()}
    times = list(exposure_times)
    if len(times) != len(rendered):
        raise InputError(f"{len(times)} exposure times given for {len(rendered)} rendered "
                         f"frames ({_names(rendered)})")
    out = {}
    for p, t in zip(rendered, times):
        if t is not None:
            t = float(t)
            if not (math.isfinite(t) and t > 0):
                raise InputError(f"exposure time {t!r} must be a positive number", p)
        out[p] = t
    return out


def _times_from_raws(frames, raw_rel, eff, warn):
    """Response exposures: raw ratios (per connected set), in seconds via EXIF."""
    comps: dict[int, list[Path]] = {}
    for p in frames:
        if p in raw_rel:
            comps.setdefault(raw_rel[p][1], []).append(p)
    times = {p: None for p in frames}
    kind = "raw"
    for members in comps.values():
        logs = {p: math.log(raw_rel[p][0]) for p in members}
        anchors = [math.log(eff[p]) - logs[p] for p in members if eff.get(p) is not None]
        if anchors:
            offset = float(np.mean(anchors))
        elif len(comps) == 1 and not any(eff.get(p) is not None for p in frames):
            offset = 0.0
        else:
            warn(f"exposure ratios from the raws of {_names(members)} cannot be put on the "
                 "scale of the other frames (no EXIF times among them); those frames are "
                 "treated as unknown")
            continue
        for p in members:
            times[p] = math.exp(logs[p] + offset)
    for p in frames:
        if p not in raw_rel:
            kind = "raw+exif"
            times[p] = eff.get(p)
    raw_exposures = {str(p): {"raw_relative": raw_rel[p][0], "exif": eff.get(p),
                              "used": times[p]} for p in frames if p in raw_rel}
    return [times[p] for p in frames], kind, raw_exposures


def _exif_deviation(raw_exposures):
    """Largest relative deviation of EXIF times from the raw-derived (used) exposures."""
    devs = []
    for v in raw_exposures.values():
        if v["exif"] is not None and v["used"] is not None:
            devs.append(math.log(v["exif"] / v["used"]))
    if len(devs) < 2:
        return None
    devs = np.array(devs) - np.mean(devs)
    return float(np.exp(np.max(np.abs(devs))) - 1.0)


def _raws_note(groups: InputGroups) -> str:
    if groups.unpaired_raws:
        verb = "has" if len(groups.unpaired_raws) == 1 else "have"
        return (f"no RAW+JPEG pair ({_names(groups.unpaired_raws)} {verb} no JPEG of the "
                "same name in the same folder)")
    return "no raw files"


def _response_missing(groups: InputGroups, candidates) -> str:
    """Why the rendered frames cannot take the response path ('' if there are none)."""
    frames = groups.rendered
    if not frames:
        return ""
    if len(frames) == 1:
        return f"{_noun(frames)} ({frames[0].name}) only"
    if len(candidates) > 1:
        return (f"{_noun(frames)} of {len(candidates)} different sizes, none with frames at "
                "≥ 2 exposures")
    _, fr, status, known = candidates[0]
    if status == "same":
        return f"{_noun(fr)} all at {_fmt_time(known[0])}"
    if status == "no_change":
        return (f"{_noun(fr)} with no exposure times (EXIF) nor any brightness change "
                "between them")
    return f"{_noun(fr)} without two distinct exposures"


def _missing_message(groups: InputGroups, candidates) -> str:
    need = "need frames at ≥ 2 exposures, or a RAW+JPEG pair"
    if not groups.rendered and not groups.unpaired_raws:
        return "no input images: " + need
    if not groups.rendered:
        k = len(groups.unpaired_raws)
        return (f"{k} raw file{'s' if k != 1 else ''} ({_names(groups.unpaired_raws)}) "
                "without a JPEG of the same name, and no other images: put each raw's "
                "camera JPEG beside it (same name, same folder) for the RAW path, or give "
                "rendered frames at ≥ 2 exposures")
    return f"{_response_missing(groups, candidates)} and {_raws_note(groups)}: {need}"


# --------------------------------------------------------------------------------------
# calibrate_pipeline
# --------------------------------------------------------------------------------------

def _as_list(x):
    if isinstance(x, (str, os.PathLike)):
        return [x]
    if isinstance(x, np.ndarray) and x.ndim == 3:
        return [x]
    return list(x)


def calibrate_pipeline(raws, rendered, *, seed: int = 0, progress=None,
                       max_samples: int = 20_000, raw_half_size: bool = True,
                       block: int | None = None, **fit_options):
    """Fit the camera pipeline (raw → rendered and back) to RAW+rendered pairs.

    The RAW path: Gong et al., *Rank-based radiometric calibration* (paper 000), §3 (colour
    matrix from rank order, monotone tone curves, lattice gamut LUT) and the inverse colour
    mapping of Lin et al., ICCV 2011, §6 (Eq. 9-11), fitted by
    :func:`selfcal.pipeline.fit_pipeline` to block-mean correspondences
    (:func:`selfcal.pairs.pair_samples`) that skip clipped and high-gradient blocks.

    Parameters
    ----------
    raws : array, path, or sequence of them
        ``HxWx3`` float linear camera RGB in ``[0, 1]``, or raw file paths (read with
        :func:`selfcal.raw.read_raw_linear`, also 16-bit linear TIFFs).
    rendered : array, path, or sequence of them
        ``HxWx3`` uint8 RGB (the camera's rendering), or JPEG/PNG/TIFF paths; one per raw.
    seed : int
        Seeds the sampling and the fit.
    progress : callable, optional
        ``progress(stage, done, total, detail)``.
    max_samples : int
        Samples drawn over all pairs.
    raw_half_size : bool
        Read raw files at half size.
    block : int, optional
        Block side for the samples (rendered pixels); default adaptive.
    **fit_options
        Passed to :func:`selfcal.pipeline.fit_pipeline`.

    Returns
    -------
    PipelineModel
        With ``render(raw)`` and ``to_raw(rendered)``.

    Raises
    ------
    InputError
        Unreadable files, a rendered image that does not match its raw (both named),
        arrays of different sizes that cannot be registered.
    CalibrationError
        Too few usable samples (everything clipped or textured), or no pipeline fit in this
        installation.
    """
    from .pairs import collect_pair_samples

    raws, rendered = _as_list(raws), _as_list(rendered)
    samples, pairs = collect_pair_samples(raws, rendered, seed=seed, max_samples=max_samples,
                                          half_size=raw_half_size, block=block,
                                          progress=progress)
    if len(samples) < MIN_PIPELINE_SAMPLES:
        raise CalibrationError(
            f"only {len(samples)} usable raw/rendered samples (need ≥ "
            f"{MIN_PIPELINE_SAMPLES}): " + "; ".join(
                f"{Path(p.rendered_name).name}: " + ", ".join(
                    f"{k} {v}" for k, v in p.samples.counts.items()) for p in pairs))
    fit = _fit_pipeline_function()
    if fit is None:
        raise CalibrationError("the RAW path (selfcal.pipeline.fit_pipeline) is not "
                               "available in this installation")
    return fit(samples.raw, samples.rendered, seed=seed, progress=progress, **fit_options)
