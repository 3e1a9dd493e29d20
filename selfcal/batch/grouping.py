"""Sessions by what the frames show: content-based grouping of a camera's frames.

A bracket is frames of one scene at several exposures.  The clock alone does not find
it: a photographer who sets each shutter speed by hand takes 10-120 s between shots (a
compact's 40-frame bracket takes half an hour), the last frame of a bracket may come
half a minute late, while two scenes can be shot 5 s apart.  So frames are grouped by
what they show; time only orders them and bounds the search (:func:`group_by_content`):

* frames of one *optical setup* only (camera body and picture settings, image size,
  lens, focal length: :func:`setup_key`), in capture order;
* a frame joins an open session of that setup (one whose last frame is at most
  ``window`` old, the ``open_sessions`` most recent) when its thumbnail agrees with the
  session's frames nearest in exposure (:func:`similarity`: the correlation of log codes
  over the pixels well exposed in both -- a monotone response makes it near 1 for one
  scene at two exposures, whatever the exposure ratio -- after registration: a small
  shift, then phase correlation [Kuglin1975] under a few small turns, for handheld
  phone brackets);
* a frame too dark or too bright to tell scenes apart (fewer than ``min_visible`` of
  its pixels well exposed: the ends of a long bracket) joins the most recent session
  whose exposures it continues, at most ``continue_stops`` past its darkest (brightest)
  frame, its few visible pixels where that frame is brightest (darkest); a session of
  such frames alone (a bracket begun at an end) joins the one nearest in time that it
  continues; these decisions are marked unsure;
* only when a thumbnail cannot be read (a truncated file), or the agreement is between
  the thresholds, does the time rule of :func:`.discover.group_sessions` decide (and
  the decision is marked unsure);
* a frame never joins a session that has its exposure already (the next bracket began),
  and two open sessions that a frame agrees with both are one (a pause mid-bracket left
  a frame that no neighbour in exposure could vouch for).

Thumbnails may be read lazily (``thumbs`` a function): a closed session drops its own,
so the search holds the open sessions' thumbnails only.  Every decision is written down
(:attr:`ContentGroup.reasons`, then :attr:`.discover.Session.reasons`), and a session any
of whose decisions was by time alone, by continuation or near the thresholds is
``unsure``.  All of this is ours except the phase correlation; the thresholds were
chosen on simulated tuning cards (:func:`selfcal.sim.hard_cards.write_hard_card` and
:func:`selfcal.sim.mixed_cards.write_mixed_card`, seeds < 1000) and are reported on
held-out seeds and on a real card (``python3 -m bench.batch_grouping``; the evidence is
in ``docs/decisions.md``, "Sessions by content").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: Frames whose thumbnails cannot be read are one session when one begins within this
#: many seconds of the previous one's end (start + exposure time); with ``--by-time``
#: (:func:`.discover.group_sessions`), a larger gap starts a new session.
DEFAULT_MAX_GAP = 10.0
#: Two exposures closer than this factor are the same exposure (``selfcal.calibrate``
#: counts exposures as distinct above 5 % too).
SAME_EXPOSURE = 1.05


@dataclass(frozen=True)
class GroupingRule:
    """The thresholds of :func:`group_by_content` (ours; the evidence for each value is
    in ``docs/decisions.md``, "Sessions by content").

    Attributes
    ----------
    max_gap : float
        Seconds: frames this close (end of one to start of the next) whose thumbnails
        cannot be read, or agree between ``differ`` and ``match``, are one session.
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
        Thumbnail pixels of translation at most each way (a handheld phone bracket
        moves by a few per cent of the frame).
    rotations : tuple of float
        Turns (degrees) of one thumbnail tried when the frames do not agree as they are
        (a phone bracket turns by a degree or two), the first one 0.
    rotate_above : float
        Turns are tried only when the best translation reaches this correlation.
    min_visible : float
        A frame with fewer than this fraction of its pixels well exposed is too dark or
        too bright to tell scenes apart: it joins a session it agrees with, or else one
        it continues (``continue_stops``); a disagreement is not trusted.
    continue_stops : float
        A frame too dark or too bright to compare (fewer than ``min_visible`` of its
        pixels well exposed) continues a session whose darkest (brightest) frame is at
        most this many stops brighter (darker), in the frame's direction.
    continue_rank : float
        ... and whose pixels it still shows (not black, not white) are, on average, at
        least at this rank (0-1) among the brightest (darkest) of that frame's.
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
    max_shift: int = 8
    rotations: tuple = (0.0, -1.5, 1.5, -3.0, 3.0)
    rotate_above: float = 0.3
    min_visible: float = 0.05
    continue_stops: float = 2.1
    continue_rank: float = 0.8
    low: int = 6
    high: int = 249
    open_sessions: int = 4
    neighbours: int = 3


def _prepared(a, rule: GroupingRule):
    """Log codes and the mask of well-exposed pixels of a thumbnail (float32)."""
    ok = (a > rule.low) & (a < rule.high)
    return np.log(np.maximum(a, 1.0)).astype(np.float32), ok


def _correlation(la, ok_a, lb, ok_b, need):
    """Pearson correlation of two log thumbnails over the pixels well exposed in both
    (None below ``need`` pixels), and that pixel count."""
    m = ok_a & ok_b
    n = int(np.count_nonzero(m))
    if n < need:
        return None, n
    x, y = la[m].astype(np.float64), lb[m].astype(np.float64)
    sx, sy = float(x.sum()), float(y.sum())
    sxx = float(np.dot(x, x)) - sx * sx / n
    syy = float(np.dot(y, y)) - sy * sy / n
    sxy = float(np.dot(x, y)) - sx * sy / n
    d = math.sqrt(max(sxx, 0.0) * max(syy, 0.0))
    return (sxy / d if d > 0 else 0.0), n


def _warped(lb, ok_b, angle, dx, dy):
    """``b`` turned by ``angle`` degrees about its centre and moved by ``(dx, dy)``
    pixels; pixels from outside the frame are not well exposed."""
    import cv2

    h, w = lb.shape
    m = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), float(angle), 1.0)
    m[:, 2] += (dx, dy)
    wl = cv2.warpAffine(lb, m, (w, h), flags=cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
    wm = cv2.warpAffine(ok_b.astype(np.uint8), m, (w, h), flags=cv2.INTER_NEAREST,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    inside = cv2.warpAffine(np.ones_like(lb), m, (w, h), flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0.0) > 0.999
    return wl, (wm > 0) & inside


def _phase_shift(la, ok_a, lb, ok_b):
    """The translation taking ``b`` onto ``a`` by phase correlation [Kuglin1975] of the
    log thumbnails (badly exposed pixels set to each one's mean: the exposure changes
    the level and the clipped areas, not where the structure is)."""
    import cv2

    def filled(l, ok):
        x = l.astype(np.float64).copy()
        x[~ok] = x[ok].mean() if ok.any() else 0.0
        return x

    win = cv2.createHanningWindow(la.shape[::-1], cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(filled(lb, ok_b), filled(la, ok_a), win)
    return dx, dy


def similarity(a, b, rule: GroupingRule = GroupingRule(), *, register: bool = True):
    """How well two thumbnails agree as one scene at two exposures, after registration.

    The correlation of log codes over the pixels well exposed in both (codes strictly
    between ``rule.low`` and ``rule.high``): a change of exposure scales codes through
    the (unknown, monotone) response, which a correlation of logs hardly sees.  ``b`` is
    registered onto ``a`` first, cheapest first, stopping at ``rule.match``: as it is;
    moved by up to a pixel; then, for each turn in ``rule.rotations`` (degrees), by the
    translation phase correlation finds ([Kuglin1975], at most ``rule.max_shift``
    pixels each way) and the pixel around it -- a handheld phone bracket moves and turns
    a little between frames (the turns only when the translation alone reaches
    ``rule.rotate_above``; none of this search with ``register`` False).  A moved
    comparison counts only over at least
    ``rule.min_visible`` of the pixels (the best of many small overlaps agrees by
    chance).  The registration search is ours.

    Returns
    -------
    (float or None, float)
        The best correlation (None when fewer than ``rule.min_overlap`` of the pixels
        are well exposed in both at every registration tried, or the thumbnails differ
        in size) and the fraction of pixels it used.

    References
    ----------
    .. [Kuglin1975] C. D. Kuglin, D. C. Hines, "The phase correlation image alignment
       method", Proc. IEEE Int. Conf. Cybernetics and Society, 1975, 163-165.
    """
    if a is None or b is None or a.shape != b.shape:
        return None, 0.0
    la, ok_a = _prepared(a, rule)
    lb, ok_b = _prepared(b, rule)
    need = max(16, rule.min_overlap * a.size)
    best, used = None, 0

    moved_need = max(need, rule.min_visible * a.size)

    def consider(c, n, moved=True):
        nonlocal best, used
        if moved and n < moved_need:    # the best of many small overlaps: by chance
            return False
        if c is not None and (best is None or c > best):
            best, used = c, n
        return best is not None and best >= rule.match

    c0, n0 = _correlation(la, ok_a, lb, ok_b, need)
    if consider(c0, n0, moved=False):
        return best, used / a.size
    for dy, dx in ((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx):
        if consider(*_shifted_correlation(la, ok_a, lb, ok_b, dy, dx, need)):
            return best, used / a.size
    if not register or not (ok_a.sum() >= moved_need and ok_b.sum() >= moved_need):
        return best, used / a.size
    s = int(rule.max_shift)
    for angle in rule.rotations:
        if angle != 0 and (best is None or best < rule.rotate_above):
            break                                # not even near: no turn will do
        rl, rm = (lb, ok_b) if angle == 0 else _warped(lb, ok_b, angle, 0.0, 0.0)
        px, py = _phase_shift(la, ok_a, rl, rm)
        px, py = max(-s, min(s, round(px))), max(-s, min(s, round(py)))
        for dy in (py - 1, py, py + 1):
            for dx in (px - 1, px, px + 1):
                if angle == 0 and abs(dx) <= 1 and abs(dy) <= 1:
                    continue                     # tried above
                if consider(*_shifted_correlation(la, ok_a, rl, rm, dy, dx, need)):
                    return best, used / a.size
    return best, used / a.size


def _shifted_correlation(la, ok_a, lb, ok_b, dy, dx, need):
    """:func:`_correlation` of ``a`` and ``b`` moved by whole pixels ``(dx, dy)``."""
    h, w = la.shape
    if abs(dy) >= h or abs(dx) >= w:
        return None, 0
    sa = (slice(max(dy, 0), h + min(dy, 0)), slice(max(dx, 0), w + min(dx, 0)))
    sb = (slice(max(-dy, 0), h + min(-dy, 0)), slice(max(-dx, 0), w + min(-dx, 0)))
    return _correlation(la[sa], ok_a[sa], lb[sb], ok_b[sb], need)


def well_exposed(thumb, rule: GroupingRule = GroupingRule()) -> float:
    """Fraction of a thumbnail's pixels strictly between ``rule.low`` and ``rule.high``."""
    return float(((thumb > rule.low) & (thumb < rule.high)).mean())


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
    blank: bool = False             # only frames too dark or too bright to compare

    @property
    def end(self) -> float:
        last = self.frames[-1]
        return last.time + (last.exposure_time or 0.0)

    def has_exposure(self, e: float) -> bool:
        return any(_same_exposure(e, g.relative_exposure) for g in self.frames)


def _compare(f, thumb, s: _Open, rule: GroupingRule):
    """Best correlation of ``f`` with the frames of ``s`` nearest in exposure (the
    whole registration search against the nearest one that shows enough, the small
    one against the others)."""
    e = f.relative_exposure
    near = sorted(range(len(s.frames)),
                  key=lambda k: abs(math.log(s.frames[k].relative_exposure / e)))
    best, searched = None, False
    for k in near[:rule.neighbours]:
        full = not searched and _blank(s.thumbs[k], rule) is None
        searched = searched or full
        c, _ = similarity(thumb, s.thumbs[k], rule, register=full)
        if c is not None and (best is None or c > best[0]):
            best = (c, s.frames[k])
        if best is not None and best[0] >= rule.match:
            break
    return best


def _verdict(best, rule: GroupingRule) -> str:
    if best is None:
        return "unknown"
    if best[0] >= rule.match:
        return "match"
    return "differ" if best[0] < rule.differ else "between"


def _blank(thumb, rule: GroupingRule) -> str | None:
    """``"dark"`` or ``"bright"`` for a thumbnail with too few well-exposed pixels to
    tell scenes apart (fewer than ``rule.min_visible``), None otherwise (or unreadable)."""
    if thumb is None or well_exposed(thumb, rule) >= rule.min_visible:
        return None
    return "dark" if float(np.median(thumb)) <= rule.low else "bright"


def _continues(f, thumb, side: str, s: _Open, rule: GroupingRule):
    """Whether blank frame ``f`` extends session ``s`` past its darkest (``side`` dark)
    or brightest frame by at most ``rule.continue_stops``, with its few visible pixels
    where that frame is brightest (darkest): a monotone response orders pixels alike at
    every exposure.  Returns ``(stops, nearest frame, rank)`` or None."""
    e = f.relative_exposure
    k = min(range(len(s.frames)), key=lambda i: s.frames[i].relative_exposure
            * (1 if side == "dark" else -1))
    g = s.frames[k]
    stops = math.log2(g.relative_exposure / e) * (1 if side == "dark" else -1)
    if not 0 < stops <= rule.continue_stops or s.thumbs[k] is None:
        return None
    other = s.thumbs[k]
    if other.shape != thumb.shape:
        return None
    seen = thumb > rule.low if side == "dark" else thumb < rule.high
    rank = None
    if int(seen.sum()) >= 3:         # the visible pixels: where g is brightest (darkest)?
        ref = np.sort(other.ravel())             # mid-rank of ties (clipped codes)
        v = other[seen]
        pct = float((np.searchsorted(ref, v, "left") + np.searchsorted(ref, v, "right"))
                    .mean()) / (2.0 * other.size)
        rank = float(pct if side == "dark" else 1.0 - pct)
        if rank < rule.continue_rank:
            return None
    return stops, g, rank


def _join_blank(f, thumb, side, recent, rule: GroupingRule) -> bool:
    """Put a blank frame into the most recent session it continues; False if none."""
    for s in reversed(recent):
        if s.blank or s.has_exposure(f.relative_exposure):
            continue
        hit = _continues(f, thumb, side, s, rule)
        if hit is None:
            continue
        stops, g, rank = hit
        s.frames.append(f)
        s.thumbs.append(thumb)
        s.reasons.append(
            f"{f.path.name}: too {side} to compare ({well_exposed(thumb, rule):.1%} of "
            f"its pixels well exposed); continues the exposures of {g.path.name} "
            f"({stops:.2f} stops {'darker' if side == 'dark' else 'brighter'}"
            + (f", its visible pixels at rank {rank:.2f} there" if rank is not None
               else "") + f"), the most recent session it continues "
            f"({max(0.0, f.time - s.end):.0f} s after its last frame)")
        s.unsure_join = True
        return True
    return False


def _absorb_blanks(open_: list, rule: GroupingRule) -> None:
    """Sessions of blank frames only (a bracket begun at an extreme) join the session
    nearest in time that they continue (:func:`_continues`), the blank session nearest
    in exposure to its session first, again until none does (each merge moves a
    session's end)."""
    while True:
        options = []
        for s in (x for x in open_ if x.blank):
            side = _blank(s.thumbs[0], rule) or "dark"
            chain = sorted(zip(s.frames, s.thumbs), key=lambda p: p[0].relative_exposure,
                           reverse=side == "dark")
            steps_ok = all(0 < math.log2(a[0].relative_exposure / b[0].relative_exposure)
                           * (1 if side == "dark" else -1) <= rule.continue_stops
                           for a, b in zip(chain, chain[1:]))
            for t in open_:
                if not steps_ok or t is s or t.blank or any(
                        t.has_exposure(g.relative_exposure) for g in s.frames):
                    continue
                gap = max(s.frames[0].time - t.end, t.frames[0].time - s.end)
                hit = _continues(chain[0][0], chain[0][1], side, t, rule)
                if gap <= rule.window and hit is not None:
                    options.append((hit[0], gap, id(s), s, t, hit, side, chain))
        if not options:
            return
        stops, _, _, s, t, (_, g, _), side, chain = min(options, key=lambda o: o[:3])
        _merge(t, s, open_, f"{chain[0][0].path.name} (too {side} to compare)"
               + (" and the frames with it" if len(chain) > 1 else "")
               + f" continue the exposures of {g.path.name} ({stops:.2f} stops), the "
               "nearest session in time: one session")
        t.unsure_join = True


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
        verdict = _verdict(best, rule)
        if s.blank and verdict == "differ":
            verdict = "unknown"          # a frame that shows almost nothing cannot differ
        scored.append((s, best, verdict))
    matches = sorted((x for x in scored if x[2] == "match"), key=lambda x: -x[1][0])
    name = f.path.name
    if matches:
        s, best, _ = matches[0]
        s.frames.append(f)
        s.thumbs.append(thumb)
        s.blank = s.blank and _blank(thumb, rule) is not None
        s.reasons.append(f"{name}: shows the scene of {best[1].path.name} "
                         f"(thumbnail correlation {best[0]:.3f})")
        for other, ob, _ in matches[1:]:
            if not any(s.has_exposure(g.relative_exposure) for g in other.frames):
                _merge(s, other, open_, f"{name} also shows the scene of "
                                        f"{ob[1].path.name} ({ob[0]:.3f}): one session")
        return
    side = _blank(thumb, rule)
    if side is not None and _join_blank(f, thumb, side, recent, rule):
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
        last.blank = last.blank and side is not None
        last.reasons.append(f"{name}: {what}, joined by time ({gap:.1f} s after the "
                            "previous frame)")
        last.unsure_join = True
        return
    open_.append(_Open(frames=[f], thumbs=[thumb],
                       reasons=[f"{name}: starts a session ({_why_new(scored, gap, rule)})"],
                       unsure_start=any(x[2] in ("unknown", "between") for x in scored),
                       blank=side is not None))


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
    into.blank = into.blank and other.blank
    open_.remove(other)


def group_by_content(frames: Sequence[Any],
                     thumbs: Sequence[np.ndarray | None] | Callable[[int], np.ndarray | None],
                     rule: GroupingRule = GroupingRule()
                     ) -> tuple[list[ContentGroup], list[tuple[Path, str]]]:
    """Group frames into bracketed sessions by what they show (time as a hint).

    Per optical setup (:func:`setup_key`), frames are placed in capture order
    (:func:`_place`); time orders them and bounds the search (a session stays open
    ``rule.window`` seconds, the ``rule.open_sessions`` most recent); what the frames
    show decides.  A session that can no longer be joined is closed and its thumbnails
    dropped, so that at most the open sessions' thumbnails are held at once when
    ``thumbs`` is a function (read lazily).

    Parameters
    ----------
    frames : sequence of FrameInfo
        With exposure times.
    thumbs : sequence or callable
        :func:`.thumbnails.thumbnail` of each frame (None where unreadable), or a function of the
        frame's index in ``frames`` that returns it (called once per frame, in capture
        order per setup).
    rule : GroupingRule

    Returns
    -------
    groups : list of ContentGroup
        Ordered by camera, then time (:func:`.discover.sessions_from_groups` names them).
    unassigned : list of (pathlib.Path, str)
    """
    thumb_of = thumbs if callable(thumbs) else thumbs.__getitem__
    by_setup: dict = {}
    for i, f in enumerate(frames):
        by_setup.setdefault(setup_key(f), []).append(i)
    built = []

    def close(sessions):
        for x in sessions:
            x.thumbs = []                       # never compared again: drop them
        built.extend(sessions)

    for key in sorted(by_setup, key=repr):
        open_: list = []
        order = sorted(by_setup[key], key=lambda i: (frames[i].time, frames[i].path.name))
        for i in order:
            f = frames[i]
            old = [x for x in open_ if f.time - x.end > rule.window]
            if old or len(open_) > rule.open_sessions:
                _absorb_blanks(open_, rule)
                open_.sort(key=lambda x: x.end)
                done = [x for x in open_ if f.time - x.end > rule.window]
                done += [x for x in open_[:max(0, len(open_) - rule.open_sessions)]
                         if x not in done]
                close(done)
                open_[:] = [x for x in open_ if x not in done]
            _place(f, thumb_of(i), open_, rule)
        _absorb_blanks(open_, rule)
        close(open_)
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
