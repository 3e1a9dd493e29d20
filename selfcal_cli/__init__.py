"""The ``selfcal`` command line (``selfcal_cli.main:main``).

The console script (and ``python -m selfcal_cli``) imports this package before anything
else, so in a program its first statements install the handler of a Ctrl-C while the
modules load: one line, exit 130 (see :mod:`selfcal_cli.interrupts`).  It uses only what
the interpreter has loaded already, so that no import comes before it.
"""

import sys as _sys


def _is_program() -> bool:
    """This process is the ``selfcal`` command (console script or ``-m selfcal_cli``),
    not Python code that imports ``selfcal_cli`` (the tests)."""
    argv0 = _sys.argv[0] if _sys.argv else ""
    if argv0 == "-m":        # python -m selfcal_cli: runpy imports the package first
        orig = list(getattr(_sys, "orig_argv", []))
        names = ("selfcal_cli", "selfcal_cli.main", "selfcal_cli.__main__")
        return any(a == "-m" and b in names for a, b in zip(orig, orig[1:])) or any(
            a.startswith("-m") and a[2:] in names for a in orig)
    name = argv0.replace("\\", "/").rsplit("/", 1)[-1].lower()
    for end in ("-script.pyw", "-script.py", ".exe"):
        if name.endswith(end):
            name = name[: -len(end)]
    return name == "selfcal"


def _exit_interrupted(signum, frame):
    """SIGINT while loading: nothing is written yet; one line, exit 130, at once."""
    import os       # (loaded at the interpreter's start: no import happens here)

    try:
        os.write(2, b"selfcal: interrupted\n")
    finally:
        os._exit(130)


#: Whether this process is the ``selfcal`` program (then it owns SIGINT) -- unless it
#: started with SIGINT ignored (a background job of a shell script): then it stays so.
PROGRAM = _is_program()
if PROGRAM:
    import _signal

    if _signal.getsignal(_signal.SIGINT) == _signal.SIG_IGN:
        PROGRAM = False
    else:
        _signal.signal(_signal.SIGINT, _exit_interrupted)
