"""The lens: vignetting (:mod:`.vignetting`), its sources other than a fit (the lens
database, :mod:`.database`; a flat field, :mod:`.flat_field`) and the absolute scale
(:mod:`.luminance`).

The self-calibrated vignetting is fitted beside the response solver it extends
(:mod:`selfcal.response.vignetting_fit`).
"""

from __future__ import annotations

from .vignetting import PARAMETER_NAMES, Vignetting, normalised_radius, radial_falloff

__all__ = ["Vignetting", "PARAMETER_NAMES", "normalised_radius", "radial_falloff"]
