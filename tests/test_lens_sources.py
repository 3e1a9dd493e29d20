"""Vignetting from the lens database (lensfun) and from a flat field.

- EXIF lens tags written by :func:`selfcal.io.images.exif_bytes` read back through
  :func:`selfcal.io.images.read_lens_info`;
- a lens profile's map equals lensfun's own ``Modifier.apply_color_modification`` on a
  flat image (an independent implementation of the same model and normalisation), at the
  calibration's crop factor and on a body of another crop factor;
- the match record says why when there is no profile;
- a flat field made with a known vignetting, noise and tone curve gives that vignetting
  back within its stated σ, ignoring clipped blocks and a dust spot.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from selfcal.errors import CalibrationError, InputError, SelfcalWarning
from selfcal.io.images import (LensInfo, encode_image, exif_bytes, read_exposure_info,
                               read_lens_info)
from selfcal.lens import Vignetting, flat_field_vignetting, lens_vignetting
from selfcal.lens.flat_field import FLAT_RESIDUAL_WARN
from selfcal.lens.database import DEFAULT_DISTANCE_M, LOG_SIGMA_FLOOR

lensfunpy = pytest.importorskip("lensfunpy")


def _jpeg_with_exif(path, image, **exif):
    import piexif

    out = io.BytesIO()
    piexif.insert(exif_bytes(**exif), encode_image(image, ".jpg"), out)
    path.write_bytes(out.getvalue())
    return path


def _lensfun_map(camera_make, camera_model, lens_model, focal, aperture, h, w,
                 distance=DEFAULT_DISTANCE_M):
    """V on every pixel by lensfun itself: its modifier adding vignetting to a flat image."""
    db = lensfunpy.Database()
    camera = db.find_cameras(camera_make, camera_model)[0]
    lens = sorted(db.find_lenses(camera, None, lens_model), key=lambda x: -x.score)[0]
    mod = lensfunpy.Modifier(lens, camera.crop_factor, w, h)
    mod.initialize(focal, aperture, distance, pixel_format=np.float32,
                   flags=lensfunpy.ModifyFlags.VIGNETTING, reverse=True)
    image = np.ones((h, w, 3), np.float32)
    assert mod.apply_color_modification(image)
    return image, lens, camera


def test_exif_lens_tags_round_trip(tmp_path):
    path = _jpeg_with_exif(tmp_path / "f.jpg", np.full((16, 24, 3), 128, np.uint8),
                           exposure_time=1 / 125, f_number=2.8, iso=200, make="Canon",
                           model="Canon EOS 5D Mark II", lens_make="Canon",
                           lens_model="EF50mm f/1.8 II", focal_length=50, focus_distance=3.2)
    info = read_lens_info(path)
    assert info == LensInfo("Canon", "Canon EOS 5D Mark II", "Canon", "EF50mm f/1.8 II",
                            50.0, 2.8, 3.2, None)
    assert read_exposure_info(path).exposure_time == pytest.approx(1 / 125)
    bare = tmp_path / "bare.jpg"
    bare.write_bytes(encode_image(np.zeros((8, 8, 3), np.uint8), ".jpg"))
    assert read_lens_info(bare) == LensInfo(None, None, None, None, None, None, None, None)
    with pytest.raises(InputError, match="absent.jpg"):
        read_lens_info(tmp_path / "absent.jpg")


@pytest.mark.parametrize("camera, lens_model, focal, aperture", [
    ("Canon EOS 5D Mark II", "EF50mm f/1.8 II", 50.0, 2.8),      # calibrated on this crop
    ("Canon EOS 550D", "EF85mm f/1.8 USM", 85.0, 2.0),           # full-frame profile, 1.6×
])
def test_lens_profile_map_equals_lensfuns_modifier(camera, lens_model, focal, aperture,
                                                   tmp_path):
    h, w = 400, 600
    path = _jpeg_with_exif(tmp_path / "frame.jpg", np.full((h, w, 3), 100, np.uint8),
                           exposure_time=0.01, f_number=aperture, make="Canon", model=camera,
                           lens_model=lens_model, focal_length=focal)
    vignetting, match = lens_vignetting(path)
    assert vignetting is not None, match.reason
    expected, lens, body = _lensfun_map("Canon", camera, lens_model, focal, aperture, h, w)
    assert match.lens_crop == pytest.approx(lens.crop_factor)
    assert match.camera_crop == pytest.approx(body.crop_factor)
    ours = vignetting.map(h, w)
    # lensfun puts the corner pixel's centre at r = 1, we the frame's corner: ~1/w apart
    np.testing.assert_allclose(ours, expected, atol=4e-3)
    assert np.abs(ours - expected).mean() < 1.5e-3
    assert float(expected.min()) < 0.9                  # a real falloff was compared
    assert vignetting.source == "lens" and vignetting.aspect is None
    assert vignetting.log_sigma_floor == LOG_SIGMA_FLOOR
    assert vignetting.description.startswith(f"lensfun: {match.lens} at {focal:g} mm "
                                              f"f/{aperture:g} (match score")
    assert match.distance == DEFAULT_DISTANCE_M and match.distance_source == "default"
    json.dumps(vignetting.to_dict())
    again = Vignetting.from_dict(json.loads(json.dumps(vignetting.to_dict())))
    np.testing.assert_array_equal(again.map(h, w), ours)


def test_lens_profile_at_another_crop_rescales_radius():
    """The same profile on a 1.6× body: the frame is the inner 1/1.6 of the calibration's."""
    full, _ = lens_vignetting(LensInfo("Canon", "Canon EOS 5D Mark II", None,
                                       "EF85mm f/1.8 USM", 85.0, 2.0, None))
    crop, match = lens_vignetting(LensInfo("Canon", "Canon EOS 550D", None,
                                           "EF85mm f/1.8 USM", 85.0, 2.0, None))
    s = match.lens_crop / match.camera_crop
    r = np.linspace(0, 1, 11)
    np.testing.assert_allclose(crop.falloff(r), full.falloff(s * r), rtol=1e-9)


def test_lens_match_says_why_not():
    none, match = lens_vignetting(LensInfo("Canon", "Canon EOS 5D Mark II", None, None,
                                           16.0, 8.0, None))
    assert none is None and "names no lens model" in match.reason
    none, match = lens_vignetting(LensInfo("Acme", "Obscura 1", None, "Pinhole", 50, 8, None))
    assert none is None and "does not know the camera (Acme Obscura 1)" in match.reason
    none, match = lens_vignetting(LensInfo("Canon", "Canon EOS 5D Mark II", None,
                                           "EF50mm f/1.8 II", None, 2.8, None))
    assert none is None and "focal length" in match.reason
    given, match = lens_vignetting(LensInfo("Canon", "Canon EOS 5D Mark II", None,
                                            "EF50mm f/1.8 II", 50.0, 2.8, 2.5))
    assert match.distance == 2.5 and match.distance_source == "exif"
    assert given.diagnostics["lens_match"]["exif"]["lens_model"] == "EF50mm f/1.8 II"


# --------------------------------------------------------------------------------------
# flat field
# --------------------------------------------------------------------------------------

TRUTH = Vignetting(np.array([[-0.45, 0.05, -0.02], [-0.40, 0.02, -0.01], [-0.35, 0.0, 0.0]]),
                   np.array([0.04, -0.03]), source="flat")


def _flat(h=300, w=450, *, noise=0.02, level=0.7, seed=3):
    rng = np.random.default_rng(seed)
    linear = level * TRUTH.map(h, w) * np.array([0.9, 1.0, 0.8], np.float32)
    linear = linear * (1 + noise * rng.standard_normal(linear.shape))
    codes = np.round(255 * np.clip(linear, 0, 1) ** (1 / 2.2))
    return codes.astype(np.uint8)


def _gamma(codes):
    return (np.asarray(codes, np.float64) / 255.0) ** 2.2


def test_flat_field_recovers_known_vignetting_within_its_sigma():
    h, w = 300, 450
    v = flat_field_vignetting(_flat(h, w), linearize=_gamma)
    assert v.source == "flat" and v.aspect == pytest.approx(w / h)
    np.testing.assert_allclose(v.centre, TRUTH.centre, atol=3e-3)
    error = np.log(v.map(h, w)) - np.log(TRUTH.map(h, w))
    sigma = v.log_sigma_map(h, w)
    assert np.abs(error).max() < 2e-3
    assert float(np.sqrt(np.mean((error / sigma) ** 2))) < 3.0    # the band is honest
    truth = Vignetting(TRUTH.coefficients, TRUTH.centre, source="flat", aspect=w / h)
    np.testing.assert_allclose(v.corner_stops(), truth.corner_stops(), atol=0.005)
    points = v.diagnostics["points"]
    assert len(points["r"]) == len(points["log_ratio"]) == len(points["count"]) > 10
    json.dumps(v.to_dict())
    # identity linearisation of a gamma-encoded frame is a different (wrong) answer
    wrong = flat_field_vignetting(_flat(h, w))
    assert np.abs(np.log(wrong.map(h, w)) - np.log(TRUTH.map(h, w))).max() > 0.05


def test_flat_field_ignores_clipped_blocks_and_a_dust_spot():
    h, w = 300, 450
    codes = _flat(h, w, level=1.0)            # the centre clips at 255
    yy, xx = np.mgrid[0:h, 0:w]
    codes[np.hypot(xx - 330, yy - 210) < 14] //= 2     # a dust shadow
    v = flat_field_vignetting(codes, linearize=_gamma)
    assert v.diagnostics["blocks_clipped"] > 0
    assert v.diagnostics["blocks_used"] < v.diagnostics["blocks"] - \
        v.diagnostics["blocks_clipped"]
    unclipped = (_gamma(codes) < 0.9).all(axis=2)
    error = np.log(v.map(h, w)) - np.log(TRUTH.map(h, w))
    assert np.abs(error[unclipped]).max() < 0.01
    assert np.abs(error).max() < 0.01       # the clipped centre too, by V(0) = 1
    with pytest.raises(CalibrationError, match="clipped out to"):
        flat_field_vignetting(_flat(h, w, level=1.3), linearize=_gamma)


def test_flat_field_from_a_file_and_bad_input(tmp_path):
    path = tmp_path / "flat.png"
    path.write_bytes(encode_image(_flat(), ".png"))
    v = flat_field_vignetting(path, linearize=_gamma)
    assert "flat.png" in v.description
    assert v.diagnostics["warnings"] == []
    checker = np.where((np.indices((300, 450)).sum(axis=0) // 40) % 2 == 0, 60, 200)
    with pytest.warns(SelfcalWarning):
        doubtful = flat_field_vignetting(np.repeat(checker[..., None], 3, axis=2)
                                         .astype(np.uint8))
    d = doubtful.diagnostics
    assert (d["residual_rms_log"] > FLAT_RESIDUAL_WARN
            or d["blocks_used"] < 0.5 * d["blocks"]) and len(d["warnings"]) == 1
    with pytest.raises(InputError):
        flat_field_vignetting(np.zeros((10, 10), np.uint8))
    with pytest.raises(CalibrationError, match="unclipped"):
        flat_field_vignetting(np.full((300, 450, 3), 255, np.uint8))
    with pytest.raises(InputError, match="absent.png"):
        flat_field_vignetting(tmp_path / "absent.png")
