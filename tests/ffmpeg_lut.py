"""LUT files applied by ffmpeg, an implementation of the formats independent of selfcal.

A helper of the tests (``test_export``), not a test module; the benches use it too, as
``tests.ffmpeg_lut`` through :mod:`bench.peers` (the tests never import from ``bench``).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np


def ffmpeg_binaries() -> list:
    """The ffmpeg executables present: imageio-ffmpeg's, then one on PATH (either may be
    missing; ``pip install imageio-ffmpeg`` provides the first)."""
    found = []
    try:
        import imageio_ffmpeg

        found.append(imageio_ffmpeg.get_ffmpeg_exe())
    except (ImportError, RuntimeError):
        pass
    system = shutil.which("ffmpeg")
    if system and system not in found:
        found.append(system)
    return found


def apply_filters_ffmpeg(exe: str, filters: str, folder, frame16: np.ndarray, *,
                         timeout: float = 600) -> np.ndarray:
    """A uint16 ``HxWx3`` RGB frame through ffmpeg's video filter graph ``filters`` (run in
    ``folder``, where the LUT files are), as float64 on [0, 1].

    Raises :class:`subprocess.CalledProcessError` when ffmpeg fails.
    """
    h, w, _ = frame16.shape
    cmd = [exe, "-hide_banner", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt",
           "rgb48le", "-s", f"{w}x{h}", "-i", "-", "-vf", filters, "-f", "rawvideo",
           "-pix_fmt", "rgb48le", "-"]
    res = subprocess.run(cmd, input=frame16.astype("<u2").tobytes(), capture_output=True,
                         cwd=folder, check=True, timeout=timeout)
    return np.frombuffer(res.stdout, "<u2").reshape(h, w, 3) / 65535.0


def apply_cube_ffmpeg(exe: str, cube, frame16: np.ndarray, interp: str = "tetrahedral",
                      *, timeout: float = 600) -> np.ndarray:
    """``cube`` applied by ffmpeg's ``lut3d`` filter; ``interp`` is ffmpeg's: ``nearest``,
    ``trilinear`` or ``tetrahedral``."""
    cube = Path(cube)
    return apply_filters_ffmpeg(exe, f"lut3d=file={cube.name}:interp={interp}", cube.parent,
                                frame16, timeout=timeout)


def apply_shaper_ffmpeg(exe: str, shaper, cube, frame16: np.ndarray) -> np.ndarray:
    """A shaper LUT written as two files (``lut1d`` then ``lut3d``, tetrahedral, in one
    folder) applied by ffmpeg."""
    shaper, cube = Path(shaper), Path(cube)
    return apply_filters_ffmpeg(
        exe, f"lut1d=file={shaper.name}:interp=linear,lut3d=file={cube.name}:interp=tetrahedral",
        shaper.parent, frame16)
