"""Ctrl-C (SIGINT) at any moment of a ``selfcal`` command: exit 130, one line, nothing
written, no traceback.

A command lives through three phases, and SIGINT is handled in each as fits it:

loading (``selfcal_cli/__init__.py``, its first statements)
    Modules load, the parser is built, the arguments are read: nothing is written yet, so
    the process says ``selfcal: interrupted`` and ends at once with 130 (``os._exit``).
    Raising there would be a traceback out of the console script's ``import`` (which no
    ``try`` surrounds), and an import with a bare ``except:`` (OpenCV's loader has one)
    would swallow the interrupt and the command would run on.
working (:func:`working`)
    The command runs: SIGINT raises :class:`KeyboardInterrupt` in the main thread, so
    that every ``finally`` removes its temporary files (``StagedOutputs``, ``selfcal
    demo``'s frames, the batch's manifest); ``main`` says ``selfcal: interrupted`` and
    returns 130.  The interrupt is also remembered: :func:`check` raises it again at the
    points the commands call it (each progress step, and just before the outputs are
    committed), so an interrupt that a library swallowed still stops the command before
    anything is written.
finished (:func:`finished`, :func:`committed`)
    The outputs are in place (or the command has failed): Ctrl-C no longer stops
    anything, the command ends with its own code (``SIG_IGN`` in a program: the
    interpreter's teardown would otherwise die of the signal, exit -2).

Only a program (the ``selfcal`` console script, ``python -m selfcal_cli``) installs the
loading and finished handlers; ``main()`` called from Python code (the tests) keeps its
caller's handler but for the working phase, and restores it after.  A process started
with SIGINT ignored (``selfcal ... &`` in a shell script: the shell ignores it for
background jobs, as ``nohup`` does SIGHUP) keeps it ignored.  A SIGINT in the
first milliseconds, before the interpreter has run any code of ours (its own start and
``site``), is the interpreter's: killed by the signal (130 in a shell), or Python's
``KeyboardInterrupt`` traceback while ``site`` imports.
"""

from __future__ import annotations

import signal

#: The exit code of an interrupted command (128 + SIGINT).
EXIT_INTERRUPTED = 130

_state = {"interrupted": False}


def _program() -> bool:
    from . import PROGRAM

    return PROGRAM


def _raise(signum, frame):
    """Working: remember the interrupt and raise it in the main thread."""
    _state["interrupted"] = True
    raise KeyboardInterrupt


def _note(signum, frame):
    """Stopping already (main is saying so): remember it, do not break the cleanup."""
    _state["interrupted"] = True


def _set(handler):
    """``signal.signal(SIGINT, handler)`` from the main thread (else None, unchanged)."""
    try:
        return signal.signal(signal.SIGINT, handler)
    except ValueError:      # not the main thread: signals are not ours to handle
        return None


def working():
    """The command starts: SIGINT raises KeyboardInterrupt; the handler it replaces
    (None, and SIGINT left ignored, in a process that started with it ignored)."""
    _state["interrupted"] = False
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        return None
    return _set(_raise)


def stopping() -> None:
    """``main`` caught the interrupt and says so: further SIGINTs are noted only."""
    _set(_note)


def finished(previous) -> None:
    """The command is over: in a program Ctrl-C no longer changes its end; otherwise the
    caller's handler again (and the interrupt forgotten: the next call starts afresh)."""
    _state["interrupted"] = False
    if _program():
        _set(signal.SIG_IGN)
    elif previous is not None:
        _set(previous)


def committed() -> None:
    """The command's outputs are in place: from here on (its summary) Ctrl-C does not
    turn a finished command into an interrupted one (in a program).  (:func:`check`
    goes inside the ``with StagedOutputs`` block, before the commit.)"""
    if _program():
        _set(signal.SIG_IGN)


def interrupted() -> bool:
    """A SIGINT came during the command."""
    return _state["interrupted"]


def check() -> None:
    """Raise KeyboardInterrupt if a SIGINT came during the command (one a library may
    have swallowed): call before committing outputs and at each progress step."""
    if _state["interrupted"]:
        raise KeyboardInterrupt
