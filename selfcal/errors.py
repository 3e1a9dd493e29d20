"""Exceptions and warnings raised by selfcal, and the warning for old keyword arguments.

The library never prints or exits: it raises these, and the command-line front end turns
them into messages and exit codes.  Every error that concerns a file names the file.
"""

from __future__ import annotations

import dataclasses
import warnings


class SelfcalError(Exception):
    """Base class of every error selfcal raises on purpose."""


class InputError(SelfcalError, ValueError):
    """An input (file or array) is missing, unreadable or not what is needed.

    Parameters
    ----------
    message : str
        What is wrong.
    path : str or os.PathLike, optional
        The file concerned; it is put at the head of the message.
    """

    def __init__(self, message: str, path: object = None) -> None:
        self.path = None if path is None else str(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class ModelFileError(InputError):
    """A model file is not a valid selfcal model (wrong format, version or content)."""


class CalibrationError(SelfcalError):
    """The data cannot determine what was asked (too few exposures, samples, ...)."""


class OutputExistsError(SelfcalError, FileExistsError):
    """An output file exists already and overwriting was not allowed."""


class SelfcalWarning(UserWarning):
    """Something the user should know, that does not stop the work."""


def options_from_keywords(options_class, options, keywords: dict, function: str, *,
                          argument: str = "options"):
    """``options`` (default ``options_class()``) with old keyword arguments folded in.

    Functions whose finer settings moved into a frozen options dataclass accept the old
    keywords for a while: each gives a :class:`DeprecationWarning` naming the field to set
    instead (in the options passed as ``argument``), never silently.  An unknown keyword is
    a :class:`TypeError`, as Python's own.

    >>> import warnings
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Opts:
    ...     margin: float = 2.0
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     opts = options_from_keywords(Opts, None, {"margin": 5.0}, "f")
    >>> opts.margin, caught[0].category.__name__
    (5.0, 'DeprecationWarning')
    >>> print(caught[0].message)
    f(margin=...) is deprecated: pass options=Opts(margin=...)
    """
    options = options_class() if options is None else options
    if not keywords:
        return options
    names = {f.name for f in dataclasses.fields(options_class)}
    unknown = sorted(set(keywords) - names)
    if unknown:
        raise TypeError(f"{function}() got an unexpected keyword argument {unknown[0]!r}")
    for key in keywords:
        warnings.warn(f"{function}({key}=...) is deprecated: pass "
                      f"{argument}={options_class.__name__}({key}=...)",
                      DeprecationWarning, stacklevel=3)
    return dataclasses.replace(options, **keywords)
