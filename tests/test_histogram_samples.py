"""Histogram-matched correspondences ([Grossberg2003]) against the simulator's truth."""

from __future__ import annotations

import numpy as np

from selfcal import sim
from selfcal.response import calibrate as cal
from selfcal.response.histogram_samples import histogram_correspondences, transfer_points
from selfcal.stack.samples import KeptData, collect_samples
from selfcal.sim.exact import EXACT_CONDITIONS

CURVE = sim.ToneCurve.film(contrast=1.1, toe=0.05, shoulder=0.85)


def test_transfer_points_of_a_known_map_without_noise():
    rng = np.random.default_rng(0)
    xa = rng.integers(0, 200, 20000).astype(np.float32)
    xb = np.clip(np.round(xa * 1.25), 0, 255).astype(np.float32)   # T(I) = 1.25 I
    ia, ib, count = transfer_points(xa, xb, 255)
    ok = (ia > 5) & (ia < 195) & (ib < 250)
    assert np.median(np.abs(ib[ok] - 1.25 * ia[ok])) < 0.5
    assert count.min() >= 1


def _stack():
    return EXACT_CONDITIONS["exact/neutral"].simulate(CURVE, seed=4, size=(120, 160))


def test_points_follow_the_true_curve():
    stack = _stack()
    s = collect_samples(stack.images, keep=KeptData(reduced=True))
    hs = histogram_correspondences(s.reduced)
    g = np.log(np.maximum(stack.inverse_response()[:, 1], 1e-6))
    logk = np.log(stack.true_exposures)
    res = []
    for k in range(hs.n_samples):
        a, b = hs.pair[k]
        if hs.clipped[b, k] or hs.weights[k, 1] == 0:
            continue
        ia, ib = hs.values[a, k, 1] * 255, hs.values[b, k, 1] * 255
        if ia < 20:          # the noisy floor: checked by the fit below
            continue
        r = np.interp(ib, np.arange(256), g) - np.interp(ia, np.arange(256), g)
        res.append(r - (logk[b] - logk[a]))
    assert len(res) > 300
    assert abs(np.median(res)) < 0.02 and np.median(np.abs(res)) < 0.04


def test_calibration_on_histograms_is_close_to_the_truth():
    stack = _stack()
    model = cal.calibrate_response(stack.images, list(stack.exposure_times),
                                   options=cal.ResponseOptions(correspondences="histogram"))
    lut, truth = model.inverse_response(), stack.inverse_response()
    assert np.all(np.diff(lut, axis=0) >= 0)
    for c in range(3):
        t, l = truth[1:255, c], lut[1:255, c]
        s = (t @ l) / (l @ l)
        assert np.sqrt(np.mean((s * l - t) ** 2)) < 0.015
