"""The ``selfcal`` command line: the parser and the front end that turns the library's
exceptions and warnings into messages and exit codes.

Each command lives in its own module (``calibrate_commands``, ``hdr_commands``,
``pipeline_commands``) and registers itself here; what they share is in ``common``.
Nothing numerical lives in ``cli/``.
"""

from __future__ import annotations

import argparse
import sys
import warnings

from . import calibrate_commands, hdr_commands, pipeline_commands
from .common import EPILOG, EXIT_CALIBRATION, EXIT_INPUT, EXIT_OUTPUT, say


def build_parser() -> argparse.ArgumentParser:
    from selfcal import __version__

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
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    import selfcal

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", selfcal.SelfcalWarning)
            code = args.func(args)
        for w in caught:
            if issubclass(w.category, selfcal.SelfcalWarning):
                say(f"warning: {w.message}")
        return code
    except selfcal.OutputExistsError as exc:
        say(f"selfcal: error: {exc}")
        return EXIT_OUTPUT
    except selfcal.InputError as exc:
        say(f"selfcal: error: {exc}")
        return EXIT_INPUT
    except selfcal.CalibrationError as exc:
        say(f"selfcal: cannot calibrate: {exc}")
        return EXIT_CALIBRATION
    except KeyboardInterrupt:
        say("selfcal: interrupted")
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
