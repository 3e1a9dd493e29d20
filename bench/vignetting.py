"""Issue 36: vignetting self-calibrated from handheld stacks, against the simulator's truth.

Stacks (``selfcal.sim.simulate_handheld_stack``): scene ``make_scene(300, 440,
dynamic_range_stops=10, saturation=0.5, seed)``, camera ``default_pipeline(gamut="smooth",
curves=DoRF curve seed mod 201, seed)``, five shots 1/200 … 1/12 s (±3 % jitter), frames
208×306 cut from the scene through each frame's similarity (shift 12 % of the frame's width
and height × U(0.85, 1), rotation U(±2°); the middle frame is the reference), the lens
falloff ``random_vignetting(seed)`` (0.5–2 stops at the farthest corner, centre off by up
to 8 % of the half-diagonal, channels ±8 %) applied in frame coordinates, then JPEG q 90.
Splits: tuning = seeds 0…N−1, held-out = seeds 1000…1000+N−1 (``--stacks N``, default 20).

Per stack, calibrations with ``calibrate_response(images, TIMES, align="homography")``:

* **fitted**: the vignetted stack; scores: the vignetting map's RMS against the truth
  (``selfcal.sim.vignetting_rms``: RMS of ``V_fit / V_true − 1`` over the frame and the
  channels; target ≤ 2 % median on held-out; "none" is the RMS of ``1 / V_true − 1``, what
  ignoring the falloff costs) and the response error (best-scale RMSE of f⁻¹ against the
  truth over codes 1…254, ``selfcal.sim.scoring.best_scale_rmse``);
* **no fit**: the same frames through ``calibrate_aligned(method="homography",
  options=ResponseOptions(fit_vignetting=False))`` (no
  vignetting fit): the response error the falloff causes when ignored;
* **no vignetting**: the same stack simulated without falloff (same seed), calibrated as
  "fitted": the response error the joint fit is to match (target: no worse);
* **tripod**: the same stack with no motion (shift 0, 0°): must say "not observable".

    python3 -m bench.vignetting --split held-out|tuning [--stacks 20] [--jobs 2]
"""

from __future__ import annotations

import argparse
import time
import warnings
from multiprocessing import Pool

import numpy as np

from .data import dorf_curve
from .tables import finish, start, table

TIMES = (1 / 200, 1 / 100, 1 / 50, 1 / 25, 1 / 12)
SCENE = (300, 440)
TARGET_RMS = 0.02


def _init_worker():
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    warnings.filterwarnings("ignore")


def make_stack(seed: int, *, vignetting=True, moved=True):
    from selfcal import sim

    scene = sim.make_scene(*SCENE, dynamic_range_stops=10.0, saturation=0.5, seed=seed)
    pipe = sim.default_pipeline(gamut="smooth", curves=dorf_curve(seed % 201), seed=seed)
    v = sim.random_vignetting(seed, aspect=306 / 208) if vignetting else None
    return sim.simulate_handheld_stack(
        scene, pipe, TIMES, frame_shape=(208, 306), vignetting=v,
        shift=0.12 if moved else 0.0, degrees=2.0 if moved else 0.0, seed=seed)


def response_error(model, stack) -> float:
    from selfcal.sim.scoring import best_scale_rmse

    codes = np.arange(1, 255)
    return best_scale_rmse(model.inverse_response(codes), stack.inverse_response(codes))


def one_stack(seed: int) -> dict:
    import selfcal
    from selfcal import sim
    from selfcal.response.calibrate import calibrate_aligned
    from selfcal.response.options import ResponseOptions

    t0 = time.perf_counter()
    times = list(TIMES)
    st = make_stack(seed)
    h, w = st.images[0].shape[:2]
    fitted = selfcal.calibrate_response(st.images, times, align="homography")
    plain, _, _ = calibrate_aligned(st.images, times, method="homography",
                                    options=ResponseOptions(fit_vignetting=False))
    flat = make_stack(seed, vignetting=False)
    flat_model = selfcal.calibrate_response(flat.images, times, align="homography")
    tripod = make_stack(seed, moved=False)
    tripod_model = selfcal.calibrate_response(tripod.images, times, align="homography")
    diag = fitted.diagnostics["vignetting"]
    return {"seed": seed, "rms": sim.vignetting_rms(fitted.vignetting, st.vignetting, h, w),
            "rms_none": sim.vignetting_rms(None, st.vignetting, h, w),
            "observable": bool(diag.get("observable")),
            "true_stops": float(st.vignetting.corner_stops()[1]),
            "fit_stops": (float(fitted.vignetting.corner_stops()[1])
                          if fitted.vignetting is not None else float("nan")),
            "resp_fit": response_error(fitted, st), "resp_plain": response_error(plain, st),
            "resp_flat": response_error(flat_model, flat),
            "flat_rms": sim.vignetting_rms(flat_model.vignetting, None, h, w),
            "tripod_observable": tripod_model.diagnostics["vignetting"].get("observable"),
            "points": diag.get("points"), "motion": max(diag.get("motion") or [0.0]),
            "seconds": time.perf_counter() - t0}


def stacks_of_split(name: str, description: str, one_stack) -> tuple:
    """The command line of the handheld-stack benches (``--split``, ``--stacks``,
    ``--jobs``), the record started, and ``one_stack(seed)`` run on the split's seeds
    (tuning 0…N−1, held-out 1000…) in single-threaded worker processes."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--split", choices=("tuning", "held-out"), required=True)
    parser.add_argument("--stacks", type=int, default=20)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    start(name, args.split)
    base = 0 if args.split == "tuning" else 1000
    seeds = list(range(base, base + args.stacks))
    with Pool(args.jobs, initializer=_init_worker) as pool:
        results = sorted(pool.imap_unordered(one_stack, seeds), key=lambda r: r["seed"])
    return args, results


def main():
    t0 = time.perf_counter()
    args, results = stacks_of_split("vignetting", __doc__.splitlines()[0], one_stack)
    wall = time.perf_counter() - t0
    print(f"{len(results)} handheld stacks ({args.split} split): 5 frames 208x306, shifts "
          "10-12 % of the frame, rotations up to 2°, falloff 0.5-2 stops at the corner; "
          "calibrate_response(images, TIMES, align='homography')\n")
    rows = [[r["seed"], f"{r['true_stops']:.2f}", f"{r['fit_stops']:.2f}",
             f"{100 * r['rms']:.2f} %", f"{100 * r['rms_none']:.1f} %",
             f"{r['resp_fit']:.4f}", f"{r['resp_plain']:.4f}", f"{r['resp_flat']:.4f}",
             f"{100 * r['flat_rms']:.2f} %", "yes" if r["tripod_observable"] is False else "NO",
             r["points"], f"{100 * r['motion']:.1f} %", f"{r['seconds']:.1f}"]
            for r in results]
    print(table(["seed", "true G stops", "fit G stops", "map RMS", "RMS if ignored",
                 "f⁻¹ err fitted", "f⁻¹ err no fit", "f⁻¹ err no vignetting",
                 "map RMS no vignetting", "tripod not observable", "points", "motion",
                 "seconds"], rows))

    def med(key):
        return float(np.median([r[key] for r in results]))

    n_tripod = sum(r["tripod_observable"] is False for r in results)
    print("\nmedians:\n")
    print(table(["map RMS", "RMS if ignored", "f⁻¹ err fitted", "f⁻¹ err no fit",
                 "f⁻¹ err no vignetting", "observable", "tripod not observable"],
                [[f"{100 * med('rms'):.2f} % (target ≤ {100 * TARGET_RMS:.0f} %)",
                  f"{100 * med('rms_none'):.1f} %", f"{med('resp_fit'):.4f}",
                  f"{med('resp_plain'):.4f}", f"{med('resp_flat'):.4f}",
                  f"{sum(r['observable'] for r in results)}/{len(results)}",
                  f"{n_tripod}/{len(results)}"]]))
    print(f"\nwall {wall:.0f} s with {args.jobs} jobs")


if __name__ == "__main__":
    main()
    finish()
