"""The response path's exposures in a session: given, from EXIF, or from the raws.

:func:`plan_response` decides, for the frames :func:`selfcal.calibrate` chose for the
response path, where their exposures come from -- the caller's times, the EXIF times, or
the ratios of their raws ([Lin2011]_ §5: "the exposure ratio can be directly computed by
dividing the raw values between two images", which removes the shutter's error and the
exponential ambiguity), put in seconds by the EXIF times -- and says why in the session's
:class:`SessionReport`.  The precedence and the scaling are ours.

References
----------
.. [Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

import math
import sys
import warnings as _warnings
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType

import numpy as np

from ..errors import CalibrationError, InputError, SelfcalWarning
from ..io.images import format_exposure_time
from .raw_ratios import raw_exposure_ratios

__all__ = ["DISTINCT_EXPOSURE_FACTOR", "SessionReport", "ResponsePlan", "plan_response",
           "times_by_frame", "distinct_exposures", "noun", "file_names", "seconds_text"]

#: Two exposures count as distinct when they differ by more than this factor.
DISTINCT_EXPOSURE_FACTOR = 1.05


def seconds_text(t) -> str:
    text = format_exposure_time(t, unknown="unknown")
    return text if text == "unknown" else text + " s"


def noun(paths) -> str:
    kinds = {p.suffix.lower() for p in paths}
    if kinds <= {".jpg", ".jpeg"}:
        name = "JPEG"
    elif kinds <= {".png"}:
        name = "PNG"
    elif kinds <= {".tif", ".tiff"}:
        name = "TIFF"
    else:
        name = "image"
    return f"{len(paths)} {name}" + ("s" if len(paths) != 1 else "")


def file_names(paths, limit=4) -> str:
    names = [Path(p).name for p in paths]
    if len(names) > limit:
        return ", ".join(names[:limit]) + f", … ({len(names)} in all)"
    return ", ".join(names)


def distinct_exposures(values) -> int:
    """Number of distinct exposures among known values (factor DISTINCT_EXPOSURE_FACTOR)."""
    vals = sorted(v for v in values if v is not None)
    if not vals:
        return 0
    count, last = 1, vals[0]
    for v in vals[1:]:
        if v > last * DISTINCT_EXPOSURE_FACTOR:
            count += 1
            last = v
    return count


class SessionReport:
    """Why each path was (or was not) taken, and the warnings (each also emitted)."""

    def __init__(self):
        self.reasons: list[str] = []
        self.warnings: list[str] = []

    def warn(self, msg: str):
        self.warnings.append(msg)
        # attribute the warning to the caller's line, whichever piece of this module warns
        level = 1
        frame: FrameType | None = sys._getframe(0)
        while frame is not None and frame.f_code.co_filename == __file__:
            frame, level = frame.f_back, level + 1
        _warnings.warn(msg, SelfcalWarning, stacklevel=level)


@dataclass
class ResponsePlan:
    """The response path's frames and exposures, as :func:`plan_response` decided them."""

    frames: list = field(default_factory=list)
    times: list | None = None          # passed to calibrate_response (None: it reads EXIF)
    exposure_kind: str | None = None   # CalibrationResult.exposure_source
    raw_exposures: dict = field(default_factory=dict)
    raw_decided: bool = False          # the raw ratios decided whether the path is taken


def plan_response(group, pair_data, infos, eff, given_times, exposure_source,
                   report: SessionReport) -> ResponsePlan:
    """The response path's frames and where their exposures come from, with the reasons.

    Raw exposure ratios (Lin et al. §5) decide a group whose frames have raws but fewer
    than two known exposures: without an exposure change between the raws, the response
    path is not taken.
    """
    plan = ResponsePlan(frames=list(group.frames))
    raw_rel, framed = _raw_ratios(plan.frames, pair_data, exposure_source, report)
    if group.status == "raw?":
        plan.raw_decided = True
        if distinct_exposures([v[0] for v in raw_rel.values()]) < 2:
            report.reasons.append(
                f"no response path: the raws of {noun(framed)} show no exposure "
                "change between them")
            plan.frames = []
            return plan
    reasons = _response_exposures(plan, raw_rel, infos, eff, given_times, exposure_source,
                                  report)
    shown = sorted({t for t in (eff.get(p) for p in plan.frames) if t is not None})
    span = f" ({seconds_text(shown[0])} … {seconds_text(shown[-1])})" if len(shown) >= 2 else ""
    n_exp = distinct_exposures([eff.get(p) for p in plan.frames])
    header = (f"response path: {noun(plan.frames)} of one scene"
              + (f" at {n_exp} exposures{span}" if n_exp >= 2 else " at different exposures"))
    report.reasons += [header] + reasons
    return plan


def _raw_ratios(frames, pair_data, exposure_source, report: SessionReport):
    """Relative exposures of the frames with raws, from the raws themselves.

    :func:`selfcal.exposure.raw_ratios.raw_exposure_ratios` (Lin et al. §5: "the exposure ratio can be
    directly computed by dividing the raw values between two images"), on the two halves
    of :func:`selfcal.exposure.raw_ratios.split_thumbnails` (pixels chosen on one, measured on the
    other: no selection bias).  Returns
    ``(raw_rel, framed)``: frame → (relative exposure, connected set), for the frames whose
    ratio is known, and the frames that have a raw.
    """
    pd_by_rendered = {Path(pd.rendered_name): pd for pd in pair_data}
    framed = [p for p in frames if p in pd_by_rendered]
    raw_rel = {}
    if len(framed) >= 2 and exposure_source in ("auto", "raw"):
        try:
            halves = [pd_by_rendered[p].thumbnail for p in framed]
            rel, rep = raw_exposure_ratios([v for v, _ in halves],
                                           select=[c for _, c in halves],
                                           statistic="sum", max_side=1024)
        except InputError as exc:
            report.warn(f"exposure ratios from the raws failed ({exc}); using EXIF times")
        else:
            for p, e, cmp_ in zip(framed, rel, rep["component"]):
                if cmp_ >= 0 and np.isfinite(e):
                    raw_rel[p] = (float(e), cmp_)
    return raw_rel, framed


def _response_exposures(plan: ResponsePlan, raw_rel, infos, eff, given_times,
                        exposure_source, report: SessionReport) -> list[str]:
    """Fill in the plan's exposures: given, unknown, from the raws, or EXIF (in that order
    of precedence); returns the reasons that say which."""
    frames = plan.frames
    if given_times is not None:
        plan.times, plan.exposure_kind = [given_times[p] for p in frames], "given"
        return ["exposure times: given by the caller"]
    if exposure_source == "unknown":
        plan.times, plan.exposure_kind = [None] * len(frames), "unknown"
        return ["exposure times: unknown (solved jointly with the response)"]
    if raw_rel and exposure_source in ("auto", "raw") and len(raw_rel) >= 2:
        plan.times, plan.exposure_kind, plan.raw_exposures = _times_from_raws(
            frames, raw_rel, eff, report.warn)
        n_used = sum(1 for p in frames if p in raw_rel)
        dev = _exif_deviation(plan.raw_exposures)
        return [
            f"exposure ratios from the raws (Lin et al. 2011 §5: median ratio of "
            f"unclipped, well-exposed raw values) for {n_used} of {len(frames)} frames"
            + (f"; EXIF times differ from them by up to {100 * dev:.1f}%"
               if dev is not None else "")
            + ("; in seconds via the EXIF times" if any(
                eff.get(p) is not None for p in raw_rel) else
               "; relative to the first frame (no EXIF times)")]
    if exposure_source == "raw":
        raise CalibrationError(
            "exposure_source='raw' needs at least two response frames with raws "
            f"(have {len(raw_rel)}: {file_names(list(raw_rel)) or 'none'})")
    plan.exposure_kind = "exif"
    if any(infos[p].exposure_time is None and eff.get(p) is not None for p in frames):
        plan.times = [eff[p] for p in frames]
    missing = [p for p in frames if eff.get(p) is None]
    if len(missing) == len(frames):
        plan.exposure_kind = "unknown"
        return ["exposure times: none in EXIF; solved jointly with the response (up to the "
                "exponential ambiguity of Lin et al. §5 -- raws of the same frames would "
                "fix it)"]
    return ["exposure times: EXIF" + (
        f" ({len(missing)} frame(s) without: solved jointly)" if missing else "")]


def times_by_frame(exposure_times, rendered):
    if exposure_times is None:
        return None
    if isinstance(exposure_times, dict):
        lookup = {Path(k).resolve(): v for k, v in exposure_times.items()}
        times = [lookup.get(p.resolve()) for p in rendered]
        return {p: (None if t is None else float(t)) for p, t in zip(rendered, times)}
    times = list(exposure_times)
    if len(times) != len(rendered):
        raise InputError(f"{len(times)} exposure times given for {len(rendered)} rendered "
                         f"frames ({file_names(rendered)})")
    out = {}
    for p, t in zip(rendered, times):
        if t is not None:
            t = float(t)
            if not (math.isfinite(t) and t > 0):
                raise InputError(f"exposure time {t!r} must be a positive number", p)
        out[p] = t
    return out


def _times_from_raws(frames, raw_rel, eff, warn):
    """Response exposures: raw ratios (per connected set), in seconds via EXIF."""
    comps: dict[int, list[Path]] = {}
    for p in frames:
        if p in raw_rel:
            comps.setdefault(raw_rel[p][1], []).append(p)
    times: dict[Path, float | None] = {p: None for p in frames}
    kind = "raw"
    for members in comps.values():
        logs = {p: math.log(raw_rel[p][0]) for p in members}
        anchors = [math.log(eff[p]) - logs[p] for p in members if eff.get(p) is not None]
        if anchors:
            offset = float(np.mean(anchors))
        elif len(comps) == 1 and not any(eff.get(p) is not None for p in frames):
            offset = 0.0
        else:
            warn(f"exposure ratios from the raws of {file_names(members)} cannot be put on the "
                 "scale of the other frames (no EXIF times among them); those frames are "
                 "treated as unknown")
            continue
        for p in members:
            times[p] = math.exp(logs[p] + offset)
    for p in frames:
        if p not in raw_rel:
            kind = "raw+exif"
            times[p] = eff.get(p)
    raw_exposures = {str(p): {"raw_relative": raw_rel[p][0], "exif": eff.get(p),
                              "used": times[p]} for p in frames if p in raw_rel}
    return [times[p] for p in frames], kind, raw_exposures


def _exif_deviation(raw_exposures):
    """Largest relative deviation of EXIF times from the raw-derived (used) exposures."""
    devs = [math.log(v["exif"] / v["used"]) for v in raw_exposures.values()
            if v["exif"] is not None and v["used"] is not None]
    if len(devs) < 2:
        return None
    devs = np.array(devs) - np.mean(devs)
    return float(np.exp(np.max(np.abs(devs))) - 1.0)
