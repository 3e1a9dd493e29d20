"""The radiance's standard deviation (selfcal.hdr.sigma) and its files."""

from __future__ import annotations

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.hdr import MergeOptions

TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8]


@pytest.fixture(scope="module")
def stack():
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=5)
    scene = sim.make_scene(128, 192, saturation=0.5, dynamic_range_stops=14, seed=5)
    return sim.simulate_stack(scene, pipe, TIMES, jitter=0.03, jpeg_quality=90, seed=5)


@pytest.fixture(scope="module")
def model(stack):
    return selfcal.calibrate_response(stack.images, TIMES)


@pytest.fixture(scope="module")
def merged(stack, model):
    return selfcal.merge_hdr(stack.images, TIMES, model, options=MergeOptions(sigma=True))


def test_sigma_is_shaped_like_the_radiance_and_leaves_it_alone(stack, model, merged):
    plain = selfcal.merge_hdr(stack.images, TIMES, model)
    assert plain.sigma is None
    np.testing.assert_array_equal(plain.radiance, merged.radiance)
    s = merged.sigma
    assert s.dtype == np.float32 and s.shape == merged.radiance.shape
    measured = ~merged.unmeasured
    assert np.all(np.isfinite(s[measured])) and np.all(s[measured] > 0)
    assert np.all(np.isinf(s[merged.unmeasured]))
    assert merged.diagnostics["sigma_curve_band"] is True


def test_sigma_predicts_the_error_against_the_truth(stack, merged):
    # |merge − truth| / σ: 0.674 in the median for a perfect Gaussian σ; a σ ten times
    # too small or too large is far outside this range
    from bench.bench_hdr_synthetic import truth_masks

    e_true, scored, *_ = truth_masks(stack)
    keep = scored & ~merged.unmeasured[..., None]
    ratio = np.abs(merged.radiance - e_true)[keep] / merged.sigma[keep]
    assert 0.2 < np.median(ratio) < 1.5


def test_sigma_without_a_band_has_no_curve_term(stack, model, merged):
    from dataclasses import replace

    bare = replace(model, inverse_log_sigma=None)
    r = selfcal.merge_hdr(stack.images, TIMES, bare, options=MergeOptions(sigma=True))
    measured = ~r.unmeasured
    assert r.diagnostics["sigma_curve_band"] is False
    assert np.all(r.sigma[measured] <= merged.sigma[measured] * (1 + 1e-5))


def test_linear_frames_get_a_sigma():
    rng = np.random.default_rng(0)
    scene = rng.uniform(0.01, 4.0, (40, 50, 3)).astype(np.float32)
    frames = [np.clip(scene * t, 0, 1).astype(np.float32) for t in (0.25, 1.0)]
    r = selfcal.merge_hdr(frames, [0.25, 1.0], linear=True, options=MergeOptions(sigma=True))
    assert r.sigma.shape == r.radiance.shape
    assert np.all(np.isfinite(r.sigma[~r.unmeasured]))


def test_exr_sigma_layer_read_back_by_the_openexr_bindings(merged, tmp_path):
    OpenEXR = pytest.importorskip("OpenEXR")
    from selfcal.hdr.io import read_radiance, write_radiance_sigma

    path = tmp_path / "out.exr"
    write_radiance_sigma(path, merged.radiance, merged.sigma)
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        chans = exr.channels()
        assert {"R", "G", "B", "sigma.R", "sigma.G", "sigma.B"} <= set(chans)
        sig = np.stack([chans[f"sigma.{c}"].pixels for c in "RGB"], axis=-1)
    np.testing.assert_array_equal(sig, merged.sigma)
    np.testing.assert_array_equal(read_radiance(path), merged.radiance)   # OpenCV reads it


def test_cli_merge_sigma_writes_a_tiff_beside_a_tiff(stack, tmp_path):
    from selfcal_cli.main import main

    folder = tmp_path / "stack"
    paths = stack.write(folder)
    out = tmp_path / "out.tif"
    assert main(["merge", *map(str, paths), "-o", str(out), "--sigma"]) == 0
    from selfcal.hdr.io import read_radiance, read_sigma

    sig = read_sigma(out)
    assert (tmp_path / "out.sigma.tiff").is_file()
    assert sig.shape == read_radiance(out).shape


def test_noise_scale_is_measured_and_recorded(merged):
    kappa = merged.diagnostics["sigma_noise_scale"]
    assert 0.25 <= kappa <= 4.0
