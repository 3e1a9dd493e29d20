"""Path choice: look at the inputs and take the calibration path(s) they support.

* Rendered frames (JPEG/PNG/TIFF) of one scene at two or more exposures → the JPEG-only
  **response path** (:func:`selfcal.calibrate_response`; Lin, Kim, Süsstrunk & Brown,
  *Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011 [Lin2011],
  §5, Eq. 7-8).
* One or more RAW+JPEG pairs (a raw file and the rendered file of the same name in the same
  folder) → the **pipeline path** (:func:`selfcal.pipeline.fit_pipeline`; Gong et al.,
  *Rank-based radiometric calibration* [Gong2018], §3; Lin et al. §6).
* A bracketed RAW+JPEG session → both, and the exposure ratios of the response path come
  from the raws (Lin et al. §5: "the exposure ratio can be directly computed by dividing
  the raw values between two images"), which fixes the shutter error and the exponential
  ambiguity of the response.

:func:`calibrate` returns a :class:`CalibrationResult` that says which path(s) were taken
and why; when neither applies it raises :class:`~selfcal.errors.CalibrationError` saying
exactly what is missing.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..exposure.legacy import legacy_keywords_accepted
from ..exposure.record import ExposureRule
from ..errors import CalibrationError, InputError
from ..io.images import (ExposureInfo, effective_exposure_times, read_exposure_info,
                         read_image, read_image_size)
from ..io.raw import read_raw_exposure_info
from ..pipeline import PipelineModel, PipelineOptions, fit_pipeline
from ..pipeline.pairs import collect_pair_samples
from ..response.calibrate import calibrate_response
from ..response.options import ResponseOptions
from ..response.model import ResponseModel
from ..exposure.linear_evidence import linear_evidence
from ..typing import ExposureTimes, PathLike, Progress
from ..exposure.plan import (ResponsePlan, SessionReport, distinct_exposures, file_names,
                            noun, plan_response, seconds_text, times_by_frame)
from .groups import InputGroups, group_inputs

__all__ = ["CalibrationResult", "PairOptions", "calibrate", "calibrate_pipeline"]

#: Median code change (of 255) that counts as a visible exposure change between frames
#: without exposure times.
BRIGHTNESS_CHANGE_CODES = 2.0
#: Fewest samples for the pipeline fit, and per pair before a pair is reported as unusable.
MIN_PIPELINE_SAMPLES = 200
MIN_PAIR_SAMPLES = 50


# ---- the result ----------------------------------------------------------------------

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
    response: ResponseModel | None = None
    pipeline: PipelineModel | None = None
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


# ---- helpers -------------------------------------------------------------------------


def _frame_info(path: Path, raw_path: Path | None) -> ExposureInfo:
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


def _brightness_changes(paths) -> bool:
    """Do frames (same size) differ in brightness by a visible exposure change?

    Median code difference (8-bit scale) against the first frame over pixels unclipped in
    both, on DCT-reduced decodes.
    """
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


# ---- calibrate -----------------------------------------------------------------------

@dataclass(frozen=True)
class PairOptions:
    """How :func:`calibrate` samples RAW+JPEG pairs for the RAW path.

    Attributes
    ----------
    raw_half_size : bool
        Read raws at half size (2×2 binned): faster, and plenty for block means.
    max_pair_samples : int
        Samples for the pipeline fit, shared among the pairs.
    block : int, optional
        Block side (rendered pixels) of the pair samples; default adaptive.
    """

    raw_half_size: bool = True
    max_pair_samples: int = 20_000
    block: int | None = None


@legacy_keywords_accepted("calibrate")
def calibrate(paths: Sequence[PathLike], *,
              exposure_times: ExposureTimes | Mapping[PathLike, float | None] | None = None,
              exposure_source: str = "auto", seed: int = 0,
              exposures: ExposureRule | None = None, align: bool | str = False,
              pairs: PairOptions | None = None,
              response_options: ResponseOptions | None = None,
              pipeline_options: PipelineOptions | None = None,
              progress: Progress | None = None) -> CalibrationResult:
    """Calibrate a camera from whatever files are given, taking the path(s) they support.

    * Rendered frames of one size at ≥ 2 distinct exposures → the response path,
      :func:`selfcal.calibrate_response` (Lin et al., ICCV 2011, §5, Eq. 7-8).  Exposures
      are distinct when they differ by more than 5 % (EXIF time × ISO / N²); frames without
      times count as distinct when their brightness visibly differs.
    * ≥ 1 RAW+JPEG pair (see :func:`group_inputs`) → the pipeline path: every pair is read
      (:func:`selfcal.io.raw.read_raw_linear`), registered
      (:func:`selfcal.pipeline.registration.register_raw_jpeg`) and sampled
      (:func:`selfcal.pipeline.pairs.pair_samples`), and the joined samples go to
      :func:`selfcal.pipeline.fit_pipeline` (Gong et al., rank-based radiometric
      calibration, §3; Lin et al. §6).
    * Both, for a bracketed RAW+JPEG session; the response path's exposures then come from
      the raws (:func:`selfcal.exposure.raw_ratios.raw_exposure_ratios`, Lin et al. §5: median ratio of
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
    exposures : ExposureRule, optional
        The rule for given times of the response path (:func:`selfcal.calibrate_response`;
        :class:`selfcal.exposure.ExposureRule`).
    align : {False, "mtb", "homography"}
        Align a handheld stack before the response path calibrates it
        (:func:`selfcal.calibrate_response`).
    pairs : PairOptions, optional
        How the RAW+JPEG pairs are sampled (half-size raws, samples, block side).
    response_options : ResponseOptions, optional
        The response path's finer settings (:func:`selfcal.calibrate_response`).
    pipeline_options : PipelineOptions, optional
        The pipeline path's finer settings (:func:`selfcal.pipeline.fit_pipeline`).

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError
        A missing or unreadable file (named), a raw LibRaw cannot read (named), a JPEG that
        does not match its raw (both named), a folder with no images (named), a frame
        named one by one whose size differs from the calibrated frames' (named, with both
        sizes; frames of another size found in a folder are left out with a warning).
    CalibrationError
        When the inputs support neither path; the message says what is missing, e.g.
        ``"3 JPEGs all at 1/60 s and no raw files: need frames at ≥ 2 exposures, or a
        RAW+JPEG pair"``.  Also for a bracket of linear TIFFs (raw converter output,
        :func:`selfcal.exposure.linear_evidence.linear_evidence`), which has no response.
    """
    if exposure_source not in ("auto", "raw", "exif", "unknown"):
        raise InputError(f"exposure_source must be auto, raw, exif or unknown, got "
                         f"{exposure_source!r}")
    pairs = PairOptions() if pairs is None else pairs
    resp_opts = {"seed": seed, "exposures": exposures, "align": align,
                 "options": response_options}
    groups = group_inputs(paths)
    report = SessionReport()
    for p, why in groups.ignored:
        report.warn(f"{p}: ignored ({why})")
    for raw in groups.unpaired_raws:
        report.warn(f"{raw}: raw file without a rendered image of the same name "
                    f"({raw.stem}.jpg) in its folder; not used")

    _check_folders(groups, report)
    given_times = times_by_frame(exposure_times, groups.rendered)
    candidates, infos, eff = _size_groups(groups, given_times, exposure_source)
    chosen = _response_group(candidates, groups, report)
    if chosen is not None and not groups.pairs:
        _refuse_linear(chosen.frames, eff)
    want_pipeline = bool(groups.pairs)
    if chosen is None and not want_pipeline:
        raise CalibrationError(_missing_message(groups, candidates))

    samples, pair_data = None, []
    if want_pipeline:
        samples, pair_data = _read_pairs(groups, seed=seed, max_samples=pairs.max_pair_samples,
                                         half_size=pairs.raw_half_size, block=pairs.block,
                                         progress=progress, report=report)
    plan = ResponsePlan()
    if chosen is not None:
        plan = plan_response(chosen, pair_data, infos, eff, given_times, exposure_source,
                              report)
    if not plan.frames and not plan.raw_decided:
        why = _response_missing(groups, candidates)
        if why:
            report.reasons.append(f"no response path: {why}")
    if not plan.frames and not want_pipeline:
        raise CalibrationError(_missing_message(groups, candidates))

    taken = []
    response_model = _run_response(plan, resp_opts, progress=progress,
                                   pipeline_follows=want_pipeline, report=report)
    if response_model is not None:
        taken.append("response")
    pipeline_model = None
    if want_pipeline:
        pipeline_model = _run_pipeline(samples, pair_data, groups, pipeline_options, seed=seed,
                                       progress=progress, response_taken=bool(taken),
                                       report=report)
        if pipeline_model is not None:
            taken.append("pipeline")
    if not taken:
        raise CalibrationError("neither calibration path succeeded: "
                               + "; ".join(report.reasons))
    return CalibrationResult(
        taken=tuple(taken), reasons=report.reasons, response=response_model,
        pipeline=pipeline_model, groups=groups, response_frames=list(plan.frames),
        exposure_source=plan.exposure_kind, exposure_times=plan.times,
        raw_exposures=plan.raw_exposures, pairs=pair_data,
        n_pipeline_samples=0 if samples is None else len(samples),
        warnings=report.warnings)


# ---- the pieces of calibrate ---------------------------------------------------------

class _SizeGroup(NamedTuple):
    """Rendered frames of one image size, and whether they can take the response path."""

    size: tuple
    frames: list
    #: "ok" (≥ 2 distinct exposures, known or by brightness), "raw?" (decided by the raw
    #: ratios), "single", "same" (all at one known time), "no_change" (no times, no change)
    status: str
    known: list        # the known exposures (EXIF or given)


def _size_groups(groups: InputGroups, given_times, exposure_source):
    """The rendered frames grouped by image size, each with its response-path status.

    Returns ``(candidates, infos, eff)``: the :class:`_SizeGroup` list, each frame's
    :class:`~selfcal.io.ExposureInfo` (EXIF, completed from its raw) and its effective
    exposure (EXIF time × ISO / N² relative to the first frame, or the given time).
    """
    raw_of = groups.raw_of
    sizes: dict[tuple, list[Path]] = {}
    for p in groups.rendered:
        sizes.setdefault(read_image_size(p), []).append(p)
    infos = {p: _frame_info(p, raw_of.get(p)) for p in groups.rendered}
    eff = dict(zip(groups.rendered, effective_exposure_times([infos[p] for p in groups.rendered])))
    if given_times is not None:
        eff = dict(given_times)

    candidates = []
    for size, frames in sizes.items():
        known = [eff[p] for p in frames if eff[p] is not None]
        unknown = [p for p in frames if eff[p] is None]
        with_raw = [p for p in frames if p in raw_of]
        if len(frames) < 2:
            status = "single"
        elif distinct_exposures(known) >= 2:
            status = "ok"
        elif len(with_raw) >= 2 and exposure_source in ("auto", "raw") and \
                given_times is None:
            status = "raw?"   # decided by the raw ratios
        elif unknown and _brightness_changes(frames):
            status = "ok"
        else:
            status = "same" if not unknown else "no_change"
        candidates.append(_SizeGroup(size, frames, status, known))
    return candidates, infos, eff


def _response_group(candidates, groups: InputGroups, report: SessionReport) -> _SizeGroup | None:
    """The size group the response path calibrates: the usable one with most frames (one
    scene per calibration).

    Rendered frames of another size, without a raw (the pipeline path uses paired frames
    of any size), would be left out: a file named one by one is refused
    (:class:`~selfcal.errors.InputError` naming it and both sizes), as the merge refuses
    it; files found in a folder are left out with a warning naming each.
    """
    usable = [c for c in candidates if c.status in ("ok", "raw?")]
    usable.sort(key=lambda c: -len(c.frames))
    if not usable:
        return None
    chosen = usable[0]
    size = f"{chosen.size[1]}x{chosen.size[0]}"
    paired, from_folder = groups.raw_of, groups.from_folder
    for c in candidates:
        if c is chosen:
            continue
        for p in c.frames:
            if p in paired:
                continue
            if p not in from_folder:
                raise InputError(
                    f"frame size {c.size[1]}x{c.size[0]} differs from the other frames' "
                    f"{size} ({file_names(chosen.frames, 2)}): one scene per calibration; "
                    "leave it out or give frames of one size", p)
            report.warn(f"{p}: left out ({c.size[1]}x{c.size[0]}, the calibrated frames "
                        f"are {size}: one scene per calibration)")
    return chosen


def _check_folders(groups: InputGroups, report: SessionReport) -> None:
    """An empty folder: an error naming it when nothing else is given, else a warning."""
    empty = [folder for folder, files in groups.folders.items() if not files]
    if not empty:
        return
    what = ("no image or raw files (JPEG, PNG, TIFF or camera raws; folders are not "
            "searched recursively)")
    if not groups.rendered and not groups.unpaired_raws:
        raise InputError(f"the folder holds {what}", empty[0])
    for folder in empty:
        report.warn(f"{folder}: the folder holds {what}")


def _refuse_linear(frames, eff) -> None:
    """Linear TIFFs (raw converter output) are not rendered frames: refuse them."""
    why = linear_evidence(frames, [eff.get(p) for p in frames])
    if why:
        raise CalibrationError(
            f"{file_names(frames)} are linear data, not rendered frames: {why}; linear data "
            "have no response to calibrate: merge them to HDR as they are (selfcal merge, "
            "which measures their exposure ratios from the pixels; merge_hdr(..., "
            "linear=True)), put each raw beside the camera's JPEG of the same name for the "
            "RAW path, or, if they are rendered frames after all, give their exposure times")


def _read_pairs(groups: InputGroups, *, seed, max_samples, half_size, block, progress,
                report: SessionReport):
    """Read, register and sample every RAW+JPEG pair (pipeline data and raw exposure
    ratios); warn about pairs with too few usable samples."""
    samples, pair_data = collect_pair_samples(
        [r for r, _ in groups.pairs], [j for _, j in groups.pairs], seed=seed,
        max_samples=max_samples, half_size=half_size, block=block, progress=progress)
    for pd in pair_data:
        c = pd.samples.counts
        if c.get("valid", 0) < MIN_PAIR_SAMPLES:
            report.warn(f"{pd.rendered_name}: only {c.get('valid', 0)} usable samples against "
                        f"its raw ({c.get('clipped_raw', 0)} blocks clipped in the raw, "
                        f"{c.get('clipped_rendered', 0)} clipped in the JPEG, "
                        f"{c.get('high_gradient', 0)} high-gradient, of {c.get('total', 0)})")
    return samples, pair_data


def _run_response(plan: ResponsePlan, resp_opts: dict, *, progress, pipeline_follows,
                  report: SessionReport):
    """The response path (:func:`selfcal.calibrate_response`) on the planned frames, or
    None without frames; a failure is an error unless the pipeline path follows.
    ``resp_opts`` holds its ``seed``, ``exposures``, ``align`` and ``options``."""
    if not plan.frames:
        return None
    try:
        model = calibrate_response(
            [str(p) for p in plan.frames], plan.times, progress=progress,
            times_source=(plan.exposure_kind or "given") if plan.times is not None
            else "given",
            seed=resp_opts["seed"], exposures=resp_opts["exposures"],
            align=resp_opts["align"], options=resp_opts["options"])
    except CalibrationError as exc:
        if not pipeline_follows:
            raise
        report.warn(f"the response path failed: {exc}")
        report.reasons.append(f"response path failed: {exc}")
        return None
    # calibrate_response warned them already: recorded here, not warned twice
    report.warnings.extend(w for w in model.diagnostics.get("warnings", [])
                           if w not in report.warnings)
    return model


def _run_pipeline(samples, pair_data, groups: InputGroups, options: PipelineOptions | None, *,
                  seed, progress, response_taken, report: SessionReport):
    """The pipeline path (:func:`selfcal.pipeline.fit_pipeline`) on the joined pair samples.

    With too few samples it is skipped with a warning when the response path was taken,
    and is an error otherwise.
    """
    n_samples = 0 if samples is None else len(samples)
    if n_samples < MIN_PIPELINE_SAMPLES:
        problem = (f"only {n_samples} usable raw/JPEG samples from "
                   f"{len(groups.pairs)} pair(s) (need ≥ {MIN_PIPELINE_SAMPLES}): "
                   "the pairs are clipped or too textured -- "
                   + "; ".join(f"{Path(pd.rendered_name).name}: " + ", ".join(
                       f"{k} {v}" for k, v in pd.samples.counts.items())
                               for pd in pair_data))
        if not response_taken:
            raise CalibrationError(problem)
        report.warn(f"pipeline path skipped: {problem}")
        report.reasons.append(f"pipeline path skipped: {problem}")
        return None
    # one group per pair (PairSamples.groups): with two or more pairs the regulariser
    # weights are chosen by leave-one-scene-out (fit_pipeline's groups; one pair: the
    # call is unchanged, leave-one-sample-out)
    n_groups = len(np.unique(samples.groups))
    model = fit_pipeline(samples.raw, samples.rendered, options, seed=seed, progress=progress,
                         groups=samples.groups if n_groups > 1 else None)
    report.reasons.append(
        f"pipeline path: {len(groups.pairs)} RAW+JPEG pair(s) "
        f"({file_names([j for _, j in groups.pairs], 3)}); {n_samples} samples"
        + (f"; regulariser weights by leave-one-scene-out over {n_groups} pairs"
           if n_groups > 1 else ""))
    return model


def _raws_note(groups: InputGroups) -> str:
    if groups.unpaired_raws:
        verb = "has" if len(groups.unpaired_raws) == 1 else "have"
        return (f"no RAW+JPEG pair ({file_names(groups.unpaired_raws)} {verb} no JPEG of the "
                "same name in the same folder)")
    return "no raw files"


def _response_missing(groups: InputGroups, candidates) -> str:
    """Why the rendered frames cannot take the response path ('' if there are none)."""
    frames = groups.rendered
    if not frames:
        return ""
    if len(frames) == 1:
        return f"{noun(frames)} ({frames[0].name}) only"
    if len(candidates) > 1:
        return (f"{noun(frames)} of {len(candidates)} different sizes, none with frames at "
                "≥ 2 exposures")
    _, fr, status, known = candidates[0]
    if status == "same":
        return f"{noun(fr)} all at {seconds_text(known[0])}"
    if status == "no_change":
        return (f"{noun(fr)} with no exposure times (EXIF) nor any brightness change "
                "between them")
    return f"{noun(fr)} without two distinct exposures"


def _missing_message(groups: InputGroups, candidates) -> str:
    need = "need frames at ≥ 2 exposures, or a RAW+JPEG pair"
    if not groups.rendered and not groups.unpaired_raws:
        return "no input images: " + need
    if not groups.rendered:
        k = len(groups.unpaired_raws)
        return (f"{k} raw file{'s' if k != 1 else ''} ({file_names(groups.unpaired_raws)}) "
                "without a JPEG of the same name, and no other images: raws are linear "
                "and have no response to calibrate (a bracket of them merges to HDR as it "
                "is: selfcal merge RAWS -o OUT.exr); put each raw's camera JPEG beside it "
                "(same name, same folder) for the RAW path, or give rendered frames at ≥ 2 "
                "exposures")
    return f"{_response_missing(groups, candidates)} and {_raws_note(groups)}: {need}"


# ---- calibrate_pipeline --------------------------------------------------------------

def _as_list(x):
    if isinstance(x, (str, os.PathLike)):
        return [x]
    if isinstance(x, np.ndarray) and x.ndim == 3:
        return [x]
    return list(x)


def calibrate_pipeline(raws: Sequence[PathLike], rendered: Sequence[PathLike], *, seed: int = 0,
                       progress: Progress | None = None, pairs: PairOptions | None = None,
                       options: PipelineOptions | None = None) -> PipelineModel:
    """Fit the camera pipeline (raw → rendered and back) to RAW+rendered pairs.

    The RAW path: Gong et al., *Rank-based radiometric calibration* [Gong2018], §3 (colour
    matrix from rank order, monotone tone curves, lattice gamut LUT) and the inverse colour
    mapping of Lin et al., ICCV 2011, §6 (Eq. 9-11), fitted by
    :func:`selfcal.pipeline.fit_pipeline` to block-mean correspondences
    (:func:`selfcal.pipeline.pairs.pair_samples`) that skip clipped and high-gradient blocks.

    Parameters
    ----------
    raws : array, path, or sequence of them
        ``HxWx3`` float linear camera RGB in ``[0, 1]``, or raw file paths (read with
        :func:`selfcal.io.raw.read_raw_linear`, also 16-bit linear TIFFs).
    rendered : array, path, or sequence of them
        ``HxWx3`` uint8 RGB (the camera's rendering), or JPEG/PNG/TIFF paths; one per raw.
    seed : int
        Seeds the sampling and the fit.
    progress : callable, optional
        ``progress(stage, done, total, detail)``.
    pairs : PairOptions, optional
        How the pairs are sampled: samples drawn over all pairs (``max_pair_samples``),
        half-size raws, block side (default ``PairOptions()``).
    options : PipelineOptions, optional
        The fit's finer settings (:func:`selfcal.pipeline.fit_pipeline`).  Each pair is
        one group of the fit, so with two or more pairs the regulariser weights are
        chosen by leave-one-scene-out -- the weights that predict a scene the fit did not
        see; ``model.diagnostics["groups"]`` holds the samples per pair.

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
        Too few usable samples (everything clipped or textured).
    """
    pairs = PairOptions() if pairs is None else pairs
    raws, rendered = _as_list(raws), _as_list(rendered)
    samples, pair_data = collect_pair_samples(
        raws, rendered, seed=seed, max_samples=pairs.max_pair_samples,
        half_size=pairs.raw_half_size, block=pairs.block, progress=progress)
    if len(samples) < MIN_PIPELINE_SAMPLES:
        raise CalibrationError(
            f"only {len(samples)} usable raw/rendered samples (need ≥ "
            f"{MIN_PIPELINE_SAMPLES}): " + "; ".join(
                f"{Path(p.rendered_name).name}: " + ", ".join(
                    f"{k} {v}" for k, v in p.samples.counts.items()) for p in pair_data))
    # one group per pair: leave-one-scene-out weights with two or more pairs
    groups = samples.groups if len(np.unique(samples.groups)) > 1 else None
    return fit_pipeline(samples.raw, samples.rendered, options, seed=seed, progress=progress,
                        groups=groups)
