"""A bracket's exposures as one typed record: given, solved, measured, used, and why.

Every stage that needs a frame's exposure asks this record; none re-reads EXIF or parses a
provenance string.  The pieces:

* :class:`GivenTime` -- one frame's time as the caller gave it or the file's EXIF (or a raw
  file's) says, read **once** (:func:`read_given_times`), with the f-number and ISO beside
  it, so both units the library uses are at hand and converting is a multiplication:

  - ``seconds``: seconds at the first timed frame's ISO and aperture (the calibration's
    unit, :attr:`selfcal.ResponseModel.exposures`);
  - ``relative``: ``t · ISO/100 / N²`` (the merge's unit: brackets of one session, shot at
    other settings, come out on one radiance scale);

* :class:`FrameExposure` -- one frame's record after a calibration or a merge: the given
  time, the Eq. 8 solve's estimate ([Lin2011] §5), the exposure measured from the pixels
  (:mod:`.measured`, :mod:`.linear`), whether the pixels contradict the time, and which
  of them is used;
* :class:`BracketExposures` -- the frames' records, the rule that chose (:class:`ExposureRule`),
  and the statistics of the measurement (:class:`MeasurementSpread`, for the merge's σ).

The rule for given times (ours, one for EXIF times and ``--times`` alike, calibration and
merge alike; docs/decisions.md, "Given times: measured by default, one rule"):

* ``"measured"`` (default): a time is a nominal value; the exposure used is the one the
  pixels measure through the curve (the times keep their scale and trend, and a frame's
  deviation from the trend is kept in proportion to how far the pixels see it: exact
  shutters stay as they are);  times the pixels contradict are refined in the solve;
* ``"held"`` (``--hold-times``): every given time is used exactly; a contradiction is
  reported and makes the verdict doubtful.

Frames without a time take the solve's or the measurement's exposure under both rules.

References
----------
[Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import InputError
from ..io.exif import ExposureInfo, read_exposure_info
from ..io.images import is_path
from ..io.raw import is_raw_path, read_raw_exposure_info
from ..typing import ExposureTimes

__all__ = ["GivenTime", "GivenTimes", "FrameExposure", "BracketExposures", "MeasurementSpread",
           "ExposureRule", "read_given_times", "RULES", "DEFAULT_RULE", "ORIGINS", "USED_FROM"]

#: The values of the rule for given times (:class:`ExposureRule`).
RULES = ("measured", "held")
#: The default rule: measured (docs/decisions.md, "Given times: measured by default").
DEFAULT_RULE = "measured"
#: Where a given time came from: the caller, the file's EXIF, a raw file's ratios, nowhere.
ORIGINS = ("given", "exif", "raw", "none")
#: Which of a frame's exposures is used.
USED_FROM = ("given", "solved", "measured")

#: Where a frame's given time came from (one of :data:`ORIGINS`) and which of its
#: exposures is used (one of :data:`USED_FROM`): checked where a record is read from a file.
Origin = str
UsedFrom = str


@dataclass(frozen=True)
class ExposureRule:
    """How a calibration and a merge treat given times (one rule, :data:`RULES`).

    Attributes
    ----------
    times : {"measured", "held"}
        ``"measured"`` (default, :data:`DEFAULT_RULE`): the exposures used are measured from
        the pixels, the times keeping their scale and trend; times the pixels contradict
        are refined in the solve.  ``"held"``: every given time is used as it is.
    refine : {"auto", True}
        The solve of Eq. 8 ([Lin2011] §5) under ``"measured"``: ``"auto"`` refines the times
        the pixels contradict (unless most are: then the times are wrong, and the verdict
        says so); True treats every time as a prior.  Ignored under ``"held"``.
    trend : {"times", "pixels"}
        What sets the measured exposures' trend over the bracket: the times' (default; the
        pixels cannot see it, the exponential ambiguity of [Lin2011] §5) or the pixels'
        ratios as they are.
    """

    times: str = DEFAULT_RULE
    refine: Literal["auto", True] = "auto"
    trend: str = "times"

    def __post_init__(self):
        if self.times not in RULES:
            raise InputError(f"the rule for given times must be one of {', '.join(RULES)}, "
                             f"not {self.times!r}")
        if self.refine not in ("auto", True):
            raise InputError(f"refine must be 'auto' or True, not {self.refine!r} "
                             "(hold the times with --hold-times)")
        if self.trend not in ("times", "pixels"):
            raise InputError(f"trend must be 'times' or 'pixels', not {self.trend!r}")

    @property
    def held(self) -> bool:
        """Every given time is used as it is."""
        return self.times == "held"

    @property
    def measured(self) -> bool:
        """The exposures used are measured from the pixels."""
        return self.times == "measured"

    def solve_refines(self, contradicted: int, known: int, unusable_share: float) -> bool:
        """Whether the solve treats the given times as priors (refines them).

        ``"held"``: never.  ``refine=True``: always.  ``"auto"``: when the pixels contradict
        some times but fewer than ``unusable_share`` of the ``known`` ones (more, and the
        times are wrong or belong to other frames: refining would hide it).
        """
        if self.held or known < 2:
            return False
        if self.refine is True:
            return True
        return bool(contradicted) and contradicted / known < unusable_share


@dataclass(frozen=True)
class GivenTime:
    """One frame's time as given: the caller's, or the file's EXIF (raw or rendered).

    Attributes
    ----------
    exposure_time : float or None
        The time in seconds as given (None: unknown).
    f_number, iso : float or None
        From EXIF where the time came from there (None for the caller's times).
    origin : {"given", "exif", "raw", "none"}
        Where the time came from (:data:`ORIGINS`).
    """

    exposure_time: float | None
    f_number: float | None = None
    iso: float | None = None
    origin: Origin = "given"

    @property
    def known(self) -> bool:
        return self.exposure_time is not None

    @property
    def relative(self) -> float | None:
        """``t · ISO/100 / N²`` (the caller's times as they are): the merge's unit."""
        if self.exposure_time is None:
            return None
        return ExposureInfo(self.exposure_time, self.f_number, self.iso).relative_exposure

    def seconds_at(self, reference: GivenTime) -> float | None:
        """The time that would expose the frame equally at ``reference``'s ISO and aperture."""
        t = self.exposure_time
        if t is None:
            return None
        if self.iso and reference.iso:
            t *= self.iso / reference.iso
        if self.f_number and reference.f_number:
            t *= (reference.f_number / self.f_number) ** 2
        return t


@dataclass(frozen=True)
class GivenTimes:
    """Every frame's :class:`GivenTime`, read once (:func:`read_given_times`).

    ``seconds`` and ``relative`` hold both units side by side, one number per frame (None
    where unknown); ``to_relative[k]`` is the factor ``relative[k] / seconds[k]`` (for a
    frame without a time, the bracket's median factor).
    """

    times: tuple[GivenTime, ...]
    sources: tuple[str, ...]
    origin: str
    read_from_files: bool = False
    seconds: tuple[float | None, ...] = field(init=False)
    relative: tuple[float | None, ...] = field(init=False)
    to_relative: tuple[float, ...] = field(init=False)

    def __post_init__(self):
        reference = next((g for g in self.times if g.known), None)
        seconds = tuple(None if reference is None else g.seconds_at(reference)
                        for g in self.times)
        relative = tuple(g.relative for g in self.times)
        factors = [r / s for r, s in zip(relative, seconds) if r is not None and s]
        common = float(np.median(factors)) if factors else 1.0
        object.__setattr__(self, "seconds", seconds)
        object.__setattr__(self, "relative", relative)
        object.__setattr__(self, "to_relative", tuple(
            r / s if r is not None and s else common for r, s in zip(relative, seconds)))

    def __len__(self) -> int:
        return len(self.times)

    @property
    def any_known(self) -> bool:
        return any(g.known for g in self.times)

    def log_seconds(self) -> np.ndarray:
        """Log of :attr:`seconds` (NaN where unknown), the solve's ``log_times``."""
        return np.array([np.nan if s is None else math.log(s) for s in self.seconds])

    def subset(self, keep: Sequence[int]) -> GivenTimes:
        """The given times of frames ``keep`` (their units re-derived: the reference frame
        of ``seconds`` is the first timed frame kept)."""
        return GivenTimes(tuple(self.times[k] for k in keep),
                          tuple(self.sources[k] for k in keep), self.origin,
                          self.read_from_files)


def _checked_time(value, source: str) -> float | None:
    if value is None:
        return None
    try:
        t = float(value)
    except (TypeError, ValueError):
        raise InputError(f"exposure time {value!r} is not a number", source) from None
    if not math.isfinite(t) or t <= 0:
        raise InputError(f"exposure time {value!r} must be a positive number", source)
    return t


def read_given_times(frames: Sequence, exposure_times: ExposureTimes | None = None,
                     sources: Sequence[str] | None = None,
                     *, origin: str = "given") -> GivenTimes:
    """Each frame's given time: the caller's (checked: the one validator), else EXIF.

    Parameters
    ----------
    frames : sequence
        Paths (EXIF is read from each: rendered files with Pillow, raw files with
        :func:`selfcal.io.raw.read_raw_exposure_info`) or arrays (no time).
    exposure_times : sequence of float or None, optional
        The caller's times, one per frame (None = unknown for that frame).  When given,
        EXIF is not read.
    sources : sequence of str, optional
        The frames' names in messages (default: the path, or ``array #k``).
    origin : {"given", "raw"}
        Where the caller's times came from (``"raw"``: the caller measured them from raw
        files, :mod:`.plan`).

    Raises
    ------
    InputError
        A time that is not a positive number, or a count that differs from the frames'
        (the message names the frame).
    """
    n = len(frames)
    names = tuple(str(s) for s in sources) if sources is not None else tuple(
        str(f) if is_path(f) else f"array #{k}" for k, f in enumerate(frames))
    if exposure_times is not None:
        given = list(exposure_times)
        if len(given) != n:
            raise InputError(f"{len(given)} exposure times given for {n} frames "
                             "(--times takes one per image)")
        times = tuple(GivenTime(_checked_time(t, src), origin=origin if t is not None
                                else "none") for t, src in zip(given, names))
        kind = origin if any(g.known for g in times) else "unknown"
        return GivenTimes(times, names, kind)
    out = []
    for f in frames:
        if not is_path(f):
            out.append(GivenTime(None, origin="none"))
            continue
        if Path(f).is_file() and Path(f).stat().st_size == 0:
            raise InputError("the file is empty", f)
        info = read_raw_exposure_info(f) if is_raw_path(f) else read_exposure_info(f)
        out.append(GivenTime(info.exposure_time, info.f_number, info.iso,
                             origin="exif" if info.exposure_time is not None else "none"))
    kind = "exif" if any(g.known for g in out) else "unknown"
    return GivenTimes(tuple(out), names, kind, read_from_files=True)


@dataclass(frozen=True)
class MeasurementSpread:
    """What the measurement of exposures from the pixels knows of its own precision
    (:func:`selfcal.exposure.measured.measure_response_exposures`): the merge's σ uses it.

    Attributes
    ----------
    log_sigma : float
        A measured frame's posterior spread in ln exposure.
    trend_log_sigma : float
        The uncertainty of the times' trend over the bracket (ln, per ln exposure).
    measurement_log_sigma : float
        The pairs' disagreement (:func:`selfcal.exposure.linear.fit_log_sigma`).
    shutter_log_sigma : float or None
        The shutters' scatter beyond it (None when the trend is the pixels').
    shrink : float
        The share of a frame's deviation from the trend kept.
    trend : {"times", "pixels"}
    by : {"calibration", "merge", "linear"}
        Which stage measured.
    reduce : int
        The files' DCT scale of the pre-pass (1: full size or kept codes).
    """

    log_sigma: float
    trend_log_sigma: float = 0.0
    measurement_log_sigma: float = 0.0
    shutter_log_sigma: float | None = None
    shrink: float = 1.0
    trend: str = "times"
    by: str = "calibration"
    reduce: int = 1

    @classmethod
    def from_summary(cls, summary: dict, by: str) -> MeasurementSpread:
        """From :func:`~selfcal.exposure.measured.measure_response_exposures`' summary."""
        return cls(log_sigma=float(summary["log_sigma"]),
                   trend_log_sigma=float(summary.get("trend_log_sigma") or 0.0),
                   measurement_log_sigma=float(summary.get("measurement_log_sigma")
                                               or summary["log_sigma"]),
                   shutter_log_sigma=(None if summary.get("shutter_log_sigma") is None
                                      else float(summary["shutter_log_sigma"])),
                   shrink=float(summary.get("shrink", 1.0)), trend=str(summary.get("trend",
                                                                              "times")),
                   by=by, reduce=int(summary.get("reduce", 1)))


@dataclass(frozen=True)
class FrameExposure:
    """One frame's exposures, in one unit (the bracket's, :attr:`BracketExposures.unit`).

    Attributes
    ----------
    source : str
        The frame's name (path, or ``array #k``).
    given : float or None
        The given time in the bracket's unit (None: unknown).
    origin : {"given", "exif", "raw", "none"}
        Where ``given`` came from.
    solved : float or None
        The Eq. 8 solve's exposure ([Lin2011] §5), on the times' scale (None: not solved,
        e.g. a frame the calibration ignored, or a merge without calibration).
    measured : float or None
        The exposure measured from the pixels, on the times' scale (None: not measured).
    contradicted : float or None
        Where the pixels contradict the given time by more than
        :data:`selfcal.exposure.times.CONTRADICTION_FACTOR`: the exposure they say instead.
    used : float or None
        The exposure used (None: the frame was not used).
    used_from : {"given", "solved", "measured"}
        Which of them ``used`` is.
    """

    source: str
    given: float | None
    origin: Origin = "given"
    solved: float | None = None
    measured: float | None = None
    contradicted: float | None = None
    used: float | None = None
    used_from: UsedFrom = "given"

    @property
    def moved(self) -> float:
        """``used / given − 1`` (0 where either is unknown): how far the time moved."""
        if self.given is None or self.used is None:
            return 0.0
        return self.used / self.given - 1.0

    def as_dict(self) -> dict:
        return {"source": self.source, "given": self.given, "origin": self.origin,
                "solved": self.solved, "measured": self.measured,
                "contradicted": self.contradicted, "used": self.used,
                "used_from": self.used_from}

    @classmethod
    def from_dict(cls, d: dict) -> FrameExposure:
        return cls(source=str(d["source"]), given=d.get("given"),
                   origin=str(d.get("origin", "given")), solved=d.get("solved"),
                   measured=d.get("measured"), contradicted=d.get("contradicted"),
                   used=d.get("used"), used_from=str(d.get("used_from", "given")))


@dataclass(frozen=True)
class BracketExposures:
    """A bracket's exposures, frame by frame, and the rule that chose them.

    Attributes
    ----------
    frames : tuple of FrameExposure
    rule : {"measured", "held"}
        The rule for given times (:class:`ExposureRule`).
    origin : {"given", "exif", "raw", "unknown"}
        Where the given times came from (``"unknown"``: none was given).
    unit : {"seconds", "relative"}
        ``"seconds"``: seconds at the first timed frame's ISO and aperture (a calibration);
        ``"relative"``: ``t · ISO/100 / N²`` (a merge).  The caller's times are in their own
        unit in both.
    refined : bool
        The solve treated the given times as priors.
    spread : MeasurementSpread or None
        The measurement's precision (None: nothing was measured).
    """

    frames: tuple[FrameExposure, ...]
    rule: str = DEFAULT_RULE
    origin: str = "unknown"
    unit: str = "seconds"
    refined: bool = False
    spread: MeasurementSpread | None = None
    #: The exposure used per frame (NaN for frames not used), the frames' names, their
    #: given times: read off :attr:`frames`.
    used: np.ndarray = field(init=False, repr=False, compare=False)
    sources: list[str] = field(init=False, repr=False, compare=False)
    given: list[float | None] = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "used", np.array(
            [np.nan if f.used is None else f.used for f in self.frames], dtype=float))
        object.__setattr__(self, "sources", [f.source for f in self.frames])
        object.__setattr__(self, "given", [f.given for f in self.frames])

    def __len__(self) -> int:
        return len(self.frames)

    def contradictions(self) -> list[FrameExposure]:
        """The frames whose given time the pixels contradict."""
        return [f for f in self.frames if f.contradicted is not None]

    def moved(self, threshold: float = 0.0) -> list[FrameExposure]:
        """Frames whose used exposure differs from the given time by more than
        ``threshold`` (relative)."""
        return [f for f in self.frames if abs(f.moved) > threshold]

    def largest_move(self) -> FrameExposure | None:
        moved = self.moved()
        return max(moved, key=lambda f: abs(f.moved)) if moved else None

    @property
    def used_from(self) -> str:
        """What most used exposures are: ``"measured"``, ``"solved"`` or ``"given"``
        (``"measured"`` when any frame's is)."""
        kinds = {f.used_from for f in self.frames if f.used is not None}
        for kind in ("measured", "solved"):
            if kind in kinds:
                return kind
        return "given"

    def with_frames(self, frames: Sequence[FrameExposure], *,
                    spread: MeasurementSpread | None = None) -> BracketExposures:
        """The record with ``frames`` (and ``spread``, when given) in place of its own."""
        return replace(self, frames=tuple(frames),
                       spread=self.spread if spread is None else spread)

    def as_dict(self) -> dict:
        """JSON-ready (the model file's ``"exposures"`` section)."""
        return {"rule": self.rule, "origin": self.origin, "unit": self.unit,
                "refined": self.refined,
                "spread": None if self.spread is None else vars(self.spread).copy(),
                "frames": [f.as_dict() for f in self.frames]}

    @classmethod
    def from_dict(cls, d: dict) -> BracketExposures:
        spread = d.get("spread")
        return cls(frames=tuple(FrameExposure.from_dict(f) for f in d["frames"]),
                   rule=d.get("rule", DEFAULT_RULE), origin=d.get("origin", "unknown"),
                   unit=d.get("unit", "seconds"), refined=bool(d.get("refined", False)),
                   spread=None if spread is None else MeasurementSpread(**spread))

    def frame_named(self, source: str) -> FrameExposure | None:
        for f in self.frames:
            if f.source == source:
                return f
        return None

    def describe_source(self) -> str:
        """Where the used exposures came from, in words (``HDRResult.exposure_source``
        keeps them): ``"given"``, ``"exif"``, ``"measured+exif"``, ``"exif+model"``, ..."""
        kind = self.used_from
        origin = self.origin if self.origin != "unknown" else ""
        if kind == "given":
            return origin or "given"
        if kind == "measured":
            return f"measured+{origin}" if origin else "measured"
        return f"{origin}+model" if origin else "model"


def frame_names(sources: Sequence[str]) -> list[str]:
    """The frames' file names (arrays keep ``array #k``)."""
    return [Path(s).name for s in sources]
