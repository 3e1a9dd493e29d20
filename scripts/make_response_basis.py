#!/usr/bin/env python3
"""Build selfcal's built-in log-domain PCA response basis (``selfcal/data/response_basis.npz``).

The model is Lin, Kim, Süsstrunk & Brown, ICCV 2011, §5, Eq. 7:
``g(I) = log f^-1(I) = g0(I) + sum_n h_n(I) c_n``.  Lin et al. (after Grossberg & Nayar's
EMoR) take the PCA from the DoRF database, which may not be redistributed; this script
computes it instead from the documented curve family in
:mod:`selfcal.response.curve_family`:

1. draw ``N_CURVES`` forward responses with a fixed seed;
2. invert each onto 1024 evenly spaced intensities on [0, 1] (``f^-1(1) = 1``);
3. floor at ``LOG_FLOOR`` and take the log; weighted PCA with per-intensity weights
   ``(rms f^-1 + WEIGHT_OFFSET)^2`` (see :mod:`selfcal.response.basis`, *The dark end*);
4. keep ``N_COMPONENTS`` components and write the .npz (byte-reproducible).

It reads nothing outside the repository.  Running it twice gives identical files.

Usage::

    python scripts/make_response_basis.py --force          # rewrite the shipped file
    python scripts/make_response_basis.py -o /tmp/b.npz --n-curves 500
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from selfcal.response.basis import ResponseBasis, log_pca_basis  # noqa: E402
from selfcal.response.curve_family import generate_inverse_curves  # noqa: E402

N_CURVES = 6000
SEED = 20110101
N_COMPONENTS = 25
N_INTENSITY = 1024
LOG_FLOOR = 1e-5
WEIGHT_OFFSET = 0.05
OUTPUT = REPO / "selfcal" / "data" / "response_basis.npz"


def make_basis(n_curves: int = N_CURVES, seed: int = SEED,
               n_components: int = N_COMPONENTS) -> ResponseBasis:
    """Generate the curve database and return its weighted log-domain PCA basis."""
    intensity, inverse, _ = generate_inverse_curves(
        n_curves, intensity=np.linspace(0.0, 1.0, N_INTENSITY), seed=seed)
    description = (
        f"selfcal log-domain PCA response basis (Lin et al. ICCV 2011 Eq. 7) from "
        f"{n_curves} curves of selfcal.response.curve_family, seed {seed}; "
        f"log floor {LOG_FLOOR:g}, weights (rms f^-1 + {WEIGHT_OFFSET:g})^2; "
        f"made by scripts/make_response_basis.py; contains no DoRF/EMoR data"
    )
    return log_pca_basis(intensity, inverse, n_components, log_floor=LOG_FLOOR,
                         weight_offset=WEIGHT_OFFSET, name="selfcal built-in",
                         description=description)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", type=Path, default=OUTPUT)
    ap.add_argument("--n-curves", type=int, default=N_CURVES)
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--n-components", type=int, default=N_COMPONENTS)
    ap.add_argument("--force", action="store_true", help="overwrite an existing output file")
    args = ap.parse_args(argv)
    basis = make_basis(args.n_curves, args.seed, args.n_components)
    path = basis.save(args.output, force=args.force)
    ev = basis.explained_variance
    share = np.cumsum(ev) / ev.sum()
    print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): {basis.n_components} "
          f"components; cumulative weighted variance at N=3..6: "
          + ", ".join(f"{share[k]:.4f}" for k in range(2, min(6, len(share)))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
