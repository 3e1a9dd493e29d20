"""Display-referred encodings (power laws, sRGB, Rec.709, BT.1886) and published camera
log encodings (S-Log2/3, LogC3, Canon Log, V-Log, F-Log): the ``gamma``, ``srgb``,
``rec709``, ``bt1886`` and log families of :mod:`selfcal.response.curve_family`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ...errors import InputError
from .curve import ResponseCurve, on_range


# --------------------------------------------------------------------------------------
# display-referred encodings
# --------------------------------------------------------------------------------------

def gamma_curve(gamma: float) -> ResponseCurve:
    """Power-law response ``f(E) = E^(1/gamma)``.

    Parameters
    ----------
    gamma : float
        The encoding gamma (2.2 for the classic PC/NTSC encoding); > 0.
    """
    if not gamma > 0:
        raise InputError("gamma must be positive")
    inv = 1.0 / gamma
    return ResponseCurve(f"gamma({gamma:.3g})", "gamma", lambda e: np.power(e, inv))


def srgb_encode(x):
    """The sRGB encoding (IEC 61966-2-1): ``12.92 x`` up to 0.0031308, else
    ``1.055 x**(1/2.4) - 0.055``; float64, the one copy selfcal uses (curves, previews,
    the simulator)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def rec709_encode(x):
    x = np.asarray(x, dtype=np.float64)
    return np.where(x < 0.018, 4.5 * x, 1.099 * np.power(np.maximum(x, 0.018), 0.45) - 0.099)


def srgb_oetf(exposure: float = 1.0) -> ResponseCurve:
    """IEC 61966-2-1 sRGB encoding used over the scene range ``[0, exposure]``.

    Parameters
    ----------
    exposure : float
        The linear value that maps to white, in (0, 1]; smaller values use more of the
        linear segment and give a straighter curve.
    """
    return ResponseCurve(f"srgb(x_max={exposure:.3g})", "srgb", on_range(srgb_encode, exposure))


def rec709_oetf(exposure: float = 1.0) -> ResponseCurve:
    """ITU-R BT.709 OETF (4.5 E below 0.018, ``1.099 E^0.45 - 0.099`` above).

    Parameters
    ----------
    exposure : float
        The linear value that maps to white, in (0, 1].
    """
    return ResponseCurve(f"rec709(x_max={exposure:.3g})", "rec709", on_range(rec709_encode, exposure))


def bt1886_inverse_eotf(black: float = 0.0, exposure: float = 1.0) -> ResponseCurve:
    """Inverse of the ITU-R BT.1886 EOTF ``L = a max(V + b, 0)^2.4`` (white 1, black ``black``).

    Parameters
    ----------
    black : float
        Display black luminance relative to white (``L_B / L_W``), e.g. 0 to 0.01.
    exposure : float
        Scene linear value that maps to white, in (0, 1].
    """
    g = 2.4
    lw, lb = 1.0, float(black)
    a = (lw ** (1 / g) - lb ** (1 / g)) ** g
    b = lb ** (1 / g) / (lw ** (1 / g) - lb ** (1 / g))

    def enc(x):
        lum = lb + (lw - lb) * np.clip(x, 0.0, None)
        return np.power(lum / a, 1 / g) - b

    return ResponseCurve(f"bt1886(black={black:.3g},x_max={exposure:.3g})", "bt1886",
                         on_range(enc, exposure))


# --------------------------------------------------------------------------------------
# camera log encodings (published formulas; x = scene reflectance, 0.18 = mid grey)
# --------------------------------------------------------------------------------------

def _slog2(x):
    # Sony S-Log2: S-Log of x * 155/219, with reflection input x/0.9.
    x = np.asarray(x, dtype=np.float64) * (155.0 / 219.0) / 0.9
    return np.where(x >= 0, 0.432699 * np.log10(np.maximum(x, 0) + 0.037584) + 0.616596 + 0.03,
                    x * 5.0 + 0.030001222851889303)


def _slog3(x):
    x = np.asarray(x, dtype=np.float64)
    return np.where(
        x >= 0.01125,
        (420.0 + np.log10((np.maximum(x, 0.01125) + 0.01) / (0.18 + 0.01)) * 261.5) / 1023.0,
        (x * (171.2102946929 - 95.0) / 0.01125 + 95.0) / 1023.0,
    )


def _logc3(x):
    # ARRI ALEXA LogC (v3), EI 800.
    cut, a, b, c, d, e, f = 0.010591, 5.555556, 0.052272, 0.247190, 0.385537, 5.367655, 0.092809
    x = np.asarray(x, dtype=np.float64)
    return np.where(x > cut, c * np.log10(a * np.maximum(x, cut) + b) + d, e * x + f)


def _clog(x):
    # Canon Log (Cinema EOS, 2011), reflection input x/0.9.
    x = np.asarray(x, dtype=np.float64) / 0.9
    return 0.529136 * np.log10(10.1596 * np.maximum(x, 0) + 1.0) + 0.0730597


def _vlog(x):
    # Panasonic V-Log.
    cut, b, c, d = 0.01, 0.00873, 0.241514, 0.598206
    x = np.asarray(x, dtype=np.float64)
    return np.where(x < cut, 5.6 * x + 0.125, c * np.log10(np.maximum(x, cut) + b) + d)


def _flog(x):
    # Fujifilm F-Log.
    a, b, c, d, e, f, cut = 0.555556, 0.009468, 0.344676, 0.790453, 8.735631, 0.092864, 0.00089
    x = np.asarray(x, dtype=np.float64)
    return np.where(x < cut, e * x + f, c * np.log10(a * np.maximum(x, cut) + b) + d)


LOG_ENCODINGS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "slog2": _slog2,
    "slog3": _slog3,
    "logc3": _logc3,
    "clog": _clog,
    "vlog": _vlog,
    "flog": _flog,
}
"""The published log encodings, by name, as functions of scene reflectance."""


def log_encoding(name: str, x_max: float = 4.0) -> ResponseCurve:
    """A published camera log encoding normalised over the reflectance range ``[0, x_max]``.

    Parameters
    ----------
    name : {"slog2", "slog3", "logc3", "clog", "vlog", "flog"}
        Sony S-Log2 / S-Log3, ARRI LogC3 (EI 800), Canon Log, Panasonic V-Log, Fujifilm
        F-Log.
    x_max : float
        Scene reflectance (0.18 = mid grey) that maps to white.
    """
    try:
        enc = LOG_ENCODINGS[name]
    except KeyError:
        raise InputError(f"unknown log encoding {name!r}; known: {sorted(LOG_ENCODINGS)}") from None
    return ResponseCurve(f"{name}(x_max={x_max:.3g})", name, on_range(enc, x_max))
