"""``selfcal show``: what it prints agrees with the model's own values, the plot is a PNG of
the requested file, and a damaged model file is a clear error."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

import selfcal
from selfcal.report.describe import describe, format_description
from selfcal_cli.common import EXIT_INPUT, EXIT_OUTPUT
from selfcal_cli.main import main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture(scope="module")
def response_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("show_response") / "model.json"
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    assert main(["calibrate", *map(str, frames), "-o", str(out)]) == 0
    return out


def _table(text: str, title_start: str) -> list[list[str]]:
    """Rows of the table whose title line starts with ``title_start`` (header dropped)."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(title_start))
    rows = []
    for ln in lines[start + 2:]:
        if not ln.strip():
            break
        rows.append(ln.split())
    return rows


def test_show_response_numbers_are_the_models(response_file, capsys):
    code, out, err = run(["show", response_file], capsys)
    assert code == 0, err
    model = selfcal.load_model(response_file)
    # exposures: one line per frame, the value in seconds in brackets after "estimated"
    est = [float(m) for m in re.findall(r"estimated \S+ s \(([0-9.eE+-]+)\)", out)]
    assert len(est) == len(model.sources) == 6
    np.testing.assert_allclose(est, model.exposures, rtol=1e-5)
    given = [float(m) for m in re.findall(r"given \S+ s \(([0-9.eE+-]+)\)", out)]
    np.testing.assert_allclose(given, model.exposure_times, rtol=1e-5)
    assert re.search(r"^exposure times from\s+exif; used measured from the pixels", out, re.M)
    # the verdict level is the model's
    level = re.search(r"^verdict: (\w+)", out, re.M).group(1)
    assert level == model.diagnostics["verdict"]
    # f⁻¹ at code 128 per channel, four decimals
    rows = {int(r[0]): [float(v) for v in r[1:]] for r in _table(out, "f⁻¹")}
    assert set(rows) >= {0, 128, 255}
    np.testing.assert_allclose(rows[128], model.inverse_response([128])[0], atol=6e-5)
    np.testing.assert_allclose(rows[255], [1, 1, 1], atol=1e-9)
    # δ of Eq. 12 per channel
    delta = re.search(r"δ \(Eq. 12\) R G B\s+(\S+) (\S+) (\S+)", out).groups()
    np.testing.assert_allclose([float(v) for v in delta], model.diagnostics["delta_eq12"],
                               rtol=1e-3)
    assert "Traceback" not in out + err


def test_show_pipeline_numbers_are_the_models(pair_model_file, capsys):
    code, out, err = run(["show", pair_model_file], capsys)
    assert code == 0, err
    model = selfcal.load_model(pair_model_file)
    assert re.search(r"^kind\s+pipeline", out, re.M)
    assert re.search(rf"^backward\s+{model.backward}\b", out, re.M)
    matrix = np.array([[float(v) for v in r[1:]] for r in _table(out, "colour matrix")])
    np.testing.assert_allclose(matrix, model.matrix, atol=6e-5)
    tone = _table(out, "tone curves f ")
    half = next(r for r in tone if float(r[0]) == 0.5)
    lo, hi = model.tone_curves.domain[:, 0], model.tone_curves.domain[:, 1]
    x = lo + 0.5 * (hi - lo)
    expect = [model.tone_curves.channel(np.array(x[k]), k) for k in range(3)]
    np.testing.assert_allclose([float(v) for v in half[4:]], expect, atol=6e-5)
    kept = model.training_colours.raw.shape[0]
    assert re.search(rf"^trust\s+{kept} training colours kept", out, re.M)
    assert "verdict: none recorded" in out


def test_describe_is_plain_values(response_file):
    desc = describe(selfcal.load_model(response_file))
    json.dumps(desc)          # JSON-able: no numpy values, nothing printed
    assert desc["kind"] == "response" and desc["verdict"] in ("ok", "doubtful", "unusable")
    assert format_description(desc).endswith("\n")


@pytest.mark.parametrize("which", ["response", "pipeline"])
def test_show_plot_writes_the_requested_png(which, response_file, pair_model_file, tmp_path,
                                            capsys):
    from PIL import Image

    model = response_file if which == "response" else pair_model_file
    png = tmp_path / "curves.png"
    code, out, err = run(["show", model, "--plot", png], capsys)
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["curves.png"]  # nothing else left
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size[0] > 400 and im.size[1] > 300
        im.load()
    # an existing plot is refused before any work, kept as it was; --force replaces it
    before = png.read_bytes()
    code, out, err = run(["show", model, "--plot", png], capsys)
    assert code == EXIT_OUTPUT and "curves.png" in err and out == ""
    assert png.read_bytes() == before
    code, out, err = run(["show", model, "--plot", png, "--force"], capsys)
    assert code == 0, err


def test_show_damaged_model_is_a_clear_error(response_file, tmp_path, capsys):
    doc = json.loads(response_file.read_text())
    doc["inverse_response"][1][100] = 2.0          # not increasing any more
    bad = tmp_path / "damaged.json"
    bad.write_text(json.dumps(doc))
    code, out, err = run(["show", bad], capsys)
    assert code == EXIT_INPUT
    assert "damaged.json" in err and "Traceback" not in out + err
    assert out == ""
    cut = tmp_path / "cut.json"
    cut.write_text(response_file.read_text()[:200])
    code, out, err = run(["show", cut, "--plot", tmp_path / "p.png"], capsys)
    assert code == EXIT_INPUT and "cut.json" in err and "Traceback" not in out + err
    assert not (tmp_path / "p.png").exists()
    code, out, err = run(["show", tmp_path / "absent.json"], capsys)
    assert code == EXIT_INPUT and "absent.json" in err


def test_show_prints_and_plots_the_vignetting(response_file, tmp_path, capsys):
    from PIL import Image

    from selfcal.lens import Vignetting, binned_points

    model = selfcal.load_model(response_file)
    cov = np.diag([1e-6, 1e-6] + [4e-4, 1e-4, 1e-5] * 3)
    r = np.linspace(0.05, 1.0, 40)
    k = np.array([[-0.45, 0.05, -0.02], [-0.40, 0.02, -0.01], [-0.35, 0.0, 0.0]])
    points = binned_points(r, np.log(1 + k[:, 0] * r[:, None] ** 2), bins=10)
    model.vignetting = Vignetting(k, [0.03, -0.02], source="flat", description="test card",
                                  covariance=cov, log_sigma_floor=0.01, aspect=1.5,
                                  diagnostics={"points": points})
    path = tmp_path / "with_vignetting.json"
    model.save(path)
    png = tmp_path / "v.png"
    code, out, err = run(["show", path, "--plot", png], capsys)
    assert code == 0, err
    loaded = selfcal.load_model(path).vignetting
    assert re.search(r"^  source\s+flat \(flat field\)$", out, re.M)
    assert re.search(r"^  description\s+test card$", out, re.M)
    found = re.search(r"^  corner R G B\s+(\S+)±(\S+) (\S+)±(\S+) (\S+)±(\S+) stops", out, re.M)
    stops = [float(found.group(i)) for i in (1, 3, 5)]
    np.testing.assert_allclose(stops, loaded.corner_stops(), atol=6e-4)
    band = [float(found.group(i)) for i in (2, 4, 6)]
    expect = 1.645 * loaded.corner_profile(2)["log_sigma"][-1] / np.log(2)
    np.testing.assert_allclose(band, expect, atol=6e-4)
    assert all(b > 0 for b in band)
    rows = _table(out, "vignetting V")
    assert [float(v) for v in rows[0][1:4]] == [1.0, 1.0, 1.0]
    with Image.open(png) as im:
        assert im.format == "PNG" and im.size[0] > 900
    json.dumps(describe(selfcal.load_model(path)))     # plain values
    # a model without one says nothing about vignetting
    code, out, err = run(["show", response_file], capsys)
    assert "vignetting" not in out
