"""Deghosting: which frames disagree with the reference frame beyond the noise, per pixel.

A frame's radiance estimate is compared with the reference frame's on luminance
``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (ITU-R BT.709 weights) and excluded where
``(g·Y − Y_ref)² > k² (g²·Var[Y] + Var[Y_ref])``: the variances are those of the noise
model (:func:`selfcal.hdr.weights.noise_variance`, after Granados et al., CVPR 2010, and
Hasinoff et al., CVPR 2010), so the test is a ``k``-sigma test on the difference of two
noisy measurements of one radiance.

Ours, not the papers': the test is made after dividing out the frame's typical ratio to
the reference ``g`` (an exposure error is not a ghost), with a relative floor
``max(tol, s)`` where ``s`` is the robust spread of ``log(Y/Y_ref)`` (a poorly fitting
response makes deghosting cautious rather than wild); luminance rather than the channels
(gamut mapping and JPEG chroma subsampling disturb the channels of saturated colours);
and a 5×5 median filter on the mask, because a ghost is a region while isolated pixels and
thin lines along edges are noise the model does not describe.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..io import _cv2

_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def _luma(x, w=_LUMA):
    return w[0] * x[..., 0] + w[1] * x[..., 1] + w[2] * x[..., 2]


def _disagree(x, v, xr, vr, k: float, tol: float, gain: float = 1.0) -> np.ndarray:
    """Pixels where two radiance estimates differ beyond the noise (deghosting test).

    Compared on luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` -- gamut mapping and
    JPEG chroma subsampling disturb the channels of saturated colours but not their
    luminance much -- with ``Var[Y] = Σ_c w_c² Var[X_c] + (tol · Y)²``:
    ``(g·Y − Y_ref)² > k² (g²·Var[Y] + Var[Y_ref])``, ``g`` the correction of the frame's
    typical ratio to the reference (see :func:`_ghost_mask`).
    """
    y, yr = _luma(x) * np.float32(gain), _luma(xr)
    g2 = np.float32(gain * gain)
    var = (g2 * _luma(v, _LUMA * _LUMA) + _luma(vr, _LUMA * _LUMA)
           + np.float32(tol * tol) * (y * y + yr * yr))
    return (y - yr) ** 2 > np.float32(k * k) * var


def _ratio_statistics(img, cover, ref_img, tab, ref_tab, strips, step: int = 4):
    """Median and robust spread (1.4826 MAD) of log(Y / Y_ref) over pixels both measure.

    On a subsample (every ``step``-th row and column).  The median is the frame's exposure
    mismatch with the reference; the spread is how well the response model and noise
    explain the pair (a static scene and a good model give a few per cent).
    """
    logs = []
    for s in strips:
        first = s.start + (-s.start) % step
        sub = (slice(first, s.stop, step), slice(None, None, step))
        codes = np.ascontiguousarray(img[sub])
        rcodes = np.ascontiguousarray(ref_img[sub])
        if codes.size == 0:
            continue
        both = (tab.valid(codes) > 0) & (ref_tab.valid(rcodes) > 0)
        if cover is not None:
            both &= cover[sub] == 0
        if not both.any():
            continue
        y = _luma(tab.radiance(codes))[both]
        yr = _luma(ref_tab.radiance(rcodes))[both]
        ok = (y > 0) & (yr > 0)
        logs.append(np.log(y[ok]) - np.log(yr[ok]))
    r = np.concatenate(logs) if logs else np.zeros(0)
    if r.size < 100:
        return 0.0, 0.0, int(r.size)
    med = float(np.median(r))
    return med, 1.4826 * float(np.median(np.abs(r - med))), int(r.size)


def _ghost_mask(img, cover, ref_img, tab, ref_tab, strips, k: float, tol: float):
    """uint8 mask (255) of the pixels where a frame disagrees with the reference frame.

    First the frame's typical ratio to the reference ``g`` and the spread ``s`` of
    ``log(Y/Y_ref)`` (:func:`_ratio_statistics`): the test of :func:`_disagree` is made
    after dividing out ``g`` (an exposure error is not a ghost) with the relative floor
    ``max(tol, s)`` (a poorly fitting response makes deghosting cautious rather than
    wild).  Then a 5×5 median filter: a ghost is a region, while isolated pixels and thin
    lines along edges (JPEG ringing, chroma subsampling, residual misalignment) are noise
    the model does not describe.

    Returns
    -------
    (numpy.ndarray, dict)
        The mask, and ``{"log_ratio": median, "spread": s, "samples": n}``.
    """
    cv2 = _cv2()
    med, spread, count = _ratio_statistics(img, cover, ref_img, tab, ref_tab, strips)
    gain = math.exp(-med)
    floor = max(tol, spread)
    off = np.zeros(img.shape[:2], dtype=np.uint8)
    for s in strips:
        codes, rcodes = img[s], ref_img[s]
        both = (tab.valid(codes) > 0) & (ref_tab.valid(rcodes) > 0)
        if cover is not None:
            both &= cover[s] == 0
        x, v = tab.radiance_variance(codes)
        xr, vr = ref_tab.radiance_variance(rcodes)
        off[s] = (_disagree(x, v, xr, vr, k, floor, gain) & both).view(np.uint8) * np.uint8(255)
    return cv2.medianBlur(off, 5), {"log_ratio": med, "spread": spread, "samples": count}


def _poor_agreement(ghost_stats: dict, sources, ref: int) -> str | None:
    """A warning when frames disagree with the reference even where nothing moves.

    ``ghost_stats`` maps a frame to the statistics of :func:`_ghost_mask`; a robust spread
    of ``log(Y/Y_ref)`` above 25 % (on at least 100 samples) says the response model or the
    exposures fit poorly -- the floor of the test then rose with it.
    """
    poor = [(st["spread"], k) for k, st in ghost_stats.items()
            if st["samples"] >= 100 and st["spread"] > 0.25]
    if not poor:
        return None
    spread, k = max(poor)
    return (f"deghosting: {len(poor)} frame(s) disagree with the reference frame "
            f"{Path(sources[ref]).name} by {100 * spread:.0f}% (typical, at "
            f"{Path(sources[k]).name}) even where nothing moves: the response "
            "model or the exposures fit poorly, so deghosting was made cautious")
