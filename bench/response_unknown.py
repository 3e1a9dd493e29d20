"""Issues 3 and 25: how well the exponential ambiguity is resolved when exposure times are missing.

With fewer than two known exposure times, Eq. 8 of Lin et al. (ICCV 2011, §5) fixes the
response only up to an exponent γ (f⁻¹ → (f⁻¹)^γ with every exposure ratio raised to γ);
selfcal resolves it with the prior of its response basis and warns.  This script measures
what that prior gives: stacks rendered by ``selfcal.sim`` (6 shots 1/250 … 1/8 s, ±3 %
jitter, noise, smooth gamut map, JPEG q90) for common encodings (sRGB, Rec.709, gamma 1.8
and 2.2, a film curve; two scenes each) and for every ``--step``-th DoRF curve of the
split, calibrated with all, two (first and last), one (first) and no times known.

Splits (issue 25): ``tuning`` -- even DoRF curves, seeds < 1000 (the common encodings on
scenes 1 and 2); ``held-out`` -- odd DoRF curves, seeds ≥ 1000 (scenes 1001 and 1002).
``--split all`` is the issue 3 protocol (every ``--step``-th curve, seeds as there).

Per case: the median RMSE of f⁻¹ over codes 1 … 254, the range of the recovered γ (the
slope of the estimated log exposures against the true ones; 1 = resolved) and the share
of stacks with γ within 0.9 … 1.1; then the issue 25 acceptance with one known time and
with none: median ≤ 0.02 and γ within 0.9 … 1.1 on ≥ 80 % of the stacks.

With ``--band`` (issue 35): the 90 % band of f⁻¹ too, per case -- *coverage*, the share of
(code, channel) for codes 1 … 254 where the true f⁻¹ lies inside
``model.band_at_codes(level=0.9)`` (both curves are 1 at code 255: the normalisation the
RMSE is scored after; its median and its mean over the stacks, the mean being the pooled
share a 90 % band should bring to 0.90), and *width*, the median relative half-width
``(upper − lower) / (2 f⁻¹)`` over codes 26 … 229 and channels (as ``bench.uncertainty``);
then the issue 35 acceptance: with one known time and with none, median coverage ≥ 0.80.
``--dump FILE`` (with ``--band``) also writes each stack's true and fitted f⁻¹ and σ of
log f⁻¹ at every code to an ``.npz`` (to study the band offline); ``--gamma-sigma S`` scores
the band with σ₀ = S in its σ_γ = σ₀ √(1 + E) instead of the library's
(``selfcal.response.bands.AMBIGUITY_LOG_GAMMA_SIGMA``; the candidates it was tuned among,
on the tuning split): the ambiguity term is redone from σ_γ and E in each calibration's
verdict evidence (:func:`band_sigma`).

    python3 -m bench.response_unknown [--split tuning|held-out|all] [--step 20]
        [--known all,two,one,none] [--centre none] [--band [--dump FILE] [--gamma-sigma S]]
        [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import time
from multiprocessing import Pool

import numpy as np

from .data import data_dir
from . import tables
from .tables import table

from selfcal.sim.scoring import rmse

TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]
KNOWN = {"all": TIMES,
         "two": [TIMES[0], None, None, None, None, TIMES[-1]],
         "one": [TIMES[0]] + [None] * 5,
         "none": [None] * 6}
WINDOW = (0.9, 1.1)
TARGET_MEDIAN, TARGET_SHARE = 0.02, 0.8
#: --band: codes scored for coverage, for width (as bench.uncertainty), and the target.
INNER, BODY = slice(1, 255), slice(26, 230)
TARGET_COVERAGE = 0.8


def one_stack(args):
    group, label, curve, seed, keys, centre, band, gamma_sigma = args
    import warnings

    import selfcal
    from selfcal import sim
    from selfcal.response import ResponseOptions

    options = ResponseOptions()
    if centre == "none":            # the prior at the basis mean, as before issue 25
        options = options.with_solver(centre_ambiguity=False)

    pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=seed)
    stack = sim.simulate_stack(sim.make_scene(384, 576, seed=seed), pipe, TIMES,
                               jitter=0.03, jpeg_quality=90, seed=seed)
    truth = stack.inverse_response()[1:255]
    true_log = np.log(stack.true_exposures)
    out = {}
    for key in keys:
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = selfcal.calibrate_response(stack.images, KNOWN[key], options=options)
        seconds = time.perf_counter() - start
        gamma = float(np.polyfit(true_log, np.log(model.exposures), 1)[0])
        out[key] = (rmse(model.inverse_response()[1:255], truth), gamma, seconds)
        if band:
            out[key] += (band_scores(model, stack.inverse_response(), gamma_sigma),)
    return group, label, out


def band_sigma(model, gamma_sigma=None):
    """The model's σ of log f⁻¹; with ``gamma_sigma`` (--gamma-sigma), its ambiguity term
    redone with that σ₀: the term the calibration added (``selfcal.response.bands``,
    σ_γ and E in the verdict's evidence) taken out in quadrature and σ₀'s put in."""
    from selfcal.response import bands

    sigma = np.asarray(model.inverse_log_sigma, dtype=float)
    evidence = model.diagnostics["verdict_evidence"]
    if gamma_sigma is None or "ambiguity_energy" not in evidence:
        return sigma
    log_inverse = bands.ambiguity_sigma(model.inverse, 1.0)          # |log f⁻¹|
    old = evidence["ambiguity_gamma_sigma"]
    new = bands.gamma_sigma_of_energy(evidence["ambiguity_energy"], gamma_sigma)
    return np.sqrt(np.maximum(sigma ** 2 - (old * log_inverse) ** 2, 0.0)
                   + (new * log_inverse) ** 2)


def band_scores(model, truth, gamma_sigma=None) -> dict:
    """Coverage and width of the model's 90 % band against the true f⁻¹ (module docstring),
    and the curves at every code (for ``--dump``)."""
    from selfcal.response.bands import band_from_sigma

    x = np.arange(256) / model.max_code
    grid_sigma = band_sigma(model, gamma_sigma)
    lower, upper, sigma = (np.stack([np.interp(x, model.intensity, t[:, c]) for c in range(3)],
                                    axis=-1)
                           for t in (*band_from_sigma(model.inverse, grid_sigma, 0.9),
                                     grid_sigma))
    est = model.inverse_response()
    inside = (truth[INNER] >= lower[INNER]) & (truth[INNER] <= upper[INNER])
    return {"coverage": float(inside.mean()),
            "width": float(np.median((upper - lower)[BODY] / (2 * est[BODY]))),
            "truth": truth, "estimate": est, "log_sigma": sigma}


def tasks_for(split, step, keys, centre, band=False, gamma_sigma=None):
    import scipy.io as sio

    from selfcal import sim

    common = {"sRGB": sim.ToneCurve.srgb(), "Rec.709": sim.ToneCurve.rec709(),
              "gamma 1.8": sim.ToneCurve.gamma(1.8), "gamma 2.2": sim.ToneCurve.gamma(2.2),
              "film": sim.ToneCurve.film()}
    seeds = (1001, 1002) if split == "held-out" else (1, 2)
    tasks = [("common", name, curve, seed, keys, centre, band, gamma_sigma)
             for name, curve in common.items()
             for seed in seeds]
    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    n = mat["I"].shape[0]
    if split == "all":
        indices, offset = range(0, n, step), 0
    else:
        half = list(range(0 if split == "tuning" else 1, n, 2))
        indices, offset = half[::step], (1000 if split == "held-out" else 0)
    tasks += [("DoRF", f"dorf{i}", sim.ToneCurve.from_table(mat["I"][i], mat["B"][i]),
               i + offset, keys, centre, band, gamma_sigma) for i in indices]
    return tasks


def summary_rows(results, keys):
    rows = []
    for group in ("common", "DoRF", "both"):
        res = [r[2] for r in results if group in (r[0], "both")]
        for key in keys:
            errors = [r[key][0] for r in res]
            gam = np.array([r[key][1] for r in res])
            inside = np.mean((gam >= WINDOW[0]) & (gam <= WINDOW[1]))
            rows.append([group, key, f"{len(res)}", f"{np.median(errors):.4f}",
                         f"{np.percentile(errors, 90):.4f}", f"{np.max(errors):.4f}",
                         f"{gam.min():.2f} … {gam.max():.2f}", f"{100 * inside:.0f} %"])
    return rows


def band_rows(results, keys):
    """Rows of the --band table: per group and case, coverage and width."""
    rows = []
    for group in ("common", "DoRF", "both"):
        res = [r[2] for r in results if group in (r[0], "both")]
        for key in keys:
            cov = np.array([r[key][3]["coverage"] for r in res])
            wid = np.array([r[key][3]["width"] for r in res])
            rows.append([group, key, f"{len(res)}", f"{np.median(cov):.3f}",
                         f"{np.mean(cov):.3f}", f"{np.percentile(cov, 10):.3f}",
                         f"{np.min(cov):.3f}",
                         f"{np.median(wid):.4f}", f"{np.percentile(wid, 90):.4f}"])
    return rows


def print_band(results, keys, dump=None):
    """The --band table, its acceptance (issue 35) and the optional dump."""
    print("\n90 % band of f⁻¹: coverage of the true curve over codes 1 … 254 (both 1 at "
          "code 255), half-width relative to f⁻¹ over codes 26 … 229\n")
    print(table(["curves", "times known", "stacks", "coverage median", "mean", "p10", "min",
                 "half-width median", "p90"], band_rows(results, keys)))
    print(f"\nAcceptance (issue 35): one known time, or none: median coverage ≥ "
          f"{TARGET_COVERAGE:.2f} over the stacks")
    for key in (k for k in ("one", "none") if k in keys):
        cov = np.median([r[2][key][3]["coverage"] for r in results])
        print(f"- {key}: median coverage {cov:.3f} over {len(results)} stacks: "
              f"{'met' if cov >= TARGET_COVERAGE else 'NOT met'}")
    if dump:
        arrays = {f"{i:03d}-{r[1]}.{key}.{name}": r[2][key][3][name]
                  for i, r in enumerate(results) for key in keys
                  for name in ("truth", "estimate", "log_sigma")}
        np.savez_compressed(dump, **arrays)
        print(f"\n(curves written to {dump})")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("tuning", "held-out", "all"), default="all")
    parser.add_argument("--step", type=int, default=20,
                        help="use every K-th DoRF curve (of the split's half)")
    parser.add_argument("--known", default="all,two,one,none",
                        help="comma-separated cases among all, two, one, none")
    parser.add_argument("--centre", default="", choices=("", "none"),
                        help="the prior's centre with < 2 known times: 'none' (the basis "
                        "mean, as before issue 25: SolverOptions(centre_ambiguity=False)); "
                        "default the library's")
    parser.add_argument("--band", action="store_true",
                        help="also score the 90 % band of f⁻¹ (coverage, width; issue 35)")
    parser.add_argument("--dump", default="",
                        help="with --band: write the true and fitted curves and σ to this .npz")
    parser.add_argument("--gamma-sigma", type=float, default=None,
                        help="with --band: score the band with this σ₀ in σ_γ = σ₀ √(1 + E) "
                        "(< 2 known times; default the library's, "
                        "selfcal.response.bands.AMBIGUITY_LOG_GAMMA_SIGMA)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args()
    tables.start("response_unknown", args.split)
    keys = [k for k in args.known.split(",") if k]
    if not keys or any(k not in KNOWN for k in keys):
        parser.error(f"--known takes cases among {', '.join(KNOWN)}")
    tasks = tasks_for(args.split, args.step, keys, args.centre, args.band, args.gamma_sigma)
    start = time.perf_counter()
    with Pool(args.jobs) as pool:
        results = list(pool.imap(one_stack, tasks))
    wall = time.perf_counter() - start

    centre = args.centre or "library default"
    print(f"{args.split} split, prior centre: {centre}. Exposure times known: all, two (first and last), one "
          "(first), none; f⁻¹ RMSE over codes 1..254 and the recovered exponent γ "
          "(1 = resolved)\n")
    print(table(["curves", "times known", "stacks", "median RMSE", "p90 RMSE", "max RMSE",
                 "γ range", f"γ in {WINDOW[0]} … {WINDOW[1]}"],
                summary_rows(results, keys)))
    def cell(v):
        band = (f", band {v[3]['coverage']:.2f} ±{v[3]['width']:.2f}" if args.band else "")
        return f"{v[0]:.4f} (γ {v[1]:.2f}{band})"

    per_curve = [[r[0], r[1], *(cell(r[2][k]) for k in keys)] for r in results]
    print("\nStack by stack" + (" (with --band: coverage and half-width of the band)"
                                if args.band else "") + ":\n")
    print(table(["group", "curve", *(f"{k} known" for k in keys)], per_curve))
    print("\nAcceptance (issue 25): one known time, or none: median ≤ 0.02, γ within "
          "0.9 … 1.1 on ≥ 80 % of stacks")
    for key in (k for k in ("one", "none") if k in keys):
        errors = np.array([r[2][key][0] for r in results])
        gam = np.array([r[2][key][1] for r in results])
        share = np.mean((gam >= WINDOW[0]) & (gam <= WINDOW[1]))
        ok = np.median(errors) <= TARGET_MEDIAN and share >= TARGET_SHARE
        print(f"- {key}: median {np.median(errors):.4f}, γ within the window on "
              f"{100 * share:.0f} % of {len(results)} stacks: {'met' if ok else 'NOT met'}")
    if args.band:
        print_band(results, keys, args.dump)
    seconds = [r[2][k][2] for r in results for k in keys]
    print(f"\nseconds per calibration (median) {np.median(seconds):.1f}; wall {wall:.0f} s "
          f"with {args.jobs} jobs")


if __name__ == "__main__":
    main()
    tables.finish()
