"""RAW↔rendered registration: where a camera's JPEG lies on its raw (scale and shift).

Cameras' JPEGs are often a little cropped or scaled against what LibRaw decodes from the
raw; the correspondences of the RAW calibration path ([Gong2018] §3; [Lin2011] §6) need
the two aligned.  :func:`register_raw_jpeg` finds an isotropic scale and a shift by a
scale search with phase correlation, then Gauss-Newton (ECC-style, gain and offset free)
at two resolutions, and judges the match by the normalised cross-correlation of
band-passed images.  The method is ours: [Lin2011] §3 extract colour-chart patches "with
simple registration", while selfcal takes any scene.  Sampling the registered pair is
:mod:`selfcal.pipeline.pairs`.

Coordinates are pixel-centre coordinates (pixel ``i`` covers ``[i - 0.5, i + 0.5]``), ``x``
to the right and ``y`` down; a registration maps a rendered-image point to the raw:
``raw_xy = scale * rendered_xy + shift``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io.images import import_cv2
from ..exposure.raw_ratios import check_linear_raw

__all__ = ["Registration", "register_raw_jpeg", "MIN_CORRELATION", "MIN_OVERLAP"]

#: Smallest normalised cross-correlation of band-passed images for a registration to count
#: as a match (``residual = 1 - correlation``).
MIN_CORRELATION = 0.6
#: Smallest fraction of the rendered image that must lie inside the raw.
MIN_OVERLAP = 0.8



@dataclass(frozen=True)
class Registration:
    """Where a rendered image lies on its raw: ``raw_xy = scale * rendered_xy + shift``.

    Attributes
    ----------
    scale : float
        Raw pixels per rendered pixel (isotropic).
    shift : tuple of float
        ``(x, y)`` in raw pixels.
    residual : float
        ``1 - r`` where ``r`` is the normalised cross-correlation of the band-passed
        (difference-of-Gaussians) grey images after alignment, over the overlap: about 0
        to 0.3 for a matching pair, near 1 for different scenes or orientations.
    ok : bool
        ``residual <= 1 - MIN_CORRELATION`` and ``overlap >= MIN_OVERLAP``.
    overlap : float
        Fraction of the rendered image that lies inside the raw.
    raw_shape, rendered_shape : tuple
        ``(H, W)`` of the two images registered.
    """

    scale: float
    shift: tuple
    residual: float
    ok: bool
    overlap: float = 1.0
    raw_shape: tuple = ()
    rendered_shape: tuple = ()

    @classmethod
    def identity(cls, shape) -> "Registration":
        """The registration of two images of the same size that are already aligned."""
        shape = tuple(int(v) for v in shape[:2])
        return cls(1.0, (0.0, 0.0), 0.0, True, 1.0, shape, shape)

    def to_raw(self, xy) -> np.ndarray:
        """Map rendered-image points ``(..., 2)`` (x, y) to raw coordinates."""
        return self.scale * np.asarray(xy, dtype=np.float64) + np.asarray(self.shift)


def as_float_rendered(rendered) -> np.ndarray:
    """Rendered image → float32 in [0, 1] (uint8 / 255, uint16 / 65535, float as is)."""
    img = np.asarray(rendered)
    if img.ndim != 3 or img.shape[2] < 3:
        raise InputError(f"expected an HxWx3 rendered image, got shape {img.shape}")
    img = img[..., :3]
    if img.dtype == np.uint8:
        return img.astype(np.float32) * np.float32(1 / 255)
    if img.dtype == np.uint16:
        return img.astype(np.float32) * np.float32(1 / 65535)
    if np.issubdtype(img.dtype, np.floating):
        out = img.astype(np.float32)
        if not np.all(np.isfinite(out)):
            raise InputError("the rendered image contains NaN or infinite values")
        return out
    raise InputError(f"unsupported rendered image type {img.dtype} (uint8, uint16 or float)")


def _grey_raw(raw: np.ndarray) -> np.ndarray:
    """A display-like grey image of a linear raw: grey-world balance, 99th-percentile white,
    gamma 1/2.2 -- close enough to a camera rendering for correlation-based alignment."""
    step = max(1, int(math.sqrt(raw.shape[0] * raw.shape[1] / 250_000)))
    sub = raw[::step, ::step].reshape(-1, 3).astype(np.float32)
    med = np.maximum(np.median(sub, axis=0), 1e-6)
    grey = (raw.astype(np.float32) / med.astype(np.float32)).mean(axis=2)
    top = float(np.percentile(grey[::step, ::step], 99.0))
    grey = np.clip(grey / max(top, 1e-6), 0.0, 1.0)
    return np.power(grey, np.float32(1 / 2.2), dtype=np.float32)


def _grey_rendered(rendered: np.ndarray) -> np.ndarray:
    return as_float_rendered(rendered).mean(axis=2)


@dataclass
class _Level:
    jpg: np.ndarray
    raw: np.ndarray
    aj: tuple      # (ax, ay) full-res rendered px per level px
    ar: tuple      # (ax, ay) full-res raw px per level px


def _resize_to(img: np.ndarray, factor: float):
    cv2 = import_cv2()
    h, w = img.shape[:2]
    nw, nh = max(8, int(round(w / factor))), max(8, int(round(h / factor)))
    if (nw, nh) == (w, h):
        return img.astype(np.float32), (1.0, 1.0)
    out = cv2.resize(img.astype(np.float32), (nw, nh), interpolation=cv2.INTER_AREA)
    return out, (w / nw, h / nh)


def _make_level(jg, rg, max_side, s0):
    f = max(1.0, max(jg.shape) / float(max_side))
    j, aj = _resize_to(jg, f)
    r, ar = _resize_to(rg, max(1.0, f * s0))
    return _Level(j, r, aj, ar)


def _to_level(s, t, lev: _Level):
    """Full-resolution (s, tx, ty) → per-axis level affine (2x3, inverse map)."""
    m = np.zeros((2, 3), dtype=np.float64)
    for k in range(2):
        aj, ar = lev.aj[k], lev.ar[k]
        m[k, k] = s * aj / ar
        m[k, 2] = (s * (0.5 * aj - 0.5) + t[k] + 0.5) / ar - 0.5
    return m


def _from_level(m, lev: _Level):
    """Per-axis level affine → full-resolution (s, (tx, ty)) with isotropic s."""
    ss = [m[k, k] * lev.ar[k] / lev.aj[k] for k in range(2)]
    s = 0.5 * (ss[0] + ss[1])
    t = tuple(lev.ar[k] * (m[k, 2] + 0.5) - 0.5 - s * (0.5 * lev.aj[k] - 0.5)
              for k in range(2))
    return s, t


def warp_image(img, m, shape, border_value=None):
    cv2 = import_cv2()
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    if border_value is None:
        return cv2.warpAffine(img, m.astype(np.float64), (shape[1], shape[0]), flags=flags,
                              borderMode=cv2.BORDER_REPLICATE)
    return cv2.warpAffine(img, m.astype(np.float64), (shape[1], shape[0]), flags=flags,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=border_value)


def inside_mask(m, raw_shape, shape, margin=0.0):
    """Level pixels of the rendered grid whose raw position lies inside the raw."""
    h, w = shape
    xs = m[0, 0] * np.arange(w) + m[0, 2]
    ys = m[1, 1] * np.arange(h) + m[1, 2]
    okx = (xs >= -0.5 + margin) & (xs <= raw_shape[1] - 0.5 - margin)
    oky = (ys >= -0.5 + margin) & (ys <= raw_shape[0] - 0.5 - margin)
    return oky[:, None] & okx[None, :]


def _coarse_search(lev: _Level, s_lo, s_hi, n_max=48):
    """Scale search with phase correlation at each candidate scale."""
    cv2 = import_cv2()
    h, w = lev.jpg.shape
    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    jh = lev.jpg - lev.jpg.mean()
    rh_, rw_ = lev.raw.shape
    raw_c = ((rw_ * lev.ar[0] - 1) / 2.0, (rh_ * lev.ar[1] - 1) / 2.0)   # full-res centre
    jpg_c = ((w * lev.aj[0] - 1) / 2.0, (h * lev.aj[1] - 1) / 2.0)
    n = int(min(n_max, max(3, math.ceil(math.log(s_hi / s_lo) / math.log(1.006)) + 1)))
    best = None
    for s in np.exp(np.linspace(math.log(s_lo), math.log(s_hi), n)):
        t = (raw_c[0] - s * jpg_c[0], raw_c[1] - s * jpg_c[1])
        m = _to_level(s, t, lev)
        rw = warp_image(lev.raw, m, (h, w))
        (dx, dy), resp = cv2.phaseCorrelate(jh.astype(np.float32),
                                            (rw - rw.mean()).astype(np.float32), window)
        if best is None or resp > best[0]:
            m2 = m.copy()
            m2[0, 2] += m[0, 0] * dx
            m2[1, 2] += m[1, 1] * dy
            best = (resp, m2)
    assert best is not None     # n >= 3 scales were tried
    return _from_level(best[1], lev)


def _line_fit(x, y):
    """Least-squares ``y ≈ a x + b``."""
    mx, my = x.mean(), y.mean()
    vx = float(((x - mx) ** 2).mean())
    a = float(((x - mx) * (y - my)).mean()) / vx if vx > 0 else 0.0
    return a, float(my - a * mx)


def _sample_at(img, px, py):
    """Bilinear samples of ``img`` at float positions (1-D arrays), replicated border."""
    cv2 = import_cv2()
    n = px.size
    cols = 4096   # remap wants maps narrower than SHRT_MAX
    rows = max(1, -(-n // cols))
    mx = np.zeros(rows * cols, dtype=np.float32)
    my = np.zeros(rows * cols, dtype=np.float32)
    mx[:n], my[:n] = px, py
    out = cv2.remap(img, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1)[:n].astype(np.float64)


def _gauss_newton(lev: _Level, s, t, iterations=30, max_points=40_000):
    """Refine (s, t) by Gauss-Newton on ``J ≈ a R(s x + t) + b`` (scale+translation, with a
    photometric gain and offset, as in ECC), over the rendered pixels of strongest
    gradient (and a sparse grid of the others) that map inside the raw."""
    cv2 = import_cv2()
    j = cv2.GaussianBlur(lev.jpg, (0, 0), 1.0)
    r = cv2.GaussianBlur(lev.raw, (0, 0), 1.0)
    gx = cv2.Sobel(r, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gy = cv2.Sobel(r, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    h, w = j.shape
    jgx = cv2.Sobel(j, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    jgy = cv2.Sobel(j, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    mag = np.hypot(jgx, jgy).ravel()
    strong = mag >= np.quantile(mag, 0.7)
    grid = np.zeros((h, w), dtype=bool)
    grid[::3, ::3] = True
    idx = np.flatnonzero(strong | grid.ravel())
    if idx.size > max_points:
        idx = idx[:: int(math.ceil(idx.size / max_points))]
    ys, xs = np.divmod(idx, w)
    xs = xs.astype(np.float64)
    ys = ys.astype(np.float64)
    jv_all = j.ravel()[idx].astype(np.float64)
    kx = (lev.aj[0] / lev.ar[0], (0.5 * lev.aj[0] - 0.5) / lev.ar[0])
    ky = (lev.aj[1] / lev.ar[1], (0.5 * lev.aj[1] - 0.5) / lev.ar[1])
    span = float(max(h, w))
    for _ in range(iterations):
        m = _to_level(s, t, lev)
        px = m[0, 0] * xs + m[0, 2]
        py = m[1, 1] * ys + m[1, 2]
        sel = (px >= 1) & (px <= r.shape[1] - 2) & (py >= 1) & (py <= r.shape[0] - 2)
        if sel.sum() < 64:
            break
        px32, py32 = px[sel].astype(np.float32), py[sel].astype(np.float32)
        rv = _sample_at(r, px32, py32)
        wx = _sample_at(gx, px32, py32)
        wy = _sample_at(gy, px32, py32)
        jv = jv_all[sel]
        # photometric fit first (closed form), then the joint step
        a, b = _line_fit(rv, jv)
        if abs(a) < 1e-9:
            break
        res = jv - a * rv - b
        dsx = wx * (xs[sel] * kx[0] + kx[1]) + wy * (ys[sel] * ky[0] + ky[1])
        jac = np.stack([a * dsx, a * wx / lev.ar[0], a * wy / lev.ar[1], rv,
                        np.ones_like(rv)], axis=1)
        try:
            step = np.linalg.solve(jac.T @ jac + 1e-12 * np.eye(5), jac.T @ res)
        except np.linalg.LinAlgError:
            break
        ds, dtx, dty = step[:3]
        # keep steps sane (the photometric terms are re-fit each iteration)
        lim = 0.5 * max(lev.ar)
        ds = float(np.clip(ds, -0.02 * s, 0.02 * s))
        dtx, dty = float(np.clip(dtx, -lim, lim)), float(np.clip(dty, -lim, lim))
        s += ds
        t = (t[0] + dtx, t[1] + dty)
        # converged when no level pixel moves by more than 0.005 px
        move = (abs(ds) * span * max(kx[0], ky[0]) + abs(dtx) / lev.ar[0]
                + abs(dty) / lev.ar[1])
        if move < 0.005:
            break
    return s, t


def _tone_match(lev: _Level, s, t):
    """A monotone table mapping raw grey to rendered grey by quantile matching."""
    m = _to_level(s, t, lev)
    h, w = lev.jpg.shape
    inside = inside_mask(m, lev.raw.shape, (h, w), margin=1.0)
    if inside.sum() < 256:
        return None
    rw = warp_image(lev.raw, m, (h, w))[inside]
    q = np.linspace(0.0, 1.0, 129)
    rq = np.quantile(rw, q)
    jq = np.quantile(lev.jpg[inside], q)
    keep = np.concatenate([[True], np.diff(rq) > 1e-6])
    if keep.sum() < 8:
        return None
    return rq[keep], np.maximum.accumulate(jq[keep])


def _match_quality(lev: _Level, s, t):
    """(normalised cross-correlation of band-passed images, overlap fraction)."""
    cv2 = import_cv2()
    h, w = lev.jpg.shape
    m = _to_level(s, t, lev)
    inside = inside_mask(m, lev.raw.shape, (h, w))
    overlap = float(inside.mean())
    rw = warp_image(lev.raw, m, (h, w))

    def band(x):
        return cv2.GaussianBlur(x, (0, 0), 1.0) - cv2.GaussianBlur(x, (0, 0), 4.0)

    core = inside_mask(m, lev.raw.shape, (h, w), margin=8.0 * max(1.0, m[0, 0]))
    core[:8], core[-8:], core[:, :8], core[:, -8:] = False, False, False, False
    if core.sum() < 256:
        return 0.0, overlap
    a = band(lev.jpg)[core].astype(np.float64)
    b = band(rw)[core].astype(np.float64)
    a -= a.mean()
    b -= b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return (float(a @ b) / den if den > 0 else 0.0), overlap


def register_raw_jpeg(raw_rgb, rendered, *, scale_range=(0.85, 1.04), coarse_size=320,
                      fine_size=1024, raw_name=None, rendered_name=None,
                      strict: bool = False) -> Registration:
    """Register a rendered (camera JPEG) image on its linear raw: scale and shift.

    Camera JPEGs are often slightly cropped and rescaled against the raw as LibRaw decodes
    it; the correspondences of the RAW path ([Gong2018] §3; [Lin2011] §6) need them aligned.
    Both images are turned into grey images (the raw grey-world balanced and gamma-encoded),
    reduced to about ``coarse_size`` pixels, and a scale search around the size ratio (phase
    correlation at each candidate scale; ``scale_range`` relative to the width and height
    ratios, the low end allowing the JPEG to cover a ~15 % smaller field) gives a start that
    Gauss-Newton refines, ECC-style (gain and offset free; scale and translation only), at
    the coarse level and again at about ``fine_size`` pixels.  The match is judged by the
    normalised cross-correlation of band-passed images (see :class:`Registration`).

    Parameters
    ----------
    raw_rgb : numpy.ndarray
        ``HxWx3`` float linear camera RGB.
    rendered : numpy.ndarray
        ``HxWx3`` uint8/uint16/float rendered RGB.
    scale_range : (float, float)
        Scales searched, relative to the smaller and larger of the width and height ratios.
    coarse_size, fine_size : int
        Longest side (pixels) of the rendered image at the search and final levels.
    raw_name, rendered_name : str, optional
        Names for the error message.
    strict : bool
        Raise :class:`~selfcal.errors.InputError` (naming both files) when the images do
        not match, instead of returning ``ok=False``.

    Returns
    -------
    Registration
    """
    raw = check_linear_raw(raw_rgb)
    ren = np.asarray(rendered)
    if ren.ndim != 3 or ren.shape[2] < 3:
        raise InputError(f"expected an HxWx3 rendered image, got shape {ren.shape}",
                         rendered_name)
    jg = _grey_rendered(ren)
    rg = _grey_raw(raw)
    hj, wj = jg.shape
    hr, wr = rg.shape
    ratios = (wr / wj, hr / hj)
    s_lo, s_hi = min(ratios) * scale_range[0], max(ratios) * scale_range[1]
    s0 = math.sqrt(s_lo * s_hi)
    coarse = _make_level(jg, rg, coarse_size, s0)
    s, t = _coarse_search(coarse, s_lo, s_hi)
    s, t = _gauss_newton(coarse, s, t)
    # match the raw grey's tones to the rendering's (histogram specification over the
    # overlap): the rendering is a monotone function of the raw, nearly, so this removes
    # most of the tone difference that would bias the least-squares alignment
    tone = _tone_match(coarse, s, t)
    if tone is not None:
        rg = np.interp(rg, *tone).astype(np.float32)
        coarse = _make_level(jg, rg, coarse_size, s0)
        s, t = _gauss_newton(coarse, s, t)
    fine = coarse
    if max(jg.shape) > coarse_size:
        fine = _make_level(jg, rg, fine_size, s)
        s, t = _gauss_newton(fine, s, t, iterations=20)
    corr, overlap = _match_quality(fine, s, t)
    residual = float(1.0 - corr)
    ok = bool(corr >= MIN_CORRELATION and overlap >= MIN_OVERLAP
              and s_lo * 0.98 <= s <= s_hi * 1.02)
    reg = Registration(float(s), (float(t[0]), float(t[1])), residual, ok, overlap,
                       (hr, wr), (hj, wj))
    if strict and not ok:
        raise InputError(
            f"does not match its raw {raw_name or '(array)'}: after the best scale and "
            f"shift (scale {s:.3f}) the images correlate only {corr:.2f} over "
            f"{100 * overlap:.0f}% overlap (need ≥ {MIN_CORRELATION} over ≥ "
            f"{100 * MIN_OVERLAP:.0f}%) -- a different scene, or a rotated or flipped JPEG?",
            rendered_name)
    return reg
