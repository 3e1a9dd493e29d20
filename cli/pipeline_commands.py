"""``selfcal to-raw`` and ``selfcal render``: apply a RAW-path model to many files.

Nothing numerical lives here: the conversion is :meth:`selfcal.pipeline.PipelineModel.to_raw`
and :meth:`~selfcal.pipeline.PipelineModel.render`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import EPILOG, EXIT_OK, say


def _load_pipeline(path):
    import selfcal

    model = selfcal.load_model(path)
    if not hasattr(model, "to_raw"):
        raise selfcal.InputError(
            "is a response model; to-raw and render need a RAW-path (pipeline) model "
            "from RAW+JPEG pairs", path)
    return model


def _outputs(inputs, folder: Path, suffix: str, force: bool):
    """Output path per input (same stem), checked before any work starts."""
    import selfcal

    outs = [folder / (Path(p).stem + suffix) for p in inputs]
    seen = {}
    for src, out in zip(inputs, outs):
        if out in seen:
            raise selfcal.InputError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
        if out.exists() and not force:
            raise selfcal.OutputExistsError(f"{out}: exists already (use --force to overwrite)")
    return outs


def _convert_files(args, inputs, suffix: str, desc: str, convert) -> list:
    """Load the model, check every output, then ``convert(model, src, out)`` per file."""
    from tqdm import tqdm

    model = _load_pipeline(args.model)
    outs = _outputs(inputs, Path(args.output), suffix, args.force)
    for src, out in tqdm(list(zip(inputs, outs)), desc=desc, unit="image", disable=None,
                         leave=False):
        convert(model, src, out)
    return outs


def cmd_to_raw(args) -> int:
    from selfcal.hdr.io import write_linear
    from selfcal.io import read_image

    def convert(model, src, out):
        write_linear(out, model.to_raw(read_image(src)), float32=args.float,
                     force=args.force, inputs=args.images)

    outs = _convert_files(args, args.images, ".tiff", "to-raw", convert)
    say(f"wrote {len(outs)} linear camera-raw TIFF{'s' if len(outs) != 1 else ''} "
         f"({'float32' if args.float else '16-bit'}) to {Path(args.output)}/")
    return EXIT_OK


def cmd_render(args) -> int:
    import numpy as np

    from selfcal.io import write_image
    from selfcal.raw import read_raw_linear

    def convert(model, src, out):
        rendered = model.render(read_raw_linear(src).rgb)
        codes = np.clip(np.round(rendered * 255.0), 0, 255).astype(np.uint8)
        write_image(out, codes, jpeg_quality=args.quality, force=args.force,
                    inputs=args.raws)

    outs = _convert_files(args, args.raws, ".jpg", "render", convert)
    say(f"wrote {len(outs)} rendered JPEG{'s' if len(outs) != 1 else ''} to "
         f"{Path(args.output)}/")
    return EXIT_OK


def register(sub) -> None:
    """Add ``to-raw`` and ``render`` to the ``selfcal`` sub-command parser."""
    p = sub.add_parser(
        "to-raw", help="convert rendered images (JPEG) to linear camera raw with a model",
        description="JPEG -> raw with a RAW-path model: E = M⁻¹ h⁻¹(f⁻¹(P)) (Lin et al. "
                    "ICCV 2011 Eq. 11) or the backward lattice LUT, whichever validated "
                    "better. Writes one linear TIFF per input, named after it.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="PIPELINE.json")
    p.add_argument("images", nargs="+", metavar="IMAGE")
    p.add_argument("-o", "--output", required=True, metavar="DIR")
    p.add_argument("--float", action="store_true", help="float32 TIFF instead of 16-bit")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_to_raw)

    p = sub.add_parser(
        "render", help="render raw files as the camera would, with a model",
        description="raw -> JPEG with a RAW-path model: P = f(g⁻¹(LUT(g(M ρ)))) (rank-based "
                    "calibration, §3). Raw files are read as linear camera RGB (no white "
                    "balance, black and white levels from the file).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="PIPELINE.json")
    p.add_argument("raws", nargs="+", metavar="RAW")
    p.add_argument("-o", "--output", required=True, metavar="DIR")
    p.add_argument("--quality", type=int, default=95, help="JPEG quality (default 95)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_render)
