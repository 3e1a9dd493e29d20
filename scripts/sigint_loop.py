#!/usr/bin/env python3
"""Ctrl-C a ``selfcal`` command at random moments and count how it ends.

Each run starts the command in its own process (``python -m selfcal_cli``, or the
``selfcal`` console script with ``--script``), sends it SIGINT after a random delay and
records its exit code, whether stderr holds a traceback, and what it left in the output
folder (the output, or a hidden temporary file).  A run the signal reaches before the
interpreter has installed its handler (the first milliseconds) ends killed by the
signal: exit code -2 here, 130 in a shell.

Usage::

    python scripts/sigint_loop.py [--runs 20] [--max-delay 4] [--seed 0] [--size H W]
        [--script] [-- merge|calibrate|demo ... OUT ...]

Without a command: ``merge`` of a simulated 4-frame bracket (``--size``, default
1200 x 1600) written to a temporary folder, the model calibrated on the fly (the
times given).  A run
whose command ended before its delay is counted apart: it was not interrupted (give a
larger ``--size``).  The table: exit code -> runs, then the runs with a traceback or a
file left behind (each with its delay).  Exit 1 when any run ended otherwise than 130
(or -2: killed by the signal before Python ran any code) quietly with nothing left.
"""

from __future__ import annotations

import argparse
import collections
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


TIMES = ["1/250", "1/60", "1/15", "1/4"]


def _bracket(folder: Path, size) -> list[str]:
    """Four JPEG frames of a simulated bracket, simulated small and enlarged to ``size``
    (the simulator is slow at many megapixels); their times are given with --times."""
    import cv2
    import numpy as np

    from selfcal import sim

    scene = sim.make_scene(240, 320, dynamic_range_stops=10, saturation=0.3, seed=1)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=1),
                               [1 / 250, 1 / 60, 1 / 15, 1 / 4], jitter=0.0, seed=1)
    folder.mkdir(parents=True)
    paths = []
    for k, img in enumerate(stack.images):
        big = cv2.resize(np.ascontiguousarray(img[..., ::-1]), (size[1], size[0]),
                         interpolation=cv2.INTER_CUBIC)
        paths.append(str(folder / f"f_{k}.jpg"))
        cv2.imwrite(paths[-1], big, [cv2.IMWRITE_JPEG_QUALITY, 92])
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--max-delay", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, nargs=2, default=(1200, 1600), metavar=("H", "W"),
                    help="the simulated frames' height and width (default 1200 1600)")
    ap.add_argument("--script", action="store_true",
                    help="run the installed console script (selfcal) instead of -m")
    ap.add_argument("command", nargs="*", help="the selfcal command and its arguments "
                    "(OUT in them is replaced by a fresh output folder's path)")
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))}
    exe = [shutil.which("selfcal") or "selfcal"] if args.script else \
        [sys.executable, "-m", "selfcal_cli"]
    codes: collections.Counter = collections.Counter()
    bad = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        frames = [] if args.command else _bracket(tmp / "in", args.size)
        for i in range(args.runs):
            out = tmp / f"out{i}"
            out.mkdir()
            command = ([a.replace("OUT", str(out)) for a in args.command] if args.command
                       else ["merge", *frames, "--times", *TIMES, "-o", str(out / "hdr.exr")])
            delay = rng.uniform(0.0, args.max_delay)
            proc = subprocess.Popen(exe + command, env=env, cwd=tmp, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            time.sleep(delay)
            if proc.poll() is not None:     # done before the signal: not a Ctrl-C run
                proc.communicate()
                codes["finished before the signal"] += 1
                print(f"run {i + 1:2d}: finished before {delay:5.2f} s (exit "
                      f"{proc.returncode}): use a larger --size", flush=True)
                shutil.rmtree(out)
                continue
            proc.send_signal(signal.SIGINT)
            stdout, stderr = proc.communicate(timeout=300)
            codes[proc.returncode] += 1
            left = sorted(p.name for p in out.rglob("*"))
            if proc.returncode not in (130, -signal.SIGINT) or "Traceback" in stderr or left:
                bad.append((delay, proc.returncode, left, stderr.strip().splitlines()[-3:]))
            print(f"run {i + 1:2d}: SIGINT at {delay:5.2f} s -> exit {proc.returncode}"
                  + (f", left {left}" if left else "")
                  + (", traceback" if "Traceback" in stderr else ""), flush=True)
    print("exit codes: " + ", ".join(f"{c}: {n}" for c, n in sorted(
        codes.items(), key=lambda cn: str(cn[0]))))
    for delay, code, left, tail in bad:
        print(f"  at {delay:.2f} s: exit {code}, left {left}: {' | '.join(tail)}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
