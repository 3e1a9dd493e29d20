"""How sure: the calibration of the curve bands and of the radiance σ.

Four parts, each printed as a table (``--parts bands,sim,real,cost``; default the first
three; ``cost``: what the band adds to a calibration and ``sigma=True`` to a merge, best of
three runs, see :func:`cost_report`):

**bands** -- the condition matrix of ``bench.response_matrix``
(``selfcal.sim.conditions.CONDITIONS``, the same cells, curves and seeds: held-out =
odd DoRF curves, seeds ≥ 1000; tuning = even curves, seeds < 1000), every cell shot with
its six frames 1/250 … 1/8 s and again with twelve frames over the same span (geometric
steps, ``dataclasses.replace(cell, exposure_times=...)``), calibrated by
``calibrate_response`` (defaults: the band of ``selfcal.response.bands``).  Per stack:
*coverage*, the share of (code, channel) for codes 1 … 254 where the true f⁻¹ lies inside
``model.band_at_codes(level=0.9)``; *width*, the median relative half-width
``(upper − lower) / (2 f⁻¹)`` over codes 26 … 229 (the body) and channels.  With
``--compare``, the same with ``bands.DEFAULT_BAND_METHOD = "bootstrap"`` (the location
bootstrap) beside the default covariance: the measurement the default was chosen on
(tuning split).

**sim** -- the hard synthetic stacks of ``bench.hdr_synthetic`` (one DoRF curve per
stack, saturated 14-stop scene, six frames, ±3 % jitter, JPEG 85/90/95; held-out: odd
curves, seed 1000 + i; tuning: even curves, seed i; ``--step`` as there), calibrated and
merged by selfcal with ``MergeOptions(sigma=True)``; κ is the noise scale the merge
measured on the stack (``selfcal.hdr.sigma``).  Per stack, over the scored channels
of ``truth_masks`` that the merge measured: the median of ``|E − E_true| / σ`` (0.674
for a perfect Gaussian σ), absolute (no rescaling: the merge's units are the truth's,
f⁻¹(255) = 1), there with ``σ_abs = √(σ² + (E·s_σ)²)``, ``s_σ`` the radiance scale's own σ
in log (``diagnostics["sigma_scale_log"]``: σ is relative to the scale), and after the
bench's global scale with σ; and the median relative σ and error.

**real** -- the real stacks of ``bench.hdr_oddeven`` (frames in exposure order, one
selfcal model from all frames, the odd and the even frames merged separately with
``sigma=True``).  Over the pixels both halves measure (``measured`` of that bench) and
neither merge flags: ``z = (E_odd·e^{−s} − E_even) / √(σ_odd² e^{−2s} + σ_even²)`` per
channel, ``s`` the median log ratio.  Column "|z| noise": σ without the curve term (the
model's band removed: one model serves both halves, so its error is the same in both and
cancels in the difference) -- the σ this test can check; "|z| full": with it; the
"before" columns (``--before-26``): the same without the curve's code-error term (issue
26, Build 4: ``MergeOptions(code_error=False, merge_unchecked=False)``, the merge and σ of
b8a2705 but for κ, whose neighbour pairs now leave σ_t out).  Tuning =
memorial and the first scene of each camera (as ``bench.hdr_oddeven``); the rest are
held out.

    python3 -m bench.uncertainty [--split heldout|tuning] [--parts bands,sim,real,cost]
        [--curves 1] [--step 20] [--size 192x288] [--reduce 1] [--compare] [--jobs 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from multiprocessing import Pool

import numpy as np

from .tables import best_of, finish, start, table
from .data import data_dir

BODY = slice(26, 230)
INNER = slice(1, 255)


def _init_worker():
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    warnings.filterwarnings("ignore")


# --------------------------------------------------------------------------------------
# bands on the condition matrix
# --------------------------------------------------------------------------------------

def band_task(task):
    cell, index, seed, size, frames, method = task
    import selfcal
    from .data import dorf_curve
    from selfcal.sim.conditions import CONDITIONS

    cond = CONDITIONS[cell]
    if frames != len(cond.exposure_times):
        t = np.geomspace(min(cond.exposure_times), max(cond.exposure_times), frames)
        cond = dataclasses.replace(cond, exposure_times=tuple(float(x) for x in t))
    stack = cond.simulate(dorf_curve(index), seed, size=size)
    t0 = time.perf_counter()
    model = selfcal.calibrate_response(stack.images, list(cond.exposure_times),
                                       options=selfcal.ResponseOptions(band_method=method))
    seconds = time.perf_counter() - t0
    truth = stack.inverse_response()
    lower, upper = model.band_at_codes(np.arange(256), 0.9)
    inside = (truth[INNER] >= lower[INNER]) & (truth[INNER] <= upper[INNER])
    est = model.inverse_response()
    width = float(np.median((upper - lower)[BODY] / (2 * est[BODY])))
    wide = model.diagnostics["verdict_evidence"].get("band_width_90", {})
    return {"cell": cell, "frames": frames, "method": method, "coverage": float(inside.mean()),
            "width": width, "widest": wide.get("width", np.nan), "seconds": seconds,
            "verdict": model.diagnostics["verdict"]}


def band_tasks(split, curves, size, methods):
    from .response_matrix import SEED_STRIDE
    from selfcal.sim.conditions import CONDITIONS

    names = list(CONDITIONS)
    pool = list(range(0 if split == "tuning" else 1, 201, 2))
    base = 0 if split == "tuning" else 1000
    tasks = []
    for k, name in enumerate(names):
        for j in range(curves):
            index = pool[(j * len(names) + k) % len(pool)]
            for frames in (6, 12):
                for method in methods:
                    tasks.append((name, index, base + SEED_STRIDE * k + j, size, frames,
                                  method))
    return tasks


def band_report(results, methods) -> list:
    rows = []
    for method in methods:
        for frames in (6, 12):
            rs = [r for r in results if r["method"] == method and r["frames"] == frames]
            if not rs:
                continue
            cov = np.array([r["coverage"] for r in rs])
            wid = np.array([r["width"] for r in rs])
            rows.append([method, frames, len(rs), f"{np.median(cov):.3f}",
                         f"{np.percentile(cov, 10):.3f}", f"{np.percentile(cov, 90):.3f}",
                         f"{np.median(wid):.4f}",
                         f"{np.median([r['widest'] for r in rs]):.3f}",
                         f"{max(r['widest'] for r in rs):.3f}",
                         f"{np.median([r['seconds'] for r in rs]):.2f}",
                         sum(r["verdict"] != "ok" for r in rs)])
    out = [table(["band", "frames", "stacks", "coverage median", "p10", "p90",
                  "half-width median", "widest (body) median", "widest max",
                  "calibration s", "not ok"], rows), ""]
    for method in methods:
        w6 = np.median([r["width"] for r in results if r["method"] == method
                        and r["frames"] == 6])
        w12 = np.median([r["width"] for r in results if r["method"] == method
                         and r["frames"] == 12])
        cov = np.median([r["coverage"] for r in results if r["method"] == method])
        out.append(f"- {method}: coverage median {cov:.3f} (target 0.80-0.95: "
                   f"{'met' if 0.8 <= cov <= 0.95 else 'NOT met'}); width 6 -> 12 frames "
                   f"{w6:.4f} -> {w12:.4f} ({'falls' if w12 < w6 else 'does NOT fall'})")
    per_cell = {}
    for r in results:
        if r["method"] == methods[0] and r["frames"] == 6:
            per_cell.setdefault(r["cell"], []).append(r["coverage"])
    out += ["", "coverage per cell (6 frames, " + methods[0] + "): " + ", ".join(
        f"{c} {np.median(v):.2f}" for c, v in per_cell.items())]
    return out


# --------------------------------------------------------------------------------------
# σ on the synthetic HDR stacks
# --------------------------------------------------------------------------------------

def sim_task(task):
    index, seed, size = task
    import scipy.io as sio

    import selfcal
    from selfcal.sim.scoring import truth_masks

    from .hdr_synthetic import QUALITIES, SATURATION, TIMES
    from selfcal import sim
    from selfcal.hdr import MergeOptions

    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    curve = sim.ToneCurve.from_table(mat["I"][index], mat["B"][index], name=f"dorf{index}")
    h, w = size
    pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=seed)
    scene = sim.make_scene(h, w, dynamic_range_stops=14.0, saturation=SATURATION, seed=seed)
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=0.03,
                               jpeg_quality=QUALITIES[seed % len(QUALITIES)], seed=seed)
    e_true, scored, *_ = truth_masks(stack)
    model = selfcal.calibrate_response(stack.images, TIMES)
    plain = selfcal.merge_hdr(stack.images, TIMES, model)
    r = selfcal.merge_hdr(stack.images, TIMES, model, options=MergeOptions(sigma=True))
    keep = scored & ~r.unmeasured[..., None]
    E, S, T = (np.asarray(a, np.float64)[keep] for a in (r.radiance, r.sigma, e_true))
    lr = np.log(T / E)
    s = float(np.exp(np.median(lr[np.abs(lr - np.median(lr)) <= np.log(2)])))
    # σ is relative to the radiance's scale; in absolute units the scale's σ joins it
    scale = r.diagnostics.get("sigma_scale_log", 0.0)
    absolute = np.sqrt(S ** 2 + (E * scale) ** 2)
    return {"index": index, "abs": float(np.median(np.abs(E - T) / absolute)),
            "scaled": float(np.median(np.abs(s * E - T) / (s * S))),
            "rel_sigma": float(np.median(S / E)), "rel_err": float(np.median(np.abs(E - T) / T)),
            "kappa": r.diagnostics["sigma_noise_scale"],
            "same": bool(np.array_equal(plain.radiance, r.radiance))}


def sim_report(results) -> list:
    rows = [[r["index"], f"{r['abs']:.3f}", f"{r['scaled']:.3f}", f"{r['rel_sigma']:.4f}",
             f"{r['rel_err']:.4f}", f"{r['kappa']:.2f}"] for r in results]
    med = np.median([r["abs"] for r in results])
    scaled = np.median([r["scaled"] for r in results])
    return [table(["DoRF curve", "median |E − E_true|/σ_abs", "after global scale (σ)",
                   "median σ/E", "median |E − E_true|/E_true", "κ"], rows),
            "", f"- median over stacks of median |E − E_true|/σ_abs: {med:.3f} (target 0.6-0.8: "
            f"{'met' if 0.6 <= med <= 0.8 else 'NOT met'}); after one global scale, "
            f"|s·E − E_true|/(s·σ): {scaled:.3f} "
            f"({'met' if 0.6 <= scaled <= 0.8 else 'NOT met'}); radiance unchanged by σ: "
            f"{all(r['same'] for r in results)}"]


# --------------------------------------------------------------------------------------
# σ on real odd/even halves
# --------------------------------------------------------------------------------------

#: --exposure-variants: the full σ with the times held as they are (``MergeOptions(
#: exposures=ExposureRule(times="held"))``, the default before issue 35) and with the
#: measured exposures but the fixed σ_t = 0.02 (``sigma_exposure_from_fit=False``).  The
#: values are MergeOptions fields; ``"exposures"`` holds the fields of its
#: :class:`selfcal.ExposureRule`.
MEASURED = (("full, times as given", {"exposures": {"times": "held"}}),
            ("full, σ_t 0.02", {"sigma_exposure_from_fit": False}))


def real_task(task):
    name, paths, times, reduce, with_measured, before = task
    from dataclasses import replace

    import selfcal
    from .data import sorted_frames
    from .metrics import measured
    from selfcal.hdr import MergeOptions

    frames, paths, times = sorted_frames(name, paths, times, reduce)
    n = len(frames)
    halves = (tuple(range(1, n, 2)), tuple(range(0, n, 2)))
    mask = measured([frames[k] for k in halves[0]]) & measured([frames[k] for k in halves[1]])
    model = selfcal.calibrate_response(frames, times)
    bare = replace(model, inverse_log_sigma=None)
    out = {"name": name, "size": f"{frames[0].shape[1]}×{frames[0].shape[0]}"}
    labels = (("noise before", bare), ("full before", model)) if before else ()
    for label, m in labels + (("noise", bare), ("full", model)):
        # "before" (--before-26): the merge and σ without the code-error term and the
        # unchecked frames (MergeOptions.code_error, .merge_unchecked)
        options = MergeOptions(sigma=True)
        if "before" in label:
            options = replace(options, code_error=False, merge_unchecked=False)
        res = [selfcal.merge_hdr([frames[k] for k in h], [times[k] for k in h], m,
                                 options=options) for h in halves]
        keep = mask & ~res[0].unmeasured & ~res[1].unmeasured
        a, b = (np.asarray(r.radiance, np.float64)[keep] for r in res)
        sa, sb = (np.asarray(r.sigma, np.float64)[keep] for r in res)
        ok = (a > 0) & (b > 0) & np.isfinite(sa) & np.isfinite(sb)
        s = float(np.median(np.log(a[ok] / b[ok])))
        g = np.exp(-s)
        z = (a[ok] * g - b[ok]) / np.sqrt((sa[ok] * g) ** 2 + sb[ok] ** 2)
        out[label] = float(np.median(np.abs(z)))
        if "before" not in label:
            out["kappa"] = [r.diagnostics["sigma_noise_scale"] for r in res]
            out["pixels"] = float(keep.mean())
        if label == "full":     # the default measures the exposures: its σ_t
            out["σ_t fit"] = [float("nan") if r.exposure_record.spread is None
                              else r.exposure_record.spread.log_sigma for r in res]
    for label, fields in (MEASURED if with_measured else ()):
        if "exposures" in fields:
            fields = {**fields, "exposures": selfcal.ExposureRule(**fields["exposures"])}
        res = [selfcal.merge_hdr([frames[k] for k in h], [times[k] for k in h], model,
                                 options=MergeOptions(sigma=True, **fields))
               for h in halves]
        out[label] = _median_abs_z(res, mask)
    return out


def _median_abs_z(res, mask) -> float:
    """Median |z| of two halves' merges over the pixels measured in both (as above)."""
    keep = mask & ~res[0].unmeasured & ~res[1].unmeasured
    a, b = (np.asarray(r.radiance, np.float64)[keep] for r in res)
    sa, sb = (np.asarray(r.sigma, np.float64)[keep] for r in res)
    ok = (a > 0) & (b > 0) & np.isfinite(sa) & np.isfinite(sb)
    g = np.exp(-float(np.median(np.log(a[ok] / b[ok]))))
    return float(np.median(np.abs((a[ok] * g - b[ok]) / np.sqrt((sa[ok] * g) ** 2
                                                                 + sb[ok] ** 2))))


def real_report(results, tuning) -> list:
    before = "noise before" in results[0]
    head = (["stack", "split", "size", "scored pixels"]
            + (["median |z| noise before", "median |z| full before"] if before else [])
            + ["median |z| noise", "median |z| full", "κ odd / even"])
    extra = [m[0] for m in MEASURED if m[0] in results[0]]
    if extra:
        head += [f"median |z| {m}" for m in extra] + ["σ_t fit odd / even"]
    rows = [[r["name"], "tuning" if r["name"] in tuning else "held out", r["size"],
             f"{100 * r['pixels']:.0f} %"]
            + ([f"{r['noise before']:.3f}", f"{r['full before']:.3f}"] if before else [])
            + [f"{r['noise']:.3f}", f"{r['full']:.3f}",
             " / ".join(f"{k:.2f}" for k in r["kappa"])]
            + [f"{r[m]:.3f}" for m in extra]
            + ([" / ".join(f"{v:.4f}" for v in r["σ_t fit"])] if extra else [])
            for r in results]
    out = [table(head, rows), ""]
    for label in ("noise", "full", *extra):
        vals = [r[label] for r in results]
        inside = sum(0.55 <= v <= 0.85 for v in vals)
        out.append(f"- median |z| ({label} σ) in 0.55-0.85: {inside} of {len(vals)} stacks "
                   f"({', '.join(f'{v:.2f}' for v in vals)})")
    return out


# --------------------------------------------------------------------------------------
# what the band and the σ cost
# --------------------------------------------------------------------------------------

def cost_report(repeats: int = 3) -> list:
    """Best-of-``repeats`` seconds: a calibration of ``sim.demo_stack()`` with its band and
    with the band replaced by zeros; a merge of a 6-frame 1536×2304 synthetic stack (arrays,
    model given) without and with ``sigma=True``; the σ's share of the merge's peak memory
    is two float32 HxWx3 sums (said, not measured)."""
    import selfcal
    from selfcal import sim
    from selfcal.hdr import MergeOptions
    from selfcal.response import bands

    def best(call):
        return best_of(call, repeats)

    demo = sim.demo_stack(0)
    times = list(demo.exposure_times)
    with_band = best(lambda: selfcal.calibrate_response(demo.images, times))
    real = bands.curve_band
    bands.curve_band = lambda *a, **k: np.zeros((a[2].intensity.size, 3))
    try:
        without = best(lambda: selfcal.calibrate_response(demo.images, times))
    finally:
        bands.curve_band = real
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=1)
    scene = sim.make_scene(1536, 2304, saturation=0.5, seed=1)
    big = sim.simulate_stack(scene, pipe, times, jitter=0.03, jpeg_quality=90, seed=1)
    model = selfcal.calibrate_response(big.images, times)
    plain = best(lambda: selfcal.merge_hdr(big.images, times, model))
    sig = best(lambda: selfcal.merge_hdr(big.images, times, model,
                                         options=MergeOptions(sigma=True)))
    return [table(["what", "without", "with", "cost"], [
        ["calibrate_response, demo stack 256×384 × 6, band (covariance)",
         f"{without:.3f} s", f"{with_band:.3f} s", f"{100 * (with_band / without - 1):+.0f} %"],
        ["merge_hdr, 1536×2304 × 6 arrays, sigma=True",
         f"{plain:.3f} s", f"{sig:.3f} s", f"{100 * (sig / plain - 1):+.0f} %"]])]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("heldout", "tuning"), default="heldout")
    parser.add_argument("--parts", default="bands,sim,real")
    parser.add_argument("--curves", type=int, default=1, help="stacks per cell (bands)")
    parser.add_argument("--step", type=int, default=20, help="DoRF curve step (sim)")
    parser.add_argument("--size", default="192x288")
    parser.add_argument("--reduce", type=int, default=1, help="real JPEGs decoded at 1/N")
    parser.add_argument("--compare", action="store_true",
                        help="bands: the location bootstrap beside the covariance")
    parser.add_argument("--only", action="append", help="real: only these stacks")
    parser.add_argument("--exposure-variants", action="store_true",
                        help="real: add the merges with the times as given, and with the "
                        "fixed exposure term σ_t = 0.02")
    parser.add_argument("--before-26", action="store_true",
                        help="real: add the merges without the code-error term and the "
                        "unchecked frames (MergeOptions(code_error=False, "
                        "merge_unchecked=False), the default before issue 26)")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    start("uncertainty", args.split)
    size = tuple(int(v) for v in args.size.split("x"))
    parts = args.parts.split(",")
    heldout = args.split == "heldout"
    split = ("held-out split (odd DoRF curves, seeds ≥ 1000; real: all but the tuning stacks)"
             if heldout else "tuning split (even DoRF curves, seeds < 1000; real: the "
             "tuning stacks)")
    print(f"# {split}\n")
    t0 = time.perf_counter()
    with Pool(args.jobs, initializer=_init_worker) as pool:
        if "bands" in parts:
            methods = ("covariance", "bootstrap") if args.compare else ("covariance",)
            tasks = band_tasks(args.split, args.curves, size, methods)
            tasks.sort(key=lambda t: -t[4])              # 12 frames first
            results = pool.map(band_task, tasks, chunksize=1)
            print(f"## Curve bands: {len(tasks)} calibrations {args.size}, 90 % band\n")
            print("\n".join(band_report(results, methods)) + "\n")
        if "sim" in parts:
            first = 1 if heldout else 0
            step = max(2, args.step - args.step % 2)
            tasks = [(i, (1000 + i) if heldout else i, size) for i in range(first, 201, step)]
            results = pool.map(sim_task, tasks, chunksize=1)
            print(f"## Radiance σ on synthetic stacks ({len(tasks)} stacks {args.size})\n")
            print("\n".join(sim_report(results)) + "\n")
        if "real" in parts:
            from .data import TUNING_STACKS as TUNING, stack_list

            stacks = stack_list()
            names = [n for n in stacks if (n in TUNING) != heldout]
            if args.only:
                names = [n for n in names if n in args.only]
            tasks = [(n, *stacks[n], args.reduce, args.exposure_variants, args.before_26)
                     for n in names]
            results = pool.map(real_task, tasks, chunksize=1)
            print(f"## Radiance σ on real odd/even halves (JPEGs decoded at 1/{args.reduce}; "
                  "ntu at 1/4 at least)\n")
            print("\n".join(real_report(results, TUNING)) + "\n")
    if "cost" in parts:
        _init_worker()
        print("## What the band and the σ cost (best of 3, one process, one thread)\n")
        print("\n".join(cost_report()) + "\n")
    print(f"wall {time.perf_counter() - t0:.0f} s with {args.jobs} jobs")


if __name__ == "__main__":
    main()
    finish()
