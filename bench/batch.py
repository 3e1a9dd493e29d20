"""``selfcal batch`` throughput and the per-camera curve (issue 17).

A simulated card dump (:func:`selfcal.sim.cards.write_library`): two camera bodies
(film-like curves; gamma 2.2), ``--sessions`` bracketed sessions in all, ``--frames``
JPEG frames of ``--height`` × ``--width`` each (default 5 × ~1 MP), EXIF as cameras write
it.  Then, on the same library:

1. **Serial loop**: ``run_batch(scheduler="serial")`` -- the same tasks, one after the
   other, in a fresh child process (its peak RSS is the process's own).
2. **LocalCluster** of ``--workers`` single-threaded worker processes (default 2: this
   machine's cores), started before the clock starts (its start-up is printed apart);
   peak RSS of each worker (``ru_maxrss``, read in the worker after the run).

Throughput is sessions per second of wall time; the ratio is cluster / serial.  Both
runs do the same work (own calibration and pool samples per session, one pooled fit per
camera, merge + preview per session), each into its own folder.

3. **Curves**: each body's pooled curve (``cameras/<camera>/model.json`` of the cluster
   run) against the simulator's truth, and single-session curves
   (``selfcal.calibrate_response`` of ``--curve-sessions`` sessions per body, spread over
   the library) against the same truth: ``selfcal.sim.scoring.best_scale_rmse`` of f⁻¹ over
   codes 1..254, mean of R, G, B.

    python3 -m bench.batch --sessions 200          # the issue's size
    python3 -m bench.batch --sessions 40 --keep /tmp/lib   # smaller, keep the card
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from .data import REPO
from .tables import finish, start, table

SERIAL = r"""
import json, resource, sys, time
from selfcal.batch import run_batch
import selfcal.choose, selfcal.hdr, cvxpy     # imported before the clock, as in the workers
root, out = sys.argv[1:3]
t0 = time.perf_counter()
result = run_batch([root], out, scheduler="serial")
seconds = time.perf_counter() - t0
use = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"seconds": seconds, "peak": use.ru_maxrss * 1024,
                  "cpu": use.ru_utime + use.ru_stime, "ok": result.count("ok"),
                  "failed": result.count("failed"),
                  "prepare": [r["prepare_seconds"] for r in result.rows],
                  "merge": [r["merge_seconds"] for r in result.rows]}))
"""


def _times(frames: int):
    """``frames`` exposure times from 1/250 s to 1 s, evenly in stops."""
    return tuple(float(t) for t in np.geomspace(1 / 250, 1.0, frames))


def _write_body(args):
    from selfcal.sim.cards import Shots, default_bodies, write_library

    root, b, per_body, height, width, frames = args
    body = default_bodies()[b]
    t0 = time.perf_counter()
    write_library(root, bodies=[body], sessions_per_body=per_body,
                  shots=Shots(height=height, width=width, times=_times(frames)), seed=b + 1,
                  per_folder=999)
    return time.perf_counter() - t0


def make_library(root: Path, sessions: int, frames: int, height: int, width: int):
    """The card dump, one body per process (two bodies)."""
    per_body = [sessions // 2 + sessions % 2, sessions // 2]
    jobs = [(str(root), b, n, height, width, frames) for b, n in enumerate(per_body) if n]
    with ProcessPoolExecutor(max_workers=2) as pool:
        list(pool.map(_write_body, jobs))


def run_serial(root: Path, out: Path) -> dict:
    proc = subprocess.run([sys.executable, "-c", SERIAL, str(root), str(out)],
                          capture_output=True, text=True, cwd=REPO, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _warm():
    import cvxpy  # noqa: F401

    import selfcal.batch.run  # noqa: F401
    import selfcal.choose  # noqa: F401
    import selfcal.hdr  # noqa: F401


def _cpu() -> float:
    """User + system CPU seconds of this process (all its threads)."""
    import resource

    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _load() -> str:
    import os

    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def run_cluster(root: Path, out: Path, workers: int, trim: bool = False) -> dict:
    import distributed

    from selfcal.batch import ClusterOptions, run_batch

    import dask

    from selfcal.batch.cluster import NO_MALLOC_TRIM

    t0 = time.perf_counter()
    with dask.config.set({NO_MALLOC_TRIM: None} if not trim else {}):
        cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                           processes=True, dashboard_address=None,
                                           silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    client.run(_warm)         # imports before the clock, as in the serial child
    start = time.perf_counter() - t0
    cpu0, here0 = client.run(_cpu), _cpu()
    t0 = time.perf_counter()
    result = run_batch([root], out, cluster=ClusterOptions(client=client))
    seconds = time.perf_counter() - t0
    cpu1, here1 = client.run(_cpu), _cpu()

    def peak():
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024

    memory = client.run(peak)
    client.close()
    cluster.close()
    return {"seconds": seconds, "start": start, "memory": memory, "rows": result.rows,
            "cpu": sum(cpu1[w] - cpu0[w] for w in cpu1), "cpu_here": here1 - here0,
            "cameras": result.cameras, "ok": result.count("ok"),
            "failed": result.count("failed")}


def curve_errors(root: Path, out: Path, rows, cameras, n_single: int):
    """Per body: the pooled curve's error and single-session curves' errors vs truth."""
    import selfcal
    from selfcal.sim.cards import default_bodies
    from selfcal.sim.scoring import best_scale_rmse

    def err(est, truth):
        codes = slice(1, 255)
        return float(np.mean([best_scale_rmse(est[codes, c], truth[codes, c])
                              for c in range(3)]))

    bodies = {b.serial: b for b in default_bodies()}
    out_rows = []
    for cam in cameras:
        body = bodies[cam["camera_label"].split("#")[-1]]
        truth = body.inverse_response()
        pooled = (err(selfcal.load_model(cam["model_file"]).inverse_response(), truth)
                  if cam["model_file"] else math.nan)
        mine = sorted((r for r in rows if r["camera"] == cam["camera"]),
                      key=lambda r: r["start"])
        pick = [mine[i] for i in np.unique(np.linspace(0, len(mine) - 1, n_single)
                                           .round().astype(int))]
        single = [err(selfcal.calibrate_response(r["frames"]).inverse_response(), truth)
                  for r in pick]
        out_rows.append((cam["camera_label"], cam["sessions"], len(cam["pooled_sessions"]),
                         len(cam["flagged_sessions"]), f"{pooled:.4f}",
                         f"{np.median(single):.4f}", f"{np.percentile(single, 90):.4f}",
                         f"{max(single):.4f}",
                         f"{np.mean([s > pooled for s in single]):.0%} of {len(single)}"))
    return out_rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=200)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--height", type=int, default=864)
    ap.add_argument("--width", type=int, default=1152)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--curve-sessions", type=int, default=12,
                    help="single-session curves per body for the curve table")
    ap.add_argument("--keep", metavar="DIR", help="write the library (and outputs) here "
                    "and keep them; an existing library there is reused")
    args = ap.parse_args(argv)
    start("batch", "none")

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-batch-"))
    root = work / "card"
    t0 = time.perf_counter()
    if not (root / "DCIM").exists():
        make_library(root, args.sessions, args.frames, args.height, args.width)
    made = time.perf_counter() - t0
    mp = args.height * args.width / 1e6
    print(f"library: {args.sessions} sessions × {args.frames} frames of "
          f"{args.width}×{args.height} ({mp:.2f} MP), 2 bodies, written in {made:.0f} s "
          f"-> {root}")

    loads = [_load()]
    se = run_serial(root, work / "out-serial")
    loads.append(_load())
    cl = run_cluster(root, work / "out-cluster", args.workers)
    loads.append(_load())
    n = cl["ok"] + cl["failed"]
    cpu_cl = cl["cpu"] + cl["cpu_here"]

    def med(xs):
        xs = [x for x in xs if x is not None]
        return f"{np.median(xs):.2f}" if xs else "-"

    rows = [("serial loop (1 process)", f"{se['seconds']:.1f}", f"{n / se['seconds']:.3f}",
             "1.00", f"{se['cpu']:.0f}", med(se["prepare"]), med(se["merge"]),
             f"{se['peak'] / 2**20:.0f} (the process)"),
            (f"LocalCluster, {args.workers} workers × 1 thread", f"{cl['seconds']:.1f}",
             f"{n / cl['seconds']:.3f}", f"{se['seconds'] / cl['seconds']:.2f}",
             f"{cpu_cl:.0f} ({cl['cpu_here']:.0f} scheduler+nannies+driver)",
             med(r["prepare_seconds"] for r in cl["rows"]),
             med(r["merge_seconds"] for r in cl["rows"]),
             ", ".join(f"{v / 2**20:.0f}" for v in sorted(cl["memory"].values())))]
    print(f"\nthroughput ({n} sessions; cluster start-up {cl['start']:.1f} s not counted; "
          f"failed: serial {se['failed']}, cluster {cl['failed']}; load average "
          f"1/5/15 min before, between, after: {' | '.join(loads)})")
    print(table(["run", "wall s", "sessions/s", "ratio", "CPU s", "prepare s (median)",
                 "merge s (median)", "peak RSS MB (per worker)"], rows))
    fits = [c["fit_seconds"] for c in cl["cameras"] if c["fit_seconds"] is not None]
    print(f"pooled fits on the cluster: {', '.join(f'{f:.1f} s' for f in fits)}")

    print("\ncurves: best-scale RMSE of f⁻¹ against the simulator's truth (codes 1..254, "
          "mean of R, G, B)")
    print(table(["body", "sessions", "pooled", "flagged", "pooled curve",
                 "single median", "single p90", "single worst", "single worse than pooled"],
                curve_errors(root, work / "out-cluster", cl["rows"], cl["cameras"],
                             args.curve_sessions)))


if __name__ == "__main__":
    main()
    finish()
