"""Film (Hurter–Driffield negative and reversal, log-logistic), filmic tone mappers
(Reinhard, Hable, ACES) and consumer-camera tone curves: the ``hd_*``, ``log_logistic``,
``reinhard``, ``hable``, ``aces`` and ``camera`` families of
:mod:`selfcal.response.curve_family`.
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from .curve import ResponseCurve, normalised, on_range
from .encodings import rec709_encode, srgb_encode


# --------------------------------------------------------------------------------------
# film
# --------------------------------------------------------------------------------------

def _softplus(x, sharpness):
    return np.logaddexp(0.0, sharpness * x) / sharpness


def _hd_density(e, *, decades, u_toe, u_shoulder, gamma_film, sharpness):
    """Density above fog as a function of normalised exposure (H&D curve).

    ``u = log10(E) + decades`` so that E = 1 sits ``decades`` above E = 10^-decades.
    """
    with np.errstate(divide="ignore"):
        u = np.log10(np.maximum(e, 1e-300)) + decades
    return gamma_film * (_softplus(u - u_toe, sharpness) - _softplus(u - u_shoulder, sharpness))


def hd_negative(*, decades=3.0, u_toe=1.0, u_shoulder=3.5, gamma_film=0.65, sharpness=4.0,
                print_contrast=0.0) -> ResponseCurve:
    """Negative film: brightness grows with the density of a Hurter–Driffield curve.

    ``D(u) = gamma_film * [sp(u - u_toe) - sp(u - u_shoulder)]`` with a soft-plus ``sp`` of
    the given sharpness, ``u`` = log10 exposure; the [0, 1] irradiance range covers
    ``decades`` decades of exposure.  Brightness is ``D`` itself (a scan of the negative,
    inverted) or, with ``print_contrast = k > 0``, ``1 - 10^(-k D)`` (printing-paper
    compression).  Normalised to [0, 1].

    Parameters
    ----------
    decades, u_toe, u_shoulder : float
        Exposure range in decades and toe / shoulder positions in log10 units above
        the bottom of the range.
    gamma_film : float
        Slope of the straight-line portion (0.5–0.7 for colour negative).
    sharpness : float
        How abrupt toe and shoulder are (soft-plus sharpness in 1/decade).
    print_contrast : float
        0 for a plain density scan; > 0 for a print-like compression.
    """
    kw = dict(decades=decades, u_toe=u_toe, u_shoulder=u_shoulder, gamma_film=gamma_film,
              sharpness=sharpness)

    def raw(e):
        d = _hd_density(e, **kw)
        if print_contrast > 0:
            return 1.0 - np.power(10.0, -print_contrast * d)
        return d

    name = (f"hd_negative(dec={decades:.3g},toe={u_toe:.3g},sh={u_shoulder:.3g},"
            f"g={gamma_film:.3g},s={sharpness:.3g},k={print_contrast:.3g})")
    return ResponseCurve(name, "hd_negative", normalised(raw))


def hd_reversal(*, decades=2.5, u_toe=0.6, u_shoulder=2.6, gamma_film=1.6, sharpness=4.0,
                d_range=3.0, scan_gamma=2.2) -> ResponseCurve:
    """Reversal (slide) film read by a scanner: transmittance of a falling H&D curve.

    Density ``D = D_max - min(density rise, d_range)`` falls with exposure; the slide
    transmits ``10^-D``; the scanner encodes transmittance with ``T^(1/scan_gamma)``.
    Normalised to [0, 1].

    Parameters
    ----------
    decades, u_toe, u_shoulder, gamma_film, sharpness : float
        As in :func:`hd_negative` (slide films have ``gamma_film`` about 1.5–2).
    d_range : float
        Density range of the film (``D_max - D_min``), limits the rise.
    scan_gamma : float
        The scanner's encoding gamma (1 = linear scan).
    """
    kw = dict(decades=decades, u_toe=u_toe, u_shoulder=u_shoulder, gamma_film=gamma_film,
              sharpness=sharpness)

    def raw(e):
        rise = _hd_density(e, **kw)
        rise = d_range - _softplus(d_range - rise, sharpness)  # soft cap at d_range
        transmittance = np.power(10.0, rise - d_range)
        return np.power(transmittance, 1.0 / scan_gamma)

    name = (f"hd_reversal(dec={decades:.3g},toe={u_toe:.3g},sh={u_shoulder:.3g},"
            f"g={gamma_film:.3g},s={sharpness:.3g},dr={d_range:.3g},scan={scan_gamma:.3g})")
    return ResponseCurve(name, "hd_reversal", normalised(raw))


def log_logistic(n: float = 1.0, m: float = 0.5) -> ResponseCurve:
    """Sigmoid in log exposure: ``f ∝ E^n / (E^n + m^n)`` (Naka–Rushton form), normalised.

    Parameters
    ----------
    n : float
        Slope in log exposure (> 0).
    m : float
        Half-saturation exposure, relative to the range's top.
    """

    def raw(e):
        p = np.power(np.maximum(e, 0.0) / m, n)
        return p / (1.0 + p)

    return ResponseCurve(f"log_logistic(n={n:.3g},m={m:.3g})", "log_logistic", normalised(raw))


# --------------------------------------------------------------------------------------
# filmic tone mappers (scene-linear -> display-linear), then a display encoding
# --------------------------------------------------------------------------------------

def _display_encode(kind: str, gamma: float = 2.2):
    if kind == "srgb":
        return srgb_encode
    return lambda y: np.power(np.maximum(y, 0.0), 1.0 / gamma)


def reinhard(white: float = 4.0, *, encoding: str = "srgb", gamma: float = 2.2) -> ResponseCurve:
    """Extended Reinhard operator ``L (1 + L / Lw^2) / (1 + L)``, ``L = white * E``, then encoded.

    Parameters
    ----------
    white : float
        The scene value mapped to white (Reinhard et al. 2002, Eq. 4).
    encoding : {"srgb", "gamma"}
        Display encoding of the tone-mapped value.
    gamma : float
        Encoding gamma when ``encoding="gamma"``.
    """
    enc = _display_encode(encoding, gamma)

    def raw(e):
        lum = white * e
        return enc(lum * (1.0 + lum / white ** 2) / (1.0 + lum))

    return ResponseCurve(f"reinhard(w={white:.3g},{encoding},{gamma:.3g})", "reinhard",
                         normalised(raw))


def hable(*, a=0.15, b=0.50, c=0.10, d=0.20, e_=0.02, f_=0.30, x_max=11.2,
          encoding: str = "gamma", gamma: float = 2.2) -> ResponseCurve:
    """Hable's filmic curve ("Uncharted 2") over ``[0, x_max]``, then a display encoding.

    ``F(x) = ((x (a x + c b) + d e) / (x (a x + b) + d f)) - e / f`` (shoulder strength a,
    linear strength b, linear angle c, toe strength d, toe numerator e, denominator f).

    Parameters
    ----------
    a, b, c, d, e_, f_ : float
        Curve parameters (defaults: Hable's published values).
    x_max : float
        Scene value mapped to white (Hable's W = 11.2).
    encoding, gamma
        Display encoding, as in :func:`reinhard`.
    """
    enc = _display_encode(encoding, gamma)

    def curve(x):
        return (x * (a * x + c * b) + d * e_) / (x * (a * x + b) + d * f_) - e_ / f_

    def raw(e):
        return enc(curve(x_max * e) / curve(x_max))

    name = f"hable(a={a:.3g},b={b:.3g},c={c:.3g},d={d:.3g},e={e_:.3g},f={f_:.3g},W={x_max:.3g})"
    return ResponseCurve(name, "hable", normalised(raw))


def aces_fitted(x_max: float = 4.0, *, encoding: str = "srgb", gamma: float = 2.2) -> ResponseCurve:
    """Narkowicz's fit of the ACES RRT+ODT, ``x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)``.

    Parameters
    ----------
    x_max : float
        Scene value mapped to white.
    encoding, gamma
        Display encoding, as in :func:`reinhard`.
    """
    enc = _display_encode(encoding, gamma)

    def raw(e):
        x = x_max * e
        return enc(np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, None))

    return ResponseCurve(f"aces(x_max={x_max:.3g},{encoding})", "aces", normalised(raw))


# --------------------------------------------------------------------------------------
# consumer-camera tone curves, polynomials, mixtures
# --------------------------------------------------------------------------------------

def _s_curve(strength: float, centre: float, slope: float):
    """Contrast curve on [0, 1]: ``y + strength * (logistic(y) - y)``, normalised logistic."""
    lo = 1.0 / (1.0 + np.exp(slope * centre))
    hi = 1.0 / (1.0 + np.exp(-slope * (1.0 - centre)))

    def s(y):
        sig = (1.0 / (1.0 + np.exp(-slope * (y - centre))) - lo) / (hi - lo)
        return y + strength * (sig - y)

    return s


def camera_tone_curve(base: str = "srgb", *, exposure: float = 1.0, gamma: float = 2.2,
                      contrast: float = 0.3, centre: float = 0.45, slope: float = 6.0) -> ResponseCurve:
    """A consumer-camera JPEG curve: base encoding, then a contrast S-curve.

    Parameters
    ----------
    base : {"srgb", "rec709", "gamma"}
        The base encoding, used over ``[0, exposure]``.
    exposure : float
        Linear value mapped to white by the base encoding, in (0, 1].
    gamma : float
        Gamma of the base when ``base="gamma"``.
    contrast : float
        Strength of the S-curve blend, in [0, 1] (0: none).
    centre, slope : float
        Centre (in encoded values) and slope of the logistic S-curve.
    """
    if base == "srgb":
        enc = srgb_encode
    elif base == "rec709":
        enc = rec709_encode
    elif base == "gamma":
        enc = _display_encode("gamma", gamma)
    else:
        raise InputError(f"unknown base encoding {base!r}")
    base_f = on_range(enc, exposure)
    s = _s_curve(contrast, centre, slope)
    name = (f"camera({base},x_max={exposure:.3g},g={gamma:.3g},c={contrast:.3g},"
            f"m={centre:.3g},k={slope:.3g})")
    return ResponseCurve(name, "camera", normalised(lambda e: s(base_f(e))))
