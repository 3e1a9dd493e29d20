"""Calibrations as files colour pipelines load.

* :mod:`selfcal.export.cube` -- ``.cube`` tables: the 1D table of a response model, the
  3D-only table of a pipeline model ([CubeLUT]_); its names are re-exported here;
* :mod:`selfcal.export.shaper` -- a pipeline model as a 1D shaper chosen from the model
  before a 3D table, written as a Resolve ``.cube`` ([RESOLVE]);
* :mod:`selfcal.export.clf` -- the same tables, and a response model's 1D table, in the
  Common LUT Format ([CLF3]);
* :mod:`selfcal.export.ocio` -- an OpenColorIO v2 config folder with the camera's colour
  spaces ([OCIO2]).

References
----------
.. [CubeLUT] See ``docs/references.md`` (also [RESOLVE], [CLF3], [OCIO2]).
"""

from __future__ import annotations

from .cube import (DEFAULT_3D_SIZE, DIRECTIONS, cube_table, model_code_range,
                   read_cube_header, write_cube)

__all__ = ["DIRECTIONS", "DEFAULT_3D_SIZE", "cube_table", "write_cube", "read_cube_header",
           "model_code_range"]
