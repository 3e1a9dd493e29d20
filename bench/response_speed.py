"""Issue 3 acceptance 3, issue 15 Build 4: speed and memory of calibrating from JPEG files.

Three stacks, each calibrated by ``selfcal.calibrate_response`` from its files (EXIF times)
and decoded by OpenCV alone (``cv2.imread`` of each full-size file, one after the other,
nothing kept), every job in a fresh child process (so peak memory is its own); module
imports (cv2; selfcal and clarabel) happen before the clock starts in both:

* ntu_canon_m3: the 17 out-of-camera 6000×4000 JPEGs (issue 3, acceptance 3);
* the 7 of them with distinct times spread over the bracket (ntu03, 05, 07, 09, 11, 13,
  16: 1/2000 … 1/100 s), at full size;
* the same 7 made small (issue 15, Build 4): decoded at 1/4 scale by libjpeg's DCT scaling
  (``selfcal.io.read_image(reduce=4)``, 1500×1000, about 1.5 MP) and written as JPEG q95
  with their EXIF exposure time, f-number and ISO (``selfcal.io.encode_image``), into a
  temporary folder removed at the end -- nothing computed from the data is kept.

Each job runs ``--repeat`` times (fresh processes); the table gives the fastest run's
seconds and the largest peak RSS.  ns/pixel is the job's seconds over the stack's pixels.
A second table splits the fastest selfcal run's seconds by stage (timers wrapped around
``selfcal.response.calibrate``'s calls of ``collect_samples``, ``solve_exposure_equations``
and ``judge_calibration`` inside the child).
Last, the small frames' f⁻¹ against the full-size frames' (RMS difference over codes
1…254): making frames small must not change the curve they give.

    python3 -m bench.response_speed [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from .data import REPO, data_dir
from .tables import finish, start, table

CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, {repo!r})
paths = {paths!r}
import cv2
stages = {{}}
if {what!r} == "selfcal":
    import clarabel  # noqa: F401  (imported lazily by the solver's monotone QP; excluded
    # like cv2's import; cvxpy is no longer imported by a calibration)
    import selfcal
    from selfcal.response import calibrate as cal

    def timed(name, f):
        def run(*a, **k):
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                stages[name] = stages.get(name, 0.0) + time.perf_counter() - t
        return run

    for name in ("collect_samples", "solve_exposure_equations", "judge_calibration"):
        setattr(cal, name, timed(name, getattr(cal, name)))
t0 = time.perf_counter()
if {what!r} == "decode":
    for p in paths:
        image = cv2.imread(p)
        del image
else:
    model = selfcal.calibrate_response(paths)
seconds = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
extra = {{}}
if {what!r} == "selfcal":
    extra = {{"block": model.diagnostics["samples"]["block_size"],
              "locations": model.diagnostics["samples"]["locations"],
              "inverse": model.inverse_response().tolist(), "stages": stages}}
print(json.dumps({{"seconds": seconds, "peak_mb": peak, **extra}}))
"""

#: The 7 frames of ntu_canon_m3 with distinct times spread over its bracket.
SMALL_STEMS = ("ntu03", "ntu05", "ntu07", "ntu09", "ntu11", "ntu13", "ntu16")
#: Decode scale of the small frames (6000×4000 / 4 = 1500×1000).
SMALL_REDUCE = 4


def run(what, paths, repeat=1):
    """Fastest seconds and largest peak of ``repeat`` fresh child processes."""
    code = CHILD.format(repo=str(REPO), paths=[str(p) for p in paths], what=what)
    runs = []
    for _ in range(repeat):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True)
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    best = min(runs, key=lambda r: r["seconds"])
    return {**best, "peak_mb": max(r["peak_mb"] for r in runs)}


def make_small(paths, folder):
    """The frames at 1/:data:`SMALL_REDUCE` scale, JPEG q95 with their EXIF exposure."""
    from selfcal.io import encode_image, read_exposure_info, read_image

    out = []
    for p in paths:
        info = read_exposure_info(p)
        image = read_image(p, reduce=SMALL_REDUCE)
        target = Path(folder) / (p.stem + ".jpg")
        target.write_bytes(encode_image(image, ".jpg", jpeg_quality=95,
                                        exposure_time=info.exposure_time,
                                        f_number=info.f_number, iso=info.iso))
        out.append(target)
    return out


def pixels(paths):
    from selfcal.io import read_image_size

    return sum(h * w for h, w in (read_image_size(p) for p in paths))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3,
                        help="fresh child processes per job (fastest kept)")
    args = parser.parse_args()
    start("response_speed", "none")
    ntu = sorted(data_dir("ntu_canon_m3").glob("*.JPG"))
    seven = [p for p in ntu if p.stem in SMALL_STEMS]
    rows, summary, inverse, stage_rows = [], {}, {}, []
    with tempfile.TemporaryDirectory(prefix="selfcal-small-") as tmp:
        small = make_small(seven, tmp)
        h, w = (v // SMALL_REDUCE for v in (4000, 6000))
        stacks = [("ntu17", f"ntu_canon_m3, {len(ntu)} × 6000×4000", ntu),
                  ("ntu7", f"7 of them, {len(seven)} × 6000×4000", seven),
                  ("small7", f"the 7 made small, {len(small)} × {w}×{h} (q95)", small)]
        for key, label, paths in stacks:
            n_pixels = pixels(paths)
            decode = run("decode", paths, args.repeat)
            calib = run("selfcal", paths, args.repeat)
            ratio = calib["seconds"] / decode["seconds"]
            summary[key] = (ratio, calib["peak_mb"])
            inverse[key] = np.array(calib["inverse"])
            st = calib["stages"]
            parts = [st.get("collect_samples", 0.0), st.get("solve_exposure_equations", 0.0),
                     st.get("judge_calibration", 0.0)]
            stage_rows.append([label, *(f"{v:.2f}" for v in parts),
                               f"{calib['seconds'] - sum(parts):.2f}",
                               f"{(calib['seconds'] - parts[0]) / decode['seconds']:.2f}"])
            for job, r in (("OpenCV imread (decode only)", decode),
                           ("selfcal.calibrate_response", calib)):
                rows.append([label, job, f"{r['seconds']:.2f}",
                             f"{r['seconds'] / decode['seconds']:.2f}",
                             f"{1e9 * r['seconds'] / n_pixels:.1f}",
                             f"{r['peak_mb']:.0f}",
                             str(r.get("block", "")), str(r.get("locations", ""))])
    print(f"each job in a fresh child process, fastest of {args.repeat}; "
          "imports excluded from both clocks\n")
    print(table(["stack", "job", "seconds", "ratio to decode", "ns/pixel",
                 "peak RSS (MB)", "block", "locations"], rows))
    print("\ntargets (issue 15, Build 4): ntu 17 × 24 MP ≤ 1.0× decode -> "
          f"{summary['ntu17'][0]:.2f}; 7 × 1.5 MP ≤ 3× decode -> {summary['small7'][0]:.2f}; "
          "selfcal peak ≤ 500 MB -> "
          f"{max(v[1] for v in summary.values()):.0f} MB")
    print("\nwhere selfcal's seconds go (the same runs): reading and sampling the frames "
          "(collect_samples, decoding included), every Eq. 8 solve (solve_exposure_equations:"
          " the fit, the check of the EXIF times and, when they are contradicted, the refit "
          "that refines them), the verdict (judge_calibration), the rest; and what is not "
          "reading, over the decode\n")
    print(table(["stack", "read + sample", "solves", "verdict", "rest",
                 "(selfcal - read) / decode"], stage_rows))
    diff = inverse["small7"][1:255] - inverse["ntu7"][1:255]
    print("\nf⁻¹ of the 7 small frames against that of the same 7 at full size: RMS "
          f"difference over codes 1…254 and the channels {np.sqrt(np.mean(diff ** 2)):.4f} "
          f"(largest {np.abs(diff).max():.4f})")


if __name__ == "__main__":
    main()
    finish()
