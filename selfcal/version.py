"""The version of this selfcal, read from the installed package's metadata.

The version is written once, in ``pyproject.toml``; ``selfcal.__version__``, ``selfcal
--version`` and the ``selfcal_version`` field of every model file written
(:mod:`selfcal.io.model_file`) all read it from here.
"""

from __future__ import annotations

from importlib import metadata

#: The distribution whose metadata holds the version.
DISTRIBUTION = "selfcal"


def installed_version() -> str:
    """The version of the installed ``selfcal`` distribution.

    Returns
    -------
    str
        The ``version`` of ``pyproject.toml`` as installed, or ``"0+unknown"`` when the
        package runs from a source tree that was never installed (no metadata to read).
    """
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "0+unknown"


__version__: str = installed_version()
