"""Type aliases of the public API, for annotations (``from selfcal.typing import PathLike``).

:data:`PathLike` is what every function that takes a file accepts; :data:`Progress` the
callbacks that report progress (called with a stage name, a count done, a total and a
message, or with the arguments each function documents; what they return is ignored).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TypeAlias, Union

__all__ = ["PathLike", "Progress"]

#: A file name: ``str`` or ``os.PathLike`` (``pathlib.Path``).
PathLike: TypeAlias = Union[str, os.PathLike[str]]
#: A progress callback.
Progress: TypeAlias = Callable[..., object]
