"""Calibrations as files other tools load: ``.cube`` look-up tables.

:mod:`selfcal.export.cube` writes a model as a 1D or 3D ``.cube`` table; its names are
re-exported here.
"""

from __future__ import annotations

from .cube import (DEFAULT_3D_SIZE, DIRECTIONS, apply_cube_ffmpeg, cube_table,
                   ffmpeg_binaries, model_code_range, read_cube_header, write_cube)

__all__ = ["DIRECTIONS", "DEFAULT_3D_SIZE", "cube_table", "write_cube", "read_cube_header",
           "ffmpeg_binaries", "apply_cube_ffmpeg", "model_code_range"]
