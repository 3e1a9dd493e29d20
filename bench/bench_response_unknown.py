"""Issue 3: how well the exponential ambiguity is resolved when exposure times are missing.

With fewer than two known exposure times, Eq. 8 of Lin et al. (ICCV 2011, §5) fixes the
response only up to an exponent γ (f⁻¹ → (f⁻¹)^γ with every exposure ratio raised to γ);
selfcal resolves it with the prior of its response basis and warns.  This script measures
what that prior gives: stacks rendered by ``selfcal.sim`` (6 shots 1/250 … 1/8 s, ±3 %
jitter, noise, smooth gamut map, JPEG q90) for common encodings (sRGB, Rec.709, gamma 1.8
and 2.2, a film curve; two scenes each) and for every ``--step``-th DoRF curve, calibrated
with all, two (first and last), one (first) and no times known.

Per case: the median RMSE of f⁻¹ over codes 1 … 254 and the range of the recovered γ, the
slope of the estimated log exposures against the true ones (1 = resolved).

    python bench/bench_response_unknown.py [--step 20] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import data_dir, table  # noqa: E402

from selfcal.sim.scoring import rmse  # noqa: E402

TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]
KNOWN = {"all": TIMES,
         "two": [TIMES[0], None, None, None, None, TIMES[-1]],
         "one": [TIMES[0]] + [None] * 5,
         "none": [None] * 6}


def one_stack(args):
    group, label, curve, seed = args
    import selfcal
    from selfcal import sim

    pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=seed)
    stack = sim.simulate_stack(sim.make_scene(384, 576, seed=seed), pipe, TIMES,
                                 jitter=0.03, jpeg_quality=90, seed=seed)
    truth = stack.inverse_response()[1:255]
    true_log = np.log(stack.true_exposures)
    out = {}
    for key, times in KNOWN.items():
        model = selfcal.calibrate_response(stack.images, times)
        gamma = float(np.polyfit(true_log, np.log(model.exposures), 1)[0])
        out[key] = (rmse(model.inverse_response()[1:255], truth), gamma)
    return group, label, out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=20, help="use every K-th DoRF curve")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args()
    import scipy.io as sio

    from selfcal import sim

    common = {"sRGB": sim.ToneCurve.srgb(), "Rec.709": sim.ToneCurve.rec709(),
              "gamma 1.8": sim.ToneCurve.gamma(1.8), "gamma 2.2": sim.ToneCurve.gamma(2.2),
              "film": sim.ToneCurve.film()}
    tasks = [("common", name, curve, seed) for name, curve in common.items() for seed in (1, 2)]
    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    tasks += [("DoRF", f"dorf{i}", sim.ToneCurve.from_table(mat["I"][i], mat["B"][i]), i)
              for i in range(0, mat["I"].shape[0], args.step)]
    with Pool(args.jobs) as pool:
        results = list(pool.imap(one_stack, tasks))

    rows = []
    for group in ("common", "DoRF"):
        res = [r[2] for r in results if r[0] == group]
        for key in KNOWN:
            errors = [r[key][0] for r in res]
            gam = [r[key][1] for r in res]
            rows.append([group, key, f"{len(res)}", f"{np.median(errors):.4f}",
                         f"{np.max(errors):.4f}", f"{min(gam):.2f} … {max(gam):.2f}"])
    print("Exposure times known: all, two (first and last), one (first), none; "
          "f⁻¹ RMSE over codes 1..254 and the recovered exponent γ (1 = resolved)\n")
    print(table(["curves", "times known", "stacks", "median RMSE", "max RMSE", "γ range"],
                rows))
    per_curve = [[r[1], *(f"{r[2][k][0]:.4f} (γ {r[2][k][1]:.2f})" for k in ("all", "none"))]
                 for r in results if r[0] == "common"]
    print("\nCommon encodings, all times known vs none:\n")
    print(table(["curve", "all known", "none known"], per_curve))


if __name__ == "__main__":
    main()
