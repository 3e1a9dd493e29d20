"""Exceptions and warnings raised by selfcal.

The library never prints or exits: it raises these, and the command-line front end turns
them into messages and exit codes.  Every error that concerns a file names the file.
"""

from __future__ import annotations


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
