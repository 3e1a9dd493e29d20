"""Looking at the inputs and choosing: the calibration path for a set of files, the model
class for a model file.

* :mod:`selfcal.choose.groups` -- files grouped into brackets, RAW+JPEG pairs and sessions;
* :mod:`selfcal.choose.paths` -- :func:`calibrate`: the JPEG-only path, the RAW path or
  both, and why (:class:`CalibrationResult`); :func:`calibrate_pipeline`;
* :mod:`selfcal.choose.loading` -- :func:`load_model`: a model file or NUS model folder as
  the model object it holds.
"""

from __future__ import annotations

from .groups import InputGroups, group_inputs
from .paths import CalibrationResult, PairOptions, calibrate, calibrate_pipeline

__all__ = ["InputGroups", "CalibrationResult", "PairOptions", "group_inputs", "calibrate",
           "calibrate_pipeline"]
