"""Issue 3: where the basis prior centres the exponent γ when no exposure time is known.

With fewer than two known times, Eq. 8 of Lin et al. (ICCV 2011) determines f⁻¹ only up to
an exponent γ (§5): (f⁻¹)^γ with times γ · log t fits the pixels as well as f⁻¹.  selfcal
then leans on its PCA-variance prior on the coefficients, c_n ~ N(0, λ_n / w).  This
script fits (f⁻¹)^γ of common encodings with the built-in basis (N = 5, as the solver) and
prints the γ at which the prior's energy Σ c_n² / λ_n is lowest, and that energy
relative to γ = 1: the exponent the prior prefers when the data cannot choose.

    python bench/bench_response_prior_gamma.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table  # noqa: E402

from selfcal import sim  # noqa: E402
from selfcal.response.basis import builtin_basis  # noqa: E402

N = 5
GAMMAS = np.round(np.arange(0.40, 1.501, 0.02), 2)


def main():
    basis = builtin_basis()
    variance = np.asarray(basis.explained_variance[:N], dtype=float)
    grid = basis.intensity
    curves = [sim.ToneCurve.srgb(), sim.ToneCurve.rec709(), sim.ToneCurve.gamma(1.8),
              sim.ToneCurve.gamma(2.2), sim.ToneCurve.film()]
    rows = []
    for curve in curves:
        inverse = curve.inverse(grid)
        energy = np.array([np.sum(basis.fit_inverse_response(grid, inverse ** g, N) ** 2
                                  / variance) for g in GAMMAS])
        best = int(np.argmin(energy))
        at_one = energy[np.flatnonzero(GAMMAS == 1.0)[0]]
        edge = " (edge of the scan)" if best in (0, len(GAMMAS) - 1) else ""
        rows.append([curve.name, f"{GAMMAS[best]:.2f}{edge}",
                     f"{energy[best] / at_one:.2f}"])
    print(f"Prior energy Σ c_n² / λ_n of the best {N}-component fit of (f⁻¹)^γ, γ in "
          f"{GAMMAS[0]:.2f} … {GAMMAS[-1]:.2f}\n")
    print(table(["curve", "γ of least prior energy", "its energy / energy at γ = 1"], rows))


if __name__ == "__main__":
    main()
