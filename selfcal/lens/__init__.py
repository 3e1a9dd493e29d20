"""The lens and the scale: what lies between the scene's luminance and the sensor.

* :mod:`selfcal.lens.vignetting` -- the radial falloff model ([Goldman2010] Eq. 4);
* :mod:`selfcal.lens.database` -- vignetting from lensfun's lens profiles (lensfunpy);
* :mod:`selfcal.lens.flat_field` -- vignetting from a flat-field frame;
* :mod:`selfcal.lens.luminance` -- the absolute scale (cd/m²): an EXIF convention or a
  reference reading.

The self-calibrated vignetting is fitted beside the response solver it extends
(:mod:`selfcal.response.vignetting_fit`).
"""

from __future__ import annotations

from .database import LensMatch, lens_vignetting
from .flat_field import flat_field_vignetting
from .luminance import (LuminanceScale, ReferenceReading, parse_reference,
                        scale_from_exif, scale_from_reference)
from .vignetting import (PARAMETER_NAMES, Vignetting, binned_points, normalised_radius,
                         radial_falloff)

__all__ = ["Vignetting", "PARAMETER_NAMES", "normalised_radius", "radial_falloff",
           "binned_points", "flat_field_vignetting", "lens_vignetting", "LensMatch",
           "LuminanceScale", "ReferenceReading", "parse_reference", "scale_from_exif",
           "scale_from_reference"]
