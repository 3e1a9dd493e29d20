"""What Eq. 8 is solved on: block samples or histogram correspondences of every pixel.

Two measurements on the stacks of ``bench_response_matrix.py`` (same cells, curves, seeds
and split; selfcal only, nominal times):

1. ``--compare``: ``selfcal.response.calibrate.CORRESPONDENCES`` = ``"blocks"`` (today's
   stratified flat block samples) against ``"histogram"`` (the [Grossberg2003] transfer
   functions of every usable pixel, ``selfcal.response.histogram_samples``, gated by the
   block fit) and ``"histogram+blocks"`` (both sets of rows in one solve), per cell and
   pooled: median and p90 of the best-scale RMSE of f⁻¹ over codes 1 … 254.
2. ``--pixels``: the error against the data used -- blocks with ``max_samples`` 250 …
   16000 (the sample locations times the frames they are read in), histograms with
   ``PIXEL_FRACTION`` 1/256 … 1 of the usable pixels (the pixel values that entered the
   histograms, summed over frame pairs and channels, as the library counts them).

    python bench/bench_response_correspondences.py --compare [--split tuning] [--curves 3]
        [--cells neutral,colourful,saturated,exact/neutral,exact/saturated]
    python bench/bench_response_correspondences.py --pixels [--split tuning] [--curves 4]
        [--cells exact/neutral,exact/saturated]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_response_matrix as matrix  # noqa: E402
from common import table  # noqa: E402

from selfcal.sim.scoring import best_scale_rmse  # noqa: E402

MODES = {"blocks": ("blocks", False), "histogram": ("histogram", False),
         "histogram+blocks": ("histogram", True)}


def _stack(task):
    _, cell, index, seed, size, _ = task
    own = getattr(matrix.CONDITIONS[cell], "size", None)
    return matrix.CONDITIONS[cell].simulate(matrix.dorf_curve(index), seed, size=own or size)


def _errors(stack, **options) -> list:
    import selfcal

    truth = stack.inverse_response()
    try:
        lut = selfcal.calibrate_response(stack.images, matrix.TIMES,
                                         **options).inverse_response()
    except Exception:
        return [np.inf] * 3
    return [best_scale_rmse(lut[1:255, c], truth[1:255, c]) for c in range(3)]


def _configure(mode: str, fraction: float = 1.0) -> None:
    from selfcal.response import calibrate, histogram_samples

    calibrate.CORRESPONDENCES, calibrate.WITH_BLOCKS = MODES[mode]
    histogram_samples.PIXEL_FRACTION = fraction


def compare_task(task):
    stack = _stack(task)
    out = {}
    for mode in MODES:
        _configure(mode)
        out[mode] = _errors(stack)
    _configure("blocks")
    return task[1], out


def pixels_task(args):
    task, settings = args
    from selfcal.response import histogram_samples
    from selfcal.stack import samples
    from selfcal.stack.samples import PER_BIN, collect_samples

    stack = _stack(task)
    rows = []
    for kind, value in settings:
        if kind == "blocks":
            _configure("blocks")
            errs = _errors(stack, max_samples=int(value))
            s = collect_samples(stack.images, max_samples=int(value))
            used = s.n_samples * s.n_frames
        elif kind == "per_bin":
            _configure("blocks")
            samples.PER_BIN = int(value)
            errs = _errors(stack, max_samples=10**6)
            s = collect_samples(stack.images, max_samples=10**6)
            used = s.n_samples * s.n_frames
            samples.PER_BIN = PER_BIN
        else:
            _configure("histogram", value)
            errs = _errors(stack)
            s = collect_samples(stack.images, keep_reduced=True)
            used = histogram_samples.histogram_correspondences(s.reduced).pixels
        rows.append((kind, value, used, errs))
    _configure("blocks")
    return task[1], rows


def _init():
    matrix._init_worker()
    warnings.filterwarnings("ignore")


def _tasks(args):
    wanted = [w.strip() for w in args.cells.split(",") if w.strip()]
    cells = {c for c in matrix.CONDITIONS
             if any(c == w or c.startswith(w + "/") for w in wanted)}
    h, w = (int(v) for v in args.size.split("x"))
    return matrix.split_tasks(args.split, args.curves, cells, (h, w), False, ("selfcal",))


def run_compare(args):
    with Pool(args.jobs, initializer=_init) as pool:
        results = pool.map(compare_task, _tasks(args))
    cells = [c for c in matrix.CONDITIONS if any(r[0] == c for r in results)]
    rows, pooled = [], {m: [] for m in MODES}
    for cell in cells:
        vals = {m: [v for c, r in results if c == cell for v in r[m]] for m in MODES}
        for m in MODES:
            pooled[m] += vals[m]
        rows.append([cell, len(vals["blocks"]) // 3]
                    + [f"{np.median(vals[m]):.4f} / {np.percentile(vals[m], 90):.4f}"
                       for m in MODES])
    rows.append(["all cells", len(pooled["blocks"]) // 3]
                + [f"{np.median(pooled[m]):.4f} / {np.percentile(pooled[m], 90):.4f}"
                   for m in MODES])
    print(f"{args.split} split, {args.curves} curves per cell; best-scale RMSE of f⁻¹ "
          "(codes 1 … 254), median / p90 over (stack, channel)\n")
    print(table(["cell", "stacks"] + list(MODES), rows))


def run_pixels(args):
    settings = ([("blocks", n) for n in (250, 1000, 4000, 16000)]
                + [("per_bin", n) for n in args.per_bin]
                + [("histogram", f) for f in (1 / 256, 1 / 64, 1 / 16, 1 / 4, 1.0)])
    if args.per_bin:
        settings = [s for s in settings if s[0] != "histogram"]
    with Pool(args.jobs, initializer=_init) as pool:
        results = pool.map(pixels_task, [(t, settings) for t in _tasks(args)])
    rows = []
    for kind, value in settings:
        errs, used = [], []
        for _, rs in results:
            for k, v, u, e in rs:
                if (k, v) == (kind, value):
                    errs += e
                    used.append(u)
        label = {"blocks": f"max_samples {value}", "per_bin": f"per_bin {value}",
                 "histogram": f"pixels × {value:.4g}"}[kind]
        failed = int(np.sum(~np.isfinite(errs))) // 3
        rows.append([kind, label, f"{np.median(used):,.0f}", f"{np.median(errs):.4f}",
                     f"{np.percentile(errs, 90, method='higher'):.4f}", failed])
    print(f"{args.split} split, cells {args.cells}, {args.curves} curves per cell; values "
          "used: block samples × frames, or pixel values in the histograms (median per "
          "stack)\n")
    print(table(["correspondences", "setting", "values used", "median", "p90",
                 "stacks failed (scored inf)"], rows))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare", action="store_true")
    parser.add_argument("--pixels", action="store_true")
    parser.add_argument("--split", choices=("heldout", "tuning"), default="tuning")
    parser.add_argument("--curves", type=int, default=3)
    parser.add_argument("--cells", default=None)
    parser.add_argument("--size", default="256x384")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--per-bin", type=lambda v: [int(x) for x in v.split(",")],
                        default=[], help="with --pixels: also these locations per intensity "
                        "bin and frame (no max_samples cap), and no histogram rows")
    args = parser.parse_args()
    if args.compare:
        args.cells = args.cells or "neutral,colourful,saturated,exact/neutral,exact/saturated"
        run_compare(args)
    if args.pixels:
        args.cells = args.cells or "exact/neutral,exact/saturated"
        run_pixels(args)
    if not (args.compare or args.pixels):
        parser.error("give --compare and/or --pixels")


if __name__ == "__main__":
    main()
