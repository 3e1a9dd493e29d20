"""Issue 26: a rendered bracket's exposures measured from its pixels through the curve.

For each real stack (the split of ``bench.hdr_oddeven``; frames in exposure order, ntu's
decoded at 1/4 for the arrays), one model is calibrated from all frames as there
(``calibrate_response`` with its defaults), then
:func:`selfcal.exposure.measured.measure_response_exposures` measures every frame's
exposure (scale from the EXIF times or memorial's shutter_times.txt):

* **from arrays** (the frames decoded at full size): the reference, as the merge measures
  arrays since issue 43 (a strided subsample of the codes, unaveraged, linearised:
  ``selfcal.exposure.measured.code_subsample``); and, as before issue 43, **every pixel**
  linearised then area-averaged to the thumbnails: the median and largest
  ``|log(e_subsample / e_every)|`` (column "arrays: subsample vs every pixel"), and the
  files' default against every pixel;
* **from files**, with the pre-pass decoded at 1/K by libjpeg's DCT scaling (block means of
  *codes*, then f⁻¹: biased on texture) for K = the default and 2, 4, 8: the median and
  largest ``|log(e_file / e_array)|`` over the frames (each set rescaled to its geometric
  mean);
* how far the times are from the pixels: median and largest ``|log(time / e_array)|``;
* the cost: seconds of a full decode of the files (``read_image``, one thread), of a
  decode at 1/8 alone, of the default pre-pass (decode at 1/K, linearise, thumbnails,
  ratios), and the ratio; best of ``--repeats``.  memorial's PNGs cannot be DCT-scaled:
  their pre-pass is a full decode.

The measurement is the option's as it stands (``selfcal.exposure.measured.TREND``:
the times' trend since b026c6b, so "times off" is the frames' deviation from it).

    python3 -m bench.measured_exposures                  # tuning stacks
    python3 -m bench.measured_exposures --split heldout
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .tables import best_of, finish, start, table
from .data import TUNING_STACKS as TUNING, sorted_frames, stack_list

REDUCES = (2, 4, 8)


def measure(frames, model, times, reduce=None):
    from selfcal.exposure.measured import measure_response_exposures
    from selfcal.stack.frames import DEFAULT_CLIP_MARGIN

    # the black floors and stuck ceilings the merge would exclude (the model's)
    levels = (model.diagnostics or {}).get("stuck_codes")
    stuck = None if levels is None else (np.asarray(levels["floor"], float),
                                         np.asarray(levels["ceiling"], float))
    e, summary = measure_response_exposures(frames, model, np.asarray(times, float),
                                            range(len(times)), clip_margin=DEFAULT_CLIP_MARGIN,
                                            stuck=stuck, reduce=reduce)
    return e, summary


def measure_every_pixel(frames, model, times):
    """The measurement before issue 43: every pixel of the arrays linearised, then
    area-averaged to the thumbnails (``measured._linear_thumbnails`` of the whole frame)."""
    from selfcal.exposure import measured
    from selfcal.stack.frames import DEFAULT_CLIP_MARGIN

    levels = (model.diagnostics or {}).get("stuck_codes")
    stuck = None if levels is None else (np.asarray(levels["floor"], float),
                                         np.asarray(levels["ceiling"], float))
    made = {k: measured._linear_thumbnails(np.asarray(frames.items[k]), model,
                                           DEFAULT_CLIP_MARGIN, stuck)
            for k in range(len(times))}
    return measured._measured_from_thumbnails(made, frames, np.asarray(times, float),
                                              trend="times", reduce=1)


def log_spread(a, b):
    d = np.log(np.asarray(a, float)) - np.log(np.asarray(b, float))
    d = np.abs(d - np.mean(d))
    return float(np.median(d)), float(np.max(d))


def run_stack(name, paths, times, repeats):
    import selfcal
    from selfcal.io import read_image
    from selfcal.stack.frames import StackFrames

    arrays, paths, times = sorted_frames(name, paths, times, 1)
    model = selfcal.calibrate_response(arrays, times)
    e_arr, s_arr = measure(StackFrames(arrays, False), model, times)
    e_every, _ = measure_every_pixel(StackFrames(arrays, False), model, times)
    files = StackFrames(paths, False)
    e_def, s_def = measure(files, model, times)
    row = {"name": name, "frames": len(paths),
           "size": "{}×{}".format(*reversed(files.shape)), "reduce": s_def["reduce"],
           "times off": log_spread(times, e_arr), "default": log_spread(e_def, e_arr),
           "every": log_spread(e_arr, e_every), "default every": log_spread(e_def, e_every),
           "log_sigma": s_arr["log_sigma"]}
    jpeg = paths[0].suffix.lower() in (".jpg", ".jpeg")
    for r in REDUCES:
        row[r] = log_spread(measure(files, model, times, r)[0], e_arr) if jpeg else None
    row["decode"] = best_of(lambda: [read_image(p) for p in paths], repeats)
    row["decode8"] = best_of(lambda: [read_image(p, reduce=8) for p in paths], repeats)
    row["prepass"] = best_of(lambda: measure(files, model, times), repeats)
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("tuning", "heldout"), default="tuning")
    parser.add_argument("--only", action="append", help="only these stacks")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args(argv)
    start("measured_exposures", args.split)
    from threadpoolctl import threadpool_limits

    stacks = stack_list()
    names = [n for n in stacks if (n in TUNING) == (args.split == "tuning")]
    if args.only:
        names = [n for n in names if n in args.only]
    t0 = time.perf_counter()
    rows = []
    with threadpool_limits(limits=1):
        for n in names:
            rows.append(run_stack(n, *stacks[n], args.repeats))
            print(f"[{n}: {time.perf_counter() - t0:.0f} s]", file=sys.stderr, flush=True)

    def pair(v):
        return "-" if v is None else f"{v[0]:.4f} / {v[1]:.4f}"

    head = (["stack", "frames", "size", "times off (median / max)", "σ_t fit",
             "pre-pass 1/K", "arrays: subsample vs every pixel",
             "files at default K vs arrays", "files at default K vs every pixel"]
            + [f"files at 1/{r} vs arrays" for r in REDUCES]
            + ["full decode s", "decode at 1/8 s", "pre-pass s", "pre-pass / decode"])
    out = [[r["name"], str(r["frames"]), r["size"], pair(r["times off"]),
            f"{r['log_sigma']:.4f}", f"1/{r['reduce']}", pair(r["every"]), pair(r["default"]),
            pair(r["default every"])]
           + [pair(r[k]) for k in REDUCES]
           + [f"{r['decode']:.2f}", f"{r['decode8']:.2f}", f"{r['prepass']:.2f}",
              f"{100 * r['prepass'] / r['decode']:.0f} %"] for r in rows]
    print(f"\nExposures measured through the curve, {args.split} split: |log| differences "
          "after one global scale (median / max over the frames); seconds best of "
          f"{args.repeats}, one thread:\n")
    print(table(head, out))
    print(f"\nwall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
    finish()
