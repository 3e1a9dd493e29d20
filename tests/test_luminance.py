"""Absolute luminance (cd/m²): the scale from a reference reading or from EXIF, the merge
that applies it, the files that say it (read back by OpenEXR's bindings and by Radiance's
own tools), and the command line.

The simulated camera's absolute calibration is known (:mod:`selfcal.sim.luminance`: it
follows the ISO 12232 standard output sensitivity exactly here).
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import selfcal
from selfcal.errors import InputError, ModelFileError
from selfcal.hdr import MergeOptions
from selfcal.hdr.io import RADIANCE_EFFICACY, write_radiance, write_radiance_sigma
from selfcal.lens.luminance import (EXIF_LOG_SIGMA, SRGB_CHROMATICITIES, LuminanceScale,
                                    ReferenceReading, absolute_radiance, card_luminance,
                                    luminance_of, parse_reference, scale_from_exif,
                                    scale_from_reference)
from selfcal.sim.luminance import true_luminance, true_relative_radiance, true_scale
from selfcal_cli.main import main


# ------------------------------------------------------------------ the scale itself

def test_parse_reference_forms():
    spot = parse_reference("10,20,30,40=120cd/m2")
    assert spot.region == (10, 20, 30, 40) and spot.luminance == 120.0
    assert parse_reference("0,0,8,8=5.5 nits").luminance == 5.5
    card = parse_reference("card:0.18@500lux:0,0,8,8", accuracy=0.05)
    assert card.luminance == pytest.approx(0.18 * 500 / math.pi)
    assert card.accuracy == 0.05
    assert parse_reference("card:18%@500lux:0,0,8,8").luminance == pytest.approx(
        card.luminance)


@pytest.mark.parametrize("text", ["10,10,50=3", "10,10,5,50=3", "1,2,3,4=-2",
                                  "card:1.5@500lux:0,0,8,8", "card:0.18@0lux:0,0,8,8",
                                  "card:0.18:0,0,8,8", "x"])
def test_parse_reference_refuses(text):
    with pytest.raises(InputError):
        parse_reference(text)


def test_card_luminance_is_rho_e_over_pi():
    assert card_luminance(1.0, math.pi) == pytest.approx(1.0)


class SrgbModel:
    """A stand-in response model: the sRGB curve, f⁻¹(255) = 1."""
    max_code = 255

    def inverse_response(self, codes):
        x = np.asarray(codes, float) / 255
        lin = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
        return np.repeat(lin[:, None], 3, axis=1)


def test_exif_scale_of_an_srgb_camera():
    # C = 10 / (100 q f⁻¹(118)), f⁻¹(118) = 0.178 on the sRGB curve, q = 0.65
    s = scale_from_exif(SrgbModel())
    grey = SrgbModel().inverse_response([118])[0, 0]
    assert s.scale == pytest.approx(0.1 / (0.65 * grey))
    assert 0.8 < s.scale < 0.9
    assert s.log_sigma == pytest.approx(math.log(2) / 3)
    assert s.source == "exif-convention" and "12232" in s.description
    linear = scale_from_exif(None)           # saturation-based: 78 / (100 q)
    assert linear.scale == pytest.approx(1.2)


def test_scale_round_trips_through_a_model_file(tmp_path):
    stack = selfcal.sim.demo_stack()
    model = selfcal.calibrate_response(stack.images[:3], stack.exposure_times[:3])
    scale = LuminanceScale(2.5, 0.04, "reference", "spot meter 120 cd/m2")
    assert LuminanceScale.from_dict(scale.to_dict()) == scale
    path = dataclasses.replace(model, luminance=scale).save(tmp_path / "m.json")
    assert selfcal.load_model(path).luminance == scale
    doc = json.loads(path.read_text())
    doc["luminance"]["scale"] = 0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ModelFileError, match="luminance"):
        selfcal.load_model(bad)


def test_reference_region_outside_or_unmeasured():
    rad = np.ones((20, 30, 3), np.float32)
    with pytest.raises(InputError, match="outside"):
        scale_from_reference(rad, ReferenceReading((0, 0, 31, 5), 10.0))
    unmeasured = np.ones((20, 30), bool)
    with pytest.raises(InputError, match="measured pixels"):
        scale_from_reference(rad, ReferenceReading((0, 0, 10, 10), 10.0),
                             unmeasured=unmeasured)
    s = scale_from_reference(rad * 4, ReferenceReading((0, 0, 10, 10), 10.0, accuracy=0.03))
    assert s.scale == pytest.approx(2.5) and s.log_sigma == pytest.approx(0.03)


def test_sigma_adds_the_scale_in_quadrature():
    rad = np.full((4, 5, 3), 2.0, np.float32)
    sig = np.full((4, 5, 3), 0.1, np.float32)
    sig[0, 0] = np.inf
    scale = LuminanceScale(10.0, 0.05, "exif-convention")
    out, s, summary = absolute_radiance(scale, rad.copy(), sig.copy())
    assert np.allclose(out, 20.0)
    assert np.allclose(s[1:], math.hypot(1.0, 20.0 * 0.05))
    assert np.isinf(s[0, 0]).all()
    assert summary["total_log_sigma"] == pytest.approx(0.05)
    # a reference measured on another merge adds the exposure level's repeatability
    _, _, summary = absolute_radiance(LuminanceScale(10.0, 0.05, "reference"), rad.copy(),
                                      None)
    assert summary["total_log_sigma"] > 0.05


# ------------------------------------------------------------------ on the simulator

def _uniform_block(values, ok, size=16):
    """The fully ok size×size block (stride 8) of least log spread at mid luminance."""
    lo, hi = np.percentile(values[ok], [25, 75])
    best, where = np.inf, None
    logs = np.log(np.maximum(values, 1e-30))
    for y in range(0, values.shape[0] - size + 1, 8):
        for x in range(0, values.shape[1] - size + 1, 8):
            if ok[y:y + size, x:x + size].all() and lo <= values[y:y + size, x:x + size].mean() <= hi:
                s = logs[y:y + size, x:x + size].std()
                if s < best:
                    best, where = s, (x, y, x + size, y + size)
    return where


@pytest.fixture(scope="module")
def written_stack(tmp_path_factory):
    from selfcal.sim.conditions import CONDITIONS
    from selfcal.sim.scoring import truth_masks

    stack = CONDITIONS["colourful/base"].simulate(selfcal.sim.ToneCurve.srgb(), seed=7)
    stack.f_number, stack.iso = 5.6, 400.0
    paths = stack.write(tmp_path_factory.mktemp("lum"))
    _, scored, *_ = truth_masks(stack)
    return stack, paths, scored.all(axis=2)


def test_reference_reading_gives_luminance_elsewhere_within_2_percent(written_stack):
    stack, paths, scored = written_stack
    l_true = true_luminance(stack)
    region = _uniform_block(l_true, scored)
    x0, y0, x1, y1 = region
    reading = ReferenceReading(region, float(l_true[y0:y1, x0:x1].mean()))
    res = selfcal.merge_hdr(paths, options=MergeOptions(luminance=reading, sigma=True))
    assert res.units == "cd/m2" and res.diagnostics["luminance"]["source"] == "reference"
    ok = scored & ~res.unmeasured
    ok[y0:y1, x0:x1] = False
    err = np.abs(luminance_of(res.radiance)[ok] / l_true[ok] - 1)
    assert np.median(err) < 0.02
    # σ in cd/m² holds the scale's σ: never below L · total log-σ
    total = res.diagnostics["luminance"]["total_log_sigma"]
    m = ~res.unmeasured
    assert np.all(res.sigma[m] >= 0.999 * np.abs(res.radiance[m]) * total)


def test_exif_alone_within_its_stated_error(written_stack):
    stack, paths, scored = written_stack
    res = selfcal.merge_hdr(paths, options=MergeOptions(luminance="exif"))
    assert res.units == "cd/m2"
    assert res.diagnostics["luminance"]["scale"] == pytest.approx(
        scale_from_exif(res.model).scale)
    ok = scored & ~res.unmeasured
    log_err = np.log(luminance_of(res.radiance)[ok] / true_luminance(stack)[ok])
    # this simulated camera follows the convention exactly: only the calibration's error
    assert abs(np.median(log_err)) < EXIF_LOG_SIGMA / 2
    # the truth's relative radiance is what the merge of EXIF files estimates
    rel = true_relative_radiance(stack)
    assert true_scale(stack) * luminance_of(rel)[ok] == pytest.approx(
        true_luminance(stack)[ok])


def test_exif_luminance_needs_exif_exposures(written_stack):
    stack, _, _ = written_stack
    with pytest.raises(InputError, match="EXIF"):
        selfcal.merge_hdr(stack.images[:3], stack.exposure_times[:3],
                          options=MergeOptions(luminance="exif"))


# ------------------------------------------------------------------ files

def test_exr_carries_white_luminance_and_chromaticities(tmp_path):
    import OpenEXR

    rad = np.random.default_rng(0).uniform(1, 5e4, (8, 10, 3)).astype(np.float32)
    def with_sigma(p, **k):
        return write_radiance_sigma(p, rad, rad / 10, **k)[0]

    for name, writer in (("plain.exr", lambda p, **k: write_radiance(p, rad, **k)),
                         ("sigma.exr", with_sigma)):
        for half in (False, True):
            path = tmp_path / f"{half}-{name}"
            written = writer(path, units="cd/m2", half=half)
            with OpenEXR.File(str(path)) as exr:
                header = dict(exr.header())
            assert header["whiteLuminance"] == pytest.approx(written.scale)
            assert np.allclose(header["chromaticities"], SRGB_CHROMATICITIES, atol=1e-6)
            assert written.scale == (2.0 if half else 1.0)
    write_radiance(tmp_path / "rel.exr", rad)
    with OpenEXR.File(str(tmp_path / "rel.exr")) as exr:
        header = dict(exr.header())
    assert "whiteLuminance" not in header and "chromaticities" in header


def _radiance_tool(name):
    found = shutil.which(name)
    if found:
        return found
    try:
        import pyradiance
    except ImportError:
        return None
    path = Path(pyradiance.__file__).parent / "bin" / name
    return str(path) if path.is_file() else None


def test_hdr_exposure_as_radiance_reads_it(tmp_path):
    getinfo, pvalue = _radiance_tool("getinfo"), _radiance_tool("pvalue")
    if not (getinfo and pvalue):
        pytest.skip("Radiance's getinfo/pvalue not found (pip install pyradiance)")
    grey = np.full((4, 6, 3), 120.0, np.float32)          # 120 cd/m², neutral
    path = tmp_path / "abs.hdr"
    write_radiance(path, grey, units="cd/m2")
    info = subprocess.run([getinfo, str(path)], capture_output=True, text=True,
                          check=True).stdout
    assert "EXPOSURE= 179" in info and "PRIMARIES= 0.6400 0.3300" in info
    # pvalue -o: the original values, stored / EXPOSURE, in W/sr/m²
    out = subprocess.run([pvalue, "-o", "-h", "-H", "-d", str(path)], capture_output=True,
                         text=True, check=True).stdout.split()
    rgb = np.array(out[:3], float)
    lum = RADIANCE_EFFICACY * float(rgb @ [0.265, 0.670, 0.065])
    assert lum == pytest.approx(120.0, rel=0.01)
    write_radiance(tmp_path / "rel.hdr", grey)
    info = subprocess.run([getinfo, str(tmp_path / "rel.hdr")], capture_output=True,
                          text=True, check=True).stdout
    assert "EXPOSURE" not in info and "PRIMARIES" in info


# ------------------------------------------------------------------ command line

@pytest.mark.parametrize("argv, named", [
    (["--reading", "10,10,50=3"], "--reading"),
    (["--reading", "card:0.18@500:1,1,9,9"], "--reading"),
    (["--reading", "0,0,5000,40=30"], "--reading"),
    (["--luminance", "exif", "--times", "1/250", "1/125", "1/60"], "--luminance"),
    (["--meter-accuracy", "150"], "--meter-accuracy"),
    (["--falsecolor", "x.jpg"], "--falsecolor"),
    (["--save-scale", "m.json"], "--save-scale"),
])
def test_cli_bad_luminance_arguments_exit_2(argv, named, written_stack, tmp_path, capsys):
    _, paths, _ = written_stack
    with pytest.raises(SystemExit) as info:
        main(["merge", *map(str, paths[:3]), "-o", str(tmp_path / "x.exr"), *argv])
    assert info.value.code == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "x.exr").exists()


def test_cli_reading_saved_and_applied_later(written_stack, tmp_path, capsys):
    import OpenEXR

    _, paths, _ = written_stack
    files = [str(p) for p in paths]
    model = tmp_path / "abs.json"
    assert main(["merge", *files, "-o", str(tmp_path / "a.hdr"), "--reading",
                 "card:0.18@500lux:8,8,24,24", "--save-scale", str(model), "--falsecolor",
                 str(tmp_path / "a.png")]) == 0
    err = capsys.readouterr().err
    assert "cd/m²" in err and (tmp_path / "a.png").stat().st_size > 0
    scale = selfcal.load_model(model).luminance
    assert scale is not None and scale.source == "reference"
    assert main(["merge", *files, "-o", str(tmp_path / "b.exr"), "--model", str(model)]) == 0
    with OpenEXR.File(str(tmp_path / "b.exr")) as exr:
        assert exr.header()["whiteLuminance"] == 1.0
    assert "luminance scale" in capsys.readouterr().err


def test_batch_applies_one_camera_curve_and_the_exif_convention(tmp_path):
    import OpenEXR

    from selfcal.batch import BatchOptions, run_batch
    from selfcal.sim.cards import default_bodies, write_library

    write_library(tmp_path / "card", bodies=default_bodies()[:1], sessions_per_body=2)
    result = run_batch([tmp_path / "card"], tmp_path / "out", scheduler="serial",
                       options=BatchOptions(luminance="exif"))
    rows = [r for r in result.rows if r["status"] == "ok"]
    assert len(rows) == 2 and all(r["units"] == "cd/m2" for r in rows)
    # one camera, one curve: one EXIF scale for all its sessions
    assert rows[0]["luminance_scale"] == pytest.approx(rows[1]["luminance_scale"])
    exr = next(p for p in rows[0]["outputs"] if p.endswith(".exr"))
    with OpenEXR.File(exr) as f:
        assert dict(f.header())["whiteLuminance"] == 1.0
