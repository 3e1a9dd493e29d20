"""The in-camera pipeline ``P = f(Γ(M ρ))``: colour matrix ``M``, gamut mapping ``Γ``,
tone curves ``f`` ([Gong2018], Eq. 1a).

The smooth gamut mapping also moves colours that are near (not only beyond) the gamut
boundary, as [Lin2011] (§4) observed in real cameras; that is what makes highly saturated
pixels outliers for per-channel response models, and the simulator reproduces it on
purpose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from .tone import ToneCurve

__all__ = ["gamut_clip", "gamut_compress", "CameraPipeline", "random_color_matrix",
           "default_pipeline"]

# Rec. 709 luma weights: the achromatic coordinate of the gamut mapping (output is sRGB-like).
LUMA = np.array([0.2126, 0.7152, 0.0722])
_GAMUTS = ("smooth", "clip", "none")


def gamut_clip(rgb: np.ndarray) -> np.ndarray:
    """Hard gamut mapping: clip each channel to ``[0, 1]`` (Γ of [Gong2018], Eq. 1, simplest).

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
    move colours *near* the gamut boundary ([Lin2011] §4, Fig. 5); this is the
    Γ of [Gong2018], Eq. 1.  The mapping works at
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
    lum = x[..., 1] + LUMA[0] * (x[..., 0] - x[..., 1]) + LUMA[2] * (x[..., 2] - x[..., 1])
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

    [Gong2018], Eq. 1a: a 3×3 colour matrix ``M``,
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
    curves: tuple[ToneCurve, ...] | ToneCurve
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

    @property
    def _curves(self) -> tuple[ToneCurve, ...]:
        """The three curves (``curves`` is made a tuple of three by ``__post_init__``)."""
        curves = self.curves
        assert isinstance(curves, tuple)
        return curves

    def colour_correct(self, raw: npt.ArrayLike) -> np.ndarray:
        """``M ρ``, or ``M min(g ρ, 1)`` with white-balance gains ``g``: the input of Γ."""
        raw = np.asarray(raw, dtype=np.float64)
        if self.white_balance is not None:
            raw = np.minimum(raw * self.white_balance, 1.0)
        return raw @ self.matrix.T

    def apply_gamut(self, x: np.ndarray) -> np.ndarray:
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
        for ch, curve in enumerate(self._curves):
            out[..., ch] = curve.forward(mapped[..., ch])
        return out

    def inverse_response(self, codes: npt.ArrayLike, max_code: int = 255) -> np.ndarray:
        """The true per-channel inverse response ``f_c^-1(code / max_code)``.

        This is the ground truth for the JPEG-only calibrators ([Lin2011] §5):
        exact for pixels that Γ leaves alone (low saturation), and ``f^-1(max_code) = 1``.

        Returns
        -------
        numpy.ndarray
            float64, shape ``(len(codes), 3)``.
        """
        y = np.clip(np.asarray(codes, dtype=np.float64).ravel() / float(max_code), 0.0, 1.0)
        return np.stack([c.inverse(y) for c in self._curves], axis=1)

    def to_dict(self) -> dict:
        """JSON-serialisable description (see :meth:`from_dict`)."""
        d = {
            "model": "P = f(Gamma(M rho))",
            "matrix": self.matrix.tolist(),
            "curves": [c.to_dict() for c in self._curves],
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
    """A plausible camera-RGB -> sRGB colour matrix ``M`` ([Gong2018], Eq. 1).

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
    # [Lin2011]): a calibrator that ties the channels together would be caught out.
    return (ToneCurve.film(contrast=0.97, toe=0.09, shoulder=0.79, exposure=1.08),
            ToneCurve.film(contrast=1.00, toe=0.10, shoulder=0.80, exposure=1.00),
            ToneCurve.film(contrast=1.03, toe=0.11, shoulder=0.81, exposure=0.95))


def default_pipeline(*, gamut: str = "smooth",
                     curves: tuple[ToneCurve, ...] | ToneCurve | None = None,
                     seed: int = 0) -> CameraPipeline:
    """A plausible camera pipeline ``P = f(Γ(M ρ))`` ([Gong2018], Eq. 1).

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

