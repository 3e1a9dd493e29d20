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

Also here, and also ours: the **misalignment test** of :func:`selfcal.hdr.merge_hdr`.
Each frame is compared with its neighbour in exposure on exposure-normalised log
luminance, downscaled (:data:`_RESIDUAL_SIDES`): the mean absolute deviation of
``log Y_b − log Y_a`` from its median at the frames' own registration, and at a shift of
one pixel in each of 8 directions.  Noise and errors of the response do not fall when a
frame is shifted; misregistration does.  When a shift lowers the residual by more than
:data:`MISALIGNMENT_GAIN` the merge warns to align.  The threshold is from aligned and
shifted stacks, held-out ones included (docs/decisions.md, "The misalignment warning: a
1-pixel shift that lowers the residual").
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..io.images import import_cv2

_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def _luma(x, w=_LUMA):
    return w[0] * x[..., 0] + w[1] * x[..., 1] + w[2] * x[..., 2]


def _disagree(x, v, xr, vr, k: float, tol: float, gain: float = 1.0) -> np.ndarray:
    """Pixels where two radiance estimates differ beyond the noise (deghosting test).

    Compared on luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` -- gamut mapping and
    JPEG chroma subsampling disturb the channels of saturated colours but not their
    luminance much -- with ``Var[Y] = Σ_c w_c² Var[X_c] + (tol · Y)²``:
    ``(g·Y − Y_ref)² > k² (g²·Var[Y] + Var[Y_ref])``, ``g`` the correction of the frame's
    typical ratio to the reference (see :func:`ghost_mask`).
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


def ghost_mask(img, cover, ref_img, tab, ref_tab, strips, k: float, tol: float):
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
    cv2 = import_cv2()
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


def poor_agreement(ghost_stats: dict, sources, ref: int) -> str | None:
    """A warning when frames disagree with the reference even where nothing moves.

    ``ghost_stats`` maps a frame to the statistics of :func:`ghost_mask`; a robust spread
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


# --------------------------------------------------------------------------------------
# the misalignment test (ours): neighbours in exposure that agree better shifted
# --------------------------------------------------------------------------------------

#: Long sides (pixels) of the luminance images the misalignment test compares: a shift of
#: a pixel at the finer size finds small misregistrations, at the coarser one large ones.
_RESIDUAL_SIDES = (512, 128)
#: Shifts (pixels at that size) the test tries around zero, in each of 8 directions.
_RESIDUAL_SHIFT = 1
#: A pair is misaligned when a shift lowers its residual by more than this fraction.
MISALIGNMENT_GAIN = 0.05


def small_log_luma(img, cover, own_white, tab):
    """log luminance of f⁻¹(I)/e at each of :data:`_RESIDUAL_SIDES`, NaN where unmeasured.

    Downscaled by integer factors (``cv2.INTER_AREA``'s fast path; the first from the
    frame, the next from the first), the clip test made on the downscaled codes.
    """
    cv2 = import_cv2()
    out = []
    small = img
    bad = None
    if cover is not None:
        bad = cover
    for side in _RESIDUAL_SIDES:
        hh, ww = small.shape[:2]
        k = max(1, int(max(hh, ww) // side))
        if k > 1:
            # (row-strided views: OpenCV reads them as a region, without a copy)
            small = cv2.resize(small[:hh // k * k, :ww // k * k], (ww // k, hh // k),
                               interpolation=cv2.INTER_AREA)
            if bad is not None:
                bad = cv2.resize(bad[:hh // k * k, :ww // k * k], (ww // k, hh // k),
                                 interpolation=cv2.INTER_AREA)
        ok = tab.valid(small) > 0
        if bad is not None:
            ok &= bad == 0
        y = _luma(tab.radiance(np.ascontiguousarray(small)))
        ok &= y > 0
        logy = np.full(y.shape, np.nan, dtype=np.float32)
        logy[ok] = np.log(y[ok])
        out.append(logy)
    return out


def neighbour_residual(a, b, sources) -> dict:
    """:func:`_shift_residual` at each size; the one whose best shift gains most."""
    (ka, ya), (kb, yb) = a, b
    tests = [_shift_residual(sa, sb) for sa, sb in zip(ya, yb)]
    best = max(tests, key=lambda t: t["gain"])
    best["frames"] = (sources[ka], sources[kb])
    best["gains"] = [t["gain"] for t in tests]
    return best


def _shift_residual(ya, yb) -> dict:
    """Residual between two exposure-normalised neighbours, unshifted and at its best shift.

    The mean absolute deviation of ``log Y_b − log Y_a`` from its median over the pixels
    both measure, at the frames' own registration and shifted by up to
    :data:`_RESIDUAL_SHIFT` pixel in each of 8 directions.  Noise and errors
    of the response do not fall when one frame is shifted; misregistration does.
    """
    hh, ww = ya.shape
    r = _RESIDUAL_SHIFT
    best, at, r0 = np.inf, (0, 0), np.nan
    sb = yb[r:hh - r, r:ww - r]
    d0 = sb - ya[r:hh - r, r:ww - r]
    d0 = d0[np.isfinite(d0)]
    if d0.size >= 1000:
        med = np.float32(np.median(d0))     # the exposure mismatch: one for every shift
        for dy in (-r, 0, r):
            for dx in (-r, 0, r):
                d = np.abs(sb - ya[r + dy:hh - r + dy, r + dx:ww - r + dx] - med)
                ok = np.isfinite(d)
                if np.count_nonzero(ok) < 1000:
                    continue
                res = float(np.mean(d[ok]))
                if dx == 0 and dy == 0:
                    r0 = res
                elif res < best:
                    best, at = res, (dx, dy)
    gain = (1.0 - best / r0) if np.isfinite(r0) and np.isfinite(best) and r0 > 0 else 0.0
    return {"residual": r0,
            "shifted_residual": best if np.isfinite(best) else None,
            "shift": at, "gain": gain, "scale": ya.shape}


def misalignment_warning(residuals, exposures_from_pixels: bool) -> str | None:
    """The ``--align`` warning when some neighbour pair registers better shifted (and,
    when the exposures were estimated from these frames' pixels, that they may carry the
    misalignment)."""
    bad = [r for r in residuals if r["gain"] > MISALIGNMENT_GAIN]
    if not bad:
        return None
    worst = max(bad, key=lambda r: r["gain"])
    a, b = (Path(f).name for f in worst["frames"])
    msg = (f"the frames look misaligned: {len(bad)} of {len(residuals)} neighbour pairs "
           f"match better shifted (at {a} vs {b}, a shift of {worst['shift'][0]:+d},"
           f"{worst['shift'][1]:+d} px at {worst['scale'][1]}x{worst['scale'][0]} lowers "
           f"the residual by {100 * worst['gain']:.0f}%); merge with --align (align='mtb' "
           "or 'homography')")
    if exposures_from_pixels:
        msg += ("; the exposures estimated from these frames may reflect the "
                "misalignment rather than the shutter")
    return msg
