"""Vignetting from a flat field: a frame of a uniform surface, or of a diffuser over the lens.

A flat field of radiance ``L`` gives, after linearisation, ``E(x) = a_c · V_c(r(x))`` per
channel: the falloff itself, up to a scale.  We fit the model of [Goldman2010], Eq. 4
(:class:`~selfcal.lens.vignetting.Vignetting`: ``V = 1 + k₁r² + k₂r⁴ + k₃r⁶`` about an
off-centre optical centre, as [Kim2008] lets it move) to the logarithm of block means::

    log m_c(b) = log a_c + log V_c(r_b; centre, k_c)

by robust nonlinear least squares (scipy's ``least_squares``, soft-L1 loss at a scale
from the residuals' MAD), then refit the inliers with plain least squares, whose
Gauss–Newton approximation ``σ² (JᵀJ)⁻¹`` is the covariance of the parameters (σ² the
residual variance).  ``V = 1`` at the centre by the form of the model; the scales ``a_c``
are not kept.  Blocks holding a clipped pixel (at either end of the code range, before
linearisation) are left out.

What is ours: the block means, the clipping test, the robust loss and the inlier refit.
The fit cannot tell vignetting from a surface that is not uniform (a light gradient across
the card moves the centre): light the surface evenly, or put a diffuser over the lens.

References
----------
[Goldman2010] D. B. Goldman, "Vignette and exposure calibration and compensation",
IEEE TPAMI 32(12), 2010.
[Kim2008] S. J. Kim and M. Pollefeys, "Robust radiometric calibration and vignetting
correction", IEEE TPAMI 30(4), 2008.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CalibrationError, InputError
from .vignetting import Vignetting, binned_points

__all__ = ["flat_field_vignetting", "CLIP_FRACTION", "BLOCKS", "K_BOUND", "MAX_NEAREST_RADIUS",
           "FLAT_RESIDUAL_WARN"]

#: Codes within this fraction of either end of the code range count as clipped.
CLIP_FRACTION = 0.02
#: Blocks across the longer side of the frame.
BLOCKS = 48
#: Bounds on each k (ours): real profiles in our units stay within ±8 (lensfun's widest,
#: k₁ = −1.5 at f/1.8, on a body of 1.6× smaller crop); the bound keeps a fit whose
#: centre is clipped from trading V(0) = 1 for a power law.
K_BOUND = 20.0
#: The fit needs an unclipped block this close to the frame's centre (half diagonals).
MAX_NEAREST_RADIUS = 0.5
#: Residual RMS (log units, block means) above which the frame is said not to look flat:
#: a synthetic flat with 2 % pixel noise leaves 0.002; a colour chart leaves 0.23.
FLAT_RESIDUAL_WARN = 0.03


def _load(frame, path_hint):
    """The frame as an array and its largest code (None for float data, in [0, 1])."""
    if isinstance(frame, (str, Path)):
        path = Path(frame)
        from ..io.raw import is_raw_path, read_raw_linear

        if is_raw_path(path):
            return read_raw_linear(path).rgb, None, path
        from ..io.images import read_image

        frame = read_image(path)
        path_hint = path
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise InputError(f"a flat field is an HxWx3 RGB frame, not shape {frame.shape}",
                         path_hint)
    if np.issubdtype(frame.dtype, np.integer):
        return frame, float(np.iinfo(frame.dtype).max), path_hint
    return frame.astype(np.float32), None, path_hint


def _block_means(linear, codes, max_code, blocks):
    """Means of ``linear`` over a grid of blocks, their centres, and which are usable."""
    h, w = linear.shape[:2]
    size = max(2, int(np.ceil(max(h, w) / blocks)))
    ny, nx = h // size, w // size
    if ny < 3 or nx < 3:
        raise InputError(f"a {w}×{h} frame is too small for a flat-field fit "
                         f"(at least {3 * size} pixels a side)")
    y0, x0 = (h - ny * size) // 2, (w - nx * size) // 2
    crop = linear[y0:y0 + ny * size, x0:x0 + nx * size].reshape(ny, size, nx, size, 3)
    means = crop.mean(axis=(1, 3), dtype=np.float64).reshape(-1, 3)
    ok = np.all(np.isfinite(means) & (means > 0), axis=1)
    if codes is not None:
        c = codes[y0:y0 + ny * size, x0:x0 + nx * size].reshape(ny, size, nx, size, 3)
        if max_code is None:
            lo, hi = CLIP_FRACTION, 1.0 - CLIP_FRACTION
        else:
            lo, hi = CLIP_FRACTION * max_code, (1.0 - CLIP_FRACTION) * max_code
        clipped = ((c.min(axis=(1, 3)) <= lo) | (c.max(axis=(1, 3)) >= hi)).any(axis=-1)
        ok &= ~clipped.reshape(-1)
    yy, xx = np.mgrid[0:ny, 0:nx]
    xs = (x0 + (xx + 0.5) * size - 0.5).reshape(-1)
    ys = (y0 + (yy + 0.5) * size - 0.5).reshape(-1)
    return means, xs, ys, ok


def _linear_start(u, v, means):
    """Starting values: ``m_c = a_c (1 + k₁r² + k₂r⁴ + k₃r⁶)`` about the image centre is
    linear in ``(a_c, a_c k_c)``; solved with weights ``1/m_c`` (relative residuals)."""
    r2 = u ** 2 + v ** 2
    design = np.stack([np.ones_like(r2), r2, r2 ** 2, r2 ** 3], axis=1)
    start = np.zeros(14)
    for c in range(3):
        w = 1.0 / means[:, c]
        beta = np.linalg.lstsq(design * w[:, None], means[:, c] * w, rcond=None)[0]
        a = beta[0] if beta[0] > 0 else float(np.max(means[:, c]))
        start[2 + 3 * c:5 + 3 * c] = np.clip(beta[1:] / a, -0.9 * K_BOUND, 0.9 * K_BOUND)
        start[11 + c] = np.log(a)
    return start


def _jacobian(p, u, v, logm):
    """∂ residuals / ∂ (cx, cy, k per channel, log a per channel), analytically."""
    du, dv = u - p[0], v - p[1]
    r2 = du ** 2 + dv ** 2
    n = u.size
    jac = np.zeros((3 * n, 14))
    for c in range(3):
        k1, k2, k3 = p[2 + 3 * c:5 + 3 * c]
        value = np.maximum(1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)), 1e-9)
        d_r2 = (k1 + 2 * k2 * r2 + 3 * k3 * r2 ** 2) / value
        rows = slice(c * n, (c + 1) * n)
        jac[rows, 0], jac[rows, 1] = -2 * du * d_r2, -2 * dv * d_r2
        jac[rows, 2 + 3 * c] = r2 / value
        jac[rows, 3 + 3 * c] = r2 ** 2 / value
        jac[rows, 4 + 3 * c] = r2 ** 3 / value
        jac[rows, 11 + c] = 1.0
    return jac


def _residuals(p, u, v, logm):
    cx, cy = p[0], p[1]
    r2 = (u - cx) ** 2 + (v - cy) ** 2
    out = []
    for c in range(3):
        k1, k2, k3 = p[2 + 3 * c:5 + 3 * c]
        value = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        out.append(p[11 + c] + np.log(np.maximum(value, 1e-9)) - logm[:, c])
    return np.concatenate(out)


def flat_field_vignetting(frame: Any, *, linearize: Callable | None = None,
                          blocks: int = BLOCKS, description: str | None = None) -> Vignetting:
    """Fit the vignetting ``V`` ([Goldman2010], Eq. 4) to a flat-field frame.

    Parameters
    ----------
    frame : array_like or path
        ``HxWx3`` RGB frame of a uniform surface (uint8, uint16, or float in [0, 1]), or
        a file: JPEG/PNG/TIFF (:func:`selfcal.io.images.read_image`) or a camera raw
        (:func:`selfcal.io.raw.read_raw_linear`, linear already).  A frame the camera
        rendered (JPEG) must be linearised: pass ``linearize``.
    linearize : callable, optional
        Maps the frame's codes to linear values (a response model's ``linearize``).
        Default: none -- the data are linear (raw, linear TIFF); integer codes are
        divided by their largest value.
    blocks : int
        Blocks across the longer side; the fit is made on their means.
    description : str, optional
        Default: "flat field" and the file name when a path is given.

    Returns
    -------
    Vignetting
        ``source="flat"``, ``aspect=w/h`` of the frame, the covariance of the
        11 parameters from the inlier refit, ``diagnostics`` with the blocks used, the
        residual RMS (log units) and ``"points"`` (the blocks' ``log V``, binned).

    Warns
    -----
    SelfcalWarning
        When the frame does not look flat (residual RMS above :data:`FLAT_RESIDUAL_WARN`
        or fewer than half the blocks inliers); also in ``diagnostics["warnings"]``.

    Raises
    ------
    InputError
        For a frame that is not HxWx3, too small, or unreadable (the file named).
    CalibrationError
        When too few blocks are unclipped for the 14 parameters, or none near the centre.
    """
    from scipy.optimize import least_squares

    codes, max_code, path = _load(frame, None)
    if linearize is not None:
        linear = np.asarray(linearize(codes), np.float64)
    elif max_code is not None:
        linear = codes.astype(np.float64) / max_code
    else:
        linear = codes.astype(np.float64)
    h, w = codes.shape[:2]
    means, xs, ys, ok = _block_means(linear, codes, max_code, blocks)
    if ok.sum() < 30:
        raise CalibrationError(f"only {int(ok.sum())} of {ok.size} flat-field blocks are "
                               "unclipped: expose the surface mid-range"
                               + (f" ({path})" if path else ""))
    half_diagonal = 0.5 * float(np.hypot(h, w))
    u = (xs[ok] - 0.5 * (w - 1)) / half_diagonal
    v = (ys[ok] - 0.5 * (h - 1)) / half_diagonal
    logm = np.log(means[ok])
    start = _linear_start(u, v, means[ok])
    nearest = float(np.hypot(u, v).min())
    if nearest > MAX_NEAREST_RADIUS:
        raise CalibrationError(f"the flat field is clipped out to {nearest:.2f} of the half "
                               "diagonal from the centre: V = 1 there cannot be fixed; "
                               "expose it lower" + (f" ({path})" if path else ""))
    args = (u, v, logm)
    bounds = (np.r_[-0.5, -0.5, np.full(9, -K_BOUND), np.full(3, -np.inf)],
              np.r_[0.5, 0.5, np.full(9, K_BOUND), np.full(3, np.inf)])
    first = least_squares(_residuals, start, jac=_jacobian, args=args, bounds=bounds,
                          x_scale="jac")
    scale = max(1.4826 * float(np.median(np.abs(first.fun))), 1e-6)
    robust = least_squares(_residuals, first.x, jac=_jacobian, args=args, bounds=bounds,
                           loss="soft_l1", f_scale=scale, x_scale="jac")
    res = robust.fun.reshape(3, -1)
    sigma = 1.4826 * np.median(np.abs(res))
    inlier = np.all(np.abs(res) <= 4.0 * max(sigma, 1e-6), axis=0)
    args = (u[inlier], v[inlier], logm[inlier])
    final = least_squares(_residuals, robust.x, jac=_jacobian, args=args, bounds=bounds,
                          x_scale="jac")
    n, p = final.fun.size, final.x.size
    variance = float(final.fun @ final.fun) / max(n - p, 1)
    jac = _jacobian(final.x, *args)
    covariance = variance * np.linalg.pinv(jac.T @ jac)
    params = final.x
    r = np.hypot(u - params[0], v - params[1])
    log_ratio = logm - params[11:]
    name = description or ("flat field" + (f" {Path(path).name}" if path else ""))
    warnings_ = []
    if np.sqrt(variance) > FLAT_RESIDUAL_WARN or inlier.mean() < 0.5:
        warnings_.append(f"{name}: does not look flat (residual {np.sqrt(variance):.3f} "
                         f"log units, {int(inlier.sum())} of {inlier.size} blocks fit): "
                         "the vignetting fitted to it is doubtful")
        import warnings

        from ..errors import SelfcalWarning

        warnings.warn(warnings_[-1], SelfcalWarning, stacklevel=2)
    return Vignetting(params[2:11].reshape(3, 3), params[:2], source="flat",
                      description=name, covariance=covariance[:11, :11],
                      log_sigma_floor=0.0, aspect=w / h,
                      diagnostics={"blocks": int(ok.size), "blocks_used": int(inlier.sum()),
                                   "blocks_clipped": int((~ok).sum()),
                                   "residual_rms_log": float(np.sqrt(variance)),
                                   "warnings": warnings_,
                                   "points": binned_points(r, log_ratio)})
