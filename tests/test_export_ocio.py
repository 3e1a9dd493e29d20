"""Shaper LUTs, CLF files and OpenColorIO configs, applied by OpenColorIO itself.

Every file is read by OpenColorIO's Python bindings (``opencolorio`` from the package
index; the reference implementation of CLF and OCIO configs) and compared with selfcal's
own ``render`` / ``to_raw`` / ``linearize``: a model in closed form (its LUTs must follow
it), the fixture pair's fitted model, the fixture stack's response model, and the NUS
D7000 model folder when ../shared/data holds it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import selfcal
from selfcal.export import write_cube
from selfcal.export.clf import write_clf, write_model_clf
from selfcal.export.ocio import (CONFIG_NAME, OCIO_3D_SIZE, ocio_colour_space_names,
                                 write_ocio_config)
from selfcal.export.shaper import (apply_shaper_lut, render_knees, shaper_lut,
                                   write_shaper_cube)
from selfcal.io import read_image
from selfcal_cli.common import EXIT_OUTPUT
from selfcal_cli.main import main

ocio = pytest.importorskip("PyOpenColorIO", reason="OpenColorIO's Python bindings (pip "
                           "install opencolorio, the test extra) are not installed")

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
NUS = Path(__file__).resolve().parents[2] / "shared" / "data" / "nus_model_nikon_d7000"


class _ClosedForm:
    """A pipeline model in closed form: ``render(ρ) = (M ρ)^(1/2.2)``, ``to_raw`` its
    inverse (not clipped: smooth, so that the tables' error is interpolation alone).  ``M`` mixes the channels asymmetrically (rows sum to 1, entries positive),
    so a 3D table written in the wrong axis order cannot follow it."""

    matrix = np.array([[0.80, 0.15, 0.05], [0.10, 0.75, 0.15], [0.02, 0.18, 0.80]])

    @staticmethod
    def tone_curves(x):
        return np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0) ** (1 / 2.2)

    @staticmethod
    def inverse_tone_curves(p):
        return np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0) ** 2.2

    def render(self, raw):
        return self.tone_curves(np.asarray(raw, dtype=np.float64) @ self.matrix.T)

    def to_raw(self, rendered):
        return self.inverse_tone_curves(rendered) @ np.linalg.inv(self.matrix).T


def _apply_file(path, x, tetrahedral=False):
    ft = ocio.FileTransform(src=str(path))
    if tetrahedral:     # a .cube carries no interpolation; CLF says tetrahedral itself
        ft.setInterpolation(ocio.INTERP_TETRAHEDRAL)
    proc = ocio.Config.CreateRaw().getProcessor(ft).getDefaultCPUProcessor()
    img = np.ascontiguousarray(np.asarray(x, dtype=np.float32))
    proc.applyRGB(img)
    return img.astype(np.float64)


def _apply_config(config, src, dst, x):
    proc = config.getProcessor(src, dst).getDefaultCPUProcessor()
    img = np.ascontiguousarray(np.asarray(x, dtype=np.float32))
    proc.applyRGB(img)
    return img.astype(np.float64)


@pytest.fixture(autouse=True)
def _fresh_ocio_cache():
    """OpenColorIO caches files by path: tests writing the same name must not share."""
    ocio.ClearAllCaches()
    yield


@pytest.fixture(scope="module")
def response_model():
    return selfcal.calibrate_response(sorted((FIXTURES / "stack").glob("*.jpg")))


def test_render_shaper_knee_from_the_tone_curve():
    # f(ε M_cc) = 1/4 with f = x^(1/2.2): ε_c = 0.25^2.2 / M_cc
    want = 0.25 ** 2.2 / np.diag(_ClosedForm.matrix)
    np.testing.assert_allclose(render_knees(_ClosedForm()), want, rtol=2e-3)
    lut = shaper_lut(_ClosedForm(), "render", size=5, shaper_size=257)
    assert lut.shaper[0].tolist() == [0, 0, 0] and np.allclose(lut.shaper[-1], 1)
    assert np.all(np.diff(lut.shaper, axis=0) > 0)
    with pytest.raises(selfcal.InputError, match="LUT_3D_SIZE"):
        shaper_lut(_ClosedForm(), "render", size=300)
    with pytest.raises(selfcal.InputError, match="to-raw' or 'render"):
        shaper_lut(_ClosedForm(), "linearize")


@pytest.mark.parametrize("direction", ["render", "to-raw"])
def test_clf_and_shaper_cube_follow_a_closed_form_model(direction, tmp_path):
    model = _ClosedForm()
    lut = shaper_lut(model, direction, size=33)
    clf = write_clf(lut, tmp_path / "m.clf", direction, name="closed form")
    cube = write_shaper_cube(lut, tmp_path / "m.cube")
    rng = np.random.default_rng(3)
    if direction == "render":
        x = rng.random((4000, 3)) ** 3          # linear raw: many dark values
    else:
        x = model.render(rng.random((4000, 3)))  # renderings inside the model's gamut
    want = model.render(x) if direction == "render" else model.to_raw(x)
    by_clf = _apply_file(clf, x)
    by_cube = _apply_file(cube, x, tetrahedral=True)
    np.testing.assert_allclose(by_clf, apply_shaper_lut(lut, x), atol=2e-6)
    np.testing.assert_allclose(by_cube, by_clf, atol=2e-6)
    err = np.abs(by_clf - want).max(axis=1)
    # measured: render 98.8 % within 0.005, worst 0.024 (x^(1/2.2) has an infinite slope
    # at black, which no table follows in its first cell); to-raw 100 %, worst 0.0013
    share, worst = np.mean(err <= 0.005), err.max()
    assert share > (0.98 if direction == "render" else 0.999) and worst < 0.03, (share, worst)
    # the CLF's structure: Range, LUT1D, LUT3D (blue fastest, tetrahedral)
    root = ET.parse(clf).getroot()
    assert root.tag == "ProcessList" and root.get("compCLFversion") == "3"
    nodes = [n.tag for n in root if n.tag in ("Range", "LUT1D", "LUT3D")]
    assert nodes == ["Range", "LUT1D", "LUT3D"]
    assert root.find("LUT3D").get("interpolation") == "tetrahedral"
    assert root.find("LUT3D/Array").get("dim") == "33 33 33 3"


def test_fitted_model_shaper_luts_by_ocio(pair_pixels_model, tmp_path):
    raw16 = read_image(FIXTURES / "pair" / "pair.tiff")
    jpg = read_image(FIXTURES / "pair" / "pair.jpg")
    want = pair_pixels_model.render(raw16)
    clf = write_model_clf(pair_pixels_model, tmp_path / "render.clf", direction="render")
    err = np.abs(_apply_file(clf, raw16 / 65535.0) - want).max(axis=2)
    plain = write_cube(pair_pixels_model, tmp_path / "plain.cube", direction="render")
    err_plain = np.abs(_apply_file(plain, raw16 / 65535.0, True) - want).max(axis=2)
    # measured: 98.5 % within 0.005 with the shaper, 57 % on the uniform 33³ grid
    assert np.mean(err <= 0.005) > 0.97 and np.mean(err_plain <= 0.005) < 0.8
    clf = write_model_clf(pair_pixels_model, tmp_path / "to_raw.clf", direction="to-raw")
    err = np.abs(_apply_file(clf, jpg / 255.0) - pair_pixels_model.to_raw(jpg)).max(axis=2)
    inner = ((jpg >= 8) & (jpg <= 247)).all(axis=2)
    assert np.mean(err[inner] <= 0.005) > 0.995       # measured 99.95 %


def test_response_exports_equal_linearize(response_model, tmp_path):
    codes = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    want = response_model.linearize(codes)
    cube = write_cube(response_model, tmp_path / "lin.cube")
    clf = write_model_clf(response_model, tmp_path / "lin.clf")
    for path in (cube, clf):
        assert np.abs(_apply_file(path, codes / 255.0) - want).max() < 1e-4, path.name
    root = ET.parse(clf).getroot()
    assert [n.tag for n in root if n.tag in ("Range", "LUT1D", "LUT3D")] == ["Range", "LUT1D"]
    cfg_path = write_ocio_config(response_model, tmp_path / "ocio", camera="stack")
    config = ocio.Config.CreateFromFile(str(cfg_path))
    config.validate()
    names = ocio_colour_space_names("stack")
    lin = _apply_config(config, names["jpeg"], names["linear"], codes / 255.0)
    assert np.abs(lin - want).max() < 1e-4
    back = _apply_config(config, names["linear"], names["jpeg"], lin)
    assert np.abs(back - codes / 255.0).max() < 0.005
    assert "JPEG's own primaries" in config.getColorSpace(names["linear"]).getDescription()


def test_ocio_config_validates_and_round_trips(tmp_path):
    model = _ClosedForm()
    cfg_path = write_ocio_config(model, tmp_path / "cam", camera="closed form", size=33)
    assert sorted(p.name for p in (tmp_path / "cam").iterdir()) == [
        CONFIG_NAME, "jpeg_to_linear.clf", "linear_to_jpeg.clf"]
    assert [p.name for p in tmp_path.iterdir()] == ["cam"]      # no temporary left
    config = ocio.Config.CreateFromFile(str(cfg_path))
    config.validate()
    names = ocio_colour_space_names("closed form")
    assert config.getRoleColorSpace("scene_linear") == names["linear"]
    assert config.getColorSpace(names["data"]).isData()
    assert "raw" in config.getColorSpace(names["linear"]).getDescription()
    jpeg = model.render(np.random.default_rng(5).random((64, 64, 3)))
    lin = _apply_config(config, names["jpeg"], names["linear"], jpeg)
    err = np.abs(lin - model.to_raw(jpeg)).max(axis=2)
    assert np.mean(err <= 0.005) > 0.99 and err.max() < 0.03
    back = _apply_config(config, names["linear"], names["jpeg"], lin)
    err = np.abs(back - jpeg).max(axis=2)
    assert np.mean(err <= 0.005) > 0.99 and err.max() < 0.02
    assert OCIO_3D_SIZE == 65


def test_export_cli_formats_and_ocio(pair_pixels_model, response_model, tmp_path, capsys,
                                     monkeypatch):
    pair_pixels_model.save(tmp_path / "pipe.json")
    response_model.save(tmp_path / "resp.json")
    # an extension the command does not write: a usage error, nothing written
    for name in ("lut.xyz", "lut"):
        with pytest.raises(SystemExit) as info:
            main(["export", str(tmp_path / "resp.json"), "-o", str(tmp_path / name)])
        assert info.value.code == 2 and not (tmp_path / name).exists()
    assert ".cube or .clf" in capsys.readouterr().err
    # .clf is CLF in both kinds (not .cube text)
    assert main(["export", str(tmp_path / "resp.json"), "-o", str(tmp_path / "lin.clf")]) == 0
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "r.clf"),
                 "--direction", "render", "--size", "9", "--shaper-size", "257"]) == 0
    for name in ("lin.clf", "r.clf"):
        assert ET.parse(tmp_path / name).getroot().tag == "ProcessList"
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "r.cube"),
                 "--direction", "render", "--size", "9", "--shaper-size", "257"]) == 0
    text = (tmp_path / "r.cube").read_text()
    assert "LUT_1D_SIZE 257" in text and "LUT_3D_SIZE 9" in text and "DOMAIN" not in text
    # --ocio: the folder whole; an existing one refused (exit 5) untouched; --force
    out = tmp_path / "cfg"
    assert main(["export", str(tmp_path / "pipe.json"), "--ocio", str(out), "--size",
                 "9", "--shaper-size", "257"]) == 0
    ocio.Config.CreateFromFile(str(out / CONFIG_NAME)).validate()
    before = (out / "linear_to_jpeg.clf").read_bytes()
    assert main(["export", str(tmp_path / "pipe.json"), "--ocio", str(out)]) == EXIT_OUTPUT
    assert (out / "linear_to_jpeg.clf").read_bytes() == before
    # all or nothing: a failure while writing leaves the old folder as it was
    import selfcal.export.ocio as export_ocio

    def broken(content, path, *args, **kwargs):
        if Path(path).name == "linear_to_jpeg.clf":
            raise OSError(28, "No space left on device")
        return write_clf(content, path, *args, **kwargs)

    monkeypatch.setattr(export_ocio, "write_clf", broken)
    assert main(["export", str(tmp_path / "pipe.json"), "--ocio", str(out), "--force",
                 "--size", "5", "--shaper-size", "65"]) == EXIT_OUTPUT
    assert (out / "linear_to_jpeg.clf").read_bytes() == before
    assert main(["export", str(tmp_path / "pipe.json"), "--ocio", str(tmp_path / "new"),
                 "--size", "5", "--shaper-size", "65"]) == EXIT_OUTPUT
    assert not (tmp_path / "new").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    monkeypatch.undo()
    assert main(["export", str(tmp_path / "pipe.json"), "--ocio", str(out), "--force",
                 "--size", "5", "--shaper-size", "65"]) == 0
    assert (out / "linear_to_jpeg.clf").read_bytes() != before
    # options that only apply to -o
    with pytest.raises(SystemExit) as info:
        main(["export", str(tmp_path / "pipe.json"), "--ocio", str(tmp_path / "x"),
              "--direction", "render"])
    assert info.value.code == 2 and not (tmp_path / "x").exists()


@pytest.mark.skipif(not NUS.exists(), reason="../shared/data/nus_model_nikon_d7000 absent")
def test_nus_shaper_luts_by_ocio(tmp_path):
    """The NUS D7000 model folder at 33³, applied by OpenColorIO to the fixture frames."""
    model = selfcal.load_model(NUS)
    jpg = read_image(FIXTURES / "pair" / "pair.jpg")[::2, ::2]     # fewer raws to render
    lo, hi = model.camera.valid_range
    ours = model.to_raw(jpg)
    clf = write_model_clf(model, tmp_path / "to_raw.clf", direction="to-raw")
    err = np.abs(_apply_file(clf, jpg / 255.0) - ours).max(axis=2)
    inside = ((jpg >= lo) & (jpg <= hi)).all(axis=2)
    assert np.mean(err[inside] <= 0.005) > 0.999          # measured 100 %
    raw16 = np.round(np.clip(ours, 0, 1) * 65535).astype(np.uint16)
    want = model.render(raw16)
    clf = write_model_clf(model, tmp_path / "render.clf", direction="render")
    err = np.abs(_apply_file(clf, raw16 / 65535.0) - want).max(axis=2)
    codes = np.round(want * 255)
    inside = ((codes >= lo) & (codes <= hi)).all(axis=2)
    # measured 97.9 % (the bench's real frames: 98.9-99.5 %, BENCHMARKS.md)
    assert np.mean(err[inside] <= 0.005) > 0.97, np.mean(err[inside] <= 0.005)
