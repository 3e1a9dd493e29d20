"""A bracket's exposures, and where each kind comes from.

Every path needs each frame's exposure; they come from one of these places:

* **given or from EXIF** -- the caller's times, or the EXIF shutter time scaled to the
  first frame's aperture and ISO (reading EXIF is file reading: :mod:`selfcal.io.images`);
  which times a calibration uses, and what happens when its fit contradicts them
  (reported, or refined and put back on the times' scale), is in :mod:`.times`;
* **raw ratios** -- a bracket's exposure ratios from the values of its linear raws
  ([Lin2011] §5: "the exposure ratio can be directly computed by dividing the raw values
  between two images"), in :mod:`.raw_ratios`;
* **measured from a linear bracket** -- the merge of raws or linear TIFFs measures the
  ratios from the pixels and takes only the scale from the times, in :mod:`.linear`;
* **measured through the response curve** -- the same measurement on a rendered bracket's
  ``f⁻¹(codes)`` once a model gives the curve (a merge option), in :mod:`.measured`;
* **the plan** -- which of these a session's response path uses, and why, in :mod:`.plan`.

Its modules:

* :mod:`selfcal.exposure.times` -- given, EXIF, refined or contradicted exposure times;
* :mod:`selfcal.exposure.raw_ratios` -- a bracket's exposure ratios from its linear raw
  pixels;
* :mod:`selfcal.exposure.linear` -- a linear bracket's (raws, linear TIFFs) exposures
  measured from its pixels;
* :mod:`selfcal.exposure.measured` -- a rendered bracket's exposures measured from its
  pixels through the model's curve;
* :mod:`selfcal.exposure.plan` -- a session's exposures for the response path: given, from
  EXIF, or from the raws.

Citation keys are those of ``docs/references.md``.
"""

from __future__ import annotations

from .plan import DISTINCT_EXPOSURE_FACTOR, ResponsePlan
from .raw_ratios import check_linear_raw, raw_exposure_ratios, raw_thumbnail, split_thumbnails
from .times import CONTRADICTED_UNUSABLE_SHARE, CONTRADICTION_FACTOR, resolve_exposure_times

__all__ = [
    "resolve_exposure_times",
    "CONTRADICTION_FACTOR",
    "CONTRADICTED_UNUSABLE_SHARE",
    "raw_exposure_ratios",
    "split_thumbnails",
    "raw_thumbnail",
    "check_linear_raw",
    "ResponsePlan",
    "DISTINCT_EXPOSURE_FACTOR",
]
