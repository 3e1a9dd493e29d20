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
    assert "verdict" in text and "times from EXIF" in text
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


def test_calibrate_pair_takes_pipeline_path(pair_model_file):
    doc = json.loads(pair_model_file.read_text())
    assert doc["format"] == "selfcal-model" and doc["kind"] == "pipeline"


def test_to_raw_and_render_against_the_pair(pair_model_file, tmp_path, capsys):
    import numpy as np

    from selfcal.io import read_image

    code, text = run(["to-raw", "--model", pair_model_file,
                      FIXTURES / "pair" / "pair.jpg", "-o", tmp_path / "raw"], capsys)
    assert code == 0, text
    est = read_image(tmp_path / "raw" / "pair.tiff").astype(float) / 65535
    truth = read_image(FIXTURES / "pair" / "pair.tiff").astype(float) / 65535
    unclipped = (truth < 0.95).all(axis=2)
    assert np.sqrt(np.mean((est - truth)[unclipped] ** 2)) < 0.03

    code, text = run(["render", "--model", pair_model_file,
                      FIXTURES / "pair" / "pair.tiff", "-o", tmp_path / "jpg"], capsys)
    assert code == 0, text
    rendered = read_image(tmp_path / "jpg" / "pair.jpg").astype(float)
    camera = read_image(FIXTURES / "pair" / "pair.jpg").astype(float)
    assert np.sqrt(np.mean((rendered - camera) ** 2)) < 8.0

    # a second run keeps what is there
    code, text = run(["render", "--model", pair_model_file,
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
    from selfcal import sim

    scene = sim.make_scene(128, 176, dynamic_range_stops=10, saturation=0.3, seed=6)
    times = [1 / 60, 1 / 15, 1 / 4]
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=6), times, jitter=0.0,
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


# ------------------------------------------------------------------ clear answers, nothing lost

def _bracket(folder, times, *, seed=1, size=(48, 64)):
    """A simulated JPEG bracket with EXIF times (the simulator's default camera)."""
    from selfcal import sim

    scene = sim.make_scene(*size, dynamic_range_stops=8, saturation=0.3, seed=seed)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=seed), list(times),
                                 jitter=0.0, seed=seed)
    return stack, stack.write(folder, prefix="f")


def test_write_failure_names_the_output_not_the_temporary_file(tmp_path):
    """Point 1: a write that fails says which output, and leaves nothing behind."""
    import errno

    from selfcal.io import OutputWriteError, StagedOutputs, atomic_output

    target = tmp_path / "r.hdr"
    with pytest.raises(OutputWriteError) as info:
        with atomic_output(target) as tmp:
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp))
    assert str(info.value) == f"{target}: cannot be written (no space left on device)"
    assert list(tmp_path.iterdir()) == []

    # a writer's own error about its temporary file is renamed to the output
    from selfcal.hdr.io import OutputWriteError as RadianceWriteError

    def failing_writer(tmp):
        # the file concerned is a field of the error (its message is "{path}: {reason}")
        raise RadianceWriteError("OpenCV could not write it (no .hdr encoder?)", tmp)

    staged = StagedOutputs()
    staged.write(tmp_path / "a.json", lambda tmp: Path(tmp).write_text("{}"))
    with pytest.raises(RadianceWriteError) as info:
        with staged:
            staged.write(tmp_path / "sub" / "r.hdr", failing_writer)
    assert str(info.value) == f"{tmp_path / 'sub' / 'r.hdr'}: OpenCV could not write it " \
                              "(no .hdr encoder?)"
    assert list(tmp_path.iterdir()) == []        # neither a.json nor sub/ nor a temp file


def test_outputs_appear_together_or_not_at_all(tmp_path):
    """Point 2: StagedOutputs renames every output at the end; nothing before."""
    from selfcal.io import StagedOutputs

    (tmp_path / "old.txt").write_text("old")
    with StagedOutputs(force=True) as staged:
        staged.write(tmp_path / "new" / "a.txt", lambda tmp: Path(tmp).write_text("a"))
        staged.write(tmp_path / "old.txt", lambda tmp: Path(tmp).write_text("b"))
        assert (tmp_path / "old.txt").read_text() == "old"
        assert not (tmp_path / "new" / "a.txt").exists()
    assert (tmp_path / "new" / "a.txt").read_text() == "a"
    assert (tmp_path / "old.txt").read_text() == "b"
    assert staged.written == [tmp_path / "new" / "a.txt", tmp_path / "old.txt"]
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "new", "old.txt"]


def test_plot_that_exists_is_refused_before_calibrating(capsys, tmp_path):
    """Point 2: calibrate -o new.json --plot existing.png wrote new.json, then failed."""
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))[:3]
    (tmp_path / "old.png").write_bytes(b"old")
    code, text = run(["calibrate", *frames, "-o", tmp_path / "new.json",
                      "--plot", tmp_path / "old.png"], capsys)
    assert code == EXIT_OUTPUT and "old.png: exists already" in text
    assert "paths taken" not in text                  # refused before any work
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.png"]


def test_frame_of_another_size(capsys, tmp_path):
    """Point 3: named one by one it is refused (named, both sizes); in a folder it is left
    out with a warning naming it -- never dropped without a word."""
    import cv2

    _, frames = _bracket(tmp_path / "stack", (1 / 60, 1 / 15, 1 / 4))
    big = tmp_path / "stack" / "zz_big.jpg"
    cv2.imwrite(str(big), cv2.resize(cv2.imread(str(frames[1])), (80, 60)))
    code, text = run(["calibrate", *frames, big, "-o", tmp_path / "m.json"], capsys)
    assert code == EXIT_INPUT
    assert "zz_big.jpg: frame size 80x60 differs from the other frames' 64x48" in text
    assert not (tmp_path / "m.json").exists()
    code, text = run(["calibrate", tmp_path / "stack", "-o", tmp_path / "m.json"], capsys)
    assert code == 0, text
    assert "zz_big.jpg: left out (80x60, the calibrated frames are 64x48" in text
    assert "warning:" in text


def test_empty_folder_is_named(capsys, tmp_path):
    """Point 5: 'no input images' did not say where it looked."""
    (tmp_path / "shoot").mkdir()
    code, text = run(["calibrate", tmp_path / "shoot", "-o", tmp_path / "m.json"], capsys)
    assert code == EXIT_INPUT
    assert f"{tmp_path / 'shoot'}: the folder holds no image or raw files" in text


@pytest.mark.parametrize("option, value, expected", [
    ("--components", "0", "from 1 to 25"), ("--components", "50", "from 1 to 25"),
    ("--saturation-threshold", "-1", "from 0 to 1"), ("--times", "-1/60", "must be positive"),
])
def test_options_are_checked_by_the_parser(capsys, tmp_path, option, value, expected):
    """Point 6: --components 0 was a traceback, 50 silently 25, β = -1 'cannot calibrate',
    and --times -1/60 an unknown option."""
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))[:3]
    values = ["1/60", value, "1/4"] if option == "--times" else [value]
    with pytest.raises(SystemExit) as info:
        main(["calibrate", *map(str, frames), "-o", str(tmp_path / "m.json"), option, *values])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err and repr(value) in err and expected in err


def test_verdict_doubtful_is_said_with_its_reasons(capsys, tmp_path):
    """A 2-frame, one-stop stack: the library doubts it; the CLI says why, exit 0."""
    import selfcal
    from selfcal_cli.common import verdict_of

    _, frames = _bracket(tmp_path / "two", (1 / 60, 1 / 30))
    out = tmp_path / "m.json"
    code, text = run(["calibrate", *frames, "-o", out], capsys)
    assert code == 0, text
    level, reasons = verdict_of(selfcal.load_model(out).diagnostics)
    assert level == "doubtful" and reasons
    assert "verdict: doubtful" in text
    for r in reasons:
        assert f"warning: {r}" in text


def test_verdict_unusable_writes_nothing_unless_forced(capsys, tmp_path):
    """Exposures 1.1x apart cannot determine a curve: exit 4 and nothing written; with
    --force it is written, with a warning."""
    _, frames = _bracket(tmp_path / "close", (1 / 60, 1.1 / 60))
    out, plot = tmp_path / "m.json", tmp_path / "m.png"
    code, text = run(["calibrate", *frames, "-o", out, "--plot", plot], capsys)
    assert code == EXIT_CALIBRATION, text
    assert "verdict: unusable" in text and "1.10×" in text
    assert "selfcal: cannot calibrate: the calibration is unusable" in text
    assert not out.exists() and not plot.exists()
    code, text = run(["calibrate", *frames, "-o", out, "--plot", plot, "--force"], capsys)
    assert code == 0, text
    assert out.exists() and plot.exists()
    assert "warning: the calibration is unusable" in text and "--force" in text


def _linear_bracket(folder, times, *, with_times: bool):
    """16-bit linear TIFFs of a simulated bracket (the raws, as a raw converter writes
    them), with or without exposure tags; and the stack (its true exposures)."""
    from selfcal import sim

    scene = sim.make_scene(48, 64, dynamic_range_stops=8, saturation=0.3, seed=3)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=3), list(times),
                                 jitter=0.0, seed=3)
    return stack.write_raws(folder, with_times=with_times), stack


def test_linear_tiff_bracket_is_not_taken_for_rendered_frames(capsys, tmp_path):
    """Point 9: 16-bit linear TIFFs (no JPEGs) were calibrated as rendered frames."""
    import numpy as np

    import selfcal
    from selfcal.exposure.linear_evidence import linear_evidence
    from selfcal.hdr.io import read_radiance

    times = (1 / 60, 1 / 15, 1 / 4)
    paths, stack = _linear_bracket(tmp_path / "raws", times, with_times=False)
    # what the response path made of them (the old behaviour): a bent curve, ratios wrong
    model = selfcal.calibrate_response(paths)
    inv = model.inverse_response()
    assert abs(inv[len(inv) // 8].mean() - 0.125) > 0.03
    ratios = model.exposures / model.exposures[0]
    assert abs(ratios[2] / 15 - 1) > 0.5
    # now: refused, saying what they are and what to do
    code, text = run(["calibrate", tmp_path / "raws", "-o", tmp_path / "m.json"], capsys)
    assert code == EXIT_CALIBRATION
    assert "raw_0.tif, raw_1.tif, raw_2.tif are linear data" in text
    assert "selfcal merge" in text
    assert not (tmp_path / "m.json").exists()
    # merge recognises them and merges them as they are
    code, text = run(["merge", *paths, "-o", tmp_path / "auto.exr"], capsys)
    assert code == 0, text
    assert "are linear data" in text and "no response fitted" in text
    assert "measured from the pixels (a relative scale)" in text
    code, text = run(["merge", *paths, "--linear", "--times", *map(str, times),
                      "-o", tmp_path / "r.exr"], capsys)
    assert code == 0, text
    radiance = read_radiance(tmp_path / "r.exr")
    truth = stack.radiance
    ok = (truth > 1e-3).all(axis=2)
    scale = np.median(radiance[ok] / truth[ok])
    assert np.median(np.abs(radiance[ok] / (scale * truth[ok]) - 1)) < 0.05
    # with times the test is decisive; rendered 16-bit TIFFs are not taken for linear
    timed, _ = _linear_bracket(tmp_path / "timed", times, with_times=True)
    assert "follow the exposure times" in linear_evidence(timed, list(times))
    from selfcal import sim

    scene = sim.make_scene(48, 64, dynamic_range_stops=8, saturation=0.3, seed=3)
    rendered = sim.simulate_stack(scene, sim.default_pipeline(seed=3), list(times),
                                    jitter=0.0, seed=3, output=sim.FrameOutput(bit_depth=16),
                                    jpeg_quality=None)
    files = rendered.write(tmp_path / "rendered16", fmt="tif")
    assert linear_evidence(files, list(times)) is None
    assert linear_evidence(files, [None] * 3) is None


def test_contradicted_exif_time_refined_by_default_or_held_on_request(capsys, tmp_path):
    import dataclasses

    import numpy as np

    from selfcal import sim

    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=3)
    scene = sim.make_scene(160, 240, dynamic_range_stops=12.0, seed=3)
    stack = sim.simulate_stack(scene, pipe, sim.DEMO_EXPOSURE_TIMES, jitter=0.02,
                                 jpeg_quality=92, seed=3)
    exif_times = np.array(stack.exposure_times, dtype=float)
    exif_times[2] *= 1.6                       # EXIF says 1.6x what the shutter gave
    paths = dataclasses.replace(stack, exposure_times=exif_times).write(tmp_path / "s")
    code, out = run(["calibrate", *paths, "-o", tmp_path / "auto.json"], capsys)
    assert code == 0
    assert "frame_02.jpg" in out and "--hold-times keeps the times" in out, out
    auto = json.loads((tmp_path / "auto.json").read_text())
    assert auto["diagnostics"]["verdict"] == "ok"
    assert auto["exposure_record"]["refined"] is True
    assert auto["exposure_record"]["frames"][2]["contradicted"] is not None
    code, out = run(["calibrate", *paths, "-o", tmp_path / "held.json",
                     "--hold-times"], capsys)
    assert code == 0
    held = json.loads((tmp_path / "held.json").read_text())
    assert held["exposure_record"]["rule"] == "held" and not held["exposure_record"]["refined"]
    assert held["diagnostics"]["verdict"] == "doubtful"
    assert [f["used"] for f in held["exposure_record"]["frames"]] == pytest.approx(
        list(exif_times))
