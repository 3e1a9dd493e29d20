"""``selfcal batch`` at scale: discovery of 10⁵ files, scheduler overhead per session.

A simulated card of ``--files`` tiny JPEGs (``--height`` × ``--width``, EXIF as cameras
write it), two bodies taking turns, brackets of 5 frames 0.3 s apart, sessions of one
body 60 s apart, 8 scenes in rotation (:func:`selfcal.sim.mixed_cards.mixed_scene`),
1,000 files per ``DCIM`` folder.  Then:

1. **Discovery** (:func:`selfcal.batch.discover`: walk, EXIF + thumbnail of each frame
   read once, grouping by content), with 1 reading thread and with the default (one per
   core, at most 8); the sessions found are checked against the truth.
2. **Scheduler overhead**: the task graph of ``selfcal batch`` (``prepare`` and
   ``finish`` per session, a pooled fit per camera, the driver's bookkeeping and its
   journal) for the first ``--run-sessions`` sessions, with the three task functions
   replaced by no-ops that return rows of the real size, on a LocalCluster of
   ``--workers`` single-threaded processes and in process (no Dask).  All of the wall
   time is then overhead: per session, it is what Dask and the driver add to a
   session's own work.
3. **Manifest**: the journal's append per row, and the final sorted manifest (JSON Lines,
   CSV, camera summary) for all rows.
4. **Real work on tiny frames** (``--work-sessions``, default 200): the same sessions run
   for real on the cluster (calibration, pooled fits, merges): seconds per session.

    python3 -m bench.batch_scale                       # 10⁵ files, 10⁴-session run
    python3 -m bench.batch_scale --files 5000 --run-sessions 1000 --work-sessions 40
"""

from __future__ import annotations

import argparse
import io
import logging
import os
import resource
import tempfile
import time
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from .tables import finish, start

FRAMES = 5
SPEEDS = (1 / 250, 1 / 60, 1 / 15, 1 / 4, 1.0)


def _load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def write_card(root: Path, files: int, height: int, width: int) -> int:
    """The card; returns the number of sessions written."""
    import piexif

    from selfcal import sim
    from selfcal.sim.cards import camera_exif, default_bodies
    from selfcal.sim.mixed_cards import mixed_scene

    bodies = default_bodies()
    encoded = {}
    for b, body in enumerate(bodies):
        for k in range(8):
            scene = mixed_scene(height, width, 100 + k)[2:2 + height, 2:2 + width]
            stack = sim.simulate_stack(scene, body.pipeline, list(SPEEDS), seed=k)
            encoded[b, k] = stack.jpeg_bytes
    start = datetime(2024, 7, 1, 8, 0, 0)
    sessions = files // FRAMES
    counters = [0, 0]
    for i in range(sessions):
        b, k = i % 2, (i // 2) % 8
        when = start + timedelta(seconds=30.0 * i + 3 * b)
        for j, t in enumerate(SPEEDS):
            counters[b] += 1
            n = counters[b]
            folder = root / "DCIM" / f"{100 + (n - 1) // 1000}SIM{b}"
            if (n - 1) % 1000 == 0:
                folder.mkdir(parents=True, exist_ok=True)
            out = io.BytesIO()
            piexif.insert(camera_exif(bodies[b], when=when, exposure_time=t),
                          encoded[b, k][j], out)
            (folder / f"{bodies[b].prefix}{n:06d}.JPG").write_bytes(out.getvalue())
            when += timedelta(seconds=t + 0.3)
    return sessions


def time_discovery(root: Path, workers: int | None):
    from selfcal.batch.discover import _pair_raws, _walk, read_frame, sessions_from_groups
    from selfcal.batch.grouping import GroupingRule, group_by_content
    from selfcal.batch.thumbnails import ThumbnailSpool, read_frames

    def cpu():
        me = resource.getrusage(resource.RUSAGE_SELF)
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime

    t0, c0 = time.perf_counter(), cpu()
    pairs = _pair_raws(_walk([root], ()), [])
    t1 = time.perf_counter()
    with ThumbnailSpool() as spool:      # as discover() holds them: on disk
        read = read_frames(pairs, read_frame, workers=workers, keep=spool.add)
        t2, c2 = time.perf_counter(), cpu()
        infos = [i for i, _ in read]
        keys = [k for _, k in read]
        groups, loose = group_by_content(infos, lambda i: spool[keys[i]], GroupingRule())
        sessions = sessions_from_groups(groups)
        t3, c3 = time.perf_counter(), cpu()
    return {"walk": t1 - t0, "read": t2 - t1, "group": t3 - t2, "total": t3 - t0,
            "cpu_read": c2 - c0, "cpu_group": c3 - c2,
            "files": len(pairs), "sessions": sessions, "loose": loose}


# ------------------------------------------------------------------ no-op tasks

def _stub_prepare(plan, options):
    from selfcal.batch.run import SessionPrep

    return SessionPrep(session=plan.id, ok=True, seconds=0.0)


def _stub_fit(plan, options, *preps):
    from selfcal.batch.run import CameraFit

    return CameraFit(camera=plan.camera, label=plan.label, candidates=list(plan.candidates))


def _stub_finish(plan, options, prep, camera=None):
    from selfcal.batch.run import plan_row

    row = plan_row(plan)
    row.update(status="ok", own_curve=[0.0] * 33, seconds=0.0)
    return row


def time_overhead(plans, cameras, workers: int, out: Path):
    """Wall seconds of the stubbed graph on a LocalCluster and in process."""
    import distributed

    from selfcal.batch import cluster
    from selfcal.batch.faults import Journal
    from selfcal.batch.run import BatchOptions

    saved = cluster.prepare_session, cluster.fit_camera, cluster.finish_session
    cluster.prepare_session, cluster.fit_camera, cluster.finish_session = (
        _stub_prepare, _stub_fit, _stub_finish)
    out.mkdir(parents=True, exist_ok=True)
    options = BatchOptions()
    result = {}
    try:
        for name in ("serial", "cluster"):
            journal = Journal(out / name)
            rows = cluster._Journaled([], journal)
            if name == "serial":
                ex = cluster.SerialExecutor()
            else:
                lc = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                              dashboard_address=None,
                                              silence_logs=logging.ERROR)
                ex = cluster.DaskExecutor(client=distributed.Client(lc))
            t0, c0 = time.perf_counter(), time.process_time()
            cluster._drive(ex, plans, cameras, {}, options, rows, len(plans), None)
            result[name] = time.perf_counter() - t0
            result[name + "_cpu"] = time.process_time() - c0
            journal.close()
            assert len(rows) == len(plans) and all(r["status"] == "ok" for r in rows)
            if name == "cluster":
                ex.client.close()
                lc.close()
            result["rows"] = list(rows)
    finally:
        cluster.prepare_session, cluster.fit_camera, cluster.finish_session = saved
    return result


def time_manifest(rows, cameras_plans, out: Path):
    from selfcal.batch.faults import Journal
    from selfcal.batch.run import camera_rows, write_manifest

    journal = Journal(out / "journal")
    t0 = time.perf_counter()
    for r in rows:
        journal.add(r)
    append = (time.perf_counter() - t0) / len(rows)
    journal.close()
    cams = camera_rows(cameras_plans, {}, rows)
    t0 = time.perf_counter()
    write_manifest(out / "manifest", rows, cams, [])
    return append, time.perf_counter() - t0


def run_real(root_sessions, out: Path, workers: int):
    """The real batch on a copy of the first sessions' frames."""
    import shutil

    from selfcal.batch import ClusterOptions, run_batch

    card = out / "card"
    for s in root_sessions:
        for f in s.frames:
            dest = card / f.path.parent.name / f.path.name
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f.path, dest)
    t0 = time.perf_counter()
    result = run_batch([card], out / "out", cluster=ClusterOptions(workers=workers))
    wall = time.perf_counter() - t0
    return wall, result


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=100_000)
    ap.add_argument("--run-sessions", type=int, default=10_000)
    ap.add_argument("--work-sessions", type=int, default=200)
    ap.add_argument("--height", type=int, default=32)
    ap.add_argument("--width", type=int, default=48)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", metavar="DIR", help="write the card here (reused if there)")
    ap.add_argument("--discovery", choices=("both", "parallel"), default="both",
                    help="time discovery with 1 thread and in parallel, or in parallel only")
    args = ap.parse_args(argv)
    start("batch_scale", "none")
    from selfcal.batch.run import plan_batch, BatchOptions
    from selfcal.batch.discover import Library

    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench-scale-"))
    root = work / "card"
    print(f"load average 1/5/15 min at the start: {_load()}; {os.cpu_count()} cores")
    t0 = time.perf_counter()
    if not (root / "DCIM").exists():
        write_card(root, args.files, args.height, args.width)
    print(f"card: {args.files} files of {args.width}x{args.height} in "
          f"{args.files // FRAMES} sessions, written in {time.perf_counter() - t0:.0f} s "
          f"-> {root}")
    from selfcal.batch.thumbnails import PROCESS_THRESHOLD

    for threads in ((1, None) if args.discovery == "both" else (None,)):
        d = time_discovery(root, threads)
        exact = sum(len(s.frames) == FRAMES for s in d["sessions"])
        print(f"discovery, {'1 thread' if threads else 'default threads'}: {d['files']} "
              f"files in {d['total']:.1f} s ({d['files'] / d['total']:.0f} files/s; walk "
              f"{d['walk']:.1f} s, EXIF + thumbnails {d['read']:.1f} s, grouping "
              f"{d['group']:.1f} s; CPU: walk + read {1e3 * d['cpu_read'] / d['files']:.2f} "
              f"ms per file, grouping {1e3 * d['cpu_group'] / d['files']:.2f} ms per "
              f"frame); {len(d['sessions'])} sessions, {exact} of "
              f"{FRAMES} frames, {len(d['loose'])} loose; peak RSS of this process so "
              f"far {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB "
              f"(readers in worker processes from {PROCESS_THRESHOLD} files on are not in "
              f"it); load {_load()}")
    sessions = d["sessions"][: args.run_sessions]
    lib = Library(sessions=sessions, roots=[root])
    plans, cameras = plan_batch(lib, work / "plan", BatchOptions())
    o = time_overhead(plans, cameras, args.workers, work / "overhead")
    n = len(plans)
    print(f"scheduler overhead, {n} sessions ({2 * n + len(cameras)} tasks) of no-op "
          f"tasks: LocalCluster of {args.workers} workers {o['cluster']:.1f} s = "
          f"{1e3 * o['cluster'] / n:.2f} ms per session; in process (no Dask) "
          f"{o['serial']:.1f} s = {1e3 * o['serial'] / n:.2f} ms per session; driver CPU "
          f"{1e3 * o['cluster_cpu'] / n:.2f} ms per session on the cluster; driver peak "
          f"RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; "
          f"load {_load()}")
    append, final = time_manifest(o["rows"], cameras, work / "manifest")
    print(f"manifest: journal append {1e6 * append:.0f} µs per row; final manifest of "
          f"{n} rows {final:.1f} s; load {_load()}")
    if args.work_sessions:
        wall, result = run_real(sessions[: args.work_sessions], work / "real", args.workers)
        rows = result.rows
        cpu = [r["seconds"] for r in rows if r["seconds"] is not None]
        print(f"real work, {len(rows)} sessions of {FRAMES} x {args.width}x{args.height} "
              f"on a LocalCluster of {args.workers} workers: {wall:.1f} s wall "
              f"({wall / len(rows):.2f} s per session), task seconds per session median "
              f"{np.median(cpu):.2f}; ok {result.count('ok')}, failed "
              f"{result.count('failed')}; worker peak RSS "
              + ", ".join(f"{v / 2**20:.0f}" for v in result.worker_memory.values())
              + f" MB; load {_load()}")


if __name__ == "__main__":
    main()
    finish()
