"""Issue 25: where the D7000 rows' error comes from -- the camera, the data, or the method.

The D7000 rows of ``bench_response_matrix.py`` score a per-channel response against the
NUS Nikon D7000 model's own tone curve, on stacks the model renders from the shared raws
(6 shots 1/250 … 1/8 s).  That model is not per-channel: a 3×3 colour transform and an
RBF gamut map sit before the tone curve, so a JPEG code of one channel is not a function
of that channel's raw value alone.  This script takes the bench's stack apart, one
degradation at a time, from a stack the calibration could fit exactly if the camera were
per-channel (noise-free sensor, no shutter jitter, 16-bit codes, no JPEG) to the bench's
own (noise, ±2 % jitter, 8-bit JPEG q92 4:2:0), at the bench's frame size (long side
384 px) and at four times it (1536 px), for selfcal (and colour-hdri's Debevec on the 8-bit stacks at the bench's size).

What the first row scores is the floor of any per-channel method on this camera: with no
noise and no quantisation, the only thing left between the codes and a per-channel curve is
the camera's cross-channel processing.  The rows below it say what each degradation adds.
Metrics as in the matrix bench: best-scale RMSE of f⁻¹ over codes 1 … 254 and the absolute
RMSE on codes 1 … 250 normalised at f⁻¹(250), root mean square over R, G, B.

    python bench/bench_d7000_floor.py [--jobs 2] [--sides 384,1536]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_response_matrix as matrix  # noqa: E402
from common import table  # noqa: E402

#: (label, noise, jitter, bit depth, JPEG quality): each row adds one degradation.
VARIANTS = (
    ("16-bit, no noise, no jitter, no JPEG", False, 0.0, 16, None),
    ("8-bit, no noise, no jitter, no JPEG", False, 0.0, 8, None),
    ("8-bit + noise", True, 0.0, 8, None),
    ("8-bit + noise + ±2 % jitter", True, 0.02, 8, None),
    ("8-bit + noise + jitter + JPEG q92 4:2:0 (the bench)", True, 0.02, 8, 92),
)
METHODS = ("selfcal", "colour")
#: colour-hdri runs on frames up to this long side only (the bench's own size).
COLOUR_MAX_SIDE = 384


def one_case(task):
    fname, side, variant = task
    from selfcal import sim
    from selfcal.pipeline.nus import read_nus_model
    from selfcal.sim.conditions import ModelCamera

    label, noise, jitter, depth, quality = VARIANTS[variant]
    cam = read_nus_model(matrix.NUS, wb_code=matrix.D7000_WB)
    rgb, render = matrix.d7000_scene(fname, cam, max_side=side)
    model = ModelCamera(render, cam.inverse_response, name=f"NUS D7000 on {fname}")
    stack = sim.simulate_stack(
        rgb, model, matrix.TIMES, jitter=jitter, jpeg_quality=quality, seed=1007,
        sensor=None if noise else sim.SensorModel.ideal(),
        output=sim.FrameOutput(bit_depth=depth),
        exposure_scale=1.0 / math.sqrt(matrix.TIMES[0] * matrix.TIMES[-1]))
    images = stack.images
    methods = METHODS
    if depth == 16 or side > COLOUR_MAX_SIDE:
        # colour-hdri's sampling bins 8-bit codes (selfcal reads 16-bit frames as they are),
        # and its Debevec solve takes minutes on the larger frames
        methods = ("selfcal",)
    t0 = time.perf_counter()
    truth = stack.inverse_response()
    if depth == 16:
        # a 16-bit calibration's table has 65536 rows: scored at the 8-bit codes' levels
        import selfcal

        lut = selfcal.calibrate_response(images, list(matrix.TIMES)).inverse_response()
        luts = {"selfcal": (lut[::257], time.perf_counter() - t0)}
        res = matrix.score(luts, truth[::257])
    else:
        res = matrix.score(matrix.calibrate_all(images, matrix.TIMES, methods), truth)
    return fname, side, variant, rgb.shape[:2], res, time.perf_counter() - t0


def _pooled(values) -> float:
    v = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(v * v)))


def _fmt(v) -> str:
    return "n/a" if math.isnan(v) else "inf" if not math.isfinite(v) else f"{v:.4f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--sides", default="384,1536",
                        help="long side of the frames, px (default %(default)s)")
    parser.add_argument("--variants", default="",
                        help="only these rows of VARIANTS (0-based, comma-separated)")
    args = parser.parse_args()
    if not (matrix.NUS.is_dir()
            and all((matrix.SHARED_DATA / "raw" / f).exists() for f in matrix.RAWS)):
        print(f"skipped: {matrix.NUS} or the raws in {matrix.SHARED_DATA / 'raw'} are absent")
        return
    sides = [int(s) for s in args.sides.split(",")]
    tasks = [(f, s, v) for s in sorted(sides, reverse=True) for f in matrix.RAWS
             for v in range(len(VARIANTS))
             if not args.variants or str(v) in args.variants.split(",")]
    t0 = time.perf_counter()
    with Pool(args.jobs, initializer=matrix._init_worker) as pool:
        results = pool.map(one_case, tasks, chunksize=1)
    rows = []
    for fname, side, variant, shape, res, _ in sorted(results, key=lambda r: (r[0], r[1], r[2])):
        s = res["selfcal"]
        c = res.get("colour", {})
        colour = _pooled(c["best"]) if "best" in c else math.nan
        rows.append([fname, f"{shape[0]}x{shape[1]}", VARIANTS[variant][0],
                     _fmt(_pooled(s["best"])), _fmt(_pooled(s["abs250"])), _fmt(colour)])
    print("NUS D7000 (wb 14) stacks of the shared raws, one degradation at a time (seed 1007); "
          "RMSE of f⁻¹, root mean square over R, G, B\n")
    print(table(["raw", "frame", "stack", "selfcal best-scale", "selfcal absolute 1…250",
                 "colour-hdri best-scale"], rows))
    print(f"\ntargets of issue 25: best-scale ≤ 0.008, absolute 1…250 ≤ 0.012; "
          f"wall {time.perf_counter() - t0:.0f} s with {args.jobs} jobs")


if __name__ == "__main__":
    main()
