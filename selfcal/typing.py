"""Type aliases of the public API, for annotations (``from selfcal.typing import PathLike``).

:data:`PathLike` is what every function that takes a file accepts; :data:`ImageInput` a
frame given as an array or as its file; :data:`ExposureTimes` a time per frame (None where
unknown); :data:`Progress` the callbacks that report progress (called with the arguments
each function documents; what they return is ignored).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Optional, TypeAlias, Union

import numpy as np

__all__ = ["PathLike", "ImageInput", "ExposureTimes", "Progress"]

#: A file name: ``str`` or ``os.PathLike`` (``pathlib.Path``).
PathLike: TypeAlias = Union[str, os.PathLike[str]]
#: A frame: an ``HxWx3`` array, or the path of its file.
ImageInput: TypeAlias = Union[np.ndarray, str, os.PathLike[str]]
#: An exposure time per frame (seconds, or anything proportional), None where unknown.
ExposureTimes: TypeAlias = Union[Sequence[Optional[float]], np.ndarray]
#: A progress callback.
Progress: TypeAlias = Callable[..., object]
