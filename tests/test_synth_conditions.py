"""The benchmark condition matrix (selfcal.sim.conditions): each cell does what its name says."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from selfcal import sim
from selfcal.errors import InputError
from selfcal.sim.conditions import (
    CONDITIONS,
    SCENES,
    Condition,
    ModelCamera,
    channel_curves,
    natural_scene,
)

SIZE = (96, 144)
LUMA = np.array([0.2126, 0.7152, 0.0722])
CURVE = sim.ToneCurve.film(contrast=1.1, toe=0.05, shoulder=0.85)


def _stack(name, seed=5, curve=CURVE):
    return CONDITIONS[name].simulate(curve, seed, size=SIZE)


def _sof_sampling(jpeg: bytes) -> list:
    """(H, V) sampling factors of each component, from the JPEG's SOF0/SOF2 segment."""
    i = 2
    while i < len(jpeg):
        marker, length = jpeg[i + 1], struct.unpack(">H", jpeg[i + 2:i + 4])[0]
        if marker in (0xC0, 0xC2):
            n = jpeg[i + 9]
            comps = jpeg[i + 10:i + 10 + 3 * n]
            return [(comps[3 * k + 1] >> 4, comps[3 * k + 1] & 15) for k in range(n)]
        i += 2 + length
    raise AssertionError("no SOF segment")


def _chroma_detail(rgb: np.ndarray) -> float:
    """Energy of Cb, Cr (BT.601) not explained by their 2×2 block means."""
    x = rgb.astype(np.float64)
    y = x @ np.array([0.299, 0.587, 0.114])
    c = np.stack([x[..., 2] - y, x[..., 0] - y], axis=-1)
    h, w = (c.shape[0] // 2) * 2, (c.shape[1] // 2) * 2
    c = c[:h, :w]
    means = c.reshape(h // 2, 2, w // 2, 2, 2).mean(axis=(1, 3))
    return float(np.mean((c - np.repeat(np.repeat(means, 2, 0), 2, 1)) ** 2))


def _luma_detail(rgb: np.ndarray) -> float:
    y = rgb.astype(np.float64) @ LUMA
    return float(np.mean((y - gaussian_filter(y, 1.0)) ** 2))


# --------------------------------------------------------------------------------------
# the matrix
# --------------------------------------------------------------------------------------

def test_matrix_names_say_what_the_cells_are():
    assert {c.scene for c in CONDITIONS.values()} == set(SCENES)
    for name, cell in CONDITIONS.items():
        scene, variant = name.split("/")
        assert cell.name == name and cell.scene == scene
        assert cell.chroma_subsampling == ("4:4:4" if variant == "jpeg444" else "4:2:0")
        assert cell.sharpen == (variant in ("sharpened", "hard"))
        assert cell.per_channel == (variant in ("per-channel", "hard"))
        assert cell.gamut == ("clip" if variant == "clip-gamut" else "smooth")
        assert cell.jitter == 0.03 and cell.exposure_times == sim.DEMO_EXPOSURE_TIMES
    assert len(CONDITIONS) == 14


@pytest.mark.parametrize("name", list(CONDITIONS))
def test_every_cell_simulates_six_nominal_shots_deterministically(name):
    a = _stack(name)
    b = _stack(name)
    assert a.condition == name and len(a.images) == 6
    assert a.images[0].shape == (*SIZE, 3) and a.images[0].dtype == np.uint8
    np.testing.assert_array_equal(a.exposure_times, sim.DEMO_EXPOSURE_TIMES)
    assert 75 <= a.params["jpeg_quality"] <= 95 and a.jpeg_quality == a.params["jpeg_quality"]
    for x, y in zip(a.images, b.images):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.true_exposures, b.true_exposures)
    c = _stack(name, seed=6)
    assert any(not np.array_equal(x, y) for x, y in zip(a.images, c.images))
    # the frames get brighter with exposure and the longest one clips somewhere
    means = [im.mean() for im in a.images]
    assert np.all(np.diff(means) > 0) and (a.images[-1] == 255).any()


def test_one_seed_draws_the_same_camera_in_every_cell():
    a, b = _stack("saturated/base"), _stack("saturated/jpeg444")
    assert a.params == b.params
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.true_exposures, b.true_exposures)
    assert {CONDITIONS[n].draw(3)["jpeg_quality"] for n in CONDITIONS} == {
        CONDITIONS["neutral/base"].draw(3)["jpeg_quality"]}
    qualities = {Condition("x").draw(seed)["jpeg_quality"] for seed in range(60)}
    assert min(qualities) >= 75 and max(qualities) <= 95 and len(qualities) > 10


def test_jitter_changes_the_true_times_not_the_nominal_ones():
    stack = _stack("colourful/base")
    ratio = stack.true_exposures / stack.exposure_times
    assert np.all(np.abs(ratio - 1) <= 0.03) and np.abs(ratio - 1).max() > 0.005
    np.testing.assert_array_equal(stack.exposure_times, sim.DEMO_EXPOSURE_TIMES)
    other = _stack("colourful/base", seed=7)
    assert not np.array_equal(other.true_exposures, stack.true_exposures)


# --------------------------------------------------------------------------------------
# JPEG chroma, sharpening
# --------------------------------------------------------------------------------------

def test_chroma_420_is_subsampled_and_444_is_not():
    a, b = _stack("saturated/base"), _stack("saturated/jpeg444")
    assert a.chroma_subsampling == "4:2:0" and b.chroma_subsampling == "4:4:4"
    assert _sof_sampling(a.jpeg_bytes[0]) == [(2, 2), (1, 1), (1, 1)]
    assert _sof_sampling(b.jpeg_bytes[0]) == [(1, 1), (1, 1), (1, 1)]
    # decoded: the chroma planes of 4:2:0 frames hold far less detail within 2x2 blocks
    for x, y in zip(a.images, b.images):
        assert _chroma_detail(x) < 0.5 * _chroma_detail(y)


def test_sharpening_raises_high_frequency_energy():
    plain, sharp = _stack("colourful/base"), _stack("colourful/sharpened")
    assert plain.sharpening is None and isinstance(sharp.sharpening, sim.UnsharpMask)
    assert 0.5 <= sharp.sharpening.amount <= 1.2
    for x, y in zip(plain.images[:-1], sharp.images[:-1]):
        assert _luma_detail(y) > 1.3 * _luma_detail(x)


# --------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------

def _small_ratio_fraction(rgb, lo=0.02, hi=0.98):
    top = rgb.max(axis=2)
    ok = (top > lo) & (top < hi)
    return float(np.mean(rgb.min(axis=2)[ok] < 0.05 * top[ok]))


def test_scene_palettes_neutral_colourful_saturated():
    neutral = natural_scene(*SIZE, palette="neutral", seed=2)
    assert np.ptp(neutral, axis=2).max() == 0.0               # every surface grey
    frac = {p: _small_ratio_fraction(natural_scene(*SIZE, palette=p, seed=2) / 4.0)
            for p in SCENES}
    assert frac["neutral"] == 0.0
    assert frac["saturated"] > 0.25 > frac["colourful"] * 3
    # the rendered frames keep it: the saturated cell's linearised middle frame
    for name, low, high in (("saturated/base", 0.25, 1.0), ("colourful/base", 0.0, 0.1),
                            ("neutral/base", 0.0, 0.0)):
        stack = _stack(name)
        truth = stack.inverse_response()
        im = stack.images[2]
        lin = np.stack([truth[im[..., c], c] for c in range(3)], axis=-1)
        code_ok = (im.max(axis=2) >= 20) & (im.max(axis=2) <= 250)
        f = float(np.mean(lin.min(axis=2)[code_ok] < 0.05 * lin.max(axis=2)[code_ok]))
        assert low <= f <= high, (name, f)


def test_scene_spans_the_range_with_shading_texture_and_a_clipped_sun():
    scene = natural_scene(*SIZE, palette="colourful", seed=4)
    lum = scene.astype(np.float64) @ LUMA
    assert scene.dtype == np.float32 and scene.shape == (*SIZE, 3) and scene.min() >= 0
    stops = np.log2(np.percentile(lum, 99.9) / np.percentile(lum, 1))
    assert stops > 12 and lum.max() > 100                     # the sun
    ground = np.log2(lum[int(0.8 * SIZE[0]):])
    assert np.all(np.diff(ground.mean(axis=0)[::8]) < 0)      # the light falls off
    assert np.std(np.diff(ground, axis=1)) > 0.05             # texture on it
    np.testing.assert_array_equal(scene, natural_scene(*SIZE, palette="colourful", seed=4))
    assert not np.array_equal(scene, natural_scene(*SIZE, palette="colourful", seed=5))


def test_natural_scene_rejects_bad_arguments():
    with pytest.raises(InputError, match="at least 32x32"):
        natural_scene(16, 64)
    with pytest.raises(InputError, match="palette"):
        natural_scene(64, 64, palette="vivid")
    with pytest.raises(InputError, match="3x3"):
        natural_scene(64, 64, camera_from_output=np.eye(2))


# --------------------------------------------------------------------------------------
# camera: curves, colour matrix with white balance, gamut maps
# --------------------------------------------------------------------------------------

def test_per_channel_curves_differ_and_one_curve_is_shared():
    one = _stack("colourful/base").inverse_response()
    np.testing.assert_array_equal(one[:, 0], one[:, 1])
    np.testing.assert_array_equal(one[:, 2], one[:, 1])
    many = _stack("colourful/per-channel").inverse_response()
    np.testing.assert_array_equal(many[:, 1], one[:, 1])      # G keeps the given curve
    assert np.sqrt(np.mean((many[:, 0] - many[:, 1]) ** 2)) > 0.002
    assert np.all(np.diff(many, axis=0) > 0) and np.all(many[-1] == 1) and np.all(many[0] == 0)


def test_channel_curves_are_powers_of_the_table():
    r, g, b = channel_curves(CURVE, ((1.1, 0.9), (1, 1), (0.9, 1.05)))
    assert g is CURVE
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(r.forward(x), CURVE.forward(x ** 1.1) ** 0.9, atol=2e-3)
    with pytest.raises(InputError, match="positive"):
        channel_curves(CURVE, ((0, 1), (1, 1), (1, 1)))


@pytest.mark.parametrize("name", ["colourful/base", "saturated/clip-gamut"])
def test_camera_has_a_white_balanced_colour_matrix_that_renders_the_scene(name):
    cell = CONDITIONS[name]
    pipe = cell.pipeline(CURVE, 5)
    g = pipe.white_balance
    assert g[1] == 1 and 1.6 <= g[0] <= 2.4 and 1.2 <= g[2] <= 2.0
    assert np.all(np.diag(pipe.matrix) > 1) and np.all(pipe.matrix - np.diag(np.diag(
        pipe.matrix)) <= 0)
    np.testing.assert_allclose(pipe.matrix.sum(axis=1), 1.0)
    # the scene is made in output RGB and taken back through the camera's colour step
    to_camera = np.linalg.inv(pipe.matrix) / g[:, None]
    colours = np.array([[0.5, 0.5, 0.5], [0.4, 0.2, 0.1], [0.05, 0.3, 0.2]])
    np.testing.assert_allclose(pipe.colour_correct(colours @ to_camera.T), colours, atol=1e-12)
    # a grey beyond the green channel's clip renders white, not magenta
    white = pipe.render(np.array([[3.0, 3.0, 3.0]]) @ to_camera.T)
    np.testing.assert_allclose(white, 1.0)


def test_smooth_and_clip_gamut_maps_differ_on_saturated_scenes():
    smooth, clip = _stack("saturated/base"), _stack("saturated/clip-gamut")
    assert smooth.pipeline.gamut == "smooth" and clip.pipeline.gamut == "clip"
    x = smooth.pipeline.colour_correct(smooth.raws[2])
    moved = np.abs(smooth.pipeline.apply_gamut(x) - np.clip(x, 0, 1)).max(axis=2) > 0.01
    assert moved.mean() > 0.1
    x = clip.pipeline.colour_correct(clip.raws[2])
    np.testing.assert_array_equal(clip.pipeline.apply_gamut(x), np.clip(x, 0, 1))
    # some saturated colours are outside the output gamut (a negative channel)
    assert (x.min(axis=2) < -1e-3).mean() > 0.01


def test_condition_wants_one_tone_curve():
    with pytest.raises(InputError, match="one ToneCurve"):
        CONDITIONS["neutral/base"].simulate((CURVE, CURVE, CURVE), 1, size=SIZE)


# --------------------------------------------------------------------------------------
# a camera model from elsewhere
# --------------------------------------------------------------------------------------

def test_model_camera_renders_stacks_with_its_table_as_truth():
    gamma = sim.ToneCurve.gamma(2.2)
    table = np.stack([gamma.inverse(np.arange(256) / 255.0)] * 3, axis=1)
    cam = ModelCamera(lambda raw: gamma.forward(raw), table, name="gamma 2.2")
    scene = natural_scene(*SIZE, palette="colourful", seed=1)
    stack = sim.simulate_stack(scene, cam, sim.DEMO_EXPOSURE_TIMES, jpeg_quality=None,
                                 sensor=sim.SensorModel.ideal(), seed=1, jitter=0.0)
    np.testing.assert_allclose(stack.inverse_response(), table)
    expected = np.round(gamma.forward(stack.raws[3].astype(np.float64)) * 255)
    np.testing.assert_array_equal(stack.images[3], expected.astype(np.uint8))
    with pytest.raises(InputError, match=r"\(256, 3\)"):
        ModelCamera(lambda raw: raw, table[:10])
    with pytest.raises(InputError, match="render"):
        sim.simulate_stack(scene, object(), sim.DEMO_EXPOSURE_TIMES)
