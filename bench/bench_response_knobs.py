"""Issue 3: the JPEG-only path's knobs, one at a time, on the truth and on the real-stack metric.

Each row changes one setting of the shipped method and scores it on

* synthetic stacks with a known truth, built as in acceptance 1 (every ``--step``-th DoRF
  curve, and ``--srgb`` sRGB stacks; 384×576, 6 shots 1/250 … 1/8 s, ±3 % jitter, noise,
  smooth gamut map, JPEG q90): the median RMSE of f⁻¹ over codes 1 … 254;
* the real stacks memorial and piccante with the acceptance-2 metric
  (``bench.real_stack_metrics.log_linearisation_error``, nominal times), where the shipped method
  stays above OpenCV Robertson (bench_response_real.py).

Knobs that are arguments of the solver (``solve_exposure_equations``) or of the sampling
(``collect_samples``), and the per-channel ranking that replaces
``samples._local_contrast``, are set by wrapping selfcal's functions inside this script;
the library keeps no switch for them.

    python bench/bench_response_knobs.py [--step 20] [--srgb 6] [--jobs 2]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import data_dir, read_real_stacks, table  # noqa: E402
from real_stack_metrics import log_linearisation_error  # noqa: E402

from selfcal.sim.scoring import rmse  # noqa: E402

TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]
REAL = ("memorial", "piccante")

# key -> (row label, ResponseOptions fields: of the sampling, of the solve; collect_samples
# kwargs)
KNOBS = [
    ("shipped", "as shipped", {}, {}, {}),
    ("beta1", "β = 1 (no saturation rejection; default 0.5)",
     {"saturation_threshold": 1.0}, {}, {}),
    ("n11", "N = 11 basis functions (default 5)", {"n_components": 11}, {}, {}),
    ("prior10", "coefficient prior weight 10 (default 100)", {}, {"prior_weight": 10.0}, {}),
    ("prior1", "coefficient prior weight 1", {}, {"prior_weight": 1.0}, {}),
    ("nothreshold", "no censored white-threshold rows", {}, {"white_threshold": False}, {}),
    ("adjacent", "adjacent pairs only (max_rank_gap 1; default 3)", {},
     {"max_rank_gap": 1}, {}),
    ("nonmonotone", "no monotonicity constraint", {}, {"monotone": False}, {}),
    ("block2", "2×2 block means (default: single pixels on these frames)", {}, {},
     {"block": 2}),
    ("perchannel", "sample ranking by per-channel spatial spread (no neutrality)", {}, {},
     {}),
]


def _per_channel_contrast(blocks):
    """The sample ranking's spread without its across-channel part: the largest
    per-channel spread over a block and its 8 neighbours, over the block's level, so a
    flat coloured block ranks as flat as a flat neutral one (``samples._local_contrast``
    takes the spread across channels too)."""
    from scipy.ndimage import maximum_filter, minimum_filter

    blocks = np.asarray(blocks, dtype=np.float32)
    size = (3, 3, 1) if blocks.shape[0] > 2 else (1, 1, 1)
    spread = (maximum_filter(blocks, size=size) - minimum_filter(blocks, size=size)).max(axis=2)
    return spread / np.maximum(blocks.mean(axis=2), 1.0)


@contextlib.contextmanager
def knob(key):
    """Wrap selfcal's sampling for one knob; yields calibrate kwargs (its options)."""
    import selfcal.response.calibrate as cal
    import selfcal.stack.samples as samples
    from selfcal.response import ResponseOptions

    _, _, kwargs, solver_kw, sampling_kw = next(k for k in KNOBS if k[0] == key)
    saved = (cal.solve_exposure_equations, cal.collect_samples, samples._local_contrast)
    try:
        if sampling_kw:
            cal.collect_samples = functools.partial(saved[1], **sampling_kw)
        if key == "perchannel":
            samples._local_contrast = _per_channel_contrast
        yield {"options": ResponseOptions(**kwargs, **solver_kw)}
    finally:
        cal.solve_exposure_equations, cal.collect_samples, samples._local_contrast = saved


def _rmse_per_knob(stack):
    import selfcal

    truth = stack.inverse_response()[1:255]
    out = {}
    for key, *_ in KNOBS:
        with knob(key) as kwargs:
            model = selfcal.calibrate_response(stack.images, TIMES, **kwargs)
        out[key] = rmse(model.inverse_response()[1:255], truth)
    return out


def one_dorf(args):
    index, irradiance, brightness = args
    from selfcal import sim

    curve = sim.ToneCurve.from_table(irradiance, brightness, name=f"dorf{index}")
    pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=index)
    stack = sim.simulate_stack(sim.make_scene(384, 576, seed=index), pipe, TIMES,
                                 jitter=0.03, jpeg_quality=90, seed=index)
    return "dorf", index, _rmse_per_knob(stack)


def one_srgb(seed):
    from selfcal import sim

    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=seed)
    stack = sim.simulate_stack(sim.make_scene(384, 576, seed=seed), pipe, TIMES,
                                 jitter=0.03, jpeg_quality=90, seed=seed)
    return "srgb", seed, _rmse_per_knob(stack)


def _run(task):
    kind, arg = task
    return one_dorf(arg) if kind == "dorf" else one_srgb(arg)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=20, help="use every K-th DoRF curve")
    parser.add_argument("--srgb", type=int, default=6, help="number of sRGB stacks")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args()
    import scipy.io as sio

    import selfcal

    real = {}
    for name, (images, times) in read_real_stacks(REAL).items():
        real[name] = {}
        for key, *_ in KNOBS:
            with knob(key) as kwargs:
                lut = selfcal.calibrate_response(images, times, **kwargs).inverse_response()
            real[name][key] = log_linearisation_error(images, times, lut)

    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    tasks = [("dorf", (i, mat["I"][i], mat["B"][i]))
             for i in range(0, mat["I"].shape[0], args.step)]
    tasks += [("srgb", seed) for seed in range(args.srgb)]
    with Pool(args.jobs) as pool:
        results = list(pool.imap_unordered(_run, tasks))
    dorf = [r[2] for r in results if r[0] == "dorf"]
    srgb = [r[2] for r in results if r[0] == "srgb"]

    rows = []
    for key, label, *_ in KNOBS:
        rows.append([label, f"{np.median([r[key] for r in dorf]):.4f}",
                     f"{np.median([r[key] for r in srgb]):.4f}",
                     *(f"{real[n][key]:.4f}" for n in REAL)])
    print(f"Median f⁻¹ RMSE over codes 1..254 on {len(dorf)} DoRF curves (every "
          f"{args.step}th) and {len(srgb)} sRGB stacks; the acceptance-2 metric on the real "
          "stacks (nominal times)\n")
    print(table(["knob", "DoRF f⁻¹ RMSE", "sRGB f⁻¹ RMSE", *REAL], rows))


if __name__ == "__main__":
    main()
