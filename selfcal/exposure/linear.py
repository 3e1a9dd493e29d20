"""Exposures of a linear bracket measured from its pixels: raw files, linear TIFFs.

Lin, Kim, Süsstrunk & Brown, ICCV 2011 [Lin2011], §5: "with RAW images, the exposure
ratio can be directly computed by dividing the raw values between two images".  Linear data
have the identity for a response, so a bracket of raws (or of a raw converter's linear
16-bit TIFFs) needs no calibration: the ratios of the frames' values at pixels well exposed
in both are the exposure ratios (:func:`selfcal.exposure.raw_ratios.raw_exposure_ratios`), free of the
shutter's error, and the frames merge to HDR directly (:func:`selfcal.merge_hdr` with
``linear=True``).

What is ours: how measured ratios and the times (EXIF or the caller's) are combined.  The
ratios set the exposures; the times set only their absolute scale, by the median over the
frames of ``log(time / measured)`` -- so one wrong time cannot move the others (anchored
on one frame, its wrong time would move them all).  Times the caller gives are kept as
they are (``use="auto"``), and a
difference from the pixels is reported, as on the response path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CalibrationError
from ..io.images import is_path
from ..stack.frames import DEFAULT_CLIP_MARGIN, StackFrames
from .linear_evidence import linear_evidence
from .record import GivenTimes
from .raw_ratios import raw_exposure_ratios, split_thumbnails

__all__ = ["LinearExposures", "measure_linear_exposures",
           "linear_tiff_evidence", "stack_frames", "MEASURE_SIDE",
           "fit_log_sigma", "MIN_LOG_SIGMA"]

#: Long side (pixels) of the area-averaged thumbnails the ratios are measured on.
MEASURE_SIDE = 512
#: Floor of the measurement's scatter and of the exposure term of σ (:func:`fit_log_sigma`).
MIN_LOG_SIGMA = 0.002


@dataclass
class LinearExposures:
    """The exposures of a linear bracket and what they rest on.

    Attributes
    ----------
    exposures : ndarray, shape (F,)
        The exposure of each frame used for the merge: in the units of the times where any
        are known, else relative to the first measured frame.
    measured : ndarray, shape (F,)
        The pixels' relative exposures (first measured frame = 1); NaN for a frame sharing
        too few well-exposed pixels with the others.
    times : list of float or None
        The times given (the caller's or EXIF ``t · ISO/100 / N²``), None where unknown.
    from_pixels : bool
        :attr:`exposures` are the pixels' ratios (False: the times as they are).
    on_times_scale : bool
        They are on the times' scale (False: no time known, relative to the first
        measured frame).
    differences : list of float or None
        Per frame, ``time / (measured × scale) − 1``: how far the time is from the pixels.
    pairs : list of tuple
        ``(i, j, ratio, count)`` of every frame pair measured.
    """

    exposures: np.ndarray
    measured: np.ndarray
    times: list
    from_pixels: bool
    on_times_scale: bool
    differences: list = field(default_factory=list)
    pairs: list = field(default_factory=list)

    def largest_difference(self):
        """``(relative difference, frame index)`` of the time furthest from the pixels, or
        None when no time was compared."""
        known = [(abs(d), k) for k, d in enumerate(self.differences) if d is not None]
        return max(known) if known else None



def _thumbnail(frames, k: int, clip_margin: float) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``k`` of a :class:`selfcal.stack.frames.StackFrames` on [0, 1] (white = 1), as the two
    half-frame thumbnails of :func:`selfcal.exposure.raw_ratios.split_thumbnails` (values, selection)."""
    if frames.raw_files[k]:
        from ..io.raw import read_raw_linear

        rgb = read_raw_linear(frames.items[k], half_size=True).rgb
        white = 1.0
    else:
        rgb = frames.load(k)
        white = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(rgb.dtype, 1.0)
    rgb = np.asarray(rgb, dtype=np.float32) / np.float32(white)
    clip_level = 1.0 - (clip_margin / 255.0 if white > 1.0 else 1e-4)
    return split_thumbnails(rgb, max_side=MEASURE_SIDE, clip_level=clip_level)


def scale_to_times(measured: np.ndarray, times: list) -> float | None:
    """The factor putting the measured exposures in the times' units: the median over the
    frames with both of ``log(time / measured)`` (None without such a frame)."""
    logs = [math.log(t / m) for t, m in zip(times, measured)
            if t is not None and math.isfinite(m)]
    return math.exp(float(np.median(logs))) if logs else None


def thumbnail_exposures(thumbs, max_gap: int | None = None, min_count: int = 100):
    """Relative exposures (first measured frame = 1, NaN outside the largest connected set
    of frames) and the measured pairs, from the frames' split thumbnails
    (:func:`selfcal.exposure.raw_ratios.split_thumbnails`: ``(values, selection)``), by
    :func:`selfcal.exposure.raw_ratios.raw_exposure_ratios` with the ``"sum"`` statistic.
    Shared by the linear path and the response path (:mod:`.measured`, which
    passes ``max_gap`` and a ``min_count`` relative to the thumbnails' size)."""
    rel, report = raw_exposure_ratios([v for v, _ in thumbs], select=[c for _, c in thumbs],
                                      statistic="sum", max_side=2 * MEASURE_SIDE,
                                      max_gap=max_gap, min_count=min_count)
    # one connected set of frames is needed for one scale
    components = [c for c in report["component"] if c >= 0]
    main = max(set(components), key=components.count) if components else None
    measured = np.array([e if c == main else np.nan
                         for e, c in zip(rel, report["component"])], dtype=float)
    if np.isfinite(measured).any():
        measured /= measured[np.isfinite(measured)][0]
    return measured, report["pairs"]


def fit_log_sigma(measured, pairs) -> float:
    """The measurement's own scatter (ours): the count-weighted RMS, over the measured
    pairs, of ``log(ratio) − log(e_j / e_i)`` -- how far the pairs disagree with the
    exposures fitted to them all -- floored at :data:`MIN_LOG_SIGMA` (a bracket of two
    frames, or one whose pairs form a chain, has no redundancy to show)."""
    num = den = 0.0
    for i, j, ratio, count in pairs:
        if math.isfinite(measured[i]) and math.isfinite(measured[j]):
            r = math.log(ratio) - math.log(measured[j] / measured[i])
            num += count * r * r
            den += count
    return max(MIN_LOG_SIGMA, math.sqrt(num / den) if den else 0.0)


def measure_linear_exposures(frames, times, *, hold: bool = False,
                             clip_margin: float = DEFAULT_CLIP_MARGIN,
                             progress=None) -> LinearExposures:
    """Relative exposures of a linear bracket from its pixels, combined with its times.

    Parameters
    ----------
    frames : selfcal.stack.frames.StackFrames
        Linear frames of one scene (raw files, linear TIFFs, or arrays).
    times : list of float or None
        Per frame, the exposure time given or read from EXIF (None where unknown).
    hold : bool
        The times as they are (an error where one is unknown), the rule's ``"held"``
        (:class:`selfcal.exposure.ExposureRule`); default the measured ratios on the
        times' scale.
    clip_margin : float
        Values within this distance of white (8-bit scale) count as clipped.
    progress : callable, optional
        ``progress("exposures", done, total, source)``.

    Returns
    -------
    LinearExposures

    Raises
    ------
    CalibrationError
        A frame whose exposure neither the pixels nor a time give (named).
    """
    n = len(frames)
    thumbs = []
    for k in range(n):
        thumbs.append(_thumbnail(frames, k, clip_margin))
        if progress is not None:
            progress("exposures", k + 1, n, frames.sources[k])
    measured, pairs = thumbnail_exposures(thumbs)
    scale = scale_to_times(measured, times)
    differences = [None if t is None or not math.isfinite(m) or scale is None
                   else float(t / (m * scale) - 1.0) for t, m in zip(times, measured)]
    if hold:
        exposures = list(times)
    else:
        exposures = [m * (scale or 1.0) if math.isfinite(m) else
                     (t if scale is not None else None) for m, t in zip(measured, times)]
    missing = [frames.sources[k] for k, e in enumerate(exposures) if e is None]
    if missing:
        why = ("has no exposure time" if hold else
               "shares too few well-exposed pixels with the other frames to measure its "
               "exposure, and has no exposure time")
        raise CalibrationError(
            f"{missing[0]}: {why} (give exposure times)"
            + (f"; {len(missing) - 1} more frames too" if len(missing) > 1 else ""))
    return LinearExposures(np.asarray(exposures, dtype=float), measured, list(times),
                           from_pixels=not hold, on_times_scale=hold or scale is not None,
                           differences=differences, pairs=pairs)


def linear_tiff_evidence(images, given: GivenTimes) -> str | None:
    """Why ``images`` -- every one a TIFF path -- are linear data rather than rendered
    frames (:func:`selfcal.exposure.linear_evidence.linear_evidence`), or None.

    The ``given`` times (:func:`selfcal.exposure.read_given_times`) make the test decisive:
    linear ratios follow them to the power 1.
    """
    if not images or not all(is_path(p) and Path(p).suffix.lower() in (".tif", ".tiff")
                             for p in images):
        return None
    return linear_evidence([Path(p) for p in images], list(given.seconds))


def stack_frames(images, given: GivenTimes, model, linear: bool, warnings: list,
                 diagnostics: dict) -> StackFrames:
    """The stack's frames for :func:`selfcal.merge_hdr`, linear when the caller says so,
    for raw files, and for TIFFs that show linear data (:func:`linear_tiff_evidence`;
    said in ``warnings`` and ``diagnostics["linear_evidence"]``) -- which would otherwise
    be calibrated as rendered frames, with a bent curve and wrong ratios."""
    why = None if linear or model is not None else linear_tiff_evidence(images, given)
    if why:
        names = ", ".join(Path(p).name for p in images[:4]) + (", …" if len(images) > 4
                                                               else "")
        warnings.append(f"{names} are linear data ({why}): merged as they are, no "
                        "response fitted (give a model or their times if they are "
                        "rendered frames after all)")
        diagnostics["linear_evidence"] = why
    return StackFrames(images, linear or bool(why))

