"""``selfcal export``: .cube LUTs read back by independent readers (colour-science, ffmpeg).

The 1D table is read by colour-science's ``read_LUT`` and applied to every 8-bit code; the
3D tables are applied to the fixture frames by ffmpeg's ``lut3d`` filter (the
imageio-ffmpeg binary and a system ``ffmpeg`` when there is one) on lossless 16-bit
frames (``rgb48le`` raw video in and out), and by colour-science's trilinear
interpolation of the table it read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import selfcal
from ffmpeg_lut import apply_cube_ffmpeg, ffmpeg_binaries
from selfcal.export import cube_table, read_cube_header, write_cube
from selfcal.io import read_image
from selfcal_cli.common import EXIT_INPUT, EXIT_OUTPUT
from selfcal_cli.main import main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


@pytest.fixture
def colour():
    """colour-science, the independent .cube reader (only the tests that read with it skip
    without it)."""
    return pytest.importorskip("colour", reason="colour-science (the independent .cube "
                               "reader) is not installed")


FFMPEG = ffmpeg_binaries()
needs_ffmpeg = pytest.mark.skipif(not FFMPEG, reason="no ffmpeg: neither imageio-ffmpeg "
                                  "(pip install imageio-ffmpeg) nor ffmpeg on PATH")


@pytest.fixture(scope="module")
def response_model():
    return selfcal.calibrate_response(sorted((FIXTURES / "stack").glob("*.jpg")))


def test_1d_cube_read_by_colour_linearises_every_code(response_model, tmp_path, colour):
    path = write_cube(response_model, tmp_path / "lin.cube")
    head = read_cube_header(path)
    assert head["LUT_1D_SIZE"] == "256" and head["TITLE"].startswith('"')
    assert head["DOMAIN_MIN"].split() == ["0.0"] * 3 and head["DOMAIN_MAX"].split() == ["1.0"] * 3
    lut = colour.read_LUT(str(path))
    assert isinstance(lut, colour.LUT3x1D) and lut.size == 256
    codes = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    want = response_model.linearize(codes)
    got = lut.apply(codes / 255.0)
    assert np.abs(got - want).max() < 1e-3
    # another size: nodes between the codes, still within 0.001
    lut = colour.read_LUT(str(write_cube(response_model, tmp_path / "l1024.cube", size=1024)))
    assert np.abs(lut.apply(codes / 255.0) - want).max() < 1e-3


def test_3d_table_order_red_fastest(pair_pixels_model):
    rows, direction, size = cube_table(pair_pixels_model, "to-raw", size=3)
    assert direction == "to-raw" and rows.shape == (27, 3)
    # row 1 is (r, g, b) = (0.5, 0, 0), row 3 is (0, 0.5, 0), row 9 is (0, 0, 0.5)
    for row, node in ((1, [0.5, 0, 0]), (3, [0, 0.5, 0]), (9, [0, 0, 0.5])):
        np.testing.assert_allclose(rows[row], pair_pixels_model.to_raw(np.array([node]))[0],
                                   atol=1e-7)


@needs_ffmpeg
@pytest.mark.parametrize("exe", FFMPEG)
def test_3d_to_raw_cube_applied_by_ffmpeg(pair_pixels_model, tmp_path, exe, colour):
    cube = write_cube(pair_pixels_model, tmp_path / "to_raw.cube", direction="to-raw")
    assert read_cube_header(cube)["LUT_3D_SIZE"] == "33"
    jpg = read_image(FIXTURES / "pair" / "pair.jpg")
    ours = pair_pixels_model.to_raw(jpg)
    by_colour = colour.read_LUT(str(cube)).apply(jpg / 255.0)
    inner = ((jpg >= 8) & (jpg <= 247)).all(axis=2)    # not in a cell touching a clip face
    for interp in ("trilinear", "tetrahedral"):
        out = apply_cube_ffmpeg(exe, cube, jpg.astype(np.uint16) * 257, interp)
        if interp == "trilinear":   # ffmpeg reads the file as colour-science does
            assert np.abs(out - by_colour).max() < 2e-4
        err = np.abs(out - ours).max(axis=2)
        assert np.percentile(err[inner], 99) < 0.005, interp
        assert err[inner].max() < 0.012, interp          # measured 0.008 (33³)


@needs_ffmpeg
@pytest.mark.parametrize("exe", FFMPEG)
def test_3d_render_cube_applied_by_ffmpeg(pair_pixels_model, tmp_path, exe, colour):
    cube = write_cube(pair_pixels_model, tmp_path / "render.cube", direction="render")
    raw16 = read_image(FIXTURES / "pair" / "pair.tiff")
    by_colour = colour.read_LUT(str(cube)).apply(raw16 / 65535.0)
    out = apply_cube_ffmpeg(exe, cube, raw16, "trilinear")
    assert np.abs(out - by_colour).max() < 2e-4
    # at the table's nodes ffmpeg gives selfcal's render (no interpolation error)
    k = np.random.default_rng(1).integers(0, 33, (64, 64, 3))
    nodes16 = np.round(k / 32 * 65535).astype(np.uint16)
    out = apply_cube_ffmpeg(exe, cube, nodes16, "tetrahedral")
    assert np.abs(out - pair_pixels_model.render(nodes16)).max() < 2e-3
    # between nodes: a uniform 33³ grid of linear raw is coarse where the tone curve is
    # steep (the fixture's median raw is 0.045); half the pixels within 0.5 %
    out = apply_cube_ffmpeg(exe, cube, raw16, "tetrahedral")
    err = np.abs(out - pair_pixels_model.render(raw16)).max(axis=2)
    assert np.median(err) < 0.005


def test_export_cli_directions_and_errors(response_model, pair_pixels_model, tmp_path, capsys):
    response_model.save(tmp_path / "resp.json")
    pair_pixels_model.save(tmp_path / "pipe.json")
    assert main(["export", str(tmp_path / "resp.json"), "-o", str(tmp_path / "r.cube")]) == 0
    assert read_cube_header(tmp_path / "r.cube")["LUT_1D_SIZE"] == "256"
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "p.cube"),
                 "--direction", "render", "--size", "17", "--no-shaper"]) == 0
    head = read_cube_header(tmp_path / "p.cube")
    assert head["LUT_3D_SIZE"] == "17" and "pipe.json" in head["TITLE"]
    assert len((tmp_path / "p.cube").read_text().splitlines()) == 6 + 17 ** 3
    capsys.readouterr()
    # an existing output: exit 5, untouched; --force replaces it
    before = (tmp_path / "p.cube").read_bytes()
    assert main(["export", str(tmp_path / "pipe.json"), "-o",
                 str(tmp_path / "p.cube")]) == EXIT_OUTPUT
    assert (tmp_path / "p.cube").read_bytes() == before
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "p.cube"),
                 "--force"]) == 0
    assert read_cube_header(tmp_path / "p.cube")["LUT_3D_SIZE"] == "33"
    # the wrong kind of model for a direction: exit 3, naming the file; nothing written
    assert main(["export", str(tmp_path / "resp.json"), "-o", str(tmp_path / "x.cube"),
                 "--direction", "to-raw"]) == EXIT_INPUT
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "x.cube"),
                 "--direction", "linearize"]) == EXIT_INPUT
    text = capsys.readouterr().err
    assert "resp.json" in text and "pipe.json" in text and not (tmp_path / "x.cube").exists()
    # a size the direction cannot have: a usage error (exit 2)
    for size in ("300", "1", "x"):
        with pytest.raises(SystemExit) as info:
            main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "x.cube"),
                  "--size", size])
        assert info.value.code == 2
    assert "LUT_3D_SIZE" in capsys.readouterr().err
    with pytest.raises(selfcal.InputError, match="LUT_1D_SIZE"):
        write_cube(response_model, tmp_path / "y.cube", size=70000)
    assert not (tmp_path / "y.cube").exists()


class _Multilinear:
    """A stand-in pipeline model whose ``to_raw`` is multilinear in the codes: a table
    continued along chords must hold it exactly at every node, inside or outside."""

    diagnostics = {"valid_range": (5, 252)}

    @staticmethod
    def to_raw(x):
        x = np.asarray(x, dtype=np.float64)
        r, g, b = x[..., 0], x[..., 1], x[..., 2]
        return np.stack([0.1 + 0.5 * r - 0.2 * g * b, r * g + 0.3 * b, 0.2 + r * g * b], -1)

    render = to_raw


class _SteepTop(_Multilinear):
    """Per channel ``x`` up to the node at 15/16, then bending up steeply to 1.5 at 255
    (an ``f⁻¹`` with the shape of a real camera's top codes)."""

    @staticmethod
    def to_raw(x):
        x = np.asarray(x, dtype=np.float64)
        knee = 15 / 16
        return np.where(x <= knee, x, x + 128.0 * (x - knee) ** 2)


def test_code_range_continues_chords_outside(tmp_path):
    size = 17
    x = np.linspace(0.0, 1.0, size)
    b, g, r = np.meshgrid(x, x, x, indexing="ij")
    nodes = np.stack([r, g, b], axis=-1).reshape(-1, 3)
    rows, _, _ = cube_table(_Multilinear(), "to-raw", size=size, code_range=(5, 252))
    np.testing.assert_allclose(rows, _Multilinear.to_raw(nodes), atol=1e-12)
    # a steep top: every node hold the model, or the top cell follows it to code 250
    steep = _SteepTop()
    plain, _, _ = cube_table(steep, "to-raw", size=size, code_range=None)
    ranged, _, _ = cube_table(steep, "to-raw", size=size, code_range=(0, 250))
    np.testing.assert_array_equal(plain, steep.to_raw(nodes))
    inside = (nodes <= 250 / 255).all(axis=1)
    np.testing.assert_array_equal(ranged[inside], plain[inside])
    red = np.arange(size) * 1                        # nodes (k, 0, 0): red varies fastest
    lerp = np.interp(np.arange(256) / 255, x, ranged[red, 0])
    want = steep.to_raw(np.arange(256) / 255)
    assert abs(lerp[250] - want[250]) < 1e-12        # the top cell's chord meets code 250
    err_plain = np.abs(np.interp(np.arange(256) / 255, x, plain[red, 0]) - want)[:251]
    assert np.abs(lerp - want)[:251].max() < 0.6 * err_plain.max()   # measured 0.47x
    # the model's own range by default, said in the file; a render table has none
    path = write_cube(_Multilinear(), tmp_path / "m.cube", direction="to-raw", size=5)
    assert "codes 5-252" in path.read_text().splitlines()[2]
    path = write_cube(_Multilinear(), tmp_path / "r.cube", direction="render", size=5)
    assert "codes" not in path.read_text()
    for bad in ((0, 256), (9, 9), ("a", 3)):
        with pytest.raises(selfcal.InputError, match="code range"):
            cube_table(_Multilinear(), "to-raw", size=5, code_range=bad)
    with pytest.raises(selfcal.InputError, match="to-raw"):
        write_cube(_Multilinear(), tmp_path / "x.cube", direction="render", size=5,
                   code_range=(5, 250))
    assert not (tmp_path / "x.cube").exists()


def test_export_cli_range(pair_pixels_model, tmp_path, capsys):
    pair_pixels_model.save(tmp_path / "pipe.json")
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "a.cube"),
                 "--size", "5"]) == 0
    assert "codes" not in (tmp_path / "a.cube").read_text()     # a fitted model: no range
    assert main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "b.cube"),
                 "--size", "5", "--range", "3", "250", "--no-shaper"]) == 0
    assert "codes 3-250" in (tmp_path / "b.cube").read_text()
    assert "3-250" in capsys.readouterr().err                   # messages go to stderr
    for extra in (["--range", "250", "3", "--no-shaper"],
                  ["--range", "0", "300", "--no-shaper"],
                  ["--direction", "render", "--range", "3", "250", "--no-shaper"],
                  ["--range", "3", "250"]):     # a shaper cube (the default) has no range
        with pytest.raises(SystemExit) as info:
            main(["export", str(tmp_path / "pipe.json"), "-o", str(tmp_path / "c.cube"),
                  *extra])
        assert info.value.code == 2
    assert "--range" in capsys.readouterr().err and not (tmp_path / "c.cube").exists()


NUS = Path(__file__).resolve().parents[2] / "shared" / "data" / "nus_model_nikon_d7000"


@pytest.mark.skipif(not NUS.exists(), reason="../shared/data/nus_model_nikon_d7000 absent")
@needs_ffmpeg
def test_nus_to_raw_cube_inside_the_model_range(tmp_path):
    """The NUS model's to-raw cube (33³, its fitted codes 5-252 by default) by ffmpeg
    against selfcal's to_raw on the fixture frame, pixels inside that range."""
    model = selfcal.load_model(NUS)
    jpg = read_image(FIXTURES / "pair" / "pair.jpg")
    ours = model.to_raw(jpg)
    inside = ((jpg >= 5) & (jpg <= 252)).all(axis=2)
    cube = write_cube(model, tmp_path / "nus.cube", size=33)
    out = apply_cube_ffmpeg(FFMPEG[0], cube, jpg.astype(np.uint16) * 257, "tetrahedral")
    err = np.abs(out - ours).max(axis=2)[inside]
    assert np.mean(err <= 0.005) > 0.999 and err.max() < 0.015   # measured 99.97 %, 0.0094
    plain = write_cube(model, tmp_path / "plain.cube", size=33, code_range=None)
    out = apply_cube_ffmpeg(FFMPEG[0], plain, jpg.astype(np.uint16) * 257, "tetrahedral")
    assert np.abs(out - ours).max(axis=2)[inside].max() > 0.03    # measured 0.047
    # the render table holds the reference evaluation at its nodes
    rows, _, _ = cube_table(model, "render", size=5)
    x = np.linspace(0.0, 1.0, 5)
    b, g, r = np.meshgrid(x, x, x, indexing="ij")
    nodes = np.stack([r, g, b], axis=-1).reshape(-1, 3)
    np.testing.assert_allclose(rows, model.camera.render(nodes), atol=1e-12)
