"""Issue 37, part 3: bad arguments and Ctrl-C, for every command, with real processes.

Every argument that a library would only check later (Dask's memory limit, the
scheduler's port, the luminance scales, the demo's seed) is a usage error (exit 2) that
names it, before any work or cluster.  Ctrl-C -- a real SIGINT sent to a real ``selfcal``
process (``python -m selfcal_cli``, or the console script as pip writes it) -- ends every
command with exit 130, the one line ``selfcal: interrupted``, no traceback, and nothing
in the output folder (no output, no temporary file), whether it comes while the modules
load, while the frames are read and calibrated, or while the merge runs.

The moments: after a delay (0.3, 1 and 3 s), while numpy loads (seen in the process's
``/proc/PID/maps``), and after the command's first line (``verdict: ok``: the merge is
under way).  The signal is sent after a delay; nothing here asserts a duration.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import selfcal
import selfcal_cli
from selfcal_cli.main import main

#: The console script as pip generates it for ``selfcal = selfcal_cli.main:main``.
CONSOLE_SCRIPT = """\
import re
import sys
from selfcal_cli.main import main
if __name__ == '__main__':
    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])
    sys.exit(main())
"""

TIMES = ["1/250", "1/60", "1/15", "1/4"]


def _env() -> dict:
    """This interpreter's view of selfcal for the child processes (PYTHONPATH first)."""
    paths = [str(Path(m.__file__).parent.parent) for m in (selfcal, selfcal_cli)]
    old = os.environ.get("PYTHONPATH", "")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(dict.fromkeys(
        paths + ([old] if old else [])))}


@pytest.fixture(scope="module")
def bracket(tmp_path_factory):
    """Four frames (2400 x 3200 JPEGs) of a simulated bracket: a merge of several seconds.

    Simulated small and enlarged (the simulator would take long at this size); the
    times are given on the command line (--times)."""
    import cv2

    from selfcal import sim

    folder = tmp_path_factory.mktemp("bracket")
    scene = sim.make_scene(240, 320, dynamic_range_stops=10, saturation=0.3, seed=1)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=1),
                               [1 / 250, 1 / 60, 1 / 15, 1 / 4], jitter=0.0, seed=1)
    paths = []
    for k, img in enumerate(stack.images):
        big = cv2.resize(np.ascontiguousarray(img[..., ::-1]), (3200, 2400),
                         interpolation=cv2.INTER_CUBIC)
        path = folder / f"f_{k}.jpg"
        assert cv2.imwrite(str(path), big, [cv2.IMWRITE_JPEG_QUALITY, 92])
        paths.append(path)
    return paths


def _start(args, tmp_path, *, script: bool = False) -> subprocess.Popen:
    if script:
        wrapper = tmp_path / "bin" / "selfcal"
        wrapper.parent.mkdir(exist_ok=True)
        wrapper.write_text(CONSOLE_SCRIPT)
        command = [sys.executable, str(wrapper)]
    else:
        command = [sys.executable, "-m", "selfcal_cli"]
    return subprocess.Popen(command + [str(a) for a in args], env=_env(), cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _when_numpy_loads(proc) -> None:
    """Wait until the process maps numpy's extension modules: it is importing them."""
    maps = Path(f"/proc/{proc.pid}/maps")
    if not maps.exists():                   # not Linux: a moment into the imports
        time.sleep(0.3)
        return
    while "numpy" not in maps.read_text():
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.001)


def _after_line(proc, start: str) -> list:
    """Read stderr up to the first line starting with ``start`` (the lines read)."""
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if line.startswith(start):
            return lines
    raise AssertionError(f"no line {start!r}: {''.join(lines)}")


def _interrupt(proc, when) -> str:
    """Send SIGINT at ``when`` (seconds, "numpy" or a line's start); stderr."""
    before = []
    if when == "numpy":
        _when_numpy_loads(proc)
    elif isinstance(when, str):
        before = _after_line(proc, when)
    else:
        time.sleep(when)
    assert proc.poll() is None, ("the command ended before the signal: give it a larger "
                                 "job", proc.communicate())
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    return "".join(before) + err


def _assert_interrupted(proc, err: str, out: Path) -> None:
    assert proc.returncode == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert err.rstrip().endswith("selfcal: interrupted"), err
    assert err.count("selfcal: interrupted") == 1, err
    left = sorted(p.name for p in out.rglob("*")) if out.exists() else []
    assert left == [], f"left behind: {left}"


# ------------------------------------------------------------------------ Ctrl-C

@pytest.mark.slow
@pytest.mark.parametrize("when, script", [
    ("numpy", True), ("numpy", False), (0.3, True), (1.0, False), (3.0, True),
    ("verdict:", False),
])
def test_merge_interrupted_exits_130_and_writes_nothing(bracket, tmp_path, when, script):
    out = tmp_path / "out"
    out.mkdir()
    proc = _start(["merge", *bracket, "--times", *TIMES, "-o", out / "hdr.exr",
                   "--preview", out / "preview.jpg", "--sigma"], tmp_path, script=script)
    _assert_interrupted(proc, _interrupt(proc, when), out)


@pytest.mark.slow
def test_calibrate_interrupted_exits_130_and_writes_nothing(bracket, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    proc = _start(["calibrate", *bracket, "--times", *TIMES, "-o", out / "model.json",
                   "--plot", out / "curves.png"], tmp_path, script=True)
    _assert_interrupted(proc, _interrupt(proc, 1.0), out)


@pytest.mark.slow
def test_demo_interrupted_exits_130_and_removes_its_frames(tmp_path):
    """Interrupted while it calibrates, the demo removes the frames it simulated and the
    folder it made."""
    out = tmp_path / "demo"
    proc = _start(["demo", "-o", out], tmp_path)
    _assert_interrupted(proc, _interrupt(proc, "simulated a"), out)
    assert not out.exists()


def test_a_command_started_with_sigint_ignored_keeps_it_ignored(tmp_path):
    """A shell script's background job (``selfcal ... &``) starts with SIGINT ignored:
    selfcal leaves it so (as Python does), and the command ends as it would."""
    proc = subprocess.Popen([sys.executable, "-m", "selfcal_cli", "--version"], env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    _when_numpy_loads(proc)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert out.startswith("selfcal ") and "interrupted" not in err


def test_main_in_process_keeps_the_callers_handler(tmp_path, capsys, monkeypatch):
    """``main()`` from Python (not the program): a KeyboardInterrupt in the work is exit
    130 with one line, and the SIGINT handler is the caller's again afterwards."""
    import selfcal_cli.calibrate_commands as cc

    def interrupted(args):
        raise KeyboardInterrupt

    before = signal.getsignal(signal.SIGINT)
    monkeypatch.setattr(cc, "cmd_demo", interrupted)
    assert main(["demo", "-o", str(tmp_path / "d")]) == 130
    assert capsys.readouterr().err == "selfcal: interrupted\n"
    assert signal.getsignal(signal.SIGINT) is before


# ------------------------------------------------------------------------ bad arguments

def test_batch_memory_limit_lots_is_a_usage_error(bracket, tmp_path):
    """Tried as a new user would: a Dask traceback (exit 1) before; now exit 2, before any
    cluster, naming the argument, nothing written."""
    out = tmp_path / "out"
    proc = _start(["batch", bracket[0].parent, "-o", out, "--memory-limit", "lots"],
                  tmp_path)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert "argument --memory-limit" in err and "'lots'" in err, err
    assert "Traceback" not in err
    assert not out.exists()


@pytest.mark.parametrize("argv, option, expected", [
    (["--memory-limit", "4"], "--memory-limit", "too little"),
    (["--memory-limit", "nan"], "--memory-limit", "not a memory limit"),
    (["--memory-limit", "1.5 foos"], "--memory-limit", "not a memory limit"),
    (["--scheduler", "tcp://127.0.0.1:99999"], "--scheduler", "port from 1 to 65535"),
    (["--workers", "0"], "--workers", "from 1 to 1024"),
    (["--max-gap", "-3"], "--max-gap", "positive"),
])
def test_batch_arguments_are_checked_before_any_cluster(tmp_path, capsys, argv, option,
                                                        expected):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main(["batch", str(tmp_path), "-o", str(out), *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err and expected in err, err
    assert not out.exists()


@pytest.mark.parametrize("text, expected", [
    ("auto", "auto"), ("0", 0), ("0.25", 0.25), ("1", 1.0), ("4GB", 4_000_000_000),
    ("4 GiB", 4 * 2 ** 30), ("512MiB", 512 * 2 ** 20), ("1e9", 10 ** 9), ("64mi", 2 ** 26),
])
def test_memory_limits_dask_takes_are_taken_as_dask_reads_them(text, expected):
    from selfcal_cli.batch_commands import _memory_limit

    assert _memory_limit(text) == expected
    dask_utils = pytest.importorskip("dask.utils")
    if isinstance(expected, int) and expected > 1:
        assert dask_utils.parse_bytes(text) == expected


def test_luminance_scale_twice_for_one_camera_is_a_usage_error(tmp_path, capsys):
    import dataclasses

    from selfcal.lens import LuminanceScale

    frames = sorted((Path(__file__).resolve().parents[1] / "fixtures" / "stack").glob("*.jpg"))
    model = dataclasses.replace(selfcal.calibrate_response(frames), luminance=LuminanceScale(
        scale=3.5, log_sigma=0.03, source="reference", description="test: a spot meter"))
    a, b = model.save(tmp_path / "a.json"), model.save(tmp_path / "b.json")
    with pytest.raises(SystemExit) as info:
        main(["batch", str(tmp_path), "-o", str(tmp_path / "out"),
              "--luminance-scale", f"Cam={a}", "--luminance-scale", f"Cam={b}"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "argument --luminance-scale: 'Cam' given more than once" in err, err
    assert not (tmp_path / "out").exists()


def test_demo_seed_must_be_a_whole_number_from_0(tmp_path, capsys):
    """A negative seed was numpy's ValueError traceback (exit 1)."""
    with pytest.raises(SystemExit) as info:
        main(["demo", "-o", str(tmp_path / "d"), "--seed", "-1"])
    assert info.value.code == 2
    assert "argument --seed:" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
