"""The command line: help, exit codes, messages naming files, no overwriting."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from selfcal_cli.common import EXIT_CALIBRATION, EXIT_INPUT, EXIT_OUTPUT
from selfcal_cli.main import main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def run(argv, capsys):
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for command in ("demo", "calibrate"):
        assert command in out
    assert "exit codes" in out


def test_calibrate_help_lists_options(capsys):
    with pytest.raises(SystemExit) as info:
        main(["calibrate", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in ("--times", "--unknown-exposures", "--refine-exposures",
                   "--saturation-threshold", "--basis", "--plot", "--force", "--align"):
        assert option in out


def test_console_script_is_installed():
    result = subprocess.run([sys.executable, "-m", "selfcal_cli", "--version"],
                            capture_output=True, text=True)
    assert result.returncode == 0
    assert result.stdout.startswith("selfcal ")


def test_bad_time_is_a_usage_error(capsys, tmp_path):
    with pytest.raises(SystemExit) as info:
        main(["calibrate", "a.jpg", "b.jpg", "-o", str(tmp_path / "m.json"),
              "--times", "1/0", "1"])
    assert info.value.code == 2
    assert "1/0" in capsys.readouterr().err


def test_calibrate_fixture_stack(capsys, tmp_path):
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    assert len(frames) >= 3
    out = tmp_path / "model.json"
    plot = tmp_path / "response.png"
    code, text = run(["calibrate", *frames, "-o", out, "--plot", plot], capsys)
    assert code == 0, text
    doc = json.loads(out.read_text())
    assert doc["format"] == "selfcal-model" and doc["kind"] == "response"
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "verdict" in text and "exif" in text
    # the truth of the fixtures: the recovered curve is close to it
    truth = json.loads((FIXTURES / "truth.json").read_text())
    import numpy as np

    import selfcal

    model = selfcal.load_model(out)
    inv_true = np.stack([truth["inverse_response"][c] for c in "RGB"], axis=1)
    est = model.inverse_response()
    assert np.sqrt(np.mean((est[1:255] - inv_true[1:255]) ** 2)) < 0.03

    # a second run refuses to overwrite, and leaves the file as it was
    before = out.read_bytes()
    code, text = run(["calibrate", *frames, "-o", out], capsys)
    assert code == EXIT_OUTPUT
    assert "exists" in text and "--force" in text
    assert out.read_bytes() == before
    code, text = run(["calibrate", *frames, "-o", out, "--force"], capsys)
    assert code == 0


def test_calibrate_refuses_to_write_over_input(capsys):
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    before = frames[0].read_bytes()
    code, text = run(["calibrate", *frames, "-o", frames[0], "--force"], capsys)
    assert code == EXIT_OUTPUT
    assert frames[0].read_bytes() == before


def test_truncated_file_named_in_error(capsys, tmp_path):
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    broken = tmp_path / "broken.jpg"
    broken.write_bytes(frames[1].read_bytes()[:500])
    code, text = run(["calibrate", frames[0], broken, frames[2], "-o", tmp_path / "m.json"],
                     capsys)
    assert code == EXIT_INPUT
    assert "broken.jpg" in text and "truncated" in text
    assert "Traceback" not in text
    assert not (tmp_path / "m.json").exists()


def test_one_frame_cannot_calibrate(capsys, tmp_path):
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    code, text = run(["calibrate", frames[0], "-o", tmp_path / "m.json"], capsys)
    assert code == EXIT_CALIBRATION
    assert "frame_00.jpg" in text and "need frames at ≥ 2 exposures" in text


def test_demo_reports_error_against_truth(capsys, tmp_path):
    out = tmp_path / "demo"
    code, text = run(["demo", "-o", out], capsys)
    assert code == 0, text
    assert (out / "model.json").exists() and (out / "response.png").exists()
    assert len(list(out.glob("*.jpg"))) == 6
    line = next(ln for ln in text.splitlines() if "RMSE of f⁻¹" in ln)
    errors = [float(tok) for tok in line.replace(",", " ").split() if tok[:1] == "0"]
    assert len(errors) == 3 and max(errors) < 0.03
    # running again without --force keeps what is there
    code, text = run(["demo", "-o", out], capsys)
    assert code == EXIT_OUTPUT


@pytest.fixture(scope="module")
def pipeline_model_file(tmp_path_factory):
    """A RAW-path model from the fixture RAW+JPEG pair (16-bit linear TIFF + JPEG)."""
    out = tmp_path_factory.mktemp("pipeline") / "camera.json"
    code = main(["calibrate", str(FIXTURES / "pair" / "pair.tiff"),
                 str(FIXTURES / "pair" / "pair.jpg"), "-o", str(out)])
    assert code == 0
    return out


def test_calibrate_pair_takes_pipeline_path(pipeline_model_file):
    doc = json.loads(pipeline_model_file.read_text())
    assert doc["format"] == "selfcal-model" and doc["kind"] == "pipeline"


def test_to_raw_and_render_against_the_pair(pipeline_model_file, tmp_path, capsys):
    import numpy as np

    from selfcal.io import read_image

    code, text = run(["to-raw", "--model", pipeline_model_file,
                      FIXTURES / "pair" / "pair.jpg", "-o", tmp_path / "raw"], capsys)
    assert code == 0, text
    est = read_image(tmp_path / "raw" / "pair.tiff").astype(float) / 65535
    truth = read_image(FIXTURES / "pair" / "pair.tiff").astype(float) / 65535
    unclipped = (truth < 0.95).all(axis=2)
    assert np.sqrt(np.mean((est - truth)[unclipped] ** 2)) < 0.03

    code, text = run(["render", "--model", pipeline_model_file,
                      FIXTURES / "pair" / "pair.tiff", "-o", tmp_path / "jpg"], capsys)
    assert code == 0, text
    rendered = read_image(tmp_path / "jpg" / "pair.jpg").astype(float)
    camera = read_image(FIXTURES / "pair" / "pair.jpg").astype(float)
    assert np.sqrt(np.mean((rendered - camera) ** 2)) < 8.0

    # a second run keeps what is there
    code, text = run(["render", "--model", pipeline_model_file,
                      FIXTURES / "pair" / "pair.tiff", "-o", tmp_path / "jpg"], capsys)
    assert code == EXIT_OUTPUT and "--force" in text


def test_to_raw_needs_a_pipeline_model(tmp_path, capsys):
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    model = tmp_path / "response.json"
    assert main(["calibrate", *map(str, frames), "-o", str(model)]) == 0
    capsys.readouterr()
    code, text = run(["to-raw", "--model", model, frames[0], "-o", tmp_path / "out"], capsys)
    assert code == EXIT_INPUT
    assert "response.json" in text and "pipeline" in text


def test_calibrate_align_handheld_files(capsys, tmp_path):
    import cv2

    import selfcal
    from selfcal import synth

    scene = synth.make_scene(128, 176, dynamic_range_stops=10, saturation=0.3, seed=6)
    times = [1 / 60, 1 / 15, 1 / 4]
    stack = synth.simulate_stack(scene, synth.default_pipeline(seed=6), times, jitter=0.0,
                                 jpeg_quality=None, seed=6)
    paths = []
    for k, (im, (dx, dy)) in enumerate(zip(stack.images, [(4, -3), (0, 0), (-5, 2)])):
        path = tmp_path / f"f{k}.png"
        cv2.imwrite(str(path), im[16 + dy:112 + dy, 16 + dx:160 + dx, ::-1])
        paths.append(str(path))
    out = tmp_path / "m.json"
    code = main(["calibrate", *paths, "-o", str(out), "--align", "mtb",
                 "--times", "1/60", "1/15", "1/4"])
    assert code == 0
    text = capsys.readouterr()
    assert "contradict" not in text.out + text.err
    model = selfcal.load_model(out)
    moves = [t[0][2] for t in model.diagnostics["alignment"]["transforms"]]
    assert moves == pytest.approx([-4, 0, 5])
