"""The ``selfcal`` command line: the parser and the front end that turns the library's
exceptions and warnings into messages and exit codes.

Each command lives in its own module (``calibrate_commands``, ``hdr_commands``,
``pipeline_commands``) and registers itself here; what they share is in ``common``.
Nothing numerical lives in ``selfcal_cli/``.
"""

from __future__ import annotations

import sys

from . import interrupts
from .common import EXIT_CALIBRATION, EXIT_INPUT, EXIT_OUTPUT  # noqa: F401 (the codes)

# Everything else is imported inside the functions: a Ctrl-C while the modules load is
# then inside main's handling (see selfcal_cli.interrupts).


def build_parser():
    import argparse

    from selfcal import __version__

    from . import (batch_commands, calibrate_commands, export_commands, hdr_commands,
                   pipeline_commands, show_commands)
    from .common import EPILOG

    parser = argparse.ArgumentParser(
        prog="selfcal",
        description="Radiometric self-calibration of cameras: response curves from "
                    "bracketed JPEG stacks (Lin et al., ICCV 2011).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"selfcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    calibrate_commands.register(sub)
    hdr_commands.register(sub)
    pipeline_commands.register(sub)
    batch_commands.register(sub)
    export_commands.register(sub)
    show_commands.register(sub)
    parser.set_defaults(commands=sub.choices)
    return parser


def _parse(parser, argv):
    """``parser.parse_args``, but a value like ``-1/60`` after ``--times`` is a usage error
    naming it (argparse would take it for an unknown option)."""
    from .common import negative_times

    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    bad = negative_times(argv)
    if bad is not None:
        commands = parser.get_default("commands")
        command = next((a for a in argv if a in commands), None)
        (commands[command] if command else parser).error(
            f"argument --times: exposure time {bad!r} must be positive (seconds, e.g. "
            "1/60 or 0.004, or ? for unknown)")
    return parser.parse_args(argv)


def main(argv=None) -> int:
    """Run one ``selfcal`` command; its exit code (130 when interrupted by Ctrl-C)."""
    previous = None
    try:
        parser = build_parser()
        args = _parse(parser, argv)
        previous = interrupts.working()
        return _run(args)
    except KeyboardInterrupt:
        interrupts.stopping()
        print("selfcal: interrupted", file=sys.stderr)
        return interrupts.EXIT_INTERRUPTED
    finally:
        interrupts.finished(previous)


def _run(args) -> int:
    """The command, its library warnings said, its exceptions turned into exit codes."""
    import warnings

    import selfcal

    from .common import reset_warnings, warn

    reset_warnings()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", selfcal.SelfcalWarning)
            try:
                code = args.func(args)
            finally:
                for w in caught:
                    if issubclass(w.category, selfcal.SelfcalWarning):
                        warn(str(w.message))
                caught.clear()
        return code
    except selfcal.SelfcalError as exc:
        # a Ctrl-C a library turned into another error (an extension module whose import
        # it broke says ImportError, and selfcal then "needs the bindings") is a Ctrl-C
        interrupts.check()
        return _error_exit(exc)


def _error_exit(exc) -> int:
    """The message and the exit code of a selfcal error."""
    import selfcal
    from selfcal.io import OutputWriteError

    from .common import say

    if isinstance(exc, (selfcal.OutputExistsError, OutputWriteError)):
        say(f"selfcal: error: {exc}")
        return EXIT_OUTPUT
    if isinstance(exc, selfcal.InputError):
        say(f"selfcal: error: {exc}")
        return EXIT_INPUT
    if isinstance(exc, selfcal.CalibrationError):
        say(f"selfcal: cannot calibrate: {exc}")
        return EXIT_CALIBRATION
    raise exc


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
