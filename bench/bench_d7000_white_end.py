"""How much of the D7000 absolute target (issue 15) hangs on the top codes.

The absolute metric scores f⁻¹ with f⁻¹(255) = 1 against the NUS Nikon D7000 model's own
tone curve (``../shared/data/nus_model_nikon_d7000``, white balance 14).  That curve climbs
from about 0.82 to 1 over its last three codes.  In a JPEG stack those codes are the ones
nearest clipping: the calibration leaves codes within ``clip_margin`` (2) of 255 out, and
JPEG moves codes there by one or two.

The oracle here knows the true f⁻¹ exactly up to code K, continues it to 255 with the slope
of its last four known codes (the steepest local trend, kinder than anything a smooth
basis would do), and is normalised so that its f⁻¹(255) = 1, as every method must be.
What it scores, absolute and at best scale (codes 1..254, mean over R, G, B), is the floor
for any method that does not measure f⁻¹ above code K.  Also printed: how far f⁻¹ moves
for one code near white (what one code of JPEG error costs there).

    python bench/bench_d7000_white_end.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED_DATA, table  # noqa: E402

NUS = SHARED_DATA / "nus_model_nikon_d7000"
INNER = slice(1, 255)


def oracle(truth: np.ndarray, known_to: int) -> np.ndarray:
    """The truth through code ``known_to``, continued linearly with the slope of its last
    four codes, scaled so that f⁻¹(255) = 1."""
    ext = truth.copy()
    slope = (truth[known_to] - truth[known_to - 4]) / 4.0
    steps = np.arange(1, 256 - known_to)[:, None]
    ext[known_to + 1:] = truth[known_to] + slope * steps
    return ext / ext[255]


def main():
    from selfcal.sim.scoring import best_scale_rmse, rmse
    from selfcal.pipeline.nus import read_nus_model

    if not NUS.is_dir():
        print(f"skipped: {NUS} is absent")
        return
    truth = np.asarray(read_nus_model(NUS, wb_code=14).inverse_response, dtype=float)
    print("NUS D7000 (wb 14) true f⁻¹ near white, mean of R, G, B, and its step per code")
    codes = range(244, 256)
    print(table(["code"] + [str(c) for c in codes],
                [["f⁻¹"] + [f"{truth[c].mean():.3f}" for c in codes],
                 ["step"] + [f"{truth[c].mean() - truth[c - 1].mean():.3f}" for c in codes]]))
    rows = []
    for k in (254, 253, 252, 251, 250, 248, 245):
        est = oracle(truth, k)
        absolute = np.mean([rmse(est[INNER, c], truth[INNER, c]) for c in range(3)])
        best = np.mean([best_scale_rmse(est[INNER, c], truth[INNER, c]) for c in range(3)])
        rows.append([k, f"{truth[k].mean():.3f}", f"{absolute:.4f}", f"{best:.4f}",
                     "yes" if absolute <= 0.012 else "no", "yes" if best <= 0.006 else "no"])
    print()
    print("oracle: the truth known exactly up to code K, continued linearly, f⁻¹(255) = 1")
    print(table(["K (last known code)", "true f⁻¹(K)", "absolute RMSE", "best-scale RMSE",
                 "absolute ≤ 0.012", "best-scale ≤ 0.006"], rows))


if __name__ == "__main__":
    main()
