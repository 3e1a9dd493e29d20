"""Issue 36: absolute luminance (cd/m²) from a reference reading or from EXIF alone.

On simulated stacks whose camera's absolute calibration is known
(:mod:`selfcal.sim.luminance`: the camera follows the ISO 12232 standard output
sensitivity, its ISO calibration off by δ stops, δ drawn uniformly in ±1/3 stop per
stack -- the tolerance :data:`selfcal.lens.luminance.EXIF_LOG_SIGMA` stands for), each
stack written as JPEG files with EXIF (time, f-number and ISO drawn per stack) and merged
from them with the defaults and ``sigma=True``:

* **reference**: a spot-meter reading of one uniform region (the 16×16 block, on a stride
  of 8, with the smallest spread of true log luminance among the fully measured blocks
  between the 25th and 75th percentile of luminance): its true mean luminance, exact
  ("exact meter") or times ``1 + N(0, 3 %)`` (the stated meter accuracy, for the σ
  columns); the luminance elsewhere (every pixel outside the region that the truth scores
  in all three channels and the merge measured) against the truth: median ``|L/L_true − 1|``;
* **EXIF**: :func:`selfcal.lens.luminance.scale_from_exif` with the merge's model; its
  scale against the camera's true one, ``log(C / C_true)``, the median ``|L/L_true − 1|``,
  and, against a camera that follows the convention exactly (δ = 0), the median
  ``log(L/L_true)``: selfcal's own part of the error (curve and exposures);
* **σ calibration**: per channel and pixel, ``|L − L_true| / σ_L`` with σ_L the merge's σ
  in cd/m² (the scale's own σ added in quadrature, :func:`absolute_radiance`): its
  median (0.674 for a well-calibrated normal σ), pooled over the pixels of a stack; then
  the median over the stacks.

Stacks: :mod:`selfcal.sim.conditions` cells and tone curves in turn, 256×384, seeds
1000… for the held-out split, 0… for tuning.

    python3 -m bench.luminance --split held-out          # 20 stacks, about a minute
    python3 -m bench.luminance --split tuning --stacks 10
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time

import numpy as np

from .tables import finish, start, table

CELLS = ("colourful/base", "saturated/base", "colourful/per-channel", "neutral/base",
         "colourful/sharpened")
F_NUMBERS = (2.8, 5.6, 8.0, 11.0)
ISOS = (100.0, 200.0, 400.0, 800.0)
BLOCK, STRIDE = 16, 8


def curves():
    from selfcal import sim

    return (("sRGB", sim.ToneCurve.srgb()), ("Rec.709", sim.ToneCurve.rec709()),
            ("gamma 1.8", sim.ToneCurve.gamma(1.8)), ("gamma 2.4", sim.ToneCurve.gamma(2.4)))


def make_stack(i: int, seed: int):
    """The i-th stack of a run: its condition, curve, f-number and ISO, and its δ."""
    from selfcal.sim.conditions import CONDITIONS

    name, curve = curves()[i % 4]
    stack = CONDITIONS[CELLS[i % len(CELLS)]].simulate(curve, seed=seed)
    rng = np.random.default_rng([seed, 36])
    stack.f_number = float(F_NUMBERS[rng.integers(4)])
    stack.iso = float(ISOS[rng.integers(4)])
    delta = float(rng.uniform(-1 / 3, 1 / 3))
    meter = float(rng.normal(0.0, 0.03))
    return stack, f"{CELLS[i % len(CELLS)]}, {name}", delta, meter


def pick_region(y_true, ok):
    """(x0, y0, x1, y1) of the most uniform fully measured mid-luminance block."""
    h, w = y_true.shape
    lo, hi = np.percentile(y_true[ok], [25, 75])
    best, where = np.inf, None
    logs = np.log(np.maximum(y_true, 1e-30))
    for y0 in range(0, h - BLOCK + 1, STRIDE):
        for x0 in range(0, w - BLOCK + 1, STRIDE):
            if not ok[y0:y0 + BLOCK, x0:x0 + BLOCK].all():
                continue
            m = float(np.mean(y_true[y0:y0 + BLOCK, x0:x0 + BLOCK]))
            s = float(np.std(logs[y0:y0 + BLOCK, x0:x0 + BLOCK]))
            if lo <= m <= hi and s < best:
                best, where = s, (x0, y0, x0 + BLOCK, y0 + BLOCK)
    return where


def z_median(result_abs, sigma_abs, l_true_rgb, mask):
    """Median over the mask's pixels and the channels of |L − L_true| / σ_L."""
    z = np.abs(result_abs - l_true_rgb) / np.maximum(sigma_abs, 1e-30)
    return float(np.median(z[mask]))


def run_stack(i: int, seed: int) -> dict:
    import selfcal
    from selfcal.hdr import MergeOptions
    from selfcal.lens.luminance import (ReferenceReading, absolute_radiance, luminance_of,
                                        scale_from_exif)
    from selfcal.sim.luminance import true_relative_radiance, true_scale
    from selfcal.sim.scoring import truth_masks

    stack, label, delta, meter = make_stack(i, seed)
    with tempfile.TemporaryDirectory() as folder:
        paths = stack.write(folder)
        res = selfcal.merge_hdr(paths, options=MergeOptions(sigma=True))
    e_rel = true_relative_radiance(stack)
    c_true = true_scale(stack, delta)
    l_true = c_true * luminance_of(e_rel)
    _, scored, *_ = truth_masks(stack)
    ok = scored.all(axis=2) & ~res.unmeasured
    region = pick_region(l_true, ok)
    x0, y0, x1, y1 = region
    elsewhere = ok.copy()
    elsewhere[y0:y1, x0:x1] = False
    l_ref = float(np.mean(l_true[y0:y1, x0:x1]))
    row = {"stack": f"{seed} ({label})", "N": stack.f_number, "ISO": stack.iso,
           "delta": delta}
    y_hat = luminance_of(res.radiance)
    exact = absolute_radiance(ReferenceReading(region, l_ref), res.radiance.copy(), None,
                              unmeasured=res.unmeasured)
    row["ref err"] = float(np.median(np.abs(exact[2]["scale"] * y_hat[elsewhere]
                                            / l_true[elsewhere] - 1)))
    noisy = ReferenceReading(region, l_ref * (1 + meter))
    rad, sig, summary = absolute_radiance(noisy, res.radiance.copy(), res.sigma.copy(),
                                          unmeasured=res.unmeasured)
    row["ref sigma"] = summary["total_log_sigma"]
    row["ref z"] = z_median(rad, sig, c_true * e_rel, elsewhere)
    exif = scale_from_exif(res.model)
    row["exif log err"] = math.log(exif.scale / c_true)
    rad, sig, summary = absolute_radiance(exif, res.radiance.copy(), res.sigma.copy())
    row["exif z"] = z_median(rad, sig, c_true * e_rel, ok)
    row["exif err"] = float(np.median(np.abs(exif.scale * y_hat[ok] / l_true[ok] - 1)))
    # selfcal's own part: against a camera that follows the convention exactly (δ = 0)
    l_true0 = true_scale(stack) * luminance_of(e_rel)
    row["exif own"] = float(np.median(np.log(exif.scale * y_hat[ok] / l_true0[ok])))
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("tuning", "held-out", "heldout"),
                        default="held-out")
    parser.add_argument("--stacks", type=int, default=20)
    args = parser.parse_args(argv)
    start("luminance", args.split)
    from threadpoolctl import threadpool_limits

    first = 0 if args.split == "tuning" else 1000
    t0 = time.perf_counter()
    rows = []
    with threadpool_limits(limits=1):
        for i in range(args.stacks):
            rows.append(run_stack(i, first + i))
            print(f"[{rows[-1]['stack']}: {time.perf_counter() - t0:.0f} s]", file=sys.stderr,
                  flush=True)
    out = [[r["stack"], f"f/{r['N']:g}", f"{r['ISO']:g}", f"{r['delta']:+.2f}",
            f"{100 * r['ref err']:.2f} %", f"{r['ref sigma']:.3f}", f"{r['ref z']:.2f}",
            f"{r['exif log err']:+.3f}", f"{100 * r['exif err']:.1f} %", f"{r['exif z']:.2f}",
            f"{r['exif own']:+.3f}"]
           for r in rows]
    head = ["stack (seed, condition, curve)", "N", "ISO", "δ (stops)",
            "reference: median |L/L_true − 1| elsewhere", "reference log-σ",
            "reference: median |z|", "EXIF: log(C/C_true)", "EXIF: median |L/L_true − 1|",
            "EXIF: median |z|", "EXIF, δ = 0: median log(L/L_true)"]
    print(f"\nAbsolute luminance, {args.split} split ({len(rows)} stacks, 256×384, merged "
          "from JPEG files with EXIF):\n")
    print(table(head, out))

    def med(key):
        return float(np.median([abs(r[key]) for r in rows]))

    print(f"\nmedian over the stacks: reference error elsewhere {100 * med('ref err'):.2f} %; "
          f"reference median |z| {med('ref z'):.2f}; EXIF |log(C/C_true)| "
          f"{med('exif log err'):.3f} (stated σ {math.log(2) / 3:.3f}), EXIF median |z| "
          f"{med('exif z'):.2f} (0.674 for a calibrated σ); EXIF with δ = 0 (selfcal's own "
          f"part): median |log(L/L_true)| {med('exif own'):.3f}")
    print(f"\nwall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
    finish()
