"""The vignetting model: a radial polynomial about an optical centre, per channel.

The form is the one of [Goldman2010], Eq. 4, which is also lensfun's ``pa`` model
(``Cd = Cs · (1 + k₁r² + k₂r⁴ + k₃r⁶)``) and Hugin's::

    V(r) = 1 + k₁ r² + k₂ r⁴ + k₃ r⁶

with ``r`` the distance from the optical centre in units of half the image diagonal
(lensfun's normalisation, so a lens profile applies at any resolution), so that
``V = 1`` at the centre.  The centre may sit off the image centre ([Goldman2010] §3.1
fixes it at the image centre; [Kim2008] lets it move): ``centre`` is its offset from the
image centre in the same units.  Each channel has its own coefficients (lenses vignette
colours differently; ours, beyond [Goldman2010], who uses one set).

The model is a value: its fit, a lens profile or a flat field make it
(:mod:`selfcal.response.vignetting_fit`, :mod:`selfcal.lens.database`,
:mod:`selfcal.lens.flat_field`), and the merge divides it out.

References
----------
[Goldman2010] D. B. Goldman, "Vignette and exposure calibration and compensation",
IEEE TPAMI 32(12), 2010.
[Kim2008] S. J. Kim and M. Pollefeys, "Robust radiometric calibration and vignetting
correction", IEEE TPAMI 30(4), 2008.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import InputError

#: Where the model came from.
SOURCES = ("self", "lens", "flat")
#: Parameters of the model, in the order of ``covariance``: the centre's two offsets,
#: then (k₁, k₂, k₃) of R, of G, of B.
PARAMETER_NAMES = ("cx", "cy") + tuple(f"k{j}_{c}" for c in "RGB" for j in (1, 2, 3))


def normalised_radius(height: int, width: int, centre: npt.ArrayLike = (0.0, 0.0), *,
                      xs: npt.ArrayLike | None = None,
                      ys: npt.ArrayLike | None = None) -> np.ndarray:
    """Distance from the optical centre in units of half the image diagonal.

    Pixel centres are at integer coordinates; the image centre at ``((w-1)/2, (h-1)/2)``.
    ``xs``, ``ys`` (pixel coordinates, any shape) give the radius at those points instead
    of on the whole grid.
    """
    half_diagonal = 0.5 * float(np.hypot(height, width))
    centre = np.asarray(centre, np.float64)
    if xs is None:
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
    u = (np.asarray(xs, np.float64) - 0.5 * (width - 1)) / half_diagonal - centre[0]
    v = (np.asarray(ys, np.float64) - 0.5 * (height - 1)) / half_diagonal - centre[1]
    return np.hypot(u, v)


def radial_falloff(r: npt.ArrayLike, coefficients: npt.ArrayLike) -> np.ndarray:
    """``V(r) = 1 + k₁r² + k₂r⁴ + k₃r⁶`` ([Goldman2010], Eq. 4), ``coefficients`` (…, 3)."""
    k = np.asarray(coefficients, np.float64)
    r2 = np.asarray(r, np.float64) ** 2
    return 1.0 + r2 * (k[..., 0] + r2 * (k[..., 1] + r2 * k[..., 2]))


def binned_points(r: Any, log_ratio: Any, *, bins: int = 24,
                  r_max: float | None = None) -> dict:
    """Measurements of ``log V`` binned in radius: the ``diagnostics["points"]`` record.

    Parameters
    ----------
    r : array_like
        ``(n,)`` radii about the optical centre, in units of half the image diagonal.
    log_ratio : array_like
        ``(n, 3)`` measured ``log V`` per channel (NaN where a channel has none).
    bins : int
        Equal-width bins over ``[0, r_max]`` (default: the largest radius).

    Returns
    -------
    dict
        ``{"r", "log_ratio", "count"}`` as JSON-ready lists (see :class:`Vignetting`).
    """
    r = np.asarray(r, np.float64).reshape(-1)
    values = np.asarray(log_ratio, np.float64).reshape(r.size, 3)
    top = float(r.max()) if r_max is None and r.size else float(r_max or 1.0)
    edges = np.linspace(0.0, max(top, 1e-9), bins + 1)
    which = np.clip(np.digitize(r, edges) - 1, 0, bins - 1)
    means, counts = [], []
    for b in range(bins):
        column = values[which == b]
        ok = np.isfinite(column)
        n = ok.sum(axis=0)
        means.append([float(column[ok[:, c], c].mean()) if n[c] else None for c in range(3)])
        counts.append([int(v) for v in n])
    keep = [i for i in range(bins) if any(counts[i])]
    centres = 0.5 * (edges[:-1] + edges[1:])
    return {"r": [float(centres[i]) for i in keep], "log_ratio": [means[i] for i in keep],
            "count": [counts[i] for i in keep]}


@dataclass
class Vignetting:
    """Per-channel radial vignetting ``V(r)`` about an optical centre ([Goldman2010], Eq. 4).

    Attributes
    ----------
    coefficients : numpy.ndarray
        ``(3, 3)``: ``(k₁, k₂, k₃)`` per channel (R, G, B).
    centre : numpy.ndarray
        ``(2,)``: the optical centre's offset from the image centre (x, y), in units of
        half the image diagonal.
    source : {"self", "lens", "flat"}
        Self-calibrated from moved frames, a lens database profile, or a flat field.
    description : str
        What it is, for people: the lens profile matched, the frames it was fitted on.
    covariance : numpy.ndarray or None
        ``(11, 11)`` covariance of the parameters (:data:`PARAMETER_NAMES`), from the fit;
        None when unknown.
    log_sigma_floor : float
        A standard deviation of ``log V`` at the corner (r = 1) that the covariance does
        not hold (a lens profile's unit-to-unit spread), growing as ``r²`` inwards.
    aspect : float or None
        ``width / height`` of the frames it was made for; None for lens profiles (any).
    diagnostics : dict
        How it was made (points used, residuals, motion observed), saved with it.  The key
        ``"points"``, when present, holds the measurements the fit saw, binned in radius
        for plots (:func:`binned_points`): ``{"r": [n], "log_ratio": [n][3], "count":
        [n][3]}`` -- bin centres in units of half the diagonal about the fitted centre, the
        mean measured ``log V`` per channel there (None where a bin is empty) and how many
        measurements each mean holds.  Any source may fill it (a flat field's blocks, the
        self-calibration's pairs); :func:`selfcal.report.plots.plot_vignetting` draws it.

    Examples
    --------
    >>> v = Vignetting(np.tile([-0.3, 0.0, 0.0], (3, 1)), np.zeros(2), source="flat")
    >>> m = v.map(3, 5)
    >>> m.shape, m.dtype, float(m[1, 2, 0])
    ((3, 5, 3), dtype('float32'), 1.0)
    """

    coefficients: np.ndarray
    centre: np.ndarray
    source: str
    description: str = ""
    covariance: np.ndarray | None = None
    log_sigma_floor: float = 0.0
    aspect: float | None = None
    diagnostics: dict = field(default_factory=dict)

    def __post_init__(self):
        self.coefficients = np.asarray(self.coefficients, np.float64).reshape(3, 3)
        self.centre = np.asarray(self.centre, np.float64).reshape(2)
        if self.source not in SOURCES:
            raise InputError(f"vignetting source {self.source!r} is not one of {SOURCES}")
        if self.covariance is not None:
            self.covariance = np.asarray(self.covariance, np.float64).reshape(11, 11)

    @property
    def parameters(self) -> np.ndarray:
        """The 11 parameters in the order of :data:`PARAMETER_NAMES`."""
        return np.concatenate([self.centre, self.coefficients.ravel()])

    def falloff(self, r: npt.ArrayLike) -> np.ndarray:
        """``V(r)`` per channel at radii ``r`` about the optical centre: shape ``r.shape + (3,)``."""
        r = np.asarray(r, np.float64)
        return radial_falloff(r[..., None], self.coefficients)

    def map(self, height: int, width: int) -> np.ndarray:
        """``V`` at every pixel of a ``height × width`` frame: float32 ``HxWx3``, 1 at the centre."""
        self.check_size(height, width)
        r = normalised_radius(height, width, self.centre)
        return self.falloff(r).astype(np.float32)

    def at(self, height: int, width: int, xs: npt.ArrayLike, ys: npt.ArrayLike) -> np.ndarray:
        """``V`` at pixel coordinates ``xs``, ``ys`` of a ``height × width`` frame: ``(…, 3)``."""
        r = normalised_radius(height, width, self.centre, xs=xs, ys=ys)
        return self.falloff(r)

    def log_sigma_map(self, height: int, width: int) -> np.ndarray:
        """Standard deviation of ``log V`` at every pixel: float32 ``HxWx3``.

        The delta method on :attr:`covariance` (the Jacobian of ``log V`` in the parameters
        taken analytically), plus :attr:`log_sigma_floor` · r² in quadrature.
        """
        self.check_size(height, width)
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float64)
        return self.log_sigma_at(height, width, xs, ys).astype(np.float32)

    def log_sigma_at(self, height: int, width: int, xs: npt.ArrayLike,
                     ys: npt.ArrayLike) -> np.ndarray:
        """:meth:`log_sigma_map` at pixel coordinates ``xs``, ``ys``: ``(…, 3)``."""
        r = normalised_radius(height, width, self.centre, xs=xs, ys=ys)
        variance = (self.log_sigma_floor * r ** 2)[..., None] ** 2 * np.ones(3)
        if self.covariance is not None:
            variance = variance + self._covariance_variance(height, width, xs, ys, r)
        return np.sqrt(variance)

    def _covariance_variance(self, height, width, xs, ys, r) -> np.ndarray:
        half_diagonal = 0.5 * float(np.hypot(height, width))
        u = (np.asarray(xs, np.float64) - 0.5 * (width - 1)) / half_diagonal - self.centre[0]
        v = (np.asarray(ys, np.float64) - 0.5 * (height - 1)) / half_diagonal - self.centre[1]
        r2 = r ** 2
        out = np.empty(r.shape + (3,))
        for c in range(3):
            k1, k2, k3 = self.coefficients[c]
            value = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            d_r2 = (k1 + 2 * k2 * r2 + 3 * k3 * r2 ** 2) / value
            # ∂ log V / ∂(cx, cy, k₁..k₃ of this channel); r² = u² + v², ∂r²/∂cx = −2u
            jac = [-2 * u * d_r2, -2 * v * d_r2, r2 / value, r2 ** 2 / value, r2 ** 3 / value]
            index = [0, 1, 2 + 3 * c, 3 + 3 * c, 4 + 3 * c]
            cov = np.asarray(self.covariance)[np.ix_(index, index)]
            out[..., c] = sum(jac[i] * jac[j] * cov[i, j] for i in range(5) for j in range(5))
        return np.maximum(out, 0.0)

    def corner_stops(self) -> np.ndarray:
        """The falloff at the farthest image corner, in stops (−log₂ V), per channel."""
        corners = [(sx, sy) for sx in (-1, 1) for sy in (-1, 1)]
        worst = max(np.hypot(sx * 0.8 - self.centre[0], sy * 0.6 - self.centre[1])
                    for sx, sy in corners) if self.aspect is None else max(
            np.hypot(sx * _half_width(self.aspect) - self.centre[0],
                     sy * _half_height(self.aspect) - self.centre[1]) for sx, sy in corners)
        return -np.log2(np.maximum(self.falloff(worst), 1e-6))

    def corner_profile(self, n: int = 33) -> dict:
        """``V`` and its σ along the ray from the optical centre to the farthest corner.

        On a frame of :attr:`aspect` (4:3 when None, as :meth:`corner_stops`), ``n``
        points evenly spaced in radius: ``{"r": (n,), "falloff": (n, 3), "log_sigma":
        (n, 3)}`` -- the radius in units of half the diagonal, ``V`` and the standard
        deviation of ``log V`` (:meth:`log_sigma_at`).  What ``selfcal show`` prints and
        plots.
        """
        aspect = 4.0 / 3.0 if self.aspect is None else float(self.aspect)
        height = 3000
        width = int(round(height * aspect))
        half_diagonal = 0.5 * float(np.hypot(height, width))
        cx = 0.5 * (width - 1) + self.centre[0] * half_diagonal
        cy = 0.5 * (height - 1) + self.centre[1] * half_diagonal
        corners = [(x, y) for x in (-0.5, width - 0.5) for y in (-0.5, height - 0.5)]
        far_x, far_y = max(corners, key=lambda c: np.hypot(c[0] - cx, c[1] - cy))
        t = np.linspace(0.0, 1.0, n)
        xs, ys = cx + t * (far_x - cx), cy + t * (far_y - cy)
        return {"r": normalised_radius(height, width, self.centre, xs=xs, ys=ys),
                "falloff": self.at(height, width, xs, ys),
                "log_sigma": self.log_sigma_at(height, width, xs, ys)}

    def check_size(self, height: int, width: int) -> None:
        """InputError unless frames of ``height × width`` have the aspect it was made for."""
        if self.aspect is None:
            return
        if abs(np.log((width / height) / self.aspect)) > 0.02:
            raise InputError(f"the vignetting was made for frames of aspect {self.aspect:.3f} "
                             f"(width/height), not {width}×{height}")

    def to_dict(self) -> dict:
        """A JSON-ready dict (model files, format version 4)."""
        return {"coefficients": self.coefficients.tolist(), "centre": self.centre.tolist(),
                "source": self.source, "description": self.description,
                "covariance": None if self.covariance is None else self.covariance.tolist(),
                "log_sigma_floor": float(self.log_sigma_floor), "aspect": self.aspect,
                "diagnostics": self.diagnostics}

    @classmethod
    def from_dict(cls, d: dict) -> "Vignetting":
        """Inverse of :meth:`to_dict`."""
        return cls(coefficients=np.asarray(d["coefficients"]), centre=np.asarray(d["centre"]),
                   source=d["source"], description=d.get("description", ""),
                   covariance=None if d.get("covariance") is None else np.asarray(d["covariance"]),
                   log_sigma_floor=float(d.get("log_sigma_floor", 0.0)),
                   aspect=d.get("aspect"), diagnostics=dict(d.get("diagnostics", {})))


def _half_width(aspect: float) -> float:
    return aspect / np.hypot(aspect, 1.0)


def _half_height(aspect: float) -> float:
    return 1.0 / np.hypot(aspect, 1.0)
