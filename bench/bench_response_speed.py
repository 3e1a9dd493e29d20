"""Issue 3, acceptance 3: speed and memory of calibrating ntu_canon_m3 from its files.

In one run, each in a fresh child process (so peak memory is its own): OpenCV decoding the
17 full-size 6000×4000 JPEGs (``cv2.imread``, one after the other, nothing kept), and
``selfcal.calibrate_response`` on the same 17 paths (EXIF times).  Module imports (cv2;
selfcal and cvxpy) happen before the clock starts in both.

    python bench/bench_response_speed.py
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, data_dir, table  # noqa: E402

CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, {repo!r})
paths = {paths!r}
import cv2
if {what!r} == "selfcal":
    import cvxpy  # noqa: F401  (imported lazily by the solver; excluded like cv2's import)
    import selfcal
t0 = time.perf_counter()
if {what!r} == "decode":
    for p in paths:
        image = cv2.imread(p)
        del image
else:
    model = selfcal.calibrate_response(paths)
seconds = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({{"seconds": seconds, "peak_mb": peak}}))
"""


def run(what, paths):
    code = CHILD.format(repo=str(REPO), paths=[str(p) for p in paths], what=what)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    paths = sorted(data_dir("ntu_canon_m3").glob("*.JPG"))
    decode = run("decode", paths)
    calib = run("selfcal", paths)
    rows = [["OpenCV imread (decode only)", f"{decode['seconds']:.2f}", "1.00",
             f"{decode['peak_mb']:.0f}"],
            ["selfcal.calibrate_response", f"{calib['seconds']:.2f}",
             f"{calib['seconds'] / decode['seconds']:.2f}", f"{calib['peak_mb']:.0f}"]]
    print(f"ntu_canon_m3: {len(paths)} JPEGs of 6000x4000, from files\n")
    print(table(["job", "seconds", "ratio to decode", "peak RSS (MB)"], rows))
    print("\ntargets: ratio ≤ 1.5, selfcal peak memory ≤ 2048 MB")


if __name__ == "__main__":
    main()
