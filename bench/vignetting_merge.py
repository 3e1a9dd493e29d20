"""Issue 36: the merge of handheld brackets through a vignetting lens, corners against the
centre, and σ with the vignetting's band.

Stacks: those of ``bench.vignetting`` (``make_stack``: five frames 208×306 moved by 10-12 %
and turned by up to 2°, falloff 0.5-2 stops at the farthest corner, off-centre and per
channel, JPEG q 90; tuning seeds 0…N−1, held-out 1000…1000+N−1).  Per stack,
``model = calibrate_response(images, TIMES, align="homography")`` (which fits the
vignetting), then ``merge_hdr(images, TIMES, model, align="homography",
options=MergeOptions(sigma=True, vignetting=V))`` with ``V``:

* ``"auto"`` -- the model's self-calibrated vignetting (the default);
* ``"none"`` -- the falloff left in (what a merge without this issue gives);
* the truth -- the simulator's own vignetting (the ceiling of any fit).

Truth: ``E_true = M ρ · exposure_scale`` of the reference frame's radiance
(``stack.radiance``, in reference coordinates); scored: the channels of pixels the merge
measured where some frame saw the noise-free colour between 2⁻⁸ and 0.9 of white and the
gamut map left it unchanged.  After one global scale (``bench.metrics.global_scale``), the
median ``|s·E/E_true − 1|`` at the centre (r < 0.3 of the half-diagonal) and at the corners
(r > 0.8); the issue's figure is their ratio (target ≤ 1.2 with vignetting on), per stack
and its median; the corner's bias (median signed error at the corners minus the
centre's), what the falloff leaves when the noise is taken out; and σ's calibration, the median ``|s·E − E_true| / (s·σ)`` over the scored
channels (0.674 for a perfect Gaussian σ; target 0.6-0.8).

    python3 -m bench.vignetting_merge --split held-out|tuning [--stacks 20] [--jobs 2]
"""

from __future__ import annotations

import time

import numpy as np

from .metrics import global_scale
from .tables import finish, table
from .vignetting import TIMES, make_stack, stacks_of_split

CENTRE, CORNER = 0.3, 0.8
FLOOR, CEILING = 2.0 ** -8, 0.9


def truth(stack):
    """``E_true`` (reference frame) and the channels some frame measures noise-free."""
    pipe = stack.pipeline
    e_true = (stack.radiance.astype(np.float64) @ pipe.matrix.T) * stack.exposure_scale
    scored = np.zeros(e_true.shape, bool)
    for t in stack.true_exposures:
        x = e_true * float(t)
        in_gamut = np.abs(pipe.apply_gamut(x) - x).max(axis=2) <= 1e-6
        scored |= in_gamut[..., None] & (x >= FLOOR) & (x.max(axis=2, keepdims=True) <= CEILING)
    return e_true, scored


def radius(h: int, w: int) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w]
    return np.hypot(xx - (w - 1) / 2, yy - (h - 1) / 2) / (0.5 * np.hypot(h, w))


def scores(result, e_true, scored) -> dict:
    keep = scored & ~result.unmeasured[..., None] & np.isfinite(result.radiance)
    s = global_scale(result.radiance, e_true, keep)
    signed = s * result.radiance / e_true - 1
    err = np.abs(signed)
    r = np.repeat(radius(*e_true.shape[:2])[..., None], 3, axis=2)
    centre = float(np.median(err[keep & (r < CENTRE)]))
    corner = float(np.median(err[keep & (r > CORNER)]))
    bias = float(np.median(signed[keep & (r > CORNER)]) - np.median(signed[keep & (r < CENTRE)]))
    sig = np.asarray(result.sigma, np.float64)
    ok = keep & np.isfinite(sig) & (sig > 0)
    z = float(np.median(np.abs(s * result.radiance[ok] - e_true[ok]) / (s * sig[ok])))
    return {"centre": centre, "corner": corner, "ratio": corner / centre, "z": z, "bias": bias,
            "all": float(np.median(err[keep]))}


def one_stack(seed: int) -> dict:
    import selfcal
    from selfcal.hdr.merge import MergeOptions

    t0 = time.perf_counter()
    stack = make_stack(seed)
    times = list(TIMES)
    model = selfcal.calibrate_response(stack.images, times, align="homography")
    e_true, scored = truth(stack)
    out = {"seed": seed, "observable": model.vignetting is not None}
    for name, choice in (("auto", "auto"), ("none", "none"), ("truth", stack.vignetting)):
        result = selfcal.merge_hdr(stack.images, times, model, align="homography",
                                   options=MergeOptions(sigma=True, vignetting=choice))
        out[name] = scores(result, e_true, scored)
    out["seconds"] = time.perf_counter() - t0
    return out


def main():
    args, results = stacks_of_split("vignetting_merge", __doc__.splitlines()[0], one_stack)
    print(f"{len(results)} handheld stacks through a vignetting lens ({args.split} split), "
          "merged with align='homography' and σ; radiance error after one global scale\n")
    rows = []
    for r in results:
        rows.append([r["seed"], "yes" if r["observable"] else "no"]
                    + [f"{r[k]['centre']:.4f} / {r[k]['corner']:.4f} ({r[k]['ratio']:.2f}×)"
                       for k in ("auto", "none", "truth")]
                    + [f"{r['auto']['z']:.3f}", f"{r['seconds']:.0f}"])
    print(table(["seed", "fitted", "auto: centre / corner (ratio)",
                 "none: centre / corner (ratio)", "true V: centre / corner (ratio)",
                 "σ median |z| (auto)", "s"], rows))

    def med(arm, key):
        return float(np.median([r[arm][key] for r in results]))

    print("\nmedians over the stacks:\n")
    print(table(["vignetting", "centre error", "corner error",
                 "corner / centre (target ≤ 1.2)", "corner bias (median signed, minus the "
                 "centre's)", "all pixels", "σ median |z| (0.6-0.8)"],
                [[arm, f"{med(arm, 'centre'):.4f}", f"{med(arm, 'corner'):.4f}",
                  f"{med(arm, 'ratio'):.2f}", f"{med(arm, 'bias'):+.4f}",
                  f"{med(arm, 'all'):.4f}", f"{med(arm, 'z'):.3f}"]
                 for arm in ("auto", "none", "truth")]))
    print("\nThe true falloff's row is the floor of any vignetting model: a corner gets "
          "0.5-2 stops less light (more noise) and fewer frames (the others' footprints "
          "leave it); the bias column is what the falloff itself leaves.")
    finish()


if __name__ == "__main__":
    main()
