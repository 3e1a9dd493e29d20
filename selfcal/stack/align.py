"""Aligning the frames of a handheld stack to its reference frame.

Below both paths: the response calibration aligns a handheld stack before it samples it
(:func:`selfcal.response.calibrate.calibrate_aligned`), and the merge aligns before it accumulates
(:func:`selfcal.merge_hdr`).  Two methods, each on OpenCV:

* ``"mtb"``: an integer translation by median threshold bitmaps (Ward, *Fast, Robust
  Image Registration for Compositing High Dynamic Range Photographs from Hand-Held
  Exposures*, JGT 8(2), 2003; ``cv2.AlignMTB``), exposure-invariant because the bitmap
  splits each frame at its own median;
* ``"homography"``: that translation refined to a homography by maximising the enhanced
  correlation coefficient (Evangelidis & Psarakis, *Parametric Image Alignment Using
  Enhanced Correlation Coefficient Maximization*, TPAMI 30(10), 2008;
  ``cv2.findTransformECC``), coarse to fine, with ORB features (Rublee et al., ICCV 2011)
  and RANSAC as the fallback.

Ours, not the papers': ECC runs on ``log(f⁻¹(I)/e)`` clamped to the radiance range both
frames measure unclipped, so two exposures look alike (a response model is an argument;
without one, a gamma-2.2 stand-in); the frames are histogram-equalised before MTB and a
shift is kept only when it lowers the bitmaps' disagreement; a homography is accepted only
when its correlation is at least 0.5 and no corner moves by more than a tenth of the
diagonal; transforms that move no corner by more than a quarter pixel are not applied.

A transform is the 3×3 map from reference pixel coordinates to the frame's;
:func:`warp_to_reference` resamples a frame onto the reference grid with it.

References
----------
.. [Ward2003] G. Ward, "Fast, Robust Image Registration for Compositing High Dynamic Range
   Photographs from Hand-Held Exposures", Journal of Graphics Tools 8(2), 2003.
.. [Evangelidis2008] G. D. Evangelidis and E. Z. Psarakis, "Parametric Image Alignment
   Using Enhanced Correlation Coefficient Maximization", IEEE TPAMI 30(10), 2008.
.. [Rublee2011] E. Rublee, V. Rabaud, K. Konolige and G. Bradski, "ORB: an efficient
   alternative to SIFT or SURF", ICCV 2011.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from .frames import (
    DEFAULT_CLIP_MARGIN,
    apply_lut,
    clip_limits,
    default_reference,
    StackFrames,
    Lineariser,
    max_code_of,
)
from ..io.images import import_cv2

__all__ = ["estimate_alignment", "warp_to_reference"]


def estimate_alignment(images, exposures=None, model=None, *, method: str = "mtb",
                       reference: int | None = None, linear: bool = False,
                       clip_margin: float = DEFAULT_CLIP_MARGIN, working_size: int = 1024,
                       warnings: list | None = None, progress=None) -> list:
    """Transforms that align each frame of a stack to the reference frame.

    ``"mtb"``: translation by median threshold bitmaps (Ward, JGT 2003, via
    ``cv2.AlignMTB``), exposure-invariant and robust, on the full-resolution grey codes.
    ``"homography"``: an MTB translation refined to a homography by ECC maximisation
    (Evangelidis & Psarakis, TPAMI 2008, ``cv2.findTransformECC`` with
    ``MOTION_HOMOGRAPHY``, coarse to fine), both on downscaled images (long side
    ``working_size``; JPEGs decoded with DCT scaling), ECC on grey *linearised* images
    ``log(f⁻¹(I)/e)`` clamped to the radiance range both frames measure unclipped, so the
    two frames look alike whatever their exposures; when ECC fails, ORB features + RANSAC
    (``cv2.findHomography``), and when that fails too, the translation (with a warning).

    Parameters
    ----------
    images : sequence
        Frames (arrays or paths; paths are decoded one at a time).
    exposures : sequence of float, optional
        Relative exposures (needed for ``"homography"``; also chooses the default
        reference, the middle exposure).
    model : ResponseModel or object with ``inverse_response``/``to_raw``, optional
        The inverse response for ``"homography"`` (default: an sRGB-like gamma 2.2).
    method : {"mtb", "homography"}
    reference : int, optional
        Index of the reference frame; default the middle one by exposure.
    linear : bool
        The frames are linear values.
    clip_margin : float
        Codes (8-bit scale) within this distance of 0 or the maximum count as clipped.
    working_size : int
        Long side of the images the homography is estimated on.
    warnings : list, optional
        Receives warnings (strings).
    progress : callable, optional
        ``progress("align", done, total, source)``.

    Returns
    -------
    list of numpy.ndarray
        Per frame, the 3×3 map from reference pixel coordinates to the frame's (use
        :func:`warp_to_reference`).
    """
    frames = images if isinstance(images, StackFrames) else StackFrames(images, linear)
    n = len(frames)
    if method is True:
        method = "mtb"
    if method not in ("mtb", "homography"):
        raise InputError(f"unknown alignment method {method!r} (mtb or homography)")
    if exposures is None:
        exposures = np.ones(n)
        if method == "homography":
            raise InputError("homography alignment needs the frames' exposures")
    exposures = np.asarray(exposures, dtype=float)
    ref = default_reference(exposures) if reference is None else int(reference)
    warnings = [] if warnings is None else warnings
    transforms = [np.eye(3) for _ in range(n)]
    order = [ref] + [k for k in range(n) if k != ref]

    if method == "mtb":
        # integer translation by MTB at full resolution
        ref_grey: np.ndarray | None = None
        for done, k in enumerate(order):
            img = frames.load(k)
            grey = _to_grey8(img)
            del img
            if k == ref:
                ref_grey = grey
            else:
                assert ref_grey is not None     # the reference is first in order
                transforms[k] = _translation(*_mtb_shift(ref_grey, grey))
            if progress is not None:
                progress("align", done + 1, n, frames.sources[k])
        return transforms

    # homography: MTB translation, then ECC, on downscaled (linearised) images
    cv2 = import_cv2()
    if model is None:
        model = _GammaModel()
    full_h, full_w = frames.shape
    s0 = min(1.0, working_size / max(full_h, full_w))
    size = (max(8, round(full_w * s0)), max(8, round(full_h * s0)))      # (w, h)
    scale = (size[0] / full_w, size[1] / full_h)
    reduce = _working_reduce(frames, working_size)
    lin = None
    ref_data: tuple[np.ndarray, float, float, np.ndarray] | None = None
    for done, k in enumerate(order):
        img = frames.load(k, reduce=reduce)
        if (img.shape[1], img.shape[0]) != size:
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        if lin is None:
            lin = Lineariser(model, linear, max_code_of(img))
        lo, hi = clip_limits(lin.max_code, clip_margin, linear)
        g, glo, ghi = _log_clamped(img, lin, exposures[k], lo, hi)
        grey = _to_grey8(img)
        del img
        if k == ref:
            ref_data = (g, glo, ghi, grey)
        else:
            assert ref_data is not None         # the reference is first in order
            t, tlo, thi, ref_grey = ref_data
            init = _translation(*_mtb_shift(ref_grey, grey))
            transforms[k] = _rescale_homography(init, 1.0 / scale[0], 1.0 / scale[1])
            a, b = max(glo, tlo), min(ghi, thi)
            h = None
            if a < b:
                tc = np.clip(t, a, b)
                ic = np.clip(g, a, b)
                try:
                    h, cc = _ecc_homography(tc, ic, init)
                    if cc < 0.5 or not _plausible(h, tc.shape):
                        h = None
                except cv2.error:
                    h = None
                if h is None:
                    h = orb_homography(tc, ic)
                    if h is not None and not _plausible(h, tc.shape):
                        h = None
            if h is None:
                warnings.append(f"{Path(frames.sources[k]).name}: homography alignment failed"
                                + ("" if a < b else " (no radiance range shared with the "
                                   "reference)") + "; kept the MTB translation")
            else:
                transforms[k] = _rescale_homography(h, 1.0 / scale[0], 1.0 / scale[1])
        if progress is not None:
            progress("align", done + 1, n, frames.sources[k])
    return transforms


def warp_to_reference(image: np.ndarray, transform: np.ndarray, *, border_value=0,
                      interpolation: str = "linear") -> np.ndarray:
    """Resample a frame onto the reference frame's pixel grid.

    Parameters
    ----------
    image : numpy.ndarray
        ``HxW`` or ``HxWxC`` frame.
    transform : numpy.ndarray
        3×3 map from reference to frame coordinates (:func:`estimate_alignment`).
    border_value : scalar
        Value outside the frame.
    interpolation : {"linear", "nearest"}

    Returns
    -------
    numpy.ndarray
        Same shape and dtype.
    """
    cv2 = import_cv2()
    h = np.asarray(transform, dtype=np.float64)
    hh, ww = image.shape[:2]
    flags = (cv2.INTER_LINEAR if interpolation == "linear" else cv2.INTER_NEAREST) \
        | cv2.WARP_INVERSE_MAP
    bv = (border_value,) * 4
    if np.allclose(h[2], [0, 0, 1]):
        if np.allclose(h[:2, :2], np.eye(2)) and np.allclose(h[:2, 2], np.round(h[:2, 2])):
            return _shift_integer(image, int(round(h[0, 2])), int(round(h[1, 2])), border_value)
        return cv2.warpAffine(image, h[:2], (ww, hh), flags=flags,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=bv)
    return cv2.warpPerspective(image, h, (ww, hh), flags=flags,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=bv)


def _shift_integer(image, tx: int, ty: int, border_value) -> np.ndarray:
    """out(x, y) = image(x + tx, y + ty), constant outside."""
    out = np.full_like(image, border_value)
    hh, ww = image.shape[:2]
    ys, yd = (slice(ty, hh), slice(0, hh - ty)) if ty >= 0 else (slice(0, hh + ty),
                                                                  slice(-ty, hh))
    xs, xd = (slice(tx, ww), slice(0, ww - tx)) if tx >= 0 else (slice(0, ww + tx),
                                                                  slice(-tx, ww))
    if abs(tx) < ww and abs(ty) < hh:
        out[yd, xd] = image[ys, xs]
    return out


# --------------------------------------------------------------------------------------
# median threshold bitmaps (Ward 2003)
# --------------------------------------------------------------------------------------

def _to_grey8(image: np.ndarray) -> np.ndarray:
    """8-bit grey image for median threshold bitmaps (codes, not linear values)."""
    cv2 = import_cv2()
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        image = (np.clip(image, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def _mtb_shift(ref_grey: np.ndarray, grey: np.ndarray, max_bits: int | None = None,
               exclude_range: int = 4) -> tuple[int, int]:
    """Translation of ``grey`` relative to ``ref_grey`` by median threshold bitmaps.

    Ward, *Fast, Robust Image Registration for Compositing High Dynamic Range Photographs
    from Hand-Held Exposures*, JGT 2003, through ``cv2.AlignMTB.calculateShift``.  Returns
    ``(dx, dy)``: shifting ``grey`` by it aligns it to ``ref_grey``.  The pyramid has
    ``max_bits`` levels (shifts up to about ``2**max_bits`` pixels); by default as many as
    keep the coarsest level at least 8 pixels high, at most 6.

    Both images are histogram-equalised first (a monotone map: the median threshold bitmap
    is unchanged, but the exclusion band around the median then holds a fixed share of the
    pixels, so very dark frames do not leave an empty bitmap), and the shift found is kept
    only when its bitmap disagreement is lower than at zero shift -- OpenCV returns the
    largest shift when the bitmaps carry no information, and MTB is fragile on very noisy
    frames (then use the homography).
    """
    cv2 = import_cv2()
    if max_bits is None:
        max_bits = int(np.clip(math.floor(math.log2(min(ref_grey.shape) / 8)), 1, 6))
    mtb = cv2.createAlignMTB(max_bits, exclude_range, False)
    a, b = cv2.equalizeHist(ref_grey), cv2.equalizeHist(grey)
    dx, dy = (int(v) for v in mtb.calculateShift(a, b))
    if (dx, dy) == (0, 0):
        return 0, 0
    tb0, eb0 = mtb.computeBitmaps(a)
    tb1, eb1 = mtb.computeBitmaps(b)

    def disagreement(sx, sy):
        t1 = _shift_integer(tb1, -sx, -sy, 0)
        e1 = _shift_integer(eb1, -sx, -sy, 0)
        both = cv2.bitwise_and(eb0, e1)
        n = cv2.countNonZero(both)
        if n < 0.01 * both.size:
            return 1.0
        return cv2.countNonZero(cv2.bitwise_and(cv2.bitwise_xor(tb0, t1), both)) / n

    if disagreement(dx, dy) < disagreement(0, 0):
        return dx, dy
    return 0, 0


# --------------------------------------------------------------------------------------
# homographies: ECC (Evangelidis & Psarakis 2008), ORB + RANSAC
# --------------------------------------------------------------------------------------

def _log_clamped(image, lin: Lineariser, exposure: float, lo: float, hi: float):
    """log radiance (grey) of a small image, and its unclipped range (log)."""
    cv2 = import_cv2()
    # the unclipped range, conservatively: every channel unclipped at both ends
    lo_x, hi_x = 1e-4, 1.0
    if lin.table is not None and lin.kind != "linear":
        lo_x = float(np.max(lin.table[int(lo) + 1]))
        hi_x = float(np.min(lin.table[int(math.ceil(hi)) - 1]))
    if lin.table is not None and lin.kind == "lut":
        x = apply_lut(image, lin.table.astype(np.float32))
    else:
        x = lin.values(image)
    grey = cv2.cvtColor(np.ascontiguousarray(x, dtype=np.float32), cv2.COLOR_RGB2GRAY)
    lo_x = max(lo_x, 1e-6)
    g = np.log(np.maximum(grey, lo_x) / exposure)
    return g.astype(np.float32), math.log(lo_x / exposure), math.log(hi_x / exposure)


def _ecc_homography(template, image, init: np.ndarray, levels: int = 3) -> tuple:
    """ECC homography (Evangelidis & Psarakis, TPAMI 2008), coarse to fine.

    ``template`` and ``image`` are float32 grey images of one size; returns the 3×3 map
    from template to image coordinates and the final correlation coefficient.
    """
    cv2 = import_cv2()
    pyr_t, pyr_i = [template], [image]
    for _ in range(levels - 1):
        if min(pyr_t[-1].shape) < 64:
            break
        pyr_t.append(cv2.resize(pyr_t[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
        pyr_i.append(cv2.resize(pyr_i[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    depth = len(pyr_t) - 1
    h = _rescale_homography(init, 0.5 ** depth)
    cc = 0.0
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    for level in range(depth, -1, -1):
        warp = h.astype(np.float32)
        cc, warp = cv2.findTransformECC(pyr_t[level], pyr_i[level], warp,
                                        cv2.MOTION_HOMOGRAPHY, criteria, None, 5)
        h = warp.astype(np.float64)
        h /= h[2, 2]
        if level:
            h = _rescale_homography(h, 2.0)
    return h, float(cc)


def refine_homography(template, image, init: np.ndarray, min_cc: float = 0.5):
    """:func:`_ecc_homography` from ``init`` (template → image, float32 grey images of one
    size), or None when ECC fails, correlates under ``min_cc`` or moves too far."""
    cv2 = import_cv2()
    try:
        h, cc = _ecc_homography(template, image, init)
    except cv2.error:
        return None
    return h if cc >= min_cc and _plausible(h, template.shape) else None


def orb_homography(template: np.ndarray, image: np.ndarray, *, threshold: float = 2.0,
                   min_inliers: int = 8) -> np.ndarray | None:
    """ORB features (Rublee et al., ICCV 2011) + RANSAC homography, template → image
    (grey images: 8-bit ones as they are, others stretched between their 1st and 99th
    percentiles); None with fewer than ``min_inliers`` inliers (at a
    reprojection ``threshold`` in pixels)."""
    cv2 = import_cv2()

    def to8(g):
        if g.dtype == np.uint8:
            return g
        lo, hi = np.percentile(g, [1, 99])
        return np.clip((g - lo) / max(hi - lo, 1e-6) * 255, 0, 255).astype(np.uint8)

    orb = cv2.ORB_create(4000)
    k1, d1 = orb.detectAndCompute(to8(template), None)
    k2, d2 = orb.detectAndCompute(to8(image), None)
    if d1 is None or d2 is None or min(len(k1), len(k2)) < min_inliers:
        return None
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    if len(matches) < min_inliers:
        return None
    src = np.array([k1[m.queryIdx].pt for m in matches], dtype=np.float32)
    dst = np.array([k2[m.trainIdx].pt for m in matches], dtype=np.float32)
    h, inliers = cv2.findHomography(src, dst, cv2.RANSAC, threshold)
    if h is None or inliers is None or int(inliers.sum()) < min_inliers:
        return None
    return h / h[2, 2]


class _GammaModel:
    """Stand-in inverse response f⁻¹(z) = z^2.2 when no model is at hand."""

    max_code = 255

    def inverse_response(self, codes):
        z = np.clip(np.asarray(codes, dtype=float) / self.max_code, 0, 1)
        return np.repeat((z ** 2.2)[:, None], 3, axis=1)


# --------------------------------------------------------------------------------------
# transforms and working sizes
# --------------------------------------------------------------------------------------

def _translation(dx: float, dy: float) -> np.ndarray:
    """3×3 map from reference to frame coordinates for a frame shifted by (−dx, −dy)."""
    return np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]])


def _scale_matrix(sx: float, sy: float | None = None) -> np.ndarray:
    """Pixel-centre map from a grid to one scaled by ``(sx, sy)`` (``u' = (u + ½) s − ½``)."""
    sy = sx if sy is None else sy
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


def _rescale_homography(h: np.ndarray, sx: float, sy: float | None = None) -> np.ndarray:
    """A homography between grids scaled by ``(sx, sy)`` relative to the grid of ``h``."""
    m = _scale_matrix(sx, sy)
    out = m @ h @ np.linalg.inv(m)
    return out / out[2, 2]


def negligible_motion(h: np.ndarray, shape, limit: float = 0.25) -> bool:
    """No corner moves by more than ``limit`` pixels: resampling would blur more than help."""
    hh, ww = shape
    corners = np.array([[0, 0, 1], [ww - 1, 0, 1], [0, hh - 1, 1], [ww - 1, hh - 1, 1]], float)
    moved = corners @ np.asarray(h, dtype=float).T
    moved = moved[:, :2] / moved[:, 2:]
    return bool(np.all(np.hypot(*(moved - corners[:, :2]).T) <= limit))


def _plausible(h: np.ndarray, shape, limit: float = 0.1) -> bool:
    """Corners move by less than ``limit`` of the image diagonal."""
    hh, ww = shape
    corners = np.array([[0, 0, 1], [ww - 1, 0, 1], [0, hh - 1, 1], [ww - 1, hh - 1, 1]], float)
    moved = corners @ h.T
    if np.any(np.abs(moved[:, 2]) < 1e-9):
        return False
    moved = moved[:, :2] / moved[:, 2:]
    return bool(np.all(np.hypot(*(moved - corners[:, :2]).T) < limit * math.hypot(hh, ww)))


def _working_reduce(frames: StackFrames, size: int) -> int:
    """JPEG DCT-scaling factor that keeps the long side at least ``size``."""
    long_side = max(frames.shape)
    r = 1
    while r < 8 and long_side / (2 * r) >= size:
        r *= 2
    return r


def aligned_working_frames(frames: StackFrames, transforms, max_side: int = 2048) -> list:
    """The frames warped onto the reference, downscaled to ``max_side`` (for calibration).

    Calibration samples block means on a coarse grid, so a reduced copy loses little, and
    17 frames of 24 MP then take about 80 MB instead of 1.2 GB.
    """
    cv2 = import_cv2()
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
        if not negligible_motion(t, img.shape[:2]):
            img = warp_to_reference(img, t)
        out.append(img)
    return out
