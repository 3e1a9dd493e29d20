"""The sensor: scene radiance × exposure -> linear raw, with shot and read noise."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["SensorModel"]


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

