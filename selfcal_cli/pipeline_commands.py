"""``selfcal to-raw`` and ``selfcal render``: apply a RAW-path model to many files.

Nothing numerical lives here: the conversion is :meth:`selfcal.pipeline.PipelineModel.to_raw`
and :meth:`~selfcal.pipeline.PipelineModel.render`.  Both warn, naming the file, when more
than :data:`WARN_OUTSIDE` of its pixels lie outside the colours the model was trained on
(their ``return_mask``): there the model extrapolates, and across scenes its error is
several times larger (``python3 -m bench.pipeline_crossscene``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from . import interrupts
from .common import (EPILOG, EXIT_OK, check_output_folder, check_outputs, int_range, say,
                     warn)

#: Share of a file's pixels outside the model's training colours above which the command
#: warns (the mask is :meth:`selfcal.pipeline.PipelineModel.outside_training`; ours).
#: A few stray pixels (noise, an edge) do not warn.  The training picture itself may: its
#: clipped and high-gradient blocks are not samples (fixtures/pair: 23 % of its JPEG).
WARN_OUTSIDE = 0.01


def _load_pipeline(path):
    import selfcal

    model = selfcal.load_model(path)
    if not hasattr(model, "to_raw"):
        raise selfcal.InputError(
            "is a response model; to-raw and render need a RAW-path (pipeline) model "
            "from RAW+JPEG pairs", path)
    return model


def _outputs(inputs, folder: Path, suffix: str, force: bool, model_path):
    """Output path per input (same stem), checked before any work starts."""
    import selfcal

    check_output_folder(folder)
    outs = [folder / (Path(p).stem + suffix) for p in inputs]
    seen = {}
    for src, out in zip(inputs, outs):
        if out in seen:
            raise selfcal.InputError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
    check_outputs(outs, [*inputs, model_path], force, create_folder=True)
    for src in inputs:
        if not Path(src).is_file():
            raise selfcal.InputError("no such file" if not Path(src).exists() else
                                     "not a file", src)
    return outs


def _convert_files(args, inputs, suffix: str, desc: str, convert) -> list:
    """Check every output, load the model, then ``convert(model, src, tmp)`` per file into
    temporary files that become the outputs together at the end (none on a failure).

    ``convert`` returns a warning about the file or None; the warnings are said at the end.
    """
    from tqdm import tqdm

    from selfcal.io import StagedOutputs

    outs = _outputs(inputs, Path(args.output), suffix, args.force, args.model)
    model = _load_pipeline(args.model)
    said = []
    with StagedOutputs(force=args.force, inputs=[*inputs, args.model]) as staged:
        for src, out in tqdm(list(zip(inputs, outs)), desc=desc, unit="image",
                             disable=None, leave=False):
            said.append(staged.write(out, lambda tmp, src=src: convert(model, src, tmp)))
        interrupts.check()
    interrupts.committed()
    for w in said:
        if w is not None:
            warn(w)
    return outs


def _outside_warning(src, mask, kind: str) -> str | None:
    """The warning for a file whose pixels lie outside the model's training colours (None:
    no warning; models saved before the training colours were kept give no mask)."""
    if mask is None or mask.size == 0:
        return None
    share = float(mask.mean())
    if share < WARN_OUTSIDE:
        return None
    return (f"{src}: {100 * share:.1f} % of its pixels have {kind} colours outside those the "
            f"model was trained on, so the conversion there is a guess (calibrate with a "
            f"pair that shows such colours)")


def cmd_to_raw(args) -> int:
    from selfcal.hdr.io import write_linear
    from selfcal.io import read_image

    def convert(model, src, out):
        raw, mask = model.to_raw(read_image(src), return_mask=True)
        write_linear(out, raw, float32=args.float, force=True)
        return _outside_warning(src, mask, "rendered")

    outs = _convert_files(args, args.images, ".tiff", "to-raw", convert)
    say(f"wrote {len(outs)} linear camera-raw TIFF{'s' if len(outs) != 1 else ''} "
         f"({'float32' if args.float else '16-bit'}) to {Path(args.output)}/")
    return EXIT_OK


def cmd_render(args) -> int:
    import numpy as np

    from selfcal.io import write_image
    from selfcal.io.raw import read_raw_linear

    def convert(model, src, out):
        rendered, mask = model.render(read_raw_linear(src).rgb, return_mask=True)
        codes = np.clip(np.round(rendered * 255.0), 0, 255).astype(np.uint8)
        write_image(out, codes, jpeg_quality=args.quality, force=True)
        return _outside_warning(src, mask, "raw")

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
                    "better. Writes one linear TIFF per input, named after it, and warns when more "
                    "than 1 % of a file's pixels lie outside the model's training colours.",
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
                    "balance, black and white levels from the file). Warns when more than 1 % of a "
                    "file's pixels lie outside the model's training colours.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="PIPELINE.json")
    p.add_argument("raws", nargs="+", metavar="RAW")
    p.add_argument("-o", "--output", required=True, metavar="DIR")
    p.add_argument("--quality", type=int_range(1, 100, "the JPEG quality"), default=95,
                   help="JPEG quality, 1 to 100 (default 95)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_render)
