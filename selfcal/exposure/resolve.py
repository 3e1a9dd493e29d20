"""The one resolver of a bracket's exposures: what a calibration and a merge use, and the
one line that says which times moved.

* :func:`calibration_exposures` -- a calibration's record from its given times, the Eq. 8
  solve ([Lin2011] §5), the times the pixels contradict and the exposures measured
  through the fitted curve (:mod:`.measured`);
* :func:`merge_exposures` -- a merge's record: the given times (caller's or EXIF, in
  ``t · ISO/100 / N²``), with the model's exposures for the frames it calibrated on those
  same times (a multiplication converts the model's unit), the model's solve filling frames
  without a time; :func:`with_measured` puts the merge's own measurement in;
* :func:`linear_exposures` -- a linear bracket's record (:mod:`.linear`);
* :func:`exposure_message` -- the run's one line about its exposures, or None;
* :func:`model_exposures` -- a model's record (derived from the diagnostics of a model file
  written before records existed).

The rule they follow (:class:`.record.ExposureRule`) is the one for EXIF times and the
caller's times alike: measured by default, ``held`` on request.  Ours.

References
----------
[Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import CalibrationError
from .measured import measure_calibration_exposures, measure_response_exposures
from .record import (
    BracketExposures,
    ExposureRule,
    FrameExposure,
    GivenTimes,
    MeasurementSpread,
)

#: A used exposure differing from its given time by more than this (relative) is said in
#: the run's exposure line.
REPORT_DIFFERENCE = 0.01
#: Two given times are the same time when they agree within this (relative).
SAME_TIME = 1e-6


def _finite(value) -> float | None:
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) and value > 0 else None


def calibration_exposures(given: GivenTimes, keep: Sequence[int], solved_log, *,
                          rule: ExposureRule, refined: bool, contradictions: Sequence[dict],
                          measured=None, spread: MeasurementSpread | None = None,
                          ) -> BracketExposures:
    """A calibration's record.

    Parameters
    ----------
    given : GivenTimes
        Every frame's given time (the calibration's unit is ``given.seconds``).
    keep : sequence of int
        The frames the solve used (the others have no solved, measured or used exposure).
    solved_log : array_like
        The solve's log exposures of the frames ``keep`` (anchored to the times).
    rule : ExposureRule
    refined : bool
        The solve treated the times as priors.
    contradictions : sequence of dict
        ``{"frame", "given", "estimated"}`` of the times the pixels contradict.
    measured : array_like, optional
        Per frame (all frames), the exposure measured through the curve (NaN: not measured).
    spread : MeasurementSpread, optional
    """
    pixels_say = {str(c["frame"]): float(c["estimated"]) for c in contradictions}
    solved = {k: _finite(math.exp(v)) for k, v in zip(keep, np.asarray(solved_log, float))}
    frames = []
    for k, (src, g) in enumerate(zip(given.sources, given.seconds)):
        s = solved.get(k)
        m = None if measured is None else _finite(measured[k])
        if k not in solved:
            used, used_from = None, "given"
        elif m is not None and rule.measured:
            used, used_from = m, "measured"
        elif g is None or refined:
            used, used_from = s, "solved"
        else:
            used, used_from = g, "given"
        frames.append(FrameExposure(source=src, given=g, origin=given.times[k].origin,
                                    solved=s, measured=m, contradicted=pixels_say.get(src),
                                    used=used, used_from=used_from))
    return BracketExposures(tuple(frames), rule=rule.times, origin=given.origin,
                            unit="seconds", refined=refined,
                            spread=spread if rule.measured else None)


def recorded_calibration(model, given: GivenTimes, keep: Sequence[int], solved_log, *,
                         rule: ExposureRule, refined: bool, contradictions: Sequence[dict],
                         codes=None, clip_margin: float, stuck=None):
    """A calibrated model with its exposures measured and recorded.

    With the codes the calibration kept while reading (``codes``, under the rule
    ``"measured"``), the kept frames' exposures are measured through the model's curve
    (:func:`selfcal.exposure.measured.measure_calibration_exposures`: the times -- or,
    refined, the solve's exposures, with whose trend the curve was fitted -- set the scale
    and the trend); then the record (:func:`calibration_exposures`) is attached and the
    model's ``exposures`` are the record's used ones.  ``model.exposures`` on the way in
    are the solve's.
    """
    measured = spread = None
    if codes is not None:
        measured, summary = measure_calibration_exposures(
            model, codes, keep, list(given.sources), times=list(given.seconds),
            solved=np.asarray(model.exposures, dtype=float), refined=refined,
            clip_margin=clip_margin, stuck=stuck)
        spread = MeasurementSpread.from_summary(summary, by="calibration")
    record = calibration_exposures(given, keep, solved_log, rule=rule, refined=refined,
                                   contradictions=contradictions, measured=measured,
                                   spread=spread)
    out = replace(model, exposure_record=record, exposures=record.used)
    out.fit_data = model.fit_data
    return out


def model_exposures(model: object) -> BracketExposures | None:
    """The model's record: ``model.exposure_record``, or for a model without one (a
    pipeline model, a response model read from an older file) one derived from its
    ``exposures``, ``exposure_times`` and ``sources`` (the model's exposures used, its
    times given); None for a model without exposures."""
    record = getattr(model, "exposure_record", None)
    if record is not None:
        return record
    exposures = getattr(model, "exposures", None)
    sources = list(getattr(model, "sources", None) or [])
    if exposures is None or len(sources) != len(np.atleast_1d(exposures)):
        return None
    times = list(getattr(model, "exposure_times", None) or [None] * len(sources))
    return record_from_diagnostics(sources, exposures, times,
                                   getattr(model, "diagnostics", None) or {})


def _same_time(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return abs(a / b - 1.0) <= SAME_TIME


def merge_exposures(given: GivenTimes, model_index: Sequence[int | None],
                    model_record: BracketExposures | None,
                    rule: ExposureRule) -> BracketExposures:
    """A merge's exposures before its own measurement (:func:`with_measured`).

    Each frame's given time is in the merge's unit ``t · ISO/100 / N²``
    (``given.relative``; the caller's times as they are).  A frame the model calibrated
    (``model_index``) on the same given time has the model's exposures, converted by the
    frame's own factor ``given.to_relative[k]``: under ``"measured"`` the model's used ones,
    under ``"held"`` the time.  A frame without a time takes the model's, scaled to the
    merge's times by the frames both know (their median ratio: the only scale the times
    leave open); a frame with neither is an error.

    Raises
    ------
    CalibrationError
        A frame with no time and no model exposure (named).
    """
    n = len(given)
    matched: list[FrameExposure | None] = [None] * n
    for k, i in enumerate(model_index):
        if i is not None and model_record is not None and i < len(model_record.frames):
            matched[k] = model_record.frames[i]
    # the scale of the model's exposures for frames without a time
    anchors = [math.log(g / (m.used * given.to_relative[k]))
               for k, (m, g) in enumerate(zip(matched, given.relative))
               if m is not None and m.used and g is not None]
    unknown_scale = math.exp(float(np.median(anchors))) if anchors else 1.0
    frames = []
    for k in range(n):
        g, m, factor = given.relative[k], matched[k], given.to_relative[k]
        same = m is not None and (g is None or _same_time(m.given, given.seconds[k]))
        scale = factor if g is not None else factor * unknown_scale

        def convert(v, scale=scale):
            return None if v is None else v * scale

        solved = convert(m.solved) if same and m is not None else None
        measured = convert(m.measured) if same and m is not None else None
        contradicted = convert(m.contradicted) if same and m is not None else None
        if g is None:
            if not same or m is None or m.used is None:
                raise CalibrationError(
                    f"{given.sources[k]}: no exposure time (give exposure times, or a model "
                    "calibrated on these frames)")
            used, used_from = convert(m.used), ("measured" if m.used_from == "measured"
                                                else "solved")
        elif rule.measured and same and m is not None and m.used is not None \
                and m.used_from != "given":
            used, used_from = convert(m.used), m.used_from
        else:
            used, used_from = g, "given"
        frames.append(FrameExposure(source=given.sources[k], given=g,
                                    origin=given.times[k].origin, solved=solved,
                                    measured=measured, contradicted=contradicted, used=used,
                                    used_from=used_from))
    spread = model_record.spread if model_record is not None else None
    own = all(f.used_from == "measured" for f in frames if f.given is not None) and \
        any(f.used_from == "measured" for f in frames)
    return BracketExposures(tuple(frames), rule=rule.times, origin=given.origin,
                            unit="relative", refined=bool(model_record and model_record.refined),
                            spread=spread if own and rule.measured else None)


def finish_merge_exposures(frames, model, record: BracketExposures, frame_set: Sequence[int],
                           rule: ExposureRule, *, clip_margin: float, stuck=None,
                           progress=None) -> tuple[BracketExposures, str | None]:
    """A merge's exposures, final, and the run's one line about them.

    Under ``"measured"`` the frames of ``frame_set`` (the merged, checked ones) are measured
    from the pixels through the model's curve
    (:func:`selfcal.exposure.measured.measure_response_exposures`), unless the model
    measured every one of them on the same times (nothing is read again then).
    """
    if rule.measured and frame_set and not measured_by_model(record, frame_set):
        out, summary = measure_response_exposures(frames, model, record.used, frame_set,
                                                  clip_margin=clip_margin, stuck=stuck,
                                                  trend=rule.trend, progress=progress)
        record = with_measured(record, out, frame_set,
                               MeasurementSpread.from_summary(summary, "merge"))
    return record, exposure_message(record)


def measured_by_model(record: BracketExposures, frame_set: Sequence[int]) -> bool:
    """Every frame of ``frame_set`` has the model's measured exposure (the merge measures
    nothing again)."""
    return record.spread is not None and all(
        record.frames[k].used_from == "measured" for k in frame_set)


def with_measured(record: BracketExposures, exposures, measured_set: Sequence[int],
                  spread: MeasurementSpread) -> BracketExposures:
    """The record with the merge's own measurement: ``exposures`` (per frame, on the
    times' scale) used for the frames of ``measured_set`` that it placed."""
    frames = list(record.frames)
    for k in measured_set:
        v = _finite(exposures[k])
        if v is None:
            continue
        frames[k] = replace(frames[k], measured=v, used=v, used_from="measured")
    return record.with_frames(frames, spread=spread)


def linear_exposures(given: GivenTimes, lin, rule: ExposureRule, log_sigma: float
                     ) -> BracketExposures:
    """A linear bracket's record from :func:`selfcal.exposure.linear.measure_linear_exposures`'
    result ``lin`` (its ratios on the times' scale, or the times held); ``log_sigma`` the
    measurement's spread (:func:`selfcal.exposure.linear.fit_log_sigma`)."""
    frames = []
    for k, (src, g) in enumerate(zip(given.sources, given.relative)):
        used = float(lin.exposures[k])
        m = used if lin.from_pixels and math.isfinite(lin.measured[k]) else None
        from_ = "measured" if m is not None else "given"
        frames.append(FrameExposure(source=src, given=g, origin=given.times[k].origin,
                                    measured=m, used=used, used_from=from_))
    spread = MeasurementSpread(log_sigma=float(log_sigma), by="linear") \
        if lin.from_pixels else None
    return BracketExposures(tuple(frames), rule=rule.times,
                            origin=given.origin if lin.on_times_scale else "unknown",
                            unit="relative", spread=spread)


def _names(frames: Sequence[FrameExposure]) -> str:
    names = [Path(f.source).name for f in frames]
    return ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")


def exposure_message(record: BracketExposures, *, hold_flag: str = "--hold-times"
                     ) -> str | None:
    """The run's one line about its exposures (None when there is nothing to say).

    Says, in one sentence: which frames' exposures moved from their given times and by
    how much (or, times held, which the pixels contradict), which frames had no time, and
    when the radiance is on a relative scale because no time is known.
    """
    label = {"exif": "EXIF times", "given": "given times", "raw": "raw files' ratios"}.get(
        record.origin, "times")
    parts = []
    if record.origin == "unknown":
        parts.append("no exposure times known: the exposures are the pixels' (a relative "
                     "scale)")
    timed = [f for f in record.frames if f.given is not None and f.used is not None]
    moved = [f for f in timed if abs(f.moved) > REPORT_DIFFERENCE]
    if moved:
        worst = max(moved, key=lambda f: abs(f.moved))
        how = {"measured": "measured from the pixels", "solved": "refined by the solve"}.get(
            worst.used_from, "changed")
        parts.append(f"exposures {how}: {len(moved)} of {len(timed)} frame(s) differ from "
                     f"the {label} by more than {100 * REPORT_DIFFERENCE:.0f}%, up to "
                     f"{100 * abs(worst.moved):.1f}% at {Path(worst.source).name} "
                     f"({hold_flag} keeps the times)")
    held = [(f, f.contradicted / f.given) for f in record.frames
            if f.contradicted is not None and f.given and f.used_from == "given"]
    if held:
        worst, ratio = max(held, key=lambda p: abs(math.log(p[1])))
        parts.append(f"the pixels contradict the {label} of {_names([f for f, _ in held])} "
                     f"(up to ×{max(ratio, 1 / ratio):.2f} at {Path(worst.source).name}); "
                     "held as given")
    untimed = [f for f in record.frames if f.given is None and f.used is not None]
    if untimed and record.origin != "unknown":
        parts.append(f"no exposure time for {_names(untimed)}: the solve's estimates are used")
    return "; ".join(parts) if parts else None


def record_from_diagnostics(sources: Sequence[str], exposures, exposure_times,
                            diagnostics: dict) -> BracketExposures:
    """The record of a model file written before records existed (versions 1-4), from the
    keys its diagnostics held: ``exposure_source``, ``refine_exposures``,
    ``contradicting_times`` and ``measured_exposures`` (the measurement's summary)."""
    origin = str(diagnostics.get("exposure_source") or "unknown").split("+")[0]
    if origin not in ("given", "exif", "raw"):
        origin = "unknown"
    refined = bool(diagnostics.get("refine_exposures", False))
    pixels_say = {str(c.get("frame")): _finite(c.get("estimated"))
                  for c in diagnostics.get("contradicting_times") or []}
    summary = diagnostics.get("measured_exposures") or None
    measured = list((summary or {}).get("measured") or [])
    frames = []
    for k, (src, e, t) in enumerate(zip(sources, np.atleast_1d(exposures), exposure_times)):
        e, t = _finite(e), _finite(t)
        was_measured = k < len(measured) and measured[k] is not None and e is not None
        if e is None:
            used_from = "given"
        elif was_measured:
            used_from = "measured"
        elif refined or t is None:
            used_from = "solved"
        else:
            used_from = "given"
        frames.append(FrameExposure(
            source=str(src), given=t, origin=origin if t is not None else "none",
            solved=e if used_from == "solved" else None,
            measured=e if was_measured else None, contradicted=pixels_say.get(str(src)),
            used=e, used_from=used_from))
    spread = None
    if summary and summary.get("log_sigma") is not None:
        spread = MeasurementSpread.from_summary(summary, by=str(summary.get("by",
                                                                            "calibration")))
    return BracketExposures(tuple(frames), rule="measured" if summary else "held",
                            origin=origin, unit="seconds", refined=refined, spread=spread)
