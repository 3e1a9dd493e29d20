"""The session search at scale: 10⁴ and 10⁵ frames, time and peak memory, one process.

What is measured is the *session search* alone (:func:`selfcal.batch.grouping.group_by_content`
given frame infos and thumbnails), not the reading of files (``python3 -m bench.batch_scale``
times discovery on a written card).  The frames are synthetic: three bodies taking
turns, each shooting brackets of its own kind in turn -- AEB bursts of 5 (0.3 s apart),
slow manual brackets of 7 (10-120 s apart), handheld phone brackets of 4 (moved by up
to 3 thumbnail pixels and turned by up to 1.5 degrees) -- of 64 scenes in rotation
(:func:`selfcal.sim.mixed_cards.mixed_scene`, grey), 1-10 minutes between brackets.
Each 64 × 43 thumbnail is rendered when asked for (an sRGB-like curve, noise seeded
by frame) by a function of the frame's index; the time spent rendering is taken out
of the search's time.

Side by side, each in a process of its own (so that its peak RSS is its own):

* **lazy** -- the search as ``selfcal batch`` runs it, thumbnails asked for in capture
  order and dropped when a session closes;
* **before (aa4f879)** -- the content grouping before issue 37, given every thumbnail
  in a list (as it was called).

Printed per run: frames, sessions found and exact, search seconds, µs per frame, the
process's peak RSS and its RSS before the search (the frame infos alone), and the load
average.

    python3 -m bench.batch_sessions_scale                     # 10⁴ and 10⁵ frames
    python3 -m bench.batch_sessions_scale --frames 10000
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from .tables import REPO, finish, start, table

SCENES = 64
KINDS = ("aeb", "slow", "phone")


def synthetic_frames(n: int, seed: int = 0):
    """``(infos, plan, truth)``: FrameInfo per frame in capture order, how to render
    each thumbnail ``(scene, exposure, dy, dx, degrees)``, the session of each frame."""
    from selfcal.batch.discover import FrameInfo

    rng = np.random.default_rng(seed)
    bodies = [("Simcam", "T1", "1001", (96, 64)), ("Simcam", "C2", "2002", (96, 64)),
              ("Simphone", "P3", "3003", (96, 72))]
    clocks = [1.7e9 + 5.0 * b for b in range(3)]
    counters = [0, 0, 0]
    rows, session = [], 0
    while len(rows) < n:
        b = session % 3
        kind = KINDS[b]
        scene = session % SCENES
        if kind == "aeb":
            mid = float(rng.uniform(-9, -2))
            stops, gaps, moved = [0, -2, 2, -4, 4], [0.3] * 4, False
        elif kind == "slow":
            mid = float(rng.uniform(-9, -3))
            stops = [0, -1, -2, -3, 1, 2, 3]
            gaps, moved = list(rng.uniform(10, 120, 6)), False
        else:
            mid = float(rng.uniform(-9, -3))
            stops, gaps, moved = [0, -2, 2, -4], list(rng.uniform(0.1, 0.4, 3)), True
        t = clocks[b]
        for k, s in enumerate(stops):
            if k:
                t += gaps[k - 1]
            exposure = 2.0 ** (mid + s)
            motion = ((float(rng.uniform(-3, 3)), float(rng.uniform(-3, 3)),
                       float(rng.uniform(-1.5, 1.5))) if moved else (0.0, 0.0, 0.0))
            counters[b] += 1
            make, model, serial, size = bodies[b]
            rows.append((t, FrameInfo(
                path=Path(f"/synthetic/{model}/F{counters[b]:07d}.JPG"), raw=None,
                make=make, model=model, serial=serial, lens="", time=t, time_source="exif",
                exposure_time=exposure, f_number=None, iso=None, exposure_bias=None,
                size=size, kind="jpeg"), (scene, exposure, *motion), session))
            t += exposure
        clocks[b] = t + float(rng.uniform(60, 600))
        session += 1
    rows.sort(key=lambda r: r[0])
    rows = rows[:n]
    return [r[1] for r in rows], [r[2] for r in rows], [r[3] for r in rows]


class Renderer:
    """Thumbnails of the synthetic frames, rendered when asked for."""

    def __init__(self, infos, plan):
        import cv2

        from selfcal.sim.mixed_cards import mixed_scene

        self.infos, self.plan = infos, plan
        self.scenes = {}
        for k in range(SCENES):
            for w, h in ((64, 43), (64, 48)):       # drawn at 3x, boxed down
                rad = mixed_scene(3 * (h + 8) - 4, 3 * (w + 8) - 4, 500 + k).mean(axis=2)
                rad = cv2.resize(rad, (w + 8, h + 8), interpolation=cv2.INTER_AREA)
                self.scenes[k, h] = (rad / float(np.median(rad))).astype(np.float32)
        self.seconds = 0.0

    def __call__(self, i):
        import cv2

        t0 = time.perf_counter()
        scene, exposure, dy, dx, deg = self.plan[i]
        w, h = self.infos[i].size
        th = 48 if h * 4 == w * 3 else 43
        rad = self.scenes[scene, th]
        if deg or dx or dy:
            m = cv2.getRotationMatrix2D((rad.shape[1] / 2, rad.shape[0] / 2), deg, 1.0)
            m[:, 2] += (dx, dy)
            rad = cv2.warpAffine(rad, m, rad.shape[::-1], borderMode=cv2.BORDER_REFLECT)
        rad = rad[4:4 + th, 4:4 + 64]
        rng = np.random.default_rng(i)
        lin = np.clip(rad * exposure * 2.0 ** 5.5 * 0.18, 0, 1)
        codes = 255.0 * lin ** (1 / 2.2) + rng.normal(0, 1.0, lin.shape)
        out = np.clip(np.round(codes), 0, 255).astype(np.uint8)
        self.seconds += time.perf_counter() - t0
        return out


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_one(n: int, how: str) -> dict:
    """One configuration, in this process."""
    from selfcal.batch.grouping import group_by_content

    infos, plan, truth = synthetic_frames(n)
    render = Renderer(infos, plan)
    rss0 = _rss_mb()
    if how == "lazy":
        t0 = time.perf_counter()
        groups, loose = group_by_content(infos, render)
        sec = time.perf_counter() - t0 - render.seconds
    else:
        from .batch_grouping import _before

        old = _before()
        thumbs = [render(i) for i in range(n)]
        t0 = time.perf_counter()
        groups, loose = old.group_by_content(infos, thumbs)
        sec = time.perf_counter() - t0
    index = {f.path: k for k, f in enumerate(infos)}
    sessions: dict = {}
    for k, s in enumerate(truth):
        sessions.setdefault(s, set()).add(k)
    want = {frozenset(v) for v in sessions.values()}
    got = [frozenset(index[f.path] for f in g.frames) for g in groups]
    return {"frames": n, "how": how, "sessions": len(want), "found": len(got),
            "exact": sum(g in want for g in got), "loose": len(loose), "seconds": sec,
            "rss_before": rss0, "rss_peak": _rss_mb(),
            "load": "/".join(f"{x:.1f}" for x in os.getloadavg())}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--baseline", choices=("yes", "no"), default="yes",
                    help="also run the grouping before issue 37")
    ap.add_argument("--one", nargs=2, metavar=("N", "HOW"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(run_one(int(args.one[0]), args.one[1])))
        return
    start("batch_sessions_scale", "none")
    print(f"load average 1/5/15 min at the start: "
          + "/".join(f"{x:.1f}" for x in os.getloadavg()) + f"; {os.cpu_count()} cores; "
          "each run one process, one thread (OMP/OpenCV threads 1)")
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               MKL_NUM_THREADS="1", OPENCV_FOR_THREADS_NUM="1",
               PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    rows = []
    for n in args.frames:
        for how in ("lazy",) + (("before",) if args.baseline == "yes" else ()):
            out = subprocess.run([sys.executable, "-m", "bench.batch_sessions_scale",
                                  "--one", str(n), how], cwd=REPO, env=env,
                                 capture_output=True, text=True)
            if out.returncode:
                print(f"{n} {how}: failed\n{out.stderr[-2000:]}")
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append((r["frames"], "lazy thumbnails" if how == "lazy" else
                         "before (aa4f879), all thumbnails", r["sessions"], r["found"],
                         r["exact"], r["loose"], f"{r['seconds']:.1f}",
                         f"{1e6 * r['seconds'] / r['frames']:.0f}",
                         f"{r['rss_before']:.0f}", f"{r['rss_peak']:.0f}", r["load"]))
            print(table(["frames", "search", "sessions", "found", "exact", "left out",
                         "search s", "µs per frame", "RSS before MB", "peak RSS MB",
                         "load"], rows[-1:]), flush=True)
    print("\nall runs")
    print(table(["frames", "search", "sessions", "found", "exact", "left out", "search s",
                 "µs per frame", "RSS before MB", "peak RSS MB", "load"], rows))


if __name__ == "__main__":
    main()
    finish()
