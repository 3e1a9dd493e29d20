"""Confidence bands on f⁻¹ (selfcal.response.bands): coverage of the truth, the model file."""

from __future__ import annotations

import json

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.errors import InputError, ModelFileError

TIMES = list(sim.DEMO_EXPOSURE_TIMES)


@pytest.fixture(scope="module")
def stack():
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=3)
    scene = sim.make_scene(192, 288, saturation=0.5, seed=3)
    return sim.simulate_stack(scene, pipe, TIMES, jitter=0.03, jpeg_quality=90, seed=3)


@pytest.fixture(scope="module")
def model(stack):
    return selfcal.calibrate_response(stack.images, TIMES)


def test_band_shape_and_order(model):
    lower, upper = model.inverse_band(0.9)
    assert lower.shape == upper.shape == model.inverse.shape
    assert np.all(lower <= model.inverse) and np.all(model.inverse <= upper)
    np.testing.assert_allclose([lower[-1], upper[-1]], 1.0)   # f⁻¹(1) = 1, no spread
    lo50, up50 = model.inverse_band(0.5)
    assert np.all(up50 - lo50 <= upper - lower)
    with pytest.raises(ValueError):
        model.inverse_band(1.5)


def test_band_covers_the_truth(model, stack):
    # the 90 % band should hold the true f⁻¹ on most codes; a band that is all bias and
    # no spread (or ten times too wide) fails
    truth = stack.inverse_response()
    lower, upper = model.band_at_codes(np.arange(256))
    inner = slice(1, 255)
    covered = np.mean((truth[inner] >= lower[inner]) & (truth[inner] <= upper[inner]))
    assert covered >= 0.7
    body = slice(26, 230)
    half = np.median((upper - lower)[body] / (2 * model.inverse_response()[body]))
    assert 0.01 < half < 0.15


def test_band_is_deterministic(stack, model):
    again = selfcal.calibrate_response(stack.images, TIMES)
    np.testing.assert_array_equal(again.inverse_log_sigma, model.inverse_log_sigma)


def test_band_round_trip(model, tmp_path):
    path = model.save(tmp_path / "m.json")
    doc = json.loads(path.read_text())
    assert doc["version"] == 3 and len(doc["inverse_log_sigma"]) == 3
    loaded = selfcal.load_model(path)
    np.testing.assert_allclose(loaded.inverse_band()[0], model.inverse_band()[0], rtol=1e-6)
    assert "band_width_90" in loaded.diagnostics["verdict_evidence"]


def test_version_1_file_loads_without_band(model, tmp_path):
    doc = json.loads(model.save(tmp_path / "m.json").read_text())
    doc["version"] = 1
    del doc["inverse_log_sigma"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    loaded = selfcal.load_model(old)
    assert loaded.inverse_log_sigma is None
    with pytest.raises(InputError, match="no confidence band"):
        loaded.inverse_band()
    np.testing.assert_allclose(loaded.inverse, model.inverse)


def test_negative_band_is_refused(model, tmp_path):
    doc = json.loads(model.save(tmp_path / "m.json").read_text())
    doc["inverse_log_sigma"][0][3] = -0.1
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="inverse_log_sigma"):
        selfcal.load_model(bad)


def test_default_band_is_the_covariance(stack):
    from selfcal.response import bands

    model = selfcal.calibrate_response(stack.images, TIMES)
    assert bands.DEFAULT_BAND_METHOD == "covariance"
    # the two estimates of the statistical part differ, but not by an order of magnitude
    assert np.all(np.isfinite(model.inverse_log_sigma))


def test_too_wide_band_is_a_verdict_reason():
    from selfcal.response import bands

    grid = np.linspace(0, 1, 11)
    inverse = np.tile(grid[:, None] ** 2.2, (1, 3))
    sigma = np.full((11, 3), 0.3)
    reason, wide = bands.band_reason(grid, inverse, sigma, 255)
    assert reason is not None and "confidence band" in reason and wide["width"] > 0.25
    reason, _ = bands.band_reason(grid, inverse, sigma / 100, 255)
    assert reason is None


def test_show_prints_the_widest_band_and_the_plot_shades_it(model, tmp_path):
    from selfcal.report.describe import describe, format_description
    from selfcal.report.plots import plot_response

    text = format_description(describe(model))
    assert "90 % band of f⁻¹" in text and "widest ±" in text
    png = plot_response(model, tmp_path / "curve.png")
    assert (tmp_path / "curve.png").stat().st_size > 1000 or png
