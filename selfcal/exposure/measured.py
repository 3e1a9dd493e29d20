"""Exposures of a rendered (JPEG) bracket measured from its pixels, given the model's curve.

[Lin2011] §5 computes a raw bracket's exposure ratios "by dividing the raw values between
two images"; once a response model gives f⁻¹, a rendered bracket's frames are linear
values too, and the same ratios measure its exposures.  The times a camera writes are
nominal (1/60 s for 2⁻⁶ s, third-stop steps of 1.2-1.33×; ``python3 -m
bench.measured_exposures`` prints how far they are from the pixels), and a merge whose
weights lean on one frame per pixel carries that frame's exposure error whole.

What is done here is the linear path's measurement (:mod:`.linear`: split
thumbnails, :func:`selfcal.exposure.raw_ratios.raw_exposure_ratios` with the ``"sum"``
statistic, the absolute scale from the times by the median of ``log(time / measured)``)
on ``f⁻¹(codes)``.  Ours:

* **where**: a calibration measures its own frames once its curve is fitted, on codes it
  kept while reading them (every pixel of a :data:`MEASURE_CODES_SIDE` subsample, no
  frame read again: :func:`measure_calibration_exposures`), and its model's exposures are
  these; a merge of those frames takes the same numbers, and measures only frames the
  model has not seen, with a pre-pass (:func:`measure_response_exposures`) that reads
  each frame once: the :func:`code_subsample` (every ``s``-th pixel of every ``s``-th
  row, unaveraged, to a :data:`PREPASS_CODES_SIDE` long side) of an array, or of a file
  decoded with libjpeg's DCT scaling when large, down to :data:`PREPASS_MIN_SIDE` (its
  codes are block means, biased where the texture within a block is strong), in
  :data:`PREPASS_THREADS` threads; those codes are linearised, then area-averaged to
  the thumbnails.  Only these ~700,000 codes a frame are linearised (until issue 43 an
  array's 24 MP were: 89 % of a merge; frames up to PREPASS_CODES_SIDE a side are
  measured as before; docs/decisions.md, "Exposures measured from the pixels: one pass
  over subsampled codes");
* **pairs**: a pair counts when the frames share :data:`MIN_PAIR_OVERLAP` of a
  thumbnail's values (frames far apart share a few at the ends of both ranges);
* **the trend** over the bracket is the times' (``ExposureRule.trend``,
  :func:`_times_trend`): the pixels cannot see it -- ``f⁻¹ → (f⁻¹)^γ`` and ``e → e^γ``
  fit them equally, §4's exponential ambiguity -- and a curve whose slope is slightly off
  makes the measured ratios drift by a few per cent per stop; the line is Theil-Sen's,
  which one frame cannot pull;
* **the pixels decide where they can**: each frame's deviation from the trend is kept in
  proportion ``s² / (s² + m²)`` -- ``m`` the measurement's own scatter (the pairs'
  disagreement, :func:`.linear.fit_log_sigma`), ``s`` the shutter's beyond it -- so exact times
  stay as they are and jittered ones follow the pixels;
* **σ**: the exposure term of the merge's σ becomes the posterior spread of a frame's
  exposure, and the trend's own uncertainty (what the shutter's errors leave in the
  times' trend) a term of its own (:func:`selfcal.hdr.sigma.add_trend_term`);
* codes at or beyond the merge's clip limits (any channel at white excludes the pixel, a
  channel at or below its black floor excludes that channel) never enter a thumbnail.

Frames the pixels cannot place (no pair with enough shared well-exposed pixels, merged
unchecked) keep their time.  The constants and the choices are in docs/decisions.md,
"Exposures measured from the pixels: by default".
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import read_image
from ..stack.frames import Lineariser, apply_lut, frame_limits, max_code_of
from .linear import MEASURE_SIDE, MIN_LOG_SIGMA, fit_log_sigma, scale_to_times, \
    thumbnail_exposures
from .raw_ratios import split_thumbnails

__all__ = ["measure_response_exposures", "measure_calibration_exposures", "PREPASS_REDUCE", "PREPASS_MIN_SIDE",
           "PREPASS_THREADS", "PREPASS_CODES_SIDE", "PAIR_GAP", "TRENDS", "MEASURE_CODES_SIDE", "MIN_PAIR_OVERLAP"]

#: Files are decoded at 1/PREPASS_REDUCE (DCT scaling) for the measurement, less where
#: the decoded long side would fall below PREPASS_MIN_SIDE: block means of codes,
#: linearised, are biased where a block holds texture (``python3 -m
#: bench.measured_exposures``).  Chosen on the tuning stacks (docs/decisions.md,
#: "Exposures measured from the pixels: an option, with the times' trend").
PREPASS_REDUCE = 8
PREPASS_MIN_SIDE = 1500
#: Threads decoding the files of the pre-pass side by side (libjpeg releases the GIL);
#: the merge that follows reads ahead with one thread beside its own.
PREPASS_THREADS = 2
#: Long side of the codes a calibration keeps of each frame it reads, for the measurement
#: after its fit (:func:`measure_calibration_exposures`), and of the codes the merge's
#: pre-pass measures a frame on (:func:`code_subsample`): the thumbnails' two halves then
#: hold every kept pixel, unaveraged; 175,000 pixels a 3:2 frame, and on ntu's 24 MP
#: frames a quarter of the cost of twice this side (docs/decisions.md, "Exposures
#: measured from the pixels: by default").
MEASURE_CODES_SIDE = MEASURE_SIDE
#: Long side of the codes the merge's pre-pass linearises of a frame (a strided
#: subsample, :func:`code_subsample`), before their linear values are area-averaged to
#: the :data:`MEASURE_SIDE` thumbnails: twice it, so a frame of up to 1024 pixels a side
#: is measured on every pixel as before issue 43 (at 512, memorial's 768-pixel frames
#: moved by a median 0.033 in log, the pairs' scatter from 0.0037 to 0.0086).
PREPASS_CODES_SIDE = 2 * MEASURE_SIDE
#: Frames are paired with the next PAIR_GAP frames by exposure only (the pairs' cost grows
#: with the square of the frame count; far pairs share few well-exposed pixels).
PAIR_GAP = 3
#: The values of ``ExposureRule.trend``: what sets the measured exposures' trend
#: over the bracket, the pixels' ratios as they are or the times' (:func:`_times_trend`).
TRENDS = ("times", "pixels")
#: A pair of frames counts when it shares this fraction of a thumbnail's values
#: (:func:`_min_overlap`).
MIN_PAIR_OVERLAP = 0.01
#: Sentinel put on excluded values: above ``_CLIP_LEVEL`` they turn to NaN in a thumbnail.
_EXCLUDED = np.float32(4.0)
_CLIP_LEVEL = 2.0


def _prepass_reduce(frames, min_side: int = PREPASS_MIN_SIDE) -> int:
    """The DCT scale for the files' pre-pass (1 for arrays): the largest of
    :data:`PREPASS_REDUCE` and its halves that keeps the long side >= ``min_side``."""
    if frames.paths[0] is None:
        return 1
    side = max(frames.shape)
    r = PREPASS_REDUCE
    while r > 1 and side / r < min_side:
        r //= 2
    return r


def code_subsample(codes: np.ndarray, side: int = MEASURE_CODES_SIDE) -> np.ndarray:
    """Every ``s``-th code of every ``s``-th row, ``s`` the smallest stride bringing the
    long side to at most ``side``: no averaging (``f⁻¹`` of a mean of codes is not the
    mean of ``f⁻¹``).  The rule of the calibration's kept codes
    (``selfcal.stack.samples.KeptData.codes_side``), which keeps :data:`MEASURE_CODES_SIDE`;
    the merge's pre-pass keeps :data:`PREPASS_CODES_SIDE` (ours)."""
    stride = max(1, -(-max(codes.shape[:2]) // int(side)))
    return np.ascontiguousarray(codes[::stride, ::stride])


def _frame_codes(frames, k: int, reduce: int) -> np.ndarray:
    """The codes frame ``k`` is measured on: :func:`code_subsample` (to
    :data:`PREPASS_CODES_SIDE`) of the array, or of
    the file decoded at 1/``reduce`` by libjpeg's DCT scaling (each decoded code a block
    mean: :data:`PREPASS_MIN_SIDE` bounds the blocks' size)."""
    item = frames.items[k]
    img = read_image(item, reduce=reduce) if frames.paths[k] is not None else np.asarray(item)
    return code_subsample(img, PREPASS_CODES_SIDE)


def _linear_thumbnails(img, model, clip_margin: float, stuck):
    """Codes ``img`` linearised by ``model`` with its clipped codes excluded, as the split
    thumbnails of :func:`selfcal.exposure.raw_ratios.split_thumbnails` (linear values
    area-averaged to :data:`MEASURE_SIDE`; none when ``img`` is that small)."""
    mc = max_code_of(img)
    lin = Lineariser(model, False, mc)
    lo, hi, floor = frame_limits(mc, clip_margin, False, stuck)
    if lin.kind == "lut" and mc is not None:
        assert lin.table is not None        # made for the frame's max code
        # the tests below, per channel and code, made tables: a channel at or below its
        # black limit or floor looks up the sentinel, a pixel with one channel at or
        # beyond its white limit gets it in all three (one lookup each, no float compare)
        codes = np.arange(mc + 1)[:, None]
        dark = codes <= lo if floor is None else (codes <= lo) | (codes < floor)
        table = np.where(dark, _EXCLUDED, lin.table).astype(np.float32)
        h, width = img.shape[0], img.shape[1] - img.shape[1] % 2
        small = width >= 2 and max(h, width // 2) <= MEASURE_SIDE
        if small:
            # split_thumbnails' halves with nothing to average: the even and the odd
            # columns' codes stacked, looked up once (the same values, fewer copies)
            img = np.concatenate([img[:, 0:width:2], img[:, 1:width:2]])
        x = apply_lut(img, table)
        over = apply_lut(img, (codes >= hi).astype(np.float32))
        white = (over[..., 0] + over[..., 1] + over[..., 2]) > 0
        np.copyto(x, _EXCLUDED, where=white[..., None])
        if small:
            np.copyto(x, np.float32(np.nan), where=x >= _CLIP_LEVEL)
            return x, np.concatenate([x[h:], x[:h]])
    else:
        x = lin.values(img)
        white = np.any(img >= hi, axis=2, keepdims=True)
        dark = img <= lo if floor is None else (img <= lo) | (img < floor)
        x[np.broadcast_to(white, x.shape) | dark] = _EXCLUDED
    return split_thumbnails(x, max_side=MEASURE_SIDE, clip_level=_CLIP_LEVEL)


def _thumbnail(frames, k: int, model, clip_margin: float, stuck, reduce: int):
    """Frame ``k``'s split thumbnails for the measurement: :func:`_linear_thumbnails` of
    its :func:`_frame_codes`."""
    return _linear_thumbnails(_frame_codes(frames, k, reduce), model, clip_margin, stuck)


def _trend_residuals(rel, times):
    """``(residuals, mask, Sxx)`` of ``log e = a + b log t + r`` over the measured frames
    (three at least; None otherwise), the line by Theil-Sen (Sen 1968: the median of the
    pairwise slopes, so one frame cannot pull it; ours to use it here)."""
    from scipy.stats import theilslopes

    rel = np.asarray(rel, dtype=float)
    ok = np.isfinite(rel)
    if ok.sum() < 3:
        return None
    x = np.log(np.asarray(times, dtype=float)[ok])
    y = np.log(rel[ok])
    b, a = theilslopes(y, x)[:2]
    r = y - (a + b * x)
    return r - np.median(r), ok, float(np.sum((x - x.mean()) ** 2))


def _times_trend(rel, times, measurement_sigma: float):
    """The measured exposures with their trend over the bracket set by the times (ours).

    ``log e = a + b log t + r`` is fitted robustly (:func:`_trend_residuals`); the times
    keep the trend (a curve whose slope is slightly off turns into a trend of the
    measured ratios, not into a shutter error) and the pixels give each frame's deviation
    ``r``, shrunk towards the time by ``k = s² / (s² + m²)``: ``m`` the measurement's own
    scatter (``measurement_sigma``, :func:`.linear.fit_log_sigma`), ``s²`` the shutter's, the
    deviations' variance beyond ``m²`` (an empirical-Bayes estimate; 0 when the deviations
    are no larger than the measurement's scatter, and then the times are kept).  That is
    how the pixels decide only where they can.

    Returns
    -------
    (numpy.ndarray, dict)
        The exposures (relative, unscaled) and ``shutter_log_sigma`` (``s``),
        ``log_sigma`` (the posterior standard deviation of a frame's log exposure,
        ``s m / √(s² + m²)``), ``trend_log_sigma`` (the standard deviation of the times'
        trend, the slope ``b``: ``s / √Σ(x − x̄)²``, what the shutter's errors leave in the
        trend the times set) and ``shrink`` (``k``).
    """
    rel = np.asarray(rel, dtype=float)
    fit = _trend_residuals(rel, times)
    m = float(measurement_sigma)
    if fit is None:
        return rel, {"shutter_log_sigma": None, "log_sigma": m, "trend_log_sigma": 0.0,
                     "shrink": 1.0}
    r, ok, sxx = fit
    n = int(ok.sum())
    s2 = max(0.0, float(np.sum(r ** 2)) / max(n - 2, 1) - m * m)
    k = s2 / (s2 + m * m) if s2 + m * m > 0 else 0.0
    out = rel.copy()
    out[ok] = np.asarray(times, dtype=float)[ok] * np.exp(k * r)
    posterior = math.sqrt(s2 * m * m / (s2 + m * m)) if s2 + m * m > 0 else 0.0
    return out, {"shutter_log_sigma": math.sqrt(s2), "log_sigma": max(MIN_LOG_SIGMA, posterior),
                 "trend_log_sigma": math.sqrt(s2 / sxx) if sxx > 0 else 0.0, "shrink": k}


def _min_overlap(thumbs) -> int:
    """Fewest shared well-exposed values a pair of thumbnails needs to count:
    :data:`MIN_PAIR_OVERLAP` of a thumbnail's values, at least 100 (frames far apart
    share a few values at the ends of both their ranges, where the curve is least sure)."""
    size = thumbs[0][0].size if thumbs else 0
    return max(100, int(MIN_PAIR_OVERLAP * size))


def measure_response_exposures(frames, model, exposures, frame_set, *, clip_margin: float,
                               stuck=None, reduce: int | None = None, trend: str = "times",
                               progress=None, names=None):
    """The frames' exposures with their ratios measured from the pixels through ``model``.

    [Lin2011] §5's ratios of linear values, on ``f⁻¹`` of each frame's
    :func:`code_subsample` (of the file decoded at 1/``reduce``) area-averaged to the
    frames' split
    thumbnails (:func:`selfcal.exposure.raw_ratios.split_thumbnails`) compared pair by
    pair (:func:`.linear.thumbnail_exposures`); what is ours is in the module docstring.

    Parameters
    ----------
    frames : selfcal.stack.frames.StackFrames
        Rendered frames (arrays or files) of one scene.
    model : object
        The merge's model (``inverse_response`` or ``to_raw``).
    exposures : numpy.ndarray
        The exposures the merge would use (given, EXIF or the model's): they set the
        scale, and stay for the frames the pixels cannot place.
    frame_set : sequence of int
        The frames to measure (the merged, checked ones).
    clip_margin : float
    stuck : (floor, ceiling) or None
        Per-channel normalised codes that do not move with exposure (excluded).
    reduce : {1, 2, 4, 8}, optional
        The files' DCT scale; default :data:`PREPASS_REDUCE`, less for small frames.
    trend : {"times", "pixels"}
        What sets the exposures' trend over the bracket: the times' (:func:`_times_trend`,
        default) or the measured ratios as they are.
    progress : callable, optional
        ``progress("exposures", done, total, source)``.
    names : sequence of str, optional
        The frames' names in the summary (default ``frames.sources``).

    Returns
    -------
    (numpy.ndarray, dict)
        The exposures to merge with, and a JSON-ready summary (``measured`` relative
        exposures, ``differences`` ``time / measured − 1`` per frame, ``log_sigma`` of
        :func:`.linear.fit_log_sigma`, the pre-pass ``reduce``).
    """
    if trend not in TRENDS:
        raise InputError(f"trend must be one of {', '.join(TRENDS)}, not {trend!r}")
    reduce = _prepass_reduce(frames) if reduce is None else int(reduce)
    frame_set = list(frame_set)

    def thumbnail(k):
        return _thumbnail(frames, k, model, clip_margin, stuck, reduce)

    made = {}
    # files: decoded in PREPASS_THREADS threads (libjpeg releases the GIL); a model's own
    # to_raw is called from this thread only.  Each frame's result is its own: the same
    # whatever the threads' timing.
    files = (any(p is not None for p in frames.paths) and hasattr(model, "inverse_response")
             and len(frame_set) > 1)
    pool = ThreadPoolExecutor(max_workers=PREPASS_THREADS) if files else None
    try:
        for q, (k, thumbs) in enumerate(zip(frame_set, map(thumbnail, frame_set) if pool is None
                                            else pool.map(thumbnail, frame_set))):
            made[k] = thumbs
            if progress is not None:
                progress("exposures", q + 1, len(frame_set), frames.sources[k])
    finally:
        if pool is not None:
            pool.shutdown()
    return _measured_from_thumbnails(made, frames, exposures, trend=trend, reduce=reduce,
                                     names=names)


def _measured_from_thumbnails(made: dict, frames, exposures, *, trend: str, reduce: int,
                              names=None):
    """:func:`measure_response_exposures` from the frames' split thumbnails (``made``,
    frame index -> ``(values, selection)``)."""
    # by exposure, frames of one exposure by their content: the pairs, and so the
    # result, do not depend on the order the frames came in
    # (the content's sum only where two frames share an exposure: the same order)
    levels = [float(exposures[k]) for k in made]
    shared = {e for e in levels if levels.count(e) > 1}
    frame_set = sorted(made, key=lambda k: (
        float(exposures[k]), float(np.nansum(made[k][0], dtype=np.float64))
        if float(exposures[k]) in shared else 0.0, k))
    thumbs = [made[k] for k in frame_set]
    rel, pairs = thumbnail_exposures(thumbs, max_gap=PAIR_GAP, min_count=_min_overlap(thumbs))
    times = [float(exposures[k]) for k in frame_set]
    scatter = fit_log_sigma(rel, pairs)
    if trend == "times":
        rel, fit = _times_trend(rel, times, scatter)
    else:
        fit = {"shutter_log_sigma": None, "log_sigma": scatter, "trend_log_sigma": 0.0,
               "shrink": 1.0}
    scale = scale_to_times(rel, times)
    out = np.array(exposures, dtype=float)
    n = len(frames)
    measured: list[float | None] = [None] * n
    differences: list[float | None] = [None] * n
    if scale is not None:
        for q, k in enumerate(frame_set):
            if math.isfinite(rel[q]):
                measured[k] = float(rel[q])
                out[k] = rel[q] * scale
                differences[k] = float(times[q] / out[k] - 1.0)
    summary = {"measured": measured, "differences": differences,
               "measurement_log_sigma": scatter, **fit, "reduce": reduce, "trend": trend,
               "frames": [Path(s).name for s in (frames.sources if names is None else names)]}
    return out, summary


def measure_calibration_exposures(model, codes, keep, sources, *, times, solved, refined: bool,
                                  clip_margin: float, stuck=None):
    """The exposures of a calibration's own frames measured through its fitted curve.

    :func:`measure_response_exposures` on ``codes``, the frames' codes the calibration
    kept while it read them (``selfcal.stack.samples.collect_samples(keep_codes=...)``):
    no frame is read again.  The given ``times`` (seconds, None where unknown) set the
    scale and the trend where known, the ``solved`` exposures where not -- and everywhere
    when the solve ``refined`` them (the curve was fitted with their trend).

    Returns
    -------
    (numpy.ndarray, dict)
        The exposures (NaN for frames outside ``keep``), in the times' units, and the
        summary of :func:`measure_response_exposures`.
    """
    from ..stack.frames import StackFrames

    solved = np.asarray(solved, dtype=float)
    # refined exposures carry the trend the curve was fitted with: they anchor it then
    anchor = np.array([t if t is not None and not refined else e
                       for t, e in zip(times, solved)], dtype=float)
    anchor = np.where(np.isfinite(anchor) & (anchor > 0), anchor, 1.0)
    out, summary = measure_response_exposures(
        StackFrames(codes, linear=False), model, anchor, list(keep), clip_margin=clip_margin,
        stuck=stuck, reduce=1, names=sources)
    measured = np.full(len(codes), np.nan)
    measured[list(keep)] = out[list(keep)]
    return measured, summary
