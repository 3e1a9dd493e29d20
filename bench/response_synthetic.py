"""Issue 3, acceptance 1: recovered inverse responses against the truth on DoRF curves.

Each of the 201 DoRF curves (../shared/data/dorf_emor/201_CRF_data.mat) is rendered by
``selfcal.sim`` into a 6-shot stack (1/250 … 1/8 s, ±3 % shutter jitter, shot and read
noise, smooth gamut mapping, JPEG quality 90).  Per curve: RMSE of f⁻¹ over codes 1…254
(f⁻¹(255) = 1), for selfcal with the nominal times, selfcal with only the first and last
times known, and OpenCV's CalibrateDebevec and CalibrateRobertson given the nominal times
(scored after their best least-squares scale).

A second table scores the same curves with the real-stack metric of acceptance 2 (the
scale-free linearisation error of bench.response_real, nominal times), next to the
*true* curve and the metric's per-code least-squares floor: where the truth is known, it
shows how far that metric tells an accurate curve from one fitted to the pixels' noise.

    python3 -m bench.response_synthetic [--step K] [--size 384x576] [--jobs 2]
"""

from __future__ import annotations

import argparse
import os
from multiprocessing import Pool

import numpy as np

from .data import data_dir
from .peers import opencv_inverse_response
from .tables import finish, start, table
from selfcal.sim.scoring import log_linearisation_error, per_code_floor

from selfcal.sim.scoring import best_scale_rmse, rmse

TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]


def one_curve(args):
    index, irradiance, brightness, size = args
    import selfcal
    from selfcal import sim

    h, w = size
    curve = sim.ToneCurve.from_table(irradiance, brightness, name=f"dorf{index}")
    pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=index)
    scene = sim.make_scene(h, w, seed=index)
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=0.03, jpeg_quality=90,
                                 seed=index)
    truth = stack.inverse_response()
    inner = slice(1, 255)
    out = {}
    metric = {}
    model = selfcal.calibrate_response(stack.images, TIMES)
    out["selfcal"] = rmse(model.inverse_response()[inner], truth[inner])
    metric["selfcal"] = log_linearisation_error(stack.images, TIMES, model.inverse_response())
    metric["truth"] = log_linearisation_error(stack.images, TIMES, truth)
    metric["floor"] = log_linearisation_error(stack.images, TIMES,
                                              per_code_floor(stack.images, TIMES))
    two = [TIMES[0], None, None, None, None, TIMES[-1]]
    model = selfcal.calibrate_response(stack.images, two)
    out["selfcal_2known"] = rmse(model.inverse_response()[inner], truth[inner])
    for method in ("debevec", "robertson"):
        resp = opencv_inverse_response(stack.images, TIMES, method)
        out[method] = best_scale_rmse(resp[inner], truth[inner])
        metric[method] = log_linearisation_error(stack.images, TIMES, resp)
    out["metric"] = metric
    return index, out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=1, help="use every K-th curve")
    parser.add_argument("--size", default="384x576", help="scene HxW (default %(default)s)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args()
    start("response_synthetic", "both")
    import scipy.io as sio

    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    h, w = (int(v) for v in args.size.lower().split("x"))
    tasks = [(i, mat["I"][i], mat["B"][i], (h, w)) for i in range(0, mat["I"].shape[0],
                                                                  args.step)]
    with Pool(args.jobs) as pool:
        results = dict(pool.imap_unordered(one_curve, tasks))
    names = [("selfcal", "selfcal, nominal times"),
             ("selfcal_2known", "selfcal, 2 times known"),
             ("debevec", "OpenCV Debevec (best scale)"),
             ("robertson", "OpenCV Robertson (best scale)")]
    rows = []
    for key, label in names:
        v = np.array([results[i][key] for i in sorted(results)])
        rows.append([label, f"{np.median(v):.4f}", f"{np.mean(v):.4f}",
                     f"{np.percentile(v, 90):.4f}", f"{np.max(v):.4f}"])
    print(f"DoRF curves: {len(results)}; stacks {h}x{w}, 6 shots 1/250..1/8 s, "
          "±3% jitter, noise, smooth gamut, JPEG q90")
    print("RMSE of f⁻¹ over codes 1..254 (f⁻¹(255) = 1)\n")
    print(table(["method", "median", "mean", "p90", "max"], rows))
    med = {k: np.median([results[i][k] for i in results]) for k, _ in names}
    best_cv = min(med["debevec"], med["robertson"])
    print(f"\nselfcal median / better OpenCV median: {med['selfcal'] / best_cv:.3f} "
          "(target ≤ 0.333)")
    print(f"targets: nominal median ≤ 0.005 -> {med['selfcal']:.4f}; "
          f"two known ≤ 0.008 -> {med['selfcal_2known']:.4f}")

    keys = [("truth", "true curve"), ("selfcal", "selfcal, nominal times"),
            ("debevec", "OpenCV Debevec"), ("robertson", "OpenCV Robertson"),
            ("floor", "per-code least-squares floor")]
    m = {k: np.array([results[i]["metric"][k] for i in sorted(results)]) for k, _ in keys}
    rows = [[label, f"{np.median(m[k]):.4f}", f"{np.median(m[k] / m['truth']):.3f}",
             f"{100 * np.mean(m[k] < m['truth']):.0f}%"] for k, label in keys]
    print("\nThe acceptance-2 metric on the same stacks (scale-free linearisation error, "
          "adjacent pairs, all channels in [25, 235], nominal times); lower is 'better'\n")
    print(table(["curve", "median", "median ratio to the true curve",
                 "stacks where it scores below the true curve"], rows))
    print(f"\nselfcal below OpenCV Robertson on "
          f"{100 * np.mean(m['selfcal'] < m['robertson']):.0f}% of the stacks, below both "
          f"OpenCV methods on {100 * np.mean(m['selfcal'] < np.minimum(m['robertson'], m['debevec'])):.0f}%")


if __name__ == "__main__":
    main()
    finish()
