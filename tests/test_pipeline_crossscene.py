"""The RAW-path model across scenes: training colours kept in the model and the
mask of pixels outside them, several pairs with leave-one-scene-out regulariser weights."""

from __future__ import annotations

import json

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.errors import InputError
from selfcal.pipeline.pairs import PairSamples, collect_pair_samples
from selfcal.pipeline import (LatticeOptions, PipelineOptions, fit_pipeline,
                              lattice_regression_lut, monotone_tone_curves)
from selfcal.pipeline.rbf import rbf_inverse_colour_mapping, rbf_leave_one_out
from selfcal.pipeline.trust import TRUST_RADIUS, TrainingColours
from conftest import dim_training_pixels


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


@pytest.fixture(scope="module")
def scene_pair():
    """A simulated pair whose training half holds only dim, weakly coloured pixels."""
    raw, jpg, pick = dim_training_pixels()
    model = fit_pipeline(raw[pick], jpg[pick] / 255.0, PipelineOptions(n_sets=3, backward="lut"),
                         seed=0)
    return {"raw": raw, "jpg": jpg, "pick": pick, "model": model}


def test_training_pixels_are_inside_and_a_far_colour_is_outside(scene_pair):
    m, raw, jpg, pick = (scene_pair[k] for k in ("model", "raw", "jpg", "pick"))
    assert not m.outside_training(raw[pick], "raw").any()
    assert not m.outside_training(jpg[pick], "rendered").any()          # uint8 codes
    assert not m.outside_training(jpg[pick] / 255.0, "rendered").any()  # floats
    far_raw = np.array([[0.95, 0.02, 0.02], [0.9, 0.9, 0.9]])
    far_jpg = np.array([[250, 5, 5], [254, 254, 254]], dtype=np.uint8)
    assert m.outside_training(far_raw, "raw").all()
    assert m.outside_training(far_jpg, "rendered").all()
    # render / to_raw hand the same masks back beside their outputs, in the input's shape
    img = raw[pick[:96]].reshape(8, 12, 3)
    out, mask = m.render(img, return_mask=True)
    assert out.shape == img.shape and mask.shape == (8, 12) and not mask.any()
    back, mask = m.to_raw(far_jpg.reshape(1, 2, 3), return_mask=True)
    assert back.shape == (1, 2, 3) and mask.shape == (1, 2) and mask.all()
    # the table test agrees with the exact distance away from the radius
    d = m.training_colours.distance(raw, "raw")
    clear = np.abs(d - TRUST_RADIUS) > 0.02
    assert np.array_equal(m.outside_training(raw, "raw")[clear], (d > TRUST_RADIUS)[clear])


def test_saved_model_keeps_its_training_colours(tmp_path, scene_pair):
    m, raw = scene_pair["model"], scene_pair["raw"]
    path = tmp_path / "camera.json"
    m.save(path)
    loaded = selfcal.load_model(path)
    tc, lc = m.training_colours, loaded.training_colours
    assert np.array_equal(lc.raw, tc.raw) and np.array_equal(lc.rendered, tc.rendered)
    assert lc.radius == tc.radius and lc.raw_scale == tc.raw_scale
    assert np.array_equal(loaded.outside_training(raw, "raw"), m.outside_training(raw, "raw"))
    assert np.array_equal(loaded.render(raw[::50]), m.render(raw[::50]))


def test_a_model_file_without_training_colours_still_loads(tmp_path, scene_pair):
    m, raw, jpg = scene_pair["model"], scene_pair["raw"], scene_pair["jpg"]
    path = tmp_path / "old.json"
    m.save(path)
    doc = json.loads(path.read_text())
    del doc["training_colours"]               # a file written before they were kept
    path.write_text(json.dumps(doc))
    old = selfcal.load_model(path)
    assert old.training_colours is None and old.outside_training(raw) is None
    out, mask = old.render(raw[:10], return_mask=True)
    assert mask is None and np.array_equal(out, m.render(raw[:10]))
    back, mask = old.to_raw(jpg[:10], return_mask=True)
    assert mask is None and np.array_equal(back, m.to_raw(jpg[:10]))


def test_training_colours_keep_the_hull_vertices_and_refuse_bad_input():
    rng = np.random.default_rng(1)
    raw = rng.uniform(0.01, 0.5, (5000, 3))
    tc = TrainingColours.from_samples(raw, raw ** 0.45, max_points=300)
    assert tc.raw.shape == (300, 3)
    from scipy.spatial import ConvexHull

    hull = raw[ConvexHull(raw).vertices]
    kept = {tuple(r) for r in tc.raw}
    assert all(tuple(v) in kept for v in hull)
    with pytest.raises(InputError, match="kind"):
        tc.outside(raw, "linear")
    with pytest.raises(InputError, match="radius"):
        TrainingColours(raw[:5], raw[:5], 1.0, radius=0.0)


# ---- several pairs: leave-one-scene-out ---------------------------------------------

def test_lattice_leave_one_group_out_matches_refitting():
    from selfcal.pipeline.lattice import LatticeLUT, trilinear_weights

    rng = np.random.default_rng(4)
    x = rng.uniform(0, 1, (240, 3))
    y = x + 0.05 * np.sin(4 * x) + 0.01 * rng.standard_normal((240, 3))
    groups = np.repeat([5, 7, 9], 80)            # any labels
    lut = lattice_regression_lut(x, y, LatticeOptions(smoothness_grid=(0.01, 0.1)),
                                 smoothness="auto", groups=groups)
    assert set(lut.validation) == {0.01, 0.1}

    def data_weight(xs):   # trace(WᵀW): the regulariser weight is relative to it
        grid = LatticeLUT(np.zeros((5, 5, 5, 3)), np.zeros(3), np.ones(3))
        return trilinear_weights(grid.coordinates(xs), 5).power(2).sum()

    for s in (0.01, 0.1):
        resid = []
        for g in (5, 7, 9):
            out = groups == g
            # refit without the group, at the same absolute regulariser weight
            rel = s * data_weight(x) / data_weight(x[~out])
            fit = lattice_regression_lut(x[~out], y[~out], smoothness=rel)
            resid.append(x[out] + fit.residual(x[out]) - y[out])
        assert lut.validation[s] == pytest.approx(_rmse(np.concatenate(resid), 0.0),
                                                  rel=1e-6)
    assert lut.smoothness == min(lut.validation, key=lut.validation.get)


def test_rbf_leave_one_group_out_matches_refitting():
    from scipy.interpolate import RBFInterpolator

    rng = np.random.default_rng(6)
    c = rng.uniform(0, 1, (60, 3))
    y = np.sin(3 * c) + 0.02 * rng.standard_normal((60, 3))
    groups = np.arange(60) % 3
    brute = np.empty_like(y)
    for g in range(3):
        out = groups == g
        r = RBFInterpolator(c[~out], y[~out], kernel="linear", degree=1, smoothing=1e-2)
        brute[out] = y[out] - r(c[out])
    got = rbf_leave_one_out(c, y, (1e-2,), groups=groups)[1e-2]
    assert got == pytest.approx(_rmse(brute, 0.0), rel=1e-8)
    # one group is plain leave-one-out; a wrong length is refused
    assert rbf_leave_one_out(c, y, (1e-2,), groups=np.zeros(60)) == \
        rbf_leave_one_out(c, y, (1e-2,))
    with pytest.raises(InputError, match="labels"):
        rbf_leave_one_out(c, y, (1e-2,), groups=np.zeros(7))
    mapping = rbf_inverse_colour_mapping(c, y, groups=groups)
    assert mapping.smoothing == min(mapping.validation, key=mapping.validation.get)


def test_tone_curve_folds_are_the_groups():
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1, (300, 3))
    y = x ** 0.5 + 0.01 * rng.standard_normal((300, 3))
    folds = np.repeat([0, 1], 150)
    a = monotone_tone_curves(x, y, smoothness="auto", folds=folds)
    b = monotone_tone_curves(x, y, smoothness="auto")
    assert a.validation != b.validation          # other folds, other held-out errors
    with pytest.raises(InputError, match="labels"):
        monotone_tone_curves(x, y, smoothness="auto", folds=folds[:10])


def test_pairs_carry_their_group_and_the_fit_uses_it():
    pairs = [sim.simulate_raw_jpeg_pair(
        sim.make_scene(64, 96, dynamic_range_stops=7.0, saturation=0.5, seed=s), seed=s)
        for s in (0, 1)]
    samples, _ = collect_pair_samples([p["raw"] for p in pairs],
                                      [p["rendered"] for p in pairs], seed=0)
    assert set(np.unique(samples.groups)) == {0, 1}
    one = collect_pair_samples([pairs[0]["raw"]], [pairs[0]["rendered"]], seed=0)[0]
    assert np.array_equal(one.groups, np.zeros(len(one)))
    joined = PairSamples.concatenate([one, one, one])
    assert np.array_equal(joined.groups, np.repeat([0, 1, 2], len(one)))
    m = fit_pipeline(samples.raw, samples.rendered, PipelineOptions(n_sets=2, backward="lut"),
                     groups=samples.groups)
    d = m.diagnostics
    assert "leave-one-scene-out over 2" in d["validation"]
    assert d["groups"] == np.bincount(samples.groups).tolist()
    # the forward LUT weight is the leave-one-scene-out minimum
    assert m.forward_lut.smoothness == min(m.forward_lut.validation,
                                           key=m.forward_lut.validation.get)
    with pytest.raises(InputError, match="one label per sample"):
        fit_pipeline(samples.raw, samples.rendered, groups=samples.groups[:5])


def test_neutral_weighting_is_checked_and_recorded(scene_pair):
    raw, jpg, pick = scene_pair["raw"], scene_pair["jpg"], scene_pair["pick"]
    with pytest.raises(InputError, match="neutral_weighting"):
        fit_pipeline(raw[pick], jpg[pick] / 255.0, PipelineOptions(neutral_weighting=0.0))
    m = fit_pipeline(raw[pick], jpg[pick] / 255.0,
                     PipelineOptions(n_sets=2, backward="lut", neutral_weighting=0.3))
    assert m.diagnostics["neutral_weighting"] == 0.3


def test_highlight_stretch_zero_is_the_identity():
    from selfcal.pipeline.lattice import highlight_stretch, highlight_stretch_inverse

    x = np.linspace(0, 1, 11)
    assert np.array_equal(highlight_stretch(x, 0.0), x)
    assert np.array_equal(highlight_stretch_inverse(x, 0.0), x)
    assert highlight_stretch(0.5, 1.5) < 0.5        # [Gong2018]'s g lifts highlights
