"""The curve object of the family: a normalised forward response ``f`` (see the package).

:func:`normalised` and :func:`on_range` make a member of any increasing encoding: it is
normalised over the exposure range it is used on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...errors import InputError


# --------------------------------------------------------------------------------------
# the curve object
# --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ResponseCurve:
    """A forward camera response ``f``: irradiance in [0, 1] to brightness in [0, 1].

    Attributes
    ----------
    name : str
        A readable description with its parameters, e.g. ``"gamma(2.2)+toe(0.004)"``.
    family : str
        The family it was drawn from (see the module docstring).
    function : callable
        ``function(E) -> f(E)`` on a float array ``E`` in [0, 1]; normalised so that
        ``f(0) = 0`` and ``f(1) = 1``.
    """

    name: str
    family: str
    function: Callable[[np.ndarray], np.ndarray]

    def __call__(self, irradiance) -> np.ndarray:
        return self.function(np.asarray(irradiance, dtype=np.float64))


def normalised(raw: Callable[[np.ndarray], np.ndarray]) -> Callable[[np.ndarray], np.ndarray]:
    """Return ``E -> (raw(E) - raw(0)) / (raw(1) - raw(0))``."""
    r0, r1 = (float(v) for v in raw(np.array([0.0, 1.0])))
    span = r1 - r0
    if not np.isfinite(span) or span <= 0:
        raise InputError("a response curve must increase from E = 0 to E = 1")

    def f(e):
        return (raw(e) - r0) / span

    return f


def on_range(encoding, x_max: float):
    """``E -> encoding(x_max * E)``, normalised: an encoding used over ``[0, x_max]``."""
    return normalised(lambda e: encoding(x_max * e))
