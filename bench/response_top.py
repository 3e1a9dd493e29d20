"""Issue 35 part 4: the error of f⁻¹ per code range, and where each channel's samples stop.

The stacks of the response matrix (:mod:`bench.response_matrix`: its cells, curves, seeds
and split, every method given the nominal times).  Per (stack, channel), f⁻¹ against the
truth on the code ranges :data:`RANGES`:

- *best-scale*: the least-squares scale of the matrix' metric (one per channel, fitted on
  codes 1 … 254), then the RMSE over the range's codes within 1 … 254 (so the ranges
  split the matrix' figure: the squares of the per-range RMSEs, weighted by the ranges'
  code counts, add up to its square);
- *absolute* (selfcal, whose f⁻¹(255) = 1 as the truth's): no scale, every code of the
  range (code 255 is 0 by construction).

Median and p90 over (stack, channel), per method; then selfcal's top range (245-255)
per cell, and where the brightest sample selfcal keeps sits: per channel, the highest
code of a sample valid in some frame (:func:`selfcal.stack.samples.frame_masks` with the
library's clip margin and β, before the measured ringing reach; the histogram of that
code is the table "brightest kept sample").

    python3 -m bench.response_top [--split heldout|tuning] [--curves 2]
        [--cells exact,saturated] [--methods selfcal,colour] [--jobs 2]
        [--no-hidden-white] [--tag before]
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
import warnings
from dataclasses import replace
from multiprocessing import Pool

import numpy as np

from . import response_matrix as rm
from .data import dorf_curve
from .tables import finish, start, table

#: The code ranges (inclusive).
RANGES = ((0, 15), (16, 63), (64, 191), (192, 244), (245, 255), (0, 255))
TOP = (245, 255)


def _init_worker():
    rm._init_worker()
    warnings.filterwarnings("ignore")


def brightest_kept(images) -> list:
    """Per channel, the highest code (0 … 255) of a sample valid in some frame."""
    from selfcal.response import ResponseOptions
    from selfcal.stack.samples import collect_samples, frame_masks

    opt = ResponseOptions()
    samples = collect_samples(images, max_samples=opt.max_samples,
                              clip_margin=opt.solver.clip_margin, seed=0)
    masks = frame_masks(samples, clip_margin=opt.solver.clip_margin,
                        saturation_threshold=opt.solver.saturation_threshold)
    valid = ~(masks["clipped"] | masks["saturated"])
    out = []
    for c in range(3):
        v = samples.values[..., c][valid]
        out.append(float(v.max() * 255) if v.size else float("nan"))
    return out


def range_errors(lut: np.ndarray, truth: np.ndarray, absolute: bool) -> list:
    """Per channel, the RMSE of f⁻¹ on each of :data:`RANGES` (see the module docstring)."""
    out = []
    for c in range(3):
        est, tru = lut[:, c].astype(np.float64), truth[:, c].astype(np.float64)
        lo_hi = (0, 255)
        if not absolute:
            inner = slice(1, 255)
            s = float(np.dot(est[inner], tru[inner]) / max(np.dot(est[inner], est[inner]),
                                                             1e-300))
            est, lo_hi = s * est, (1, 254)
        row = []
        for a, b in RANGES:
            a, b = max(a, lo_hi[0]), min(b, lo_hi[1])
            d = est[a:b + 1] - tru[a:b + 1]
            row.append(float(np.sqrt(np.mean(d * d))))
        out.append(row)
    return out


def one_stack(task):
    _, cell, index, seed, size, methods = task
    own = getattr(rm.CONDITIONS[cell], "size", None)
    stack = rm.CONDITIONS[cell].simulate(dorf_curve(index), seed, size=own or size)
    truth = stack.inverse_response()
    luts = rm.calibrate_all(stack.images, rm.TIMES, methods)
    res = {}
    for m, (lut, _) in luts.items():
        if lut is None:
            res[m] = None
            continue
        res[m] = {"best": range_errors(lut, truth, False)}
        if m == "selfcal":
            res[m]["abs"] = range_errors(lut, truth, True)
    return {"cell": cell, "index": index, "seed": seed, "methods": res,
            "top_kept": brightest_kept(stack.images)}


def _stats(results, method, key):
    rows = [ch for r in results if r["methods"].get(method) for ch in r["methods"][method][key]]
    a = np.array(rows)              # (stack·channel, ranges)
    return np.median(a, axis=0), np.percentile(a, 90, axis=0), len(rows)


def report(results, args) -> str:
    names = [f"{a}-{b}" for a, b in RANGES]
    title = ("held-out split (odd DoRF curves, seeds ≥ 1000)" if args.split == "heldout"
             else "tuning split (even DoRF curves, seeds < 1000)")
    lines = [f"### {title}", "",
             f"{len(results)} stacks ({args.curves} per cell, cells: {', '.join(args.cells)}); "
             "RMSE of f⁻¹ per code range, median / p90 over (stack, channel); best-scale: "
             "one scale per channel fitted on codes 1 … 254, ranges within 1 … 254", ""]
    rows = []
    for m in args.methods:
        keys = ["best"] + (["abs"] if m == "selfcal" else [])
        for key in keys:
            med, p90, n = _stats(results, m, key)
            label = f"{rm.LABELS[m]} ({'absolute' if key == 'abs' else 'best-scale'})"
            rows.append([label, n] + [f"{x:.4f} / {y:.4f}" for x, y in zip(med, p90)])
    lines += [table(["method", "channels"] + names, rows), ""]
    # selfcal's top range per cell, and where its samples stop
    top = RANGES.index(TOP)
    rows = []
    for cell in args.cells:
        rs = [r for r in results if r["cell"] == cell and r["methods"].get("selfcal")]
        if not rs:
            continue
        best = [ch[top] for r in rs for ch in r["methods"]["selfcal"]["best"]]
        ab = [ch[top] for r in rs for ch in r["methods"]["selfcal"]["abs"]]
        whole = [ch[-1] for r in rs for ch in r["methods"]["selfcal"]["best"]]
        kept = [k for r in rs for k in r["top_kept"]]
        # the top range's share of the squared best-scale error over 1 … 254
        share = np.median([(ch[top] ** 2 * 10) / max(ch[-1] ** 2 * 254, 1e-30)
                           for r in rs for ch in r["methods"]["selfcal"]["best"]])
        row = [cell, len(rs), f"{np.median(whole):.4f}", f"{np.median(best):.4f}",
               f"{np.median(ab):.4f}", f"{share:.2f}",
               f"{np.min(kept):.0f} / {np.median(kept):.0f} / {np.max(kept):.0f}"]
        if "colour" in args.methods:
            cb = [ch[top] for r in rs if r["methods"].get("colour")
                  for ch in r["methods"]["colour"]["best"]]
            row.append(f"{np.median(cb):.4f}" if cb else "n/a")
        rows.append(row)
    headers = ["cell", "stacks", "selfcal 1-254 best-scale", "245-255 best-scale",
               "245-255 absolute", "245-254 share of the squared error",
               "brightest kept sample min / median / max"]
    if "colour" in args.methods:
        headers.append("colour-hdri 245-255 best-scale")
    lines += ["selfcal per cell (medians over (stack, channel))", "", table(headers, rows), ""]
    kept = np.array([k for r in results for k in r["top_kept"]])
    edges = [0, 225, 235, 240, 245, 250, 256]
    counts = np.histogram(kept, bins=edges)[0]
    lines += ["Brightest kept sample (code) per (stack, channel)", "",
              table([f"{a}-{b - 1}" for a, b in zip(edges[:-1], edges[1:])],
                    [[int(c) for c in counts]]), ""]
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("heldout", "tuning"), default="heldout")
    parser.add_argument("--curves", type=int, default=2,
                        help="stacks (DoRF curves) per cell (default %(default)s)")
    parser.add_argument("--cells", default="", help="comma-separated cells or scene prefixes")
    parser.add_argument("--size", default="256x384", help="frame HxW (default %(default)s)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--methods", default="selfcal",
                        help="comma-separated subset of " + ",".join(rm.METHODS)
                             + " (default %(default)s)")
    parser.add_argument("--tag", default="",
                        help="a name for the run's record (bench/results/response_top.*"
                             "tag-<name>*.json), e.g. before / after a change")
    parser.add_argument("--no-hidden-white", action="store_true",
                        help="selfcal with ResponseOptions(hidden_white=False), for the "
                             "comparison")
    args = parser.parse_args()
    if args.no_hidden_white:      # set before the workers fork
        rm.SELFCAL_OPTIONS = replace(rm.SELFCAL_OPTIONS, hidden_white=False)
    start("response_top", args.split)
    args.methods = tuple(m for m in rm.METHODS if m in args.methods.split(","))
    if "selfcal" not in args.methods:
        parser.error("--methods must include selfcal")
    wanted = [w.strip() for w in args.cells.split(",") if w.strip()]
    args.cells = [c for c in rm.CONDITIONS
                  if not wanted or any(c == w or c.startswith(w + "/") for w in wanted)]
    if not rm.DORF.exists():
        sys.exit(f"benchmark data not found: {rm.DORF}")
    h, w = (int(v) for v in args.size.lower().split("x"))
    tasks = rm.split_tasks(args.split, args.curves, set(args.cells), (h, w), False,
                           args.methods)
    t0 = time.perf_counter()
    with Pool(args.jobs, initializer=_init_worker) as pool:
        results = list(pool.imap_unordered(one_stack, tasks))
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(report(results, args))
    print(f"wall {time.perf_counter() - t0:.0f} s with {args.jobs} jobs; CPU "
          f"{usage.ru_utime + usage.ru_stime:.0f} s")


if __name__ == "__main__":
    main()
    finish()
