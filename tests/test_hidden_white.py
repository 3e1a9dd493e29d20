"""Samples the first fit predicts at white count as clipped (selfcal.response.hidden_white)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

import selfcal
from selfcal.response import ResponseOptions
from selfcal.response.hidden_white import hidden_white_mask
from selfcal.sim import ToneCurve
from selfcal.sim.exact import EXACT_CONDITIONS


def test_a_sample_predicted_beyond_white_is_clipped_there_and_brighter():
    # a linear curve, three frames one stop apart; sample 0 at 0.6 in frame 0 is predicted
    # at 1.2 in frame 1 (read 0.97 there: JPEG moved a white area below the limit)
    grid = np.linspace(0.0, 1.0, 1001)
    inverse = np.repeat(np.maximum(grid, 1e-6)[:, None], 3, axis=1)
    values = np.array([[[0.60] * 3, [0.30] * 3, [0.20] * 3],
                       [[0.97] * 3, [0.60] * 3, [0.40] * 3],
                       [[0.98] * 3, [0.97] * 3, [0.80] * 3]])
    samples = SimpleNamespace(values=values, max_code=255)
    result = SimpleNamespace(log_exposures=np.log([1.0, 2.0, 4.0]),
                             pair_frames=np.array([(0, 1), (1, 2), (0, 2)]))
    valid = np.ones((3, 3), bool)
    white = hidden_white_mask(samples, valid, result, grid, inverse)
    assert white.tolist() == [[False, False, False],
                              [True, False, False],     # 0.6 × 2
                              [True, True, False]]      # propagated; 0.6 × 2 = 1.2
    # only where valid: a sample the masks already reject is not counted again
    valid[2, 0] = False
    assert not hidden_white_mask(samples, valid, result, grid, inverse)[2, 0]


def _top_error(model, truth) -> float:
    """Worst channel's RMSE of f⁻¹ over codes 245 … 254, after the best scale on 1 … 254."""
    lut = model.inverse_response()
    worst = 0.0
    for c in range(3):
        est, tru = lut[1:255, c], truth[1:255, c]
        s = float(est @ tru / (est @ est))
        worst = max(worst, float(np.sqrt(np.mean((s * est[244:] - tru[244:]) ** 2))))
    return worst


def test_the_top_of_the_curve_against_the_simulators_truth():
    # per-channel-exact stack (no colour matrix), a film curve, JPEG 4:2:0: white patches
    # the encoder moved below the clip limit read as valid samples; without the test the
    # top codes' error was 0.050 (worst channel), the whole curve's 0.013
    stack = EXACT_CONDITIONS["exact/saturated"].simulate(ToneCurve.film(), 0, size=(150, 200))
    truth = stack.inverse_response()
    model = selfcal.calibrate_response(stack.images, list(stack.exposure_times))
    assert model.diagnostics["hidden_white_samples"] > 0
    assert _top_error(model, truth) < 0.015
    off = selfcal.calibrate_response(stack.images, list(stack.exposure_times),
                                     options=ResponseOptions(hidden_white=False))
    assert off.diagnostics["hidden_white_samples"] == 0
    assert _top_error(off, truth) > 2 * _top_error(model, truth)
