"""The exposure-time stage of :func:`selfcal.calibrate_response`: which times are given,
whether they are refined, and what the pixels say about them.

[Lin2011] §5 solves Eq. 8 with the exposure ratios known, or unknown and solved jointly
(after [Kim2008]); the rest is ours: times from EXIF scaled to one aperture and ISO, a
time the pixels contradict reported (or, for EXIF times, refined), and refined exposures
put back on the given times' absolute scale.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import CalibrationError, InputError
from ..io.images import is_path
from ..typing import ExposureTimes

#: A frame whose given time and pixels disagree by more than this factor is reported.
CONTRADICTION_FACTOR = 1.25
#: Share of the known times contradicted at or above which the times are not refined and
#: the calibration is unusable (:mod:`selfcal.response.verdict`: times in the wrong order,
#: the wrong frames).
CONTRADICTED_UNUSABLE_SHARE = 0.5


def resolve_exposure_times(frames: Sequence, exposure_times: ExposureTimes | None,
                           sources: Sequence, times_source: str | None = None,
                           ) -> tuple[list[float | None], str]:
    """Given times per frame (None = unknown), from the caller or from EXIF, and their label.

    When EXIF gives f-number and ISO that vary over the stack, times are scaled to the
    first frame's aperture and ISO (exposure ∝ t · ISO / N²), so the result stays in seconds
    at the first frame's settings.

    The label (the model's ``diagnostics["exposure_source"]``) says where the times came
    from: ``times_source`` (default ``"given"``) for times the caller gave, ``"exif"`` when
    EXIF gave at least one, and ``"unknown"`` when no frame has a time (all given as None,
    arrays without times, files without EXIF times).
    """
    n = len(frames)
    if exposure_times is not None:
        times = list(exposure_times)
        if len(times) != n:
            raise InputError(f"{len(times)} exposure times given for {n} frames")
        out: list[float | None] = []
        for t, src in zip(times, sources):
            if t is None:
                out.append(None)
                continue
            try:
                tf = float(t)
            except (TypeError, ValueError):
                raise InputError(f"exposure time {t!r} is not a number", src) from None
            if not math.isfinite(tf) or tf <= 0:
                raise InputError(f"exposure time {t!r} must be a positive number", src)
            out.append(tf)
        if all(t is None for t in out):
            return out, "unknown"
        return out, times_source or "given"
    if not all(is_path(f) for f in frames):
        return [None] * n, "unknown"
    from ..io.images import effective_exposure_times, read_exposure_info

    out = effective_exposure_times([read_exposure_info(f) for f in frames])
    return out, "exif" if any(t is not None for t in out) else "unknown"


def log_exposure_times(times) -> np.ndarray:
    """Log exposure times (NaN where unknown); an error when all are known and equal."""
    log_times = np.array([np.nan if t is None else math.log(t) for t in times])
    known = np.isfinite(log_times)
    if known.sum() >= 2 and np.ptp(log_times[known]) < math.log(1.0001) and known.all():
        raise CalibrationError(
            "all frames have the same exposure time: Eq. 8 needs exposure changes "
            "(bracket the exposure, or pass --unknown-exposures if the times are wrong)")
    return log_times


def check_refine_option(refine_exposures):
    """``refine_exposures`` itself, when it is True, False or ``"auto"``; else a ValueError."""
    if refine_exposures not in (True, False, "auto"):
        raise ValueError(f"refine_exposures must be True, False or 'auto', not "
                         f"{refine_exposures!r}")
    return refine_exposures


def refine_decision(refine_exposures, time_source, contradictions, log_times) -> bool:
    """Whether the exposures are refined: ``"auto"`` refines EXIF times the pixels
    contradict (ours; the mission's "shutters are inaccurate").

    Times the caller gave are held (a contradiction is reported, the verdict is doubtful);
    so are EXIF times when most of them are contradicted: then the times are wrong or
    belong to other frames, and refining would hide it.
    """
    if refine_exposures != "auto":
        return bool(refine_exposures)
    known = int(np.isfinite(log_times).sum())
    return (time_source == "exif" and bool(contradictions)
            and len(contradictions) / known < CONTRADICTED_UNUSABLE_SHARE)


def contradiction_messages(contradictions, *, refined: bool) -> list[str]:
    """The warning of each contradicted time, saying whether it was refined or held."""
    if refined:
        return [f"{c['frame']}: the pixels contradict the EXIF exposure time "
                f"({c['given']:g} s in EXIF, the pixels say about {c['estimated']:g} s): "
                "shutters are inaccurate, so the exposures were refined "
                "(--no-refine-exposures keeps the EXIF times)" for c in contradictions]
    return [f"{c['frame']}: the pixels contradict the given exposure time "
            f"({c['given']:g} s given, the pixels say about {c['estimated']:g} s); "
            "consider --refine-exposures" for c in contradictions]


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
