"""Half-float radiance outputs never hold inf or NaN.

A radiance in EXIF units (t·ISO/100/N²) of a daylight bracket (f/16, ISO 100, 1/4000 s)
reaches ~1e7, far beyond half-float's 65,504: ``write_radiance(half=True)`` stores it
divided by a power of two and records the factor.  Read back here by readers other than
selfcal's: OpenCV for EXR, tifffile for TIFF, and the scale from the bytes of the EXR
header / the TIFF's ImageDescription.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402

from selfcal import sim  # noqa: E402
from selfcal.hdr.io import (  # noqa: E402
    HALF_LIMIT,
    SCALE_ATTRIBUTE,
    read_radiance,
    write_radiance,
)
from selfcal.response.model import ResponseModel  # noqa: E402

HALF_MAX = 65504.0


def daylight_radiance(shape=(40, 60, 3), top=1e7, seed=0) -> np.ndarray:
    """Log-uniform radiance from 1e-3 up to ``top`` (reached exactly), float32."""
    rng = np.random.default_rng(seed)
    r = np.exp(rng.uniform(np.log(1e-3), np.log(top), shape))
    r.flat[0] = top
    return r.astype(np.float32)


def exr_scale_from_bytes(path) -> float | None:
    """The selfcalRadianceScale double of an EXR header, read from the bytes directly."""
    data = open(path, "rb").read()
    key = SCALE_ATTRIBUTE.encode() + b"\0double\0"
    at = data.find(key)
    if at < 0:
        return None
    size, value = struct.unpack_from("<id", data, at + len(key))
    assert size == 8
    return value


def tiff_scale(path) -> float | None:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        meta = json.loads(tif.pages[0].description)
    return meta.get(SCALE_ATTRIBUTE)


def assert_equal_to_half_precision(stored_times_scale, radiance, scale):
    """Equal up to half rounding: relative 2⁻¹¹ where the stored value is a normal float16,
    absolute 2⁻²⁵·scale (half a subnormal step) below."""
    normal = np.abs(radiance) / scale >= 2.0 ** -14
    err = np.abs(stored_times_scale.astype(np.float64) - radiance)
    assert np.all(err[normal] <= 2.0 ** -11 * np.abs(radiance[normal]))
    assert np.all(err[~normal] <= 2.0 ** -25 * scale)
    assert normal.mean() > 0.5


@pytest.mark.parametrize("name", ["r.exr", "r.tif"])
def test_half_output_is_finite_and_scaled_back(tmp_path, name):
    radiance = daylight_radiance()
    written = write_radiance(tmp_path / name, radiance, half=True)
    scale = written.scale
    # the smallest power of two that brings 1e7 to at most 2**15: 2**9 = 512
    assert scale == 512.0 and 1e7 / scale <= HALF_LIMIT < 1e7 / (scale / 2)
    if name.endswith(".exr"):
        stored = cv2.imread(str(written), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
        assert exr_scale_from_bytes(written) == scale
    else:
        import tifffile

        stored = tifffile.imread(written)
        assert stored.dtype == np.float16
        assert tiff_scale(written) == scale
    assert stored.shape == radiance.shape
    assert np.all(np.isfinite(stored)) and np.abs(stored).max() <= HALF_MAX
    assert_equal_to_half_precision(stored.astype(np.float64) * scale, radiance, scale)
    # selfcal's own reader multiplies back
    back = read_radiance(written)
    assert_equal_to_half_precision(back, radiance, scale)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


@pytest.mark.parametrize("name", ["r.exr", "r.tiff"])
def test_values_in_range_are_written_unscaled(tmp_path, name):
    radiance = daylight_radiance(top=30000.0)
    written = write_radiance(tmp_path / name, radiance, half=True)
    assert written.scale == 1.0
    if name.endswith(".exr"):
        assert exr_scale_from_bytes(written) is None
    else:
        assert tiff_scale(written) is None
    np.testing.assert_allclose(read_radiance(written), radiance, rtol=2.0 ** -11,
                               atol=2.0 ** -25)


def test_float32_and_negative_values(tmp_path):
    radiance = daylight_radiance()
    radiance[0, 1] = -3e6           # magnitudes count, whatever the sign
    assert write_radiance(tmp_path / "f.exr", radiance).scale == 1.0    # float32 fits
    np.testing.assert_array_equal(read_radiance(tmp_path / "f.exr"), radiance)
    written = write_radiance(tmp_path / "h.exr", radiance, half=True)
    stored = cv2.imread(str(written), cv2.IMREAD_UNCHANGED)
    assert np.all(np.isfinite(stored))
    assert read_radiance(written)[0, 1, 0] == pytest.approx(-3e6, rel=2.0 ** -11)


def test_cli_merge_half_says_the_scale(tmp_path, capsys):
    """A daylight bracket with EXIF (f/16, ISO 100, 1/4000 … 1/250 s): merge --half."""
    from selfcal_cli import main as cli_main

    times = [1 / 4000, 1 / 2000, 1 / 1000, 1 / 500, 1 / 250]
    scene = sim.make_scene(48, 64, dynamic_range_stops=10.0, seed=3)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=3), times,
                                 jpeg_quality=95, seed=3)
    stack.f_number = 16.0
    frames = stack.write(tmp_path / "frames")
    model = ResponseModel(intensity=np.arange(256) / 255.0, inverse=stack.inverse_response(),
                          coefficients=np.zeros((3, 1)), basis_name="truth",
                          exposures=np.asarray(stack.true_exposures, dtype=float),
                          exposure_times=list(stack.exposure_times),
                          sources=[f"array #{k}" for k in range(len(times))])
    model.save(tmp_path / "model.json")
    out = tmp_path / "day.exr"
    code = cli_main.main(["merge", *map(str, frames), "--model", str(tmp_path / "model.json"),
                          "-o", str(out), "--half"])
    text = capsys.readouterr()
    text = text.out + text.err
    assert code == 0, text
    scale = exr_scale_from_bytes(out)
    assert scale is not None and scale > 1 and scale == 2.0 ** round(np.log2(scale))
    assert f"x {scale:g}" in text and SCALE_ATTRIBUTE in text
    stored = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert np.all(np.isfinite(stored)) and np.abs(stored).max() <= HALF_LIMIT
    assert np.abs(read_radiance(out)).max() > HALF_MAX       # the radiance is out of range
