"""Tests of the camera simulator (selfcal.sim) and the fixtures it generates."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from selfcal import io, sim
from selfcal.errors import InputError, OutputExistsError
from selfcal.sim import (
    CameraPipeline,
    SensorModel,
    ToneCurve,
    default_pipeline,
    gamut_clip,
    gamut_compress,
    make_scene,
    random_color_matrix,
    simulate_raw_jpeg_pair,
    simulate_stack,
)

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
SHARED_DATA = ROOT.parent / "shared" / "data"
LUMA = np.array([0.2126, 0.7152, 0.0722])


def _curves():
    x = np.linspace(0, 1, 257)
    return [
        ToneCurve.gamma(2.2),
        ToneCurve.gamma(0.8),
        ToneCurve.srgb(),
        ToneCurve.rec709(),
        ToneCurve.film(),
        ToneCurve.film(contrast=1.6, toe=0.4, shoulder=0.6, exposure=2.5),
        ToneCurve.from_table(x, np.sqrt(x), name="sqrt"),
    ]


# --------------------------------------------------------------------------------------
# tone curves
# --------------------------------------------------------------------------------------

@pytest.mark.parametrize("curve", _curves(), ids=lambda c: c.name)
def test_tone_curve_monotone_with_fixed_ends_and_exact_inverse(curve):
    assert curve.forward(0.0) == 0.0
    assert curve.forward(1.0) == 1.0
    assert curve.inverse(1.0) == 1.0 and curve.inverse(0.0) == 0.0
    assert np.all(np.diff(curve.brightness) > 0) and np.all(np.diff(curve.irradiance) > 0)
    x = np.linspace(0, 1, 10001)
    fx = curve.forward(x)
    assert np.all(np.diff(fx) > 0)
    np.testing.assert_allclose(curve.inverse(fx), x, atol=1e-12)
    y = np.linspace(0, 1, 10001)
    np.testing.assert_allclose(curve.forward(curve.inverse(y)), y, atol=1e-12)
    # inputs are clipped to [0, 1]
    np.testing.assert_array_equal(curve.forward(np.array([-0.5, 2.0])), [0.0, 1.0])


def test_analytic_curves_follow_their_formulas():
    x = np.array([0.001, 0.01, 0.18, 0.5, 0.9])
    np.testing.assert_allclose(ToneCurve.gamma(2.2).forward(x), x ** (1 / 2.2), atol=2e-5)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(ToneCurve.srgb().forward(x), srgb, atol=2e-5)
    assert ToneCurve.rec709().forward(0.01) == pytest.approx(0.045, abs=1e-5)
    film = ToneCurve.film()
    # an S-curve against log exposure: the toe makes shadows darker than the plain gamma
    assert film.forward(0.001) < ToneCurve.gamma(2.2).forward(0.001)
    # the shoulder rolls off: slope near white is lower than at mid-tones
    slope = np.gradient(film.forward(np.linspace(0, 1, 1001)), 1e-3)
    assert slope[-1] < 0.7 * slope[500]


def test_from_table_rejects_bad_tables():
    x = np.linspace(0, 1, 11)
    with pytest.raises(InputError, match="monotone"):
        ToneCurve.from_table(x, np.r_[0, 0.3, 0.2, np.linspace(0.4, 1, 8)])
    with pytest.raises(InputError, match=r"span \[0, 1\]"):
        ToneCurve.from_table(x * 255, x)
    with pytest.raises(InputError, match=r"span \[0, 1\]"):
        ToneCurve.from_table(x, 0.5 * x)
    with pytest.raises(InputError):
        ToneCurve.from_table(x, x[:-1])
    with pytest.raises(InputError):
        ToneCurve.from_table(x, np.where(x > 0.5, np.nan, x))
    with pytest.raises(InputError):
        ToneCurve.from_table([0, 0.5, 0.5, 1], [0, 0.2, 0.4, 1])  # two values at 0.5


def test_from_table_sorts_and_repairs_flat_stretches():
    x = np.linspace(0, 1, 11)
    y = np.r_[0, 0, 0, np.linspace(0.1, 0.9, 7), 1]  # flat toe: not invertible as given
    rng = np.random.default_rng(1)
    order = rng.permutation(11)
    curve = ToneCurve.from_table(x[order], y[order], name="flat toe")
    assert np.all(np.diff(curve.brightness) > 0)
    np.testing.assert_allclose(curve.forward(x), y, atol=2e-6)
    assert curve.inverse(curve.forward(0.15)) == pytest.approx(0.15, abs=1e-9)


@pytest.mark.parametrize("curve", _curves(), ids=lambda c: c.name)
def test_tone_curve_json_round_trip(curve):
    back = ToneCurve.from_dict(json.loads(json.dumps(curve.to_dict())))
    assert back.name == curve.name and back.kind == curve.kind
    x = np.linspace(0, 1, 999)
    np.testing.assert_array_equal(back.forward(x), curve.forward(x))


def test_from_table_reads_dorf_curves():
    path = SHARED_DATA / "dorf_emor" / "201_CRF_data.mat"
    if not path.exists():
        pytest.skip(f"{path} not present (real data lives outside the repository)")
    from scipy.io import loadmat

    d = loadmat(path)
    for k in (0, 50, 200):
        curve = ToneCurve.from_table(d["I"][k], d["B"][k], name=f"dorf{k}")
        np.testing.assert_allclose(curve.forward(d["I"][k]), d["B"][k], atol=2e-6)


# --------------------------------------------------------------------------------------
# gamut mapping
# --------------------------------------------------------------------------------------

def test_gamut_compress_identity_on_greys_and_monotone_along_them():
    v = np.linspace(-0.5, 1.5, 2001)
    greys = np.repeat(v[:, None], 3, axis=1)
    out = gamut_compress(greys)
    np.testing.assert_allclose(out, np.clip(greys, 0, 1), atol=1e-12)
    assert np.all(np.diff(out[:, 0]) >= 0)


def test_gamut_compress_leaves_low_saturation_colours_alone():
    rng = np.random.default_rng(0)
    lum = rng.uniform(0.1, 0.8, 5000)
    direction = rng.normal(size=(5000, 3))
    direction -= (direction @ LUMA)[:, None]
    direction /= np.abs(direction).max(axis=1, keepdims=True)
    # chroma at most 0.7 of the distance to the cube boundary (knee is 0.8)
    room = np.minimum(lum, 1 - lum)
    rgb = lum[:, None] + 0.7 * room[:, None] * direction
    np.testing.assert_allclose(gamut_compress(rgb, knee=0.8), rgb, atol=1e-12)


def test_gamut_compress_moves_saturated_and_near_boundary_colours_toward_grey():
    rng = np.random.default_rng(2)
    rgb = rng.normal(0.5, 0.6, size=(20000, 3))
    out = gamut_compress(rgb)
    assert out.min() >= 0 and out.max() <= 1
    # near-boundary colours inside the cube are changed too (Lin et al. ICCV 2011 §4):
    # 90 % of the way from grey to the cube's surface, above the knee of 0.8
    lum = rng.uniform(0.2, 0.8, 2000)
    d = rng.normal(size=(2000, 3))
    d -= (d @ LUMA)[:, None]
    to_edge = np.min(np.where(d > 0, (1 - lum[:, None]) / d, lum[:, None] / -d), axis=1)
    near = lum[:, None] + 0.9 * to_edge[:, None] * d
    assert near.min() >= 0 and near.max() <= 1
    moved = np.abs(gamut_compress(near) - near).max(axis=1)
    assert np.all(moved > 1e-4)
    # luma and hue kept, chroma reduced, for colours whose luma is within [0, 1]
    ok = (rgb @ LUMA > 0.05) & (rgb @ LUMA < 0.95)
    np.testing.assert_allclose(out[ok] @ LUMA, rgb[ok] @ LUMA, atol=1e-9)
    c_in = rgb[ok] - (rgb[ok] @ LUMA)[:, None]
    c_out = out[ok] - (out[ok] @ LUMA)[:, None]
    ratio = np.linalg.norm(c_out, axis=1) / np.linalg.norm(c_in, axis=1)
    assert np.all(ratio <= 1 + 1e-9)
    cos = np.sum(c_in * c_out, axis=1) / (np.linalg.norm(c_in, axis=1)
                                          * np.linalg.norm(c_out, axis=1) + 1e-300)
    assert np.all(cos[ratio > 1e-6] > 1 - 1e-9)


def test_gamut_compress_is_continuous():
    # sweep lines from grey out through the gamut boundary and far beyond it
    rng = np.random.default_rng(3)
    t = np.linspace(0, 3, 30001)
    for _ in range(20):
        grey = rng.uniform(0.15, 0.85)
        d = rng.normal(size=3)
        d -= d @ LUMA
        path = grey + t[:, None] * d[None, :] / np.abs(d).max()
        out = gamut_compress(path)
        step = np.abs(np.diff(out, axis=0)).max()
        assert step < 5 * np.abs(np.diff(path, axis=0)).max()


def test_gamut_clip_and_strength_zero():
    rgb = np.array([[1.2, 0.5, -0.1], [0.3, 0.4, 0.5]])
    np.testing.assert_array_equal(gamut_clip(rgb), [[1, 0.5, 0], [0.3, 0.4, 0.5]])
    # strength 0: in-gamut colours untouched, out-of-gamut ones put on the boundary
    out = gamut_compress(rgb, strength=0.0)
    np.testing.assert_allclose(out[1], rgb[1], atol=1e-12)
    assert out[0].min() == pytest.approx(0.0, abs=1e-9) or out[0].max() == pytest.approx(1.0)
    with pytest.raises(InputError):
        gamut_compress(rgb, knee=1.0)


# --------------------------------------------------------------------------------------
# pipeline and matrix
# --------------------------------------------------------------------------------------

def test_random_color_matrix_is_plausible():
    for seed in range(5):
        m = random_color_matrix(seed)
        np.testing.assert_allclose(m.sum(axis=1), 1.0, atol=1e-12)
        off = m[~np.eye(3, dtype=bool)]
        assert np.all(off < 0)
        assert np.all(np.diag(m) > np.abs(m).sum(axis=1) - np.abs(np.diag(m)))
    assert not np.allclose(random_color_matrix(0), random_color_matrix(1))
    np.testing.assert_allclose(random_color_matrix(0, strength=0), np.eye(3))


def test_pipeline_keeps_white_and_round_trips_through_json():
    p = default_pipeline(seed=4)
    np.testing.assert_allclose(p.render(np.ones(3)), 1.0, atol=1e-12)
    np.testing.assert_array_equal(p.render(np.zeros(3)), 0.0)
    back = CameraPipeline.from_dict(json.loads(json.dumps(p.to_dict())))
    raw = np.random.default_rng(0).uniform(size=(500, 3))
    np.testing.assert_array_equal(back.render(raw), p.render(raw))
    np.testing.assert_array_equal(back.inverse_response(range(256)),
                                  p.inverse_response(range(256)))
    one = default_pipeline(curves=ToneCurve.srgb(), gamut="clip")
    assert all(c.name == "srgb" for c in one.curves) and one.gamut == "clip"
    with pytest.raises(InputError):
        default_pipeline(gamut="fancy")
    with pytest.raises(InputError):
        default_pipeline(curves=[ToneCurve.srgb()] * 2)


def test_pipeline_white_balance_then_highlight_clip_then_matrix():
    m = random_color_matrix(3)
    gains = np.array([2.0, 1.0, 1.5])
    p = CameraPipeline(matrix=m, curves=ToneCurve.srgb(), gamut="clip", white_balance=gains)
    raw = np.array([[0.1, 0.2, 0.3], [0.4, 0.9, 0.5], [0.6, 1.0, 0.9]])
    expected = np.minimum(raw * gains, 1.0) @ m.T
    np.testing.assert_allclose(p.colour_correct(raw), expected, atol=1e-15)
    # a grey whose green raw clipped: white after the highlight clip (without it, magenta)
    np.testing.assert_allclose(p.render(np.array([0.7, 1.0, 0.9])), 1.0)
    plain = CameraPipeline(matrix=m @ np.diag(gains), curves=ToneCurve.srgb(), gamut="clip")
    assert plain.render(np.array([0.7, 1.0, 0.9]))[1] < 0.99
    np.testing.assert_allclose(plain.render(raw[:2]), p.render(raw[:2]), atol=1e-12)
    back = CameraPipeline.from_dict(json.loads(json.dumps(p.to_dict())))
    np.testing.assert_array_equal(back.white_balance, gains)
    assert "white_balance" not in default_pipeline().to_dict()
    for bad in ([1.0, 2.0], [1.0, 0.0, 1.0], [1.0, np.nan, 1.0]):
        with pytest.raises(InputError, match="white_balance"):
            CameraPipeline(matrix=m, curves=ToneCurve.srgb(), white_balance=bad)


def test_unsharp_mask_sharpens_luma_edges_only():
    usm = sim.UnsharpMask(amount=1.0, sigma=1.0)
    flat = np.full((16, 16, 3), 0.4)
    np.testing.assert_allclose(usm.apply(flat), flat, atol=1e-12)
    edge = np.zeros((16, 16, 3)) + np.array([0.2, 0.3, 0.1])
    edge[:, 8:] += 0.3
    out = usm.apply(edge)
    assert out[0, 8, 1] > edge[0, 8, 1] + 0.05 and out[0, 7, 1] < edge[0, 7, 1] - 0.05
    # the same detail is added to the three channels (luma sharpening: chroma unchanged)
    d = out - edge
    np.testing.assert_allclose(d[..., 0], d[..., 1], atol=1e-12)
    np.testing.assert_allclose(d[..., 2], d[..., 1], atol=1e-12)
    assert out.min() >= 0 and out.max() <= 1
    with pytest.raises(InputError, match="amount"):
        sim.UnsharpMask(amount=-1.0)
    with pytest.raises(InputError, match="sigma"):
        sim.UnsharpMask(sigma=0.0)


def test_stack_sharpening_and_chroma_subsampling():
    scene = make_scene(32, 48, seed=2)
    p = default_pipeline()
    usm = sim.UnsharpMask(0.7, 1.2)
    times = [1 / 60, 1 / 15]
    a = simulate_stack(scene, p, times, jitter=0.0, sensor=SensorModel.ideal(),
                       jpeg_quality=None, output=sim.FrameOutput(sharpening=usm))
    for image, raw in zip(a.images, a.raws):
        expected = np.round(usm.apply(p.render(raw)) * 255).astype(np.uint8)
        np.testing.assert_array_equal(image, expected)
    assert a.sharpening is usm and a.chroma_subsampling is None
    default = simulate_stack(scene, p, times, jpeg_quality=90, seed=1)
    assert default.chroma_subsampling == "4:2:0"
    assert default.jpeg_bytes[0] == io.encode_image(
        np.round(p.render(default.raws[0]) * 255).astype(np.uint8), ".jpg", jpeg_quality=90)
    full = simulate_stack(scene, p, times, jpeg_quality=90, seed=1,
                          output=sim.FrameOutput(chroma_subsampling="4:4:4"))
    assert full.chroma_subsampling == "4:4:4" and full.jpeg_bytes[0] != default.jpeg_bytes[0]
    np.testing.assert_array_equal(full.raws[0], default.raws[0])
    with pytest.raises(InputError, match="chroma_subsampling"):
        sim.FrameOutput(chroma_subsampling="4:1:1")
    with pytest.raises(InputError, match="UnsharpMask"):
        sim.FrameOutput(sharpening=0.5)
    with pytest.raises(InputError, match="bit_depth"):
        sim.FrameOutput(bit_depth=12)
    with pytest.raises(InputError, match="FrameOutput"):
        simulate_stack(scene, p, times, output=sim.UnsharpMask())
    with pytest.raises(TypeError):          # the knobs are FrameOutput's, not keywords
        simulate_stack(scene, p, times, chroma_subsampling="4:4:4")


def test_default_curves_differ_between_channels():
    inv = default_pipeline().inverse_response([64, 128, 192])
    assert np.all(np.ptp(inv, axis=1) > 0.005)


# --------------------------------------------------------------------------------------
# scene
# --------------------------------------------------------------------------------------

def test_scene_range_and_determinism():
    a = make_scene(64, 96, seed=5)
    assert a.shape == (64, 96, 3) and a.dtype == np.float32
    assert a.min() > 0 and a.max() == 1.0
    assert np.log2(a.max() / a.min()) >= 14
    assert np.log2(make_scene(64, 96, dynamic_range_stops=12).min() ** -1) >= 12
    np.testing.assert_array_equal(a, make_scene(64, 96, seed=5))
    assert not np.array_equal(a, make_scene(64, 96, seed=6))
    # luminance spread over many stops, not two clusters
    stops = np.log2(a.mean(axis=2))
    assert np.percentile(stops, 95) - np.percentile(stops, 5) > 8


def test_scene_saturation_controls_chroma():
    grey = make_scene(64, 96, saturation=0.0)
    np.testing.assert_array_equal(grey[..., 0], grey[..., 1])
    np.testing.assert_array_equal(grey[..., 1], grey[..., 2])

    def chroma(s):
        return np.ptp(s, axis=2) / s.max(axis=2)

    low, high = make_scene(64, 96, saturation=0.2), make_scene(64, 96, saturation=1.0)
    assert chroma(high).max() > 0.9
    assert np.percentile(chroma(high), 90) > 2 * np.percentile(chroma(low), 90)
    with pytest.raises(InputError):
        make_scene(64, 96, saturation=1.5)


# --------------------------------------------------------------------------------------
# sensor and stacks
# --------------------------------------------------------------------------------------

def test_sensor_noise_and_clipping():
    rng = np.random.default_rng(0)
    flat = np.full((200, 200, 3), 0.25)
    raw = SensorModel(full_well_electrons=10000, read_noise=0.0).expose(flat, 1.0, rng)
    assert raw.dtype == np.float32
    assert raw.std() == pytest.approx(np.sqrt(0.25 / 10000), rel=0.05)   # Poisson
    assert raw.mean() == pytest.approx(0.25, abs=1e-3)
    bright = SensorModel().expose(flat, 8.0, rng)
    assert np.all(bright == 1.0)
    crushed = SensorModel(read_noise=0.0, black_level=0.3).expose(flat, 1.0, rng)
    assert np.all(crushed == 0.0)
    ideal = SensorModel.ideal().expose(flat, 2.0, rng)
    np.testing.assert_array_equal(ideal, np.float32(0.5))


def _ideal_stack(saturation, seed=0):
    scene = make_scene(64, 96, saturation=saturation, seed=seed)
    return simulate_stack(scene, default_pipeline(seed=seed), [1 / 250, 1 / 60, 1 / 15, 1 / 4],
                          jitter=0.0, sensor=SensorModel.ideal(), jpeg_quality=None, seed=seed)


def test_stack_codes_equal_the_pipeline_model():
    stack = _ideal_stack(0.5)
    p = stack.pipeline
    assert stack.jpeg_bytes is None
    np.testing.assert_array_equal(stack.true_exposures, stack.exposure_times)
    for image, t, raw in zip(stack.images, stack.true_exposures, stack.raws):
        x = np.clip(stack.radiance.astype(np.float64) * (stack.exposure_scale * t), 0, 1)
        x = x.astype(np.float32)
        np.testing.assert_array_equal(raw, x)
        # P = f(Γ(M ρ)), Gong et al. Eq. 1a, rebuilt from the public pieces
        mapped = gamut_compress(x.astype(np.float64) @ p.matrix.T, knee=p.knee,
                                strength=p.strength)
        expected = np.stack([p.curves[c].forward(mapped[..., c]) for c in range(3)], -1)
        np.testing.assert_array_equal(image, np.round(expected * 255).astype(np.uint8))


@pytest.mark.parametrize("saturation", [0.0, 0.15])
def test_true_inverse_response_linearises_low_chroma_pixels(saturation):
    stack = _ideal_stack(saturation, seed=1)
    p = stack.pipeline
    curves = p.curves
    checked = 0
    for image, raw in zip(stack.images, stack.raws):
        x = raw.astype(np.float64) @ p.matrix.T                    # M ρ: what f^-1 recovers
        codes = image.reshape(-1, 3).astype(np.int64)
        x = x.reshape(-1, 3)
        hsv_s = np.ptp(x, axis=1) / np.maximum(x.max(axis=1), 1e-12)
        ok = ((raw.reshape(-1, 3) < 1).all(1) & (codes > 0).all(1) & (codes < 255).all(1)
              & (hsv_s < 0.25) & (x.max(axis=1) < 0.9))
        lin = stack.inverse_response(codes[ok].ravel()).reshape(-1, 3, 3)
        lin = lin[:, [0, 1, 2], [0, 1, 2]]                          # channel c from curve c
        for c in range(3):
            k = codes[ok, c] / 255.0
            lo = curves[c].inverse(k - 0.5 / 255)
            hi = curves[c].inverse(k + 0.5 / 255)
            bound = np.maximum(lin[:, c] - lo, hi - lin[:, c]) + 1e-9
            assert np.all(np.abs(lin[:, c] - x[ok, c]) <= bound)
        checked += ok.sum()
    assert checked > 2000


def test_stack_jitter_repeats_and_determinism():
    scene = make_scene(32, 48, seed=2)
    p = default_pipeline()
    times = [1 / 30, 1 / 500, 1 / 125]
    a = simulate_stack(scene, p, times, jitter=0.05, repeats=2, seed=3)
    np.testing.assert_allclose(a.exposure_times, np.repeat(np.sort(times), 2))
    rel = a.true_exposures / a.exposure_times - 1
    assert np.all(np.abs(rel) <= 0.05) and np.abs(rel).max() > 0
    assert a.true_exposures[0] != a.true_exposures[1]        # repeats: independent jitter
    assert not np.array_equal(a.raws[0], a.raws[1])         # ... and independent noise
    b = simulate_stack(scene, p, times, jitter=0.05, repeats=2, seed=3)
    for x, y in zip(a.images, b.images):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.true_exposures, b.true_exposures)
    c = simulate_stack(scene, p, times, jitter=0.05, repeats=2, seed=4)
    assert not np.array_equal(a.images[2], c.images[2])
    assert len(a) == 6 and a.images[0].dtype == np.uint8 and a.max_code == 255


def test_default_exposure_scale_and_demo_bracket():
    stack = sim.demo_stack()
    assert len(stack) == 6 and stack.images[0].shape == (256, 384, 3)
    median = np.median(stack.radiance.mean(axis=2))
    t_mid = np.sqrt(stack.exposure_times[0] * stack.exposure_times[-1])
    assert median * stack.exposure_scale * t_mid == pytest.approx(0.18)
    # highlights clipped in the longest frame, deep shadows in the shortest
    assert (stack.raws[-1] >= 1).mean() > 0.2
    assert (stack.raws[0] < 0.01).mean() > 0.2
    means = [im.mean() for im in stack.images]
    assert np.all(np.diff(means) > 0)
    assert stack.inverse_response().shape == (256, 3)


def test_sixteen_bit_stack_has_no_jpeg():
    stack = simulate_stack(make_scene(32, 48), default_pipeline(), [0.01, 0.04],
                           output=sim.FrameOutput(bit_depth=16))
    assert stack.images[0].dtype == np.uint16 and stack.max_code == 65535
    assert stack.jpeg_quality is None and stack.images[1].max() > 255
    assert stack.inverse_response().shape == (65536, 3)
    with pytest.raises(InputError):
        stack.write("unused", fmt="jpg")


def test_write_jpeg_decodes_to_images_with_nominal_exif(tmp_path):
    scene = make_scene(48, 64, seed=1)
    stack = simulate_stack(scene, default_pipeline(), [1 / 250, 1 / 60, 1 / 15], seed=1)
    paths = stack.write(tmp_path / "out")
    assert [p.name for p in paths] == ["frame_00.jpg", "frame_01.jpg", "frame_02.jpg"]
    assert sorted((tmp_path / "out").iterdir()) == paths      # nothing else written
    for path, image, t in zip(paths, stack.images, stack.exposure_times):
        np.testing.assert_array_equal(io.read_image(path), image)
        info = io.read_exposure_info(path)
        assert info.exposure_time == pytest.approx(t, rel=1e-9)
        assert info.f_number == 8.0 and info.iso == 100
    with pytest.raises(OutputExistsError):
        stack.write(tmp_path / "out")
    assert stack.write(tmp_path / "out", force=True) == paths


@pytest.mark.parametrize("fmt", ["png", "tif"])
def test_write_lossless_sixteen_bit(tmp_path, fmt):
    stack = simulate_stack(make_scene(32, 48), default_pipeline(), [1 / 100, 1 / 25],
                           output=sim.FrameOutput(bit_depth=16), seed=2)
    paths = stack.write(tmp_path, fmt=fmt)
    for path, image, t in zip(paths, stack.images, stack.exposure_times):
        back = io.read_image(path)
        assert back.dtype == np.uint16
        np.testing.assert_array_equal(back, image)
        if fmt == "png":
            assert io.read_exposure_info(path).exposure_time == pytest.approx(t)
        else:
            import tifffile

            with tifffile.TiffFile(path) as tif:
                num, den = tif.pages[0].tags["ExposureTime"].value
            assert num / den == pytest.approx(t)


def test_raw_jpeg_pair():
    pair = simulate_raw_jpeg_pair(seed=3)
    raw, rendered = pair["raw"], pair["rendered"]
    assert raw.dtype == np.float32 and raw.min() >= 0 and raw.max() <= 1
    assert rendered.dtype == np.uint8 and rendered.shape == raw.shape
    levels = raw.astype(np.float64) * 65535                     # quantised like a 16-bit ADC
    np.testing.assert_allclose(levels, np.round(levels), atol=1e-2)
    codes = np.round(pair["pipeline"].render(raw) * 255)
    np.testing.assert_array_equal(pair["codes"], codes)
    assert np.abs(rendered.astype(float) - codes).mean() < 2.0   # JPEG loss only
    assert 0.05 < raw.mean() < 0.5 and (raw >= 1).mean() < 0.05  # a usable exposure


# --------------------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------------------

def _truth():
    path = FIXTURES / "truth.json"
    assert path.exists(), "run python fixtures/make_fixtures.py"
    return json.loads(path.read_text())


def test_fixture_files_exist_and_match_truth():
    truth = _truth()
    files = [FIXTURES / f for f in truth["stack"]["files"]]
    assert len(files) >= 5
    total = sum(p.stat().st_size for p in FIXTURES.rglob("*") if p.is_file())
    assert total < 1_000_000
    for path, t, true in zip(files, truth["stack"]["nominal_times"],
                             truth["stack"]["true_exposures"]):
        assert io.read_exposure_info(path).exposure_time == pytest.approx(t, rel=1e-9)
        assert abs(true / t - 1) <= truth["stack"]["jitter"]
    images = [io.read_image(p) for p in files]
    assert all(im.shape == (128, 192, 3) and im.dtype == np.uint8 for im in images)
    assert np.all(np.diff([im.mean() for im in images]) > 0)
    pipeline = CameraPipeline.from_dict(truth["pipeline"])
    inv = pipeline.inverse_response(truth["inverse_response"]["codes"])
    for c, name in enumerate("RGB"):
        # to rounding: numpy builds differ in the last bit of pow/log (SIMD kernels)
        np.testing.assert_allclose(inv[:, c], truth["inverse_response"][name],
                                   rtol=1e-12, atol=0)


def test_fixture_pair_is_the_raw_rendered_by_the_true_pipeline():
    truth = _truth()
    raw16 = io.read_image(FIXTURES / truth["pair"]["raw"])
    assert raw16.dtype == np.uint16
    rendered = io.read_image(FIXTURES / truth["pair"]["rendered"])
    pipeline = CameraPipeline.from_dict(truth["pipeline"])
    codes = np.round(pipeline.render(raw16 / 65535.0) * 255)
    err = np.abs(rendered - codes)
    # JPEG (q95, 4:2:0 chroma) on the textured scene: ~2.4 codes; another camera matrix
    # gives ~4.8, another tone curve 5.5-7
    assert err.mean() < 3.0 and np.median(err) <= 2


def test_fixtures_are_what_the_generator_makes():
    spec = importlib.util.spec_from_file_location("make_fixtures",
                                                  FIXTURES / "make_fixtures.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    truth = _truth()
    scene = make_scene(mod.HEIGHT, mod.WIDTH, dynamic_range_stops=14.0, saturation=0.5,
                       seed=mod.SEED)
    stack = simulate_stack(scene, default_pipeline(seed=mod.SEED), mod.TIMES, jitter=0.03,
                           jpeg_quality=mod.STACK_JPEG_QUALITY, seed=mod.SEED)
    np.testing.assert_array_equal(stack.true_exposures, truth["stack"]["true_exposures"])
    for rel, image in zip(truth["stack"]["files"], stack.images):
        # equal on this machine; another JPEG encoder build may differ by a code or so
        diff = np.abs(io.read_image(FIXTURES / rel).astype(int) - image).mean()
        assert diff < 0.5
