"""Drawing members of the family at random, sampling them on grids and inverting them:
what ``scripts/make_response_basis.py`` builds the built-in basis from.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ...errors import InputError
from .curve import ResponseCurve
from .encodings import (LOG_ENCODINGS, bt1886_inverse_eotf, gamma_curve, log_encoding,
                        rec709_oetf, srgb_oetf)
from .film_tone import (aces_fitted, camera_tone_curve, hable, hd_negative, hd_reversal,
                        log_logistic, reinhard)
from .modifiers import (MIN_WHITE_SLOPE, bernstein_monotone, mixture, with_black_crush,
                        with_black_offset, with_linear_toe, with_power, with_soft_shoulder,
                        with_warp, with_white_clip)


# --------------------------------------------------------------------------------------
# random sampling
# --------------------------------------------------------------------------------------

FAMILY_WEIGHTS: dict[str, float] = {
    "gamma": 0.07,
    "display": 0.10,     # srgb / rec709 / bt1886
    "log": 0.08,         # the six log encodings
    "film": 0.22,        # hd_negative / hd_reversal / log_logistic
    "tonemap": 0.10,     # reinhard / hable / aces
    "camera": 0.23,
    "bernstein": 0.08,
    "mixture": 0.12,
}
"""How often each family is drawn by :func:`sample_response_curves`."""


def _loguniform(rng, lo, hi):
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _draw_base(rng: np.random.Generator, family: str) -> ResponseCurve:
    if family == "gamma":
        return gamma_curve(_loguniform(rng, 0.9, 3.2))
    if family == "display":
        kind = rng.choice(["srgb", "rec709", "bt1886"])
        x = _loguniform(rng, 0.1, 1.0)
        if kind == "srgb":
            return srgb_oetf(x)
        if kind == "rec709":
            return rec709_oetf(x)
        return bt1886_inverse_eotf(rng.uniform(0.0, 0.01), x)
    if family == "log":
        name = str(rng.choice(sorted(LOG_ENCODINGS)))
        return log_encoding(name, _loguniform(rng, 0.3, 16.0))
    if family == "film":
        kind = rng.choice(["negative", "reversal", "log_logistic"], p=[0.45, 0.35, 0.20])
        decades = rng.uniform(1.5, 4.0)
        sharp = _loguniform(rng, 1.5, 8.0)
        if kind == "negative":
            toe = rng.uniform(0.0, 0.5 * decades)
            return hd_negative(decades=decades, u_toe=toe,
                               u_shoulder=toe + rng.uniform(0.8, 3.5),
                               gamma_film=rng.uniform(0.45, 1.0), sharpness=sharp,
                               print_contrast=float(rng.choice([0.0, rng.uniform(0.3, 2.0)])))
        if kind == "reversal":
            toe = rng.uniform(0.0, 0.5 * decades)
            return hd_reversal(decades=decades, u_toe=toe,
                               u_shoulder=toe + rng.uniform(1.0, 3.0),
                               gamma_film=rng.uniform(1.2, 2.2), sharpness=sharp,
                               d_range=rng.uniform(2.0, 3.8),
                               scan_gamma=rng.uniform(1.0, 2.6))
        return log_logistic(_loguniform(rng, 0.4, 3.0), _loguniform(rng, 0.03, 3.0))
    if family == "tonemap":
        kind = rng.choice(["reinhard", "hable", "aces"])
        enc = str(rng.choice(["srgb", "gamma"]))
        gam = rng.uniform(1.8, 2.6)
        if kind == "reinhard":
            return reinhard(_loguniform(rng, 1.0, 30.0), encoding=enc, gamma=gam)
        if kind == "hable":
            s = lambda: _loguniform(rng, 0.5, 2.0)  # noqa: E731
            return hable(a=0.15 * s(), b=0.5 * s(), c=0.1 * s(), d=0.2 * s(), e_=0.02 * s(),
                         f_=0.3 * s(), x_max=_loguniform(rng, 1.0, 16.0), encoding=enc, gamma=gam)
        return aces_fitted(_loguniform(rng, 0.5, 16.0), encoding=enc, gamma=gam)
    if family == "camera":
        base = str(rng.choice(["srgb", "rec709", "gamma"]))
        return camera_tone_curve(base, exposure=_loguniform(rng, 0.15, 1.0),
                                 gamma=rng.uniform(1.6, 2.8),
                                 contrast=rng.uniform(0.0, 0.8), centre=rng.uniform(0.3, 0.65),
                                 slope=rng.uniform(3.0, 10.0))
    if family == "bernstein":
        n = int(rng.integers(3, 9))
        inc = rng.dirichlet(np.full(n, rng.uniform(0.5, 3.0)))
        if rng.random() < 0.7:
            inc = np.sort(inc)[::-1]  # decreasing increments: concave, like most responses
        return bernstein_monotone(np.concatenate([[0.0], np.cumsum(inc)]))
    raise InputError(f"unknown family {family!r}")


def modify_randomly(curve: ResponseCurve, rng: np.random.Generator) -> ResponseCurve:
    """Apply the random processing variants described in the module docstring."""
    if rng.random() < 0.25:
        curve = with_black_offset(curve, _loguniform(rng, 1e-4, 0.05))
    if rng.random() < 0.25:
        curve = with_linear_toe(curve, _loguniform(rng, 1e-3, 0.03))
    if rng.random() < 0.35:
        curve = with_soft_shoulder(curve, rng.uniform(0.5, 0.92), _loguniform(rng, 0.3, 4.0),
                                   on=str(rng.choice(["output", "exposure"])))
    if rng.random() < 0.15:
        curve = with_power(curve, output=_loguniform(rng, 0.7, 1.4),
                           exposure=_loguniform(rng, 0.8, 1.25))
    if rng.random() < 0.3:
        k = int(rng.integers(1, 5))
        a = rng.normal(0.0, 0.12, size=k) / np.arange(1, k + 1)
        total = np.sum(np.abs(a))
        if total > 0.6:
            a *= 0.6 / total
        curve = with_warp(curve, a, on=str(rng.choice(["output", "exposure"])))
    if rng.random() < 0.04:
        curve = with_black_crush(curve, _loguniform(rng, 1e-3, 0.02))
    return curve


_CHECK_GRID = np.concatenate([[0.0], np.geomspace(1e-7, 1e-2, 60), np.linspace(0.0, 1.0, 513)[1:]])
_CHECK_GRID.sort()


def _acceptable(curve: ResponseCurve) -> bool:
    with np.errstate(all="ignore"):
        y = curve(_CHECK_GRID)
    return bool(np.all(np.isfinite(y)) and np.all(np.diff(y) >= -1e-9)
                and abs(y[0]) < 1e-9 and abs(y[-1] - 1.0) < 1e-9)


def sample_response_curves(n_curves: int, *, seed: int = 0,
                           weights: dict[str, float] | None = None) -> list[ResponseCurve]:
    """Draw ``n_curves`` random members of the family, deterministically by ``seed``.

    Parameters
    ----------
    n_curves : int
        How many curves.
    seed : int
        Seed of the :class:`numpy.random.Generator`; the same seed gives the same curves.
    weights : dict, optional
        Family probabilities (keys of :data:`FAMILY_WEIGHTS`); default
        :data:`FAMILY_WEIGHTS`.

    Returns
    -------
    list of ResponseCurve
        Normalised, monotone forward curves (draws that fail the monotonicity check are
        redrawn).
    """
    if n_curves < 0:
        raise InputError("n_curves must be non-negative")
    weights = dict(FAMILY_WEIGHTS if weights is None else weights)
    names = sorted(weights)
    p = np.array([weights[k] for k in names], dtype=np.float64)
    p /= p.sum()
    base_names = [k for k in names if k != "mixture"]
    pb = np.array([weights[k] for k in base_names], dtype=np.float64)
    pb /= pb.sum()
    rng = np.random.default_rng(seed)
    out: list[ResponseCurve] = []
    while len(out) < n_curves:
        family = str(rng.choice(names, p=p))
        try:
            if family == "mixture":
                k = int(rng.integers(2, 4))
                parts = [modify_randomly(_draw_base(rng, str(rng.choice(base_names, p=pb))), rng)
                         for _ in range(k)]
                curve = mixture(parts, rng.dirichlet(np.ones(k)))
            else:
                curve = modify_randomly(_draw_base(rng, family), rng)
            curve = with_white_clip(curve, MIN_WHITE_SLOPE)
        except InputError:
            continue
        if _acceptable(curve):
            out.append(curve)
    return out


# --------------------------------------------------------------------------------------
# sampling on grids, inversion
# --------------------------------------------------------------------------------------

def _dense_irradiance() -> np.ndarray:
    e = np.concatenate([[0.0], np.geomspace(1e-10, 1e-2, 3000), np.linspace(0.0, 1.0, 16385)])
    return np.unique(e)


_DENSE = _dense_irradiance()


def evaluate_curves(curves: Sequence[ResponseCurve], irradiance) -> np.ndarray:
    """Sample forward curves on an irradiance grid: array ``(len(curves), len(irradiance))``.

    Values are clipped to [0, 1] and made non-decreasing (removing rounding wiggles).
    """
    e = np.asarray(irradiance, dtype=np.float64)
    out = np.empty((len(curves), e.size))
    with np.errstate(all="ignore"):
        for i, c in enumerate(curves):
            out[i] = c(e)
    return np.clip(out, 0.0, 1.0)


def invert_curve(curve: ResponseCurve, intensity) -> np.ndarray:
    """Inverse response ``f^-1(I) = inf {E : f(E) >= I}`` at the given intensities.

    Computed on a dense irradiance grid (geometric near 0, 16k uniform points) with linear
    interpolation; exact at the ends: ``f^-1(0) = 0`` and ``f^-1(1) = 1``.

    Parameters
    ----------
    curve : ResponseCurve
        A normalised monotone forward curve.
    intensity : array_like
        Normalised intensities in [0, 1].
    """
    i = np.asarray(intensity, dtype=np.float64)
    with np.errstate(all="ignore"):
        y = np.clip(curve(_DENSE), 0.0, 1.0)
    y = np.maximum.accumulate(y)
    # Strictly increasing abscissae for np.interp; on a plateau this picks its left end,
    # i.e. the infimum in the definition above.
    y = y + _DENSE * 1e-12
    y = (y - y[0]) / (y[-1] - y[0])
    inv = np.interp(i, y, _DENSE)
    inv = np.where(i <= 0.0, 0.0, np.where(i >= 1.0, 1.0, inv))
    return inv


def _unit_grid(values, what: str) -> np.ndarray:
    """``values`` as a 1-D float grid in [0, 1] (default 1024 even points), or InputError."""
    g = np.linspace(0.0, 1.0, 1024) if values is None else np.asarray(values, dtype=np.float64)
    if g.ndim != 1 or np.any(g < 0) or np.any(g > 1):
        raise InputError(f"the {what} grid must be a 1-D array in [0, 1]")
    return g


def generate_response_curves(n_curves: int, *, grid=None, seed: int = 0):
    """Generate a database of forward response curves (Grossberg & Nayar's DoRF layout).

    Parameters
    ----------
    n_curves : int
        Number of curves.
    grid : array_like, optional
        Irradiance samples in [0, 1]; default 1024 evenly spaced points, as in DoRF.
    seed : int
        Random seed; the same seed gives the same curves.

    Returns
    -------
    irradiance : ndarray, shape (K,)
    curves : ndarray, shape (n_curves, K)
        Forward responses ``f(E)``, each monotone with ``f(0) = 0``, ``f(1) = 1``.
    """
    e = _unit_grid(grid, "irradiance")
    return e, evaluate_curves(sample_response_curves(n_curves, seed=seed), e)


def generate_inverse_curves(n_curves: int, *, intensity=None, seed: int = 0):
    """Generate inverse responses ``f^-1`` of the family on an intensity grid.

    Parameters
    ----------
    n_curves : int
        Number of curves.
    intensity : array_like, optional
        Intensity samples in [0, 1]; default 1024 evenly spaced points.
    seed : int
        Random seed; the same seed gives the same curves.

    Returns
    -------
    intensity : ndarray, shape (K,)
    inverse : ndarray, shape (n_curves, K)
        ``f^-1(I)`` with ``f^-1(0) = 0`` and ``f^-1(1) = 1``.
    names : list of str
        The curves' descriptions.
    """
    i = _unit_grid(intensity, "intensity")
    curves = sample_response_curves(n_curves, seed=seed)
    inv = np.empty((len(curves), i.size))
    for k, c in enumerate(curves):
        inv[k] = invert_curve(c, i)
    return i, inv, [c.name for c in curves]
