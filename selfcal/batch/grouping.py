"""Sessions by what the frames show: content-based grouping of a camera's frames.

A bracket is frames of one scene at several exposures.  The clock alone does not find
it: a photographer who sets each shutter speed by hand takes 5-90 s between shots (and
may pause for minutes mid-bracket), while two scenes can be shot 5 s apart.  So frames
are grouped by what they show, with time as a hint (:func:`group_by_content`):

* frames of one *optical setup* only (camera body and picture settings, image size,
  lens, focal length: :func:`setup_key`);
* a frame joins an open session of that setup when its thumbnail agrees with the
  session's frames nearest in exposure, after a small shift (:func:`similarity`: the
  correlation of log codes over the pixels well exposed in both -- a monotone response
  makes it near 1 for one scene at two exposures, whatever the exposure ratio);
* when the thumbnails cannot be compared (too few pixels well exposed in both: a night
  scene's shortest exposures, or a frame whose pixels cannot be read), the time rule of
  :func:`.discover.group_sessions` decides, and the decision is marked unsure;
* a frame never joins a session that has its exposure already (the next bracket began),
  and two open sessions that a frame agrees with both are one (a pause mid-bracket left
  a frame that no neighbour in exposure could vouch for).

Every decision is written down (:attr:`ContentGroup.reasons`, then
:attr:`.discover.Session.reasons`), and a session any of
whose decisions was by time alone or near the thresholds is ``unsure``.  All of this is
ours; the thresholds were chosen on a simulated tuning card
(:func:`.simulate.write_mixed_card`, seed 11) and are reported on another (seed 23) and
on a real card (``python3 -m bench.batch_grouping``).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: Frames whose thumbnails cannot be compared are one session when one begins within this
#: many seconds of the previous one's end (start + exposure time); with ``--by-time``
#: (:func:`.discover.group_sessions`), a larger gap starts a new session.
DEFAULT_MAX_GAP = 10.0
#: Two exposures closer than this factor are the same exposure (``selfcal.calibrate``
#: counts exposures as distinct above 5 % too).
SAME_EXPOSURE = 1.05

#: Thumbnail width in pixels (height keeps the aspect ratio).
THUMB_WIDTH = 64


@dataclass(frozen=True)
class GroupingRule:
    """The thresholds of :func:`group_by_content`.

    Attributes
    ----------
    max_gap : float
        Seconds: frames this close (end of one to start of the next) whose thumbnails
        cannot be compared are one session.
    window : float
        Seconds: a session stays open this long after its last frame (a manual bracket's
        pauses are shorter).
    match : float
        Thumbnail correlation at and above which two frames show one scene.
    differ : float
        Correlation below which they show two; in between, time decides (unsure).
    min_overlap : float
        Fraction of the thumbnail well exposed in both frames for a comparison to count.
    max_shift : int
        Thumbnail pixels of shift tried each way (a handheld burst moves a little).
    low, high : int
        8-bit codes strictly between which a thumbnail pixel is well exposed.
    open_sessions : int
        Sessions of a setup a frame is compared with at most (most recent first).
    neighbours : int
        Frames of a session (nearest in exposure) a frame is compared with.
    """

    max_gap: float = DEFAULT_MAX_GAP
    window: float = 1800.0
    match: float = 0.70
    differ: float = 0.50
    min_overlap: float = 0.01
    max_shift: int = 2
    low: int = 6
    high: int = 249
    open_sessions: int = 4
    neighbours: int = 3


# ------------------------------------------------------------------------ thumbnails

def thumbnail(path, width: int = THUMB_WIDTH):
    """A small grey thumbnail of a rendered frame (uint8 codes), or None.

    Decoded at reduced size where the format allows (JPEG DCT scaling), averaged over
    boxes.  Returns None when the pixels cannot be read (a truncated file, say): the
    grouping then falls back on time, and the session's own work reports the file.
    """
    from PIL import Image

    try:
        with Image.open(path) as im:
            return _thumbnail_of(im, width)
    except Exception:  # noqa: BLE001 -- any unreadable frame: no thumbnail
        return None


def _thumbnail_of(im, width: int = THUMB_WIDTH):
    """:func:`thumbnail` of an open Pillow image (None when its pixels cannot be read)."""
    from PIL import Image

    try:
        w, h = im.size
        tw = max(1, min(int(width), w))
        th = max(1, round(tw * h / w))
        im.draft("RGB", (2 * tw, 2 * th))
        grey = im.convert("L") if im.mode in ("RGB", "L") else im.convert("RGB").convert("L")
        return np.asarray(grey.resize((tw, th), Image.Resampling.BOX), dtype=np.uint8)
    except Exception:  # noqa: BLE001 -- truncated or corrupt pixels: no thumbnail
        return None


def _read_one(pair, reader, thumbnails=True):
    """EXIF and thumbnail of one frame from one opening of the file (``reader`` is
    :func:`.discover.read_frame`)."""
    from ..errors import InputError

    try:
        info, thumb = reader(*pair, also=_thumbnail_of if thumbnails else None)
    except InputError as exc:
        return exc, None
    return info, (thumb if info.exposure_time is not None else None)


def _read_chunk(pairs, reader, thumbnails):
    return [_read_one(p, reader, thumbnails) for p in pairs]


#: Frames from which :func:`read_frames` reads in worker processes rather than threads.
PROCESS_THRESHOLD = 2000


def read_frames(pairs, reader, *, workers: int | None = None, thumbnails: bool = True):
    """EXIF and thumbnail of each ``(rendered, raw)`` pair, each file read once, in
    parallel: threads for a few files, processes (``spawn``-safe, chunks of 500) from
    :data:`PROCESS_THRESHOLD` on -- Pillow's EXIF parsing holds the GIL.

    ``reader`` is :func:`.discover.read_frame` (passed in: this module does not import
    the discovery).  Returns a list of ``(FrameInfo or InputError, thumbnail or None)``
    in input order.
    """
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    pairs = list(pairs)
    n = int(workers or min(8, os.cpu_count() or 1))
    if n <= 1 or len(pairs) < 8:
        return [_read_one(p, reader, thumbnails) for p in pairs]
    if len(pairs) < PROCESS_THRESHOLD:
        with ThreadPoolExecutor(max_workers=n) as pool:
            return list(pool.map(partial(_read_one, reader=reader, thumbnails=thumbnails),
                                 pairs))
    chunks = [pairs[i:i + 500] for i in range(0, len(pairs), 500)]
    spawn = multiprocessing.get_context("spawn")     # no fork of a threaded process
    with ProcessPoolExecutor(max_workers=n, mp_context=spawn) as pool:
        done = pool.map(partial(_read_chunk, reader=reader, thumbnails=thumbnails), chunks)
        return [x for chunk in done for x in chunk]


def _shifted(a, b, dy, dx):
    h, w = a.shape
    return (a[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)],
            b[max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)])


def similarity(a, b, rule: GroupingRule = GroupingRule()):
    """How well two thumbnails agree as one scene at two exposures.

    The correlation of log codes over the pixels well exposed in both (codes strictly
    between ``rule.low`` and ``rule.high``), the best over shifts of up to
    ``rule.max_shift`` pixels.  Exposure-normalised in effect: a change of exposure
    scales codes through the (unknown, monotone) response, which a correlation of logs
    hardly sees.

    Returns
    -------
    (float or None, float)
        The correlation (None when fewer than ``rule.min_overlap`` of the pixels are well
        exposed in both at every shift, or the thumbnails differ in size) and the
        fraction of pixels it used.
    """
    if a is None or b is None or a.shape != b.shape:
        return None, 0.0
    best, used = None, 0.0
    la, lb = np.log(np.maximum(a, 1.0)), np.log(np.maximum(b, 1.0))
    ok_a = (a > rule.low) & (a < rule.high)
    ok_b = (b > rule.low) & (b < rule.high)
    need = max(16, rule.min_overlap * a.size)
    s = int(rule.max_shift)
    shifts = [(0, 0)] + [(dy, dx) for dy in range(-s, s + 1) for dx in range(-s, s + 1)
                         if dy or dx]
    for dy, dx in shifts:
        if best is not None and best >= rule.match:
            break                        # agreement found: no need for the other shifts
        ma, mb = _shifted(ok_a, ok_b, dy, dx)
        m = ma & mb
        n = int(m.sum())
        if n < need:
            continue
        xa, xb = _shifted(la, lb, dy, dx)
        x, y = xa[m], xb[m]
        x, y = x - x.mean(), y - y.mean()
        d = math.sqrt(float((x * x).sum()) * float((y * y).sum()))
        c = float((x * y).sum()) / d if d > 0 else 0.0
        if best is None or c > best:
            best, used = c, n / a.size
    return best, used


# ------------------------------------------------------------------------ grouping

def setup_key(info) -> tuple:
    """Frames that can share a bracket: camera key, image size, lens, focal length."""
    return (info.camera, tuple(info.size), info.lens, getattr(info, "focal_length", None))


def _same_exposure(e1: float, e2: float) -> bool:
    return abs(math.log(e1 / e2)) < math.log(SAME_EXPOSURE)


@dataclass
class _Open:
    """A session being built."""

    frames: list
    thumbs: list
    reasons: list = field(default_factory=list)
    unsure_start: bool = False      # may belong to the session before it
    unsure_join: bool = False       # a frame joined by time alone

    @property
    def end(self) -> float:
        last = self.frames[-1]
        return last.time + (last.exposure_time or 0.0)

    def has_exposure(self, e: float) -> bool:
        return any(_same_exposure(e, g.relative_exposure) for g in self.frames)


def _compare(f, thumb, s: _Open, rule: GroupingRule):
    """Best correlation of ``f`` with the frames of ``s`` nearest in exposure."""
    e = f.relative_exposure
    near = sorted(range(len(s.frames)),
                  key=lambda k: abs(math.log(s.frames[k].relative_exposure / e)))
    best = None
    for k in near[:rule.neighbours]:
        c, _ = similarity(thumb, s.thumbs[k], rule)
        if c is not None and (best is None or c > best[0]):
            best = (c, s.frames[k])
    return best


def _verdict(best, rule: GroupingRule) -> str:
    if best is None:
        return "unknown"
    if best[0] >= rule.match:
        return "match"
    return "differ" if best[0] < rule.differ else "between"


def _place(f, thumb, open_: list, rule: GroupingRule) -> None:
    """Put frame ``f`` into an open session (or a new one), writing down why."""
    open_.sort(key=lambda s: s.end)
    recent = [s for s in open_ if f.time - s.end <= rule.window][-rule.open_sessions:]
    scored: list[tuple[_Open, tuple, str]] = []
    for s in reversed(recent):           # most recent first
        if s.has_exposure(f.relative_exposure):
            continue
        if any(x[2] == "match" for x in scored) and not s.unsure_start:
            continue                     # placed; only a doubtful start may be bridged
        best = _compare(f, thumb, s, rule)
        scored.append((s, best, _verdict(best, rule)))
    matches = sorted((x for x in scored if x[2] == "match"), key=lambda x: -x[1][0])
    name = f.path.name
    if matches:
        s, best, _ = matches[0]
        s.frames.append(f)
        s.thumbs.append(thumb)
        s.reasons.append(f"{name}: shows the scene of {best[1].path.name} "
                         f"(thumbnail correlation {best[0]:.3f})")
        for other, ob, _ in matches[1:]:
            if not any(s.has_exposure(g.relative_exposure) for g in other.frames):
                _merge(s, other, open_, f"{name} also shows the scene of "
                                        f"{ob[1].path.name} ({ob[0]:.3f}): one session")
        return
    last = open_[-1] if open_ else None
    gap = None if last is None else f.time - last.end
    entry = next((x for x in scored if x[0] is last), None)
    # (a session that was scored is the last one: neither is None then, nor the gap)
    if (entry is not None and last is not None and gap is not None
            and entry[2] in ("unknown", "between") and gap <= rule.max_gap):
        what = ("thumbnails not comparable (too few pixels well exposed in both)"
                if entry[2] == "unknown" else
                f"thumbnail correlation {entry[1][0]:.3f} between the thresholds")
        last.frames.append(f)
        last.thumbs.append(thumb)
        last.reasons.append(f"{name}: {what}, joined by time ({gap:.1f} s after the "
                            "previous frame)")
        last.unsure_join = True
        return
    open_.append(_Open(frames=[f], thumbs=[thumb],
                       reasons=[f"{name}: starts a session ({_why_new(scored, gap, rule)})"],
                       unsure_start=any(x[2] in ("unknown", "between") for x in scored)))


def _why_new(scored, gap, rule: GroupingRule) -> str:
    if gap is None:
        return "first frame of its camera setup"
    if not scored:
        return "no open session without its exposure"
    parts = []
    for s, best, verdict in scored:
        first = s.frames[0].path.name
        if verdict == "differ":
            parts.append(f"differs from the session of {first} ({best[0]:.3f})")
        elif verdict == "between":
            parts.append(f"unsure against the session of {first} ({best[0]:.3f}) and "
                         f"{gap:.0f} s later")
        else:
            parts.append(f"not comparable with the session of {first} and {gap:.0f} s "
                         f"later (> {rule.max_gap:g} s)")
    return ", ".join(parts)


def _merge(into: _Open, other: _Open, open_: list, why: str) -> None:
    pairs = sorted(zip(into.frames + other.frames, into.thumbs + other.thumbs),
                   key=lambda p: (p[0].time, p[0].path.name))
    into.frames = [p[0] for p in pairs]
    into.thumbs = [p[1] for p in pairs]
    into.reasons += other.reasons + [why]
    into.unsure_join = into.unsure_join or other.unsure_join
    open_.remove(other)


def group_by_content(frames: Sequence[Any], thumbs: Sequence[np.ndarray | None],
                     rule: GroupingRule = GroupingRule()
                     ) -> tuple[list[ContentGroup], list[tuple[Path, str]]]:
    """Group frames into bracketed sessions by what they show (time as a hint).

    Parameters
    ----------
    frames : sequence of FrameInfo
        With exposure times.
    thumbs : sequence
        :func:`thumbnail` of each frame (None where unreadable).
    rule : GroupingRule

    Returns
    -------
    groups : list of ContentGroup
        Ordered by camera, then time (:func:`.discover.sessions_from_groups` names them).
    unassigned : list of (pathlib.Path, str)
    """
    by_setup: dict = {}
    for f, t in zip(frames, thumbs):
        by_setup.setdefault(setup_key(f), []).append((f, t))
    built = []
    for key in sorted(by_setup, key=repr):
        open_: list = []
        for f, t in sorted(by_setup[key], key=lambda p: (p[0].time, p[0].path.name)):
            _place(f, t, open_, rule)
            if len(open_) > rule.open_sessions:    # never compared again: closed
                open_.sort(key=lambda s: s.end)
                built += open_[:-rule.open_sessions]
                del open_[:-rule.open_sessions]
        built += open_
    return _groups(built)


@dataclass
class ContentGroup:
    """A session as :func:`group_by_content` finds it (named by
    :func:`.discover.sessions_from_groups`).

    Attributes
    ----------
    frames : list of FrameInfo
        In capture order.
    reasons : list of str
        Why each frame is in it.
    unsure : bool
        Some decision was by time alone or near a threshold.
    """

    frames: list
    reasons: list
    unsure: bool = False


def _groups(built):
    groups, loose = [], []
    for s in built:
        if len(s.frames) < 2:
            loose.append((s.frames[0].path, "a single frame: no other frame of its camera "
                          "shows its scene at another exposure ("
                          + s.reasons[0].split("(", 1)[-1]))
            continue
        groups.append(ContentGroup(frames=list(s.frames), reasons=list(s.reasons),
                                   unsure=s.unsure_start or s.unsure_join))
    groups.sort(key=lambda g: (g.frames[0].camera, g.frames[0].time, g.frames[0].path.name))
    return groups, loose
