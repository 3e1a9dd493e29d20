"""A harder simulated card: slow manual brackets, long tripod brackets, phone brackets.

For the content grouping's tuning and tests (:mod:`selfcal.batch.grouping`), the cases
where the clock misleads (issue 37).  Three bodies shoot, each with its own clock:

* a tripod camera (``Simcam T1``) and a compact (``Simcam C2``):

  - ``slow`` -- a manual bracket of 5-9 frames one stop apart, each shutter speed set by
    hand, 10-120 s between frames (the speeds down from the metered one, then up);
  - ``long`` -- a long tripod bracket of 30-40 frames 1/3 stop apart (10-13 stops) of a
    scene of low contrast (its log radiance squeezed to 60 %), 3-60 s between frames: its
    darkest frames are black and its brightest white, nothing to compare;
  - ``neighbours`` -- two slow brackets of *different* scenes, the second begun one minute
    (50-70 s) after the first ended: closer in time than the first's own frames;
  - ``late`` -- an auto bracket (3 or 5 frames 0.3 s apart) whose last frame is taken
    20-40 s after the others;
  - ``aeb`` -- an auto bracket, 0.3 s apart (where the clock alone is right);

* a phone (``Simphone P3``, 4:3 frames, another size) shooting ``phone`` brackets: 3-5
  frames 0.1-0.4 s apart, 1-2 stops apart, handheld (each frame shifted by up to 4 % of
  the width each way and turned by up to 1.5 degrees each way), and ``phone_neighbours`` (two of them, of
  different scenes, one minute apart).

Frames are numbered per body in shot order and filed flat in ``DCIM/1NNSIMCM`` folders.
Scenes are those of :func:`.mixed_cards.mixed_scene` (each its own layout).
:func:`copy_card` copies a card into another folder, file times kept, as a library
holding two copies of one card does.  All of this is ours.
"""

from __future__ import annotations

import shutil
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from .camera import default_pipeline
from .cards import SimulatedBody, SimulatedLibrary, SimulatedSession, default_bodies
from .mixed_cards import CardWriter, add_sessions, mixed_scene
from .stacks import simulate_stack
from .tone import ToneCurve

#: Shutter speeds 1/3 stop apart, 1/16384 s to 2 s.
THIRD_STOPS = tuple(2.0 ** (k / 3.0) for k in range(-42, 4))
#: What each body shoots, in turn (every kind appears when there are as many events).
CAMERA_KINDS = ("slow", "long", "neighbours", "late", "aeb")
PHONE_KINDS = ("phone", "phone_neighbours")


def hard_bodies() -> list:
    """The card's bodies: two cameras of :func:`.cards.default_bodies` and a phone with
    its own response and frame size (4:3)."""
    a, b = default_bodies()
    a = SimulatedBody("Simcam", "T1", a.serial, a.lens, a.pipeline, prefix="IMG_")
    b = SimulatedBody("Simcam", "C2", b.serial, b.lens, b.pipeline, prefix="DSC_")
    phone = SimulatedBody("Simphone", "P3", "3003", "Simphone back camera 4.2mm f/1.8",
                          default_pipeline(curves=ToneCurve.gamma(2.4), seed=3),
                          prefix="PXL_")
    return [a, b, phone]


def _speeds(rng, n: int, step: int) -> list:
    """``n`` shutter speeds ``step`` thirds of a stop apart, in shot order: down from
    a metered one, then up."""
    lo = int(rng.integers(0, len(THIRD_STOPS) - step * (n - 1)))
    speeds = [THIRD_STOPS[lo + step * i] for i in range(n)]
    start = int(rng.integers(1, n - 1))
    return speeds[start::-1] + speeds[start + 1:]


def _event(kind, rng, sid, clock):
    """The shots of one event: ``[(scene, speed, time, handheld, mode)]``, clock after."""
    shots = []

    def slow(scene, speeds, pause):
        nonlocal clock
        for i, t in enumerate(speeds):
            if i:
                clock += float(rng.uniform(*pause))
            shots.append((scene, t, clock, False, 1))
            clock += t

    def burst(scene, speeds, gap, handheld, mode):
        nonlocal clock
        for t in speeds:
            shots.append((scene, t, clock, handheld, mode))
            clock += t + float(rng.uniform(*gap))

    if kind == "slow":
        slow(sid, _speeds(rng, int(rng.integers(5, 10)), 3), (10.0, 120.0))
    elif kind == "long":
        slow(sid, _speeds(rng, int(rng.integers(30, 41)), 1), (3.0, 60.0))
    elif kind == "neighbours":
        slow(sid, _speeds(rng, int(rng.integers(5, 8)), 3), (10.0, 120.0))
        clock += float(rng.uniform(50.0, 70.0))
        slow(sid + 1, _speeds(rng, int(rng.integers(5, 8)), 3), (10.0, 120.0))
    elif kind in ("late", "aeb"):
        n = 3 if rng.random() < 0.5 else 5
        mid = int(rng.integers(12, len(THIRD_STOPS) - 12))
        order = [0, -6, 6] if n == 3 else [0, -6, 6, -12, 12]     # 2 stops apart
        speeds = [THIRD_STOPS[mid + o] for o in order]
        burst(sid, speeds[:-1] if kind == "late" else speeds, (0.3, 0.3), False, 2)
        if kind == "late":
            clock += float(rng.uniform(20.0, 40.0))
            burst(sid, speeds[-1:], (0.3, 0.3), False, 2)
    else:                                               # phone, phone_neighbours
        for k in range(1 if kind == "phone" else 2):
            if k:
                clock += float(rng.uniform(50.0, 70.0))
            n = int(rng.integers(3, 6))
            step = int(rng.choice([3, 6]))
            mid = int(rng.integers(15, len(THIRD_STOPS) - 15))
            offs = [0] + [s * step * ((i + 2) // 2) for i, s in
                          zip(range(n - 1), [-1, 1] * 3)]
            burst(sid + k, [THIRD_STOPS[mid + o] for o in offs], (0.1, 0.4), True, 0)
    return shots, clock


def _render(scene, pipe, t, scale, motion, seed, size, quality):
    """One frame: the scene moved (``(dy, dx, degrees)``) about its centre, cropped."""
    import cv2

    h, w = size
    H, W = scene.shape[:2]
    dy, dx, deg = motion
    m = cv2.getRotationMatrix2D((W / 2.0, H / 2.0), deg, 1.0)
    m[:, 2] += (dx, dy)
    moved = cv2.warpAffine(scene, m, (W, H), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT)
    y0, x0 = (H - h) // 2, (W - w) // 2
    stack = simulate_stack(np.ascontiguousarray(moved[y0:y0 + h, x0:x0 + w]), pipe, [t],
                           exposure_scale=scale, seed=seed, jpeg_quality=quality)
    assert stack.jpeg_bytes is not None
    return stack.jpeg_bytes[0], float(stack.exposure_times[0])


def write_hard_card(root, *, seed: int = 0, events_per_body: int = 5, height: int = 64,
                    width: int = 96, phone_size=(72, 96), per_folder: int = 60,
                    jpeg_quality: int = 90, start=datetime(2024, 9, 1, 9, 0, 0)
                    ) -> SimulatedLibrary:
    """Write a card of hard brackets (see the module) with the truth of its sessions.

    Parameters
    ----------
    root : path
    seed : int
        Everything (events, scenes, motion, noise, timing) derives from it.
    events_per_body : int
        Events per camera body (drawn from :data:`CAMERA_KINDS`, each kind once first);
        the phone has ``max(2, events_per_body // 2)`` (:data:`PHONE_KINDS`).
    height, width : int
        The cameras' frame size; ``phone_size`` the phone's ``(height, width)``.

    Returns
    -------
    SimulatedLibrary
        ``sessions`` in order of their first frame; each a scene at several exposures.
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    bodies = hard_bodies()
    base = (start - datetime(1970, 1, 1)).total_seconds()
    plans, flat = [], set()
    for b, body in enumerate(bodies):
        pool = PHONE_KINDS if b == 2 else CAMERA_KINDS
        n = max(2, events_per_body // 2) if b == 2 else events_per_body
        kinds = list(pool) + [pool[int(rng.integers(len(pool)))]
                              for _ in range(max(0, n - len(pool)))]
        kinds = [kinds[i] for i in rng.permutation(len(kinds))][:n]
        clock = base + 5.0 * b
        for e, kind in enumerate(kinds):
            shots, clock = _event(kind, rng, seed * 10_000 + 100 * b + 2 * e, clock)
            if kind == "long":
                flat.add(seed * 10_000 + 100 * b + 2 * e)
            plans.append((b, shots))
            clock += float(rng.uniform(120.0, 1200.0))
    all_shots = sorted((when, b, s, t, hh, mode) for b, shots in plans
                       for s, t, when, hh, mode in shots)
    margin = 12
    scenes, scales = {}, {}
    for b, s in sorted({(x[1], x[2]) for x in all_shots}):
        h, w = phone_size if b == 2 else (height, width)
        scenes[s] = mixed_scene(h + 2 * margin - 4, w + 2 * margin - 4, s)
        if s in flat:
            mid = float(np.median(scenes[s]))
            scenes[s] = (mid * (np.maximum(scenes[s], 1e-6) / mid) ** 0.6).astype(np.float32)
        speeds = [x[3] for x in all_shots if x[2] == s]
        median = float(np.median(scenes[s].mean(axis=2)))
        scales[s] = 0.18 / (median * float(np.sqrt(min(speeds) * max(speeds))))
    counters = [0] * len(bodies)
    truth: dict = {}
    for k, (when, b, s, t, handheld, mode) in enumerate(all_shots):
        body = bodies[b]
        size = phone_size if b == 2 else (height, width)
        motion = (0.0, 0.0, 0.0)
        if handheld:
            reach = 0.04 * size[1]
            motion = (float(rng.uniform(-reach, reach)) * size[0] / size[1],
                      float(rng.uniform(-reach, reach)), float(rng.uniform(-1.5, 1.5)))
        data, t = _render(scenes[s], body.pipeline, t, scales[s], motion,
                          seed * 7919 + k, size, jpeg_quality)
        stamp = datetime(1970, 1, 1) + timedelta(seconds=round(when, 2))
        bias = round(float(np.log2(t * scales[s] * 4)) * 3) / 3
        path = CardWriter(root, body, per_folder, counters, b).write(data, stamp, t, mode, bias)
        truth.setdefault((b, s), []).append((path, t, stamp))
    lib = SimulatedLibrary(root=root)
    add_sessions(lib, truth, bodies)
    return lib


def copy_card(lib: SimulatedLibrary, dest) -> SimulatedLibrary:
    """Copy a written card to ``dest`` (every file, times kept: ``shutil.copy2``), as a
    library with a second copy of a card holds it.  Returns the copy's truth."""
    dest = Path(dest)
    out = SimulatedLibrary(root=dest)
    for f in sorted(p for p in Path(lib.root).rglob("*") if p.is_file()):
        target = dest / f.relative_to(lib.root)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(f, target)
    for s in lib.sessions:
        out.sessions.append(SimulatedSession(
            body=s.body, frames=[dest / Path(p).relative_to(lib.root) for p in s.frames],
            exposure_times=list(s.exposure_times), start=s.start, pipeline=s.pipeline,
            seed=s.seed))
    return out
