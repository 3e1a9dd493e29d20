"""HDR merge speed and memory on full-size real frames (issue 5).

1. Speed: five 24 MP frames of ../shared/data/ntu_canon_m3 (1/2000 … 1/100 s, decoded
   once to RGB arrays), one response model calibrated from them: ``selfcal.merge_hdr`` of
   the arrays vs ``cv2.createMergeDebevec().process`` on the same arrays (BGR) with the
   same model's response as a 256×1×3 float32 table.  Times from one run, and their ratio
   (target: selfcal no slower).
2. Memory: the full 17-frame merge *from files* (decoded one at a time) in a fresh child
   process (started first, from a small parent), with the EXR written; peak RSS from
   ``resource.getrusage`` ru_maxrss and /proc VmHWM (target ≤ 2 GB).

    python bench/bench_hdr_speed.py
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, Timer, data_dir, table  # noqa: E402

SPEED_FRAMES = ["ntu03", "ntu05", "ntu09", "ntu12", "ntu16"]

CALIBRATE = r"""
import json, sys
import selfcal
paths, model_path = json.loads(sys.argv[1])
selfcal.calibrate_response(paths).save(model_path)
"""

MERGE = r"""
import json, resource, sys, time
import selfcal
from selfcal.hdr.io import write_radiance
paths, model_path, out = json.loads(sys.argv[1])
model = selfcal.load_model(model_path)


def peaks():
    # VmHWM: this process's own high-water mark; ru_maxrss can also carry the parent's
    # RSS at fork time across exec on Linux, so both are reported.
    hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM"))
    return hwm, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


t0 = time.perf_counter()
result = selfcal.merge_hdr(paths, model=model)
t1 = time.perf_counter()
merge_peaks = peaks()
write_radiance(out, result.radiance, half=True)
t2 = time.perf_counter()
print(json.dumps({"merge_s": t1 - t0, "write_s": t2 - t1, "merge_peaks_kb": merge_peaks,
                  "total_peaks_kb": peaks(), "shape": list(result.radiance.shape),
                  "unmeasured": float(result.unmeasured.mean()),
                  "warnings": result.warnings}))
"""


def run_child(code: str, arg) -> str:
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(arg)], capture_output=True,
                          text=True, cwd=REPO)
    if proc.returncode != 0:
        sys.exit(f"child process failed:\n{proc.stderr}")
    return proc.stdout


def memory_run(folder: Path):
    """17-frame merge from files in fresh child processes (run first: a small parent)."""
    all_paths = [str(p) for p in sorted(folder.glob("*.JPG"))]
    with tempfile.TemporaryDirectory() as tmp:
        model_path = str(Path(tmp) / "model.json")
        with Timer() as t_cal:
            run_child(CALIBRATE, [all_paths, model_path])
        out = Path(tmp) / "merged.exr"
        stats = json.loads(run_child(MERGE, [all_paths, model_path, str(out)])
                           .strip().splitlines()[-1])
        stats["exr_mb"] = out.stat().st_size / 1e6
    stats["calibrate_s"] = t_cal.seconds
    stats["frames"] = len(all_paths)
    return stats


def main():
    import cv2

    import selfcal
    from selfcal.io import read_exposure_info, read_image

    folder = data_dir("ntu_canon_m3")
    stats = memory_run(folder)
    paths = [folder / f"{n}.JPG" for n in SPEED_FRAMES]
    with Timer() as t_cal:
        model = selfcal.calibrate_response(paths)
    with Timer() as t_dec:
        images = [read_image(p) for p in paths]
    times = [read_exposure_info(p).relative_exposure for p in paths]
    h, w = images[0].shape[:2]

    with Timer() as t_self:
        result = selfcal.merge_hdr(images, times, model)
    with Timer() as t_noise:
        selfcal.merge_hdr(images, times, model, weighting="noise", deghost=True)
    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images]
    response = model.inverse_response()[:, ::-1].astype(np.float32).reshape(256, 1, 3)
    with Timer() as t_cv:
        cv_out = cv2.createMergeDebevec().process(bgr, np.asarray(times, np.float32), response)
    del bgr, cv_out, images

    print(f"speed: {len(paths)} frames of {w}x{h} ({w * h / 1e6:.0f} MP), decoded arrays, one "
          f"model (calibrated from the files in {t_cal.seconds:.1f} s; decoding took "
          f"{t_dec.seconds:.1f} s, not counted)\n")
    print(table(["merge", "seconds", "ratio to OpenCV"],
                [["selfcal merge_hdr (hat)", f"{t_self.seconds:.2f}",
                  f"{t_self.seconds / t_cv.seconds:.2f}"],
                 ["selfcal merge_hdr (noise, deghost)", f"{t_noise.seconds:.2f}",
                  f"{t_noise.seconds / t_cv.seconds:.2f}"],
                 ["OpenCV MergeDebevec", f"{t_cv.seconds:.2f}", "1.00"]]))
    print(f"\nselfcal / OpenCV time: {t_self.seconds / t_cv.seconds:.2f} (target ≤ 1); "
          f"selfcal unmeasured pixels {100 * result.unmeasured.mean():.1f}%")
    del result

    h, w = stats["shape"][:2]
    gb = 1024 ** 2
    print(f"\nmemory: {stats['frames']} frames of {w}x{h} merged from files (decoded one at "
          f"a time) with a model calibrated from them (in its own process, "
          f"{stats['calibrate_s']:.1f} s); half EXR written ({stats['exr_mb']:.0f} MB, PIZ)\n")
    mh, mr = stats["merge_peaks_kb"]
    th, tr = stats["total_peaks_kb"]
    print(table(["measure", "merge", "merge + EXR write"],
                [["seconds", f"{stats['merge_s']:.1f}",
                  f"{stats['merge_s'] + stats['write_s']:.1f}"],
                 ["peak RSS, VmHWM (GB)", f"{mh / gb:.2f}", f"{th / gb:.2f}"],
                 ["peak RSS, ru_maxrss (GB)", f"{mr / gb:.2f}", f"{tr / gb:.2f}"]]))
    print(f"\npeak RSS {max(th, tr) / gb:.2f} GB (target ≤ 2 GB); the accumulators alone "
          f"(2 × H×W×3 float32) are {2 * w * h * 12 / 1024 ** 3:.2f} GB; unmeasured pixels "
          f"{100 * stats['unmeasured']:.2f}%")
    for warning in stats["warnings"]:
        print(f"  merge warning: {warning}")

if __name__ == "__main__":
    main()
