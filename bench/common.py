"""Shared helpers of the benchmark scripts: data location, stacks, OpenCV baselines.

The measures the benches print live in :mod:`selfcal.sim.scoring` (RMSE of f⁻¹ against
the simulator's truth) and ``real_stack_metrics`` beside this file (the log-linearisation
error, its saturation split, the per-code floor).
"""

from __future__ import annotations

import os
import sys
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")


def data_dir(*parts) -> Path:
    """Path into ../shared/data; exit with a clear message when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        sys.exit(f"benchmark data not found: {path} (the benchmarks read ../shared/data)")
    return path


def real_stacks():
    """The real stacks of issue 3: name -> (paths, nominal times in seconds)."""
    from selfcal.io import read_exposure_info

    stacks = {}
    mem = data_dir("memorial")
    times = [float(Fraction(t)) for t in (mem / "shutter_times.txt").read_text().split()]
    paths = sorted(mem.glob("memorial*.png"))
    stacks["memorial"] = (paths, times)
    for name, folder, pattern in [("piccante", "piccante_canon_t2i/stack", "*.jpg"),
                                  ("frobisher", "frobisher_canon_5d2", "*.jpg"),
                                  ("ntu", "ntu_canon_m3", "*.JPG")]:
        paths = sorted(data_dir(folder).glob(pattern))
        stacks[name] = (paths, [read_exposure_info(p).exposure_time for p in paths])
    return stacks


def read_real_stacks(names):
    """Decoded frames of the named real stacks: name -> (RGB images, nominal times)."""
    from selfcal.io import read_image

    stacks = real_stacks()
    return {name: ([read_image(p) for p in stacks[name][0]], stacks[name][1])
            for name in names}


def opencv_inverse_response(images_rgb, times, method: str) -> np.ndarray:
    """OpenCV's CalibrateDebevec / CalibrateRobertson response as f⁻¹, (256, 3) RGB."""
    import cv2

    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images_rgb]
    t = np.asarray(times, dtype=np.float32)
    if method == "debevec":
        cal = cv2.createCalibrateDebevec()
    elif method == "robertson":
        cal = cv2.createCalibrateRobertson()
    else:
        raise ValueError(method)
    resp = cal.process(bgr, t).reshape(256, 3)[:, ::-1]
    return resp.astype(np.float64)


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.t0


def best_of(call, repeats: int) -> float:
    """The shortest of ``repeats`` wall-clock timings of ``call()`` (seconds)."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        out.append(time.perf_counter() - t0)
    return min(out)


def table(headers, rows) -> str:
    """A plain-text table (also valid Markdown)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(cells[0], widths)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    for r in cells[1:]:
        lines.append("| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |")
    return "\n".join(lines)


def real_bracket_scenes():
    """The scenes of ../shared/data/real_brackets (see its SOURCE.txt), in name order.

    Returns ``"camera/scene" -> (paths, EXIF exposure times in seconds)``, e.g.
    ``"sony_ilce6400/scene1"``; each camera shoots every scene at one ISO and f-number, so
    the times alone set the exposures.
    """
    from selfcal.io import read_exposure_info

    root = data_dir("real_brackets")
    scenes = {}
    for folder in sorted(p for p in root.glob("*/*") if p.is_dir()):
        paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".jpg", ".jpeg"))
        if paths:
            scenes[f"{folder.parent.name}/{folder.name}"] = (
                paths, [read_exposure_info(p).exposure_time for p in paths])
    return scenes


def colour_hdri_stack(images, times, meta=None):
    """A colour-hdri ``ImageStack`` of 8-bit RGB frames, shortest exposure first.

    ``meta``: per frame ``(f-number, ISO)``; default f/8, ISO 100 for every frame (only the
    times then set the exposures, as for our simulated stacks).
    """
    from colour_hdri import ImageStack
    from colour_hdri.utilities import Image, Metadata

    stack = ImageStack()
    for k in np.argsort(np.asarray(times, float), kind="stable"):
        n, iso = meta[k] if meta is not None else (8.0, 100.0)
        im = Image()
        im.data = np.asarray(images[k]).astype(np.float64) / 255.0
        im.metadata = Metadata(f_number=n, exposure_time=float(times[k]), iso=iso)
        stack.append(im)
    return stack


def colour_hdri_inverse_response(images, times, meta=None) -> np.ndarray:
    """colour-hdri's Debevec 1997 curves (its defaults: Grossberg sampling, hat weights)
    as f⁻¹, (256, 3), max 1."""
    from colour_hdri import camera_response_functions_Debevec1997

    return np.asarray(camera_response_functions_Debevec1997(
        colour_hdri_stack(images, times, meta)), dtype=np.float64)


def camera_name(cam) -> str:
    """An NUS camera model as a table title names it: its folder's name, not the path of
    one machine."""
    return repr(cam).replace(repr(str(cam.folder)), repr(cam.folder.name))
