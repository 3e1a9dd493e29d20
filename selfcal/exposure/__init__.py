"""A bracket's exposures: the one room for them.

The given times are read once (:func:`read_given_times`: the caller's, checked, or EXIF,
both units side by side), every stage's exposures go into one typed record per frame
(:class:`BracketExposures`, :mod:`.record`: given, solved, measured, used, contradicted,
and where each came from), saved in the model, and one rule says how given times are
treated (:class:`ExposureRule`: measured by default, held on request), resolved for the
calibration and the merge in :mod:`.resolve`.  Every path needs each frame's exposure;
they come from one of these places:

* **given or from EXIF** -- the caller's times, or the EXIF shutter time with the frame's
  aperture and ISO (:mod:`.record`); the constants of contradicted times in :mod:`.times`;
* **raw ratios** -- a bracket's exposure ratios from the values of its linear raws
  ([Lin2011] §5: "the exposure ratio can be directly computed by dividing the raw values
  between two images"), in :mod:`.raw_ratios`;
* **measured from a linear bracket** -- the merge of raws or linear TIFFs measures the
  ratios from the pixels and takes only the scale from the times, in :mod:`.linear`;
* **measured through the response curve** -- the same measurement on a rendered bracket's
  ``f⁻¹(codes)`` once a model gives the curve (a merge option), in :mod:`.measured`;
* **the plan** -- which of these a session's response path uses, and why, in :mod:`.plan`.

Its modules:

* :mod:`selfcal.exposure.record` -- the given times read once, the per-frame record, the rule;
* :mod:`selfcal.exposure.resolve` -- the record of a calibration, of a merge, of a linear
  bracket, of an older model file; the run's one line about its exposures;
* :mod:`selfcal.exposure.times` -- the thresholds of contradicted times;
* :mod:`selfcal.exposure.legacy` -- 1.0's names of the rule, accepted until 2.0;
* :mod:`selfcal.exposure.linear_evidence` -- whether 16-bit or float TIFFs are linear data;
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
from .record import (
    BracketExposures,
    ExposureRule,
    FrameExposure,
    GivenTime,
    GivenTimes,
    MeasurementSpread,
    read_given_times,
)
from .resolve import exposure_message, merge_exposures, model_exposures
from .times import CONTRADICTED_UNUSABLE_SHARE, CONTRADICTION_FACTOR

__all__ = [
    "ExposureRule",
    "GivenTime",
    "GivenTimes",
    "FrameExposure",
    "BracketExposures",
    "MeasurementSpread",
    "read_given_times",
    "merge_exposures",
    "model_exposures",
    "exposure_message",
    "CONTRADICTION_FACTOR",
    "CONTRADICTED_UNUSABLE_SHARE",
    "raw_exposure_ratios",
    "split_thumbnails",
    "raw_thumbnail",
    "check_linear_raw",
    "ResponsePlan",
    "DISTINCT_EXPOSURE_FACTOR",
]
