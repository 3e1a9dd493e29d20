"""Monotone polynomials and mixtures, and the modifiers every member may get (toe,
black offset and crush, soft shoulder, powers, warp) and the white clip every member gets
(:mod:`selfcal.response.curve_family`, *White point*).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ...errors import InputError
from .curve import ResponseCurve, normalised


MIN_WHITE_SLOPE = 0.08
"""Smallest relative slope ``d log f / d log E`` a member has at white (:func:`with_white_clip`)."""


def bernstein_monotone(control: Sequence[float] | np.ndarray) -> ResponseCurve:
    """Monotone Bernstein polynomial ``sum_k b_k C(n,k) E^k (1-E)^(n-k)``.

    Parameters
    ----------
    control : sequence of float
        Control values ``b_0 = 0 <= b_1 <= ... <= b_n = 1``; non-decreasing control values
        give a non-decreasing polynomial.
    """
    b = np.asarray(control, dtype=np.float64)
    if b.ndim != 1 or b.size < 2 or np.any(np.diff(b) < 0):
        raise InputError("Bernstein control values must be a non-decreasing sequence")
    n = b.size - 1
    from scipy.special import comb

    binom = comb(n, np.arange(n + 1))

    def raw(e):
        e = np.asarray(e, dtype=np.float64)[..., None]
        k = np.arange(n + 1)
        return np.sum(b * binom * np.power(e, k) * np.power(1.0 - e, n - k), axis=-1)

    return ResponseCurve(f"bernstein({n})", "bernstein", normalised(raw))


def mixture(curves: Sequence[ResponseCurve],
            weights: Sequence[float] | np.ndarray) -> ResponseCurve:
    """Convex mixture ``sum_i w_i f_i`` of normalised curves (weights are renormalised)."""
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (len(curves),) or np.any(w < 0) or w.sum() <= 0:
        raise InputError("mixture weights must be non-negative, one per curve")
    w = w / w.sum()
    fns = [c.function for c in curves]

    def f(e):
        return sum(wi * fi(e) for wi, fi in zip(w, fns))

    name = "mix(" + ",".join(f"{wi:.2f}*{c.name}" for wi, c in zip(w, curves)) + ")"
    return ResponseCurve(name, "mixture", f)


# --------------------------------------------------------------------------------------
# modifiers: toe, shoulder, offsets, warps
# --------------------------------------------------------------------------------------

def with_linear_toe(curve: ResponseCurve, toe: float) -> ResponseCurve:
    """Replace ``f`` below irradiance ``toe`` by the line through 0 and ``(toe, f(toe))``.

    Real encodings are linear near black (sRGB below 0.0031, Rec.709 below 0.018) to limit
    noise gain.
    """
    f = curve.function
    ft = float(f(np.array([toe]))[0])

    def g(e):
        return np.where(e < toe, e * (ft / toe), f(np.maximum(e, toe)))

    return ResponseCurve(f"{curve.name}+toe({toe:.3g})", curve.family, g)


def with_black_offset(curve: ResponseCurve, offset: float) -> ResponseCurve:
    """Flare / black-level subtraction: ``f(δ + (1 - δ) E)`` renormalised.

    Shifting the start of the curve away from its (often infinitely steep) origin makes it
    nearly linear near black, smoothly.
    """
    f = curve.function
    return ResponseCurve(f"{curve.name}+offset({offset:.3g})", curve.family,
                         normalised(lambda e: f(offset + (1.0 - offset) * e)))


def with_black_crush(curve: ResponseCurve, level: float) -> ResponseCurve:
    """A JPEG black point above zero: ``max(f - level, 0) / (1 - level)``."""
    f = curve.function
    return ResponseCurve(f"{curve.name}+crush({level:.3g})", curve.family,
                         lambda e: np.maximum(f(e) - level, 0.0) / (1.0 - level))


def _shoulder_map(knee: float, strength: float):
    """Concave map: identity below ``knee``, exponential roll-off above; h(1) < 1."""

    def h(y):
        t = np.maximum(y - knee, 0.0) / (1.0 - knee)
        roll = (1.0 - np.exp(-strength * t)) / strength
        return np.where(y <= knee, y, knee + (1.0 - knee) * roll)

    return h


def with_soft_shoulder(curve: ResponseCurve, knee: float, strength: float,
                       on: str = "output") -> ResponseCurve:
    """Highlight roll-off: identity below ``knee``, C1 exponential compression above.

    Parameters
    ----------
    knee : float
        Where the roll-off starts, in (0, 1).
    strength : float
        Compression rate above the knee (> 0).
    on : {"output", "exposure"}
        Compress the brightness (a video knee) or the exposure before the curve.
    """
    f = curve.function
    h = _shoulder_map(knee, strength)
    if on == "output":
        raw = lambda e: h(f(e))  # noqa: E731
    elif on == "exposure":
        raw = lambda e: f(h(e) / float(h(np.array(1.0))))  # noqa: E731
    else:
        raise InputError("on must be 'output' or 'exposure'")
    return ResponseCurve(f"{curve.name}+shoulder({knee:.3g},{strength:.3g},{on})", curve.family,
                         normalised(raw))


# Exposures at which the white point is searched for: geometric, 0.2 % steps, from
# 1/1000 of the range up to 1 (a white point lower than that would leave nothing of the curve).
_WHITE_SEARCH = np.geomspace(1e-3, 1.0, 3455)


def with_white_clip(curve: ResponseCurve, min_slope: float = MIN_WHITE_SLOPE) -> ResponseCurve:
    """Put white where a real camera would clip: where ``f`` still has a usable slope.

    The *relative slope* of ``f`` at ``E`` is its local slope over its average slope from
    black, ``f'(E) / (f(E) / E) = d log f / d log E`` (film's "point gamma" of the
    curve).  If it is at least ``min_slope`` at ``E = 1`` the curve is returned unchanged.
    Otherwise white is moved down to the largest exposure ``E_w`` where the relative slope
    still reaches ``min_slope`` and the curve becomes ``f(E_w E) / f(E_w)``: the scene light
    above ``E_w`` is clipped (``f = 1``), as a sensor, an ADC or an 8-bit encoder clips,
    instead of crawling towards white along an asymptote.

    Parameters
    ----------
    min_slope : float
        The smallest relative slope allowed at white, in (0, 1).

    Raises
    ------
    InputError
        If the relative slope stays below ``min_slope`` down to ``E = 0.001``.
    """
    if not 0 < min_slope < 1:
        raise InputError("min_slope must lie in (0, 1)")
    f = curve.function
    with np.errstate(all="ignore"):
        y = f(_WHITE_SEARCH)
        # relative slope on each interval of the search grid
        rel = np.diff(np.log(y)) / np.diff(np.log(_WHITE_SEARCH))
    ok = np.isfinite(rel) & (rel >= min_slope)
    if ok[-1]:
        return curve
    if not ok.any():
        raise InputError("the curve has no usable slope above E = 0.001")
    k = int(np.flatnonzero(ok)[-1]) + 1
    e_w, y_w = float(_WHITE_SEARCH[k]), float(y[k])
    return ResponseCurve(f"{curve.name}+white({e_w:.3g})", curve.family,
                         lambda e: f(e_w * np.asarray(e, dtype=np.float64)) / y_w)


def with_power(curve: ResponseCurve, *, output: float = 1.0, exposure: float = 1.0) -> ResponseCurve:
    """``f(E^exposure)^output``: extra encoding gamma on either side."""
    f = curve.function
    return ResponseCurve(f"{curve.name}+pow({output:.3g},{exposure:.3g})", curve.family,
                         lambda e: np.power(np.clip(f(np.power(e, exposure)), 0.0, None), output))


def _warp(amplitudes):
    a = np.asarray(amplitudes, dtype=np.float64)
    k = np.arange(1, a.size + 1) * np.pi

    def w(y):
        y = np.asarray(y, dtype=np.float64)
        return y + np.sum(a * np.sin(np.multiply.outer(y, k)) / k, axis=-1)

    return w


def with_warp(curve: ResponseCurve, amplitudes: Sequence[float] | np.ndarray,
              on: str = "output") -> ResponseCurve:
    """Smooth monotone perturbation ``w(y) = y + sum_k a_k sin(k pi y) / (k pi)``.

    ``w(0) = 0``, ``w(1) = 1`` and ``w' >= 1 - sum |a_k|``, so the warp is monotone when
    ``sum |a_k| < 1``.

    Parameters
    ----------
    amplitudes : sequence of float
        The ``a_k``; ``sum |a_k|`` must be below 1.
    on : {"output", "exposure"}
        Warp the brightness (``w(f(E))``) or the exposure (``f(w(E))``).
    """
    if np.sum(np.abs(amplitudes)) >= 1:
        raise InputError("warp amplitudes must have sum |a_k| < 1 to stay monotone")
    f = curve.function
    w = _warp(amplitudes)
    g = (lambda e: w(np.clip(f(e), 0.0, 1.0))) if on == "output" else (lambda e: f(w(e)))
    return ResponseCurve(f"{curve.name}+warp({len(amplitudes)},{on})", curve.family, g)
