"""A camera simulator with ground truth: scenes, sensor, in-camera pipeline, stacks.

The simulated camera follows the pipeline model of Gong et al., *Rank-based radiometric
calibration* (paper 000), Eq. 1a::

    P = f(Γ(M ρ))

where ρ is the linear camera raw (here: scene radiance × exposure, with shot and read
noise and black/white clipping), ``M`` a 3×3 colour matrix, ``Γ`` a gamut mapping and
``f`` three per-channel tone curves.  The smooth gamut mapping also moves colours that are
near (not only beyond) the gamut boundary, as Lin, Kim, Süsstrunk & Brown observed in real
cameras (*Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011, §4,
paper 002); that is what makes highly saturated pixels outliers for per-channel response
models, and the simulator reproduces it on purpose.

Everything the calibrators estimate is known here: the true per-channel inverse response,
the true (jittered) exposures, the colour matrix and the linear raws.  Tests, fixtures,
benchmarks and ``selfcal demo`` are built on it.

Examples
--------
>>> from selfcal import sim
>>> stack = sim.demo_stack()
>>> len(stack.images), stack.images[0].dtype
(6, dtype('uint8'))
>>> truth = stack.inverse_response()        # (256, 3) true f^-1 per channel
"""

from __future__ import annotations

import io as _io
import math
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, OutputExistsError
from ..io.images import import_cv2
from ..response.curve_family import srgb_encode

__all__ = [
    "ToneCurve",
    "gamut_clip",
    "gamut_compress",
    "CameraPipeline",
    "random_color_matrix",
    "default_pipeline",
    "UnsharpMask",
    "CHROMA_SUBSAMPLINGS",
    "make_scene",
    "SensorModel",
    "SyntheticStack",
    "simulate_stack",
    "simulate_raw_jpeg_pair",
    "handheld",
    "demo_stack",
    "DEMO_EXPOSURE_TIMES",
]

#: Nominal shutter times of :func:`demo_stack` (seconds), one stop apart (camera-rounded).
DEMO_EXPOSURE_TIMES = (1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8)

# Rec. 709 luma weights: the achromatic coordinate of the gamut mapping (output is sRGB-like).
_LUMA = np.array([0.2126, 0.7152, 0.0722])
_GAMUTS = ("smooth", "clip", "none")

#: JPEG chroma subsamplings :func:`simulate_stack` can write (OpenCV's default is 4:2:0).
CHROMA_SUBSAMPLINGS = ("4:2:0", "4:2:2", "4:4:4")


# --------------------------------------------------------------------------------------
# tone curves
# --------------------------------------------------------------------------------------

def _strictly_increasing(y: np.ndarray, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Add a tiny ramp ``eps * x`` where ``y`` is flat, so that ``f`` has an exact inverse."""
    if np.all(np.diff(y) > 0):
        return y
    # y + eps*x is strictly increasing whenever y is non-decreasing and x strictly increasing;
    # dividing by (1 + eps) keeps f(1) = 1.
    return (y + eps * x) / (1.0 + eps)


class ToneCurve:
    """A monotone increasing tone curve ``f: [0, 1] -> [0, 1]``, ``f(0) = 0``, ``f(1) = 1``.

    The ``f`` of Gong et al., rank-based radiometric calibration, Eq. 1 (one per channel),
    i.e. the camera response function of Lin et al. ICCV 2011, Eq. 1.  It is held as a dense
    table ``(irradiance, brightness)``, both strictly increasing, and evaluated by linear
    interpolation (``numpy.interp``): a piecewise-linear interpolant of a monotone table is
    monotone, and its inverse is exact -- the same table with the axes swapped -- so
    ``inverse(forward(x)) == x`` up to rounding and the "true" inverse response of a
    simulated camera is exactly the inverse of what rendered its images.

    Analytic curves are sampled at 4096 points ``x = t**2`` (``t`` uniform), dense near
    black where display curves are steep.  Build curves with the class methods
    (:meth:`gamma`, :meth:`srgb`, :meth:`rec709`, :meth:`film`, :meth:`from_table`).

    Attributes
    ----------
    name : str
        A short human-readable name.
    kind : str
        ``"gamma"``, ``"srgb"``, ``"rec709"``, ``"film"`` or ``"table"``.
    params : dict
        The parameters of an analytic curve (empty for tables).
    """

    _SAMPLES = 4096

    def __init__(self, irradiance, brightness, name: str = "table", *, kind: str = "table",
                 params: dict | None = None):
        x = np.array(irradiance, dtype=np.float64).ravel()
        y = np.array(brightness, dtype=np.float64).ravel()
        if x.size != y.size or x.size < 2:
            raise InputError("a tone curve table needs two arrays of equal length >= 2")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise InputError("a tone curve table must be finite")
        if not (np.all(np.diff(x) > 0) and np.all(np.diff(y) > 0)):
            raise InputError("a tone curve table must be strictly increasing "
                             "(use ToneCurve.from_table for user tables)")
        if x[0] != 0 or x[-1] != 1 or y[0] != 0 or y[-1] != 1:
            raise InputError("a tone curve table must run from (0, 0) to (1, 1)")
        x.flags.writeable = False
        y.flags.writeable = False
        self._x = x
        self._y = y
        self.name = str(name)
        self.kind = str(kind)
        self.params = dict(params or {})

    # ---- construction ----------------------------------------------------------------

    @classmethod
    def _from_function(cls, fn, name: str, kind: str, params: dict) -> "ToneCurve":
        x = np.linspace(0.0, 1.0, cls._SAMPLES) ** 2
        x[-1] = 1.0
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            y = np.asarray(fn(x), dtype=np.float64)
        y = (y - y[0]) / (y[-1] - y[0])  # normalise: f(0) = 0, f(1) = 1
        y[0], y[-1] = 0.0, 1.0
        y = _strictly_increasing(np.maximum.accumulate(y), x)
        return cls(x, y, name, kind=kind, params=params)

    @classmethod
    def gamma(cls, gamma: float) -> "ToneCurve":
        """Power-law curve ``f(x) = x**(1/gamma)`` (``gamma=2.2`` is the classic display curve).

        Parameters
        ----------
        gamma : float
            Positive exponent; ``gamma > 1`` brightens (concave curve), ``gamma = 1`` is linear.
        """
        g = float(gamma)
        if not (np.isfinite(g) and g > 0):
            raise InputError(f"gamma must be a positive number, got {gamma!r}")
        return cls._from_function(lambda x: x ** (1.0 / g), f"gamma {g:g}", "gamma",
                                  {"gamma": g})

    @classmethod
    def srgb(cls) -> "ToneCurve":
        """The sRGB opto-electronic transfer function (IEC 61966-2-1).

        ``f(x) = 12.92 x`` for ``x <= 0.0031308``, else ``1.055 x**(1/2.4) - 0.055``.
        """
        return cls._from_function(srgb_encode, "srgb", "srgb", {})

    @classmethod
    def rec709(cls) -> "ToneCurve":
        """The ITU-R BT.709 OETF: ``4.5 x`` below β, else ``α x**0.45 - (α - 1)``.

        α = 1.09929682680944, β = 0.018053968510807 (the exact, continuous constants).
        """
        a, b = 1.09929682680944, 0.018053968510807

        def fn(x):
            return np.where(x < b, 4.5 * x, a * x ** 0.45 - (a - 1))

        return cls._from_function(fn, "rec709", "rec709", {})

    @classmethod
    def film(cls, contrast: float = 1.0, toe: float = 0.1, shoulder: float = 0.8,
             exposure: float = 1.0) -> "ToneCurve":
        """A film-like S-curve (S-shaped against log exposure): a toe and a shoulder.

        With ``v = exposure * x`` the curve is built from three strictly increasing steps,
        then normalised to ``f(0) = 0``, ``f(1) = 1``::

            base(v)     = v ** (contrast / 2.2)                  display gamma, scaled slope
            toe(y)      = (1 + toe) y² / (y + toe)               ~ y²/toe in the shadows
            shoulder(z) = z                                      for z <= shoulder
                        = k + (1 - k) tanh((z - k) / (1 - k))    above it (k = shoulder)
            f(x)        = shoulder(toe(base(v))) / shoulder(toe(base(exposure)))

        The shoulder is C¹ at the knee and saturates smoothly (highlight roll-off); the toe
        darkens and compresses the shadows.  Camera response curves (e.g. the DoRF set of
        Grossberg & Nayar) look like this.

        Parameters
        ----------
        contrast : float
            Slope multiplier in log-log terms; ``1`` gives a 1/2.2 gamma before toe/shoulder.
        toe : float
            Toe strength, ``>= 0`` (0: no toe).
        shoulder : float
            Knee of the highlight roll-off in ``(0, 1]`` (1: no shoulder).
        exposure : float
            Input gain ``> 0``; larger values push more of the range into the shoulder.
        """
        c, t, k, e = (float(contrast), float(toe), float(shoulder), float(exposure))
        if not (np.isfinite(c) and c > 0):
            raise InputError(f"film contrast must be > 0, got {contrast!r}")
        if not (np.isfinite(t) and t >= 0):
            raise InputError(f"film toe must be >= 0, got {toe!r}")
        if not (0 < k <= 1):
            raise InputError(f"film shoulder must be in (0, 1], got {shoulder!r}")
        if not (np.isfinite(e) and e > 0):
            raise InputError(f"film exposure must be > 0, got {exposure!r}")

        def fn(x):
            y = (e * x) ** (c / 2.2)
            if t > 0:
                y = (1 + t) * y * y / (y + t)
            if k < 1:
                y = np.where(y > k, k + (1 - k) * np.tanh((y - k) / (1 - k)), y)
            return y

        name = f"film(contrast={c:g}, toe={t:g}, shoulder={k:g}, exposure={e:g})"
        return cls._from_function(fn, name, "film",
                                  {"contrast": c, "toe": t, "shoulder": k, "exposure": e})

    @classmethod
    def from_table(cls, irradiance, brightness, name: str = "table") -> "ToneCurve":
        """A tone curve from a user table, e.g. one DoRF curve (``I`` grid, ``B`` values).

        The table is sorted by irradiance; repeated irradiance values must have equal
        brightness (they are merged).  Flat stretches are made strictly increasing with a
        tiny ramp (``1e-6 * x``) so that the inverse exists.

        Parameters
        ----------
        irradiance, brightness : array_like
            1-D arrays of equal length, spanning ``[0, 1]`` (within 1e-6; the ends are set
            exactly), brightness non-decreasing in irradiance.
        name : str

        Raises
        ------
        InputError
            When the table is not 1-D, has NaNs, does not span ``[0, 1]`` on both axes, or
            is not monotone non-decreasing.
        """
        x = np.asarray(irradiance, dtype=np.float64)
        y = np.asarray(brightness, dtype=np.float64)
        if x.ndim != 1 or y.ndim != 1 or x.size != y.size:
            raise InputError(f"tone curve table {name!r}: irradiance and brightness must be "
                             f"1-D arrays of equal length (got shapes {x.shape}, {y.shape})")
        if x.size < 2:
            raise InputError(f"tone curve table {name!r}: needs at least two samples")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
            raise InputError(f"tone curve table {name!r}: contains NaN or infinite values")
        order = np.argsort(x, kind="stable")
        x, y = x[order], y[order]
        same = np.diff(x) == 0
        if np.any(same):
            if np.any(y[1:][same] != y[:-1][same]):
                raise InputError(f"tone curve table {name!r}: one irradiance value has two "
                                 "different brightness values")
            keep = np.concatenate([[True], ~same])
            x, y = x[keep], y[keep]
        tol = 1e-6
        for label, arr in (("irradiance", x), ("brightness", y)):
            if abs(arr.min()) > tol or abs(arr.max() - 1) > tol:
                raise InputError(f"tone curve table {name!r}: {label} must span [0, 1] "
                                 f"(got [{arr.min():g}, {arr.max():g}]); rescale it first")
        dy = np.diff(y)
        if np.any(dy < 0):
            i = int(np.argmax(dy < 0))
            raise InputError(f"tone curve table {name!r}: brightness is not monotone "
                             f"non-decreasing (drops from {y[i]:g} to {y[i + 1]:g} at "
                             f"irradiance {x[i + 1]:g})")
        if x.size < 2:
            raise InputError(f"tone curve table {name!r}: needs at least two distinct samples")
        x = np.clip(x, 0, 1)
        y = np.clip(y, 0, 1)
        x[0], x[-1], y[0], y[-1] = 0.0, 1.0, 0.0, 1.0
        if np.any(np.diff(x) <= 0) or np.any(np.diff(y) < 0):  # snapping broke the order
            raise InputError(f"tone curve table {name!r}: end samples are out of order")
        y = _strictly_increasing(y, x)
        return cls(x, y, name, kind="table")

    # ---- evaluation ------------------------------------------------------------------

    @property
    def irradiance(self) -> np.ndarray:
        """The table's irradiance (input) samples, read-only."""
        return self._x

    @property
    def brightness(self) -> np.ndarray:
        """The table's brightness (output) samples, read-only."""
        return self._y

    def forward(self, x: np.ndarray) -> np.ndarray:
        """Evaluate ``f(x)`` after clipping ``x`` to ``[0, 1]``; float64, same shape as ``x``."""
        x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
        return np.interp(x, self._x, self._y)

    def inverse(self, y: np.ndarray) -> np.ndarray:
        """Evaluate ``f^-1(y)`` (``y`` clipped to ``[0, 1]``); exact inverse of :meth:`forward`."""
        y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
        return np.interp(y, self._y, self._x)

    __call__ = forward

    # ---- serialisation ---------------------------------------------------------------

    def to_dict(self) -> dict:
        """JSON-serialisable description: the parameters for analytic curves, else the table."""
        d = {"name": self.name, "kind": self.kind}
        if self.kind == "table":
            d["irradiance"] = self._x.tolist()
            d["brightness"] = self._y.tolist()
        else:
            d["params"] = dict(self.params)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ToneCurve":
        """Rebuild a curve from :meth:`to_dict` output."""
        try:
            kind = d["kind"]
            if kind == "table":
                curve = cls.from_table(d["irradiance"], d["brightness"],
                                       name=d.get("name", "table"))
            elif kind == "gamma":
                curve = cls.gamma(d["params"]["gamma"])
            elif kind == "srgb":
                curve = cls.srgb()
            elif kind == "rec709":
                curve = cls.rec709()
            elif kind == "film":
                curve = cls.film(**d["params"])
            else:
                raise InputError(f"unknown tone curve kind {kind!r}")
        except (KeyError, TypeError) as exc:
            raise InputError(f"not a valid tone curve description ({exc!r})") from None
        curve.name = str(d.get("name", curve.name))
        return curve

    def __repr__(self) -> str:
        return f"ToneCurve({self.name!r})"


# --------------------------------------------------------------------------------------
# gamut mapping Γ
# --------------------------------------------------------------------------------------

def gamut_clip(rgb: np.ndarray) -> np.ndarray:
    """Hard gamut mapping: clip each channel to ``[0, 1]`` (Γ of Gong et al., Eq. 1, simplest).

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Colour-corrected linear RGB ``M ρ``.

    Returns
    -------
    numpy.ndarray
        float64, same shape, in ``[0, 1]``.
    """
    return np.clip(np.asarray(rgb, dtype=np.float64), 0.0, 1.0)


def gamut_compress(rgb: np.ndarray, *, knee: float = 0.8, strength: float = 1.0) -> np.ndarray:
    """Smooth gamut mapping Γ: compress saturated colours toward the achromatic axis.

    Real cameras move out-of-gamut colours into the output gamut and, in doing so, also
    move colours *near* the gamut boundary (Lin et al. ICCV 2011 §4, Fig. 5); this is the
    Γ of Gong et al., rank-based radiometric calibration, Eq. 1.  The mapping works at
    constant luma and hue:

    1. ``L = w · rgb`` (Rec. 709 weights), ``c = rgb - L`` (chroma vector, ``w · c = 0``),
       ``L' = clip(L, 0, 1)``.
    2. Relative saturation ``u = max_i(c_i / (1 - L') if c_i > 0, -c_i / L' if c_i < 0)``:
       ``L' + c / u`` is the gamut (cube) boundary, so ``u <= 1`` means in gamut, ``u > 1``
       out of gamut (``u = 0`` on the grey axis).
    3. Soft knee: ``u' = u`` for ``u <= knee``, else
       ``u' = knee + (1 - knee) tanh((u - knee) / (1 - knee))`` (C¹, ``u' < 1``).
       ``strength`` blends with the plain chroma clip ``min(u, 1)``:
       ``u'' = strength u' + (1 - strength) min(u, 1)``.
    4. Output ``L' + (u'' / u) c``, clipped to ``[0, 1]`` against rounding.

    Properties: identity for all colours with ``u <= knee`` (greys and low-saturation
    colours), identity on greys in ``[0, 1]`` (clipped outside: grey highlights are the
    tone curve's business), monotone along the neutral axis, continuous, output in the
    cube.  Bright colours lose chroma as ``L`` approaches 1 (the room to the cube's top
    shrinks): a soft clip of coloured highlights toward white.

    Parameters
    ----------
    rgb : array_like, shape (..., 3)
        Colour-corrected linear RGB ``M ρ``, may lie outside ``[0, 1]³``.
    knee : float
        Relative saturation in ``[0, 1)`` below which colours are untouched.
    strength : float
        In ``[0, 1]``: 1 = the soft compression, 0 = a chroma clip onto the boundary.

    Returns
    -------
    numpy.ndarray
        float64, same shape, in ``[0, 1]``.
    """
    knee = float(knee)
    strength = float(strength)
    if not (0.0 <= knee < 1.0):
        raise InputError(f"gamut knee must be in [0, 1), got {knee!r}")
    if not (0.0 <= strength <= 1.0):
        raise InputError(f"gamut strength must be in [0, 1], got {strength!r}")
    x = np.asarray(rgb, dtype=np.float64)
    if x.shape[-1:] != (3,):
        raise InputError(f"expected RGB data with a last axis of 3, got shape {x.shape}")
    # L = w·x written around G so that a grey gives exactly L = v and c = 0 (no rounding)
    lum = x[..., 1] + _LUMA[0] * (x[..., 0] - x[..., 1]) + _LUMA[2] * (x[..., 2] - x[..., 1])
    c = x - lum[..., None]
    lc = np.clip(lum, 0.0, 1.0)[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.where(c > 0, c / (1.0 - lc), 0.0)    # inf where L' = 1 and c_i > 0
        down = np.where(c < 0, -c / lc, 0.0)         # inf where L' = 0 and c_i < 0
        u = np.maximum(up, down).max(axis=-1)
        t = np.maximum(u - knee, 0.0) / (1.0 - knee)
        soft = np.where(u <= knee, u, knee + (1.0 - knee) * np.tanh(t))
        target = strength * soft + (1.0 - strength) * np.minimum(u, 1.0)
        scale = np.where(u > 0, target / u, 1.0)    # u = inf -> 0: fully desaturated
    scale = np.nan_to_num(scale, nan=0.0)
    return np.clip(lc + scale[..., None] * c, 0.0, 1.0)


# --------------------------------------------------------------------------------------
# the pipeline P = f(Γ(M ρ))
# --------------------------------------------------------------------------------------

def _three_curves(curves) -> tuple:
    if isinstance(curves, ToneCurve):
        return (curves, curves, curves)
    try:
        curves = tuple(curves)
    except TypeError:
        raise InputError("curves must be a ToneCurve or a sequence of three") from None
    if len(curves) != 3 or not all(isinstance(c, ToneCurve) for c in curves):
        raise InputError("curves must be a ToneCurve or a sequence of three ToneCurves")
    return curves


@dataclass(eq=False)
class CameraPipeline:
    """An in-camera rendering pipeline ``P = f(Γ(M ρ))``.

    Gong et al., rank-based radiometric calibration, Eq. 1a: a 3×3 colour matrix ``M``,
    a gamut mapping ``Γ`` and per-channel tone curves ``f``.  With ``white_balance``
    gains ``g`` the colour step is ``M min(g ρ, 1)``: white balance, then the highlight
    clip of raw converters (dcraw's default), so a grey whose green raw channel clipped
    stays white instead of turning magenta; ``M`` is then the colour correction of a
    white-balanced raw.

    Attributes
    ----------
    matrix : numpy.ndarray
        3×3 colour matrix ``M`` (camera RGB, or white-balanced camera RGB when
        ``white_balance`` is set -> output RGB); rows summing to 1 keep white.
    curves : tuple of ToneCurve
        Tone curves for R, G, B (a single curve is used for all three).
    gamut : str
        ``"smooth"`` (:func:`gamut_compress`), ``"clip"`` (:func:`gamut_clip`) or
        ``"none"`` (no mapping; the tone curves still clip their input to ``[0, 1]``,
        so the result equals ``"clip"`` -- kept for symmetry with the papers' models).
    knee, strength : float
        Parameters of the smooth gamut mapping.
    white_balance : numpy.ndarray or None
        Per-channel gains ``g`` (3 positive numbers) applied to the raw, then clipped at 1,
        before ``M``; None (default): no white-balance step.
    """

    matrix: np.ndarray
    curves: tuple
    gamut: str = "smooth"
    knee: float = 0.8
    strength: float = 1.0
    white_balance: np.ndarray | None = None

    def __post_init__(self):
        m = np.array(self.matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise InputError(f"the colour matrix must be a finite 3x3 array, got {m.shape}")
        self.matrix = m
        self.curves = _three_curves(self.curves)
        if self.gamut not in _GAMUTS:
            raise InputError(f"gamut must be one of {_GAMUTS}, got {self.gamut!r}")
        self.knee = float(self.knee)
        self.strength = float(self.strength)
        gamut_compress(np.zeros(3), knee=self.knee, strength=self.strength)  # validates
        if self.white_balance is not None:
            g = np.array(self.white_balance, dtype=np.float64).ravel()
            if g.shape != (3,) or not np.all(np.isfinite(g)) or np.any(g <= 0):
                raise InputError("white_balance must be three positive gains, got "
                                 f"{self.white_balance!r}")
            self.white_balance = g

    def colour_correct(self, raw) -> np.ndarray:
        """``M ρ``, or ``M min(g ρ, 1)`` with white-balance gains ``g``: the input of Γ."""
        raw = np.asarray(raw, dtype=np.float64)
        if self.white_balance is not None:
            raw = np.minimum(raw * self.white_balance, 1.0)
        return raw @ self.matrix.T

    def apply_gamut(self, x) -> np.ndarray:
        """Apply Γ to colour-corrected RGB ``x = M ρ`` (shape ``(..., 3)``)."""
        if self.gamut == "smooth":
            return gamut_compress(x, knee=self.knee, strength=self.strength)
        if self.gamut == "clip":
            return gamut_clip(x)
        return np.asarray(x, dtype=np.float64)

    def render(self, raw: np.ndarray) -> np.ndarray:
        """Render linear camera RGB to output RGB, ``f(Γ(M ρ))``, before quantisation.

        Parameters
        ----------
        raw : array_like, shape (H, W, 3) or (N, 3)
            Linear camera RGB (normally in ``[0, 1]``).

        Returns
        -------
        numpy.ndarray
            float64 in ``[0, 1]``, same shape.
        """
        raw = np.asarray(raw, dtype=np.float64)
        if raw.shape[-1:] != (3,):
            raise InputError(f"expected RGB data with a last axis of 3, got shape {raw.shape}")
        mapped = self.apply_gamut(self.colour_correct(raw))
        out = np.empty_like(mapped)
        for ch, curve in enumerate(self.curves):
            out[..., ch] = curve.forward(mapped[..., ch])
        return out

    def inverse_response(self, codes, max_code: int = 255) -> np.ndarray:
        """The true per-channel inverse response ``f_c^-1(code / max_code)``.

        This is the ground truth for the JPEG-only calibrators (Lin et al. ICCV 2011 §5):
        exact for pixels that Γ leaves alone (low saturation), and ``f^-1(max_code) = 1``.

        Returns
        -------
        numpy.ndarray
            float64, shape ``(len(codes), 3)``.
        """
        y = np.clip(np.asarray(codes, dtype=np.float64).ravel() / float(max_code), 0.0, 1.0)
        return np.stack([c.inverse(y) for c in self.curves], axis=1)

    def to_dict(self) -> dict:
        """JSON-serialisable description (see :meth:`from_dict`)."""
        d = {
            "model": "P = f(Gamma(M rho))",
            "matrix": self.matrix.tolist(),
            "curves": [c.to_dict() for c in self.curves],
            "gamut": self.gamut,
            "knee": self.knee,
            "strength": self.strength,
        }
        if self.white_balance is not None:
            d["white_balance"] = self.white_balance.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "CameraPipeline":
        """Rebuild a pipeline from :meth:`to_dict` output."""
        try:
            return cls(matrix=np.asarray(d["matrix"], dtype=np.float64),
                       curves=tuple(ToneCurve.from_dict(c) for c in d["curves"]),
                       gamut=d.get("gamut", "smooth"), knee=d.get("knee", 0.8),
                       strength=d.get("strength", 1.0),
                       white_balance=d.get("white_balance"))
        except (KeyError, TypeError) as exc:
            raise InputError(f"not a valid camera pipeline description ({exc!r})") from None


def random_color_matrix(seed: int = 0, strength: float = 1.0) -> np.ndarray:
    """A plausible camera-RGB -> sRGB colour matrix ``M`` (Gong et al., Eq. 1).

    Real camera matrices are diagonal-dominant with negative off-diagonal terms (they undo
    the overlap of the sensor's spectral sensitivities) and rows summing to 1 (white stays
    white).  Off-diagonals are drawn from ``-strength * U(0.05, 0.45)``; the diagonal makes
    each row sum to 1, so the matrix is strictly diagonally dominant and invertible.

    Parameters
    ----------
    seed : int
    strength : float
        ``>= 0``; 0 gives the identity.

    Returns
    -------
    numpy.ndarray
        3×3 float64.
    """
    strength = float(strength)
    if not (np.isfinite(strength) and strength >= 0):
        raise InputError(f"matrix strength must be >= 0, got {strength!r}")
    rng = np.random.default_rng(seed)
    m = -strength * rng.uniform(0.05, 0.45, size=(3, 3))
    np.fill_diagonal(m, 0.0)
    np.fill_diagonal(m, 1.0 - m.sum(axis=1))
    return m


def _default_curves() -> tuple:
    # Slightly different film-like curves per channel, as in real cameras (DoRF, Fig. 3 of
    # Lin et al.): a calibrator that ties the channels together would be caught out.
    return (ToneCurve.film(contrast=0.97, toe=0.09, shoulder=0.79, exposure=1.08),
            ToneCurve.film(contrast=1.00, toe=0.10, shoulder=0.80, exposure=1.00),
            ToneCurve.film(contrast=1.03, toe=0.11, shoulder=0.81, exposure=0.95))


def default_pipeline(*, gamut: str = "smooth", curves=None, seed: int = 0) -> CameraPipeline:
    """A plausible camera pipeline ``P = f(Γ(M ρ))`` (Gong et al., Eq. 1).

    Parameters
    ----------
    gamut : str
        ``"smooth"``, ``"clip"`` or ``"none"`` (see :class:`CameraPipeline`).
    curves : ToneCurve or sequence of three, optional
        Default: three slightly different film-like curves (fixed, not seed dependent).
    seed : int
        Seed of the colour matrix (:func:`random_color_matrix`).
    """
    curves = _default_curves() if curves is None else _three_curves(curves)
    return CameraPipeline(matrix=random_color_matrix(seed), curves=curves, gamut=gamut)


# --------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------

def _opponent(hue: np.ndarray) -> np.ndarray:
    """Unit chroma directions ``cos(h - 2πi/3)``: sum to zero, components in [-1, 1]."""
    return np.cos(hue[..., None] - np.arange(3) * (2 * np.pi / 3))


def _unit_noise(rng, shape, sigma) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    n = gaussian_filter(rng.standard_normal(shape), sigma=sigma, mode="reflect")
    return (n - n.mean()) / (n.std() + 1e-12)


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

    # chart
    rows, cols = 4, 6
    n_col = (rows - 1) * cols
    log_l[:h1, :w1] = -0.55 * dr   # surround
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

    # texture
    th, tw = h1, w - w1
    yy, xx = np.mgrid[0:th, 0:tw]
    checker = np.sign(np.sin(2 * np.pi * (xx + 0.5) / 8) * np.sin(2 * np.pi * (yy + 0.5) / 8))
    tex = (-0.45 * dr + 1.6 * _unit_noise(rng, (th, tw), max(th, tw) / 10)
           + 0.4 * _unit_noise(rng, (th, tw), 1.0) + 0.35 * checker)
    log_l[:h1, w1:] = np.clip(tex, -dr, 0.0)
    hue[:h1, w1:] = np.pi * _unit_noise(rng, (th, tw), max(th, tw) / 6)
    chroma[:h1, w1:] = sat * 0.7 / (1 + np.exp(-1.5 * _unit_noise(rng, (th, tw), 4.0)))

    # neutral luminance ramp, log-linear over the whole range (and half a stop more)
    log_l[h1:h2, :] = np.linspace(-dr - 0.5, 0.0, w)[None, :]

    # hue x chroma and hue x luminance ramps
    bh, half = h - h2, w // 2
    log_l[h2:, :half] = -0.4 * dr
    hue[h2:, :half] = np.linspace(0, 2 * np.pi, half, endpoint=False)[None, :]
    chroma[h2:, :half] = np.linspace(0.0, sat, bh)[:, None]
    log_l[h2:, half:] = np.linspace(0.0, -dr, bh)[:, None]
    hue[h2:, half:] = np.linspace(0, 2 * np.pi, w - half, endpoint=False)[None, :]
    chroma[h2:, half:] = sat

    rgb = np.exp2(log_l)[..., None] * (1.0 + 0.97 * chroma[..., None] * _opponent(hue))
    rgb /= rgb.max()
    return rgb.astype(np.float32)


# --------------------------------------------------------------------------------------
# sensor
# --------------------------------------------------------------------------------------

@dataclass
class SensorModel:
    """A linear sensor: shot noise, read noise, black level, white clipping.

    Attributes
    ----------
    full_well_electrons : float
        Electrons at white; shot noise is Poisson in electrons.  ``inf`` or ``<= 0`` turns
        shot noise off.
    read_noise : float
        Standard deviation of additive Gaussian read noise, as a fraction of white.
    black_level : float
        Fraction of white subtracted after noise (a mis-set black point crushes shadows);
        the output is ``clip(signal + noise - black_level, 0, 1)``.
    """

    full_well_electrons: float = 20000.0
    read_noise: float = 0.0005
    black_level: float = 0.0

    def __post_init__(self):
        if not (self.read_noise >= 0 and np.isfinite(self.read_noise)):
            raise InputError(f"read_noise must be >= 0, got {self.read_noise!r}")
        if not (0 <= self.black_level < 1):
            raise InputError(f"black_level must be in [0, 1), got {self.black_level!r}")

    @classmethod
    def ideal(cls) -> "SensorModel":
        """A noise-free sensor (only white clipping)."""
        return cls(full_well_electrons=float("inf"), read_noise=0.0, black_level=0.0)

    @property
    def shot_noise(self) -> bool:
        fw = self.full_well_electrons
        return bool(np.isfinite(fw) and fw > 0)

    def expose(self, radiance: np.ndarray, exposure: float,
               rng: np.random.Generator) -> np.ndarray:
        """Expose the sensor: the linear raw ``clip(radiance * exposure + noise - black, 0, 1)``.

        Parameters
        ----------
        radiance : array_like
            Scene radiance (camera RGB).
        exposure : float
            Radiance-to-signal factor (``exposure_scale * time``); signal 1 is white.
        rng : numpy.random.Generator

        Returns
        -------
        numpy.ndarray
            float32 in ``[0, 1]``, same shape as ``radiance``.
        """
        exposure = float(exposure)
        if not (np.isfinite(exposure) and exposure > 0):
            raise InputError(f"exposure must be a positive number, got {exposure!r}")
        signal = np.asarray(radiance, dtype=np.float64) * exposure
        if self.shot_noise:
            fw = float(self.full_well_electrons)
            # above 2x white the result clips anyway; bounding λ keeps Poisson cheap
            signal = rng.poisson(np.clip(signal, 0.0, 2.0) * fw) / fw
        if self.read_noise > 0:
            signal = signal + rng.normal(0.0, self.read_noise, size=signal.shape)
        return np.clip(signal - self.black_level, 0.0, 1.0).astype(np.float32)


# --------------------------------------------------------------------------------------
# stacks
# --------------------------------------------------------------------------------------

def _decode_jpeg(data: bytes) -> np.ndarray:
    # the same decoder and flags as selfcal.io.read_image, so files decode to `images`
    cv2 = import_cv2()
    bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8),
                       cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _jpeg_round_trip(codes: np.ndarray, quality: int,
                     chroma_subsampling: str = "4:2:0") -> tuple[np.ndarray, bytes]:
    """JPEG-encode ``codes`` with OpenCV (libjpeg) and decode them again.

    4:2:0 is OpenCV's default (``selfcal.io.encode_image``); the other subsamplings set
    ``IMWRITE_JPEG_SAMPLING_FACTOR``.
    """
    if chroma_subsampling == "4:2:0":
        from ..io.images import encode_image

        data = encode_image(codes, ".jpg", jpeg_quality=int(quality))
        return _decode_jpeg(data), data
    cv2 = import_cv2()
    factor = {"4:2:2": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
              "4:4:4": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444}[chroma_subsampling]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(codes[:, :, ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality),
                            cv2.IMWRITE_JPEG_SAMPLING_FACTOR, int(factor)])
    if not ok:
        raise InputError("OpenCV could not encode the frame as JPEG")
    data = buf.tobytes()
    return _decode_jpeg(data), data


@dataclass(frozen=True)
class UnsharpMask:
    """In-camera sharpening: an unsharp mask on the luma of the rendered image.

    ``Y = w · P`` (Rec. 709 weights) of the rendered, gamma-encoded image ``P`` in
    ``[0, 1]``; ``P' = clip(P + amount (Y - G_σ * Y), 0, 1)`` with ``G_σ`` a Gaussian
    blur -- the same detail added to R, G and B, i.e. sharpening of the luma channel
    only, as cameras do before JPEG (ours: the simulator's stand-in for them; there is
    no threshold).  It overshoots at edges, and its halos are not a per-pixel function
    of exposure: a per-pixel response model cannot explain them.

    Attributes
    ----------
    amount : float
        ``>= 0`` (0: off; 0.5-1 is a typical camera setting).
    sigma : float
        Blur radius in pixels, ``> 0``.
    """

    amount: float = 0.8
    sigma: float = 1.0

    def __post_init__(self):
        if not (np.isfinite(self.amount) and self.amount >= 0):
            raise InputError(f"sharpening amount must be >= 0, got {self.amount!r}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(f"sharpening sigma must be > 0, got {self.sigma!r}")

    def apply(self, rendered: np.ndarray) -> np.ndarray:
        """Sharpen ``HxWx3`` rendered values in ``[0, 1]``; float64, clipped to ``[0, 1]``."""
        from scipy.ndimage import gaussian_filter

        p = np.asarray(rendered, dtype=np.float64)
        if p.ndim != 3 or p.shape[2] != 3:
            raise InputError(f"sharpening needs an HxWx3 image, got shape {p.shape}")
        y = p @ _LUMA
        detail = self.amount * (y - gaussian_filter(y, self.sigma, mode="reflect"))
        return np.clip(p + detail[..., None], 0.0, 1.0)


def _png_with_exif(png: bytes, exif: bytes) -> bytes:
    """Insert an ``eXIf`` chunk (TIFF-structured EXIF) right after the PNG's IHDR chunk."""
    if exif.startswith(b"Exif\x00\x00"):
        exif = exif[6:]
    ihdr_len = struct.unpack(">I", png[8:12])[0]
    at = 8 + 12 + ihdr_len
    chunk = (struct.pack(">I", len(exif)) + b"eXIf" + exif
             + struct.pack(">I", zlib.crc32(b"eXIf" + exif) & 0xFFFFFFFF))
    return png[:at] + chunk + png[at:]


def _rational(x: float, max_den: int = 1_000_000) -> tuple[int, int]:
    from fractions import Fraction

    fr = Fraction(float(x)).limit_denominator(max_den)
    return fr.numerator, fr.denominator


def _tiff_with_exif_tags(image: np.ndarray, time, f_number, iso) -> bytes:
    """16/8-bit RGB TIFF with ExposureTime, FNumber, ISO in IFD0 (as TIFF/EP and DNG do)."""
    import tifffile

    tags = []
    if time is not None:
        tags.append((33434, 5, 1, _rational(time), False))          # ExposureTime
    if f_number is not None:
        tags.append((33437, 5, 1, _rational(f_number, 100), False))  # FNumber
    if iso is not None:
        tags.append((34855, 3, 1, int(round(iso)), False))         # ISOSpeedRatings
    out = _io.BytesIO()
    tifffile.imwrite(out, image, photometric="rgb", extratags=tags)
    return out.getvalue()


def _refuse_existing(paths, force: bool) -> None:
    """OutputExistsError for the first of ``paths`` that exists, unless ``force``."""
    for p in paths if not force else ():
        if p.exists():
            raise OutputExistsError(f"{p}: exists already (use --force to overwrite)")


@dataclass(eq=False)
class SyntheticStack:
    """A simulated bracketed exposure stack with its ground truth.

    Attributes
    ----------
    images : list of numpy.ndarray
        ``HxWx3`` RGB frames, uint8 (after the JPEG round trip when JPEG was on) or uint16.
    exposure_times : numpy.ndarray
        Nominal shutter times in seconds (what EXIF says), one per frame, ascending.
    true_exposures : numpy.ndarray
        Actual shutter times after jitter (what the sensor got), seconds.
    radiance : numpy.ndarray
        The scene (linear camera RGB).
    raws : list of numpy.ndarray
        float32 linear raw per frame in ``[0, 1]``, after noise and clipping.
    pipeline : CameraPipeline
    bit_depth : int
        8 or 16.
    exposure_scale : float
        ``radiance * exposure_scale * true_exposure`` is the sensor signal (1 = white).
    seed : int
    jpeg_quality : int or None
        JPEG quality of the frames (None: no JPEG).
    jitter : float
        Relative shutter jitter used.
    f_number, iso : float
        Written to EXIF by :meth:`write`.
    chroma_subsampling : str or None
        JPEG chroma subsampling of the frames (None: no JPEG).
    sharpening : UnsharpMask or None
        In-camera sharpening applied before quantisation and JPEG.
    condition : str or None
        Name of the benchmark condition that made the stack
        (:mod:`selfcal.sim.conditions`), else None.
    params : dict
        What a condition drew from its seed (JPEG quality, gains, ...), for reports.
    """

    images: list
    exposure_times: np.ndarray
    true_exposures: np.ndarray
    radiance: np.ndarray
    raws: list
    pipeline: CameraPipeline
    bit_depth: int
    exposure_scale: float
    seed: int
    jpeg_quality: int | None = None
    jitter: float = 0.0
    f_number: float = 8.0
    iso: float = 100.0
    _encoded: list | None = field(default=None, repr=False)
    chroma_subsampling: str | None = None
    sharpening: UnsharpMask | None = None
    condition: str | None = None
    params: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.images)

    @property
    def max_code(self) -> int:
        """The largest code value: 255 or 65535."""
        return 255 if self.bit_depth == 8 else 65535

    def inverse_response(self, codes=None) -> np.ndarray:
        """The true inverse response at ``codes`` (default: all codes ``0..max_code``).

        Returns
        -------
        numpy.ndarray
            ``(n, 3)`` float64, ``f_c^-1(code / max_code)`` (see
            :meth:`CameraPipeline.inverse_response`).
        """
        if codes is None:
            codes = np.arange(self.max_code + 1)
        return self.pipeline.inverse_response(codes, self.max_code)

    def write(self, folder, *, fmt: str = "jpg", jpeg_quality: int = 95, force: bool = False,
              prefix: str = "frame") -> list[Path]:
        """Write the frames as image files with their nominal exposure data.

        Files are named ``{prefix}_{i:02d}.{fmt}`` and written atomically; nothing else is
        written.  JPEG frames that went through the JPEG round trip are written from their
        encoded bytes, with an EXIF block (ExposureTime = nominal time, FNumber, ISO)
        inserted, so they decode to exactly :attr:`images`.  PNG files carry the same EXIF
        in an ``eXIf`` chunk; TIFF files carry the three tags in IFD0 (TIFF/EP style).
        PNG and TIFF are lossless (16-bit for a 16-bit stack).

        Parameters
        ----------
        folder : str or os.PathLike
            Created if missing.
        fmt : str
            ``"jpg"``, ``"png"`` or ``"tif"``.
        jpeg_quality : int
            Used only for ``fmt="jpg"`` on a stack simulated without JPEG (then the files
            are a lossy copy of :attr:`images`; write PNG for an exact one).
        force : bool
            Allow replacing existing files.
        prefix : str

        Returns
        -------
        list of pathlib.Path

        Raises
        ------
        OutputExistsError
            When a target file exists and ``force`` is false (nothing is written then).
        InputError
            For an unknown format, or JPEG output of a 16-bit stack.
        """
        from ..io.images import exif_bytes, write_bytes_atomic, write_image

        ext = {"jpg": "jpg", "jpeg": "jpg", "png": "png", "tif": "tif",
               "tiff": "tif"}.get(str(fmt).lower().lstrip("."))
        if ext is None:
            raise InputError(f"unsupported stack output format {fmt!r} (jpg, png or tif)")
        if ext == "jpg" and self.bit_depth != 8:
            raise InputError("JPEG is 8-bit: write a 16-bit stack as png or tif")
        folder = Path(folder)
        digits = max(2, len(str(len(self.images) - 1)))
        paths = [folder / f"{prefix}_{i:0{digits}d}.{ext}" for i in range(len(self.images))]
        _refuse_existing(paths, force)
        for i, (path, image) in enumerate(zip(paths, self.images)):
            t = float(self.exposure_times[i])
            meta = {"exposure_time": t, "f_number": self.f_number, "iso": self.iso}
            if ext == "jpg" and self._encoded is not None:
                import piexif

                out = _io.BytesIO()
                piexif.insert(exif_bytes(**meta), self._encoded[i], out)
                write_bytes_atomic(path, out.getvalue(), force=force)
            elif ext == "jpg":
                write_image(path, image, force=force, jpeg_quality=jpeg_quality, **meta)
            elif ext == "png":
                from ..io.images import encode_image

                data = _png_with_exif(encode_image(image, ".png"), exif_bytes(**meta))
                write_bytes_atomic(path, data, force=force)
            else:
                write_bytes_atomic(path, _tiff_with_exif_tags(image, t, self.f_number,
                                                              self.iso), force=force)
        return paths

    def write_raws(self, folder, *, with_times: bool = True, force: bool = False,
                   prefix: str = "raw") -> list[Path]:
        """Write the frames' linear raws as 16-bit TIFFs, as a raw converter does
        (``dcraw -4 -T``: no tone curve, black at 0, white = 65535).

        Files are ``{prefix}_{i}.tif``, written atomically; with ``with_times`` they
        carry the nominal ExposureTime, FNumber and ISO in IFD0, else no exposure data
        (many converters drop it).

        Returns
        -------
        list of pathlib.Path

        Raises
        ------
        OutputExistsError
            When a target file exists and ``force`` is false (nothing is written then).
        """
        from ..io.images import write_bytes_atomic

        folder = Path(folder)
        paths = [folder / f"{prefix}_{i}.tif" for i in range(len(self.raws))]
        _refuse_existing(paths, force)
        for i, (path, raw) in enumerate(zip(paths, self.raws)):
            codes = np.round(np.clip(raw, 0.0, 1.0) * 65535).astype(np.uint16)
            meta = ((float(self.exposure_times[i]), self.f_number, self.iso) if with_times
                    else (None, None, None))
            write_bytes_atomic(path, _tiff_with_exif_tags(codes, *meta), force=force)
        return paths


def _check_scene(scene) -> np.ndarray:
    scene = np.asarray(scene)
    if scene.ndim != 3 or scene.shape[2] != 3:
        raise InputError(f"the scene must be an HxWx3 array, got shape {scene.shape}")
    if not np.issubdtype(scene.dtype, np.floating):
        scene = scene.astype(np.float32)
    if not np.all(np.isfinite(scene)) or scene.min() < 0:
        raise InputError("the scene radiance must be finite and non-negative")
    return scene


def _check_stack_args(pipeline, exposure_times, jitter, repeats, bit_depth, jpeg_quality,
                      chroma_subsampling, sharpening) -> np.ndarray:
    """Validate :func:`simulate_stack`'s arguments; return the sorted nominal times."""
    if not (callable(getattr(pipeline, "render", None))
            and callable(getattr(pipeline, "inverse_response", None))):
        raise InputError("pipeline must be a CameraPipeline (see default_pipeline), or an "
                         "object with render(raw) and inverse_response(codes, max_code)")
    times = np.asarray(exposure_times, dtype=np.float64).ravel()
    if times.size == 0 or not np.all(np.isfinite(times)) or np.any(times <= 0):
        raise InputError("exposure_times must be a non-empty sequence of positive numbers")
    if not (0.0 <= float(jitter) < 1.0):
        raise InputError(f"jitter must be in [0, 1), got {jitter!r}")
    if int(repeats) != repeats or repeats < 1:
        raise InputError(f"repeats must be a positive integer, got {repeats!r}")
    if bit_depth not in (8, 16):
        raise InputError(f"bit_depth must be 8 or 16, got {bit_depth!r}")
    if jpeg_quality is not None and not (0 <= int(jpeg_quality) <= 100):
        raise InputError(f"jpeg_quality must be in [0, 100], got {jpeg_quality!r}")
    if chroma_subsampling not in CHROMA_SUBSAMPLINGS:
        raise InputError(f"chroma_subsampling must be one of {CHROMA_SUBSAMPLINGS}, got "
                         f"{chroma_subsampling!r}")
    if sharpening is not None and not isinstance(sharpening, UnsharpMask):
        raise InputError("sharpening must be an UnsharpMask or None")
    return np.repeat(np.sort(times), int(repeats))


def simulate_stack(scene, pipeline, exposure_times, *, jitter: float = 0.03, repeats: int = 1,
                   sensor: SensorModel | None = None, jpeg_quality: int | None = 90,
                   bit_depth: int = 8, exposure_scale: float | None = None,
                   seed: int = 0, chroma_subsampling: str = "4:2:0",
                   sharpening: UnsharpMask | None = None) -> SyntheticStack:
    """Simulate a bracketed exposure stack through ``P = f(Γ(M ρ))``.

    Per frame: ``ρ = sensor.expose(scene, exposure_scale * true_time)`` (noise, black and
    white clipping), ``P = pipeline.render(ρ)`` (Gong et al., Eq. 1a), optionally
    in-camera sharpening of ``P``, codes ``round(P * max_code)``, then (8-bit only) a JPEG
    round trip through OpenCV.  The shutter jitter and the unknown exposure ratios it
    causes are those discussed by Lin et al. ICCV 2011 §4-5.

    Parameters
    ----------
    scene : array_like
        ``HxWx3`` linear radiance in camera RGB (e.g. :func:`make_scene`).
    pipeline : CameraPipeline
        Or any object with ``render(raw)`` (linear camera RGB -> rendered ``[0, 1]``) and
        ``inverse_response(codes, max_code)`` (the truth, ``(n, 3)``), e.g. a real
        camera's model read from files.
    exposure_times : sequence of float
        Nominal shutter times in seconds; frames are ordered by time (ascending).
    jitter : float
        Shutter inaccuracy: ``true = nominal * (1 + U(-jitter, jitter))`` per shot,
        independently (uniform ±jitter), ``0 <= jitter < 1``.
    repeats : int
        Each nominal time is shot ``repeats`` times (independent jitter and noise).
    sensor : SensorModel, optional
        Default ``SensorModel()`` (shot + read noise); ``SensorModel.ideal()`` is noise-free.
    jpeg_quality : int or None
        OpenCV JPEG quality for 8-bit stacks; None: no JPEG.  Ignored for 16-bit stacks.
    bit_depth : int
        8 or 16.
    exposure_scale : float, optional
        Default: ``0.18 / (median(scene luminance) * sqrt(t_min * t_max))`` -- the frame in
        the middle of the bracket (geometric mean of the extreme times) exposes the scene's
        median luminance (mean over channels) at raw mid-grey 0.18.  On a 14-stop scene a
        1/250 .. 1/8 s bracket then clips highlights in the longest frame and leaves the
        shadows deep in noise in the shortest.
    seed : int
        Everything random derives from ``numpy.random.SeedSequence(seed)``.
    chroma_subsampling : str
        JPEG chroma subsampling, one of :data:`CHROMA_SUBSAMPLINGS` (default 4:2:0,
        OpenCV's default and most cameras' at everyday qualities).
    sharpening : UnsharpMask, optional
        In-camera sharpening of the rendered frame before quantisation and JPEG.

    Returns
    -------
    SyntheticStack
    """
    scene = _check_scene(scene)
    nominal = _check_stack_args(pipeline, exposure_times, jitter, repeats, bit_depth,
                                jpeg_quality, chroma_subsampling, sharpening)
    jitter = float(jitter)
    sensor = SensorModel() if sensor is None else sensor
    if exposure_scale is None:
        median = float(np.median(scene.mean(axis=2, dtype=np.float64)))
        if median <= 0:
            raise InputError("the scene's median radiance is zero; give exposure_scale")
        exposure_scale = 0.18 / (median * math.sqrt(nominal[0] * nominal[-1]))
    exposure_scale = float(exposure_scale)
    if not (np.isfinite(exposure_scale) and exposure_scale > 0):
        raise InputError(f"exposure_scale must be positive, got {exposure_scale!r}")

    seqs = np.random.SeedSequence(seed).spawn(1 + nominal.size)
    shutter = np.random.default_rng(seqs[0])
    true = nominal * (1.0 + shutter.uniform(-jitter, jitter, nominal.size))
    max_code = 255 if bit_depth == 8 else 65535
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    use_jpeg = jpeg_quality is not None and bit_depth == 8

    images, raws, encoded = [], [], []
    for i, t in enumerate(true):
        raw = sensor.expose(scene, exposure_scale * float(t), np.random.default_rng(seqs[1 + i]))
        rendered = pipeline.render(raw)
        if sharpening is not None:
            rendered = sharpening.apply(rendered)
        codes = np.round(rendered * max_code).astype(dtype)
        if use_jpeg:
            codes, data = _jpeg_round_trip(codes, jpeg_quality, chroma_subsampling)
            encoded.append(data)
        raws.append(raw)
        images.append(codes)
    return SyntheticStack(images=images, exposure_times=nominal, true_exposures=true,
                          radiance=scene, raws=raws, pipeline=pipeline, bit_depth=bit_depth,
                          exposure_scale=exposure_scale, seed=seed,
                          jpeg_quality=int(jpeg_quality) if use_jpeg else None,
                          jitter=jitter, _encoded=encoded if use_jpeg else None,
                          chroma_subsampling=chroma_subsampling if use_jpeg else None,
                          sharpening=sharpening)


def simulate_raw_jpeg_pair(scene=None, pipeline=None, *, exposure: float = 1.0, sensor=None,
                           jpeg_quality: int | None = 95, seed: int = 0,
                           raw_bits: int | None = 16) -> dict:
    """Simulate one RAW+JPEG pair, the input of the rank-based (RAW) calibration path.

    ``raw = sensor.expose(scene, exposure)`` (quantised to ``raw_bits`` like an ADC), and
    ``rendered = JPEG(round(255 f(Γ(M raw))))`` -- Gong et al., rank-based radiometric
    calibration, Eq. 1a.

    Parameters
    ----------
    scene : array_like, optional
        Default: ``make_scene(dynamic_range_stops=8, saturation=0.6, seed=seed)`` -- a
        range a single exposure covers, with saturated colours for the gamut mapping.
    pipeline : CameraPipeline, optional
        Default ``default_pipeline(seed=seed)``.
    exposure : float
        Radiance-to-signal factor (scene white = 1, so 1 puts white at raw white).
    sensor : SensorModel, optional
        Default ``SensorModel()``.
    jpeg_quality : int or None
        None: no JPEG (``rendered`` are the quantised codes).
    seed : int
    raw_bits : int or None
        Quantise the raw to this many bits (16 makes a 16-bit TIFF of it exact); None: keep
        float.

    Returns
    -------
    dict
        ``raw`` (float32 ``HxWx3`` linear camera RGB in ``[0, 1]``), ``rendered`` (uint8 RGB
        after JPEG), ``codes`` (uint8 before JPEG), ``encoded`` (the JPEG bytes or None),
        ``pipeline``, ``radiance``, ``exposure``.
    """
    scene = (make_scene(dynamic_range_stops=8.0, saturation=0.6, seed=seed)
             if scene is None else _check_scene(scene))
    pipeline = default_pipeline(seed=seed) if pipeline is None else pipeline
    sensor = SensorModel() if sensor is None else sensor
    raw = sensor.expose(scene, exposure, np.random.default_rng(np.random.SeedSequence(seed)))
    if raw_bits is not None:
        if not (1 <= int(raw_bits) <= 24):
            raise InputError(f"raw_bits must be in [1, 24], got {raw_bits!r}")
        levels = float(2 ** int(raw_bits) - 1)
        raw = (np.round(raw.astype(np.float64) * levels) / levels).astype(np.float32)
    codes = np.round(pipeline.render(raw) * 255).astype(np.uint8)
    if jpeg_quality is not None:
        rendered, data = _jpeg_round_trip(codes, jpeg_quality)
    else:
        rendered, data = codes, None
    return {"raw": raw, "rendered": rendered, "codes": codes, "encoded": data,
            "pipeline": pipeline, "radiance": scene, "exposure": float(exposure)}


def handheld(images, *, fraction: float = 0.02, degrees: float = 0.5, seed: int = 0) -> list:
    """The frames of a stack as a handheld camera would have taken them (ours).

    Every frame but the middle one is turned by up to ``±degrees`` about its centre and
    shifted by up to ``±fraction`` of the width in x and y (uniform, seeded), with
    reflected borders (``cv2.warpAffine``, bilinear): the misalignment a verdict or an
    alignment step must notice.

    Examples
    --------
    >>> frames = handheld(demo_stack().images, seed=1)
    >>> len(frames), frames[0].shape
    (6, (256, 384, 3))
    """
    import cv2

    rng = np.random.default_rng(seed)
    out = []
    for k, im in enumerate(images):
        if k == len(images) // 2:
            out.append(im)
            continue
        h, w = im.shape[:2]
        m = cv2.getRotationMatrix2D((w / 2, h / 2), rng.uniform(-degrees, degrees), 1.0)
        m[:, 2] += rng.uniform(-fraction, fraction, 2) * w
        out.append(cv2.warpAffine(im, m, (w, h), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REFLECT))
    return out


def demo_stack(seed: int = 0) -> SyntheticStack:
    """The built-in stack of ``selfcal demo``.

    Six shots at 1/250, 1/125, 1/60, 1/30, 1/15, 1/8 s with ±3 % shutter jitter of a
    384×256, 14-stop scene with moderate saturation (0.5), rendered by
    ``default_pipeline(gamut="smooth", seed=seed)`` and saved as JPEG quality 90.
    """
    scene = make_scene(256, 384, dynamic_range_stops=14.0, saturation=0.5, seed=seed)
    return simulate_stack(scene, default_pipeline(gamut="smooth", seed=seed),
                          DEMO_EXPOSURE_TIMES, jitter=0.03, jpeg_quality=90, seed=seed)
