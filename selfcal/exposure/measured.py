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
on ``f⁻¹(codes)``.  Ours: the trend of the measured exposures over the bracket is the
times' (``MergeOptions.exposure_trend``, :func:`_times_trend`) -- a calibrated curve whose slope is slightly
off makes the measured ratios drift by a few per cent per stop, which a shutter does not
(docs/decisions.md, "Exposures measured from the pixels: an option, with the times' trend");
codes at or beyond the merge's clip limits (any channel at white excludes the pixel, a
channel at or below its black floor excludes that channel) never enter a thumbnail;
arrays are linearised at full size and then area-averaged (unbiased); files are decoded
with libjpeg's DCT scaling when large (:func:`selfcal.io.read_image` ``reduce``, down to
:data:`PREPASS_MIN_SIDE`: a pre-pass cheaper than the full decode, whose block means of
*codes* are then linearised, biased where the texture within a block is strong --
``python3 -m bench.measured_exposures``); the exposure term of the merge's σ
becomes the pair residual of the measurement (:func:`fit_log_sigma`).  Frames the pixels
cannot place (no shared well-exposed pixels, merged unchecked) keep their time.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import read_image
from ..stack.frames import Lineariser, apply_lut, frame_limits, max_code_of
from .linear import MEASURE_SIDE, REPORT_DIFFERENCE, scale_to_times, \
    thumbnail_exposures
from .raw_ratios import split_thumbnails

__all__ = ["measure_response_exposures", "fit_log_sigma", "PREPASS_REDUCE", "PREPASS_MIN_SIDE",
           "PAIR_GAP", "MIN_LOG_SIGMA", "TRENDS"]

#: Files are decoded at 1/PREPASS_REDUCE (DCT scaling) for the measurement, less where
#: the decoded long side would fall below PREPASS_MIN_SIDE: block means of codes,
#: linearised, are biased where a block holds texture (``python3 -m
#: bench.measured_exposures``).  Chosen on the tuning stacks (docs/decisions.md,
#: "Exposures measured from the pixels: an option, with the times' trend").
PREPASS_REDUCE = 8
PREPASS_MIN_SIDE = 1500
#: Frames are paired with the next PAIR_GAP frames by exposure only (the pairs' cost grows
#: with the square of the frame count; far pairs share few well-exposed pixels).
PAIR_GAP = 3
#: The values of ``MergeOptions.exposure_trend``: what sets the measured exposures' trend
#: over the bracket, the pixels' ratios as they are or the times' (:func:`_times_trend`).
TRENDS = ("times", "pixels")
#: Floor of the exposure term of σ when the exposures are measured (:func:`fit_log_sigma`).
MIN_LOG_SIGMA = 0.005
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


def _thumbnail(frames, k: int, model, clip_margin: float, stuck, reduce: int):
    """Frame ``k`` linearised by ``model`` with its clipped codes excluded, as the split
    thumbnails of :func:`selfcal.exposure.raw_ratios.split_thumbnails`."""
    item = frames.items[k]
    img = read_image(item, reduce=reduce) if frames.paths[k] is not None else np.asarray(item)
    mc = max_code_of(img)
    lin = Lineariser(model, False, mc)
    lo, hi, floor = frame_limits(mc, clip_margin, False, stuck)
    if lin.kind == "lut":
        assert lin.table is not None        # made for the frame's max code
        x = apply_lut(img, lin.table.astype(np.float32))
    else:
        x = lin.values(img)
    white = np.any(img >= hi, axis=2, keepdims=True)
    dark = img <= lo if floor is None else (img <= lo) | (img < floor)
    x[np.broadcast_to(white, x.shape) | dark] = _EXCLUDED
    return split_thumbnails(x, max_side=MEASURE_SIDE, clip_level=_CLIP_LEVEL)


def _times_trend(rel, times):
    """The measured exposures with their trend against the times replaced by the times'
    (ours): ``log e = a + b log t + r`` fitted by least squares over the measured frames
    (three at least), and ``t · exp(r)`` kept -- the pixels' deviations frame by frame,
    the times' ratio over the whole bracket (a curve whose slope is off turns into a
    trend of the measured ratios, not into a shutter error)."""
    rel = np.asarray(rel, dtype=float)
    ok = np.isfinite(rel)
    if ok.sum() < 3:
        return rel
    x = np.log(np.asarray(times, dtype=float)[ok])
    y = np.log(rel[ok])
    b, a = np.polyfit(x, y, 1)
    out = rel.copy()
    out[ok] = np.exp(x + (y - (a + b * x)))
    return out


def fit_log_sigma(measured, pairs) -> float:
    """The exposure term of σ for measured exposures (ours): the count-weighted RMS, over
    the measured pairs, of ``log(ratio) − log(e_j / e_i)`` -- how far the pairs disagree
    with the exposures fitted to them all -- floored at :data:`MIN_LOG_SIGMA` (a bracket
    of two frames, or one whose pairs form a chain, has no redundancy to show)."""
    num = den = 0.0
    for i, j, ratio, count in pairs:
        if math.isfinite(measured[i]) and math.isfinite(measured[j]):
            r = math.log(ratio) - math.log(measured[j] / measured[i])
            num += count * r * r
            den += count
    return max(MIN_LOG_SIGMA, math.sqrt(num / den) if den else 0.0)


def measure_response_exposures(frames, model, exposures, frame_set, *, clip_margin: float,
                               stuck=None, reduce: int | None = None, trend: str = "times",
                               progress=None):
    """The frames' exposures with their ratios measured from the pixels through ``model``.

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

    Returns
    -------
    (numpy.ndarray, dict)
        The exposures to merge with, and a JSON-ready summary (``measured`` relative
        exposures, ``differences`` ``time / measured − 1`` per frame, ``log_sigma`` of
        :func:`fit_log_sigma`, the pre-pass ``reduce``).
    """
    frame_set = sorted(frame_set, key=lambda k: (float(exposures[k]), k))
    reduce = _prepass_reduce(frames) if reduce is None else int(reduce)
    thumbs = []
    for q, k in enumerate(frame_set):
        thumbs.append(_thumbnail(frames, k, model, clip_margin, stuck, reduce))
        if progress is not None:
            progress("exposures", q + 1, len(frame_set), frames.sources[k])
    rel, pairs = thumbnail_exposures(thumbs, max_gap=PAIR_GAP)
    times = [float(exposures[k]) for k in frame_set]
    log_sigma = fit_log_sigma(rel, pairs)
    if trend not in TRENDS:
        raise InputError(f"trend must be one of {', '.join(TRENDS)}, not {trend!r}")
    if trend == "times":
        rel = _times_trend(rel, times)
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
               "log_sigma": log_sigma, "reduce": reduce, "trend": trend,
               "frames": [Path(s).name for s in frames.sources]}
    return out, summary


def measured_warning(summary: dict, label: str) -> str | None:
    """The warning saying which times the pixels moved and by how much (as the linear
    path's), or None when none moved by more than :data:`.linear.REPORT_DIFFERENCE`."""
    moved = [(abs(d), k) for k, d in enumerate(summary["differences"])
             if d is not None and abs(d) > REPORT_DIFFERENCE]
    if not moved:
        return None
    worst, k = max(moved)
    return (f"using the exposure ratios measured from the pixels instead of the {label}: "
            f"{len(moved)} frame(s) differ by more than {100 * REPORT_DIFFERENCE:.0f}%, "
            f"up to {100 * worst:.1f}% at {summary['frames'][k]}")
