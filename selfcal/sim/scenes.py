"""Synthetic scenes: linear radiance in camera RGB, with known colours and a known range.

:func:`make_scene` is the test chart of the simulator (patches, texture, ramps); the
procedural outdoor scene of the benchmark conditions is
:func:`selfcal.sim.conditions.natural_scene`, built on the same smooth noise.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["make_scene"]


def _opponent(hue: np.ndarray) -> np.ndarray:
    """Unit chroma directions ``cos(h - 2πi/3)``: sum to zero, components in [-1, 1]."""
    return np.cos(hue[..., None] - np.arange(3) * (2 * np.pi / 3))


def unit_noise(rng, shape, sigma) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    n = gaussian_filter(rng.standard_normal(shape), sigma=sigma, mode="reflect")
    return (n - n.mean()) / (n.std() + 1e-12)


def _chart(shape, rng, dr: float, sat: float) -> tuple:
    """The chart: 4 × 6 flat patches on a dark surround, 18 coloured (shuffled
    luminances over the range, hues round the circle) and a bottom row of 6 greys.
    Returns log2 luminance, hue and chroma of the region."""
    h1, w1 = shape
    log_l, hue, chroma = np.full(shape, -0.55 * dr), np.zeros(shape), np.zeros(shape)
    rows, cols = 4, 6
    n_col = (rows - 1) * cols
    lums = rng.permutation(np.linspace(-dr, 0.0, n_col))
    hues = rng.permutation(np.linspace(0, 2 * np.pi, n_col, endpoint=False))
    hues = hues + rng.uniform(-0.15, 0.15, n_col)
    chromas = sat * rng.uniform(0.35, 1.0, n_col)
    greys = np.linspace(0.0, -dr, cols)
    ys = np.linspace(0, h1, rows + 1).round().astype(int)
    xs = np.linspace(0, w1, cols + 1).round().astype(int)
    gap = max(1, min(h1 // rows, w1 // cols) // 8)
    for r in range(rows):
        for c in range(cols):
            sl = (slice(ys[r] + gap, ys[r + 1] - gap), slice(xs[c] + gap, xs[c + 1] - gap))
            if r < rows - 1:
                i = r * cols + c
                log_l[sl], hue[sl], chroma[sl] = lums[i], hues[i], chromas[i]
            else:
                log_l[sl] = greys[c]
    return log_l, hue, chroma


def _texture(shape, rng, dr: float, sat: float) -> tuple:
    """Band-pass noise in log luminance (≈ ±4 stops), a fine checker, slowly varying hue
    and chroma.  Returns log2 luminance, hue and chroma of the region."""
    th, tw = shape
    yy, xx = np.mgrid[0:th, 0:tw]
    checker = np.sign(np.sin(2 * np.pi * (xx + 0.5) / 8) * np.sin(2 * np.pi * (yy + 0.5) / 8))
    tex = (-0.45 * dr + 1.6 * unit_noise(rng, (th, tw), max(th, tw) / 10)
           + 0.4 * unit_noise(rng, (th, tw), 1.0) + 0.35 * checker)
    log_l = np.clip(tex, -dr, 0.0)
    hue = np.pi * unit_noise(rng, (th, tw), max(th, tw) / 6)
    chroma = sat * 0.7 / (1 + np.exp(-1.5 * unit_noise(rng, (th, tw), 4.0)))
    return log_l, hue, chroma


def _colour_ramps(shape, dr: float, sat: float) -> tuple:
    """Hue (x) × chroma (y) at constant luminance on the left half, hue (x) × luminance
    (y) at chroma ``sat`` on the right.  Returns log2 luminance, hue and chroma."""
    bh, w = shape
    half = w // 2
    log_l, hue, chroma = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    log_l[:, :half] = -0.4 * dr
    hue[:, :half] = np.linspace(0, 2 * np.pi, half, endpoint=False)[None, :]
    chroma[:, :half] = np.linspace(0.0, sat, bh)[:, None]
    log_l[:, half:] = np.linspace(0.0, -dr, bh)[:, None]
    hue[:, half:] = np.linspace(0, 2 * np.pi, w - half, endpoint=False)[None, :]
    chroma[:, half:] = sat
    return log_l, hue, chroma


def make_scene(height: int = 256, width: int = 384, *, dynamic_range_stops: float = 14.0,
               saturation: float = 0.5, seed: int = 0) -> np.ndarray:
    """A synthetic high-dynamic-range scene: linear radiance in camera RGB.

    Layout (fractions of the image):

    * top-left (½ H × ⅔ W): a chart, 4 × 6 flat patches on a dark surround; 18 coloured
      patches with luminances log-spaced over the whole range (shuffled) and hues spread
      round the circle, and a bottom row of 6 greys stepping from white to the darkest
      level (a step wedge);
    * top-right: texture -- band-pass filtered noise in log luminance (≈ ±4 stops), a
      fine checker pattern, and slowly varying hue and chroma;
    * middle strip (⅛ H): a neutral luminance ramp, log-linear over the whole range;
    * bottom-left: hue (x) × chroma (y, 0 → ``saturation``) at constant luminance;
    * bottom-right: hue (x) × luminance (y, white → darkest) at chroma ``saturation``.

    A colour of luminance ``Y``, hue ``h`` and chroma ``s`` is
    ``Y (1 + 0.97 s d(h))`` with ``d_i(h) = cos(h - 2πi/3)`` (mean over channels = ``Y``).

    Parameters
    ----------
    height, width : int
        At least 16 each.
    dynamic_range_stops : float
        The darkest grey (on the ramp) is ``2**-(stops + 0.5)`` of white, so that
        ``max / min >= 2**dynamic_range_stops``.
    saturation : float
        Chroma scale in ``[0, 1]`` for every colour in the scene: 0 gives an all-grey
        scene (neutral patches), 1 highly saturated colours (channel ratios up to ~65:1).
    seed : int
        Patch order, hues and texture are drawn from ``numpy.random.default_rng(seed)``.

    Returns
    -------
    numpy.ndarray
        float32 ``(height, width, 3)``, strictly positive, brightest value exactly 1.
    """
    h, w = int(height), int(width)
    if h < 16 or w < 16:
        raise InputError(f"scene must be at least 16x16 pixels, got {h}x{w}")
    dr = float(dynamic_range_stops)
    if not (np.isfinite(dr) and 0 < dr <= 60):
        raise InputError(f"dynamic_range_stops must be in (0, 60], got {dynamic_range_stops!r}")
    sat = float(saturation)
    if not (0.0 <= sat <= 1.0):
        raise InputError(f"saturation must be in [0, 1], got {saturation!r}")
    rng = np.random.default_rng(seed)
    log_l = np.zeros((h, w))      # log2 luminance relative to white
    hue = np.zeros((h, w))
    chroma = np.zeros((h, w))
    h1, h2, w1 = h // 2, (5 * h) // 8, (2 * w) // 3
    chart, texture = (slice(0, h1), slice(0, w1)), (slice(0, h1), slice(w1, w))
    log_l[chart], hue[chart], chroma[chart] = _chart((h1, w1), rng, dr, sat)
    log_l[texture], hue[texture], chroma[texture] = _texture((h1, w - w1), rng, dr, sat)
    # neutral luminance ramp, log-linear over the whole range (and half a stop more)
    log_l[h1:h2, :] = np.linspace(-dr - 0.5, 0.0, w)[None, :]
    log_l[h2:], hue[h2:], chroma[h2:] = _colour_ramps((h - h2, w), dr, sat)

    rgb = np.exp2(log_l)[..., None] * (1.0 + 0.97 * chroma[..., None] * _opponent(hue))
    rgb /= rgb.max()
    return rgb.astype(np.float32)
