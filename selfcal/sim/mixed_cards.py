"""A simulated card as photographers fill it: AEB bursts, manual brackets, scenes mixed.

For the content-based grouping's tests and its tuning (:mod:`.grouping`).  Each camera
body shoots, in turn and with its own clock, a sequence of brackets of *different* scenes:

* ``aeb`` -- an auto-exposure bracket: 3 or 5 frames 0.3 s apart (EXIF ExposureMode 2),
  handheld (each frame shifted by up to 2 pixels);
* ``manual`` -- a manual bracket on a tripod: 5-8 frames, each shutter speed set by hand
  (5-90 s apart, EXIF ExposureMode 1), and sometimes a pause of 3-6 minutes mid-bracket;
  the speeds are not always in order (down from the metered one, then up);
* ``pair`` -- two scenes shot 4-6 s apart (an AEB burst each): two sessions;
* ``alternate`` -- two scenes on two tripods, shot frame about (A, B, A, B, ...), 4-8 s
  apart: two sessions whose frames interleave.

Frames are numbered per body in shot order and filed flat in ``DCIM/1NNSIMCM`` folders,
the bodies' frames interleaved in time.  Scenes differ by seed (patch order, hues,
texture of :func:`selfcal.make_scene`) and by a shuffle of its 3 x 4 blocks, a
flip, a roll and a smooth illumination field drawn per scene, so that no two share a layout.  Ours.
"""

from __future__ import annotations

import io as _io
from collections.abc import Sequence
from datetime import datetime, timedelta

import numpy as np

from .scenes import make_scene
from .stacks import simulate_stack
from .cards import SimulatedLibrary, SimulatedSession, camera_exif, default_bodies

#: Shutter speeds of the simulated brackets (seconds).
SPEEDS = tuple(2.0 ** k for k in range(-12, 1))
KINDS = ("aeb", "manual", "pair", "alternate")


def mixed_scene(height: int, width: int, seed: int) -> np.ndarray:
    """A scene of its own layout: :func:`selfcal.make_scene` in shuffled blocks,
    flipped, rolled and lit by a smooth random field (±2 stops), 2 pixels larger each way
    than asked (for the handheld shift)."""
    rng = np.random.default_rng(10_000 + seed)
    h, w = height + 4, width + 4
    bh, bw = -(-h // 3), -(-w // 4)
    full = make_scene(3 * bh, 4 * bw, seed=seed, dynamic_range_stops=10.0)
    blocks = [full[i * bh:(i + 1) * bh, j * bw:(j + 1) * bw] for i in range(3)
              for j in range(4)]
    order = rng.permutation(12)
    scene = np.concatenate([np.concatenate([blocks[order[4 * i + j]] for j in range(4)],
                                           axis=1) for i in range(3)], axis=0)[:h, :w]
    if rng.random() < 0.5:
        scene = scene[:, ::-1]
    if rng.random() < 0.5:
        scene = scene[::-1]
    scene = np.roll(scene, int(rng.integers(w)), axis=1)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    field = np.zeros((h, w))
    for _ in range(3):
        cy, cx, r = rng.random(), rng.random(), 0.2 + 0.4 * rng.random()
        field += rng.uniform(-1, 1) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / r ** 2)
    return np.ascontiguousarray(scene * (2.0 ** (2.0 * field))[..., None], dtype=np.float32)


def _bracket(rng, kind: str) -> list:
    """Shutter speeds in shot order."""
    if kind in ("aeb", "pair", "alternate"):
        n = 3 if rng.random() < 0.5 else 5
        mid = int(rng.integers(4, len(SPEEDS) - 4))
        order = [0, -2, 2] if n == 3 else [0, -2, 2, -4, 4]     # metered, under, over
        return [SPEEDS[mid + o] for o in order]
    n = int(rng.integers(5, 9))
    lo = int(rng.integers(0, len(SPEEDS) - n))
    speeds = list(SPEEDS[lo:lo + n])
    start = int(rng.integers(1, n - 1))
    return speeds[start::-1] + speeds[start + 1:]             # down, then up


class CardWriter:
    """Writes the frames of one body to a card: numbering per body, ``DCIM/1NNSIMCM``
    folders of ``per_folder`` files, EXIF (exposure mode and bias set per frame)."""

    def __init__(self, root, body, per_folder, counters, index):
        self.root, self.body, self.per_folder = root, body, per_folder
        self.counters, self.index = counters, index

    def write(self, image_bytes, when, t, mode, bias):
        import piexif

        self.counters[self.index] += 1
        n = self.counters[self.index]
        folder = self.root / "DCIM" / f"{100 + (n - 1) // self.per_folder}SIMCM"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{self.body.prefix}{n:04d}.JPG"
        exif = camera_exif(self.body, when=when, exposure_time=t, bias=bias)
        d = piexif.load(exif)
        d["Exif"][piexif.ExifIFD.ExposureMode] = mode
        out = _io.BytesIO()
        piexif.insert(piexif.dump(d), image_bytes, out)
        path.write_bytes(out.getvalue())
        return path


def _render(scene, pipe, t, scale, shift, seed, size, quality):
    h, w = size
    dy, dx = shift
    crop = scene[2 + dy:2 + dy + h, 2 + dx:2 + dx + w]
    stack = simulate_stack(crop, pipe, [t], exposure_scale=scale, seed=seed,
                           jpeg_quality=quality)
    assert stack.jpeg_bytes is not None   # a JPEG card's frames are encoded
    return stack.jpeg_bytes[0], float(stack.exposure_times[0])


def _scale(scene, speeds) -> float:
    median = float(np.median(scene.mean(axis=2)))
    return 0.18 / (median * float(np.sqrt(min(speeds) * max(speeds))))


def _shoot(kind, rng, scenes, clock, seed):
    """The shots of one event: ``[(scene index, speed, time, shift, mode)]`` and the clock
    after it."""
    shots = []
    if kind in ("aeb", "pair"):
        for k in range(1 if kind == "aeb" else 2):
            if k:
                clock += float(rng.uniform(4.0, 6.0))
            for t in _bracket(rng, "aeb"):
                shots.append((scenes[k], t, clock, tuple(rng.integers(-2, 3, 2)), 2))
                clock += t + 0.3
    elif kind == "manual":
        speeds = _bracket(rng, "manual")
        pause_at = int(rng.integers(2, len(speeds) - 1)) if rng.random() < 0.6 else -1
        for i, t in enumerate(speeds):
            if i:
                clock += float(rng.uniform(5.0, 90.0))
                if i == pause_at:
                    clock += float(rng.uniform(180.0, 360.0))
            shots.append((scenes[0], t, clock, (0, 0), 1))
            clock += t
    else:                                       # alternate
        a, b = _bracket(rng, "manual")[:4], _bracket(rng, "manual")[:4]
        for ta, tb in zip(a, b):
            for s, t in ((scenes[0], ta), (scenes[1], tb)):
                shots.append((s, t, clock, (0, 0), 1))
                clock += t + float(rng.uniform(4.0, 8.0))
    return shots, clock


def write_mixed_card(root, *, seed: int = 0, events_per_body: int = 6, bodies=None,
                     height: int = 64, width: int = 96, per_folder: int = 40,
                     jpeg_quality: int = 90,
                     start=datetime(2024, 6, 1, 9, 0, 0)) -> SimulatedLibrary:
    """Write a card of mixed brackets (see the module) with the truth of its sessions.

    Parameters
    ----------
    root : path
    seed : int
        Everything (events, scenes, noise, timing) derives from it.
    events_per_body : int
        Events per body, each drawn from :data:`KINDS` (every kind appears when there
        are four events or more).
    bodies : list of SimulatedBody, optional
        Default :func:`.simulate.default_bodies`.
    height, width : int
        Frame size.

    Returns
    -------
    SimulatedLibrary
        ``sessions`` in shot order per body; each a scene at several exposures.
    """
    from pathlib import Path

    root = Path(root)
    rng = np.random.default_rng(seed)
    bodies = default_bodies() if bodies is None else list(bodies)
    lib = SimulatedLibrary(root=root)
    counters = [0] * len(bodies)
    base = (start - datetime(1970, 1, 1)).total_seconds()
    plans = []
    for b, body in enumerate(bodies):
        kinds = list(KINDS) + [KINDS[int(rng.integers(len(KINDS)))]
                               for _ in range(max(0, events_per_body - len(KINDS)))]
        kinds = [kinds[i] for i in rng.permutation(len(kinds))][:events_per_body]
        clock = base + 3.0 * b
        for e, kind in enumerate(kinds):
            sid = seed * 10_000 + 100 * b + 2 * e
            shots, clock = _shoot(kind, rng, (sid, sid + 1), clock, seed)
            plans.append((b, shots))
            clock += float(rng.uniform(5.0, 1200.0))
    all_shots = sorted(((when, b, s, t, shift, mode) for b, shots in plans
                        for s, t, when, shift, mode in shots))
    scenes: dict[int, np.ndarray] = {}
    scales: dict[int, float] = {}
    truth: dict[tuple[int, int], list[tuple[Path, float, datetime]]] = {}
    for s in {x[2] for x in all_shots}:
        scenes[s] = mixed_scene(height, width, s)
        speeds = [x[3] for x in all_shots if x[2] == s]
        scales[s] = _scale(scenes[s], speeds)
    for k, (when, b, s, t, shift, mode) in enumerate(all_shots):
        body = bodies[b]
        data, t = _render(scenes[s], body.pipeline, t, scales[s], shift, seed * 7919 + k,
                          (height, width), jpeg_quality)
        stamp = datetime(1970, 1, 1) + timedelta(seconds=round(when, 2))
        bias = round(float(np.log2(t * scales[s] * 4)) * 3) / 3
        path = CardWriter(root, body, per_folder, counters, b).write(data, stamp, t, mode, bias)
        truth.setdefault((b, s), []).append((path, t, stamp))
    add_sessions(lib, truth, bodies)
    return lib


def add_sessions(lib: SimulatedLibrary, truth: dict, bodies: Sequence) -> None:
    """The card's true sessions into ``lib``, in the order they began: ``truth`` maps
    ``(body index, scene seed)`` to the session's ``(path, exposure time, stamp)``."""
    for (b, s), frames in sorted(truth.items(), key=lambda x: x[1][0][2]):
        lib.sessions.append(SimulatedSession(
            body=bodies[b], frames=[f[0] for f in frames],
            exposure_times=[f[1] for f in frames], start=frames[0][2],
            pipeline=bodies[b].pipeline, seed=s))
