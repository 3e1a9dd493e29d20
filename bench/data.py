"""The benchmarks' data: ``../shared/data`` (see its README), read in place, never copied.

Splits (the developers' rule: tune on one, report on the other): synthetic stacks with
seeds < 1000 and even DoRF curves, and one real scene per camera (:data:`TUNING_STACKS`),
are the **tuning** split; seeds ≥ 1000, odd DoRF curves and every other real stack are
**held out**.
"""

from __future__ import annotations

import os
import sys
from fractions import Fraction
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

#: Real stacks the library may be tuned on: memorial and the first scene of each camera.
TUNING_STACKS = ("memorial", "fujifilm_xh1/scene1", "sony_ilce6400/scene1")
#: The 24 MP ntu frames are decoded at 1/NTU_REDUCE at least.
NTU_REDUCE = 4
#: DoRF forward curves (201 of them) and their inverses.
DORF = SHARED_DATA / "dorf_emor" / "201_CRF_data.mat"
_DORF_CACHE: dict = {}


def data_dir(*parts) -> Path:
    """Path into ../shared/data; exit with a clear message when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        sys.exit(f"benchmark data not found: {path} (the benchmarks read ../shared/data)")
    return path


def split_of_seed(seed: int) -> str:
    """``"tuning"`` for simulator seeds < 1000, else ``"held-out"``."""
    return "tuning" if seed < 1000 else "held-out"


def split_of_stack(name: str) -> str:
    """``"tuning"`` for :data:`TUNING_STACKS`, else ``"held-out"``."""
    return "tuning" if name in TUNING_STACKS else "held-out"


def dorf_curve(index: int):
    """The ``index``-th DoRF forward curve as a :class:`selfcal.sim.ToneCurve`."""
    import scipy.io as sio

    from selfcal import sim

    if "mat" not in _DORF_CACHE:
        _DORF_CACHE["mat"] = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    mat = _DORF_CACHE["mat"]
    return sim.ToneCurve.from_table(mat["I"][index], mat["B"][index], name=f"dorf{index}")


def dorf_stack_arguments(parser) -> None:
    """``--step``, ``--size``, ``--jobs`` and ``--split`` of the benches that simulate one
    stack per DoRF curve (:func:`dorf_stacks`)."""
    parser.add_argument("--step", type=int, default=10,
                        help="every K-th DoRF curve, an even and an odd one (default %(default)s)")
    parser.add_argument("--size", default="256x384", help="scene HxW (default %(default)s)")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    parser.add_argument("--split", choices=("both", "tuning", "held-out"), default="both")


def dorf_stacks(parser, args) -> tuple[list, tuple]:
    """``(curve index, seed)`` of the stacks :func:`dorf_stack_arguments` chose, and the
    scene size ``(h, w)``: even curves ``0, K, 2K, …`` with seed = index (tuning), the odd
    curve after each with seed = 1000 + index (held out)."""
    if args.step < 1:
        parser.error("--step must be >= 1")
    h, w = (int(v) for v in args.size.lower().split("x"))
    n_curves = 201
    even = sorted({i - i % 2 for i in range(0, n_curves, args.step)})
    stacks = []
    if args.split in ("both", "tuning"):
        stacks += [(i, i) for i in even]
    if args.split in ("both", "held-out"):
        stacks += [(i + 1, 1000 + i + 1) for i in even if i + 1 < n_curves]
    return stacks, (h, w)


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


def stack_list():
    """Every real stack, name -> (paths, times), in the order the tables print."""
    stacks = {}
    base = real_stacks()
    for name in ("memorial", "piccante", "ntu", "frobisher"):
        stacks[name] = base[name]
    stacks.update(real_bracket_scenes())
    return stacks


def exposure_meta(paths):
    """(f-number, ISO) per frame from EXIF, 1 and 100 where absent (memorial's PNGs)."""
    from selfcal.io import read_exposure_info

    out = []
    for p in paths:
        info = read_exposure_info(p) if p.suffix.lower() in (".jpg", ".jpeg") else None
        out.append((info.f_number if info and info.f_number else 1.0,
                    info.iso if info and info.iso else 100.0))
    return out


def sorted_frames(name, paths, times, reduce: int):
    """The stack's frames decoded (ntu reduced at least :data:`NTU_REDUCE`), paths and
    times, in increasing exposure."""
    from selfcal.io import read_image

    if name == "ntu":
        reduce = max(reduce, NTU_REDUCE)
    order = np.argsort(np.asarray(times, float), kind="stable")
    paths = [paths[k] for k in order]
    times = [float(times[k]) for k in order]
    return [read_image(p, reduce=reduce) for p in paths], paths, times


def camera_name(cam) -> str:
    """An NUS camera model as a table title names it: its folder's name, not the path of
    one machine."""
    return repr(cam).replace(repr(str(cam.folder)), repr(cam.folder.name))
