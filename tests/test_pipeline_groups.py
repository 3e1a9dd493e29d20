"""Several RAW+JPEG pairs at once: ``calibrate_pipeline`` and ``calibrate`` give
``fit_pipeline`` one group per pair, so its regulariser weights are chosen by
leave-one-scene-out (the weight that predicts a scene the fit did not see)."""

from __future__ import annotations

import numpy as np
import pytest

import selfcal
import selfcal.choose.paths
from selfcal import sim
from selfcal.io import write_image
from selfcal.pipeline.pairs import collect_pair_samples
from selfcal.pipeline import PipelineOptions, lattice_regression_lut

#: fast options (two matrix sets, the lattice backward variant, a small baked table); the
#: forward LUT weight stays "auto", so it is chosen by held-out error over the groups.
FAST = PipelineOptions(n_sets=2, backward="lut", bake_size=17, inverse_smoothness=1e-4)


@pytest.fixture(scope="module")
def two_pairs():
    """One simulated camera, two scenes of different content (a chart-and-ramps scene and
    a natural one) and size (so calibrate does not take them for a bracketed stack)."""
    from selfcal.sim import conditions

    camera = sim.default_pipeline(seed=0)
    scenes = [sim.make_scene(96, 144, dynamic_range_stops=7.0, saturation=0.6, seed=1),
              conditions.natural_scene(112, 160, palette="colourful", seed=2)]
    return [sim.simulate_raw_jpeg_pair(s, camera, exposure=e, seed=k)
            for k, (s, e) in enumerate(zip(scenes, (1.0, 0.6)))]


def _scene_fold_lut(model, raw, rendered, groups):
    """The forward LUT refitted on the model's own ``f(M ρ)`` of its samples with
    ``groups`` as folds (None: leave-one-sample-out): what fit_pipeline's last forward step
    does ([Gong2018] §3.4 lattice regression; the weight by held-out error is ours)."""
    y = np.clip(model.tone_curves(raw @ model.matrix.T), 0.0, 1.0)
    return lattice_regression_lut(y, rendered, smoothness="auto", groups=groups)


def test_two_pairs_are_two_groups_and_the_weights_come_from_scene_folds(two_pairs, fit_calls):
    raws = [p["raw"] for p in two_pairs]
    jpgs = [p["rendered"] for p in two_pairs]
    model = selfcal.calibrate_pipeline(raws, jpgs, seed=0, options=FAST)
    raw, ren, options = fit_calls[-1]
    # one label per sample, one group per pair, in the order of the pairs
    expected, _ = collect_pair_samples(raws, jpgs, seed=0, max_samples=20_000)
    assert np.array_equal(options["groups"], expected.groups)
    per_pair = np.bincount(expected.groups).tolist()
    assert len(per_pair) == 2 and min(per_pair) >= 50
    d = model.diagnostics
    assert d["groups"] == per_pair
    assert "leave-one-scene-out over 2 groups" in d["validation"]
    # the forward LUT's held-out errors are those of the scene folds, not of single samples
    by_scene = _scene_fold_lut(model, raw, ren, options["groups"])
    by_sample = _scene_fold_lut(model, raw, ren, None)
    got = model.forward_lut.validation
    assert got.keys() == by_scene.validation.keys()
    np.testing.assert_allclose([got[k] for k in got],
                               [by_scene.validation[k] for k in got], rtol=1e-6)
    assert not np.allclose([got[k] for k in got], [by_sample.validation[k] for k in got],
                           rtol=1e-3)
    assert model.forward_lut.smoothness == by_scene.smoothness
    # scene folds predict a scene the fit did not see: their held-out error is the larger
    assert min(got.values()) > min(by_sample.validation.values())


def test_one_pair_keeps_leave_one_sample_out(two_pairs, fit_calls):
    p = two_pairs[0]
    model = selfcal.calibrate_pipeline(p["raw"], p["rendered"], seed=0, options=FAST)
    assert "groups" not in fit_calls[-1][2]
    assert model.diagnostics["groups"] is None
    assert "leave-one-out" in model.diagnostics["validation"]


def test_groups_cannot_be_passed_by_the_caller(two_pairs):
    p = two_pairs[0]
    with pytest.raises(TypeError, match="groups"):
        selfcal.calibrate_pipeline(p["raw"], p["rendered"], groups=np.zeros(10), options=FAST)


def test_calibrate_on_two_pair_files_fits_by_scene(tmp_path, two_pairs, fit_calls):
    paths = []
    for k, p in enumerate(two_pairs):
        raw_path = tmp_path / f"SCENE{k}.tiff"
        write_image(raw_path, (p["raw"].astype(np.float64) * 65535).round().astype(np.uint16))
        paths += [raw_path, write_image(tmp_path / f"SCENE{k}.jpg", p["rendered"],
                                        jpeg_quality=95)]
    result = selfcal.calibrate(paths, pipeline_options=FAST)
    assert result.taken == ("pipeline",) and len(result.pairs) == 2
    _, _, options = fit_calls[-1]
    counts = np.bincount(options["groups"]).tolist()
    assert len(counts) == 2 and sum(counts) == result.n_pipeline_samples
    assert result.pipeline.diagnostics["groups"] == counts
    assert result.reasons[-1].endswith("leave-one-scene-out over 2 pairs")
