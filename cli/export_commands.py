"""``selfcal export``: a model as a ``.cube`` look-up table other tools read.

Nothing numerical lives here: the table and the file are :func:`selfcal.export.write_cube`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import EPILOG, EXIT_OK, check_outputs, int_range, say


def cmd_export(args) -> int:
    import selfcal
    from selfcal.export.cube import (SIZE_LIMITS, check_export, default_direction,
                                model_code_range, write_cube)

    out = Path(args.output)
    check_outputs([out], [args.model], args.force)
    model = selfcal.load_model(args.model)
    if args.size is not None:   # the range of the size depends on the direction: exit 2
        direction = args.direction or default_direction(model)
        dims = 1 if direction == "linearize" else 3
        lo, hi = SIZE_LIMITS[dims]
        if not lo <= args.size <= hi:
            args.parser.error(f"argument --size: LUT_{dims}D_SIZE must be from {lo} to {hi}, "
                              f"not {args.size}")
    code_range = "model"
    if args.range is not None:  # a usage error (exit 2), like the size
        lo, hi = args.range
        if (args.direction or default_direction(model)) != "to-raw":
            args.parser.error("argument --range: applies to --direction to-raw only")
        if not 0 <= lo < hi <= 255:
            args.parser.error(f"argument --range: needs 0 <= LOW < HIGH <= 255, not {lo} {hi}")
        code_range = (lo, hi)
    try:
        direction, size = check_export(model, args.direction, args.size)
    except selfcal.InputError as exc:
        raise selfcal.InputError(exc.reason, args.model) from None
    if code_range == "model":
        code_range = model_code_range(model) if direction == "to-raw" else None
    write_cube(model, out, direction=direction, size=size, force=args.force,
               inputs=[args.model], title=f"selfcal {direction}: {Path(args.model).name}",
               code_range=code_range)
    dims = "1D" if direction == "linearize" else "3D"
    follows = "" if code_range is None else \
        f", the model followed for codes {code_range[0]}-{code_range[1]}"
    say(f"wrote {out} ({dims} LUT, {size}{'³' if dims == '3D' else ''} nodes, {direction}"
        f"{follows})")
    return EXIT_OK


def register(sub) -> None:
    """Add ``export`` to the ``selfcal`` sub-command parser."""
    p = sub.add_parser(
        "export", help="write a model as a .cube LUT (Resolve, ffmpeg, OpenColorIO)",
        description="Write a model as a .cube LUT (Adobe Cube LUT Specification 1.0). "
                    "A response model gives a 1D LUT that linearises (input code/max_code "
                    "in [0, 1], one column per channel); a RAW-path model (a selfcal "
                    "pipeline model or an NUS model folder) gives a 3D LUT: to-raw (JPEG "
                    "code/255 -> linear camera raw) or render (raw normalised to [0, 1] "
                    "-> rendered code/255). DOMAIN is 0..1 in every direction (ffmpeg "
                    "cannot read a narrower one); --range sets the codes a to-raw LUT "
                    "follows.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", metavar="MODEL",
                   help="a selfcal model file, or an NUS model folder")
    p.add_argument("-o", "--output", required=True, metavar="FILE.cube")
    p.add_argument("--direction", choices=("linearize", "to-raw", "render"), default=None,
                   help="linearize (response models, the default for them), to-raw (the "
                        "default for pipeline models) or render")
    p.add_argument("--size", type=int_range(2, 65536, "the LUT size"), default=None,
                   help="nodes: LUT_1D_SIZE 2-65536 (default max_code+1), LUT_3D_SIZE "
                        "2-256 (default 33; 65 is finer)")
    p.add_argument("--range", nargs=2, type=int, default=None, metavar=("LOW", "HIGH"),
                   help="to-raw: the codes inside which the 3D LUT follows the model; nodes "
                        "outside continue its chords (default: the codes the model was "
                        "fitted on when it says, e.g. an NUS folder's 5 252; 0 255: every "
                        "node holds the model)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=cmd_export, parser=p)
