"""``selfcal batch``: a photo library to radiance maps, one curve per camera, on Dask.

Registered on the main parser by :func:`register`; nothing numerical lives here (the work
is :func:`selfcal.batch.run_batch`).
"""

from __future__ import annotations

import argparse
import math
import re
import signal
import sys
import threading
from collections import Counter
from dataclasses import replace
from pathlib import Path

from .common import EPILOG, EXIT_OK, check_output_folder, int_range, say, warn

#: Some sessions failed (each is named, with its error, here and in the manifest); the
#: others are done.
EXIT_SESSIONS_FAILED = 6
#: Dask is not installed, or the cluster cannot be reached or started.
EXIT_CLUSTER = 7
#: Interrupted by Ctrl-C (128 + SIGINT) or SIGTERM (128 + SIGTERM): finished sessions are
#: kept, a rerun does the rest.
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that the batch stops as on Ctrl-C."""


def _raise_terminated(signum, frame):
    raise Terminated()


def _terminate_as_interrupt():
    """Turn SIGTERM into :class:`Terminated` (main thread only); the previous handler."""
    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, _raise_terminated)

BATCH_EPILOG = EPILOG + """
batch: 6 some sessions failed (named, with the error, on screen and in the manifest; the
others are done and a rerun skips them), 7 Dask is missing (pip install "selfcal[batch]")
or the scheduler cannot be reached, 130/143 interrupted by Ctrl-C/SIGTERM (finished
sessions kept, none half written; the same command again does the rest)."""


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
        _say_raw_model(cam)
    _say_unassigned(result.unassigned)
    unsure = sum(bool(r.get("grouping_unsure")) for r in result.rows)
    if unsure:
        say(f"sessions grouped with doubt: {unsure} (grouping_unsure in the manifest, "
            "with the reason of each decision; --dry-run shows them before any work)")
    for row in result.failed:
        say(f"failed: {row['session']}: {row['error']}")
    for path in result.files:
        say(f"wrote {path}")


def _say_raw_model(cam) -> None:
    """The camera's RAW-path model from its RAW+JPEG pairs, where it has one (or why not)."""
    if cam.get("raw_model_file"):
        say(f"    RAW-path model from {len(cam['raw_scenes'])} scenes' RAW+JPEG pairs: "
            f"forward {cam['raw_loso_forward']:.2f} codes on scenes left out "
            f"({cam['raw_training_forward']:.2f} on its own); {cam['raw_model_file']}")
    elif cam.get("raw_fit_error"):
        say(f"    no RAW-path model: {cam['raw_fit_error']}")


def _say_unassigned(unassigned) -> None:
    if unassigned:
        reasons = Counter(why.split(" (")[0] for _, why in unassigned)
        say(f"files in no session: {len(unassigned)} ("
            + "; ".join(f"{n} {why}" for why, n in reasons.most_common()) + ")")


def _say_dry_run(library) -> None:
    """The sessions ``selfcal batch`` would make, with the grouping's reason for every
    frame (why it joined or started its session), the files in none and the copies
    skipped."""
    sessions = library.sessions
    unsure = sum(s.unsure for s in sessions)
    copies = getattr(library, "copies", [])
    say(f"dry run: {len(sessions)} sessions, {len(library.cameras)} cameras, "
        f"{sum(len(s.frames) for s in sessions)} frames in sessions, "
        f"{len(library.unassigned)} files in none" + (f"; {unsure} unsure" if unsure else "")
        + (f"; {len(copies)} copies skipped" if copies else ""))
    for s in sessions:
        times = [f.exposure_time for f in s.frames]
        say(f"  {s.id}: {len(s.frames)} frames, {min(times):.3g}-{max(times):.3g} s, "
            f"{s.frames[0].path.name} .. {s.frames[-1].path.name}"
            + ("  [unsure]" if s.unsure else ""))
        for why in s.reasons:
            say(f"      {why}")
    for path, why in library.unassigned:
        say(f"  not in a session: {path}: {why}")
    for skipped, kept in copies:
        say(f"  copy skipped: {skipped} (the same file as {kept})")


def _nothing_to_do(unassigned, roots) -> int:
    say(f"selfcal: nothing to do: no bracketed session under {', '.join(roots)} "
        "(nothing written)")
    _say_unassigned(unassigned)
    return EXIT_OK


def cmd_batch(args) -> int:
    from selfcal.batch import BatchOptions, ClusterError, ClusterOptions, discover, run_batch

    cameras = [cam for cam, _ in args.luminance_scale]
    twice = sorted({cam for cam in cameras if cameras.count(cam) > 1})
    if twice:
        args.parser.error(f"argument --luminance-scale: {', '.join(map(repr, twice))} given "
                          "more than once (one scale per camera)")
    out = Path(args.output)
    check_output_folder(out)
    if args.dry_run:
        library = discover([Path(r) for r in args.roots], exclude=[out],
                           max_gap=args.max_gap, by_content=not args.by_time)
        if not library.sessions:
            return _nothing_to_do(library.unassigned, args.roots)
        _say_dry_run(library)
        return EXIT_OK
    for given, option in ((args.workers, "--workers"), (args.memory_limit, "--memory-limit")):
        if args.scheduler and given is not None:
            warn(f"{option} is for the local cluster; "
                 + ("--scheduler serial runs in this process" if args.scheduler == "serial"
                    else "the scheduler's workers are used"))
    options = BatchOptions(linearize=args.linearize, pool=not args.no_pool,
                           force=args.force, by_content=not args.by_time,
                           max_gap=args.max_gap,
                           luminance=None if args.luminance == "none" else args.luminance,
                           camera_scales=dict(args.luminance_scale))
    if args.no_raw_library:
        options = replace(options, raw_library=None)
    previous = _terminate_as_interrupt()
    try:
        result = run_batch(
            [Path(r) for r in args.roots], out, scheduler=args.scheduler,
            cluster=ClusterOptions(workers=args.workers, memory_limit="auto"
                                   if args.memory_limit is None else args.memory_limit),
            options=options, redo=args.redo, progress=_progress_bar())
    except ClusterError as exc:
        say(f"selfcal: error: {exc}")
        return EXIT_CLUSTER
    except KeyboardInterrupt as exc:
        say(f"selfcal: interrupted: the sessions finished so far are kept, none is half "
            f"written ({out / 'manifest.csv'} names every session); the same command "
            "again does the rest")
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if not result.rows and not result.files:
        return _nothing_to_do(result.unassigned, args.roots)
    _say_summary(result)
    if result.failed:
        say(f"selfcal: {len(result.failed)} of {len(result.rows)} sessions failed (see "
            f"{result.out_dir / 'manifest.csv'})")
        return EXIT_SESSIONS_FAILED
    return EXIT_OK


_ADDRESS = re.compile(r"^(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9a-fA-F:]+\]|[^\s:/\[\]]+)"
                      r":(\d{1,5})$")


def _is_address(text: str) -> bool:
    """A Dask scheduler address with a port from 1 to 65535."""
    m = _ADDRESS.match(text)
    return bool(m) and 1 <= int(m.group(1)) <= 65535


def _scheduler_address(text: str) -> str:
    """``serial``, a Dask scheduler address with a port (``tcp://host:8786``), or a
    scheduler file (``dask scheduler --scheduler-file F``: JSON with its address)."""
    import json

    if text == "serial" or _is_address(text.strip()):
        return text.strip()
    path = Path(text)
    if path.suffix.lower() == ".json" or path.is_file():
        try:
            address = json.loads(path.read_text())["address"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            why = "no such file" if isinstance(exc, FileNotFoundError) else \
                f"not a Dask scheduler file: {type(exc).__name__}: {exc}"
            raise argparse.ArgumentTypeError(f"{path}: {why}") from None
        if isinstance(address, str) and _is_address(address):
            return address
        raise argparse.ArgumentTypeError(f"{path}: its address {address!r} is not a Dask "
                                         "scheduler address")
    raise argparse.ArgumentTypeError(
        f"not a Dask scheduler address: {text!r} (give one like tcp://host:8786, the "
        "port from 1 to 65535, a "
        "scheduler file, or 'serial' to run without Dask)")


#: Dask's byte units (``dask.utils.byte_sizes``: kB = 1000, KiB = 1024, ...), lower case.
_BYTE_UNITS = {"": 1, "b": 1, **{p + s: 1000 ** (i + 1) for i, p in enumerate("kmgtp")
                                 for s in ("", "b")},
               **{p + s: 1024 ** (i + 1) for i, p in enumerate("kmgtp") for s in ("i", "ib")}}
#: The smallest per-worker memory limit taken (a bare "4" is 4 bytes, not 4 GB).
MIN_MEMORY_LIMIT = 64 * 2 ** 20


def _memory_limit(text: str):
    """``--memory-limit``: what Dask's ``memory_limit`` takes, checked before any cluster
    starts -- ``auto``, 0 (no limit), a fraction of the memory (0 < x <= 1) or a size
    (``4GB``, ``512MiB``, bytes) of at least :data:`MIN_MEMORY_LIMIT`."""
    t = text.strip().lower().replace(" ", "")
    if t == "auto":
        return "auto"
    m = re.fullmatch(r"([0-9.]+(?:e[+-]?[0-9]+)?)?([a-z]*)", t)
    number = unit = None
    if m and m.group(2) in _BYTE_UNITS:
        try:
            number = float(m.group(1) or "1")
        except ValueError:
            pass
        unit = _BYTE_UNITS[m.group(2)]
    hint = ("give a size like 4GB or 512MiB, a fraction of the memory like 0.5, auto "
            "(the memory shared among the workers) or 0 (no limit)")
    if number is None or unit is None or not math.isfinite(number):
        raise argparse.ArgumentTypeError(f"not a memory limit: {text!r}; {hint}")
    if number == 0:
        return 0
    if not m.group(2) and number <= 1:
        return number                        # a fraction of the machine's memory
    size = int(number * unit)
    if size < MIN_MEMORY_LIMIT:
        raise argparse.ArgumentTypeError(
            f"{text!r} is {size} bytes, too little for a worker (at least 64MiB); {hint}")
    return size


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise argparse.ArgumentTypeError(f"the gap must be a positive number of seconds, "
                                         f"not {text!r}")
    return value


def _camera_scale(text: str):
    """``CAMERA=MODEL.json``: the luminance scale a model file holds, for one camera."""
    camera, sep, path = text.rpartition("=")
    if not sep or not camera.strip() or not path:
        raise argparse.ArgumentTypeError(f"expected CAMERA=MODEL.json, not {text!r}")
    import selfcal

    try:
        model = selfcal.load_model(path)
    except selfcal.SelfcalError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    scale = getattr(model, "luminance", None)
    if scale is None:
        raise argparse.ArgumentTypeError(
            f"{path}: the model holds no luminance scale (selfcal merge --reading ... "
            "--save-scale MODEL.json stores one)")
    return camera.strip(), scale


def register(sub) -> None:
    """Add the ``batch`` command to the main parser's subparsers."""
    from selfcal.batch.discover import DEFAULT_MAX_GAP

    p = sub.add_parser(
        "batch", help="calibrate and merge every bracketed session of a photo library",
        description="Find the bracketed sessions in folders of frames (card dumps: what the "
                    "frames show, EXIF body, time and exposure), fit one curve per camera body "
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
    p.add_argument("--scheduler", metavar="ADDRESS", type=_scheduler_address,
                   help="an existing Dask scheduler (tcp://host:port, or the JSON file "
                        "of dask scheduler --scheduler-file); 'serial' runs without Dask "
                        "in this process (default: a local cluster)")
    p.add_argument("--workers", type=int_range(1, 1024, "--workers"), metavar="N",
                   help="local cluster workers, one thread each (default: the cores)")
    p.add_argument("--memory-limit", type=_memory_limit, metavar="LIMIT",
                   help="memory per local worker: a size (4GB, 512MiB), a fraction of the "
                        "machine's memory (0.25), 0 for none, or auto (default: the "
                        "machine's memory shared among the workers); Dask pauses, then "
                        "restarts a worker beyond it")
    p.add_argument("--linearize", action="store_true",
                   help="also write each frame linearised (16-bit TIFF, linear/)")
    p.add_argument("--luminance", choices=("none", "exif"), default="none",
                   help="exif: every session's radiance in cd/m² by the ISO 12232 "
                        "convention from its EXIF time, f-number and ISO, with its "
                        "camera's curve (±1/3 stop); none (default): relative")
    p.add_argument("--luminance-scale", type=_camera_scale, action="append", default=[],
                   metavar="CAMERA=MODEL.json",
                   help="every session of CAMERA (its EXIF model, or make model #serial) "
                        "in cd/m² with the scale MODEL.json holds (measured once with "
                        "selfcal merge --reading ... --save-scale); repeat per camera")
    p.add_argument("--no-pool", action="store_true",
                   help="fit every session alone (no per-camera curve)")
    p.add_argument("--no-raw-library", action="store_true",
                   help="fit no RAW-path model per camera from its RAW+JPEG pairs")
    p.add_argument("--max-gap", type=_positive_seconds, default=DEFAULT_MAX_GAP,
                   metavar="S", help="seconds within which frames whose thumbnails cannot "
                                     "be compared are one session; with --by-time, the "
                                     "gap that starts a new session (default %(default)g)")
    p.add_argument("--by-time", action="store_true",
                   help="find sessions by the time gap alone (default: by what the frames "
                        "show -- thumbnails that agree after exposure normalisation -- "
                        "with time as a hint)")
    p.add_argument("--dry-run", action="store_true",
                   help="print the sessions the batch would make, with the reason of each "
                        "grouping decision, and stop (nothing written, no cluster)")
    p.add_argument("--redo", action="store_true",
                   help="run every session again, even those finished before")
    p.add_argument("--force", action="store_true",
                   help="use calibrations whose verdict is unusable; write into a "
                        "non-empty folder that holds no batch")
    p.set_defaults(func=cmd_batch, parser=p)
