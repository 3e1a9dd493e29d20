"""NUS model folders as models: ``selfcal.load_model(folder)`` and ``--model FOLDER``.

The reference is the direct RBF evaluation of :class:`selfcal.pipeline.nus.NUSCameraModel`
([Kim2012]); the model ``load_model`` returns is baked into dense tables.
Metric: differences in ``[0, 1]`` (raw for ``to_raw``, rendered for ``render``), RMS over
the pixels of the fixture frames (every pixel: the tables cover the whole input cube),
the reference ``to_raw`` clipped to ``[0, 1]`` as every pipeline model's output is.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile

import selfcal
from selfcal.io import read_image, write_image
from selfcal.pipeline import PipelineModel
from selfcal.pipeline.nus import NUSPipelineModel, read_nus_model
from selfcal_cli.common import EXIT_INPUT
from selfcal_cli.main import main

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "fixtures"
NUS = REPO.parent / "shared" / "data" / "nus_model_nikon_d7000"
needs_nus = pytest.mark.skipif(not NUS.exists(),
                               reason="../shared/data/nus_model_nikon_d7000 absent")


def _rms(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - b) ** 2)))


@pytest.fixture(scope="module")
def nus():
    model = selfcal.load_model(NUS)
    return model, read_nus_model(NUS, wb_code=14)


def test_a_folder_that_is_not_an_nus_model_is_refused(tmp_path):
    with pytest.raises(selfcal.ModelFileError, match="folder"):
        selfcal.load_model(tmp_path)


@needs_nus
def test_load_model_gives_a_pipeline_model_matching_the_reference(nus):
    model, cam = nus
    assert isinstance(model, PipelineModel) and isinstance(model, NUSPipelineModel)
    assert selfcal.load_model(NUS) is model          # baked once per process
    jpg = read_image(FIXTURES / "pair" / "pair.jpg")
    ours = model.to_raw(jpg)
    assert ours.dtype == np.float32 and ours.shape == jpg.shape
    ref = np.clip(cam.to_raw(jpg), 0.0, 1.0)
    assert _rms(ours, ref) < 1e-3                    # measured 1.4e-4 (max 1.3e-3)
    # float input goes through the same table
    assert _rms(model.to_raw(jpg / 255.0), ref) < 1e-3
    raw = read_image(FIXTURES / "pair" / "pair.tiff")
    ours = model.render(raw)
    ref = cam.render(raw / 65535.0)
    assert ours.dtype == np.float32 and ours.shape == raw.shape
    err = np.abs(ours - ref).max(axis=2)
    assert _rms(ours, ref) < 3e-4                    # measured 7.1e-5 (49³ table: 1.7e-3)
    # 3 of the 24,576 pixels are off by more than 1e-3 (at most 2.7e-3): next to a kink
    # of the RBF's cones, where trilinear interpolation is first order
    assert np.percentile(err, 99.9) < 1e-3 and err.max() < 5e-3
    # float input in [0, 1] reads the same 16-bit codes
    np.testing.assert_array_equal(model.render(raw / 65535.0), ours)
    with pytest.raises(selfcal.InputError):
        model.to_raw(jpg, variant="lut")
    with pytest.raises(selfcal.InputError, match="not saved"):
        model.save(Path("unused.json"))


@needs_nus
def test_to_raw_and_render_cli_with_a_model_folder(nus, tmp_path, capsys):
    model, cam = nus
    jpg_path = FIXTURES / "pair" / "pair.jpg"
    code = main(["to-raw", "--model", str(NUS), str(jpg_path), "-o", str(tmp_path / "raw"),
                 "--float"])
    assert code == 0, capsys.readouterr().err
    est = tifffile.imread(tmp_path / "raw" / "pair.tiff")
    ref = np.clip(cam.to_raw(read_image(jpg_path)), 0.0, 1.0)
    assert _rms(est, ref) < 1e-3
    code = main(["render", "--model", str(NUS), str(FIXTURES / "pair" / "pair.tiff"), "-o",
                 str(tmp_path / "jpg"), "--quality", "100"])
    assert code == 0, capsys.readouterr().err
    # a JPEG file: compared with the reference written the same way (same rounding,
    # chroma subsampling and quality)
    got = read_image(tmp_path / "jpg" / "pair.jpg").astype(np.float64)
    ref = cam.render(read_image(FIXTURES / "pair" / "pair.tiff") / 65535.0) * 255.0
    write_image(tmp_path / "ref.jpg", np.clip(np.round(ref), 0, 255).astype(np.uint8),
                jpeg_quality=100)
    # measured 1.0 code: the baked render differs by 0.44 code RMS (3 at most)
    assert _rms(got, read_image(tmp_path / "ref.jpg")) < 1.5    # codes
    # export as a 3D-only LUT (the default .cube carries a shaper: tests/test_export_ocio.py)
    assert main(["export", str(NUS), "-o", str(tmp_path / "nus.cube"), "--size", "9",
                 "--no-shaper"]) == 0
    lines = (tmp_path / "nus.cube").read_text().splitlines()
    # 6 header lines and the comment on the model's fitted codes (5-252)
    assert len(lines) == 7 + 9 ** 3 and "codes 5-252" in lines[2]


@needs_nus
def test_render_over_the_whole_cube_and_in_any_order(nus):
    model, cam = nus
    x = np.random.default_rng(0).random((3000, 3))
    ours = model.render(x)
    assert np.abs(ours - cam.render(x)).max() < 1e-3     # measured 2.5e-4
    # the lazily evaluated table gives the same numbers whatever was rendered before
    order = np.random.default_rng(1).permutation(x.shape[0])
    np.testing.assert_array_equal(model.render(x[order]), ours[order])
    fresh = NUSPipelineModel(cam_both := read_nus_model(NUS, "jpg2raw", wb_code=14))
    np.testing.assert_array_equal(fresh.render(x[::-1]), ours[::-1])
    assert fresh.render_exact(x[:5]).shape == (5, 3) and cam_both.wb_code == 14


@pytest.mark.parametrize("cells, refine", [(6, 3), (4, 8)])
def test_lazy_render_table_is_exact_for_a_function_linear_in_the_shaper(cells, refine):
    """Trilinear interpolation in ``u = ρ^γ`` reproduces a function linear in ``u``
    exactly: any error is in the blocks, the packed indices or the lazy filling."""
    from selfcal.pipeline.nus_render import LazyRenderTable

    gamma = 0.45
    a = np.array([[0.3, -0.2, 0.1], [0.05, 0.6, -0.1], [0.2, 0.1, 0.4]])

    def linear_in_u(rho):
        return 0.01 + (rho ** gamma) @ a

    table = LazyRenderTable(linear_in_u, cells, refine, gamma, scale=1000.0,
                             shift=[1, 2, 3, 4])
    rng = np.random.default_rng(0)
    q = np.concatenate([rng.integers(0, 65536, (5000, 3)), [[0, 0, 0], [65535] * 3],
                        rng.integers(0, 40, (500, 3))]).astype(np.intp)
    want = 1000.0 * linear_in_u(q / 65535.0) + [1, 2, 3]
    first = table(q)
    np.testing.assert_allclose(first[:, :3], want, atol=2e-3)    # float32 of ~1000
    assert np.all(first[:, 3] == 4)
    # blocks only where pixels fell, each with at most its nodes (faces duplicated)
    assert 0 < table.n_blocks <= cells ** 3
    assert table.evaluated <= table.n_blocks * (refine + 1) ** 3
    evaluated = table.evaluated
    again = table(q[::-1].copy())
    np.testing.assert_allclose(again[::-1], first, atol=1e-4)
    assert table.evaluated == evaluated                 # nothing evaluated twice


def _write_small_nus(folder: Path) -> None:
    """An NUS-format model folder of our own (no data needed): a 3×3 transform per white
    balance, an RBF of 40 random cones plus an affine part, a gamma-2.2 tone table."""
    folder.mkdir()
    rng = np.random.default_rng(3)
    base = np.array([[1.6, -0.4, -0.2], [-0.2, 1.4, -0.2], [0.0, -0.4, 1.4]])
    lines = ["1"] + [" ".join(f"{v:.6f}" for v in r) for r in base] + ["14"]
    lines += [" ".join(f"{v:.6f}" for v in r) for r in base * [1.8, 1.0, 2.0]]
    lines += ["1.8 1.0 2.0"]
    centres = rng.uniform(-0.1, 1.2, (40, 3))
    coefs = np.vstack([rng.normal(0, 0.05, (40, 3)), [[0.01, 0.0, -0.01]], 0.9 * np.eye(3)])
    table = np.repeat((np.arange(256) / 255.0)[:, None] ** 2.2, 3, axis=1)

    def rows(a):
        return "\n".join(" ".join(f"{v:.6f}" for v in r) for r in a) + "\n"

    for d in ("raw2jpg", "jpg2raw"):
        (folder / f"{d}_transform.txt").write_text("\n".join(lines) + "\n")
        (folder / f"{d}_ctrlPoints.txt").write_text(f"40\n{rows(centres)}")
        (folder / f"{d}_coefs.txt").write_text(f"44\n{rows(coefs)}")
        (folder / f"{d}_respFcns.txt").write_text(f"16400.0 0.0 0.0 0.0\n{rows(table)}")


def test_render_of_a_small_model_folder_against_its_reference(tmp_path):
    """The whole render path (lazy table, clip, tone table) without the shared data."""
    _write_small_nus(tmp_path / "small")
    model = selfcal.load_model(tmp_path / "small")
    cam = read_nus_model(tmp_path / "small", wb_code=14)
    x = np.random.default_rng(4).random((20_000, 3)) ** 2          # dense near black
    ours = model.render(x)
    assert ours.dtype == np.float32 and ours.shape == x.shape
    err = np.abs(ours - cam.render(x)).max(axis=1)
    assert np.percentile(err, 99.9) < 1e-3 and err.max() < 3e-3    # measured 3.2e-4, 1.0e-3
    codes = np.round(x * 65535).astype(np.uint16)
    np.testing.assert_array_equal(model.render(codes), model.render(codes / 65535.0))
    out, mask = model.render(x[:10].reshape(2, 5, 3), return_mask=True)
    assert out.shape == (2, 5, 3) and mask is None
    with pytest.raises(selfcal.InputError, match="3 channels"):
        model.render(np.zeros((4, 2), np.uint16))
    with pytest.raises(selfcal.InputError, match="NaN"):
        model.render(np.full((1, 3), np.nan))


def test_cli_names_a_folder_that_is_not_a_model(tmp_path, capsys):
    frame = FIXTURES / "pair" / "pair.jpg"
    code = main(["to-raw", "--model", str(tmp_path), str(frame), "-o", str(tmp_path / "o")])
    assert code == EXIT_INPUT
    assert str(tmp_path) in capsys.readouterr().err
