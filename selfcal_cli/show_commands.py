"""``selfcal show MODEL [--plot FILE.png]``: what a model is, its fit, verdict, warnings and
curves, for both kinds of model, and a response model's vignetting when it has one.

Nothing numerical lives here: the content is :func:`selfcal.report.describe.describe` and its text
:func:`selfcal.report.describe.format_description`; the figure is
:func:`selfcal.report.plot_model`.  The description goes to stdout (it is the command's
output); errors and warnings go to stderr as for every command.
"""

from __future__ import annotations

import argparse
import sys

from .common import EPILOG, EXIT_OK, check_outputs, say


def cmd_show(args) -> int:
    import selfcal
    from selfcal.report.describe import describe, format_description

    check_outputs([args.plot], [args.model], args.force)
    model = selfcal.load_model(args.model)
    sys.stdout.write(format_description(describe(model), name=str(args.model)))
    if args.plot:
        from selfcal.report import plot_model

        path = plot_model(model, args.plot, force=args.force)
        say(f"wrote {path}")
    return EXIT_OK


def register(sub) -> None:
    p = sub.add_parser(
        "show", help="describe a model: what it is, its fit, verdict, warnings and curves",
        description="Describe a model file (response or RAW-path pipeline): kind, frames and "
                    "exposures with their source, solver settings, fit residuals and δ "
                    "(Eq. 12), verdict with reasons, warnings, a table of its curves, and "
                    "its vignetting when it has one (source, optical centre, corner "
                    "falloff per channel with its 90 % band).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", metavar="MODEL", help="a model file written by selfcal")
    p.add_argument("--plot", metavar="FILE.png",
                   help="also write a PNG of the curves (and of the vignetting, if any)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --plot file")
    p.set_defaults(func=cmd_show)
