"""Issue 15: the response curve on a matrix of conditions, held out from tuning, against peers.

Stacks (``selfcal.sim.conditions.CONDITIONS``, one stack per cell, DoRF curve and seed):
a procedural outdoor scene (colour chart, foliage, sky with the sun, skin-toned spheres, a
long shadow ramp; shading and texture) -- neutral, colourful or saturated; a random colour
matrix with white balance and highlight clip; the smooth or the clip gamut map; one DoRF
curve for all channels or different ones per channel; in-camera sharpening or not; shot
and read noise; six shots 1/250 … 1/8 s with ±3 % shutter jitter; OpenCV JPEG 4:2:0 or
4:4:4 at a quality drawn from the seed in 75 … 95.  Every method gets the nominal times.
The ``exact/…`` cells (``selfcal.sim.exact``) have no colour matrix and no gamut map:
the curves act per channel on the noisy sensor values of a Voronoi-patch scene over 12
stops, JPEG q92 4:2:0, at 300x400 and at 1.5 MP (their own size, whatever ``--size``).

Curves: the forward tables of ``../shared/data/dorf_emor/201_CRF_data.mat``.  Split:
*tuning* = even-indexed curves and seeds < 1000; *held-out* = odd-indexed curves and
seeds ≥ 1000 (cell k, stack j: seed ``50 k + j``, plus 1000 held out; curve number
``j · cells + k`` of the split's list, so no two stacks of a run share a curve while
there are enough).  Choose parameters on the tuning split only; report the held-out one.

Methods: ``selfcal.calibrate_response`` (defaults); colour-hdri's
``camera_response_functions_Debevec1997`` (its default Grossberg 2003 histogram sampling;
an ``ImageStack`` of code/255 frames, shortest first, BLAS on one thread); OpenCV
``CalibrateDebevec`` and ``CalibrateRobertson`` (``bench.peers``); Mitsunaga & Nayar
1999 (``bench.peers``: polynomial response, exposure ratios re-estimated from
the nominal ones).

Metric, per channel: RMSE of f⁻¹ over codes 1 … 254 after the least-squares scale
(``selfcal.sim.scoring.best_scale_rmse``, one scale per channel); for selfcal also the
absolute RMSE (its f⁻¹(255) = 1, as the truth's).  Median and p90 are over the
(stack, channel) values of a cell; a method that fails scores +inf.  Time: wall time of
each method's call, per stack.

D7000 rows: the NUS Nikon D7000 in-camera model (``../shared/data/nus_model_nikon_d7000``,
``selfcal.pipeline.nus``, white-balance setting 14) renders each raw of
``../shared/data/raw`` (``selfcal.io.raw.read_raw_linear``, half size, block-averaged to at
most 384 px, white-balanced with its as-shot gains, clipped at 1, divided by the model's
gains) as the middle of a six-shot bracket 1/250 … 1/8 s: the raw scaled by
``t / sqrt(t_min t_max)``, shot and read noise (``SensorModel()``), clipped at white, ±2 %
jitter, JPEG q92 4:2:0.  Truth: the model's own tone curve (its ``raw2jpg_respFcns``
f⁻¹).  Reported per raw: best-scale and absolute RMSE over the three channels (each
channel with its own scale).  Skipped, with a message, when the data are absent.

    python3 -m bench.response_matrix [--split heldout|tuning] [--curves 6]
        [--cells saturated/base,neutral] [--size 256x384] [--jobs 2] [--no-d7000]
        [--methods selfcal,colour,...] [--no-ringing] [--no-hidden-white]
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
import time
import warnings
from dataclasses import replace
from multiprocessing import Pool

import numpy as np

from .data import SHARED_DATA, dorf_curve
from .peers import (colour_hdri_inverse_response, mitsunaga_nayar_inverse_response,
                    opencv_inverse_response)
from .tables import finish, start, table

from selfcal.response import ResponseOptions
from selfcal.sim import DEMO_EXPOSURE_TIMES
from selfcal.sim.conditions import CONDITIONS as _NATURAL
from selfcal.sim.exact import EXACT_CONDITIONS
from selfcal.sim.scoring import best_scale_rmse, rmse

# every cell: the natural-scene cells (colour matrix and gamut map before the curves), then
# the cells where the per-channel model is exact (their frame size is their own)
CONDITIONS = {**_NATURAL, **EXACT_CONDITIONS}

TIMES = list(DEMO_EXPOSURE_TIMES)
METHODS = ("selfcal", "colour", "debevec", "robertson", "mitsunaga")
LABELS = {"selfcal": "selfcal", "colour": "colour-hdri Debevec",
          "debevec": "OpenCV Debevec", "robertson": "OpenCV Robertson",
          "mitsunaga": "Mitsunaga-Nayar 1999"}
INNER = slice(1, 255)
DORF = SHARED_DATA / "dorf_emor" / "201_CRF_data.mat"
NUS = SHARED_DATA / "nus_model_nikon_d7000"
RAWS = ("colorchart_canon550d.dng", "blackmagic_cinema.dng")
D7000_WB = 14
SEED_STRIDE = 50
_DORF_CACHE = {}


def _init_worker():
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    warnings.filterwarnings("ignore")


#: The times selfcal is given (``--selfcal-times``): all, the first only, or none; the peers
#: always get all.
SELFCAL_TIMES = "all"


#: selfcal's options (``--no-ringing``, ``--basis-mean-prior``, ``--correspondences``,
#: ``--near-clip-blocks`` change them).
SELFCAL_OPTIONS = ResponseOptions()


def _selfcal_times(times) -> list:
    times = list(times)
    if SELFCAL_TIMES == "one":
        return times[:1] + [None] * (len(times) - 1)
    return [None] * len(times) if SELFCAL_TIMES == "none" else times


def calibrate_all(images, times, methods=METHODS) -> dict:
    """method -> (f⁻¹ table (256, 3) or None when the method failed, seconds)."""
    import selfcal

    calls = {
        "selfcal": lambda: selfcal.calibrate_response(
            images, _selfcal_times(times), options=SELFCAL_OPTIONS).inverse_response(),
        "colour": lambda: colour_hdri_inverse_response(images, times),
        "debevec": lambda: opencv_inverse_response(images, times, "debevec"),
        "robertson": lambda: opencv_inverse_response(images, times, "robertson"),
        "mitsunaga": lambda: mitsunaga_nayar_inverse_response(images, times),
    }
    out = {}
    for method in methods:
        call = calls[method]
        t0 = time.perf_counter()
        try:
            lut = np.asarray(call(), dtype=np.float64)
            if lut.shape != (256, 3) or not np.all(np.isfinite(lut)):
                lut = None
        except Exception:       # a peer (or selfcal) failing on a stack scores +inf
            lut = None
        out[method] = (lut, time.perf_counter() - t0)
    return out


def score(luts: dict, truth: np.ndarray) -> dict:
    """Per method: best-scale RMSE per channel, seconds, monotone channels; selfcal: absolute."""
    res = {m: {"best": [math.nan] * 3, "seconds": math.nan, "monotone": [True] * 3,
               "abs": [math.nan] * 3} for m in METHODS if m not in luts}   # not run
    for method, (lut, seconds) in luts.items():
        if lut is None:
            res[method] = {"best": [math.inf] * 3, "seconds": seconds, "monotone": [False] * 3}
            if method == "selfcal":
                res[method]["abs"] = [math.inf] * 3
                res[method]["abs250"] = [math.inf] * 3
            continue
        res[method] = {
            "best": [best_scale_rmse(lut[INNER, c], truth[INNER, c]) for c in range(3)],
            "seconds": seconds,
            "monotone": [bool(np.all(np.diff(lut[:, c]) >= 0)) for c in range(3)]}
        if method == "selfcal":
            res[method]["abs"] = [rmse(lut[INNER, c], truth[INNER, c]) for c in range(3)]
            # absolute scale judged on codes 1 … 250, both normalised at f⁻¹(250)
            res[method]["abs250"] = [
                rmse(lut[1:251, c] / max(lut[250, c], 1e-12), truth[1:251, c] / truth[250, c])
                for c in range(3)]
    return res


def one_cell_stack(task):
    _, cell, index, seed, size, methods = task
    t0 = time.perf_counter()
    own = getattr(CONDITIONS[cell], "size", None)     # the exact cells' own size
    stack = CONDITIONS[cell].simulate(dorf_curve(index), seed, size=own or size)
    simulate_seconds = time.perf_counter() - t0
    res = score(calibrate_all(stack.images, TIMES, methods), stack.inverse_response())
    return {"kind": "cell", "cell": cell, "index": index, "seed": seed,
            "quality": stack.params["jpeg_quality"], "simulate": simulate_seconds,
            "methods": res}


def d7000_scene(fname: str, cam, max_side: int = 384):
    """A raw of ../shared/data/raw as the D7000 model's input: (camera RGB, render)."""
    from selfcal.io.raw import read_raw_linear

    raw = read_raw_linear(SHARED_DATA / "raw" / fname, half_size=True)
    rgb = raw.rgb.astype(np.float64)
    f = max(1, math.ceil(max(rgb.shape[:2]) / max_side))
    h, w = rgb.shape[0] // f, rgb.shape[1] // f
    rgb = rgb[:h * f, :w * f].reshape(h, f, w, f, 3).mean(axis=(1, 3))
    wb = np.asarray(raw.camera_wb if raw.camera_wb is not None else (1, 1, 1), np.float64)

    def render(x):
        return cam.render(np.clip(np.asarray(x, np.float64) * wb, 0.0, 1.0) / cam.gains)

    return rgb, render


def one_d7000_stack(task):
    _, fname, seed, methods = task
    from selfcal import sim
    from selfcal.pipeline.nus import read_nus_model
    from selfcal.sim.conditions import ModelCamera

    t0 = time.perf_counter()
    cam = read_nus_model(NUS, wb_code=D7000_WB)
    rgb, render = d7000_scene(fname, cam)
    model = ModelCamera(render, cam.inverse_response, name=f"NUS D7000 on {fname}")
    stack = sim.simulate_stack(rgb, model, TIMES, jitter=0.02, jpeg_quality=92, seed=seed,
                                 exposure_scale=1.0 / math.sqrt(TIMES[0] * TIMES[-1]))
    simulate_seconds = time.perf_counter() - t0
    res = score(calibrate_all(stack.images, TIMES, methods), stack.inverse_response())
    return {"kind": "d7000", "raw": fname, "seed": seed, "size": rgb.shape[:2],
            "simulate": simulate_seconds, "methods": res}


def run_task(task):
    return one_cell_stack(task) if task[0] == "cell" else one_d7000_stack(task)


def split_tasks(split: str, n_curves: int, cells, size, d7000: bool, methods) -> list:
    """The split's stacks: (kind, cell, curve index, seed, size, methods) and the D7000
    ones (kind, raw, seed, methods)."""
    tuning = split == "tuning"
    curves = list(range(0 if tuning else 1, 201, 2))
    base = 0 if tuning else 1000
    names = list(CONDITIONS)
    tasks = []
    if d7000 and NUS.is_dir() and all((SHARED_DATA / "raw" / f).exists() for f in RAWS):
        tasks += [("d7000", f, base + 7, methods) for f in RAWS]      # longest first
    for k, name in enumerate(names):
        if name not in cells:
            continue
        for j in range(n_curves):
            # the stride is the natural cells' count, so adding the exact cells left the
            # natural cells' curves and seeds as they were
            tasks.append(("cell", name, curves[(j * len(_NATURAL) + k) % len(curves)],
                          base + SEED_STRIDE * k + j, size, methods))
    return tasks


# --------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------

def _values(results, method, key="best"):
    return np.array([v for r in results for v in r["methods"][method][key]], dtype=float)


def _fmt(v):
    return "n/a" if np.isnan(v) else "inf" if not np.isfinite(v) else f"{v:.4f}"


def _ratio(v):
    return "n/a" if np.isnan(v) else f"{v:.2f}"


def cell_table(results, cells):
    rows, stats = [], {}
    for cell in cells:
        rs = [r for r in results if r.get("cell") == cell]
        if not rs:
            continue
        s = {m: (np.median(_values(rs, m)), np.percentile(_values(rs, m), 90)) for m in METHODS}
        s["abs"] = np.median(_values(rs, "selfcal", "abs"))
        best_cv = np.nanmin([s["debevec"][0], s["robertson"][0], np.inf])
        best_cv = np.nan if np.isinf(best_cv) else best_cv
        s["vs_colour"] = s["selfcal"][0] / s["colour"][0]
        s["vs_opencv"] = s["selfcal"][0] / best_cv
        stats[cell] = s
        rows.append([cell, len(rs)] + [_fmt(s["selfcal"][0]), _fmt(s["selfcal"][1]),
                                       _fmt(s["abs"])]
                    + [x for m in METHODS[1:] for x in (_fmt(s[m][0]), _fmt(s[m][1]))]
                    + [_ratio(s["vs_colour"]), _ratio(s["vs_opencv"])])
    headers = (["cell", "stacks", "selfcal median", "p90", "abs median"]
               + [x for m in METHODS[1:] for x in (f"{LABELS[m]} median", "p90")]
               + ["selfcal / colour-hdri", "selfcal / best OpenCV"])
    return table(headers, rows), stats


def acceptance_lines(stats) -> list:
    def line(text, ok_by_cell, worst):
        if any(v is None for v in ok_by_cell.values()):
            return f"- {text}: not measured (a method was left out)"
        ok = sum(ok_by_cell.values())
        mark = "met" if ok == len(ok_by_cell) else "NOT met"
        return f"- {text}: {mark} ({ok}/{len(ok_by_cell)} cells; worst {worst})"

    def worst(key, idx=None):
        cell = max(stats, key=lambda c: stats[c][key] if idx is None else stats[c][key][idx])
        v = stats[cell][key] if idx is None else stats[cell][key][idx]
        return f"{cell} {v:.4f}" if key in ("selfcal", "abs") else f"{cell} {v:.2f}"

    return [
        line("selfcal median best-scale RMSE ≤ 0.005 in every cell",
             {c: s["selfcal"][0] <= 0.005 for c, s in stats.items()}, worst("selfcal", 0)),
        line("selfcal p90 ≤ 0.010 in every cell",
             {c: s["selfcal"][1] <= 0.010 for c, s in stats.items()}, worst("selfcal", 1)),
        line("selfcal median ≤ 0.7× colour-hdri's Debevec in every cell (aim ≤ 0.5×)",
             {c: None if np.isnan(s["vs_colour"]) else s["vs_colour"] <= 0.7
              for c, s in stats.items()}, worst("vs_colour")),
        line("selfcal median ≤ 1/4 of OpenCV's better method in every cell",
             {c: None if np.isnan(s["vs_opencv"]) else s["vs_opencv"] <= 0.25
              for c, s in stats.items()}, worst("vs_opencv")),
        line("selfcal absolute (f⁻¹(255) = 1) median ≤ 0.008 in every cell",
             {c: s["abs"] <= 0.008 for c, s in stats.items()}, worst("abs")),
    ]


def d7000_report(results) -> list:
    rs = [r for r in results if r["kind"] == "d7000"]
    if not rs:
        return []

    def pooled(r, m, key="best"):
        v = np.array(r["methods"][m][key])
        return float(np.sqrt(np.mean(v * v)))

    rows, ok = [], True
    for r in rs:
        best, absolute = pooled(r, "selfcal"), pooled(r, "selfcal", "abs")
        abs250 = pooled(r, "selfcal", "abs250")
        ok &= best <= 0.008 and abs250 <= 0.012
        rows.append([r["raw"], f"{r['size'][0]}x{r['size'][1]}", _fmt(best), _fmt(absolute),
                     _fmt(abs250)] + [_fmt(pooled(r, m)) for m in METHODS[1:]])
    out = ["", "D7000 in-camera model on the shared raws (6 shots 1/250 … 1/8 s, ±2 % jitter, "
           "noise, JPEG q92 4:2:0); RMSE over the three channels' codes 1 … 254", "",
           table(["raw", "frame", "selfcal best-scale", "selfcal absolute",
                  "selfcal absolute 1…250 at f⁻¹(250)"]
                 + [LABELS[m] for m in METHODS[1:]], rows), "",
           f"- D7000: best-scale ≤ 0.008 and absolute (codes 1 … 250, normalised at "
           f"f⁻¹(250)) ≤ 0.012 on each raw: "
           f"{'met' if ok else 'NOT met'}"]
    return out


def report(results, split, args, wall, cpu) -> str:
    cells = [c for c in CONDITIONS if c in args.cells]
    cell_results = [r for r in results if r["kind"] == "cell"]
    title = ("held-out split (odd DoRF curves, seeds ≥ 1000)" if split == "heldout"
             else "tuning split (even DoRF curves, seeds < 1000)")
    lines = [f"### {title}", ""]
    if SELFCAL_TIMES != "all":
        lines += [f"selfcal given {SELFCAL_TIMES} of the exposure times"
                  + (", prior at the basis mean" if args.basis_mean_prior else ""), ""]
    if cell_results:
        tab, stats = cell_table(cell_results, cells)
        own = sorted({"x".join(map(str, CONDITIONS[c].size)) for c in cells
                      if getattr(CONDITIONS[c], "size", None)})
        sizes = args.size + (f" (the exact cells at their own {', '.join(own)})" if own else "")
        lines += [f"{len(cell_results)} stacks {sizes}, {args.curves} per cell; "
                  "RMSE of f⁻¹ over codes 1 … 254 after the best scale per channel, "
                  "median and p90 over (stack, channel); ratios of the medians", "", tab,
                  "", "Acceptance (synthetic matrix):"] + acceptance_lines(stats)
        n = len(cell_results) * 3
        mono = ", ".join(f"{LABELS[m]} {n - int(_values(cell_results, m, 'monotone').sum())}"
                         for m in METHODS if m in args.methods)
        secs = ", ".join(
            f"{LABELS[m]} {np.median([r['methods'][m]['seconds'] for r in cell_results]):.2f} s"
            for m in METHODS if m in args.methods)
        sim = np.median([r["simulate"] for r in cell_results])
        lines += ["", f"Non-monotone channels (of {n}): {mono}",
                  f"Time per stack (median): {secs}; simulating a stack {sim:.2f} s"]
    lines += d7000_report(results)
    lines += ["", f"wall {wall:.0f} s with {args.jobs} jobs; CPU {cpu:.0f} s (workers' user + "
              "system)"]
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("heldout", "tuning"), default="heldout")
    parser.add_argument("--curves", type=int, default=6,
                        help="stacks (DoRF curves) per cell (default %(default)s, ≤ 50)")
    parser.add_argument("--cells", default="",
                        help="comma-separated cell names or scene prefixes (default: all)")
    parser.add_argument("--size", default="256x384", help="frame HxW (default %(default)s)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--no-d7000", action="store_true", help="leave out the D7000 rows")
    parser.add_argument("--methods", default=",".join(METHODS),
                        help="comma-separated subset of %(default)s (quick looks; the "
                             "acceptance lines need all four)")
    parser.add_argument("--no-ringing", action="store_true",
                        help="selfcal without the measured ringing reach "
                             "(ResponseOptions(measure_ringing=False)), for the comparison")
    parser.add_argument("--selfcal-times", choices=("all", "one", "none"), default="all",
                        help="the exposure times selfcal is given (the peers get all)")
    parser.add_argument("--basis-mean-prior", action="store_true",
                        help="with fewer than two known times, centre selfcal's prior at "
                             "the basis mean as before issue 25 "
                             "(SolverOptions(centre_ambiguity=False)), for the comparison")
    parser.add_argument("--correspondences", choices=("blocks", "histogram"),
                        help="selfcal's correspondences "
                             "(ResponseOptions.correspondences); default the library's")
    parser.add_argument("--near-clip-blocks", type=int, metavar="R",
                        help="blocks within R blocks of a clipped one count as clipped "
                             "(ResponseOptions.near_clip_blocks); default the library's")
    parser.add_argument("--no-hidden-white", action="store_true",
                        help="selfcal without counting the samples its first fit predicts "
                             "at white as clipped (ResponseOptions(hidden_white=False)), "
                             "for the comparison")
    args = parser.parse_args()
    start("response_matrix", args.split)
    global SELFCAL_TIMES
    SELFCAL_TIMES = args.selfcal_times
    global SELFCAL_OPTIONS          # set before the workers fork
    if args.no_ringing:
        SELFCAL_OPTIONS = replace(SELFCAL_OPTIONS, measure_ringing=False)
    if args.no_hidden_white:
        SELFCAL_OPTIONS = replace(SELFCAL_OPTIONS, hidden_white=False)
    if args.basis_mean_prior:
        SELFCAL_OPTIONS = SELFCAL_OPTIONS.with_solver(centre_ambiguity=False)
    if args.correspondences:
        SELFCAL_OPTIONS = replace(SELFCAL_OPTIONS, correspondences=args.correspondences)
    if args.near_clip_blocks is not None:
        SELFCAL_OPTIONS = replace(SELFCAL_OPTIONS, near_clip_blocks=args.near_clip_blocks)
    args.methods = tuple(m for m in METHODS if m in args.methods.split(","))
    if "selfcal" not in args.methods:
        parser.error("--methods must include selfcal")
    if not 1 <= args.curves <= SEED_STRIDE:
        parser.error(f"--curves must be in 1 … {SEED_STRIDE}")
    wanted = [w.strip() for w in args.cells.split(",") if w.strip()]
    args.cells = [c for c in CONDITIONS
                  if not wanted or any(c == w or c.startswith(w + "/") for w in wanted)]
    if not args.cells:
        parser.error(f"no cell matches --cells; cells: {', '.join(CONDITIONS)}")
    if not DORF.exists():
        sys.exit(f"benchmark data not found: {DORF} (the benchmarks read ../shared/data)")
    if not args.no_d7000 and not (NUS.is_dir() and all((SHARED_DATA / "raw" / f).exists()
                                                       for f in RAWS)):
        print(f"D7000 rows skipped: {NUS} or the raws in {SHARED_DATA / 'raw'} are absent")
    h, w = (int(v) for v in args.size.lower().split("x"))
    tasks = split_tasks(args.split, args.curves, set(args.cells), (h, w), not args.no_d7000,
                        args.methods)
    t0 = time.perf_counter()
    pool = Pool(args.jobs, initializer=_init_worker)
    results = list(pool.imap_unordered(run_task, tasks))
    pool.close()
    pool.join()
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(report(results, args.split, args, time.perf_counter() - t0,
                 usage.ru_utime + usage.ru_stime))


if __name__ == "__main__":
    main()
    finish()
