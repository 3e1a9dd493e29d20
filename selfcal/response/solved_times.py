"""The given times inside the solve of :func:`selfcal.calibrate_response`: the log times
Eq. 8 takes (an error when they cannot move it), refined exposures put back on the times'
scale, and the times they corrected.

[Lin2011] §5 solves Eq. 8 with the exposure ratios known, or unknown and solved jointly
(after [Kim2008]); the anchoring is ours.  Which times are refined is the rule's
(:class:`selfcal.exposure.ExposureRule`); the times are read in :mod:`selfcal.exposure`.

References
----------
[Lin2011], [Kim2008] See ``docs/references.md``.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CalibrationError
from ..exposure.times import CONTRADICTION_FACTOR

__all__ = ["log_exposure_times", "anchor_refined", "corrected_times"]


def log_exposure_times(times) -> np.ndarray:
    """Log exposure times (NaN where unknown); an error when all are known and equal."""
    log_times = np.array([np.nan if t is None else math.log(t) for t in times])
    known = np.isfinite(log_times)
    if known.sum() >= 2 and np.ptp(log_times[known]) < math.log(1.0001) and known.all():
        raise CalibrationError(
            "all frames have the same exposure time: Eq. 8 needs exposure changes "
            "(bracket the exposure, or pass --unknown-exposures if the times are wrong)")
    return log_times


def anchor_refined(log_exposures, log_times) -> np.ndarray:
    """Refined log exposures with their absolute scale set by the times that agree (ours).

    Eq. 8 fixes exposure ratios only; the absolute scale is a free constant.  It is set
    so that the median over the frames with a given time of ``log t − K`` is zero: the
    frames whose times agree with the pixels keep them, whatever one wrong time says
    (shifting every log exposure by one constant leaves the curve unchanged).
    """
    K = np.asarray(log_exposures, dtype=float)
    known = np.isfinite(log_times)
    if known.sum() < 2:
        return K
    return K + float(np.median(log_times[known] - K[known]))


def corrected_times(log_exposures, log_times, used_sources, sub_times) -> list:
    """Frames whose refined exposure moved from the given time by more than
    :data:`CONTRADICTION_FACTOR` (what ``refine_exposures`` corrected), as
    ``contradicting_times`` entries."""
    out = []
    for j in np.flatnonzero(np.isfinite(log_times)):
        if abs(log_exposures[j] - log_times[j]) > math.log(CONTRADICTION_FACTOR):
            out.append({"frame": used_sources[j], "given": sub_times[j],
                        "estimated": math.exp(log_exposures[j])})
    return out
