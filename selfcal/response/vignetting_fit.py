"""Vignetting self-calibrated from frames that moved, jointly with the response.

After homography alignment a scene point ``x`` (reference pixel coordinates) is seen in
frame ``j`` at ``p_j = H_j x``; [Goldman2010] Eq. 1-2 and §3-4 in the log domain::

    log f⁻¹(B_j(p_j)) = log e_j + log V(p_j) + log L(x)

with ``V`` the radial polynomial of Eq. 4 (:class:`selfcal.lens.Vignetting`: an optical
centre and ``k₁..k₃`` per channel).  [Goldman2010] solves for ``V``, ``e_j`` and the
response by alternation on the radiances ``L``; here ``log L(x)`` is eliminated in closed
form (variable projection: for given ``V`` and ``e`` it is the weighted mean over the
frames that see ``x``), and the remaining 11 + (F − 1) parameters are fitted by
Gauss-Newton with a Huber loss (:func:`scipy.optimize.least_squares`) on block means of
smooth, unclipped regions.  The response is fitted by the existing solve of [Lin2011]
Eq. 8 on the aligned frames, and the two alternate (ours): each aligned frame's codes are
moved by the vignetting ratio ``V(x) / V(H_j x)`` through the current curve, so every
frame carries the reference frame's falloff, which then cancels from Eq. 8; the response
is refitted on those frames, the vignetting on the original ones with that response.

Ours, beyond [Goldman2010]: the free optical centre ([Kim2008] lets it move), per-channel
coefficients, weak priors on the parameters (k ~ N(0, 1), centre ~ N(0, 0.2²)), the
covariance from the robust-weighted Gauss-Newton normal matrix, and the observability
test (how far the frames moved; how well the fit pins the corner falloff).

References
----------
[Goldman2010] D. B. Goldman, "Vignette and exposure calibration and compensation",
IEEE TPAMI 32(12), 2010.
[Kim2008] S. J. Kim and M. Pollefeys, "Robust radiometric calibration and vignetting
correction", IEEE TPAMI 30(4), 2008.
[Lin2011] H. Lin, S. J. Kim, S. Süsstrunk, M. S. Brown, "Revisiting radiometric
calibration for color computer vision", ICCV 2011.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import CalibrationError
from ..io.images import import_cv2
from ..lens.vignetting import Vignetting, normalised_radius, radial_falloff
from ..stack.align import orb_homography

#: Frames that moved less than this (largest RMS displacement of a frame's pixels from the
#: reference's, a fraction of the image diagonal) show no vignetting: nothing is fitted.
MIN_MOTION = 0.015
#: The fit is refused as ill-conditioned when the standard deviation of log V at the
#: image corner (from the covariance, worst channel) exceeds this.
MAX_CORNER_LOG_SIGMA = 0.1
#: A fitted falloff darker than this anywhere in the frame (3 stops; lensfun's strongest
#: profiles of rectilinear lenses lose about 2.5 wide open), or brighter than the centre
#: by more than MAX_BRIGHTENING, is refused as implausible (ours).
MIN_FALLOFF = 0.125
MAX_BRIGHTENING = 1.05
#: Fewer correspondences than this (points seen unclipped in two frames or more): refused.
MIN_POINTS = 150
#: Rounds of the alternation response → vignetting (→ corrected frames → response ...).
DEFAULT_ROUNDS = 3
#: Codes (8-bit scale) within this distance of 0 or the maximum are not used.
CODE_MARGIN = 6.0
#: Largest standard deviation of the codes inside a block (8-bit scale): flat blocks only.
MAX_BLOCK_STD = 2.5
#: Blocks whose HSV saturation exceeds this in a frame are not used there: the camera's
#: colour step (matrix, gamut mapping) mixes the channels of saturated colours, which a
#: per-channel curve does not undo ([Lin2011] §5 rejects them for the response too).
MAX_SATURATION = 0.5
#: Prior standard deviations of the coefficients and of the centre offset (weak).
PRIOR_SIGMA_K = 1.0
PRIOR_SIGMA_CENTRE = 0.2
#: Prior standard deviation of the residual alignment (pixels), fitted per frame as an
#: affine map through the scene's log gradient.
PRIOR_SIGMA_SHIFT = 2.0
#: Huber threshold on standardised residuals.
HUBER_K = 1.5


@dataclass
class VignettingFit:
    """One fit of [Goldman2010] Eq. 1-4 on the aligned frames (:func:`fit_vignetting`)."""

    vignetting: Vignetting
    log_exposures: np.ndarray
    corner_log_sigma: float
    points: int
    residual: float


def working_transforms(transforms, full_shape, working_shape) -> list:
    """The reference→frame homographies rescaled from full-size to working pixels."""
    sy = working_shape[0] / full_shape[0]
    sx = working_shape[1] / full_shape[1]
    s = np.diag([sx, sy, 1.0])
    s_inv = np.diag([1.0 / sx, 1.0 / sy, 1.0])
    return [s @ np.asarray(t, np.float64) @ s_inv for t in transforms]


def frame_motion(transforms, shape) -> list:
    """Per frame, the RMS displacement ``|H_j x − x|`` over the frame's pixels, as a
    fraction of the image diagonal (ours: what makes the falloff observable)."""
    h, w = shape
    ys, xs = np.mgrid[0:h:max(1, h // 16), 0:w:max(1, w // 16)].astype(np.float64)
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    out = []
    for t in transforms:
        q = np.asarray(t, np.float64) @ pts
        q = q[:2] / q[2]
        out.append(float(np.sqrt(np.mean(np.sum((q - pts[:2]) ** 2, axis=0))) / math.hypot(h, w)))
    return out


def _block_stats(frame: np.ndarray, block: int, scale: float, curve):
    """Per block: the mean codes (nb_y, nb_x, 3) on the 8-bit scale, the largest
    per-channel std of the codes, the lowest and highest code, and the mean gradient of
    ``log f⁻¹`` (nb_y, nb_x, 3, 2: d/dx, d/dy per pixel)."""
    h, w = frame.shape[:2]
    ny, nx = h // block, w // block
    a = frame.astype(np.float64) * scale
    logs = np.stack([np.interp(a[..., c] / 255.0, curve[0], curve[1][:, c])
                     for c in range(3)], axis=-1)
    gy, gx = np.gradient(logs, axis=(0, 1))
    grad = np.stack([gx, gy], axis=-1)[:ny * block, :nx * block]
    grad = grad.reshape(ny, block, nx, block, 3, 2).mean(axis=(1, 3))
    a = a[:ny * block, :nx * block].reshape(ny, block, nx, block, 3)
    lo, hi = a.min(axis=(1, 3)).min(axis=-1), a.max(axis=(1, 3)).max(axis=-1)
    return a.mean(axis=(1, 3)), a.std(axis=(1, 3)).max(axis=-1), lo, hi, grad


def correspondences(frames, transforms, intensity, inverse, max_code: int, *,
                    block: int | None = None) -> dict:
    """Block means of the aligned frames where they are smooth and unclipped, linearised.

    Returns a dict with ``log`` (P, F, 3) ``log f⁻¹`` of the block means, ``valid``
    (P, F), ``weight`` (P, F, 3) the inverse variance of one code's quantisation through
    the curve's slope, ``xs``, ``ys`` (P, F) the points' positions in each frame
    (``H_j x``), and the frame ``shape``.
    """
    h, w = frames[0].shape[:2]
    block = block or max(4, max(h, w) // 96)
    scale = 255.0 / max_code
    curve = (intensity, np.log(np.maximum(inverse, 1e-6)))
    stats = [_block_stats(f, block, scale, curve) for f in frames]
    means = np.stack([s[0].reshape(-1, 3) for s in stats], axis=1)     # (P, F, 3)
    std = np.stack([s[1].ravel() for s in stats], axis=1)
    lo = np.stack([s[2].ravel() for s in stats], axis=1)
    hi = np.stack([s[3].ravel() for s in stats], axis=1)
    grad = np.stack([s[4].reshape(-1, 3, 2) for s in stats], axis=1)   # (P, F, 3, 2)
    top, bottom = means.max(axis=-1), means.min(axis=-1)
    saturation = (top - bottom) / np.maximum(top, 1e-6)       # HSV S, as [Lin2011] §5
    valid = ((lo > CODE_MARGIN) & (hi < 255.0 - CODE_MARGIN) & (std <= MAX_BLOCK_STD)
             & (saturation <= MAX_SATURATION))
    ny, nx = h // block, w // block
    cy, cx = np.mgrid[0:ny, 0:nx].astype(np.float64)
    cx, cy = cx.ravel() * block + 0.5 * (block - 1), cy.ravel() * block + 0.5 * (block - 1)
    pts = np.stack([cx, cy, np.ones_like(cx)])
    xs, ys = np.empty(valid.shape), np.empty(valid.shape)
    for j, t in enumerate(transforms):
        q = np.asarray(t, np.float64) @ pts
        xs[:, j], ys[:, j] = q[0] / q[2], q[1] / q[2]
    inside = (xs >= block) & (xs <= w - 1 - block) & (ys >= block) & (ys <= h - 1 - block)
    valid &= inside
    keep = valid.sum(axis=1) >= 2
    means, valid, xs, ys, grad = means[keep], valid[keep], xs[keep], ys[keep], grad[keep]
    # the scene's log gradient at each point: the frames' mean (exposure cancels)
    grad = (grad * valid[..., None, None]).sum(axis=1) / valid.sum(axis=1)[:, None, None]
    u = (cx[keep] - 0.5 * (w - 1)) / (0.5 * w)
    v = (cy[keep] - 0.5 * (h - 1)) / (0.5 * h)
    log = np.empty(means.shape)
    weight = np.empty(means.shape)
    for c in range(3):
        x = means[..., c] / 255.0
        g = np.log(np.maximum(inverse[:, c], 1e-6))
        log[..., c] = np.interp(x, intensity, g)
        step = 1.0 / 255.0
        slope = (np.interp(x + step, intensity, g) - np.interp(x - step, intensity, g)) / 2
        noise = slope ** 2 / (block * block) + 1e-6     # one code per pixel, averaged
        weight[..., c] = 1.0 / noise
    return {"log": log, "valid": valid, "weight": weight, "xs": xs, "ys": ys,
            "shape": (h, w), "block": block, "grad": grad,
            "uv1": np.stack([u, v, np.ones_like(u)], axis=1)}


def _unpack(params, n_frames: int, reference: int):
    """Centre, coefficients, log exposures and the residual alignment (F, 2, 3) in pixels
    per unit of the normalised frame coordinates (the reference's held at 0)."""
    centre, k = params[:2], params[2:11].reshape(3, 3)
    others = np.arange(n_frames) != reference
    log_e = np.zeros(n_frames)
    log_e[others] = params[11:11 + n_frames - 1]
    shift = np.zeros((n_frames, 2, 3))
    shift[others] = params[11 + n_frames - 1:].reshape(n_frames - 1, 2, 3)
    return centre, k, log_e, shift


def _model_log_v(data, centre, k):
    h, w = data["shape"]
    r = normalised_radius(h, w, centre, xs=data["xs"], ys=data["ys"])
    v = radial_falloff(r[..., None], k)
    return np.log(np.maximum(v, 1e-3))


def _residuals(params, data, reference: int):
    """Projected residuals (log L eliminated as the weighted mean) and prior rows."""
    n_frames = data["valid"].shape[1]
    centre, k, log_e, shift = _unpack(params, n_frames, reference)
    # log L(x + δ_j(x)) ≈ log L(x) + ∇log L · δ_j(x): the alignment's residual error
    delta = np.einsum("fab,pb->pfa", shift, data["uv1"])                  # (P, F, 2)
    moved = np.einsum("pca,pfa->pfc", data["grad"], delta)
    m = data["log"] - log_e[None, :, None] - _model_log_v(data, centre, k) - moved
    wv = data["weight"] * data["valid"][..., None]
    level = (wv * m).sum(axis=1) / wv.sum(axis=1)
    res = np.sqrt(wv) * (m - level[:, None, :])
    prior = np.concatenate([centre / PRIOR_SIGMA_CENTRE, k.ravel() / PRIOR_SIGMA_K,
                            params[11 + n_frames - 1:] / PRIOR_SIGMA_SHIFT])
    return np.concatenate([res[data["valid"]].ravel(), prior])


def _jacobian(params, data, reference: int):
    """The Jacobian of :func:`_residuals`, analytic: the projection of ``∂m/∂θ``."""
    n_frames = data["valid"].shape[1]
    centre, k, _, _ = _unpack(params, n_frames, reference)
    h, w = data["shape"]
    half_diagonal = 0.5 * math.hypot(h, w)
    u = (data["xs"] - 0.5 * (w - 1)) / half_diagonal - centre[0]
    v = (data["ys"] - 0.5 * (h - 1)) / half_diagonal - centre[1]
    r2 = (u * u + v * v)[..., None]                                        # (P, F, 1)
    value = np.maximum(radial_falloff(np.sqrt(r2), k), 1e-3)               # (P, F, 3)
    d_r2 = (k[:, 0] + 2 * k[:, 1] * r2 + 3 * k[:, 2] * r2 ** 2) / value
    n_p = params.size
    dm = np.zeros(data["log"].shape + (n_p,))                              # (P, F, 3, n)
    dm[..., 0] = 2 * u[..., None] * d_r2
    dm[..., 1] = 2 * v[..., None] * d_r2
    for c in range(3):
        for n in range(3):
            dm[:, :, c, 2 + 3 * c + n] = -(r2[..., 0] ** (n + 1)) / value[..., c]
    others = np.flatnonzero(np.arange(n_frames) != reference)
    for i, j in enumerate(others):
        dm[:, j, :, 11 + i] = -1.0
        base = 11 + n_frames - 1 + 6 * i
        for a in range(2):
            for b in range(3):
                dm[:, j, :, base + 3 * a + b] = -data["grad"][:, :, a] * data["uv1"][:, b, None]
    wv = data["weight"] * data["valid"][..., None]
    level = (wv[..., None] * dm).sum(axis=1) / wv.sum(axis=1)[..., None]
    jac = np.sqrt(wv)[..., None] * (dm - level[:, None])
    prior = np.diag(np.concatenate([np.full(2, 1 / PRIOR_SIGMA_CENTRE),
                                    np.full(9, 1 / PRIOR_SIGMA_K), np.zeros(n_frames - 1),
                                    np.full(6 * (n_frames - 1), 1 / PRIOR_SIGMA_SHIFT)]))
    prior = prior[np.r_[0:11, 11 + n_frames - 1:n_p]]
    return np.concatenate([jac[data["valid"]].reshape(-1, n_p), prior])


def fit_vignetting(data: dict, reference: int, log_exposures0) -> VignettingFit:
    """Fit [Goldman2010] Eq. 1-4 (log domain, ``log L`` projected out) by Gauss-Newton
    with a Huber loss; the covariance is ``σ² (JᵀJ)⁻¹`` with the robust-weighted Jacobian
    and residual variance ``σ²`` (``log L``'s degrees of freedom counted).

    ``data`` is :func:`correspondences`' output; ``log_exposures0`` starts the exposures
    (the response fit's), the reference frame's held at 0.
    """
    from scipy.optimize import least_squares

    n_frames = data["valid"].shape[1]
    others = np.arange(n_frames) != reference
    x0 = np.concatenate([np.zeros(11), (np.asarray(log_exposures0, np.float64)
                                         - log_exposures0[reference])[others],
                         np.zeros(6 * (n_frames - 1))])
    plain = least_squares(_residuals, x0, jac=_jacobian, args=(data, reference),
                          method="trf", x_scale="jac")
    n_obs = int(data["valid"].sum() * 3)
    scale = 1.4826 * float(np.median(np.abs(plain.fun[:n_obs]))) or 1.0
    fit = least_squares(_residuals, plain.x, jac=_jacobian, args=(data, reference),
                        method="trf", loss="huber", f_scale=HUBER_K * scale, x_scale="jac")
    r = fit.fun[:n_obs]
    w = np.minimum(1.0, HUBER_K * scale / np.maximum(np.abs(r), 1e-12))
    dof = max(1.0, float(w.sum()) - fit.x.size - 3 * data["valid"].shape[0])
    sigma2 = float((w * r ** 2).sum()) / dof
    jac = np.asarray(fit.jac)
    cov = np.linalg.pinv(jac.T @ jac) * sigma2
    centre, k, log_e, _ = _unpack(fit.x, n_frames, reference)
    h, w_ = data["shape"]
    vig = Vignetting(k, centre, source="self", covariance=cov[:11, :11], aspect=w_ / h)
    corner = vig.log_sigma_at(h, w_, np.array([0.0, w_ - 1.0, 0.0, w_ - 1.0]),
                              np.array([0.0, 0.0, h - 1.0, h - 1.0]))
    # the residual in log units: the weighted residuals back on the log scale
    wv = (data["weight"] * data["valid"][..., None])[data["valid"]].ravel()
    rms_log = float(np.sqrt(np.median((r / np.sqrt(wv)) ** 2)) * 1.4826)
    return VignettingFit(vignetting=vig, log_exposures=log_e,
                         corner_log_sigma=float(corner.max()),
                         points=int(data["valid"].shape[0]), residual=rms_log)


def correct_frames(frames, transforms, vignetting: Vignetting, intensity, inverse,
                   max_code: int, seed: int = 0) -> list:
    """Each aligned frame's codes moved by ``V(x) / V(H_j x)`` through the curve (ours).

    The codes become ``f(f⁻¹(B) · V(x) / V(H_j x))`` (dithered by ``U(−½, ½)`` before
    rounding, seeded), so that every frame carries the reference frame's falloff ``V(x)``;
    codes within :data:`CODE_MARGIN` of the ends (clipped, or outside the frame) are kept.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 3603]))
    h, w = frames[0].shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    log_v_ref = np.log(np.maximum(vignetting.at(h, w, xs, ys), 1e-3))
    pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    margin = CODE_MARGIN * max_code / 255.0
    out = []
    for frame, t in zip(frames, transforms):
        q = np.asarray(t, np.float64) @ pts
        px, py = (q[0] / q[2]).reshape(h, w), (q[1] / q[2]).reshape(h, w)
        ratio = np.exp(log_v_ref - np.log(np.maximum(vignetting.at(h, w, px, py), 1e-3)))
        codes = frame.astype(np.float64)
        new = np.empty_like(codes)
        for c in range(3):
            lin = np.interp(codes[..., c] / max_code, intensity, inverse[:, c]) * ratio[..., c]
            new[..., c] = np.interp(lin, inverse[:, c], intensity) * max_code
        new = np.round(new + rng.uniform(-0.5, 0.5, new.shape))
        keep = (codes <= margin) | (codes >= max_code - margin)
        new = np.where(keep, codes, np.clip(new, 0, max_code))
        out.append(new.astype(frame.dtype))
    return out


def _log_grey_corrected(frame, vignetting: Vignetting, intensity, inverse, max_code: int):
    """``log`` of the grey ``f⁻¹(B) / V(p)`` of an unaligned frame (float32), and the
    log range its unclipped codes span once divided by ``V``."""
    cv2 = import_cv2()
    h, w = frame.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    v = np.maximum(vignetting.at(h, w, xs, ys), 1e-3)
    codes = frame.astype(np.float64) / max_code
    lin = np.stack([np.interp(codes[..., c], intensity, inverse[:, c]) / v[..., c]
                    for c in range(3)], axis=-1)
    grey = cv2.cvtColor(np.ascontiguousarray(lin, dtype=np.float32), cv2.COLOR_RGB2GRAY)
    margin = CODE_MARGIN / 255.0
    lo = float(np.max([np.interp(margin, intensity, inverse[:, c]) for c in range(3)]))
    hi = float(np.min([np.interp(1 - margin, intensity, inverse[:, c]) for c in range(3)]))
    lo = math.log(max(lo, 1e-6)) - float(np.log(v.min()))
    return np.log(np.maximum(grey, 1e-6)).astype(np.float32), lo, math.log(max(hi, 1e-6))


def realign(originals, shape, transforms, reference: int, fit: VignettingFit, model) -> list:
    """The homographies refined by ECC on the frames' log radiance with the fitted
    vignetting divided out (ours: the falloff, different in each frame at a scene point,
    biases ECC on the raw frames); a frame where ECC fails keeps its homography."""
    from ..stack.align import refine_homography

    cv2 = import_cv2()
    h, w = shape
    logs = []
    for j, im in enumerate(originals):
        im = np.asarray(im)
        if im.shape[:2] != (h, w):
            im = cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)
        g, lo, hi = _log_grey_corrected(im, fit.vignetting, model.intensity, model.inverse,
                                        model.max_code)
        e = float(fit.log_exposures[j])
        logs.append((g - np.float32(e), lo - e, hi - e))
    t, tlo, thi = logs[reference]
    out = []
    for j, (g, glo, ghi) in enumerate(logs):
        a, b = max(glo, tlo), min(ghi, thi)
        new = None if j == reference or a >= b else refine_homography(
            np.clip(t, a, b), np.clip(g, a, b), np.asarray(transforms[j], np.float64))
        out.append(np.asarray(transforms[j], np.float64) if new is None else new)
    return out


def not_observable(reason: str, motion=None) -> dict:
    """``model.diagnostics["vignetting"]`` when nothing was fitted."""
    return {"observable": False, "reason": reason,
            "motion": None if motion is None else [round(m, 5) for m in motion]}


def single_exposure(times) -> bool:
    """All frames' times known and equal (a panorama): Eq. 8 has nothing to fit."""
    known = [t for t in times if t is not None]
    return len(known) == len(times) and max(known) / min(known) < 1.0001


def wide_alignment(images, reference: int, seed: int = 0, min_inliers: int = 40) -> list:
    """Reference→frame homographies for frames that moved far (a panorama), by ORB
    features matched both ways and RANSAC (``cv2.findHomography``, seeded); None for a
    frame with fewer than ``min_inliers`` inliers.  (The bracket alignment,
    :func:`selfcal.stack.align.estimate_alignment`, refuses motions over 10 %.)"""
    cv2 = import_cv2()
    cv2.setRNGSeed(int(seed))
    grey = [cv2.cvtColor(np.asarray(im, np.uint8), cv2.COLOR_RGB2GRAY) for im in images]
    return [np.eye(3) if j == reference else
            orb_homography(grey[reference], g, threshold=1.5, min_inliers=min_inliers)
            for j, g in enumerate(grey)]


def _panorama_frames(originals, small, reference: int, seed: int):
    """The frames aligned by :func:`wide_alignment` at the working size, and their
    homographies (frames it could not align left out)."""
    from ..stack.align import warp_to_reference

    h, w = small[0].shape[:2]
    images = []
    for im in originals:
        im = np.asarray(im)
        if im.shape[:2] != (h, w):
            import cv2

            im = cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)
        images.append(im)
    transforms = wide_alignment(images, reference, seed)
    keep = [j for j, t in enumerate(transforms) if t is not None]
    return ([warp_to_reference(images[j], transforms[j]) for j in keep],
            [transforms[j] for j in keep], keep.index(reference))


def _warped(images, transforms, shape) -> list:
    """The frames at the working size warped onto the reference by ``transforms``."""
    from ..stack.align import warp_to_reference

    cv2 = import_cv2()
    h, w = shape
    out = []
    for im, t in zip(images, transforms):
        if im.shape[:2] != (h, w):
            im = cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)
        out.append(warp_to_reference(im, t))
    return out


def calibrate_with_vignetting(frames, transforms, times, recalibrate, prior_model, *,
                              reference: int, seed: int = 0, rounds: int | None = None,
                              originals=None, realign_after_first: bool = True):
    """The response and the vignetting of aligned frames, fitted in alternation.

    Parameters
    ----------
    frames : list of numpy.ndarray
        The frames aligned onto the reference (working size).
    transforms : list of numpy.ndarray
        Reference→frame homographies in working pixels.
    times : list of float or None
        The frames' exposure times (seconds; None unknown).
    recalibrate : callable
        ``recalibrate(frames) -> ResponseModel``: the response solve of [Lin2011] Eq. 8.
    prior_model : callable
        ``prior_model(frames) -> ResponseModel``: the PCA prior's mean curve, for frames
        all at one exposure (Eq. 8 then has no exposure change to fit).
    reference : int
    seed : int
    originals : callable, optional
        ``originals() -> list of arrays``, the frames unaligned: frames all at one exposure
        (a panorama) are aligned again from them by :func:`wide_alignment`.
    rounds : int, optional
        Vignetting fits (default :data:`DEFAULT_ROUNDS`) (each followed by a response refit on the corrected frames).
    realign_after_first : bool
        Refine the homographies once, after the first vignetting fit, by ECC on the frames
        with that vignetting divided out (:func:`realign`; needs ``originals``).

    Returns
    -------
    ResponseModel
        ``model.vignetting`` the fit (``None`` when not observable) and
        ``model.diagnostics["vignetting"]`` what happened.
    """
    rounds = DEFAULT_ROUNDS if rounds is None else int(rounds)
    fixed = single_exposure(times)
    model = prior_model(frames) if fixed else recalibrate(frames)
    if fixed and originals is not None:
        frames, transforms, reference = _panorama_frames(originals(), frames, reference, seed)
        if len(frames) < 2:
            return _refused(model, "no frame could be matched to the reference", [0.0])
    h, w = frames[0].shape[:2]
    motion = frame_motion(transforms, (h, w))
    if max(motion) < MIN_MOTION:
        return _refused(model, "the frames did not move enough (largest displacement "
                        f"{max(motion):.1%} of the diagonal, under {MIN_MOTION:.1%})", motion)
    fit, done = None, 0
    for done in range(1, rounds + 1):
        data = correspondences(frames, transforms, model.intensity, model.inverse,
                               model.max_code)
        if data["valid"].shape[0] < MIN_POINTS:
            return _refused(model, f"only {data['valid'].shape[0]} smooth unclipped points "
                            f"are seen in two frames or more (under {MIN_POINTS})", motion)
        # one exposure (a panorama): equal starts, for the frames the alignment kept
        log_e0 = np.zeros(len(frames)) if fixed else np.log(np.where(
            np.isfinite(model.exposures) & (model.exposures > 0), model.exposures, 1.0))
        fit = fit_vignetting(data, reference, log_e0)
        if fit.corner_log_sigma > MAX_CORNER_LOG_SIGMA:
            return _refused(model, "the fit is ill-conditioned (σ of log V at the corner "
                            f"{fit.corner_log_sigma:.2f}, over {MAX_CORNER_LOG_SIGMA})",
                            motion)
        if fixed:
            break
        if done == 1 and originals is not None and realign_after_first:
            images = [np.asarray(im) for im in originals()]
            transforms = realign(images, (h, w), transforms, reference, fit, model)
            frames = _warped(images, transforms, (h, w))
        corrected = correct_frames(frames, transforms, fit.vignetting, model.intensity,
                                   model.inverse, model.max_code, seed=seed + done)
        try:
            model = recalibrate(corrected)
        except CalibrationError:
            break
    assert fit is not None      # rounds >= 1
    vig = fit.vignetting
    implausible = implausible_falloff(vig, h, w)
    if implausible:
        return _refused(model, implausible, motion)
    vig.description = (f"self-calibrated from {len(frames)} frames that moved "
                       f"(up to {max(motion):.1%} of the diagonal)")
    vig.diagnostics = {"points": fit.points, "residual": round(fit.residual, 5),
                       "motion": [round(m, 5) for m in motion], "rounds": done,
                       "corner_log_sigma": round(fit.corner_log_sigma, 5),
                       "log_exposures": [round(float(e), 5) for e in fit.log_exposures],
                       "response": "prior mean" if fixed else "fitted jointly"}
    model.vignetting = vig
    model.diagnostics["vignetting"] = {"observable": True, **vig.diagnostics,
                                       "corner_stops": [round(float(s), 4)
                                                        for s in vig.corner_stops()]}
    return model


def prior_mean_model(frames, times, basis, n_components: int):
    """A ResponseModel whose curve is the PCA prior's mean (Eq. 7 of [Lin2011] with every
    coefficient 0): frames all at one exposure leave Eq. 8 nothing to fit (ours)."""
    from .model import ResponseModel

    coefficients = np.zeros((3, n_components))
    inverse = basis.channel_inverses(coefficients, n_components)
    max_code = 65535 if frames[0].dtype == np.uint16 else 255
    reason = ("all frames at one exposure: the response is the prior's mean curve, not "
              "measured (Eq. 8 needs exposure changes)")
    return ResponseModel(
        intensity=basis.intensity.copy(), inverse=inverse, coefficients=coefficients,
        basis_name=basis.name, exposures=np.array([float(t) for t in times]),
        exposure_times=list(times), sources=[f"array #{k}" for k in range(len(frames))],
        max_code=max_code,
        diagnostics={"warnings": [reason], "verdict": "doubtful", "verdict_reasons": [reason],
                     "response_source": "prior mean", "frames_used": []})


def implausible_falloff(vignetting: Vignetting, height: int, width: int) -> str:
    """Why a fitted falloff is no lens's (darker than :data:`MIN_FALLOFF` or brighter than
    :data:`MAX_BRIGHTENING` somewhere in the frame), or "" when it could be one."""
    ys, xs = np.mgrid[0:height:max(1, height // 32), 0:width:max(1, width // 32)]
    ys = np.concatenate([ys.ravel(), [0, 0, height - 1, height - 1]])
    xs = np.concatenate([xs.ravel(), [0, width - 1, 0, width - 1]])
    v = vignetting.at(height, width, xs.astype(float), ys.astype(float))
    if not np.all(np.isfinite(v)) or v.min() < MIN_FALLOFF:
        return (f"the fitted falloff is implausible (V down to {np.nanmin(v):.3g} in the "
                f"frame, under {MIN_FALLOFF}: more than {-np.log2(MIN_FALLOFF):.0f} stops)")
    if v.max() > MAX_BRIGHTENING:
        return (f"the fitted falloff is implausible (V up to {v.max():.3g}: brighter than "
                "the optical centre)")
    return ""


def _refused(model, reason: str, motion):
    model.vignetting = None
    model.diagnostics["vignetting"] = not_observable(reason, motion)
    model.diagnostics.setdefault("warnings", []).append(
        f"vignetting not observable: {reason}; no vignetting fitted")
    return model
