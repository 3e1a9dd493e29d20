#!/usr/bin/env python3
"""How far the golden test's outputs move between runs, thread counts and library stacks.

``tests/test_golden.py`` compares the public API's outputs with ``tests/golden/public_api.npz``.
Its tolerances come from what this script measures: it computes the same outputs in fresh
processes, once per BLAS/OpenMP thread count and per Python interpreter given (a virtual
environment with other numpy/scipy/cvxpy/OpenCV versions stands in for another machine), and
prints, per array, the largest difference from the golden file relative to the array's
largest magnitude, and how many elements differ at all.

Usage::

    python scripts/golden_spread.py                       # this interpreter, 1 and 2 threads
    python scripts/golden_spread.py --python /path/to/other-venv/bin/python

Each interpreter must be able to import selfcal's dependencies; the repository's own
``selfcal`` is imported (the tree, not an installed copy).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / "tests" / "golden" / "public_api.npz"
#: Runs each output set in a fresh process with the repository first on the path.
DUMP = """
import sys
sys.path[:0] = [{repo!r}, {tests!r}]
import numpy as np, test_golden
np.savez({out!r}, **test_golden._public_outputs())
"""


def outputs_in_process(python: str, threads: int, out: Path) -> dict[str, np.ndarray]:
    """The golden test's outputs computed by ``python`` with ``threads`` BLAS threads."""
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), OPENBLAS_NUM_THREADS=str(threads),
               MKL_NUM_THREADS=str(threads))
    code = DUMP.format(repo=str(REPO), tests=str(REPO / "tests"), out=str(out))
    subprocess.run([python, "-c", code], check=True, env=env)
    with np.load(out) as found:
        return {k: found[k] for k in found.files}


def spread_rows(label: str, now: dict[str, np.ndarray], golden) -> list[str]:
    rows = []
    for name in golden.files:
        want = golden[name].astype(np.float64)
        got = now[name].astype(np.float64)
        diff = np.abs(got - want)
        scale = max(float(np.abs(want).max()), 1e-300)
        rows.append(f"{label:<28} {name:<20} {golden[name].dtype.name:<8} "
                    f"{diff.max() / scale:10.2e} {int((diff > 0).sum()):>8} / {diff.size}")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--python", action="append", default=[],
                        help="another interpreter (repeatable); default: this one only")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args(argv)
    pythons = [sys.executable, *args.python]
    golden = np.load(GOLDEN)
    print(f"{'interpreter, threads':<28} {'array':<20} {'dtype':<8} "
          f"{'max |Δ|/max':>10} {'elements differing':>20}")
    with tempfile.TemporaryDirectory() as tmp:
        for python in pythons:
            versions = subprocess.run(
                [python, "-c", "import numpy, scipy, cvxpy, cv2; print(numpy.__version__, "
                 "scipy.__version__, cvxpy.__version__, cv2.__version__)"],
                check=True, capture_output=True, text=True).stdout.split()
            print(f"# {python}: numpy {versions[0]}, scipy {versions[1]}, "
                  f"cvxpy {versions[2]}, OpenCV {versions[3]}")
            for threads in args.threads:
                now = outputs_in_process(python, threads, Path(tmp) / "out.npz")
                label = f"{Path(python).parent.parent.name}, {threads} thread(s)"
                print("\n".join(spread_rows(label, now, golden)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
