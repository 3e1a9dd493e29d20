"""The curve's error per code level (selfcal.response.code_error) and what the merge makes
of it: recovered from rows of known spread, kept in the model file, and lowering the
weights of the codes where it exceeds the noise model."""

from __future__ import annotations

import warnings

import numpy as np

import selfcal
from selfcal import sim
from selfcal.hdr.weights import DEFAULT_NOISE, FrameTables
from selfcal.response.code_error import LEVELS, _solve_levels, code_error_at
from selfcal.stack.frames import Lineariser


def test_levels_recovered_from_rows_of_known_spread():
    """Rows whose residual has variance s_a² + s_b² (the two codes' errors): the solve
    gives back each bin's s."""
    rng = np.random.default_rng(0)
    s_true = 0.01 + 0.04 * np.linspace(0, 1, LEVELS) ** 4     # worse towards white
    n = 200_000
    ba = rng.integers(0, LEVELS, n)
    bb = np.minimum(ba + rng.integers(0, 4, n), LEVELS - 1)   # neighbours in exposure
    r = rng.normal(0.0, np.sqrt(s_true[ba] ** 2 + s_true[bb] ** 2))
    s = _solve_levels(ba, bb, r)
    assert np.all(np.isfinite(s))
    np.testing.assert_allclose(s, s_true, rtol=0.15)


def test_unreached_levels_take_the_nearest_reached_one():
    rng = np.random.default_rng(1)
    ba = rng.integers(4, 8, 5000)
    r = rng.normal(0.0, 0.02 * np.sqrt(2), ba.size)
    s = _solve_levels(ba, ba, r)
    np.testing.assert_allclose(s[:4], s[4], rtol=1e-12)
    np.testing.assert_allclose(s[8:], s[7], rtol=1e-12)
    np.testing.assert_allclose(s[4:8], 0.02, rtol=0.15)


def test_profile_in_the_model_and_its_file(tmp_path):
    demo = sim.demo_stack(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = selfcal.calibrate_response(demo.images, list(demo.exposure_times))
    prof = model.diagnostics["code_error_log"]
    assert len(prof["levels"]) == LEVELS and np.shape(prof["sigma"]) == (LEVELS, 3)
    assert prof["block"] >= 1
    s = np.asarray(prof["sigma"])
    assert np.all(s >= 0) and np.all(s < 0.5)
    model.save(tmp_path / "m.json")
    back = selfcal.load_model(tmp_path / "m.json")
    np.testing.assert_allclose(code_error_at(back.diagnostics["code_error_log"], 255),
                               code_error_at(prof, 255))


class _Model:
    """A gamma-2.2 inverse response with a given code-error profile."""

    def __init__(self, profile):
        self.diagnostics = {"code_error_log": profile}

    def inverse_response(self, codes):
        z = np.asarray(codes, float) / 255.0
        return np.repeat((z ** 2.2)[:, None], 3, axis=1)


def _weights(profile):
    lin = Lineariser(_Model(profile), False, 255)
    tab = FrameTables(lin, 1.0, "noise", DEFAULT_NOISE, 2.0, 253.0, False)
    return tab.w_table[:, 1].astype(float), tab


def test_weights_fall_where_the_curve_is_worse_than_the_noise():
    levels = ((np.arange(LEVELS) + 0.5) / LEVELS).tolist()
    flat = {"levels": levels, "sigma": [[1e-4] * 3] * LEVELS, "block": 1}
    top = np.full(LEVELS, 1e-4)
    top[-2:] = 0.1                                  # the two brightest bins: 10 %
    worse = {"levels": levels, "sigma": [[v] * 3 for v in top], "block": 1}
    w0, tab0 = _weights(None)
    w1, _ = _weights(flat)
    w2, tab2 = _weights(worse)
    assert tab0.code_error is None
    # an error the noise model explains already changes nothing ...
    np.testing.assert_allclose(w1, w0, rtol=1e-6)
    # ... one beyond it lowers the weights there, and only there
    assert np.all(w2[245:253] < 0.3 * w0[245:253])
    np.testing.assert_allclose(w2[10:200], w0[10:200], rtol=1e-6)
    assert np.all(tab2.code_error[:200] == 0)
