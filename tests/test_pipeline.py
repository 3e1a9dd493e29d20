"""Tests of the RAW path model (selfcal.pipeline): rank-based matrix, tone curves, lattice
LUT, RBF h⁻¹, PipelineModel, model files, the NUS model reader, the baselines."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.errors import CalibrationError, InputError, ModelFileError, OutputExistsError
from selfcal.pipeline import (
    BackwardStages,
    ForwardStages,
    LatticeOptions,
    PipelineModel,
    PipelineOptions,
    fit_pipeline,
    lattice_regression_lut,
    monotone_tone_curves,
    rank_based_matrix,
    rbf_inverse_colour_mapping,
)
from selfcal.pipeline.baselines import independent_polynomial_model, least_squares_rbf_model
from selfcal.pipeline.matrix import fibonacci_sphere, rank_based_row
from selfcal.pipeline.nus import read_nus_model

ROOT = Path(__file__).resolve().parents[1]
NUS = ROOT.parent / "shared" / "data" / "nus_model_nikon_d7000"


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


@pytest.fixture(scope="module")
def pair():
    """A synthetic RAW+JPEG pair (smooth gamut mapping) and a held-out pixel split."""
    p = sim.simulate_raw_jpeg_pair(seed=0)
    raw = p["raw"].reshape(-1, 3).astype(np.float64)
    jpg = p["rendered"].reshape(-1, 3)
    rng = np.random.default_rng(123)
    train = rng.choice(raw.shape[0], 1500, replace=False)
    test = np.setdiff1d(np.arange(raw.shape[0]), train)
    truth = p["pipeline"].render(p["raw"]).reshape(-1, 3)
    return {"pair": p, "raw": raw, "jpg": jpg, "codes": p["codes"].reshape(-1, 3),
            "train": train, "test": test, "truth": truth}


@pytest.fixture(scope="module")
def model(pair):
    return fit_pipeline(pair["raw"][pair["train"]], pair["jpg"][pair["train"]] / 255.0,
                        PipelineOptions(n_sets=10), seed=0)


# ---- end to end on the simulator -------------------------------------------------------

def test_forward_and_backward_errors_on_held_out_pixels(pair, model):
    test = pair["test"]
    fwd = _rmse(model.render(pair["raw"][test]), pair["truth"][test]) * 255
    assert fwd < 4.0   # the JPEG it was trained on is itself ~3 codes from the truth
    ok = ~((pair["jpg"][test] == 0) | (pair["jpg"][test] == 255)).any(axis=1)
    back_jpg = _rmse(model.to_raw(pair["jpg"][test][ok]), pair["raw"][test][ok])
    back_codes = _rmse(model.to_raw(pair["codes"][test][ok]), pair["raw"][test][ok])
    assert back_jpg < 0.012
    assert back_codes < 0.008
    # better than the linear part alone (M and the per-channel curves)
    e = model.inverse_tone_curves(pair["codes"][test][ok] / 255.0)
    plain = _rmse(np.clip(e @ model.matrix_inverse.T, 0, 1), pair["raw"][test][ok])
    assert back_codes < plain


def test_images_keep_their_shape_and_dtype(pair, model):
    p = pair["pair"]
    out = model.render(p["raw"])
    assert out.shape == p["raw"].shape and out.dtype == np.float32
    assert 0.0 <= out.min() and out.max() <= 1.0
    back = model.to_raw(p["rendered"])
    assert back.shape == p["rendered"].shape and back.dtype == np.float32
    # uint8 path (pre-interpolated code table) equals the float path
    back_f = model.to_raw(p["rendered"].astype(np.float32) / 255.0)
    assert np.max(np.abs(back - back_f)) < 1e-4


def test_render_to_raw_round_trip_for_in_gamut_colours(pair, model):
    raw = pair["raw"]
    p = pair["pair"]["pipeline"]
    mapped = raw @ p.matrix.T
    lum = mapped.mean(axis=1, keepdims=True)
    inside = (np.all((mapped > 0.02) & (mapped < 0.9), axis=1)
              & (np.abs(mapped - lum).max(axis=1) < 0.3 * lum[:, 0]))
    sel = raw[inside][::7]
    assert sel.shape[0] > 500
    back = model.to_raw(model.render(sel))
    assert _rmse(back, sel) < 0.006


def test_baked_table_matches_direct_evaluation(pair, model):
    codes = pair["codes"][pair["test"]][::11]
    truth = pair["raw"][pair["test"]][::11]
    for variant in ("lut", "rbf"):
        baked = model.to_raw(codes, variant=variant)
        exact = model.to_raw(codes, variant=variant, exact=True)
        assert _rmse(baked, exact) < 0.0015
        assert _rmse(baked, truth) < 1.03 * _rmse(exact, truth)


def test_diagnostics_report_both_backward_variants(model):
    d = model.diagnostics
    assert d["backward"] in ("lut", "rbf") and d["backward"] == model.backward
    assert set(d["backward_validation_rmse"]) == {"lut", "rbf"}
    assert d["backward"] == min(d["backward_validation_rmse"],
                                key=d["backward_validation_rmse"].get)
    assert d["forward_train_rmse"] <= d["forward_train_rmse_without_lut"] + 1e-9
    assert len(d["matrix_search"]["set_train_rmse"]) == 10
    assert d["samples"]["used"] == 1500


# ---- the parts -------------------------------------------------------------------------

# slow: the literal half-space count over 100,000 directions, three rows
@pytest.mark.slow
def test_fast_search_reaches_the_literal_count():
    p = sim.simulate_raw_jpeg_pair(seed=2)
    raw = p["raw"].reshape(-1, 3).astype(np.float64)
    jpg = p["rendered"].reshape(-1, 3) / 255.0
    idx = np.random.default_rng(5).choice(raw.shape[0], 120, replace=False)
    for k in range(3):
        fast = rank_based_row(raw[idx], jpg[idx], k, method="fast")
        literal = rank_based_row(raw[idx], jpg[idx], k, method="literal")
        assert fast["best"] >= literal["best"]
        assert fast["satisfied"] >= literal["satisfied"]
        assert fast["evaluated"] * 10 < literal["evaluated"]
        assert np.degrees(np.arccos(min(1.0, fast["row"] @ literal["row"]))) < 3.0


def test_rank_based_matrix_recovers_the_rows_without_gamut_mapping():
    rng = np.random.default_rng(0)
    raw = rng.uniform(0, 1, (200, 3)) ** 2
    m_true = sim.random_color_matrix(seed=4)
    pipe = sim.default_pipeline(gamut="none", seed=4)
    rendered = np.round(pipe.render(raw) * 255) / 255
    inside = np.all((raw @ m_true.T > 0) & (raw @ m_true.T < 1), axis=1)
    m = rank_based_matrix(raw[inside], rendered[inside])
    unit = m_true / np.linalg.norm(m_true, axis=1, keepdims=True)
    angles = np.degrees(np.arccos(np.clip(np.sum(m * unit, axis=1), -1, 1)))
    assert np.all(angles < 1.5), angles
    assert np.allclose(np.linalg.norm(m, axis=1), 1.0)


def test_fibonacci_sphere_is_unit_and_covers_the_sphere():
    u = fibonacci_sphere(100_000)
    assert np.allclose(np.linalg.norm(u, axis=1), 1.0)
    assert np.allclose(u.mean(axis=0), 0.0, atol=1e-4)
    # every direction has a lattice point within 0.6° ([Gong2018]'s sampling: 1.15°)
    rng = np.random.default_rng(0)
    v = rng.standard_normal((300, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    nearest = np.degrees(np.arccos(np.clip((v @ u.T).max(axis=1), -1, 1)))
    assert nearest.max() < 0.6


def test_tone_curves_are_monotone(model):
    for curves in (model.tone_curves, model.inverse_tone_curves):
        for k in range(3):
            x, y = curves.table(k, 20_001)
            assert np.all(np.diff(y) >= -1e-6)
    # a noisy, locally decreasing target still gives a monotone curve
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 1, (500, 3))
    y = x ** 0.5 + 0.05 * np.sin(20 * x) + 0.02 * rng.standard_normal((500, 3))
    fit = monotone_tone_curves(x, y)
    for k in range(3):
        grid = np.linspace(0, 1, 5001)
        assert np.all(np.diff(fit.channel(grid, k)) >= -1e-6)
        assert _rmse(fit.channel(x[:, k], k), x[:, k] ** 0.5) < 0.05


def test_lattice_lut_reproduces_a_known_smooth_map():
    rng = np.random.default_rng(2)

    def target(x):
        return x + 0.04 * np.sin(2.5 * x[:, [1, 2, 0]]) * x[:, [2, 0, 1]]

    x = rng.uniform(0, 1, (3000, 3))
    lut = lattice_regression_lut(x, target(x), smoothness="auto")
    assert lut.nodes.shape == (5, 5, 5, 3)
    xt = rng.uniform(0, 1, (2000, 3))
    err = _rmse(xt + lut.residual(xt), target(xt))
    assert err < 0.002
    assert err < 0.2 * _rmse(xt, target(xt))
    assert lut.validation and lut.smoothness in lut.validation


def test_lattice_lut_linear_term_is_outside_the_smoothness_penalty():
    """Ours, not [Gong2018]'s (selfcal.pipeline.lattice): beside the 125 × 3 node values a
    3×3 linear term, unpenalised, so the Laplacian does not shrink a linear correction."""
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (2000, 3))
    a = 0.1 * np.array([[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.1, 0.0, 1.0]])
    y = x + (x - 0.5) @ a                       # a purely linear correction
    lut = lattice_regression_lut(x, y, smoothness=1.0)
    assert lut.nodes.size + lut.linear.size == 125 * 3 + 9
    np.testing.assert_allclose(lut.linear, a, atol=1e-8)   # measured: 2e-11
    assert _rmse(x + lut.residual(x), y) < 1e-8
    # [Gong2018]'s LUT alone (affine=False) pays for it: measured 0.0052 RMSE (1.3 codes)
    plain = lattice_regression_lut(x, y, LatticeOptions(affine=False), smoothness=1.0)
    assert not plain.linear.any()
    assert _rmse(x + plain.residual(x), y) > 0.003


def test_rbf_inverts_a_known_gamut_compression():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (1500, 3))
    e = sim.gamut_compress(x, knee=0.5)
    h_inv = rbf_inverse_colour_mapping(e, x, seed=0)
    assert h_inv.centres.shape[0] <= 1500
    xt = rng.uniform(0.05, 0.95, (1000, 3))
    et = sim.gamut_compress(xt, knee=0.5)
    moved = np.abs(et - xt).max(axis=1) > 0.01
    assert moved.mean() > 0.2
    assert _rmse(h_inv(et), xt) < 0.3 * _rmse(et, xt)
    assert _rmse(h_inv(et), xt) < 0.02
    # the closed-form leave-one-out choice picked one of the grid values
    assert h_inv.smoothing in h_inv.validation


def test_rbf_matches_scipy_for_a_fixed_smoothing():
    from scipy.interpolate import RBFInterpolator

    rng = np.random.default_rng(4)
    c = rng.uniform(0, 1, (200, 3))
    v = np.sin(3 * c)
    ours = rbf_inverse_colour_mapping(c, v, smoothing=1e-3)
    ref = RBFInterpolator(c, v, kernel="linear", degree=1, smoothing=1e-3)
    q = rng.uniform(0, 1, (50, 3))
    assert np.allclose(ours(q), ref(q))


# ---- files, determinism, errors ---------------------------------------------------------

def test_save_and_load_give_identical_outputs(tmp_path, pair, model):
    path = tmp_path / "camera.json"
    model.save(path)
    with pytest.raises(OutputExistsError):
        model.save(path)
    model.save(path, force=True)
    loaded = selfcal.load_model(path)
    assert isinstance(loaded, PipelineModel)
    assert loaded.backward == model.backward
    assert np.array_equal(loaded.matrix, model.matrix)
    sample_raw = pair["raw"][::97]
    sample_jpg = pair["jpg"][::97]
    assert np.array_equal(loaded.render(sample_raw), model.render(sample_raw))
    for variant in ("lut", "rbf"):
        assert np.array_equal(loaded.to_raw(sample_jpg, variant=variant),
                              model.to_raw(sample_jpg, variant=variant))
        assert np.array_equal(loaded.to_raw(sample_jpg / 255.0, variant=variant),
                              model.to_raw(sample_jpg / 255.0, variant=variant))
    assert set(loaded.clipped_corrections) == set(model.clipped_corrections)
    assert ((sample_jpg == 0) | (sample_jpg == 255)).any(axis=1).sum() >= 10
    assert loaded.diagnostics["backward_validation_rmse"] == pytest.approx(
        model.diagnostics["backward_validation_rmse"])


def test_a_damaged_model_file_is_rejected(tmp_path, model):
    import json

    path = tmp_path / "camera.json"
    model.save(path)
    doc = json.loads(path.read_text())
    doc["matrix"] = [[1, 2], [3, 4]]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="bad.json"):
        selfcal.load_model(bad)
    del doc["tone_curves"]
    bad.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="tone_curves"):
        selfcal.load_model(bad)


# slow: three RAW-path fits (test_golden pins the fixed-seed outputs)
@pytest.mark.slow
def test_same_seed_same_model_other_seed_other_sets(pair):
    raw, jpg = pair["raw"], pair["jpg"] / 255.0
    three = PipelineOptions(n_sets=3)
    a = fit_pipeline(raw, jpg, three, n_train=400, seed=7)
    b = fit_pipeline(raw, jpg, three, n_train=400, seed=7)
    c = fit_pipeline(raw, jpg, three, n_train=400, seed=8)
    assert np.array_equal(a.matrix, b.matrix)
    q = pair["jpg"][::131]
    assert np.array_equal(a.to_raw(q), b.to_raw(q))
    assert np.array_equal(a.render(raw[::131]), b.render(raw[::131]))
    assert not np.array_equal(a.matrix, c.matrix)


def test_bad_input_is_refused_with_clear_messages(pair):
    raw, jpg = pair["raw"][:500], pair["jpg"][:500] / 255.0
    bad = raw.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        fit_pipeline(bad, jpg)
    with pytest.raises(InputError, match=r"shape \(n, 3\)"):
        fit_pipeline(raw[:, :2], jpg)
    with pytest.raises(InputError, match="rows"):
        fit_pipeline(raw, jpg[:400])
    with pytest.raises(InputError, match="divide"):
        fit_pipeline(raw, jpg * 255.0)
    with pytest.raises(CalibrationError, match="too few"):
        fit_pipeline(raw[:20], jpg[:20])
    grey = np.repeat(np.linspace(0.01, 0.9, 200)[:, None], 3, axis=1)
    with pytest.raises(CalibrationError, match="colour variety"):
        fit_pipeline(grey, grey ** 0.45)
    with pytest.raises(InputError, match="backward"):
        fit_pipeline(raw, jpg, PipelineOptions(backward="spline"))
    with pytest.raises(TypeError, match="n_set"):
        fit_pipeline(raw, jpg, n_set=3)                 # a misspelt knob is no option


def test_the_options_objects_are_the_one_way_to_set_the_knobs(pair, model):
    """The 0.x keyword forms are gone: a knob passed by name, PipelineModel's flat
    arguments and lattice_regression_lut's keywords are a TypeError."""
    raw, jpg = pair["raw"], pair["jpg"] / 255.0
    with pytest.raises(TypeError, match="n_sets"):
        fit_pipeline(raw, jpg, n_train=300, n_sets=2)
    with pytest.raises(TypeError):
        PipelineModel(model.matrix, model.tone_curves, model.forward_lut,
                      model.inverse_tone_curves, model.backward_lut)
    with pytest.raises(TypeError, match="forward_stages"):
        PipelineModel(None, None)
    grouped = PipelineModel(
        ForwardStages(model.matrix, model.tone_curves, model.forward_lut),
        BackwardStages(model.inverse_tone_curves, model.backward_lut, model.rbf,
                       model.clipped_corrections),
        backward=model.backward, diagnostics=model.diagnostics,
        training_colours=model.training_colours)
    assert grouped.to_dict() == model.to_dict()
    x = np.random.default_rng(0).uniform(0, 1, (300, 3))
    with pytest.raises(TypeError, match="affine"):
        lattice_regression_lut(x, x ** 1.1, smoothness=1.0, affine=False)


def test_model_methods_refuse_bad_arrays(model):
    with pytest.raises(InputError, match="3 channels"):
        model.render(np.zeros((4, 4)))
    with pytest.raises(InputError, match="NaN"):
        model.to_raw(np.full((2, 3), np.nan))
    with pytest.raises(InputError, match="variant"):
        model.to_raw(np.zeros((2, 3)), variant="spline")
    with pytest.raises(InputError, match="ambiguous"):
        model.to_raw(np.zeros((2, 3), dtype=np.int64))


def test_backward_lut_only_skips_the_rbf(pair):
    m = fit_pipeline(pair["raw"], pair["jpg"] / 255.0,
                     PipelineOptions(n_sets=2, backward="lut"), n_train=300)
    assert m.backward == "lut" and m.rbf is None
    with pytest.raises(InputError, match="RBF"):
        m.to_raw(pair["jpg"][:5], variant="rbf")


def test_one_shot_140_samples(pair):
    m = fit_pipeline(pair["raw"], pair["jpg"] / 255.0, PipelineOptions(n_sets=5),
                     n_train=140, seed=1)
    test = pair["test"]
    assert _rmse(m.render(pair["raw"][test]), pair["truth"][test]) * 255 < 6.0


# ---- baselines --------------------------------------------------------------------------

# slow: the two baselines' fits (benchmark peers, not the library's path)
@pytest.mark.slow
def test_baselines_fit_and_invert(pair):
    tr = pair["train"]
    raw, jpg = pair["raw"][tr], pair["jpg"][tr] / 255.0
    test = pair["test"][::5]
    for fit in (independent_polynomial_model, least_squares_rbf_model):
        b = fit(raw, jpg)
        assert _rmse(b.render(pair["raw"][test]), pair["truth"][test]) * 255 < 8
        ok = ~((pair["jpg"][test] == 0) | (pair["jpg"][test] == 255)).any(axis=1)
        assert _rmse(b.to_raw(pair["jpg"][test][ok]), pair["raw"][test][ok]) < 0.02


# ---- the NUS model reader ---------------------------------------------------------------

def _write_tiny_nus(folder: Path):
    """A 5-point NUS-format model: zero RBF weights, identity affine part, gamma 2 curve."""
    folder.mkdir()
    base = np.array([[1.5, -0.4, -0.1], [-0.2, 1.4, -0.2], [0.0, -0.5, 1.5]])
    gains = {3: np.array([1.3, 1.0, 2.2]), 14: np.array([1.8, 1.0, 2.0])}
    lines = [f"{len(gains)}"] + [" ".join(f"{v:.6f}" for v in r) for r in base]
    for code, g in gains.items():
        lines.append(str(code))
        lines += [" ".join(f"{v:.6f}" for v in r) for r in base * g]
        lines.append(" ".join(f"{v:.6f}" for v in g))
    centres = np.array([[0.1, 0.2, 0.3], [0.5, 0.5, 0.5], [0.9, 0.1, 0.2], [0.2, 0.8, 0.4],
                        [0.3, 0.3, 0.9]])
    coefs = np.vstack([np.zeros((5, 3)), np.zeros((1, 3)), np.eye(3)])
    table = np.repeat((np.arange(256) / 255.0)[:, None] ** 2, 3, axis=1)
    for d in ("raw2jpg", "jpg2raw"):
        (folder / f"{d}_transform.txt").write_text("\n".join(lines) + "\n")
        (folder / f"{d}_ctrlPoints.txt").write_text(
            "5\n" + "\n".join(" ".join(f"{v:.6f}" for v in r) for r in centres) + "\n")
        (folder / f"{d}_coefs.txt").write_text(
            "9\n" + "\n".join(" ".join(f"{v:.6f}" for v in r) for r in coefs) + "\n")
        (folder / f"{d}_respFcns.txt").write_text(
            "16400.0 0.0 0.0 0.0\n" + "\n".join(" ".join(f"{v:.6f}" for v in r)
                                                for r in table) + "\n")
        (folder / f"{d}_validRange.txt").write_text("5 252\n")
    return base, gains


def test_nus_reader_on_a_tiny_model_in_the_file_format(tmp_path):
    base, gains = _write_tiny_nus(tmp_path / "tiny")
    cam = read_nus_model(tmp_path / "tiny", wb_code=14)
    assert np.allclose(cam.transform, base * gains[14], atol=1e-6)
    assert cam.valid_range == (5, 252)
    rng = np.random.default_rng(0)
    raw = rng.uniform(0, 0.4, (100, 3))
    expected = np.sqrt(np.clip(raw @ (base * gains[14]).T, 0, 1))
    assert np.allclose(cam.render(raw), expected, atol=2e-4)
    assert np.allclose(cam(raw), cam.render(raw))
    codes = np.round(cam.render(raw) * 255).astype(np.uint8)
    inside = np.all(raw @ (base * gains[14]).T > 0.05, axis=1)
    assert _rmse(cam.to_raw(codes)[inside], raw[inside]) < 0.01
    assert read_nus_model(tmp_path / "tiny", direction="jpg2raw").direction == "jpg2raw"
    with pytest.raises(InputError, match="white-balance setting 7"):
        read_nus_model(tmp_path / "tiny", wb_code=7)
    with pytest.raises(InputError, match="no such"):
        read_nus_model(tmp_path / "missing")
    (tmp_path / "tiny" / "raw2jpg_coefs.txt").write_text("3\n1 2 3\n")
    with pytest.raises(InputError, match="coefs"):
        read_nus_model(tmp_path / "tiny")


@pytest.mark.skipif(not NUS.exists(), reason="../shared/data/nus_model_nikon_d7000 absent")
def test_nus_d7000_model_reads_and_inverts():
    cam = read_nus_model(NUS, wb_code=14)
    assert cam.inverse_response.shape == (256, 3)
    assert set(cam.white_balances) == {3, 4, 9, 10, 11, 14}
    rng = np.random.default_rng(0)
    wb = rng.uniform(0.03, 0.3, (300, 3))           # white-balanced raws
    raw = wb / cam.gains
    codes = np.round(cam.render(raw) * 255).astype(np.uint8)
    ok = ~((codes <= 5) | (codes >= 252)).any(axis=1)
    assert ok.mean() > 0.8
    # the published backward model undoes the published forward model
    assert _rmse(cam.to_raw(codes)[ok], raw[ok]) < 0.005


def test_closed_form_leave_one_out_matches_refitting():
    from scipy.interpolate import RBFInterpolator

    from selfcal.pipeline.rbf import rbf_leave_one_out

    rng = np.random.default_rng(6)
    c = rng.uniform(0, 1, (60, 3))
    y = np.sin(3 * c) + 0.02 * rng.standard_normal((60, 3))
    brute = []
    for i in range(60):
        keep = np.arange(60) != i
        r = RBFInterpolator(c[keep], y[keep], kernel="linear", degree=1, smoothing=1e-2)
        brute.append(y[i] - r(c[i:i + 1])[0])
    assert rbf_leave_one_out(c, y, (1e-2,))[1e-2] == pytest.approx(
        _rmse(np.array(brute), 0.0), rel=1e-8)
    # the lattice regression's hat-matrix shortcut (fixed regulariser weight)
    x = rng.uniform(0, 1, (80, 3))
    t = x + 0.05 * np.sin(4 * x) + 0.01 * rng.standard_normal((80, 3))
    lut = lattice_regression_lut(x, t, LatticeOptions(smoothness_grid=(0.05,)),
                                 smoothness="auto")
    assert set(lut.validation) == {0.05}
    assert lut.validation[0.05] > _rmse(x + lut.residual(x), t)   # held out > in sample


# ---- clipped pixels: E[raw | clipped code] from clipped training samples ----------------

def test_clipped_pixels_get_the_conditional_expectation(model, pair):
    """A clipped code does not determine the raw: the correction learned from the clipped
    training samples must bring clipped pixels closer than the backward model alone (which
    returns the smallest raw the code allows), and leave the other pixels alone."""
    import copy

    def without_correction(m):
        plain = copy.copy(m)
        plain.clipped_corrections = {}
        plain._code_tables = {}
        return plain

    # an over-exposed synthetic pair (4 % of pixels clipped, 2 % of raws saturated)
    p = sim.simulate_raw_jpeg_pair(seed=0, exposure=1.5, jpeg_quality=None)
    raw = p["raw"].reshape(-1, 3).astype(np.float64)
    codes = p["rendered"].reshape(-1, 3)
    m = fit_pipeline(raw, codes / 255.0, PipelineOptions(n_sets=3, backward="lut"),
                     n_train=800, seed=0)
    info = m.diagnostics["clipped_correction"]["lut"]
    assert info["samples"] >= 20 and info["kept"]
    clipped = ((codes == 0) | (codes == 255)).any(axis=1)
    corrected = m.to_raw(codes)
    before = without_correction(m).to_raw(codes)
    # clipped pixels: at least a quarter lower error (about 45 % lower on this pair)
    assert _rmse(corrected[clipped], raw[clipped]) < 0.75 * _rmse(before[clipped],
                                                                   raw[clipped])
    # unclipped pixels: untouched, bit for bit
    assert np.array_equal(corrected[~clipped], before[~clipped])
    # the float path applies the same correction
    assert np.max(np.abs(m.to_raw(codes[clipped] / 255.0) - corrected[clipped])) < 1e-4

    # the fixture model (1,500 samples of the default pair, 17 of them clipped)
    assert model.diagnostics["clipped_correction"]["rbf"]["samples"] >= 5
    jpg = pair["jpg"][pair["test"]]
    clipped = ((jpg == 0) | (jpg == 255)).any(axis=1)
    plain = without_correction(model)
    for variant in ("lut", "rbf"):
        a, b = model.to_raw(jpg, variant=variant), plain.to_raw(jpg, variant=variant)
        assert np.array_equal(a[~clipped], b[~clipped])
        assert _rmse(a[clipped], pair["raw"][pair["test"]][clipped]) < _rmse(
            b[clipped], pair["raw"][pair["test"]][clipped])
    # held-out scores over all training samples pool the clipped ones' in
    pooled = model.diagnostics["backward_validation_rmse"]
    unclipped = model.diagnostics["backward_validation_rmse_unclipped"]
    assert all(pooled[v] > unclipped[v] for v in pooled)


def test_clipped_correction_is_chosen_by_held_out_error():
    from selfcal.pipeline.clipped import ClippedCorrection, clipped_pixel_correction

    rng = np.random.default_rng(11)
    # clipped samples on the face P_R = 1: the missing raw grows with P_G
    p = np.column_stack([np.ones(60), rng.uniform(0, 1, 60), rng.uniform(0, 1, 60)])
    resid = np.column_stack([0.2 * p[:, 1], np.zeros(60), np.zeros(60)])
    resid += 0.01 * rng.standard_normal((60, 3))
    corr, scores = clipped_pixel_correction(p, resid)
    assert isinstance(corr, ClippedCorrection)
    assert min(scores.values()) < 0.3 * scores["none"]
    q = np.column_stack([np.ones(5), np.linspace(0.1, 0.9, 5), np.full(5, 0.5)])
    assert np.allclose(corr(q)[:, 0], 0.2 * q[:, 1], atol=0.03)
    # the residual grows with P_G, which a constant correction (h = inf) cannot follow: the
    # held-out choice is a local kernel, and far from every clipped training sample (here a
    # whole code cube away, at P_R = 0) that correction fades out to none
    assert np.isfinite(corr.bandwidth)
    assert scores[f"{corr.bandwidth:g},{corr.prior_weight:g}"] < min(
        v for k, v in scores.items() if k.startswith("inf,"))
    assert np.all(np.abs(corr(np.array([[0.0, 0.5, 0.5]]))) < 0.05)
    # residuals without structure (zero-mean noise): no correction, or a negligible one
    noise = 0.05 * rng.standard_normal((60, 3))
    weak = clipped_pixel_correction(p, noise)[0]
    assert weak is None or np.abs(weak(q)).max() < 0.02
    # too few clipped samples: none
    assert clipped_pixel_correction(p[:2], resid[:2]) == (None, {})
    # model-file round trip
    again = ClippedCorrection.from_dict(corr.to_dict())
    assert np.array_equal(again(q), corr(q))


def test_top_code_without_clipped_training_samples_stands_for_sensor_white(tmp_path):
    """No training sample at 255: a 255 is read as the white whose largest raw channel is
    saturated (ρ_w ∝ M⁻¹ 1), over the last half code only; with samples there, no prior."""
    import copy

    p = sim.simulate_raw_jpeg_pair(seed=0, exposure=1.5, jpeg_quality=None)
    raw = p["raw"].reshape(-1, 3).astype(np.float64)
    codes = p["rendered"].reshape(-1, 3)
    top = (codes == 255).any(axis=1)
    rng = np.random.default_rng(0)
    idx = rng.choice(np.flatnonzero(~top & (raw.max(axis=1) < 0.7)), 800, replace=False)
    m = fit_pipeline(raw[idx], codes[idx] / 255.0, PipelineOptions(n_sets=3, backward="lut"),
                     seed=0)
    inv = m.inverse_tone_curves
    assert inv.top is not None
    white = np.linalg.solve(m.matrix, np.ones(3))
    white /= white.max()
    np.testing.assert_allclose(inv.top, (m.matrix @ white)[0], rtol=1e-9)
    # (up to the backward LUT's residual correction there)
    at_white = m.to_raw(np.array([[255, 255, 255]], np.uint8))[0]
    np.testing.assert_allclose(at_white, white, atol=0.06)
    assert at_white.max() > 0.98
    # codes below the top are the polynomial's, exactly
    plain = copy.deepcopy(inv)
    plain.top = None
    x = np.linspace(0, 254 / 255, 300)[:, None].repeat(3, 1)
    assert np.array_equal(inv(x), plain(x))
    # at the top: the white where the polynomial falls short of it, else the polynomial
    np.testing.assert_allclose(inv(np.ones((1, 3)))[0],
                               np.maximum(plain(np.ones((1, 3)))[0], inv.top))
    assert np.any(inv.top > plain(np.ones((1, 3)))[0])
    # clipped pixels of the whole image come closer to their raw than without the prior
    without = copy.copy(m)
    without.inverse_tone_curves = plain
    without._tables, without._code_tables = {}, {}
    assert _rmse(m.to_raw(codes)[top], raw[top]) < _rmse(without.to_raw(codes)[top], raw[top])
    # saved and loaded with the model
    loaded = selfcal.load_model(m.save(tmp_path / "m.json"))
    np.testing.assert_array_equal(loaded.inverse_tone_curves.top, inv.top)
    # training samples at 255 in every channel: they decide, no prior
    idx2 = rng.choice(codes.shape[0], 1500, replace=False)
    assert (codes[idx2] == 255).any(axis=0).all()
    m2 = fit_pipeline(raw[idx2], codes[idx2] / 255.0,
                      PipelineOptions(n_sets=3, backward="lut"), seed=0)
    assert m2.inverse_tone_curves.top is None
