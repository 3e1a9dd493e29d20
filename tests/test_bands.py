"""Confidence bands on f⁻¹ (selfcal.response.bands): coverage of the truth, the model file."""

from __future__ import annotations

import copy
import json

import cv2
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
    assert doc["version"] == 5 and len(doc["inverse_log_sigma"]) == 3
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


def test_default_band_is_the_covariance(stack, model):
    from selfcal.response import bands
    from selfcal.response.options import ResponseOptions

    assert bands.DEFAULT_BAND_METHOD == "covariance"   # the ``model`` fixture's band
    booted = selfcal.calibrate_response(stack.images, TIMES,
                                        options=ResponseOptions(band_method="bootstrap"))
    assert np.all(np.isfinite(model.inverse_log_sigma))
    # the two estimates of the statistical part differ, but not by an order of magnitude
    assert not np.allclose(booted.inverse_log_sigma, model.inverse_log_sigma)
    body = slice(len(model.intensity) // 10, len(model.intensity) * 9 // 10)
    ratio = booted.inverse_log_sigma[body] / model.inverse_log_sigma[body]
    assert 0.1 < ratio.min() and ratio.max() < 10


def test_the_callers_solver_options_reach_the_band(stack, monkeypatch):
    # issue 43: the band re-forms the solve the caller asked for, not the solver's defaults
    import dataclasses

    import selfcal.response.calibrate as cal
    from selfcal.response import ResponseOptions, SolverOptions, bands

    seen = []
    real = cal.band_for_fit

    def spy(*args, **kwargs):
        seen.append((args, kwargs))
        return real(*args, **kwargs)

    monkeypatch.setattr(cal, "band_for_fit", spy)
    solver = SolverOptions(huber_k=2.5, prior_weight=30.0)
    selfcal.calibrate_response(stack.images, TIMES, options=ResponseOptions(solver=solver))
    (samples, masks, basis, result, log_times, *_), kwargs = seen[-1]
    assert kwargs["options"] == solver          # N = 5 fits the basis: nothing capped

    def band(options):
        return bands.curve_band(samples, masks, basis, result.coefficients,
                                result.log_exposures, np.isfinite(log_times), options=options)

    asked = band(kwargs["options"])
    for default in ({"huber_k": SolverOptions().huber_k},
                    {"prior_weight": SolverOptions().prior_weight}):
        assert not np.allclose(band(dataclasses.replace(solver, **default)), asked)


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
    # the shading: the curves' panel of the model inks more pixels than the same model
    # without its band
    bare = copy.copy(model)
    bare.inverse_log_sigma = None
    inked = []
    for which, name in ((model, "curve.png"), (bare, "bare.png")):
        png = plot_response(which, tmp_path / name)
        assert png == tmp_path / name
        image = cv2.imread(str(png))
        inked.append(np.mean(np.any(image[:, : image.shape[1] // 2] < 250, axis=2)))
    assert inked[0] > inked[1] + 0.005


# ------------------------------------------------------------------ issue 35: unknown times

def _coverage(model, truth) -> float:
    lower, upper = model.band_at_codes(np.arange(256))
    inner = slice(1, 255)
    return float(np.mean((truth[inner] >= lower[inner]) & (truth[inner] <= upper[inner])))


@pytest.fixture(scope="module")
def small_stacks():
    """Small stacks of three curves the prior's centre (sRGB, Rec.709) does not match
    exactly: sRGB itself, a flatter power law, a film curve."""
    out = []
    for curve in (sim.ToneCurve.srgb(), sim.ToneCurve.gamma(1.8), sim.ToneCurve.film()):
        pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=3)
        scene = sim.make_scene(96, 144, saturation=0.5, seed=3)
        out.append(sim.simulate_stack(scene, pipe, TIMES, jitter=0.03, jpeg_quality=90,
                                      seed=3))
    return out


def _data_band(model):
    """The band without the ambiguity term: that term (σ_γ in the evidence) taken out."""
    from selfcal.response import bands

    sigma_gamma = model.diagnostics["verdict_evidence"]["ambiguity_gamma_sigma"]
    amb = bands.ambiguity_sigma(model.inverse, sigma_gamma)
    assert np.all(model.inverse_log_sigma >= amb - 1e-9)
    return np.sqrt(np.maximum(model.inverse_log_sigma ** 2 - amb ** 2, 0.0))


@pytest.mark.filterwarnings("ignore:fewer than two different exposure times")
def test_band_with_no_time_known_carries_the_ambiguity(small_stacks):
    # with no time (or one) the prior chooses γ; the band must cover the truth anyway
    from dataclasses import replace

    one = [TIMES[0]] + [None] * (len(TIMES) - 1)
    covered = []
    for stack in small_stacks:
        truth = stack.inverse_response()
        for known in ([None] * len(TIMES), one):
            model = selfcal.calibrate_response(stack.images, known)
            assert model.diagnostics["ambiguity_resolved_by_prior"]
            covered.append(_coverage(model, truth))
    assert min(covered) >= 0.8, covered
    # without the ambiguity term the band is the scatter around the prior's choice, which
    # misses the flatter curve (this is what the term is for)
    flat = small_stacks[1]
    model = selfcal.calibrate_response(flat.images, [None] * len(TIMES))
    bare = replace(model, inverse_log_sigma=_data_band(model))
    assert _coverage(bare, flat.inverse_response()) < 0.5


@pytest.mark.filterwarnings("ignore:fewer than two different exposure times")
def test_band_with_two_times_known_has_no_ambiguity_term(small_stacks):
    # the term is there only when the solve left γ to the prior: with all times known and
    # with two, the band is the data's (narrow), and no σ_γ is reported
    stack = small_stacks[0]
    two = [TIMES[0]] + [None] * (len(TIMES) - 2) + [TIMES[-1]]
    for known in (TIMES, two):
        model = selfcal.calibrate_response(stack.images, known)
        assert "ambiguity_gamma_sigma" not in model.diagnostics["verdict_evidence"]
        lower, upper = model.band_at_codes(np.arange(256))
        body = slice(26, 230)
        half = np.median((upper - lower)[body] / (2 * model.inverse_response()[body]))
        assert half < 0.15


@pytest.mark.filterwarnings("ignore:fewer than two different exposure times")
def test_ambiguity_term_is_the_log_effect_of_gamma(small_stacks):
    from selfcal.response import bands

    grid = np.linspace(0.0, 1.0, 11)
    inverse = np.tile(grid[:, None] ** 2.2, (1, 3))
    amb = bands.ambiguity_sigma(inverse, 0.3)
    assert np.all(np.isfinite(amb)) and np.all(amb[-1] == 0.0)      # f⁻¹(1) = 1
    np.testing.assert_allclose(amb[1:], 0.3 * 2.2 * np.abs(np.log(grid[1:, None]))
                               * np.ones((1, 3)))
    # in the model: the band with no time known is the data's band and this term in
    # quadrature; the verdict is judged on the data's band alone (the ambiguity has its
    # own warning)
    stack = small_stacks[0]
    model = selfcal.calibrate_response(stack.images, [None] * len(TIMES))
    evidence = model.diagnostics["verdict_evidence"]
    sigma_gamma = evidence["ambiguity_gamma_sigma"]
    # σ_γ = σ₀ √(1 + E): at least σ₀, and sRGB (half of the prior's centre) lies near it
    assert sigma_gamma == pytest.approx(bands.gamma_sigma_of_energy(
        evidence["ambiguity_energy"]))
    assert bands.AMBIGUITY_LOG_GAMMA_SIGMA <= sigma_gamma < 2 * bands.AMBIGUITY_LOG_GAMMA_SIGMA
    wide = bands.widest_band(model.intensity, model.inverse, _data_band(model))
    assert evidence["band_width_90"]["width"] == pytest.approx(wide["width"], abs=1e-3)
    assert model.diagnostics["verdict"] == "ok"


def test_ambiguity_gamma_sigma_grows_with_the_distance_from_the_prior_centre():
    from selfcal.response import bands
    from selfcal.response.basis import builtin_basis
    from selfcal.response.priors import ambiguity_centre

    basis, N = builtin_basis(), 5
    centre = np.tile(ambiguity_centre(basis, N), (3, 1))
    s0 = bands.AMBIGUITY_LOG_GAMMA_SIGMA
    assert bands.ambiguity_gamma_sigma(basis, centre, N) == pytest.approx((s0, 0.0))
    lam = np.asarray(basis.explained_variance[:N])
    off = centre.copy()
    off[:, 0] += 2.0 * np.sqrt(lam[0])                       # E = 4 in every channel
    assert bands.ambiguity_gamma_sigma(basis, off, N) == pytest.approx((s0 * np.sqrt(5.0), 4.0))
    off[:, 0] += 100.0 * np.sqrt(lam[0])                     # far beyond any camera: capped
    assert bands.ambiguity_gamma_sigma(basis, off, N)[0] == bands.AMBIGUITY_LOG_GAMMA_SIGMA_MAX
    assert bands.gamma_sigma_of_energy(4.0, 0.2) == pytest.approx(0.2 * np.sqrt(5.0))
