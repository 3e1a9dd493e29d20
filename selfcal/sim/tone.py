"""Tone curves ``f``: the last step of the simulated camera ``P = f(Γ(M ρ))``.

:class:`ToneCurve` is a monotone table with an exact inverse, so the true inverse
response of a simulated camera is exactly the inverse of what rendered its images.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..response.curve_family import srgb_encode

__all__ = ["ToneCurve"]


def _strictly_increasing(y: np.ndarray, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Add a tiny ramp ``eps * x`` where ``y`` is flat, so that ``f`` has an exact inverse."""
    if np.all(np.diff(y) > 0):
        return y
    # y + eps*x is strictly increasing whenever y is non-decreasing and x strictly increasing;
    # dividing by (1 + eps) keeps f(1) = 1.
    return (y + eps * x) / (1.0 + eps)


class ToneCurve:
    """A monotone increasing tone curve ``f: [0, 1] -> [0, 1]``, ``f(0) = 0``, ``f(1) = 1``.

    The ``f`` of [Gong2018], Eq. 1 (one per channel), i.e. the camera response function
    of [Lin2011], Eq. 1.  It is held as a dense table ``(irradiance, brightness)``, both
    strictly increasing, and evaluated by linear interpolation (``numpy.interp``): a
    piecewise-linear interpolant of a monotone table is monotone, and its inverse is
    exact -- the same table with the axes swapped -- so
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

    def __init__(self, irradiance: npt.ArrayLike, brightness: npt.ArrayLike,
                 name: str = "table", *, kind: str = "table",
                 params: dict | None = None) -> None:
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
    def from_table(cls, irradiance: npt.ArrayLike, brightness: npt.ArrayLike,
                   name: str = "table") -> "ToneCurve":
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
        d: dict[str, object] = {"name": self.name, "kind": self.kind}
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

