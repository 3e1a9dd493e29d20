"""The measured reach of JPEG damage next to clipped areas (selfcal.response.white_end)."""

from __future__ import annotations

import numpy as np

from selfcal.response.white_end import ringing_reach


def _rows(bias_at, noise_at=(), n=400, seed=0):
    rng = np.random.default_rng(seed)
    distance = np.concatenate([np.full(n, d, float) for d in range(1, 7)] + [np.full(4 * n, 20.0)])
    level = rng.uniform(0, 1, distance.size)
    residual = rng.normal(0, 1.5, distance.size)
    for d in bias_at:
        residual[distance == d] -= 4.0        # codes pulled down next to the clip
    for d in noise_at:
        residual[distance == d] *= 3.0       # only noisier
    return residual, distance, level


def test_biased_rows_next_to_the_clip_set_the_reach():
    assert ringing_reach(*_rows(bias_at=(1, 2))) == 2
    assert ringing_reach(*_rows(bias_at=(1,))) == 1


def test_clean_or_only_noisier_rows_give_no_reach():
    assert ringing_reach(*_rows(bias_at=())) == 0
    assert ringing_reach(*_rows(bias_at=(), noise_at=(1,))) == 0
