"""Bad input over the command line: every case a clear answer, nothing half-written.

Each case runs ``selfcal`` (in process; a few through a real subprocess) on real tiny files
built here (a 48x64 simulated bracket, response and pipeline models, broken copies) and
asserts:

* the documented exit code (``selfcal_cli.common.EXIT_*``; 2 for what the parser refuses);
* exactly one ``selfcal: error:`` / ``selfcal: cannot calibrate:`` line (``selfcal
  <command>: error:`` for the parser's), naming the file or option and the cause;
* no traceback;
* nothing changed under the test folder: every file has the same sha256 and no file or
  folder appeared (no outputs, no temporary files, no half-made output folders).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from selfcal_cli.common import EXIT_CALIBRATION, EXIT_INPUT, EXIT_OUTPUT, EXIT_USAGE
from selfcal_cli.main import main

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
H, W = 48, 64
TIMES = (1 / 60, 1 / 15, 1 / 4)
ERROR_LINE = re.compile(r"^selfcal(?: [a-z-]+)?: (?:error|cannot calibrate): ")


# ------------------------------------------------------------------------------ inputs

def _write_linear_tiff(path: Path, linear: np.ndarray, time: float) -> None:
    import tifffile

    fr = Fraction(time).limit_denominator(100_000)
    data = np.clip(np.round(linear * 65535), 0, 65535).astype(np.uint16)
    tifffile.imwrite(path, data, photometric="rgb",
                     extratags=[(33434, 5, 1, (fr.numerator, fr.denominator), False)])


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Path:
    """The good inputs every case starts from (copied into each test's folder)."""
    import selfcal
    from selfcal import sim

    root = tmp_path_factory.mktemp("assets")
    scene = sim.make_scene(H, W, dynamic_range_stops=8, saturation=0.3, seed=1)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=1), list(TIMES),
                                 jitter=0.0, seed=1)
    frames = stack.write(root, prefix="f")
    for k, p in enumerate(frames):                       # f0.jpg f1.jpg f2.jpg
        p.rename(root / f"f{k}.jpg")
    frames = [root / f"f{k}.jpg" for k in range(3)]
    selfcal.calibrate_response(frames).save(root / "resp.json")
    selfcal.calibrate_pipeline(
        FIXTURES / "pair" / "pair.tiff", FIXTURES / "pair" / "pair.jpg",
        options=selfcal.PipelineOptions(n_sets=2, backward="lut", bake_size=17,
                                        inverse_smoothness=1e-4,
                                        lut_smoothness=3e-3)).save(root / "pipe.json")
    shutil.copy(FIXTURES / "pair" / "pair.tiff", root / "raw.tiff")
    (root / "lin").mkdir()
    for k, (raw, t) in enumerate(zip(stack.raws, TIMES)):
        _write_linear_tiff(root / "lin" / f"l{k}.tif", raw, t)
    return root


@dataclass
class Env:
    """One test's folders: ``inp`` (copies of the assets), ``out`` (an empty folder)."""

    root: Path
    inp: Path = field(init=False)
    out: Path = field(init=False)

    def __post_init__(self):
        self.inp = self.root / "in"
        self.out = self.root / "out"

    def f(self, k: int) -> Path:
        return self.inp / f"f{k}.jpg"

    @property
    def frames(self) -> list:
        return [self.f(k) for k in range(3)]

    @property
    def resp(self) -> Path:
        return self.inp / "resp.json"

    @property
    def pipe(self) -> Path:
        return self.inp / "pipe.json"


@pytest.fixture
def env(assets, tmp_path) -> Env:
    e = Env(tmp_path)
    shutil.copytree(assets, e.inp)
    e.out.mkdir()
    return e


def _snapshot(root: Path) -> dict:
    """Every file (sha256) and folder under root."""
    found = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for d in dirnames:
            found[os.path.relpath(os.path.join(dirpath, d), root) + "/"] = "dir"
        for name in filenames:
            path = os.path.join(dirpath, name)
            found[os.path.relpath(path, root)] = hashlib.sha256(
                Path(path).read_bytes()).hexdigest()
    return found


def _run(argv, capsys) -> tuple[int, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:           # the parser's own exits
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.out + captured.err


# ------------------------------------------------------------------------------ bad files

def _truncate(path: Path, keep: int = -300) -> None:
    """Cut the file: keep its first ``keep`` bytes (negative: all but the last)."""
    path.write_bytes(path.read_bytes()[:keep])


def _image(path: Path, value, size=(H, W)) -> None:
    from selfcal.io import write_image

    write_image(path, np.full((*size, 3), value, np.uint8), force=True)


def _bracket_of(e: Env, folder: str, value) -> list:
    """Three frames with EXIF times at 1/60, 1/15, 1/4 s, all of one value."""
    from selfcal.io import write_image

    d = e.inp / folder
    d.mkdir()
    paths = []
    for k, t in enumerate(TIMES):
        paths.append(write_image(d / f"{folder}{k}.jpg", np.full((H, W, 3), value, np.uint8),
                                 exposure_time=t))
    return paths


def _other_size(e: Env) -> Path:
    import cv2

    img = cv2.imread(str(e.f(1)))
    cv2.imwrite(str(e.inp / "big.jpg"), cv2.resize(img, (W + 16, H + 12)))
    return e.inp / "big.jpg"


def _same_time_stack(e: Env) -> Path:
    from selfcal import sim

    scene = sim.make_scene(H, W, dynamic_range_stops=8, saturation=0.3, seed=2)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=2), [1 / 60] * 3,
                                 jitter=0.0, seed=2)
    stack.write(e.inp / "same", prefix="s")
    return e.inp / "same"


def _unwritable_system_folder():
    """A folder no one can create files in, even root (/sys); None when there is none."""
    folder = Path("/sys")
    if not folder.is_dir():
        return None
    try:
        (folder / ".selfcal-probe").touch()
    except OSError:
        return folder
    (folder / ".selfcal-probe").unlink()
    return None


SYS = _unwritable_system_folder()
needs_sys = pytest.mark.skipif(SYS is None, reason="no folder here refuses every write")


# ------------------------------------------------------------------------------ the cases

@dataclass
class Case:
    id: str
    argv: object                 # callable(env) -> list
    code: int
    names: object                # callable(env) -> list of strings the error line names
    cause: str                   # regex the error line matches (the cause)
    setup: object = None         # callable(env), run before the snapshot
    marks: tuple = ()


def _c(id, argv, code, names, cause, setup=None, marks=()):
    return pytest.param(Case(id, argv, code, names, cause, setup), id=id, marks=marks)


def calib(*extra):
    return lambda e: ["calibrate", *e.frames, "-o", e.out / "m.json", *extra]


def merge(*extra):
    return lambda e: ["merge", *e.frames, "--model", e.resp, "-o", e.out / "r.exr", *extra]


def write(name, data):
    return lambda e: (e.inp / name).write_bytes(data)


def mkfile(where):
    return lambda e: (e.root / where).write_text("a regular file\n")


GARBAGE = b"this is not an image, it is a text file\n" * 20
MODEL_GARBAGE = b"\x00\x01garbage, not JSON"
NOT_A_MODEL = b'{"format": "something-else", "kind": "response"}'

CASES = [
    # ---- calibrate: input files
    _c("calibrate-truncated-jpeg", calib(), EXIT_INPUT, lambda e: ["f1.jpg"], "truncated",
       setup=lambda e: _truncate(e.f(1))),
    _c("calibrate-truncated-header", calib(), EXIT_INPUT, lambda e: ["f2.jpg"], "truncated",
       setup=lambda e: _truncate(e.f(2), 120)),
    _c("calibrate-not-an-image", lambda e: ["calibrate", *e.frames[:2], e.inp / "notes.jpg",
                                            "-o", e.out / "m.json"],
       EXIT_INPUT, lambda e: ["notes.jpg"], "not an image", setup=write("notes.jpg", GARBAGE)),
    _c("calibrate-zero-byte", lambda e: ["calibrate", *e.frames[:2], e.inp / "zero.jpg",
                                         "-o", e.out / "m.json"],
       EXIT_INPUT, lambda e: ["zero.jpg"], "empty", setup=write("zero.jpg", b"")),
    _c("calibrate-unknown-suffix", lambda e: ["calibrate", *e.frames, e.inp / "data.csv",
                                              "-o", e.out / "m.json"],
       EXIT_INPUT, lambda e: ["data.csv"], "not an image or raw file",
       setup=write("data.csv", b"1,2,3\n")),
    _c("calibrate-missing-file", lambda e: ["calibrate", *e.frames, e.inp / "nope.jpg",
                                            "-o", e.out / "m.json"],
       EXIT_INPUT, lambda e: ["nope.jpg"], "no such file"),
    _c("calibrate-other-size", lambda e: ["calibrate", e.f(0), e.inp / "big.jpg", e.f(2),
                                          e.f(1), "-o", e.out / "m.json"],
       EXIT_INPUT, lambda e: ["big.jpg", "80x60", "64x48"], "differs",
       setup=_other_size),
    _c("calibrate-single-frame", lambda e: ["calibrate", e.f(0), "-o", e.out / "m.json"],
       EXIT_CALIBRATION, lambda e: ["f0.jpg"], "need frames at ≥ 2 exposures"),
    _c("calibrate-all-white", lambda e: ["calibrate", e.inp / "white", "-o", e.out / "m.json"],
       EXIT_CALIBRATION, lambda e: ["white0.jpg"], "clipped",
       setup=lambda e: _bracket_of(e, "white", 255)),
    _c("calibrate-all-black", lambda e: ["calibrate", e.inp / "black", "-o", e.out / "m.json"],
       EXIT_CALIBRATION, lambda e: ["black0.jpg"], "clipped",
       setup=lambda e: _bracket_of(e, "black", 0)),
    _c("calibrate-one-exposure", lambda e: ["calibrate", e.inp / "same", "-o",
                                            e.out / "m.json"],
       EXIT_CALIBRATION, lambda e: ["1/60"], "all at 1/60 s", setup=_same_time_stack),
    _c("calibrate-empty-folder", lambda e: ["calibrate", e.inp / "empty", "-o",
                                            e.out / "m.json"],
       EXIT_INPUT, lambda e: ["empty"], "no image or raw files",
       setup=lambda e: (e.inp / "empty").mkdir()),
    _c("calibrate-folder-of-text", lambda e: ["calibrate", e.inp / "docs", "-o",
                                              e.out / "m.json"],
       EXIT_INPUT, lambda e: ["docs"], "no image or raw files",
       setup=lambda e: ((e.inp / "docs").mkdir(), (e.inp / "docs" / "a.txt").write_text("x"))),
    _c("calibrate-raw-without-jpeg", lambda e: ["calibrate", e.inp / "lone.dng", "-o",
                                                e.out / "m.json"],
       EXIT_CALIBRATION, lambda e: ["lone.dng"], "without a JPEG of the same name",
       setup=write("lone.dng", GARBAGE)),
    _c("calibrate-raw-garbage", lambda e: ["calibrate", e.inp / "f0.dng", *e.frames, "-o",
                                           e.out / "m.json"],
       EXIT_INPUT, lambda e: ["f0.dng"], "not a raw file", setup=write("f0.dng", GARBAGE)),
    _c("calibrate-linear-tiffs", lambda e: ["calibrate", e.inp / "lin", "-o",
                                            e.out / "m.json"],
       EXIT_CALIBRATION, lambda e: ["l0.tif"], "linear data"),
    # ---- calibrate: options
    _c("calibrate-times-count", calib("--times", "1/60", "1/15"), EXIT_INPUT,
       lambda e: ["f0.jpg"], "2 exposure times given for 3"),
    _c("calibrate-times-zero", calib("--times", "0", "1/15", "1/4"), EXIT_USAGE,
       lambda e: ["--times", "'0'"], "must be positive"),
    _c("calibrate-times-negative-fraction", calib("--times", "1/60", "-1/60", "1/4"),
       EXIT_USAGE, lambda e: ["--times", "'-1/60'"], "must be positive"),
    _c("calibrate-times-negative", calib("--times", "1/60", "-1", "1/4"), EXIT_USAGE,
       lambda e: ["--times", "'-1'"], "must be positive"),
    _c("calibrate-times-garbage", calib("--times", "1/60", "fast", "1/4"), EXIT_USAGE,
       lambda e: ["--times", "'fast'"], "not a number"),
    _c("calibrate-times-division-by-zero", calib("--times", "1/0", "1/15", "1/4"),
       EXIT_USAGE, lambda e: ["--times", "'1/0'"], "not a number"),
    _c("calibrate-times-and-unknown", calib("--times", "1/60", "1/15", "1/4",
                                            "--unknown-exposures"),
       EXIT_USAGE, lambda e: ["--unknown-exposures", "--times"], "not allowed"),
    _c("calibrate-components-0", calib("--components", "0"), EXIT_USAGE,
       lambda e: ["--components", "'0'"], "from 1 to 25"),
    _c("calibrate-components-50", calib("--components", "50"), EXIT_USAGE,
       lambda e: ["--components", "'50'"], "from 1 to 25"),
    _c("calibrate-components-text", calib("--components", "five"), EXIT_USAGE,
       lambda e: ["--components", "'five'"], "whole number"),
    _c("calibrate-saturation-negative", calib("--saturation-threshold", "-1"), EXIT_USAGE,
       lambda e: ["--saturation-threshold", "'-1'"], "from 0 to 1"),
    _c("calibrate-saturation-2", calib("--saturation-threshold", "2"), EXIT_USAGE,
       lambda e: ["--saturation-threshold", "'2'"], "from 0 to 1"),
    _c("calibrate-saturation-nan", calib("--saturation-threshold", "nan"), EXIT_USAGE,
       lambda e: ["--saturation-threshold", "'nan'"], "from 0 to 1"),
    _c("calibrate-align-unknown", calib("--align", "sift"), EXIT_USAGE,
       lambda e: ["--align", "'sift'"], "invalid choice"),
    _c("calibrate-basis-garbage", calib("--basis", "IN/basis.txt"), EXIT_INPUT,
       lambda e: ["basis.txt"], "neither a selfcal .npz basis nor an inverse-EMoR",
       setup=write("basis.txt", GARBAGE)),
    _c("calibrate-basis-missing", calib("--basis", "IN/nobasis.npz"), EXIT_INPUT,
       lambda e: ["nobasis.npz"], "no such"),
    # ---- calibrate: outputs
    _c("calibrate-output-exists", lambda e: ["calibrate", *e.frames, "-o", e.out / "old.json"],
       EXIT_OUTPUT, lambda e: ["old.json"], "exists already.*--force",
       setup=lambda e: (e.out / "old.json").write_text("{}")),
    _c("calibrate-output-is-input", lambda e: ["calibrate", *e.frames, "-o", e.f(0), "--force"],
       EXIT_OUTPUT, lambda e: ["f0.jpg"], "input"),
    _c("calibrate-output-folder-missing", lambda e: ["calibrate", *e.frames, "-o",
                                                     e.out / "nodir" / "m.json"],
       EXIT_OUTPUT, lambda e: ["m.json", "nodir"], "does not exist"),
    _c("calibrate-output-under-a-file", lambda e: ["calibrate", *e.frames, "-o",
                                                   e.root / "afile" / "m.json"],
       EXIT_OUTPUT, lambda e: ["afile/m.json"], "is a file, not a folder",
       setup=mkfile("afile")),
    _c("calibrate-output-is-a-folder", lambda e: ["calibrate", *e.frames, "-o", e.out],
       EXIT_OUTPUT, lambda e: ["out"], "directory"),
    _c("calibrate-plot-exists", calib("--plot", "OUT/old.png"), EXIT_OUTPUT,
       lambda e: ["old.png"], "exists already",
       setup=lambda e: (e.out / "old.png").write_bytes(b"\x89PNG old")),
    _c("calibrate-plot-not-png", calib("--plot", "OUT/plot.jpg"), EXIT_INPUT,
       lambda e: ["plot.jpg"], r"\.png"),
    _c("calibrate-plot-under-a-file", calib("--plot", "ROOT/afile/plot.png"), EXIT_OUTPUT,
       lambda e: ["plot.png"], "is a file, not a folder", setup=mkfile("afile")),
    _c("calibrate-pipeline-output-is-the-output", calib("--pipeline-output", "OUT/m.json"),
       EXIT_INPUT, lambda e: ["m.json"], "two different outputs"),
    _c("calibrate-pipeline-output-exists", calib("--pipeline-output", "OUT/p.json"),
       EXIT_OUTPUT, lambda e: ["p.json"], "exists already",
       setup=lambda e: (e.out / "p.json").write_text("{}")),
    _c("calibrate-unwritable-system-folder", lambda e: ["calibrate", *e.frames, "-o",
                                                        SYS / "selfcal-m.json"],
       EXIT_OUTPUT, lambda e: ["selfcal-m.json"], "cannot be written", marks=needs_sys),
    # ---- merge
    _c("merge-truncated-jpeg", merge(), EXIT_INPUT, lambda e: ["f1.jpg"], "truncated",
       setup=lambda e: _truncate(e.f(1))),
    _c("merge-zero-byte", lambda e: ["merge", *e.frames[:2], e.inp / "zero.jpg", "--model",
                                     e.resp, "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["zero.jpg"], "empty", setup=write("zero.jpg", b"")),
    _c("merge-missing-frame", lambda e: ["merge", *e.frames, e.inp / "gone.jpg", "--model",
                                         e.resp, "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["gone.jpg"], "no such file"),
    _c("merge-other-size", lambda e: ["merge", e.f(0), e.inp / "big.jpg", e.f(2), "--model",
                                      e.resp, "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["big.jpg", "80x60"], "differs", setup=_other_size),
    _c("merge-output-exists", lambda e: ["merge", *e.frames, "--model", e.resp, "-o",
                                         e.out / "old.exr"],
       EXIT_OUTPUT, lambda e: ["old.exr"], "exists already",
       setup=lambda e: (e.out / "old.exr").write_bytes(b"old")),
    _c("merge-output-format", lambda e: ["merge", *e.frames, "--model", e.resp, "-o",
                                         e.out / "r.png"],
       EXIT_INPUT, lambda e: ["r.png"], "unsupported radiance format"),
    _c("merge-preview-format", merge("--preview", "OUT/p.bmp"), EXIT_INPUT,
       lambda e: ["p.bmp"], "preview is a .jpg or .png"),
    _c("merge-preview-exists", merge("--preview", "OUT/p.jpg"), EXIT_OUTPUT,
       lambda e: ["p.jpg"], "exists already",
       setup=lambda e: (e.out / "p.jpg").write_bytes(b"old preview")),
    _c("merge-output-under-a-file", lambda e: ["merge", *e.frames, "--model", e.resp, "-o",
                                               e.root / "afile" / "r.exr"],
       EXIT_OUTPUT, lambda e: ["afile/r.exr"], "is a file, not a folder",
       setup=mkfile("afile")),
    _c("merge-output-folder-missing", lambda e: ["merge", *e.frames, "--model", e.resp,
                                                 "-o", e.out / "nodir" / "r.exr"],
       EXIT_OUTPUT, lambda e: ["r.exr", "nodir"], "does not exist"),
    _c("merge-output-is-input", lambda e: ["merge", "--linear", *sorted((e.inp / "lin").iterdir()),
                                           "-o", e.inp / "lin" / "l0.tif", "--force"],
       EXIT_OUTPUT, lambda e: ["l0.tif"], "input"),
    _c("merge-model-missing", lambda e: ["merge", *e.frames, "--model", e.inp / "no.json",
                                         "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["no.json"], "no such"),
    _c("merge-model-garbage", lambda e: ["merge", *e.frames, "--model", e.inp / "bad.json",
                                         "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["bad.json"], "JSON|model", setup=write("bad.json", MODEL_GARBAGE)),
    _c("merge-model-truncated", lambda e: ["merge", *e.frames, "--model", e.inp / "cut.json",
                                           "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["cut.json"], "JSON",
       setup=lambda e: (e.inp / "cut.json").write_bytes(e.resp.read_bytes()[:200])),
    _c("merge-model-wrong-format", lambda e: ["merge", *e.frames, "--model",
                                              e.inp / "other.json", "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["other.json"], "model|format",
       setup=write("other.json", NOT_A_MODEL)),
    _c("merge-model-is-an-image", lambda e: ["merge", *e.frames[1:], "--model", e.f(0),
                                             "-o", e.out / "r.exr"],
       EXIT_INPUT, lambda e: ["f0.jpg"], "JSON|model"),
    _c("merge-times-count", merge("--times", "1/60", "1/15"), EXIT_INPUT,
       lambda e: ["--times"], "2 values for 3 images"),
    _c("merge-times-negative", merge("--times", "1/60", "-1/15", "1/4"), EXIT_USAGE,
       lambda e: ["--times", "'-1/15'"], "must be positive"),
    _c("merge-linear-and-model", merge("--linear"), EXIT_USAGE,
       lambda e: ["--linear", "--model"], "not allowed"),
    _c("merge-reference-out-of-range", merge("--reference", "7"), EXIT_INPUT,
       lambda e: ["--reference 7"], "out of range"),
    _c("merge-one-frame-no-model", lambda e: ["merge", e.f(0), "-o", e.out / "r.exr"],
       EXIT_CALIBRATION, lambda e: ["f0.jpg"], "one frame and no model"),
    _c("merge-weighting-unknown", merge("--weighting", "flat"), EXIT_USAGE,
       lambda e: ["--weighting", "'flat'"], "invalid choice"),
    _c("merge-unwritable-system-folder", lambda e: ["merge", *e.frames, "--model", e.resp,
                                                    "-o", SYS / "selfcal-r.exr"],
       EXIT_OUTPUT, lambda e: ["selfcal-r.exr"], "cannot be written", marks=needs_sys),
    # ---- linearize
    _c("linearize-model-missing", lambda e: ["linearize", "--model", e.inp / "no.json",
                                             *e.frames, "-o", e.out / "lin"],
       EXIT_INPUT, lambda e: ["no.json"], "no such"),
    _c("linearize-model-garbage", lambda e: ["linearize", "--model", e.inp / "bad.json",
                                             *e.frames, "-o", e.out / "lin"],
       EXIT_INPUT, lambda e: ["bad.json"], "JSON|model", setup=write("bad.json", MODEL_GARBAGE)),
    _c("linearize-output-is-a-file", lambda e: ["linearize", "--model", e.resp, *e.frames,
                                                "-o", e.root / "afile"],
       EXIT_OUTPUT, lambda e: ["afile"], "is a file", setup=mkfile("afile")),
    _c("linearize-output-exists", lambda e: ["linearize", "--model", e.resp, *e.frames,
                                             "-o", e.out],
       EXIT_OUTPUT, lambda e: ["f1.tif"], "exists already",
       setup=lambda e: (e.out / "f1.tif").write_bytes(b"old")),
    _c("linearize-truncated-input", lambda e: ["linearize", "--model", e.resp, *e.frames,
                                               "-o", e.out / "lin"],
       EXIT_INPUT, lambda e: ["f2.jpg"], "truncated", setup=lambda e: _truncate(e.f(2))),
    _c("linearize-missing-input", lambda e: ["linearize", "--model", e.resp, *e.frames,
                                             e.inp / "gone.jpg", "-o", e.out / "lin"],
       EXIT_INPUT, lambda e: ["gone.jpg"], "no such file"),
    _c("linearize-same-name-twice", lambda e: ["linearize", "--model", e.resp, e.f(0),
                                               e.inp / "lin" / "f0.jpg", "-o", e.out],
       EXIT_INPUT, lambda e: ["f0.jpg", "f0.tif"], "same file",
       setup=lambda e: shutil.copy(e.f(0), e.inp / "lin" / "f0.jpg")),
    _c("linearize-unwritable-system-folder", lambda e: ["linearize", "--model", e.resp,
                                                        *e.frames, "-o", SYS / "selfcal-l"],
       EXIT_OUTPUT, lambda e: ["f0.tif"], "cannot be written", marks=needs_sys),
    # ---- to-raw
    _c("to-raw-response-model", lambda e: ["to-raw", "--model", e.resp, *e.frames, "-o",
                                           e.out / "raw"],
       EXIT_INPUT, lambda e: ["resp.json"], "pipeline"),
    _c("to-raw-model-garbage", lambda e: ["to-raw", "--model", e.inp / "bad.json", *e.frames,
                                          "-o", e.out / "raw"],
       EXIT_INPUT, lambda e: ["bad.json"], "JSON|model", setup=write("bad.json", MODEL_GARBAGE)),
    _c("to-raw-truncated-second-image", lambda e: ["to-raw", "--model", e.pipe, *e.frames,
                                                   "-o", e.out / "raw"],
       EXIT_INPUT, lambda e: ["f1.jpg"], "truncated", setup=lambda e: _truncate(e.f(1))),
    _c("to-raw-output-exists", lambda e: ["to-raw", "--model", e.pipe, *e.frames, "-o", e.out],
       EXIT_OUTPUT, lambda e: ["f2.tiff"], "exists already",
       setup=lambda e: (e.out / "f2.tiff").write_bytes(b"old")),
    _c("to-raw-output-under-a-file", lambda e: ["to-raw", "--model", e.pipe, *e.frames, "-o",
                                                e.root / "afile" / "raw"],
       EXIT_OUTPUT, lambda e: ["afile"], "is a file", setup=mkfile("afile")),
    _c("to-raw-missing-input", lambda e: ["to-raw", "--model", e.pipe, e.inp / "gone.jpg",
                                          "-o", e.out / "raw"],
       EXIT_INPUT, lambda e: ["gone.jpg"], "no such file"),
    # ---- render
    _c("render-response-model", lambda e: ["render", "--model", e.resp, e.inp / "raw.tiff",
                                           "-o", e.out / "jpg"],
       EXIT_INPUT, lambda e: ["resp.json"], "pipeline"),
    _c("render-jpeg-as-raw", lambda e: ["render", "--model", e.pipe, e.f(0), "-o",
                                        e.out / "jpg"],
       EXIT_INPUT, lambda e: ["f0.jpg"], "raw"),
    _c("render-garbage-raw", lambda e: ["render", "--model", e.pipe, e.inp / "x.dng", "-o",
                                        e.out / "jpg"],
       EXIT_INPUT, lambda e: ["x.dng"], "raw", setup=write("x.dng", GARBAGE)),
    _c("render-quality-0", lambda e: ["render", "--model", e.pipe, e.inp / "raw.tiff",
                                      "--quality", "0", "-o", e.out / "jpg"],
       EXIT_USAGE, lambda e: ["--quality", "'0'"], "from 1 to 100"),
    _c("render-quality-text", lambda e: ["render", "--model", e.pipe, e.inp / "raw.tiff",
                                         "--quality", "high", "-o", e.out / "jpg"],
       EXIT_USAGE, lambda e: ["--quality", "'high'"], "whole number"),
    _c("render-output-exists", lambda e: ["render", "--model", e.pipe, e.inp / "raw.tiff",
                                          "-o", e.out],
       EXIT_OUTPUT, lambda e: ["raw.jpg"], "exists already",
       setup=lambda e: (e.out / "raw.jpg").write_bytes(b"old")),
    _c("render-missing-raw", lambda e: ["render", "--model", e.pipe, e.inp / "gone.dng",
                                        "-o", e.out / "jpg"],
       EXIT_INPUT, lambda e: ["gone.dng"], "no such file"),
    _c("render-model-truncated", lambda e: ["render", "--model", e.inp / "cut.json",
                                            e.inp / "raw.tiff", "-o", e.out / "jpg"],
       EXIT_INPUT, lambda e: ["cut.json"], "JSON",
       setup=lambda e: (e.inp / "cut.json").write_bytes(e.pipe.read_bytes()[:300])),
]


def _argv(case: Case, e: Env) -> list:
    subst = {"IN/": f"{e.inp}/", "OUT/": f"{e.out}/", "ROOT/": f"{e.root}/"}
    out = []
    for a in case.argv(e):
        a = str(a)
        for k, v in subst.items():
            if a.startswith(k):
                a = v + a[len(k):]
        out.append(a)
    return out


def _check(case: Case, e: Env, code: int, text: str, before: dict) -> None:
    assert code == case.code, text
    assert "Traceback" not in text, text
    errors = [ln for ln in text.splitlines() if ERROR_LINE.match(ln)]
    assert len(errors) == 1, text
    line = errors[0]
    for name in case.names(e):
        assert name in line, f"{name!r} not named in: {line}"
    assert re.search(case.cause, line), f"cause {case.cause!r} not in: {line}"
    assert _snapshot(e.root) == before, "files changed or left behind"


@pytest.mark.parametrize("case", CASES)
def test_bad_input(case, env, capsys):
    if case.setup is not None:
        case.setup(env)
    before = _snapshot(env.root)
    code, text = _run(_argv(case, env), capsys)
    _check(case, env, code, text, before)


def test_there_are_enough_cases():
    assert len({c.values[0].id for c in CASES}) == len(CASES) >= 50


# a handful through a real process: the exit code and no traceback, for real
SUBPROCESS = ["calibrate-truncated-jpeg", "calibrate-times-negative-fraction",
              "calibrate-output-under-a-file", "merge-preview-exists",
              "to-raw-truncated-second-image", "calibrate-empty-folder"]


@pytest.mark.parametrize("case", [c for c in CASES if c.values[0].id in SUBPROCESS],
                         ids=lambda c: c.id)
def test_bad_input_in_a_process(case, env):
    if case.setup is not None:
        case.setup(env)
    before = _snapshot(env.root)
    result = subprocess.run([sys.executable, "-m", "selfcal_cli", *_argv(case, env)],
                            capture_output=True, text=True, cwd=env.root, timeout=120)
    _check(case, env, result.returncode, result.stdout + result.stderr, before)


def test_unwritable_output_folder(env, capsys):
    """chmod a-w on the output folder (ineffective for root: skipped then)."""
    env.out.chmod(0o555)
    try:
        if os.access(env.out, os.W_OK):
            pytest.skip("running as root: chmod does not stop writes")
        case = Case("unwritable", lambda e: ["calibrate", *e.frames, "-o", e.out / "m.json"],
                    EXIT_OUTPUT, lambda e: ["m.json"], "cannot be written")
        before = _snapshot(env.root)
        code, text = _run(_argv(case, env), capsys)
        _check(case, env, code, text, before)
    finally:
        env.out.chmod(0o755)
