"""The JPEG-only path: recovered curves against the simulator's truth, exposures, bad input."""

from __future__ import annotations

import dataclasses
import json
import math
import warnings

import numpy as np
import pytest

import selfcal
from conftest import rmse_vs_truth
from selfcal import sim
from selfcal.errors import CalibrationError, InputError, ModelFileError
from selfcal.response import ResponseOptions, SolverOptions
from selfcal.stack.samples import collect_samples

TIMES = list(sim.DEMO_EXPOSURE_TIMES)




@pytest.fixture(scope="module")
def srgb_stack():
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=1)
    scene = sim.make_scene(192, 288, saturation=0.5, seed=1)
    return sim.simulate_stack(scene, pipe, TIMES, jitter=0.03, jpeg_quality=90, seed=1)


@pytest.fixture(scope="module")
def film_stack():
    stack = sim.demo_stack(seed=0)
    return stack


@pytest.fixture(scope="module")
def srgb_model(srgb_stack):
    return selfcal.calibrate_response(srgb_stack.images, TIMES)


def test_known_times_recover_truth(srgb_model, srgb_stack):
    # 0.0091 when the clipping-threshold rows took their interpolated θ as exact: this
    # scene's flat patches leave gaps of tens of codes around the crossing (now 0.0049)
    assert rmse_vs_truth(srgb_model, srgb_stack) < 0.0065
    # the solve held the given times; the exposures measured through the curve after it
    # are closer to the true (jittered) ones than the times are, on the times' scale
    true = np.asarray(srgb_stack.true_exposures)
    assert srgb_model.exposure_record.refined is False
    assert {f.used_from for f in srgb_model.exposure_record.frames} == {"measured"}
    assert abs(np.median(np.log(srgb_model.exposures / TIMES))) < 1e-9
    assert _ratio_error(srgb_model.exposures, true) < 0.5 * _ratio_error(TIMES, true)
    assert srgb_model.diagnostics["verdict"] == "ok"
    inv = srgb_model.inverse_response()
    assert inv[-1] == pytest.approx([1, 1, 1])
    assert np.all(np.diff(inv, axis=0) >= 0)


def _ratio_error(exposures, true):
    """RMS of log(exposure / true) about its mean: what is wrong beyond one scale."""
    d = np.log(np.asarray(exposures, float) / np.asarray(true, float))
    return float(np.sqrt(np.mean((d - d.mean()) ** 2)))


def test_per_channel_curves_differ_as_truth_does(film_stack):
    model = selfcal.calibrate_response(film_stack.images, list(film_stack.exposure_times))
    truth = film_stack.inverse_response()
    est = model.inverse_response()
    err = np.sqrt(np.mean((est[1:255] - truth[1:255]) ** 2, axis=0))
    assert np.all(err < 0.012), err
    # the channels' true curves differ; the recovered ones keep that order at mid-grey
    assert np.argsort(est[128]).tolist() == np.argsort(truth[128]).tolist()


@pytest.fixture(scope="module")
def knee_stack():
    """A response whose inverse rises steeply over the last codes (a DoRF-like knee)."""
    x = np.linspace(0, 1, 1024)
    y = np.where(x <= 0.9, 0.97 * (x / 0.9) ** (1 / 2.2), 0.97 + 0.3 * (x - 0.9))
    pipe = sim.default_pipeline(gamut="smooth", seed=2,
                                  curves=sim.ToneCurve.from_table(x, y, name="knee"))
    scene = sim.make_scene(192, 288, saturation=0.5, seed=2)
    return sim.simulate_stack(scene, pipe, TIMES, jitter=0.03, jpeg_quality=90, seed=2)


def test_white_thresholds_locate_the_top_code(knee_stack):
    from selfcal.response.solver import white_thresholds
    from selfcal.stack.samples import collect_samples, frame_masks

    samples = collect_samples(knee_stack.images)
    masks = frame_masks(samples)
    valid = ~(masks["clipped"] | masks["saturated"])
    order = np.argsort(knee_stack.exposure_times)
    rows = white_thresholds(samples.values, valid, order, 3, 255, 2 / 255)
    assert len(rows) >= 20
    truth = knee_stack.inverse_response()
    codes = np.arange(256)
    top = np.interp(254.5, codes, truth[:, 0])
    # f⁻¹(θ)·(t_b/t_a) is where the channel reaches 255: f⁻¹(254.5), per row
    ratio = np.array([np.interp(th * 255, codes, truth[:, c])
                      * knee_stack.true_exposures[b] / knee_stack.true_exposures[a] / top
                      for c, a, b, th, *_ in rows])
    assert abs(np.median(ratio) - 1) < 0.02
    assert np.all(np.abs(ratio - 1) < 0.06)
    # the true crossing lies in the gap the samples leave around θ (within noise)
    inside = []
    for c, a, b, th, _, lo, hi in rows:
        k = knee_stack.true_exposures[b] / knee_stack.true_exposures[a]
        crossing = np.interp(top / k, truth[:, c], codes) / 255
        assert lo <= th <= hi
        inside.append(lo - 2 / 255 <= crossing <= hi + 2 / 255)
    assert np.mean(inside) >= 0.9, np.mean(inside)


def test_clipping_propagates_along_exposure():
    """White clipping in a frame holds in every brighter one, black in every darker one."""
    from selfcal.stack.samples import collect_samples, frame_masks

    ramp = np.linspace(40, 200, 64)
    frames = []
    for gain in (1.0, 1.1, 1.2):
        im = np.tile(ramp * gain, (48, 1))[..., None].repeat(3, axis=2)
        im[:8] = 255 if gain == 1.0 else 250      # a highlight that JPEG left below 255
        im[-8:] = 0 if gain == 1.2 else 4          # a shadow crushed in the brightest frame
        frames.append(np.clip(np.round(im), 0, 255).astype(np.uint8))
    samples = collect_samples(frames, block=4)
    rows = samples.locations[:, 0] * 4
    top, bottom = rows < 8, rows >= 40
    assert top.any() and bottom.any()
    masks = frame_masks(samples)
    assert masks["clipped"][:, top].all() and masks["clipped"][:, bottom].all()
    plain = frame_masks(samples, propagate=False)
    assert not plain["clipped"][1:, top].any() and not plain["clipped"][:2, bottom].any()


def test_flat_neutral_blocks_are_chosen_before_flat_coloured_ones():
    """The flatness ranking counts spread across channels: neutral patches go first."""
    from selfcal.stack.samples import collect_samples

    # left half a flat neutral grey, right half a flat orange of the same mean level
    frames = []
    for gain in (1.0, 1.2):
        im = np.empty((32, 64, 3))
        im[:, :32] = 120.0 * gain
        im[:, 32:] = np.array([180.0, 120.0, 60.0]) * gain
        frames.append(np.clip(np.round(im), 0, 255).astype(np.uint8))
    samples = collect_samples(frames, block=2, per_bin=4)
    cols = samples.locations[:, 1] * 2
    assert samples.n_samples > 0
    # one intensity bin, both patches in it: only the neutral patch is taken
    assert np.all(cols < 32), cols

def test_normal_equations_by_blocks_match_the_sparse_system():
    """The block assembly of AᵀWA, AᵀWb equals the general sparse product."""
    import scipy.sparse as sp

    from selfcal.response.solver import NormalEquations

    rng = np.random.default_rng(4)
    F, N, m, nt = 5, 4, 300, 7
    pa = rng.integers(0, F, m)
    pb = (pa + rng.integers(1, F, m)) % F
    dH = [rng.normal(size=(m, N)) for _ in range(3)]
    rhs = [rng.normal(size=m) for _ in range(3)]
    A_thr = sp.csr_matrix(rng.normal(size=(nt, 3 * N + F)) * (rng.random((nt, 3 * N + F)) < 0.4))
    b_thr = rng.normal(size=nt)
    w = rng.uniform(0.1, 2.0, 3 * m + nt)
    # the same rows, written out: dH_c · c_c − K[pb] + K[pa] = rhs_c
    S = np.zeros((m, F))
    S[np.arange(m), pb] -= 1
    S[np.arange(m), pa] += 1
    blocks = [np.hstack([np.zeros((m, c * N)), dH[c], np.zeros((m, (2 - c) * N)), S])
              for c in range(3)]
    A = np.vstack(blocks + [A_thr.toarray()])
    b = np.concatenate(rhs + [b_thr])
    normal = NormalEquations(dH, rhs, pa, pb, F, N, A_thr, b_thr)
    Q, q = normal(w)
    np.testing.assert_allclose(Q, A.T @ (w[:, None] * A), rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(q, A.T @ (w * b), rtol=1e-10, atol=1e-9)
    x = rng.normal(size=3 * N + F)
    np.testing.assert_allclose(normal.residual(x), A @ x - b, rtol=1e-10, atol=1e-10)


def test_delta_of_eq12_is_small_on_a_clean_stack(film_stack):
    model = selfcal.calibrate_response(film_stack.images, list(film_stack.exposure_times))
    assert max(model.diagnostics["delta_eq12"]) < 0.05


def test_steep_top_scale_comes_from_the_clipping_threshold(knee_stack, monkeypatch):
    import selfcal.response.calibrate as cal

    with_rows = rmse_vs_truth(selfcal.calibrate_response(knee_stack.images, TIMES),
                              knee_stack)
    solve = cal.solve_exposure_equations
    monkeypatch.setattr(cal, "solve_exposure_equations", lambda *a, options, **k: solve(
        *a, options=dataclasses.replace(options, white_threshold=False), **k))
    without = rmse_vs_truth(selfcal.calibrate_response(knee_stack.images, TIMES),
                            knee_stack)
    assert with_rows < 0.004
    assert with_rows < 0.6 * without


def test_two_known_times_fix_ambiguity(srgb_stack):
    times = [TIMES[0], None, None, None, None, TIMES[-1]]
    model = selfcal.calibrate_response(srgb_stack.images, times)
    assert rmse_vs_truth(model, srgb_stack) < 0.015
    # the unknown frames' exposures come out near the true (jittered) ones
    rel = model.exposures[1:5] / srgb_stack.true_exposures[1:5]
    assert np.all(np.abs(rel - 1) < 0.08), rel
    assert not model.diagnostics["ambiguity_resolved_by_prior"]


def test_unknown_times_warn_about_ambiguity(srgb_stack):
    model = selfcal.calibrate_response(srgb_stack.images, [None] * 6)
    assert model.diagnostics["ambiguity_resolved_by_prior"]
    # ratios between frames are still ordered like the truth
    assert np.all(np.diff(model.exposures) > 0)


def test_unknown_times_give_the_exponent_within_a_bound():
    # no time known: γ (the slope of the log exposures against the true ones) comes from
    # the prior, centred at standard encodings (sRGB, Rec.709); a film curve is not one of
    # them.  Centred at the basis mean, as before, this stack gave γ 0.81 and f⁻¹ 0.054
    # away from the truth; now 0.96 and 0.009
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.film(), seed=2)
    stack = sim.simulate_stack(sim.make_scene(192, 288, seed=2), pipe, TIMES, jitter=0.03,
                               jpeg_quality=90, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = selfcal.calibrate_response(stack.images, [None] * 6)
    gamma = np.polyfit(np.log(stack.true_exposures), np.log(model.exposures), 1)[0]
    assert abs(gamma - 1) < 0.1, gamma
    assert rmse_vs_truth(model, stack) < 0.02


def test_refine_exposures_beats_wrong_nominal_times():
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.gamma(2.2), seed=3)
    scene = sim.make_scene(192, 288, seed=3)
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=0.12, jpeg_quality=90, seed=3)
    refined = selfcal.calibrate_response(stack.images, TIMES,
                                         exposures=selfcal.ExposureRule(refine=True))
    assert refined.exposure_record.refined
    true = stack.true_exposures
    # compare ratios to the first frame (the overall scale is the prior's)
    err_nominal = np.abs(np.log(np.array(TIMES) / TIMES[0]) - np.log(true / true[0]))
    err_refined = np.abs(np.log(refined.exposures / refined.exposures[0]) - np.log(true / true[0]))
    assert err_refined.mean() < 0.7 * err_nominal.mean()


def test_rejections_are_counted_by_reason():
    pipe = sim.default_pipeline(gamut="smooth", seed=4)
    scene = sim.make_scene(192, 288, saturation=1.0, seed=4)
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=0.0, jpeg_quality=90, seed=4)
    model = selfcal.calibrate_response(stack.images, TIMES,
                                       options=ResponseOptions(
                                           solver=SolverOptions(saturation_threshold=0.3)))
    rejected = model.diagnostics["samples"]["rejected"]
    assert rejected["clipped"] > 0 and rejected["saturated"] > 0
    strict = selfcal.calibrate_response(stack.images, TIMES,
                                        options=ResponseOptions(
                                            solver=SolverOptions(saturation_threshold=0.15)))
    assert strict.diagnostics["samples"]["rejected"]["saturated"] > rejected["saturated"]
    assert strict.diagnostics["saturation_threshold"] == 0.15


def test_options_object_and_no_keyword_forms(srgb_stack, srgb_model):
    frames = srgb_stack.images[:3]
    new = selfcal.calibrate_response(frames, TIMES[:3], options=ResponseOptions(
        solver=SolverOptions(n_components=4, clip_margin=3.0), max_samples=1500))
    assert new.diagnostics["n_components"] == 4 and new.diagnostics["clip_margin"] == 3.0
    # the 0.x keyword forms are gone: the fields are set on the options
    with pytest.raises(TypeError, match="n_components"):
        selfcal.calibrate_response(frames, TIMES[:3], n_components=4)
    with pytest.raises(selfcal.InputError, match="correspondences"):
        ResponseOptions(correspondences="pixels")
    # the solver's fields are declared in SolverOptions only (issue 43); the keywords of 1.0
    # still set them, with a DeprecationWarning
    with pytest.warns(DeprecationWarning, match=r"solver=SolverOptions\(saturation_thr"):
        flat = ResponseOptions(saturation_threshold=0.3, max_samples=1500)
    assert flat == ResponseOptions(solver=SolverOptions(saturation_threshold=0.3),
                                   max_samples=1500)
    assert not hasattr(flat, "saturation_threshold")     # read through .solver
    with pytest.raises(selfcal.InputError, match="SolverOptions"):
        ResponseOptions(solver={"huber_k": 2.0})
    assert ResponseOptions().with_solver(huber_k=2.0).solver == SolverOptions(huber_k=2.0)
    # the defaults are the options' defaults (the shared model was calibrated without any)
    assert srgb_model.diagnostics["n_components"] == ResponseOptions().solver.n_components


def test_solver_options_and_no_keyword_forms():
    from selfcal.response.basis import builtin_basis
    from selfcal.response.solver import solve_exposure_equations

    samples = collect_samples(sim.demo_stack(seed=0).images[:3], max_samples=600)
    log_times = np.log(TIMES[:3])
    new = solve_exposure_equations(samples, builtin_basis(), log_times,
                                   options=SolverOptions(max_rank_gap=1, huber_k=2.0))
    default = solve_exposure_equations(samples, builtin_basis(), log_times)
    assert not np.array_equal(default.coefficients, new.coefficients)
    with pytest.raises(TypeError, match="huber_k"):
        solve_exposure_equations(samples, builtin_basis(), log_times, huber_k=2.0)


def test_contradicting_time_is_reported(srgb_stack):
    times = list(TIMES)
    times[3] = times[3] * 2.5  # EXIF lies about one frame
    model = selfcal.calibrate_response(srgb_stack.images, times)
    flagged = [f.source for f in model.exposure_record.contradictions()]
    assert flagged == ["array #3"]
    # the caller's times follow the rule EXIF times do: the contradicted one is refined
    # (and then measured), held with ExposureRule(times="held")
    assert model.exposure_record.refined
    assert abs(model.exposure_record.frames[3].moved) > 0.4
    held = selfcal.calibrate_response(srgb_stack.images, times,
                                      exposures=selfcal.ExposureRule(times="held"))
    assert [f.source for f in held.exposure_record.contradictions()] == ["array #3"]
    assert not held.exposure_record.refined
    np.testing.assert_allclose(held.exposures, times, rtol=1e-12)
    line = selfcal.exposure.exposure_message(held.exposure_record)
    assert "array #3" in line and "held" in line


def test_sixteen_bit_stack():
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=5)
    scene = sim.make_scene(128, 192, seed=5)
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=0.0, jpeg_quality=None,
                                 output=sim.FrameOutput(bit_depth=16), seed=5)
    model = selfcal.calibrate_response(stack.images, TIMES)
    assert model.max_code == 65535
    assert rmse_vs_truth(model, stack) < 0.01


def test_linearize_applies_inverse_per_channel(srgb_model, srgb_stack):
    image = srgb_stack.images[2]
    lin = srgb_model.linearize(image)
    assert lin.dtype == np.float32 and lin.shape == image.shape
    lut = srgb_model.inverse_response()
    assert lin[5, 7, 1] == pytest.approx(lut[image[5, 7, 1], 1], rel=1e-6)
    # float input in [0, 1] gives the same as codes
    lin_f = srgb_model.linearize(image.astype(np.float32) / 255)
    np.testing.assert_allclose(lin_f, lin, atol=1e-5)
    with pytest.raises(InputError):
        srgb_model.linearize(np.full((2, 2, 3), np.nan, np.float32))


def test_save_load_round_trip(srgb_model, srgb_stack, tmp_path):
    path = tmp_path / "model.json"
    srgb_model.save(path)
    loaded = selfcal.load_model(path)
    np.testing.assert_array_equal(loaded.linearize(srgb_stack.images[1]),
                                  srgb_model.linearize(srgb_stack.images[1]))
    np.testing.assert_allclose(loaded.exposures, srgb_model.exposures)
    with pytest.raises(selfcal.OutputExistsError):
        srgb_model.save(path)
    srgb_model.save(path, force=True)


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.update(version=99), "version"),
    (lambda d: d.update(format="other"), "not a selfcal model"),
    (lambda d: d.pop("inverse_response"), "inverse_response"),
    (lambda d: d["inverse_response"][0].reverse(), "not increasing"),
])
def test_load_rejects_bad_model_files(srgb_model, tmp_path, mutate, message):
    path = tmp_path / "m.json"
    srgb_model.save(path)
    doc = json.loads(path.read_text())
    mutate(doc)
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match=message) as info:
        selfcal.load_model(path)
    assert str(path) in str(info.value)


def test_load_rejects_non_json(tmp_path):
    path = tmp_path / "m.json"
    path.write_text("{not json")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        selfcal.load_model(path)


def test_deterministic(srgb_stack):
    a = selfcal.calibrate_response(srgb_stack.images, TIMES)
    b = selfcal.calibrate_response(srgb_stack.images, TIMES)
    np.testing.assert_array_equal(a.inverse, b.inverse)


# ------------------------------------------------------------------ bad input

def test_one_frame_is_an_error(srgb_stack):
    with pytest.raises(CalibrationError, match="one frame"):
        selfcal.calibrate_response(srgb_stack.images[:1], TIMES[:1])


def test_frames_of_different_sizes(srgb_stack):
    frames = list(srgb_stack.images[:3])
    frames[2] = frames[2][:-4]
    with pytest.raises(InputError, match="array #2.*differs"):
        selfcal.calibrate_response(frames, TIMES[:3])


def test_duplicate_frame_with_other_time(srgb_stack):
    frames = [srgb_stack.images[0], srgb_stack.images[1], srgb_stack.images[1]]
    with pytest.raises(InputError, match="array #2.*identical"):
        selfcal.calibrate_response(frames, TIMES[:3])


def test_all_clipped_frame_is_dropped_with_warning(srgb_stack):
    frames = list(srgb_stack.images) + [np.full_like(srgb_stack.images[0], 255)]
    model = selfcal.calibrate_response(frames, TIMES + [1.0])
    assert [(f.source, f.reason) for f in model.frames_ignored] == [("array #6", "clipped")]
    assert "array #6" not in model.diagnostics["frames_used"]
    assert math.isnan(model.exposures[6])


def test_nan_array_is_an_error(srgb_stack):
    frames = [srgb_stack.images[0].astype(np.float32), srgb_stack.images[1]]
    frames[0][0, 0, 0] = np.nan
    with pytest.raises(InputError, match="array #0.*NaN"):
        selfcal.calibrate_response(frames, TIMES[:2])


def test_same_time_everywhere_is_an_error(srgb_stack):
    with pytest.raises(CalibrationError, match="same exposure"):
        selfcal.calibrate_response(srgb_stack.images[:3], [0.01] * 3)


def test_bad_time_value_names_frame(srgb_stack):
    with pytest.raises(InputError, match="array #1.*positive"):
        selfcal.calibrate_response(srgb_stack.images[:2], [0.01, -1])


def test_files_truncated_or_not_images(tmp_path, srgb_stack):
    paths = srgb_stack.write(tmp_path / "stack")
    data = paths[2].read_bytes()
    paths[2].write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="frame.*truncated"):
        selfcal.calibrate_response(paths)
    paths[2].write_text("hello")
    with pytest.raises(InputError, match="not an image"):
        selfcal.calibrate_response(paths)


def test_jpeg_padded_with_zeros_after_its_end_is_read(tmp_path, srgb_stack):
    # The Sony ILCE-6400 pads its JPEGs with up to ~30 KB of zeros after the EOI marker.
    from selfcal.io import read_image

    path = srgb_stack.write(tmp_path / "stack")[0]
    data = path.read_bytes()
    path.write_bytes(data + bytes(30_000))
    np.testing.assert_array_equal(read_image(path), srgb_stack.images[0])
    path.write_bytes(data[: len(data) // 2] + bytes(30_000))   # truncated, then padded
    with pytest.raises(InputError, match="truncated"):
        read_image(path)


def test_exif_times_are_used_and_missing_exif_warned(tmp_path, srgb_stack):
    paths = srgb_stack.write(tmp_path / "stack")
    model = selfcal.calibrate_response(paths)
    assert model.exposure_record.origin == "exif"
    # measured through the curve, on the EXIF times' scale
    true = np.asarray(srgb_stack.true_exposures)
    assert _ratio_error(model.exposures, true) < _ratio_error(srgb_stack.exposure_times, true)
    # strip EXIF from one file: its time becomes unknown, and the warning names it
    from selfcal.io import encode_image

    paths[4].write_bytes(encode_image(srgb_stack.images[4], ".png"))
    stripped = paths[4]
    model = selfcal.calibrate_response(paths)
    assert any(str(stripped) in w and "no exposure time" in w
               for w in model.diagnostics["warnings"])
    assert model.exposures[4] == pytest.approx(srgb_stack.true_exposures[4], rel=0.08)


def test_isolated_long_exposure_is_not_called_contradicted(tmp_path):
    """A frame far beyond the bracket shares no unclipped samples: say so, do not guess."""
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=4)
    scene = sim.make_scene(160, 240, dynamic_range_stops=14, saturation=0.3, seed=4)
    times = TIMES + [TIMES[-1] * 1000]
    stack = sim.simulate_stack(scene, pipe, times, jitter=0.0, jpeg_quality=90, seed=4)
    model = selfcal.calibrate_response(stack.images, times)
    warnings = model.diagnostics["warnings"]
    assert any("array #6" in w and "shares only" in w for w in warnings), warnings
    assert not any("array #6" in w and "contradict" in w for w in warnings), warnings
    # ignored, not fitted: the curve is the one of the bracket without it
    bracket = selfcal.calibrate_response(stack.images[:6], TIMES)
    assert rmse_vs_truth(model, stack) <= 1.02 * rmse_vs_truth(bracket, stack)
    assert rmse_vs_truth(model, stack) < 0.02
    # the ignored frame has no exposure estimate, and the model still saves and loads
    assert np.isnan(model.exposures[6]) and np.all(np.isfinite(model.exposures[:6]))
    loaded = selfcal.load_model(model.save(tmp_path / "m.json"))
    assert np.isnan(loaded.exposures[6])
    np.testing.assert_allclose(loaded.exposures[:6], model.exposures[:6])
