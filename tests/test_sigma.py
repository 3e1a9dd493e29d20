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
    from selfcal.sim.scoring import truth_masks

    e_true, scored, *_ = truth_masks(stack)
    keep = scored & ~merged.unmeasured[..., None]
    # σ is relative to the radiance's scale (the band's floor, a shift of the whole
    # curve, is the scale's σ, said apart): compare after one global scale ...
    log_scale = float(np.median(np.log(e_true[keep] / merged.radiance[keep])))
    scaled = np.exp(log_scale) * merged.radiance
    ratio = np.abs(scaled - e_true)[keep] / (np.exp(log_scale) * merged.sigma[keep])
    assert 0.3 < np.median(ratio) < 1.2
    # ... and the scale itself is off by about the scale's σ (a few of it at most)
    scale_sigma = merged.diagnostics["sigma_scale_log"]
    assert 0.005 < scale_sigma < 0.1
    assert abs(log_scale) < 4 * scale_sigma


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


def test_packed_lookup_returns_both_tables_bit_for_bit():
    # σ's two terms ride in one float64 table (two float32 side by side): the lookup must
    # copy their bits, zeros, denormals and extremes included
    from selfcal.hdr.weights import packed_lookup as _lookup
    from selfcal.hdr.weights import packed_table as _packed

    rng = np.random.default_rng(3)
    pairs = (rng.standard_normal((256, 3, 2)) * 10.0 ** rng.integers(-40, 38, (256, 3, 2))
             ).astype(np.float32)
    pairs[:8] = 0.0
    pairs[8:16, :, 1] = 0.0                       # float64 denormals
    pairs[16:24, :, 0] = np.float32(1e-45)
    pairs[24] = np.finfo(np.float32).max
    codes = rng.integers(0, 256, (37, 41, 3), dtype=np.uint8)
    codes[0, :3] = np.arange(256)[:, None][[0, 9, 24]]
    table = _packed(pairs)
    for c in (codes, codes.astype(np.uint16)):
        out = _lookup(c, table, np.empty(c.shape, np.float64))
        got = out.view(np.float32).reshape(c.shape + (2,))
        want = pairs[c, np.arange(3)]
        np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


def test_sigma_sums_against_an_independent_float64_sum(model):
    # SigmaSums' packed float32 sums and its σ against the formula of the module docstring
    # summed in float64 from the same tables (relative error of float32 sums: < 1e-5)
    from dataclasses import replace

    from selfcal.stack.frames import frame_limits
    from selfcal.hdr.sigma import SigmaSums
    from selfcal.hdr.weights import DEFAULT_NOISE, FrameTables, noise_variance
    from selfcal.stack.frames import Lineariser

    rng = np.random.default_rng(4)
    h, w, times = 23, 31, [0.01, 0.04, 0.16]
    lin = Lineariser(model, False, 255)
    lo, hi, floor = frame_limits(255, 2.0, False, None)
    sums = SigmaSums((h, w), model)
    sums.kappa = 1.7
    var = np.zeros((h, w, 3))
    cur = np.zeros((h, w, 3))
    den = np.zeros((h, w, 3), dtype=np.float32)
    x_axis = np.arange(256) / 255
    band = np.stack([np.interp(x_axis, model.intensity, model.inverse_log_sigma[:, c])
                     for c in range(3)], axis=-1)
    # less its floor below 95 % of white, in quadrature (the scale's share)
    floor = band[1:int(0.95 * 255)].min(axis=0)
    band = np.sqrt(np.maximum(band ** 2 - floor ** 2, 0.0))
    for e in times:
        tab = FrameTables(lin, e, "noise", DEFAULT_NOISE, lo, hi, False, max(times), floor)
        sums.prepare(tab)
        codes = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        codes[:3] = 255                                  # never measured: σ = inf
        for s in (slice(0, 10), slice(10, h)):
            sums.add(s, codes[s], tab)
        wt = tab.w_table.astype(np.float64)[codes, np.arange(3)]
        x = lin.table[codes, np.arange(3)]
        v = noise_variance(x, lin.slope[codes, np.arange(3)], e,
                           replace(DEFAULT_NOISE, relative=0.0), code_std=lin.code_std())
        X = x / e
        if tab.code_error is not None:
            v = v + (X * tab.code_error[codes, np.arange(3)]) ** 2
        var += wt * wt * (v + (X * sums.sigma_t) ** 2)
        cur += wt * X * band[codes, np.arange(3)]
        den += tab.w_table[codes, np.arange(3)]
    np.testing.assert_allclose(sums.sums[..., 0], var, rtol=1e-5)
    np.testing.assert_allclose(sums.sums[..., 1], cur, rtol=1e-5)
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.sqrt(1.7 ** 2 * var / den.astype(np.float64) ** 2 + (cur / den) ** 2)
    sums.finish_strip(slice(0, h), den)
    measured = np.isfinite(want)
    assert np.all(np.isinf(den[:3])) and not measured[:3].any() and measured[3:].all()
    np.testing.assert_allclose(den[measured], want[measured], rtol=1e-5)


def test_trend_term_against_an_independent_float64_sum():
    from selfcal.hdr.sigma import add_trend_term

    rng = np.random.default_rng(7)
    radiance = rng.uniform(0.01, 50.0, (70, 40, 3)).astype(np.float32)
    sigma = (0.03 * radiance).astype(np.float32)
    sigma[:2] = np.inf                              # unmeasured stays so
    before = sigma.astype(np.float64)
    centre = add_trend_term(sigma, radiance, 0.02, rows=16)
    sample = radiance[::8, ::8][np.isfinite(before[::8, ::8])]
    assert centre == pytest.approx(np.median(np.log(sample)), rel=1e-6)
    e = radiance.astype(np.float64)
    want = np.sqrt(before ** 2 + (e * 0.02 * (np.log(e) - centre)) ** 2)
    np.testing.assert_allclose(sigma[2:], want[2:], rtol=1e-5)
    assert np.all(np.isinf(sigma[:2]))
    # far from the scale's centre σ grows; at it, it is unchanged
    assert np.all(sigma >= before.astype(np.float32) * (1 - 1e-6))
