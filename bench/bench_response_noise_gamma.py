"""Issue 25: does the noise of an 8-bit stack pin the exponent γ that Eq. 8 leaves free?

With fewer than two known exposure times, Eq. 8 of Lin et al. (ICCV 2011, §5) fixes f⁻¹
only up to an exponent: F^s with exposure ratios k^s fits the pixels as well as F for any
s.  The frame-to-frame transfer functions τ are the same for every s, so histograms and
correspondences cannot choose it ([Grossberg2003], the PAMI paper); the sensor noise could:
shot noise has variance ∝ the linear signal, so in code units its variance at code I is
α F(I)^s / (F^s)'(I)², a shape that changes with s.  This script asks whether that shape
can be read off a stack in the most favourable case -- the *true* F and the true exposures
give τ exactly, so that the residuals r = I_b − τ(I_a) of adjacent frames are noise and
JPEG error only:

- per adjacent frame pair, channel and 6-code bin of I_a (pixels unclipped in all channels
  of both frames, bins of ≥ 200 pixels), the robust variance of r (MAD²);
- for each s in 0.60 … 1.60, the model var(r) = α·shot_s + β·read_s + q·(1 + τ'²) (shot,
  read and code-domain noise of both frames through F^s; α, β, q ≥ 0 by non-negative
  least squares on relative errors) and its residual norm.

A usable γ estimate needs the norm to rise clearly away from s = 1.  Printed per curve:
the s of the least norm, the norm at s = 1 and the largest norm over the scan, both
relative to the least.

    python bench/bench_response_noise_gamma.py [--split tuning|held-out] [--jpeg 90|0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table  # noqa: E402

from selfcal import sim  # noqa: E402

S = np.round(np.arange(0.6, 1.601, 0.05), 2)
TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]
CODES = np.arange(256) / 255.0


def bin_variances(stack, F):
    """Rows (channel, I_a, I_b, k, pixels, robust var of r in code²) per pair, channel, bin."""
    K = np.log(stack.true_exposures)
    out = []
    for a in range(len(TIMES) - 1):
        k = np.exp(K[a + 1] - K[a])
        Ia = stack.images[a].reshape(-1, 3).astype(float) / 255
        Ib = stack.images[a + 1].reshape(-1, 3).astype(float) / 255
        ok = ((np.minimum(Ia.min(1), Ib.min(1)) > 4 / 255)
              & (np.maximum(Ia.max(1), Ib.max(1)) < 250 / 255))
        for c in range(3):
            ia, ib = Ia[ok, c], Ib[ok, c]
            tau = np.interp(k * np.interp(ia, CODES, F[:, c]), F[:, c], CODES)
            r = (ib - tau) * 255
            idx = np.digitize(ia, np.arange(4, 251, 6) / 255)
            for j in np.unique(idx):
                sel = idx == j
                if sel.sum() < 200:
                    continue
                mad = np.median(np.abs(r[sel] - np.median(r[sel])))
                out.append((c, np.median(ia[sel]), np.median(ib[sel]), k, sel.sum(),
                            (1.4826 * mad) ** 2))
    return np.array(out)


def norms(rows, F):
    """The NNLS residual norm of the noise model for every s of the scan."""
    out = []
    for s in S:
        A, y = [], []
        for c, ia, ib, k, n, v in rows:
            h = F[:, int(c)] ** s
            dh = np.gradient(h, CODES) / 255                  # per code
            ha, hb = np.interp(ia, CODES, h), np.interp(ib, CODES, h)
            da, db = np.interp(ia, CODES, dh), np.interp(ib, CODES, dh)
            tp = k ** s * da / db                             # τ'(I_a), the same for every s
            w = np.sqrt(n) / v
            A.append(w * np.array([hb / db ** 2 + tp ** 2 * ha / da ** 2,
                                   1 / db ** 2 + tp ** 2 / da ** 2, 1 + tp ** 2]))
            y.append(w * v)
        A = np.array(A)
        scale = A.max(axis=0)
        out.append(nnls(A / scale, np.array(y))[1])
    return np.array(out)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("tuning", "held-out"), default="tuning")
    parser.add_argument("--jpeg", type=int, default=90, help="JPEG quality; 0: no JPEG")
    args = parser.parse_args()
    seed = 1 if args.split == "tuning" else 1001
    curves = [sim.ToneCurve.srgb(), sim.ToneCurve.rec709(), sim.ToneCurve.gamma(1.8),
              sim.ToneCurve.gamma(2.2), sim.ToneCurve.film()]
    rows = []
    for curve in curves:
        pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=seed)
        stack = sim.simulate_stack(sim.make_scene(384, 576, seed=seed), pipe, TIMES,
                                   jitter=0.03, jpeg_quality=args.jpeg or None, seed=seed)
        F = stack.inverse_response()
        r = norms(bin_variances(stack, F), F)
        rows.append([curve.name, f"{S[int(np.argmin(r))]:.2f}",
                     f"{r[S == 1.0][0] / r.min():.3f}", f"{r.max() / r.min():.3f}"])
    print(f"{args.split} split (scene seed {seed}), JPEG {args.jpeg or 'off'}: noise-model "
          f"residual norm over s = {S[0]:.2f} … {S[-1]:.2f} (true F and exposures)\n")
    print(table(["curve", "s of least norm", "norm at s = 1 / least", "largest / least"],
                rows))


if __name__ == "__main__":
    main()
