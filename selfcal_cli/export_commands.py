"""``selfcal export``: a model as LUT files other tools read, or an OpenColorIO config.

``-o X.cube`` / ``-o X.clf`` (any other extension is refused) or ``--ocio DIR``.  Nothing
numerical lives here: the tables and files are :func:`selfcal.export.write_cube` (1D, and
3D-only with ``--no-shaper``), :func:`selfcal.export.shaper.write_shaper_cube`,
:func:`selfcal.export.clf.write_model_clf` and
:func:`selfcal.export.ocio.write_ocio_config`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import EPILOG, EXIT_OK, check_outputs, int_range, say


#: What ``-o`` writes, by extension.
FORMATS = (".cube", ".clf")


def _check_args(args) -> None:
    """Usage errors that need no model (exit 2)."""
    if args.output is not None:
        suffix = Path(args.output).suffix.lower()
        if suffix not in FORMATS:
            args.parser.error(f"argument -o/--output: selfcal export writes .cube or .clf "
                              f"files, not {suffix or 'a file without an extension'!r} "
                              f"({args.output}); use --ocio DIR for an OpenColorIO config")
        if args.no_shaper and suffix != ".cube":
            args.parser.error("argument --no-shaper: applies to a .cube output only")
    elif args.no_shaper or args.range is not None or args.direction is not None:
        args.parser.error("argument --ocio: writes both directions with shapers; "
                          "--direction, --no-shaper and --range apply to -o only")
    if args.range is not None and not args.no_shaper:
        args.parser.error("argument --range: applies to a 3D-only cube (--no-shaper); a "
                          "shaper LUT follows the whole code range")


def _export_ocio(args, model) -> int:
    from selfcal.export.ocio import write_ocio_config

    import selfcal

    try:
        path = write_ocio_config(model, args.ocio, camera=Path(args.model).stem or "camera",
                                 size=args.size, shaper_size=args.shaper_size,
                                 force=args.force, inputs=[args.model])
    except selfcal.InputError as exc:
        if exc.path is not None:
            raise
        raise selfcal.InputError(exc.reason, args.model) from None
    say(f"wrote {path} and its LUTs (OpenColorIO v2 config)")
    return EXIT_OK


def _export_shaper(args, model, direction: str, size: int, out: Path) -> int:
    from selfcal.export.clf import write_model_clf
    from selfcal.export.shaper import shaper_lut, write_shaper_cube

    title = f"selfcal {direction}: {Path(args.model).name}"
    if out.suffix.lower() == ".clf":
        write_model_clf(model, out, direction=direction, size=size,
                        shaper_size=args.shaper_size, name=title, force=args.force,
                        inputs=[args.model])
        what = "CLF"
    else:
        lut = shaper_lut(model, direction, size=size, shaper_size=args.shaper_size)
        write_shaper_cube(lut, out, title=title, force=args.force, inputs=[args.model])
        what = "Resolve .cube"
    say(f"wrote {out} ({what}: {args.shaper_size}-node shaper + 3D LUT, {size}³ nodes, "
        f"{direction})")
    return EXIT_OK


def cmd_export(args) -> int:
    import selfcal
    from selfcal.export.cube import (SIZE_LIMITS, check_export, default_direction,
                                model_code_range, write_cube)

    _check_args(args)
    if args.ocio is not None:
        from selfcal.export.ocio import check_ocio_folder

        check_ocio_folder(args.ocio, args.force, [args.model])
    else:
        check_outputs([Path(args.output)], [args.model], args.force)
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
    if args.ocio is not None:
        return _export_ocio(args, model)
    out = Path(args.output)
    try:
        direction, size = check_export(model, args.direction, args.size)
    except selfcal.InputError as exc:
        raise selfcal.InputError(exc.reason, args.model) from None
    if direction != "linearize" and (out.suffix.lower() == ".clf" or not args.no_shaper):
        return _export_shaper(args, model, direction, size, out)
    if direction == "linearize" and out.suffix.lower() == ".clf":
        from selfcal.export.clf import write_model_clf

        write_model_clf(model, out, direction=direction, size=size, force=args.force,
                        inputs=[args.model], name=f"selfcal linearize: {Path(args.model).name}")
        say(f"wrote {out} (CLF: 1D LUT, {size} nodes, linearize)")
        return EXIT_OK
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
        "export", help="write a model as a LUT (.cube, .clf) or an OpenColorIO config",
        description="Write a model as a LUT file or an OpenColorIO v2 config. A response "
                    "model gives a 1D LUT that linearises (input code/max_code in [0, 1], "
                    "one column per channel): -o X.cube (Adobe Cube 1.0) or -o X.clf "
                    "(Common LUT Format). A RAW-path model (a selfcal pipeline model or an "
                    "NUS model folder) gives a 1D shaper chosen from the model followed by "
                    "a 3D LUT: to-raw (JPEG code/255 -> linear camera raw) or render (raw "
                    "normalised to [0, 1] -> rendered code/255), as -o X.cube (Resolve "
                    "layout, shaper and 3D table in one file) or -o X.clf (Range, LUT1D, "
                    "LUT3D); --no-shaper writes a 3D-only Adobe cube (for ffmpeg's lut3d; "
                    "--range sets the codes its to-raw table follows). --ocio DIR writes a "
                    "folder: config.ocio and its CLF files, the camera's JPEG encoding and "
                    "scene-linear colour spaces.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("model", metavar="MODEL",
                   help="a selfcal model file, or an NUS model folder")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("-o", "--output", metavar="FILE.cube|FILE.clf",
                       help="the LUT file; its extension says the format")
    where.add_argument("--ocio", metavar="DIR",
                       help="write an OpenColorIO v2 config folder (config.ocio + LUTs); "
                            "created whole or not at all")
    p.add_argument("--direction", choices=("linearize", "to-raw", "render"), default=None,
                   help="linearize (response models, the default for them), to-raw (the "
                        "default for pipeline models) or render")
    p.add_argument("--size", type=int_range(2, 65536, "the LUT size"), default=None,
                   help="nodes: LUT_1D_SIZE 2-65536 (default max_code+1), LUT_3D_SIZE "
                        "2-256 (default 33, --ocio 65; 65 is finer)")
    p.add_argument("--range", nargs=2, type=int, default=None, metavar=("LOW", "HIGH"),
                   help="--no-shaper to-raw: the codes inside which the 3D LUT follows the "
                        "model; nodes "
                        "outside continue its chords (default: the codes the model was "
                        "fitted on when it says, e.g. an NUS folder's 5 252; 0 255: every "
                        "node holds the model)")
    p.add_argument("--shaper-size", type=int_range(2, 65536, "the shaper size"),
                   default=4081, metavar="N",
                   help="nodes of the 1D shaper before a 3D LUT (default 4081: 16 per "
                        "8-bit code)")
    p.add_argument("--no-shaper", action="store_true",
                   help="to-raw/render .cube: a 3D-only Adobe cube, no shaper (what "
                        "ffmpeg's lut3d reads alone; coarse in the render's toe)")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing output (file or --ocio folder)")
    p.set_defaults(func=cmd_export, parser=p)
