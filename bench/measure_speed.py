"""Issue 43, item 7: the cost of the exposures measured from the pixels, on frames the
model has not seen.

One model, calibrated (``selfcal.calibrate_response``, defaults, EXIF times) from the 12
frames of ../shared/data/ntu_canon_m3 that are not :data:`bench.hdr_speed.SPEED_FRAMES`;
then, side by side in this one process, each timing repeated ``--repeats`` times (the two
merges with and without measured exposures alternating, first one then the other
first; then OpenCV's and the others likewise).  The machine is shared: the tables give
the median and the best wall seconds, the median process-CPU seconds, and the ratios
within each round with their median over the rounds:

1. **arrays**: the five SPEED_FRAMES (24 MP, decoded once to RGB arrays, not counted),
   none of them the model's: ``selfcal.merge_hdr(arrays, times, model)`` by default
   (exposures measured: the pre-pass of
   :func:`selfcal.exposure.measured.measure_response_exposures`), the same with
   ``MergeOptions(exposures=ExposureRule(times="held"))``, and ``cv2.createMergeDebevec().process``
   on the same arrays (BGR) with the model's response as a 256×1×3 table.  Targets: the
   default ≤ 1.15× the merge without, and ≤ 0.5× OpenCV.
2. **files**: all 17 ntu files from disk (12 of them the model's, 5 not: the merge
   measures every frame with the pre-pass, as for frames it has not seen -- checked from
   ``diagnostics["measured_exposures"]["by"]``), the same two merges, and OpenCV's
   (``cv2.imread`` of every file, then ``MergeDebevec``).  Target: ≤ 1.15× the merge
   without.

The pre-pass alone (``measure_response_exposures`` on the frames to merge) is timed as
well.  Nothing here is a timed assertion; no data is written.

    python3 -m bench.measure_speed [--repeats 3] [--arrays-only]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from .data import SHARED_DATA
from .hdr_speed import SPEED_FRAMES
from .tables import finish, start, table


def _timed(call):
    t0, c0 = time.perf_counter(), time.process_time()
    out = call()
    return time.perf_counter() - t0, time.process_time() - c0, out


def _side_by_side(runs: dict, repeats: int) -> tuple:
    """Wall and process-CPU seconds of each named call, ``repeats`` times: the first two
    (the merges with and without measured exposures) in rounds of their own, in turn
    first and second (ABAB with the order swapped each round), then the others likewise.
    (In a rotating order of all four, OpenCV's 5 s merge between the two, the arrays'
    ratio came out 1.29 in CPU seconds; the two alone, alternating, 1.01 in the same
    hour: the order is kept out of the ratio.)"""
    names = list(runs)
    seconds: dict = {n: [] for n in names}
    cpu: dict = {n: [] for n in names}
    for group in (names[:2], names[2:]):
        for r in range(repeats):
            for n in (group if r % 2 == 0 else group[::-1]):
                dt, dc, out = _timed(runs[n])
                del out
                seconds[n].append(dt)
                cpu[n].append(dc)
    return seconds, cpu


def _report(title: str, timings: tuple, base: str, without: str, cv: str) -> None:
    seconds, cpu = timings
    med = {n: statistics.median(s) for n, s in seconds.items()}
    best = {n: min(s) for n, s in seconds.items()}
    mcpu = {n: statistics.median(s) for n, s in cpu.items()}

    def paired(a, b):
        # the median over the rounds of a/b within a round (adjacent in time for the two
        # merges; for the others, the same round of their own loop)
        return statistics.median(x / y for x, y in zip(seconds[a], seconds[b]))

    rows = [[n, f"{med[n]:.2f}", f"{best[n]:.2f}", " ".join(f"{x:.2f}" for x in s),
             f"{mcpu[n]:.2f}", f"{paired(n, without):.2f}", f"{paired(n, cv):.2f}"]
            for n, s in seconds.items()]
    print(f"\n{title}\n")
    print(table(["run", "median s", "best s", "all s", "median CPU s",
                 "/ without (per round, median)", "/ OpenCV (per round, median)"], rows))
    print(f"\nmeasured / without: {paired(base, without):.2f} per round, "
          f"{med[base] / med[without]:.2f} of the medians, {best[base] / best[without]:.2f} "
          f"of the best, {mcpu[base] / mcpu[without]:.2f} in CPU seconds (target ≤ 1.15); "
          f"default / OpenCV: {paired(base, cv):.2f} per round, {med[base] / med[cv]:.2f} of "
          f"the medians, {best[base] / best[cv]:.2f} of the best")


def _prepass(frames_in, model, times):
    """The pre-pass alone, as the merge calls it (the model's stuck codes excluded)."""
    from selfcal.exposure.measured import measure_response_exposures
    from selfcal.stack.frames import DEFAULT_CLIP_MARGIN, StackFrames

    levels = (model.diagnostics or {}).get("stuck_codes")
    stuck = None if levels is None else (np.asarray(levels["floor"], float),
                                         np.asarray(levels["ceiling"], float))
    frames = StackFrames(frames_in, False)
    return measure_response_exposures(frames, model, np.asarray(times, float),
                                      list(range(len(frames))),
                                      clip_margin=DEFAULT_CLIP_MARGIN, stuck=stuck)


def main(argv=None):
    import cv2

    import selfcal
    from selfcal.io import read_exposure_info, read_image

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--arrays-only", action="store_true")
    args = parser.parse_args(argv)
    folder = SHARED_DATA / "ntu_canon_m3"
    if not folder.exists():
        print(f"skipped: {folder} is absent (this bench reads ../shared/data)")
        return
    start("measure_speed", "none")
    every = sorted(folder.glob("*.JPG"))
    speed = [folder / f"{n}.JPG" for n in SPEED_FRAMES]
    others = [p for p in every if p not in speed]
    dt_cal, _, model = _timed(lambda: selfcal.calibrate_response(others))
    print(f"model: calibrated from the {len(others)} ntu frames outside {SPEED_FRAMES} "
          f"in {dt_cal:.1f} s")
    without = selfcal.MergeOptions(exposures=selfcal.ExposureRule(times="held"))
    response = model.inverse_response()[:, ::-1].astype(np.float32).reshape(256, 1, 3)

    images = [read_image(p) for p in speed]
    times = [read_exposure_info(p).relative_exposure for p in speed]
    check = selfcal.merge_hdr(images, times, model)
    by = check.diagnostics.get("measured_exposures", {}).get("by")
    e_with = np.asarray(check.exposures)
    del check
    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images]
    t32 = np.asarray(times, np.float32)
    seconds = _side_by_side({
        "merge_hdr (default: exposures measured)":
            lambda: selfcal.merge_hdr(images, times, model),
        "merge_hdr (times held)":
            lambda: selfcal.merge_hdr(images, times, model, options=without),
        "OpenCV MergeDebevec": lambda: cv2.createMergeDebevec().process(bgr, t32, response),
        "pre-pass alone (measure_response_exposures)":
            lambda: _prepass(images, model, times),
    }, args.repeats)
    h, w = images[0].shape[:2]
    _report(f"arrays: {len(images)} frames of {w}x{h} the model has not seen (measured by: "
            f"{by}); seconds over {args.repeats} rounds", seconds,
            "merge_hdr (default: exposures measured)", "merge_hdr (times held)",
            "OpenCV MergeDebevec")
    print("measured / EXIF exposures: "
          + " ".join(f"{e / t:.4f}" for e, t in zip(e_with, times)))
    del images, bgr
    if args.arrays_only:
        return

    paths = [str(p) for p in every]
    ftimes = np.asarray([read_exposure_info(p).relative_exposure for p in paths], np.float32)
    check = selfcal.merge_hdr(paths, model=model)
    by = check.diagnostics.get("measured_exposures", {}).get("by")
    del check

    def opencv_files():
        frames = [cv2.imread(p, cv2.IMREAD_COLOR) for p in paths]
        return cv2.createMergeDebevec().process(frames, ftimes, response)

    seconds = _side_by_side({
        "merge_hdr (default: exposures measured)": lambda: selfcal.merge_hdr(paths, model=model),
        "merge_hdr (times held)":
            lambda: selfcal.merge_hdr(paths, model=model, options=without),
        "OpenCV: imread all, MergeDebevec": opencv_files,
        "pre-pass alone (measure_response_exposures)":
            lambda: _prepass(paths, model, ftimes),
        "decode the files (read_image)": lambda: [read_image(p) for p in paths],
    }, args.repeats)
    _report(f"files: the {len(paths)} ntu files from disk (12 the model's, 5 not: measured "
            f"by: {by}); seconds over {args.repeats} rounds", seconds,
            "merge_hdr (default: exposures measured)", "merge_hdr (times held)",
            "OpenCV: imread all, MergeDebevec")


if __name__ == "__main__":
    main(sys.argv[1:])
    finish()
