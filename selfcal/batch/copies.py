"""Copies of one card in a library: the same frames in several folders, used once.

Photo libraries hold copies (a card dumped twice, a backup folder beside the working
one).  Frames that are one file -- the same camera, capture time (with sub-seconds),
exposure, image size, file size and first 64 kB (:func:`frame_identity`) -- are one
frame for the session search (:func:`collapse_copies`); once sessions are found, each
session takes all of its frames from one copy, the copy that holds most of them
(:func:`choose_copies`), and says which copies it skipped.  Ours.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

#: Bytes at the start of a file hashed to tell copies of a frame from other frames.
PREFIX_BYTES = 65536


def _prefix_hash(path: Path, n: int = PREFIX_BYTES) -> str | None:
    try:
        with open(path, "rb") as fh:
            return hashlib.sha1(fh.read(n)).hexdigest()
    except OSError:
        return None


def frame_identity(info, *, prefix_bytes: int = PREFIX_BYTES) -> tuple:
    """What makes two files copies of one frame: camera key, capture time, exposure
    time, image size, file size and the SHA-1 of the first ``prefix_bytes``."""
    try:
        nbytes = info.path.stat().st_size
    except OSError:
        nbytes = None
    return (info.camera, info.time, info.exposure_time, tuple(info.size), nbytes,
            _prefix_hash(info.path, prefix_bytes))


def collapse_copies(infos: Sequence, thumbs: Sequence, *, prefix_bytes: int = PREFIX_BYTES):
    """One frame per file content: the first copy (by path) stands for the others.

    Only frames that agree on camera, capture time, exposure, size and file size are
    hashed (the first ``prefix_bytes`` of each).

    Returns
    -------
    infos, thumbs : list
        The frames kept (in input order) and their thumbnails.
    copies : dict
        Path of a kept frame -> the FrameInfo of its other copies.
    """
    cheap: dict = {}
    for i, f in enumerate(infos):
        try:
            nbytes = f.path.stat().st_size
        except OSError:
            nbytes = None
        key = (f.camera, f.time, f.exposure_time, tuple(f.size), nbytes)
        cheap.setdefault(key, []).append(i)
    drop: set = set()
    copies: dict = {}
    for idx in cheap.values():
        if len(idx) < 2:
            continue
        by_hash: dict = {}
        for i in idx:
            by_hash.setdefault(_prefix_hash(infos[i].path, prefix_bytes), []).append(i)
        for h, same in by_hash.items():
            if h is None or len(same) < 2:
                continue
            same.sort(key=lambda i: str(infos[i].path))
            copies[infos[same[0]].path] = [infos[i] for i in same[1:]]
            drop.update(same[1:])
    keep = [i for i in range(len(infos)) if i not in drop]
    return [infos[i] for i in keep], [thumbs[i] for i in keep], copies


def _roots(paths: Sequence[Path]) -> list:
    """Each path without the tail all of them share (the folder of each copy)."""
    parts = [p.parts for p in paths]
    k = 0
    while all(len(x) > k for x in parts) and len({x[-1 - k] for x in parts}) == 1:
        k += 1
    return [Path(*x[:len(x) - k]) if len(x) > k else Path(x[0]) for x in parts]


def choose_copies(sessions: Sequence, copies: dict) -> list:
    """Each session's frames from one copy; returns ``[(skipped path, kept path)]``.

    For a session with copied frames, the copy folder (the path each copy of a frame
    does not share with the others) that holds most of its frames is chosen (ties: the
    first by name); each frame is taken from there when it is there.  The sessions'
    frames are replaced in place, and a reason says where the frames were taken from
    and which copies were skipped.
    """
    skipped = []
    for s in sessions:
        options = []
        for f in s.frames:
            alts = [f] + list(copies.get(f.path, ()))
            options.append(list(zip(_roots([a.path for a in alts]), alts)))
        if all(len(o) == 1 for o in options):
            continue
        count: dict = {}
        for o in options:
            for root in {r for r, _ in o}:
                count[root] = count.get(root, 0) + 1
        best = min(count, key=lambda r: (-count[r], str(r)))
        frames: list = []
        told: dict = {}
        for f, o in zip(s.frames, options):
            chosen = next((a for r, a in o if r == best), o[0][1])
            frames.append(chosen)
            others = [(r, a.path) for r, a in o if a is not chosen]
            skipped += [(p, chosen.path) for _, p in others]
            if others:
                key = (next(r for r, a in o if a is chosen), tuple(r for r, _ in others))
                told.setdefault(key, []).append(chosen.path.name)
        for (root, elsewhere), names in told.items():
            s.reasons.append(
                f"copies: {len(names)} frame{'s' if len(names) > 1 else ''} ("
                + (names[0] if len(names) == 1 else f"{names[0]} .. {names[-1]}")
                + f") taken from {root}; the same files (camera, capture time, size, "
                f"first {PREFIX_BYTES // 1024} kB) skipped in "
                + ", ".join(map(str, elsewhere)))
        s.frames = frames
    used = {f.path for s in sessions for f in s.frames}
    for kept, others in copies.items():         # copies of frames in no session
        if kept not in used and not any(o.path in used for o in others):
            skipped += [(o.path, kept) for o in others]
    return sorted(skipped, key=lambda x: str(x[0]))

