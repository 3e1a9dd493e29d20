"""Issues 3 and 25: where the basis prior centres the exponent γ when no exposure time is known.

With fewer than two known times, Eq. 8 of Lin et al. (ICCV 2011) determines f⁻¹ only up to
an exponent γ (§5): (f⁻¹)^γ with times γ · log t fits the pixels as well as f⁻¹.  selfcal
then leans on its PCA-variance prior on the coefficients, c_n ~ N(μ_n, λ_n / w).  This
script fits (f⁻¹)^γ of common encodings with the built-in basis (N = 5, as the solver) and
prints the γ at which the prior's energy Σ (c_n − μ_n)² / λ_n is lowest, and that energy
relative to γ = 1: the exponent the prior prefers when the data cannot choose.

``--centres`` (issue 25) compares centres μ of the prior: 0 (the basis mean, the prior of
every solve), the library's :func:`selfcal.response.priors.ambiguity_centre` (used when
fewer than two different times are known), power laws of a few exponents, and the mean
coefficients of the DoRF curves of the *other* half (computed here from the shared data,
never stored), on the common encodings and on the DoRF curves of ``--split``: how many of
them get a least-energy γ within 0.9 … 1.1.

    python bench/bench_response_prior_gamma.py
    python bench/bench_response_prior_gamma.py --centres --split tuning
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import data_dir, table  # noqa: E402

from selfcal import sim  # noqa: E402
from selfcal.response.basis import builtin_basis  # noqa: E402

N = 5
GAMMAS = np.round(np.arange(0.40, 1.501, 0.02), 2)
WINDOW = (0.9, 1.1)


def _coefficients(basis, inverse):
    """The basis coefficients of (f⁻¹)^γ for every γ of the scan, shape (γ, N)."""
    grid = basis.intensity
    return np.array([basis.fit_inverse_response(grid, inverse ** g, N) for g in GAMMAS])


def least_energy_gamma(coeffs, centre, variance):
    """The γ of the scan whose coefficients are least costly under N(centre, variance)."""
    energy = np.sum((coeffs - centre) ** 2 / variance, axis=1)
    return GAMMAS[int(np.argmin(energy))], energy


def common_curves():
    return [sim.ToneCurve.srgb(), sim.ToneCurve.rec709(), sim.ToneCurve.gamma(1.8),
            sim.ToneCurve.gamma(2.2), sim.ToneCurve.film()]


def dorf_inverses(basis, split):
    """f⁻¹ on the basis grid of the DoRF curves of a split: even indices (tuning) or odd."""
    import scipy.io as sio

    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    start = 0 if split == "tuning" else 1
    grid = basis.intensity
    out = []
    for i in range(start, mat["I"].shape[0], 2):
        out.append(sim.ToneCurve.from_table(mat["I"][i], mat["B"][i]).inverse(grid))
    return out


def baseline_table(basis, variance):
    rows = []
    for curve in common_curves():
        gamma, energy = least_energy_gamma(_coefficients(basis, curve.inverse(basis.intensity)),
                                           np.zeros(N), variance)
        at_one = energy[np.flatnonzero(GAMMAS == 1.0)[0]]
        edge = " (edge of the scan)" if gamma in (GAMMAS[0], GAMMAS[-1]) else ""
        rows.append([curve.name, f"{gamma:.2f}{edge}", f"{energy.min() / at_one:.2f}"])
    print(f"Prior energy Σ c_n² / λ_n of the best {N}-component fit of (f⁻¹)^γ, γ in "
          f"{GAMMAS[0]:.2f} … {GAMMAS[-1]:.2f}\n")
    print(table(["curve", "γ of least prior energy", "its energy / energy at γ = 1"], rows))


def centres_table(basis, variance, split):
    from selfcal.response.priors import ambiguity_centre

    grid = basis.intensity
    other = "held-out" if split == "tuning" else "tuning"
    dorf_other = dorf_inverses(basis, other)
    centres = {"0 (basis mean)": np.zeros(N),
               "library ambiguity_centre": ambiguity_centre(basis, N)}
    for p in (1.8, 2.0, 2.2, 2.4):
        centres[f"gamma {p}"] = basis.fit_inverse_response(grid, grid ** p, N)
    centres[f"mean of DoRF {other} half"] = np.mean(
        [basis.fit_inverse_response(grid, inv, N) for inv in dorf_other], axis=0)
    common = [(c.name, _coefficients(basis, c.inverse(grid))) for c in common_curves()]
    dorf = [_coefficients(basis, inv) for inv in dorf_inverses(basis, split)]
    rows = []
    for name, mu in centres.items():
        g_common = [least_energy_gamma(co, mu, variance)[0] for _, co in common]
        g_dorf = np.array([least_energy_gamma(co, mu, variance)[0] for co in dorf])
        inside = np.mean((g_dorf >= WINDOW[0]) & (g_dorf <= WINDOW[1]))
        rows.append([name, *(f"{g:.2f}" for g in g_common),
                     f"{np.median(g_dorf):.2f}",
                     f"{np.percentile(g_dorf, 10):.2f} … {np.percentile(g_dorf, 90):.2f}",
                     f"{100 * inside:.0f} %"])
    print(f"\n{split} split: γ of least prior energy Σ (c_n − μ_n)² / λ_n per centre μ "
          f"({len(dorf)} DoRF curves of the split)\n")
    print(table(["centre μ", *(n for n, _ in common), "DoRF median", "DoRF p10 … p90",
                 f"DoRF in {WINDOW[0]} … {WINDOW[1]}"], rows))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--centres", action="store_true",
                        help="compare prior centres on the common encodings and DoRF")
    parser.add_argument("--split", choices=("tuning", "held-out"), default="tuning")
    args = parser.parse_args()
    basis = builtin_basis()
    variance = np.asarray(basis.explained_variance[:N], dtype=float)
    if args.centres:
        centres_table(basis, variance, args.split)
    else:
        baseline_table(basis, variance)


if __name__ == "__main__":
    main()
