"""Raw reading (linear, black → 0, white → 1), RAW+JPEG registration, pair samples, raw
exposure ratios.  Real DNGs from ../shared/data/raw when present."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from selfcal import sim
from selfcal.errors import InputError
from selfcal.io import read_image, write_bytes_atomic, write_image
from selfcal.pipeline.pairs import BlockRejection, pair_samples, sample_raw_jpeg_pair
from selfcal.exposure.raw_ratios import raw_exposure_ratios, raw_thumbnail
from selfcal.pipeline.registration import Registration, register_raw_jpeg
from selfcal.io.raw import (RAW_SUFFIXES, is_linear_tiff, read_raw_exposure_info,
                         read_raw_linear)

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CANON = SHARED / "raw" / "colorchart_canon550d.dng"
BLACKMAGIC = SHARED / "raw" / "blackmagic_cinema.dng"

needs_canon = pytest.mark.skipif(not CANON.exists(),
                                 reason=f"real raw data not present ({CANON})")
needs_blackmagic = pytest.mark.skipif(not BLACKMAGIC.exists(),
                                      reason=f"real raw data not present ({BLACKMAGIC})")


def crop_and_scale(img, crop=0.02, factor=0.8):
    """Crop ``crop`` off every side, resize by ``factor`` (INTER_AREA) and return the
    image with the true registration (raw_xy = s * xy + t, pixel centres)."""
    import cv2

    h, w = img.shape[:2]
    cx, cy = int(round(crop * w)), int(round(crop * h))
    part = img[cy:h - cy, cx:w - cx]
    size = (int(round(part.shape[1] * factor)), int(round(part.shape[0] * factor)))
    out = cv2.resize(part, size, interpolation=cv2.INTER_AREA)
    fx, fy = part.shape[1] / size[0], part.shape[0] / size[1]
    return out, (fx, fy), (0.5 * fx - 0.5 + cx, 0.5 * fy - 0.5 + cy)


def corner_error(reg, shape, scale, shift):
    h, w = shape[:2]
    pts = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float)
    truth = np.stack([pts[:, 0] * scale[0] + shift[0], pts[:, 1] * scale[1] + shift[1]], 1)
    return float(np.abs(reg.to_raw(pts) - truth).max())


def jpeg_round_trip(img, quality=92):
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(img[:, :, ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1].copy()


@pytest.fixture(scope="module")
def sim_pair():
    scene = sim.make_scene(240, 360, dynamic_range_stops=8.0, saturation=0.6, seed=3)
    return sim.simulate_raw_jpeg_pair(scene, exposure=1.0, seed=3)


# ------------------------------------------------------------------ raw reading

def test_raw_suffixes_cover_the_common_cameras():
    for s in ("dng", "cr2", "cr3", "nef", "arw", "raf", "orf", "rw2", "pef", "srw", "x3f",
              "3fr", "iiq", "rwl", "erf", "kdc", "mos", "mrw", "nrw", "srf", "sr2"):
        assert "." + s in RAW_SUFFIXES


def test_linear_tiff_reads_as_raw():
    path = FIXTURES / "pair" / "pair.tiff"
    assert is_linear_tiff(path)
    assert not is_linear_tiff(FIXTURES / "pair" / "pair.jpg")
    raw = read_raw_linear(path)
    codes = read_image(path)
    assert raw.rgb.dtype == np.float32 and raw.rgb.shape == codes.shape
    np.testing.assert_allclose(raw.rgb, codes / 65535.0, atol=1e-7)
    assert raw.source == "tiff" and raw.camera_wb is None
    half = read_raw_linear(path, half_size=True)
    assert half.rgb.shape == (codes.shape[0] // 2, codes.shape[1] // 2, 3)
    np.testing.assert_allclose(half.rgb[3, 5], raw.rgb[6:8, 10:12].mean(axis=(0, 1)),
                               atol=1e-6)


def test_exposure_tags_of_tiff_structured_raws(tmp_path):
    from selfcal.sim.encoding import tiff_with_exif_tags

    path = tmp_path / "linear.tiff"
    write_bytes_atomic(path, tiff_with_exif_tags(np.zeros((8, 8, 3), np.uint16),
                                                  1 / 60, 5.6, 200))
    info = read_raw_exposure_info(path)
    assert info.exposure_time == pytest.approx(1 / 60) and info.f_number == 5.6
    assert info.iso == 200
    assert read_raw_linear(path).exposure == info


def test_8bit_tiff_is_not_a_raw(tmp_path):
    path = tmp_path / "eight.tif"
    write_image(path, np.zeros((8, 8, 3), np.uint8))
    assert not is_linear_tiff(path)
    with pytest.raises(InputError, match="8-bit TIFF is not a linear raw") as info:
        read_raw_linear(path)
    assert "eight.tif" in str(info.value)


def test_unreadable_raw_names_the_file(tmp_path):
    bad = tmp_path / "IMG_0001.CR2"
    bad.write_bytes(b"this is not a raw file" * 100)
    with pytest.raises(InputError, match="not a raw file LibRaw can read") as info:
        read_raw_linear(bad)
    assert "IMG_0001.CR2" in str(info.value)
    with pytest.raises(InputError, match="no such file"):
        read_raw_linear(tmp_path / "missing.NEF")
    # and the exposure reader does not raise for such files
    assert read_raw_exposure_info(bad).exposure_time is None


def _cfa_reference(path):
    """(raw - black_c) / (white_c - black_c) at each CFA site, and the site colours."""
    import rawpy

    with rawpy.imread(str(path)) as r:
        vis = r.raw_image_visible.astype(np.float64)
        cols = r.raw_colors_visible.copy()
        black = np.asarray(r.black_level_per_channel, float)
        white = float(r.white_level)
    ref = np.clip((vis - black[cols]) / (white - black[cols]), 0.0, 1.0)
    return ref, np.where(cols == 3, 1, cols)


@needs_canon
def test_real_dng_is_linear_black_0_white_1_not_white_balanced():
    raw = read_raw_linear(CANON)
    rgb = raw.rgb
    assert rgb.dtype == np.float32 and rgb.ndim == 3 and rgb.shape[2] == 3
    assert rgb.min() >= 0.0 and rgb.max() <= 1.0
    # bilinear demosaicing keeps the sensor value at each CFA site: compare with the
    # affine map black -> 0, white -> 1 computed here from rawpy's own raw data
    ref, cols = _cfa_reference(CANON)
    h, w = rgb.shape[:2]
    ref, cols = ref[:h, :w], cols[:h, :w]
    got = np.take_along_axis(rgb, cols[..., None], axis=2)[..., 0]
    np.testing.assert_allclose(got, ref, atol=2.0 / 65535)
    assert raw.black_level == (2056.0, 2056.0, 2056.0)
    assert raw.white_level == (15000.0, 15000.0, 15000.0)
    assert float(rgb.min()) == 0.0      # sensor values below black clip to 0
    # no white balance: on this grey-surround chart green dominates
    med = np.median(rgb.reshape(-1, 3), axis=0)
    assert med[1] > 1.5 * med[0] and med[1] > 1.2 * med[2]
    # the as-shot multipliers are reported, normalised to G = 1, not applied
    assert raw.camera_wb is not None and raw.camera_wb[1] == 1.0 and raw.camera_wb[0] > 1
    # the file stores 0 for the exposure fields: unknown, not 0 s or 1 s
    assert raw.exposure.exposure_time is None


@needs_canon
def test_real_dng_half_size_bins_2x2():
    full = read_raw_linear(CANON)
    half = read_raw_linear(CANON, half_size=True)
    assert half.rgb.shape == (full.rgb.shape[0] // 2, full.rgb.shape[1] // 2, 3)
    ref, cols = _cfa_reference(CANON)
    hh, hw = half.rgb.shape[:2]
    cell = ref[:2 * hh, :2 * hw].reshape(hh, 2, hw, 2)
    # RGGB: R at (0, 0), B at (1, 1) of each cell
    assert np.all(cols[0::2, 0::2][:hh, :hw] == 0)
    np.testing.assert_allclose(half.rgb[..., 0], cell[:, 0, :, 0], atol=2.0 / 65535)
    np.testing.assert_allclose(half.rgb[..., 2], cell[:, 1, :, 1], atol=2.0 / 65535)
    green = 0.5 * (cell[:, 0, :, 1] + cell[:, 1, :, 0])
    assert np.median(np.abs(half.rgb[..., 1] - green)) < 2.0 / 65535


@needs_blackmagic
def test_real_cinemadng_linearisation_table_and_levels():
    raw = read_raw_linear(BLACKMAGIC)
    ref, cols = _cfa_reference(BLACKMAGIC)
    h, w = raw.rgb.shape[:2]
    sub = (slice(400, 800), slice(1000, 1600))
    got = np.take_along_axis(raw.rgb[sub], cols[:h, :w][sub][..., None], axis=2)[..., 0]
    np.testing.assert_allclose(got, ref[:h, :w][sub], atol=2.0 / 65535)
    assert 0.0 <= raw.rgb.min() and raw.rgb.max() <= 1.0
    assert raw.black_level[0] == 512.0


# ------------------------------------------------------------------ registration

def test_registration_identity(sim_pair):
    reg = register_raw_jpeg(sim_pair["raw"], sim_pair["rendered"])
    assert reg.ok and reg.residual < 0.1
    assert corner_error(reg, sim_pair["rendered"].shape, (1, 1), (0, 0)) < 0.5


@pytest.mark.parametrize("factor", [0.8, 0.5])
def test_registration_recovers_crop_and_scale(sim_pair, factor):
    jpeg, scale, shift = crop_and_scale(sim_pair["rendered"], 0.02, factor)
    reg = register_raw_jpeg(sim_pair["raw"], jpeg)
    assert reg.ok, reg
    assert abs(reg.scale - np.mean(scale)) < 0.004 * np.mean(scale)
    assert corner_error(reg, jpeg.shape, scale, shift) < 0.5 * np.mean(scale)


def test_mismatched_pair_detected(sim_pair, tmp_path):
    flipped = sim_pair["rendered"][::-1, ::-1].copy()
    reg = register_raw_jpeg(sim_pair["raw"], flipped)
    assert not reg.ok and reg.residual > 0.5
    rotated = np.rot90(sim_pair["rendered"]).copy()
    assert not register_raw_jpeg(sim_pair["raw"], rotated).ok
    # with files: the error names both
    raw_path, jpg_path = tmp_path / "IMG_1.tiff", tmp_path / "IMG_1.jpg"
    write_image(raw_path, (sim_pair["raw"] * 65535).round().astype(np.uint16))
    write_image(jpg_path, flipped)
    with pytest.raises(InputError, match="does not match its raw") as info:
        sample_raw_jpeg_pair(raw_path, jpg_path)
    assert "IMG_1.jpg" in str(info.value) and "IMG_1.tiff" in str(info.value)


@needs_canon
def test_real_dng_registration_against_a_rendering(tmp_path):
    import rawpy

    with rawpy.imread(str(CANON)) as r:
        rendered = r.postprocess(use_camera_wb=True, user_flip=0)   # sRGB, camera WB
    jpeg, scale, shift = crop_and_scale(rendered, 0.02, 0.6)
    jpeg = jpeg_round_trip(jpeg, 90)
    raw = read_raw_linear(CANON, half_size=True).rgb
    reg = register_raw_jpeg(raw, jpeg)
    # truth on the half-size grid: x_half = (x_full + 0.5) / 2 - 0.5
    scale_h = (scale[0] / 2, scale[1] / 2)
    shift_h = ((shift[0] + 0.5) / 2 - 0.5, (shift[1] + 0.5) / 2 - 0.5)
    assert reg.ok and reg.residual < 0.2, reg
    assert corner_error(reg, jpeg.shape, scale_h, shift_h) < 0.5
    # a different scene (the other real raw's rendering) does not match
    if BLACKMAGIC.exists():
        with rawpy.imread(str(BLACKMAGIC)) as r:
            other = r.postprocess(use_camera_wb=True, user_flip=0, half_size=True)
        assert not register_raw_jpeg(raw, other).ok


# ------------------------------------------------------------------ samples

def test_samples_match_the_camera_and_skip_clipped_and_textured_blocks(sim_pair):
    raw = sim_pair["raw"].copy()
    ren = sim_pair["rendered"].copy()
    pipe = sim_pair["pipeline"]
    h, w = ren.shape[:2]
    # a clipped raw patch, and a textured patch (fine checker) in both images
    raw[20:60, 20:60] = 1.0
    ren[20:60, 20:60] = 255
    yy, xx = np.mgrid[0:40, 0:40]
    checker = ((yy // 2 + xx // 2) % 2).astype(np.float32)
    raw[150:190, 40:80] = (0.05 + 0.3 * checker)[..., None]
    ren[150:190, 40:80] = np.round(255 * pipe.render(raw[150:190, 40:80])).astype(np.uint8)
    ps = pair_samples(raw, ren, None, block=8, seed=0)
    c = ps.counts
    assert c["total"] == (h // 8) * (w // 8)
    assert c["clipped_raw"] >= 25 and c["high_gradient"] >= 25
    assert c["valid"] == c["used"] == len(ps)
    assert sum(c[k] for k in ("outside", "clipped_raw", "clipped_rendered",
                              "high_gradient", "valid")) == c["total"]
    x, y = ps.positions[:, 0], ps.positions[:, 1]
    assert not np.any((x > 16) & (x < 64) & (y > 16) & (y < 64))
    assert not np.any((x > 40) & (x < 80) & (y > 150) & (y < 190))   # block centres inside
    assert ps.raw.max() < 0.98
    assert ps.rendered.min() > 1 / 255 and ps.rendered.max() < 254 / 255
    # the kept block means follow the camera: f(Γ(M mean raw)) ≈ mean rendered
    err = np.abs(pipe.render(ps.raw.astype(np.float32)[None])[0] - ps.rendered) * 255
    assert np.median(err) < 1.0 and np.percentile(err, 95) < 3.0
    # seeded subsampling
    a = pair_samples(raw, ren, None, block=8, n_max=100, seed=4)
    b = pair_samples(raw, ren, None, block=8, n_max=100, seed=4)
    assert len(a) == 100 and a.counts["used"] == 100
    np.testing.assert_array_equal(a.raw, b.raw)


def test_blocks_clipped_throughout_are_kept_on_request(sim_pair):
    raw = sim_pair["raw"].copy()
    ren = sim_pair["rendered"].copy()
    raw[20:60, 20:60] = 1.0                      # clipped raw, rendered white
    ren[20:60, 20:60] = 255
    ren[100:140, 100:140, 2] = 0                 # a rendered channel at 0 throughout
    default = pair_samples(raw, ren, None, block=8, seed=0)
    kept = pair_samples(raw, ren, None, block=8, seed=0,
                        rejection=BlockRejection(keep_clipped=True))
    with pytest.raises(TypeError, match="keep_clipped"):     # the 0.x keyword is gone
        pair_samples(raw, ren, None, block=8, seed=0, keep_clipped=True)
    inside = lambda ps, y0, x0: np.any(                               # noqa: E731
        (ps.positions[:, 0] > x0) & (ps.positions[:, 0] < x0 + 40)
        & (ps.positions[:, 1] > y0) & (ps.positions[:, 1] < y0 + 40))
    assert not inside(default, 20, 20) and not inside(default, 100, 100)
    assert inside(kept, 20, 20) and inside(kept, 100, 100)
    assert kept.counts["valid"] > default.counts["valid"]
    # blocks clipped throughout have exact means; blocks clipped in part stay out
    white = (kept.positions[:, 0] > 24) & (kept.positions[:, 0] < 56) & \
        (kept.positions[:, 1] > 24) & (kept.positions[:, 1] < 56)
    assert np.all(kept.raw[white] == 1.0) and np.all(kept.rendered[white] == 1.0)
    edge = (np.abs(kept.positions[:, 0] - 20) < 4) | (np.abs(kept.positions[:, 0] - 60) < 4)
    assert not np.any(edge & (kept.positions[:, 1] > 24) & (kept.positions[:, 1] < 56))


def test_samples_of_a_cropped_scaled_jpeg_follow_the_camera(sim_pair):
    jpeg, _, _ = crop_and_scale(sim_pair["rendered"], 0.02, 0.5)
    reg = register_raw_jpeg(sim_pair["raw"], jpeg)
    ps = pair_samples(sim_pair["raw"], jpeg, reg, seed=0)
    assert len(ps) > 200 and ps.counts["outside"] == 0
    err = np.abs(sim_pair["pipeline"].render(ps.raw.astype(np.float32)[None])[0]
                 - ps.rendered) * 255
    assert np.median(err) < 1.0 and np.percentile(err, 95) < 3.0


def test_samples_need_registration_for_different_sizes(sim_pair):
    with pytest.raises(InputError, match="register them first"):
        pair_samples(sim_pair["raw"], sim_pair["rendered"][:100])


def test_identity_registration():
    reg = Registration.identity((4, 6, 3))
    assert reg.ok and reg.scale == 1 and reg.raw_shape == (4, 6)


# ------------------------------------------------------------------ exposure ratios

def test_raw_exposure_ratios_beat_jittered_exif():
    scene = sim.make_scene(96, 144, dynamic_range_stops=10.0, saturation=0.5, seed=2)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=2),
                                 [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8],
                                 jitter=0.05, seed=2)
    rel, report = raw_exposure_ratios([raw_thumbnail(r) for r in stack.raws])
    truth = stack.true_exposures / stack.true_exposures[0]
    exif = stack.exposure_times / stack.exposure_times[0]
    err_raw = np.abs(np.log(rel / truth)).max()
    err_exif = np.abs(np.log(exif / truth)).max()
    assert err_raw < 0.005 and err_raw < err_exif / 4
    assert report["component"] == [0] * 6


def test_raw_exposure_ratios_ignore_clipped_values():
    rng = np.random.default_rng(0)
    base = rng.uniform(0.01, 0.5, (64, 64, 3)).astype(np.float32)
    bright = np.minimum(base * 4.0, 1.0)        # clipped where base > 0.25
    rel, _ = raw_exposure_ratios([base, bright])
    assert rel[0] == 1.0 and abs(rel[1] - 4.0) < 1e-3
    # frames without shared well-exposed values are isolated
    rel, rep = raw_exposure_ratios([base, np.full_like(base, 1.0)])
    assert rep["component"] == [-1, -1] and np.isnan(rel).all()
