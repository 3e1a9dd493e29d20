"""The scores (selfcal.sim.scoring, selfcal.response.delta) on inputs
whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from selfcal import sim
from selfcal.response.delta import delta_eq12
from selfcal.sim.scoring import (best_scale_rmse, log_linearisation_error,
                                  log_linearisation_error_by_saturation, per_code_floor, rmse)

TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]


def test_rmse_of_a_constant_offset_is_the_offset():
    curve = np.linspace(0.0, 1.0, 254) ** 2.2
    assert rmse(curve, curve) == 0.0
    assert rmse(curve + 0.01, curve) == pytest.approx(0.01, rel=1e-9)


@pytest.mark.parametrize("scale", [0.25, 0.7, 3.0])
def test_a_scaled_curve_is_at_best_scale_distance_zero(scale):
    truth = np.linspace(0.0, 1.0, 254)[:, None] ** np.array([2.2, 1.8, 2.4])
    assert best_scale_rmse(scale * truth, truth) == pytest.approx(0.0, abs=1e-12)
    assert rmse(scale * truth, truth) > 0.01           # the absolute RMSE does see it
    wrong = np.linspace(0.0, 1.0, 254)[:, None] ** np.array([1.5, 1.5, 1.5])
    assert best_scale_rmse(wrong, truth) > 0.01


@pytest.fixture(scope="module")
def noiseless_stack():
    """A camera that follows the per-channel model exactly: no noise, jitter or JPEG."""
    pipe = sim.CameraPipeline(matrix=np.eye(3), curves=sim.ToneCurve.gamma(2.2),
                                gamut="none")
    return sim.simulate_stack(sim.make_scene(48, 64, seed=3), pipe, TIMES, jitter=0.0,
                                sensor=sim.SensorModel.ideal(), jpeg_quality=None,
                                output=sim.FrameOutput(bit_depth=16), seed=3)


def _delta_inputs(stack):
    codes = np.arange(stack.max_code + 1)
    values = np.stack([im.reshape(-1, 3) for im in stack.images]) / stack.max_code
    # unclipped in every channel: the inliers
    valid = ((values > 0) & (values < 1)).all(axis=2)
    pairs = [(a, a + 1) for a in range(len(stack.images) - 1)]
    return codes / stack.max_code, values, valid, np.log(stack.true_exposures), pairs


def test_delta_of_the_true_curve_is_zero_on_a_noiseless_stack(noiseless_stack):
    grid, values, valid, log_exposures, pairs = _delta_inputs(noiseless_stack)
    truth = noiseless_stack.inverse_response()
    delta = delta_eq12(values, grid, truth, log_exposures, pairs, valid)
    assert delta.shape == (3,)
    assert delta.max() < 1e-4                           # 16-bit quantisation only
    wrong = np.stack([grid ** 1.6] * 3, axis=1)
    assert delta_eq12(values, grid, wrong, log_exposures, pairs, valid).min() > 10 * delta.max()


def test_delta_over_all_points_counts_the_clipped_ones(noiseless_stack):
    grid, values, valid, log_exposures, pairs = _delta_inputs(noiseless_stack)
    assert not valid.all()                              # the bracket clips
    truth = noiseless_stack.inverse_response()
    inliers = delta_eq12(values, grid, truth, log_exposures, pairs, valid)
    everything = delta_eq12(values, grid, truth, log_exposures, pairs)
    assert np.all(everything > 10 * inliers)
    everywhere = np.ones_like(valid)
    assert np.array_equal(everything,
                          delta_eq12(values, grid, truth, log_exposures, pairs, everywhere))


@pytest.fixture(scope="module")
def noisy_stack():
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=1)
    return sim.simulate_stack(sim.make_scene(64, 96, seed=1), pipe, TIMES,
                                jpeg_quality=90, seed=1)


def test_the_per_code_floor_is_below_every_curve(noisy_stack):
    images = noisy_stack.images
    floor = per_code_floor(images, TIMES)
    assert floor.shape == (256, 3)
    assert np.allclose(floor.max(axis=0), 1.0)
    at_floor = log_linearisation_error(images, TIMES, floor)
    grid = np.arange(256) / 255.0
    curves = {"truth": noisy_stack.inverse_response(),
              "gamma 2.2": np.stack([grid ** 2.2] * 3, axis=1),
              "linear": np.stack([grid] * 3, axis=1)}
    for name, lut in curves.items():
        assert at_floor <= log_linearisation_error(images, TIMES, lut) + 1e-9, name


def test_the_metric_of_a_linear_camera_is_zero():
    rng = np.random.default_rng(0)
    dark = rng.integers(25, 117, size=(8, 8, 3)).astype(np.uint8)
    lut = np.stack([np.arange(256) / 255.0] * 3, axis=1)
    assert log_linearisation_error([dark, 2 * dark], [1.0, 2.0], lut) == pytest.approx(
        0.0, abs=1e-12)
    # the metric is free of f⁻¹'s scale
    curve = lut ** 1.7
    assert log_linearisation_error([dark, 2 * dark], [1.0, 2.0], 0.5 * curve) == pytest.approx(
        log_linearisation_error([dark, 2 * dark], [1.0, 2.0], curve), rel=1e-12)


def test_the_saturation_bands_partition_the_pixels(noisy_stack):
    images, lut = noisy_stack.images, noisy_stack.inverse_response()
    whole = log_linearisation_error(images, TIMES, lut)
    rms, share = log_linearisation_error_by_saturation(images, TIMES, lut)
    assert rms.shape == share.shape == (3,)
    assert share.sum() == pytest.approx(1.0)
    # every pixel pair is in one band: the bands' squared errors add up to the whole
    assert np.nansum(share * rms ** 2) == pytest.approx(whole ** 2, rel=1e-12)
    one_band, one_share = log_linearisation_error_by_saturation(images, TIMES, lut,
                                                                edges=(0.0, 1.0))
    assert one_share.tolist() == [1.0]
    assert one_band[0] == pytest.approx(whole, rel=1e-12)
