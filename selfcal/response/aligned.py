"""Align, then calibrate: the response of a handheld stack, from its frames aligned first.

Misaligned frames give wrong correspondences, and the solve of Lin, Kim, Süsstrunk & Brown
(*Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011, §5, Eq. 8)
then reads them as contradicted exposure times.  So the frames are aligned to the
reference frame first (:func:`selfcal.align.estimate_alignment`: Ward's median threshold
bitmaps, or an ECC homography) and the response is calibrated on the aligned frames.

Ours, not the paper's: with unknown times, a provisional calibration on the unaligned
frames supplies the exposures the homography needs; the aligned frames are downscaled to
a 2048-pixel long side (:func:`_aligned_working_frames`), since the calibration samples
block means only; the model's sources and messages name the original frames.

The calibration itself (:func:`selfcal.calibrate_response` and its reading of exposure
times) is passed in by the caller: ``calibrate_response(..., align=...)`` calls this
module, so this module does not import it back.
"""

from __future__ import annotations

import numpy as np

from ..align import (
    _negligible,
    _rescale_homography,
    _working_reduce,
    estimate_alignment,
    warp_to_reference,
)
from ..errors import InputError
from ..frames import (
    DEFAULT_CLIP_MARGIN,
    _default_reference,
    _Frames,
    _given_exposures,
    _name_arrays,
    _resolve_exposures,
)
from ..io import _cv2

__all__ = ["calibrate_aligned"]


def calibrate_aligned(images, exposure_times=None, *, calibrate, resolve_times,
                      method="mtb", reference=None, clip_margin: float = DEFAULT_CLIP_MARGIN,
                      warnings: list | None = None, progress=None, max_side: int = 2048,
                      **options):
    """Align a handheld stack to its reference frame, then calibrate its response.

    Misaligned frames give wrong correspondences, and the solve of Lin et al. (ICCV 2011,
    Eq. 8) then reads them as contradicted exposure times; so the frames are aligned first
    (:func:`selfcal.align.estimate_alignment`; with unknown times, after a provisional
    calibration that supplies the exposures the homography needs) and the response is
    calibrated on the aligned frames, downscaled to ``max_side``
    (:func:`_aligned_working_frames`: the calibration uses block means only).  Both the
    calibration and the reading of the frames' times come from the caller (``calibrate``,
    ``resolve_times``), so that the response path can offer ``align=`` without a circle.

    Parameters
    ----------
    images : sequence
        Frames (arrays or paths).
    exposure_times : sequence of float or None, optional
        As for :func:`selfcal.calibrate_response`.
    calibrate : callable
        The calibration of unaligned frames, :func:`selfcal.calibrate_response`:
        ``calibrate(images, exposure_times, progress=..., **options) -> ResponseModel``.
    resolve_times : callable
        The frames' own times, :func:`selfcal.response.calibrate.resolve_exposure_times`:
        ``resolve_times(images, exposure_times, sources) -> (times, source)``.
    method : {"mtb", "homography"}
        Alignment (see :func:`selfcal.align.estimate_alignment`).
    reference : int, optional
        Reference frame; default the middle exposure.
    options
        Passed on to ``calibrate``.

    Returns
    -------
    model : ResponseModel
        Its ``sources`` are the original frames'; ``diagnostics["calibrated_on"]`` says
        what it was calibrated on, ``diagnostics["alignment"]`` holds the transforms.
    transforms : list of numpy.ndarray
        Per frame, the 3×3 map from reference to frame pixel coordinates.
    reference : int
    """
    frames = images if isinstance(images, _Frames) else _Frames(images, False)
    n = len(frames)
    warnings = [] if warnings is None else warnings
    given, _ = _given_exposures(frames, exposure_times)
    provisional = None
    if any(g is None for g in given):
        provisional = calibrate(frames.items, exposure_times, progress=progress, **options)
        given = list(_resolve_exposures(frames, exposure_times, provisional, True, [])[0])
    ref = _default_reference(given) if reference is None else int(reference)
    if not 0 <= ref < n:
        raise InputError(f"reference frame {reference} is out of range (0..{n - 1})")
    transforms = estimate_alignment(frames, given, provisional, method=method, reference=ref,
                                    clip_margin=clip_margin, warnings=warnings,
                                    progress=progress)
    small = _aligned_working_frames(frames, transforms, max_side=max_side)
    # the solve gets the frames' own times (seconds, None where unknown), as unaligned
    times, time_source = resolve_times(frames.items, exposure_times, list(frames.sources))
    options.setdefault("clip_margin", clip_margin)
    model = calibrate(small, times, progress=progress, **options)
    model.diagnostics["exposure_source"] = time_source
    model.sources = list(frames.sources)
    diag = model.diagnostics
    diag["warnings"] = [_name_arrays(w, frames.sources) for w in diag.get("warnings", [])]
    diag["frames_used"] = [_name_arrays(f, frames.sources)
                           for f in diag.get("frames_used", [])]
    diag["per_pair_rms_log"] = {_name_arrays(k, frames.sources): v
                                for k, v in diag.get("per_pair_rms_log", {}).items()}
    for c in diag.get("contradicting_times", []) or []:
        c["frame"] = _name_arrays(str(c.get("frame")), frames.sources)
    model.diagnostics["calibrated_on"] = (f"frames aligned ({method}), long side "
                                          f"{max(small[0].shape[:2])} px")
    model.diagnostics["alignment"] = {
        "method": method, "reference": frames.sources[ref],
        "transforms": [np.round(t, 6).tolist() for t in transforms]}
    return model, transforms, ref


def _aligned_working_frames(frames: _Frames, transforms, max_side: int = 2048) -> list:
    """The frames warped onto the reference, downscaled to ``max_side`` (for calibration).

    Calibration samples block means on a coarse grid, so a reduced copy loses little, and
    17 frames of 24 MP then take about 80 MB instead of 1.2 GB.
    """
    cv2 = _cv2()
    full_h, full_w = frames.shape
    s0 = min(1.0, max_side / max(full_h, full_w))
    size = (max(8, round(full_w * s0)), max(8, round(full_h * s0)))
    sx, sy = size[0] / full_w, size[1] / full_h
    reduce = _working_reduce(frames, max_side)
    out = []
    for k in range(len(frames)):
        img = frames.load(k, reduce=reduce)
        if (img.shape[1], img.shape[0]) != size:
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        t = _rescale_homography(transforms[k], sx, sy)
        if not _negligible(t, img.shape[:2]):
            img = warp_to_reference(img, t)
        out.append(img)
    return out
