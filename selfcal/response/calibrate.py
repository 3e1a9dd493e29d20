"""``calibrate_response``: the JPEG-only path, from frames to a ResponseModel.

[Lin2011] §5 (Eq. 7-8, outlier rejection) and §7 (δ, Eq. 12); unknown exposures solved
jointly after [Kim2008].  The stages, in the order they run: the
exposure times (:mod:`selfcal.exposure.times`), the samples and the frames the solve can use
(:mod:`.frame_choice`), the solve of Eq. 8 (:mod:`.solver`), δ (:mod:`.delta`) and the
verdict (:mod:`.verdict`).  Their finer settings travel together in
:class:`ResponseOptions`.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..stack.align import aligned_working_frames, estimate_alignment
from ..errors import CalibrationError, InputError, SelfcalWarning
from ..stack.frames import DEFAULT_CLIP_MARGIN, StackFrames, default_reference
from .stuck_codes import stuck_code_levels
from ..io.images import is_path
from ..stack.samples import KeptData, SampleSet, collect_samples, frame_masks
from ..typing import ExposureTimes, ImageInput, Progress
from .bands import band_for_fit
from .model import ResponseModel
from .code_error import code_error_profile
from .delta import delta_eq12
from .hidden_white import white_end_masks
from ..exposure.legacy import legacy_keywords_accepted
from ..exposure.record import ExposureRule, GivenTimes, read_given_times
from ..exposure.resolve import exposure_message, recorded_calibration
from ..exposure.times import CONTRADICTED_UNUSABLE_SHARE, CONTRADICTION_FACTOR
from .solved_times import anchor_refined, corrected_times, log_exposure_times
from .diagnostics import fit_diagnostics
from ..exposure.measured import MEASURE_CODES_SIDE
from .frame_choice import record_ignored, subset, without_clipped_frames, without_duplicates
from .options import ResponseOptions
from .solver import SolveResult, solve_exposure_equations
from .verdict import judge_calibration

#: A frame sharing fewer unclipped samples than this with every other frame is ignored:
#: it is too far from the rest of the bracket to add equations or have its time checked.
MIN_SHARED_SAMPLES = 20


@dataclass(frozen=True)
class CalibrationCall:
    """What one calibration was asked for (:func:`calibrate_response`'s arguments)."""

    options: ResponseOptions
    rule: ExposureRule = ExposureRule()
    seed: int = 0
    progress: object = None


@legacy_keywords_accepted("calibrate_response")
def calibrate_response(images: Sequence[ImageInput], exposure_times: ExposureTimes | None = None,
                       *, exposures: ExposureRule | None = None, seed: int = 0,
                       align: bool | str = False, progress: Progress | None = None,
                       times_source: str = "given",
                       options: ResponseOptions | None = None) -> ResponseModel:
    """Estimate each channel's camera response from an exposure stack.

    Implements [Lin2011] §5: log-domain PCA model (Eq. 7) fitted to the exposure equation
    g(I′) − g(I) = K′ (Eq. 8) over sample pairs, with clipped and highly saturated
    samples rejected and a Huber loss for the rest.

    Parameters
    ----------
    images : sequence
        ``HxWx3`` uint8/uint16 RGB arrays, or paths to JPEG/PNG/TIFF files (8 or 16 bit).
        Several shots at one exposure are allowed.
    exposure_times : sequence of float or None, optional
        Exposure time per frame; None for a frame whose time is unknown.  When omitted,
        times come from EXIF for paths and are unknown for arrays.
    exposures : ExposureRule, optional
        The rule for given times, EXIF and the caller's alike
        (:class:`selfcal.exposure.ExposureRule`): by default the times the pixels
        contradict by more than :data:`selfcal.exposure.times.CONTRADICTION_FACTOR` are
        refined in the solve, and the model's exposures are measured from the pixels
        through the fitted curve (the times keep their scale and trend);
        ``ExposureRule(times="held")`` holds every time.  1.0's ``refine_exposures=``
        is still accepted until 2.0, with a DeprecationWarning
        (:mod:`selfcal.exposure.legacy`).
    seed : int
        Seed of every random choice (the same input gives the same model).
    align : {False, "mtb", "homography"}
        Handheld stacks: align the frames to the middle exposure first
        (:func:`calibrate_aligned`); misaligned frames give wrong
        correspondences, which read as contradicted exposure times.  With
        ``"homography"`` the lens falloff is fitted jointly when the frames moved
        (:mod:`.vignetting_fit`, [Goldman2010]; ``diagnostics["vignetting"]`` says if not).
    progress : callable, optional
        ``progress(stage, done, total, detail)`` for long work.
    times_source : {"given", "raw"}
        Where the given ``exposure_times`` came from (``"raw"``: measured from raw files),
        for the model's :attr:`~ResponseModel.exposure_record`.
    options : ResponseOptions, optional
        The finer settings of the sampling and the solve (number of components, β, clip
        margin, samples, Huber threshold, priors, correspondences); default
        ``ResponseOptions()``.

    Returns
    -------
    ResponseModel
        Its ``diagnostics`` hold the fit's evidence and the verdict
        (:mod:`selfcal.response.verdict`): ``"verdict"`` (``"ok"``, ``"doubtful"`` or
        ``"unusable"`` -- the model is returned in every case), ``"verdict_reasons"``
        and ``"verdict_evidence"``; its ``frames_ignored`` the frames left out and why;
        its ``exposure_record`` every frame's given, solved, measured and used exposure.

    Warns
    -----
    SelfcalWarning
        The exposures' line (:func:`selfcal.exposure.exposure_message`) and each of the
        model's ``diagnostics["warnings"]`` (frames ignored, the exponential ambiguity left
        to the prior, the verdict's reasons).

    Raises
    ------
    InputError
        Unreadable files, frames of different sizes, duplicates with different times,
        NaN in arrays, bad times (the message names the file).
    CalibrationError
        When the data cannot determine a response (one frame, no exposure change, too few
        valid samples).
    """
    call = CalibrationCall(options=ResponseOptions() if options is None else options,
                 rule=ExposureRule() if exposures is None else exposures, seed=seed,
                 progress=progress)
    frames = list(images)
    if len(frames) < 2:
        raise CalibrationError(
            "one frame only: a response needs at least two frames at different exposures")
    given = read_given_times(frames, exposure_times, origin=times_source)
    if align:
        model = _calibrate_after_alignment(StackFrames(frames, False), given, align, call)
    else:
        model = calibrate_given(frames, given, call)
    model.diagnostics.setdefault("vignetting", {
        "observable": None, "reason": "not attempted (needs --align homography)"})
    emit_warnings(model)
    return model


def emit_warnings(model, stacklevel: int = 3) -> None:
    """Emit the model's exposure line and each of its ``diagnostics["warnings"]`` as a
    SelfcalWarning."""
    import warnings as _warnings

    for message in model_warnings(model):
        _warnings.warn(message, SelfcalWarning, stacklevel=stacklevel)


def model_warnings(model) -> list[str]:
    """What a calibration has to say: its exposures' line (from the record, the one place
    it is worded), then ``diagnostics["warnings"]``."""
    record = getattr(model, "exposure_record", None)
    line = None if record is None else exposure_message(record)
    return ([line] if line else []) + list(model.diagnostics.get("warnings", []))


@dataclass(frozen=True, eq=False)
class _Usable:
    """The frames the solve uses: their samples, masks, given times and names."""

    samples: SampleSet
    masks: dict
    log_times: np.ndarray           # NaN where unknown
    sources: list
    times: list                     # seconds, None where unknown


@dataclass(frozen=True, eq=False)
class _Readout:
    """The read stage's result: every frame's samples and masks, the frames kept."""

    samples: SampleSet
    masks: dict
    keep: list
    ignored: tuple
    warnings: tuple


@dataclass(frozen=True, eq=False)
class _Solved:
    """The solve stage's result: the fit of Eq. 8, the times it refined or holds, the
    contradicted ones, the measured ringing reach and hidden white samples."""

    result: SolveResult
    refined: bool
    contradictions: list
    reach: int
    hidden: int


def calibrate_given(frames: Sequence, given: GivenTimes, call: CalibrationCall) -> ResponseModel:
    """:func:`calibrate_response` on frames whose given times are read
    (:func:`selfcal.exposure.read_given_times`), without emitting its warnings (they are
    in the model).

    The stages, each a function of the values before it: read the frames' samples and
    choose the usable ones (:func:`_read_stage`), solve Eq. 8 with the rule for the times
    (:func:`_solve_stage`), judge the fit (:func:`_judged_fit`), its band
    (:func:`.bands.band_for_fit`), the exposures measured through the curve
    (:func:`_measure_stage`) and the model (:func:`_model_stage`).
    """
    frames = list(frames)
    if len(frames) < 2:
        raise CalibrationError(
            "one frame only: a response needs at least two frames at different exposures")
    basis, n_components = _log_domain_basis(call.options.basis,
                                            call.options.solver.n_components)
    options = call.options.with_solver(n_components=n_components)
    read = _read_stage(frames, given, options, call)
    keep = read.keep
    sub_times = [given.seconds[k] for k in keep]
    usable = _Usable(samples=subset(read.samples, keep),
                     masks={k: v[keep] for k, v in read.masks.items()},
                     log_times=log_exposure_times(sub_times),
                     sources=[given.sources[k] for k in keep], times=sub_times)
    solved = _solve_stage(read.samples, usable, keep, basis, options, call)
    warnings = list(read.warnings) + list(solved.result.warnings)
    fit = _judged_fit(usable, basis, solved.result, options=options, refined=solved.refined,
                      contradictions=solved.contradictions)
    warnings.extend(fit["reasons"])
    band_warnings: list[str] = []
    log_sigma = band_for_fit(usable.samples, usable.masks, basis, solved.result,
                             usable.log_times, fit, band_warnings,
                             options=options.solver, seed=call.seed,
                             method=options.band_method)
    warnings.extend(band_warnings)
    model = _model_stage(read, usable, given, basis, solved, fit, log_sigma, warnings,
                         options)
    stuck = fit["stuck"]
    return recorded_calibration(
        model, given, keep, solved.result.log_exposures, rule=call.rule,
        refined=solved.refined, contradictions=solved.contradictions,
        codes=read.samples.codes, clip_margin=options.solver.clip_margin,
        stuck=None if stuck is None else (np.asarray(stuck["floor"], dtype=float),
                                          np.asarray(stuck["ceiling"], dtype=float)))


def _read_stage(frames, given: GivenTimes, options: ResponseOptions, call: CalibrationCall) -> _Readout:
    """The frames' samples and masks, and the frames the solve can use
    (:func:`_sample_usable_frames`), with a warning for each file without an EXIF time."""
    warnings: list[str] = []
    if given.read_from_files and all(is_path(f) for f in frames):
        for src, g in zip(given.sources, given.times):
            if not g.known:
                warnings.append(f"{src}: no exposure time in EXIF; treated as unknown")
    ignored: list = []
    samples, masks, keep = _sample_usable_frames(
        frames, list(given.sources), list(given.seconds), warnings, options=options,
        seed=call.seed, progress=call.progress, ignored=ignored,
        keep_codes=call.rule.measured)
    return _Readout(samples=samples, masks=masks, keep=keep,
                    ignored=tuple(sorted(ignored, key=lambda f: given.sources.index(f.source))),
                    warnings=tuple(warnings))


def _solve_stage(samples, usable: _Usable, keep, basis, options, call: CalibrationCall) -> _Solved:
    """Eq. 8 solved over the usable frames, the given times held or refined by the rule
    (:meth:`selfcal.exposure.ExposureRule.solve_refines`: the times the pixels contradict,
    found by :func:`_contradicted_times`), then once more without the samples the fit
    predicts at white (:func:`.hidden_white.white_end_masks`; held times only)."""
    rule = call.rule
    refine_from_start = rule.measured and rule.refine is True
    solve = functools.partial(_solve, usable, basis, options=options, progress=call.progress)
    result = solve(refine_exposures=refine_from_start)
    if samples.reduced is not None:     # the block fit gates the histogram correspondences
        solve = _histogram_solve(samples, usable, keep, basis, result, options, call.progress)
        result = solve(refine_exposures=refine_from_start)
    known = int(np.isfinite(usable.log_times).sum())
    contradictions = []
    if known >= 2 and not refine_from_start:
        contradictions = _contradicted_times(usable, basis, options)
    refined = rule.solve_refines(len(contradictions), known, CONTRADICTED_UNUSABLE_SHARE)
    if refined and contradictions:        # decided now: times contradicted
        result = solve(refine_exposures=True)
    # measured on the final fit with the exposures held only: refined exposures lean on
    # the samples near clipped areas (a 192x288 stack with one wrong EXIF time, refined,
    # went from 0.0026 to 0.0081 f⁻¹ RMSE without them; tests/test_verdict.py)
    reach, hidden = ((0, 0) if refined else
                     white_end_masks(usable.samples, usable.masks, basis, result, options))
    if reach or hidden:       # the masks the partial holds are updated in place
        result = solve(refine_exposures=False)
    if refined:
        result.log_exposures = anchor_refined(result.log_exposures, usable.log_times)
    return _Solved(result=result, refined=refined, contradictions=contradictions,
                   reach=int(reach), hidden=hidden)


def _model_stage(read: _Readout, usable: _Usable, given: GivenTimes, basis, solved: _Solved,
                 fit, log_sigma, warnings, options) -> ResponseModel:
    """The :class:`ResponseModel`: the curve, its band, the diagnostics of the fit, and the
    solve's exposures (NaN for frames it did not use); the record of its exposures is
    :func:`selfcal.exposure.resolve.recorded_calibration`'s."""
    result = solved.result
    diagnostics = fit_diagnostics(
        result, fit, warnings=warnings, options=options, frames_used=usable.sources,
        samples=read.samples)
    diagnostics["stuck_codes"] = fit["stuck"]
    # the curve's error per code level (the merge weighs and its σ counts it)
    diagnostics["code_error_log"] = code_error_profile(
        usable.samples, ~(usable.masks["clipped"] | usable.masks["saturated"]), result,
        fit["grid"], fit["inverse"])
    if options.measure_ringing:
        diagnostics["ringing_reach_blocks"] = solved.reach
    diagnostics["hidden_white_samples"] = solved.hidden
    diagnostics["frame_digests"] = list(read.samples.digests)
    model = ResponseModel(intensity=fit["grid"].copy(), inverse=fit["inverse"],
                          coefficients=result.coefficients, basis_name=basis.name,
                          exposures=_solved_exposures(len(given), read.keep,
                                                      result.log_exposures),
                          exposure_times=list(given.seconds), sources=list(given.sources),
                          max_code=read.samples.max_code, diagnostics=diagnostics,
                          inverse_log_sigma=log_sigma, frames_ignored=read.ignored)
    model.fit_data = _btf_data(usable.samples, usable.masks, result, usable.sources)
    return model


def _solved_exposures(n: int, keep, log_exposures) -> np.ndarray:
    """The solve's exposures of every frame (NaN for frames it did not use)."""
    out = np.full(n, np.nan)
    out[keep] = np.exp(log_exposures)
    return out


def _judged_fit(usable: _Usable, basis, result, *, options, refined: bool, contradictions):
    """The fitted f⁻¹ table, δ of Eq. 12, the stuck code levels and the verdict.

    With ``refined`` the verdict sees the times the pixels corrected (evidence only);
    otherwise the contradicted ones.
    """
    sub, log_times = usable.samples, usable.log_times
    grid, inverse = _inverse_response(basis, result.coefficients,
                                      options.solver.n_components)
    valid = ~(usable.masks["clipped"] | usable.masks["saturated"])
    pairs = [tuple(p) for p in result.pair_frames]
    delta = delta_eq12(sub.values, grid, inverse, result.log_exposures, pairs, valid)
    # per channel, the black floor and stuck ceiling of the codes (the stuck-sample test
    # as code levels): the merge gives them zero weight, the verdict leaves them out
    stuck = stuck_code_levels(sub.values, result.log_exposures,
                              clip_margin=options.solver.clip_margin)
    corrected = (corrected_times(result.log_exposures, log_times, usable.sources,
                                 usable.times)
                 if refined else contradictions)
    verdict, reasons, evidence = judge_calibration(
        sub, valid, grid, inverse, result.log_exposures, pairs, log_times=log_times,
        contradictions=corrected, refined=refined, stuck_codes=stuck)
    return {"grid": grid, "inverse": inverse, "delta": delta, "stuck": stuck,
            "verdict": verdict, "reasons": reasons, "evidence": evidence}


def _calibrate_after_alignment(frames: StackFrames, given: GivenTimes, align, call: CalibrationCall):
    """``calibrate_response(..., align=...)``: align the frames, then calibrate.

    The warnings of the alignment come first in the model's diagnostics.  The options'
    clip margin serves the alignment and the calibration of the aligned frames; the
    provisional calibration that supplies unknown times for the alignment uses the
    default clip margin (as it always has).
    """
    if align is True:
        align = "mtb"
    if align not in ("mtb", "homography"):
        raise InputError(f"unknown alignment {align!r} (mtb or homography)")
    provisional = replace(call,
                          options=call.options.with_solver(clip_margin=DEFAULT_CLIP_MARGIN))
    model, _, _, warnings = aligned_calibration(frames, given, provisional, method=align,
                                                clip_margin=call.options.solver.clip_margin)
    model.diagnostics["warnings"] = warnings + model.diagnostics["warnings"]
    return model


@legacy_keywords_accepted("calibrate_aligned")
def calibrate_aligned(images, exposure_times=None, *, method="mtb", reference=None,
                      clip_margin: float | None = None, progress=None, max_side: int = 2048,
                      exposures: ExposureRule | None = None,
                      options: ResponseOptions | None = None):
    """Align a handheld stack to its reference frame, then calibrate its response.

    Misaligned frames give wrong correspondences, and the solve of [Lin2011] Eq. 8 then
    reads them as contradicted exposure times; so the frames are aligned first
    (:func:`selfcal.stack.align.estimate_alignment`; with unknown times, after a provisional
    calibration that supplies the exposures the homography needs) and the response is
    calibrated on the aligned frames, downscaled to ``max_side``
    (:func:`selfcal.stack.align.aligned_working_frames`: the calibration uses block means only).

    Ours, not the paper's: with unknown times, a provisional calibration on the unaligned
    frames supplies the exposures the homography needs; the model's sources and messages
    name the original frames.

    Parameters
    ----------
    images : sequence
        Frames (arrays or paths).
    exposure_times : sequence of float or None, optional
        As for :func:`selfcal.calibrate_response`.
    method : {"mtb", "homography"}
        Alignment (see :func:`selfcal.stack.align.estimate_alignment`).
    reference : int, optional
        Reference frame; default the middle exposure.
    clip_margin : float, optional
        Clip margin of the alignment and of the calibration of the aligned frames;
        default the ``options``' (``ResponseOptions.solver.clip_margin``).
    progress : callable, optional
        As for :func:`calibrate_response`.
    max_side : int
        Long side (pixels) of the aligned frames the response is calibrated on.
    exposures : ExposureRule, optional
        As for :func:`calibrate_response`.
    options : ResponseOptions, optional
        The calibration's finer settings (default ``ResponseOptions()``).

    Returns
    -------
    (ResponseModel, list of 3x3 arrays, int)
        The model (its ``sources`` the frames given, its ``diagnostics["alignment"]`` the
        transforms), each frame's transform to the reference, and the reference.

    Warns
    -----
    SelfcalWarning
        The model's warnings (:func:`model_warnings`), the alignment's first.
    """
    resolved = ResponseOptions() if options is None else options
    call = CalibrationCall(options=resolved, progress=progress,
                 rule=ExposureRule() if exposures is None else exposures)
    frames = images if isinstance(images, StackFrames) else StackFrames(images, False)
    given = read_given_times(frames.items, exposure_times, frames.sources)
    model, transforms, ref, warnings = aligned_calibration(
        frames, given, call, reference=reference,
        clip_margin=resolved.solver.clip_margin if clip_margin is None else clip_margin,
        method=method, max_side=max_side)
    model.diagnostics["warnings"] = warnings + model.diagnostics["warnings"]
    emit_warnings(model)
    return model, transforms, ref


def aligned_calibration(frames: StackFrames, given: GivenTimes, call: CalibrationCall, *, method="mtb",
                        reference=None, clip_margin: float = DEFAULT_CLIP_MARGIN,
                        max_side: int = 2048):
    """:func:`calibrate_aligned` on frames whose times are read, without emitting the
    model's warnings; with ``options.fit_vignetting`` and homographies, the vignetting is
    fitted jointly.

    ``call`` serves the provisional calibration (unknown times); the aligned frames are
    calibrated with ``clip_margin``, the alignment's.  The aligned working frames are
    named after the frames they come from, so every message names the files.

    Returns
    -------
    (ResponseModel, transforms, reference, the alignment's warnings)
    """
    n = len(frames)
    progress = call.progress
    warnings: list[str] = []
    seconds = list(given.seconds)
    provisional = None
    if any(s is None for s in seconds):
        provisional = calibrate_given(frames.items, given, call)
        seconds = [float(e) for e in provisional.exposures]
    ref = default_reference(seconds) if reference is None else int(reference)
    if not 0 <= ref < n:
        raise InputError(f"reference frame {reference} is out of range (0..{n - 1})")
    transforms = estimate_alignment(frames, seconds, provisional, method=method, reference=ref,
                                    clip_margin=clip_margin, warnings=warnings,
                                    progress=progress)
    small = aligned_working_frames(frames, transforms, max_side=max_side)
    # the solve gets the frames' own times (seconds, None where unknown), as unaligned
    aligned = replace(call, options=call.options.with_solver(clip_margin=clip_margin))
    times = list(given.seconds)
    if call.options.fit_vignetting and method == "homography":   # [Goldman2010]
        from . import vignetting_fit as vf

        basis = _log_domain_basis(call.options.basis, call.options.solver.n_components)
        model = vf.calibrate_with_vignetting(
            small, vf.working_transforms(transforms, frames.shape, small[0].shape[:2]), times,
            lambda f: calibrate_given(f, given, aligned),
            lambda f: vf.prior_mean_model(f, times, *basis), reference=ref, seed=call.seed,
            originals=lambda: [frames.load(k) for k in range(n)])
    else:
        model = calibrate_given(small, given, aligned)
    model.diagnostics["calibrated_on"] = (f"frames aligned ({method}), long side "
                                          f"{max(small[0].shape[:2])} px")
    model.diagnostics["alignment"] = {
        "method": method, "reference": frames.sources[ref],
        "transforms": [np.round(t, 6).tolist() for t in transforms]}
    return model, transforms, ref, warnings


def _log_domain_basis(basis, n_components: int):
    """The response basis in the log domain of Eq. 7, and N capped at its size."""
    if basis is None:
        from .basis import builtin_basis

        basis = builtin_basis()
    elif is_path(basis):
        from .basis import load_basis_file

        basis = load_basis_file(basis)
    if basis.domain != "log":
        basis = basis.to_log_domain()
    return basis, int(min(n_components, basis.n_components))


def _sample_usable_frames(frames, sources, times, warnings, *, options: ResponseOptions, seed,
                          progress, ignored: list, keep_codes: bool):
    """Read the frames' samples and masks; choose the frames the solve can use.

    Dropped, with a warning each and in this order: frames clipped almost everywhere
    (said to be white or black when they are), duplicates (identical pixels, every pixel
    compared) among the frames that remain, and frames sharing fewer than
    :data:`MIN_SHARED_SAMPLES` unclipped samples with every other frame.  The clipped
    frames go first: two almost white frames of a long bracket can differ in a few dozen
    pixels only, and are no duplicates.

    Returns
    -------
    samples : SampleSet
        Of every frame.
    masks : dict of ndarray
        ``frame_masks`` of every frame.
    keep : list of int
        Indices of the usable frames (at least two).
    """
    def frame_progress(k, n, src):
        if progress is not None:
            progress("read", k, n, src)

    clip_margin = options.solver.clip_margin
    samples = collect_samples(frames, sources=sources, max_samples=options.max_samples,
                              clip_margin=clip_margin, seed=seed, progress=frame_progress,
                              keep=KeptData(reduced=options.correspondences != "blocks",
                                            codes_side=MEASURE_CODES_SIDE
                                            if keep_codes else 0),
                              near_clip_blocks=options.near_clip_blocks)
    masks = frame_masks(samples, clip_margin=clip_margin,
                        saturation_threshold=options.solver.saturation_threshold)
    keep = without_clipped_frames(samples, masks, sources, warnings, clip_margin, ignored)
    keep = without_duplicates([samples.digests[k] for k in keep], [times[k] for k in keep],
                              [sources[k] for k in keep], warnings, keep, ignored)
    # A frame that shares (almost) no unclipped samples with any other frame -- e.g. one
    # long exposure far beyond the rest of the bracket -- adds no usable equations: its few
    # pair rows sit at the clipping limits, and its exposure could be neither estimated nor
    # checked against the pixels.
    usable = ~(masks["clipped"] | masks["saturated"])
    for k in list(keep):
        shared = max((int((usable[k] & usable[j]).sum()) for j in keep if j != k), default=0)
        if shared < MIN_SHARED_SAMPLES and len(keep) > 2:
            record_ignored(sources[k], "unchecked", f"shares only {shared} unclipped samples "
                           "with any other frame (too far from the rest of the bracket)",
                           warnings, ignored)
            keep.remove(k)
    if len(keep) < 2:
        raise CalibrationError(
            "fewer than two usable frames remain (the others are duplicates, clipped "
            "everywhere or share no unclipped samples): " + "; ".join(warnings))
    return samples, masks, keep


def _histogram_solve(samples, usable: _Usable, keep, basis, first, options, progress):
    """The solve on histogram correspondences of every usable pixel, gated by a first fit
    (:func:`.histogram_samples.solve_data`), with the block samples too when
    ``options.correspondences == "histogram+blocks"``."""
    from .histogram_samples import solve_data

    grid, inverse = _inverse_response(basis, first.coefficients,
                                      options.solver.n_components)
    data, masks, weights = solve_data(
        samples, keep, (grid, inverse, first.log_exposures),
        clip_margin=options.solver.clip_margin,
        saturation_threshold=options.solver.saturation_threshold,
        blocks=((usable.samples, usable.masks)
                if options.correspondences == "histogram+blocks" else None))
    return functools.partial(_solve, replace(usable, samples=data, masks=masks), basis,
                             options=options, progress=progress, weights=weights)


def _solve(usable: _Usable, basis, *, options, refine_exposures, progress, weights=None):
    """Eq. 8 over the usable frames' samples (:func:`solve_exposure_equations`)."""
    if progress is not None:
        progress("solve", 0, 1, "")
    result = solve_exposure_equations(
        usable.samples, basis, usable.log_times, refine_exposures=refine_exposures,
        masks=usable.masks, options=options.solver, sample_weights=weights)
    if progress is not None:
        progress("solve", 1, 1, "")
    return result


def _contradicted_times(usable: _Usable, basis, options) -> list:
    """Given times the pixels contradict by more than
    :data:`selfcal.exposure.times.CONTRADICTION_FACTOR`.

    Re-solves with the times as a prior (``refine_exposures=True``, a short solve) and
    compares the estimated exposure ratios with the given ones.
    """
    log_times = usable.log_times
    known = np.isfinite(log_times)
    contradictions = []
    free = solve_exposure_equations(
        usable.samples, basis, log_times, refine_exposures=True, masks=usable.masks,
        options=replace(options.solver, max_iterations=4, monotone=False))
    # compare ratios, not absolute values: the prior only pins the overall scale
    dev = free.log_exposures - log_times
    dev = dev - np.nanmedian(dev[known])
    for j in np.flatnonzero(known):
        if abs(dev[j]) > math.log(CONTRADICTION_FACTOR):
            est = math.exp(log_times[j] + dev[j])
            contradictions.append({"frame": usable.sources[j], "given": usable.times[j],
                                   "estimated": est})
    return contradictions


def _inverse_response(basis, coefficients, n_components):
    """f⁻¹ on the basis grid from the Eq. 7 coefficients, made non-decreasing.

    Returns the grid and f⁻¹ as (grid size, 3).
    """
    return basis.intensity, basis.channel_inverses(coefficients, n_components)


def _btf_data(samples, masks, result, names):
    """Samples of one frame pair with their rejection reasons, for the BTF plot (Fig. 3)."""
    best = None
    for a, b in result.pair_frames:
        ratio = math.exp(result.log_exposures[b] - result.log_exposures[a])
        if ratio < 1.2:
            continue
        unclipped = ~(masks["clipped"][a] | masks["clipped"][b])
        score = unclipped.sum() / (1 + abs(math.log(ratio / 2.0)))
        if best is None or score > best[0]:
            best = (score, a, b, ratio)
    if best is None:
        return None
    _, a, b, ratio = best
    reason = np.zeros(samples.n_samples, dtype=np.int8)  # 0 used
    reason[masks["saturated"][a] | masks["saturated"][b]] = 2
    reason[masks["clipped"][a] | masks["clipped"][b]] = 1
    return {"frames": (names[a], names[b]), "ratio": ratio,
            "I": samples.values[a], "I2": samples.values[b], "reason": reason}
