"""The thresholds of a given time the pixels contradict: when it is said, and when most
times contradicted make a calibration unusable rather than refined (ours; the verdict,
:mod:`selfcal.response.verdict`, and the rule, :class:`selfcal.exposure.ExposureRule`,
read them).  The times in the solve itself are :mod:`selfcal.response.solved_times`'.
"""

from __future__ import annotations

#: A frame whose given time and pixels disagree by more than this factor is reported.
CONTRADICTION_FACTOR = 1.25
#: Share of the known times contradicted at or above which the times are not refined and
#: the calibration is unusable (:mod:`selfcal.response.verdict`: times in the wrong order,
#: the wrong frames).
CONTRADICTED_UNUSABLE_SHARE = 0.5
