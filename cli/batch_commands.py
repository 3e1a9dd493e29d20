"""``selfcal batch``: a photo library to radiance maps, one curve per camera, on Dask.

Registered on the main parser by :func:`register`; nothing numerical lives here (the work
is :func:`selfcal.batch.run_batch`).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from .common import EPILOG, EXIT_OK, check_output_folder, int_range, say, warn

#: Some sessions failed (each is named, with its error, here and in the manifest); the
#: others are done.
EXIT_SESSIONS_FAILED = 6
#: Dask is not installed, or the cluster cannot be reached or started.
EXIT_CLUSTER = 7

BATCH_EPILOG = EPILOG + """
batch: 6 some sessions failed (named, with the error, on screen and in the manifest; the
others are done and a rerun skips them), 7 Dask is missing (pip install "selfcal[batch]")
or the scheduler cannot be reached."""


def _progress_bar():
    """A tqdm bar over sessions for ``progress("sessions", done, total, session)``."""
    from tqdm import tqdm

    state = {}

    def callback(stage, done, total, detail=""):
        bar = state.get("bar")
        if bar is None:
            bar = state["bar"] = tqdm(total=total, initial=done, desc="sessions",
                                      unit="session", file=sys.stderr, disable=None)
        bar.n = done
        if detail:
            bar.set_postfix_str(str(detail)[-40:], refresh=False)
        bar.refresh()
        if done >= total:
            bar.close()

    return callback


def _say_summary(result) -> None:
    rows = result.rows
    say(f"sessions: {len(rows)} ({result.count('ok')} done, {result.count('skipped')} "
        f"skipped as finished before, {result.count('failed')} failed)"
        + (f" on {result.executor}" if result.executor else ""))
    for cam in result.cameras:
        how = (f"one curve from {len(cam['pooled_sessions'])} sessions"
               if cam["model_file"] else "no shared curve"
               + (f" ({cam['fit_error']})" if cam["fit_error"] else ""))
        flagged = len(cam["flagged_sessions"])
        say(f"  {cam['camera_label']}: {cam['sessions']} sessions, {how}"
            + (f", {flagged} flagged (fitted alone)" if flagged else "")
            + (f", {cam['alone_sessions']} fitted alone" if cam["alone_sessions"]
               and cam["alone_sessions"] != flagged else ""))
    if result.unassigned:
        reasons = Counter(why.split(" (")[0] for _, why in result.unassigned)
        say(f"files in no session: {len(result.unassigned)} ("
            + "; ".join(f"{n} {why}" for why, n in reasons.most_common()) + ")")
    for row in result.failed:
        say(f"failed: {row['session']}: {row['error']}")
    for path in result.files:
        say(f"wrote {path}")


def cmd_batch(args) -> int:
    import selfcal
    from selfcal.batch import ClusterError, run_batch

    out = Path(args.output)
    check_output_folder(out)
    if args.scheduler and args.workers:
        warn("--workers is for the local cluster; the scheduler's workers are used")
    try:
        result = run_batch(
            [Path(r) for r in args.roots], out, scheduler=args.scheduler,
            workers=args.workers, memory_limit=args.memory_limit,
            linearize=args.linearize, pool=not args.no_pool, force=args.force,
            redo=args.redo, max_gap=args.max_gap, progress=_progress_bar())
    except ClusterError as exc:
        say(f"selfcal: error: {exc}")
        return EXIT_CLUSTER
    _say_summary(result)
    if result.failed:
        say(f"selfcal: {len(result.failed)} of {len(result.rows)} sessions failed (see "
            f"{result.out_dir / 'manifest.csv'})")
        return EXIT_SESSIONS_FAILED
    if not result.rows:
        raise selfcal.InputError("no bracketed session found (see unassigned.csv for why "
                                 "each file was left out)", ", ".join(args.roots))
    return EXIT_OK


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise argparse.ArgumentTypeError(f"the gap must be a positive number of seconds, "
                                         f"not {text!r}")
    return value


def register(sub) -> None:
    """Add the ``batch`` command to the main parser's subparsers."""
    from selfcal.batch.discover import DEFAULT_MAX_GAP

    p = sub.add_parser(
        "batch", help="calibrate and merge every bracketed session of a photo library",
        description="Find the bracketed sessions in folders of frames (card dumps: EXIF "
                    "body, time and exposure), fit one response curve per camera body "
                    "from samples pooled across its sessions (a session that disagrees "
                    "is flagged and fitted alone), and merge every session into an HDR "
                    "radiance map (EXR) with a preview. Writes a manifest (JSON Lines and "
                    "CSV: one row per session) and a per-camera summary; a rerun skips "
                    "sessions whose outputs are newer than their frames. Runs on Dask: a "
                    "local cluster (one worker process per core) or --scheduler.",
        epilog=BATCH_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("roots", nargs="+", metavar="ROOT", help="folders of frames (walked "
                   "recursively; hidden files and the output folder are skipped)")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR",
                   help="the batch folder (created if missing)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler (tcp://host:port); 'serial' runs "
                        "without Dask in this process (default: a local cluster)")
    p.add_argument("--workers", type=int_range(1, 1024, "--workers"), metavar="N",
                   help="local cluster workers, one thread each (default: the cores)")
    p.add_argument("--memory-limit", default="auto", metavar="LIMIT",
                   help="memory per local worker, e.g. 4GB (default: the machine's memory "
                        "shared among the workers); Dask pauses, then restarts a worker "
                        "beyond it")
    p.add_argument("--linearize", action="store_true",
                   help="also write each frame linearised (16-bit TIFF, linear/)")
    p.add_argument("--no-pool", action="store_true",
                   help="fit every session alone (no per-camera curve)")
    p.add_argument("--max-gap", type=_positive_seconds, default=DEFAULT_MAX_GAP,
                   metavar="S", help="seconds between frames that start a new session "
                                     "(default %(default)g)")
    p.add_argument("--redo", action="store_true",
                   help="run every session again, even those finished before")
    p.add_argument("--force", action="store_true",
                   help="use calibrations whose verdict is unusable; write into a "
                        "non-empty folder that holds no batch")
    p.set_defaults(func=cmd_batch)
