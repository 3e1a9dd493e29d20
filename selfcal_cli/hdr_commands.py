"""``selfcal merge`` and ``selfcal linearize``: radiance maps and linear images.

Registered on the main parser by :func:`register`; nothing numerical lives here (the work
is :func:`selfcal.merge_hdr`, :func:`selfcal.hdr.linearize_images` and
:mod:`selfcal.hdr.io`).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from . import interrupts
from .common import (EPILOG, EXIT_OK, add_exposure_flags, add_vignetting_argument,
                     exposure_rule, say_vignetting,
                     vignetting_argument, check_output_folder, check_outputs, parse_time,
                     progress_bar, say, say_verdict, warn)

RADIANCE_FORMATS = ".exr (OpenEXR), .hdr (Radiance RGBE), .tif (float32 TIFF)"


# ------------------------------------------------------------------------- merge

def cmd_merge(args) -> int:
    import selfcal
    from selfcal.hdr import MergeOptions, merge_hdr
    from selfcal.hdr.io import RADIANCE_SUFFIXES, sigma_path, write_preview
    from selfcal.io import StagedOutputs

    images = [Path(p) for p in args.images]
    out = Path(args.output)
    if out.suffix.lower() not in RADIANCE_SUFFIXES:
        raise selfcal.InputError(f"{out}: unsupported radiance format {out.suffix!r} "
                                 f"(use {RADIANCE_FORMATS})")
    if args.preview and Path(args.preview).suffix.lower() not in (".jpg", ".jpeg", ".png"):
        raise selfcal.InputError(f"{args.preview}: the preview is a .jpg or .png")
    if args.times is not None and len(args.times) != len(images):
        raise selfcal.InputError(f"--times gives {len(args.times)} values for "
                                 f"{len(images)} images")
    vignetting = vignetting_argument(args.vignetting)
    inputs = images + ([Path(args.model)] if args.model else []) + (
        [vignetting] if isinstance(vignetting, Path) else [])
    sig_out = (sigma_path(out) if args.sigma and out.suffix.lower() != ".exr" else None)
    _check_luminance_arguments(args, images)
    check_outputs([out, args.preview, sig_out, args.falsecolor, args.save_scale], inputs,
                  args.force)
    for p in images:
        if not p.is_file():
            raise selfcal.InputError("no such file" if not p.exists() else "not a file", p)
    if args.reference is not None and not 0 <= args.reference < len(images):
        raise selfcal.InputError(f"--reference {args.reference} is out of range for "
                                 f"{len(images)} images (0 to {len(images) - 1})")
    model = selfcal.load_model(args.model) if args.model else None
    luminance = _luminance_option(args, images, model)
    if not args.linear and model is None:
        if len(images) == 1:
            raise selfcal.CalibrationError(
                f"{images[0]}: one frame and no model: give --model (a response needs at "
                "least two frames to calibrate), or --linear for a linear image")

    result = merge_hdr(images, args.times, model, weighting=args.weighting,
                       align=args.align or False, deghost=args.deghost, linear=args.linear,
                       options=MergeOptions(reference=args.reference,
                                            exposures=exposure_rule(args),
                                            sigma=args.sigma,
                                            vignetting=vignetting,
                                            luminance=luminance),
                       progress=progress_bar("merge"))
    args.linear = args.linear or "linear_evidence" in result.diagnostics
    if model is None and not args.linear:
        say_verdict(getattr(result.model, "diagnostics", None) or
                    {"verdict": result.diagnostics.get("model_verdict")},
                    args.force, "the response calibrated on the fly")
    with StagedOutputs(force=args.force, inputs=inputs) as staged:
        written = _stage_radiance(staged, result, out, sig_out, args)
        if args.preview:
            staged.write(args.preview, lambda tmp: write_preview(
                tmp, result.radiance, force=True, mask=~result.unmeasured))
        _stage_luminance_outputs(staged, result, args)
        # the summary before the outputs appear: their renaming is the last of the work
        for line in _merge_summary(result, images, args):
            say(line)
        say_vignetting(result.diagnostics.get("vignetting"))
        for w in result.warnings:
            warn(w)
        interrupts.check()
    interrupts.committed()
    _say_written(result, written, out, sig_out, args)
    return EXIT_OK


def _merge_summary(result, images, args) -> list:
    """What ``selfcal merge`` says about a merge, as lines: the exposures and where they
    came from, each frame's share and shift, the radiance range and the unmeasured
    pixels."""
    import numpy as np

    lines: list = []
    say = lines.append

    how = ("linear input" if args.linear else
           f"model from {args.model}" if args.model else "model calibrated on the fly")
    record = result.exposure_record
    origin = {"exif": "EXIF t·ISO/100/N²", "given": "the given times", "raw": "the raw files",
              "unknown": "no times"}.get(record.origin, record.origin)
    unit = {"measured": "measured from the pixels (a relative scale)"
            if record.origin == "unknown" else
            f"measured from the pixels, on the scale of {origin}",
            "solved": f"{origin}, the model's solve where it had no time",
            "given": f"{origin}, held" if record.rule == "held" else origin}[record.used_from]
    say(f"frames: {len(images)}  ({how}; exposure e = {unit})")
    say(f"{'frame':<32} {'e':>10} {'used':>7}" + ("  shift" if result.transforms else "")
        + "  given     moved  from")
    used = result.diagnostics.get("frame_used_fraction", [])
    for k, (src, e) in enumerate(zip(result.sources, result.exposures)):
        mark = " (reference)" if k == result.reference else ""
        line = f"{Path(src).name:<32} {float(e):>10.4g} {100 * used[k]:6.1f}%"
        if result.transforms is not None:
            t = result.transforms[k]
            line += f"  {-t[0, 2]:+.1f},{-t[1, 2]:+.1f} px"
        f = record.frames[k]
        line += (f"  {f.given:<9.4g} {100 * f.moved:+5.1f}%" if f.given is not None
                 else f"  {'-':<9} {'':>6}") + f"  {f.used_from}"
        say(line + mark)
    rad = result.radiance
    measured = ~result.unmeasured
    if measured.any():
        lum = rad[measured] @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        lum = lum[lum > 0]
        if lum.size:
            lo, hi = np.percentile(lum, [0.1, 99.9])
            say(f"radiance: {rad.shape[1]}x{rad.shape[0]}, luminance {lo:.4g} .. {hi:.4g} "
                 f"(0.1-99.9%), {np.log2(hi / max(lo, 1e-30)):.1f} stops; "
                + ("cd/m²" if result.units == "cd/m2" else "1 = white at e = 1"))
    lum = result.diagnostics.get("luminance")
    if lum:
        say(f"luminance scale: {lum['scale']:.4g} cd/m² per unit of relative radiance, "
            f"±{100 * math.expm1(lum['total_log_sigma']):.2g}% (1σ); "
            f"{lum['source']}: {lum['description']}")
    say(f"unmeasured (clipped in every frame): {100 * result.unmeasured.mean():.2f}% of "
         "pixels" + (f"; deghosted: {100 * result.ghost.mean():.2f}%" if args.deghost else ""))
    return lines


def _say_written(result, written, out, sig_out, args) -> None:
    """The summary's last lines: the files written (and the σ with ``--sigma``)."""
    say(f"wrote {out}" + ("" if written.scale == 1 else
                          f" (half floats scaled into range: stored values x {written.scale:g}"
                          " = radiance; the factor is recorded in the file as"
                          " selfcalRadianceScale)"))
    if args.sigma:
        _say_sigma(result, out, sig_out)
    if args.preview:
        say(f"wrote {args.preview}")
    if args.falsecolor:
        say(f"wrote {args.falsecolor} (false-colour luminance, log scale)")
    if args.save_scale:
        say(f"wrote {args.save_scale} (the response model with this luminance scale: later "
            "merges with --model apply it)")


# ------------------------------------------------------------------------- linearize

def cmd_linearize(args) -> int:
    import selfcal
    from selfcal.hdr import linearize_images
    from selfcal.hdr.io import write_linear
    from selfcal.io import StagedOutputs, read_exposure_info

    images = [Path(p) for p in args.images]
    folder = Path(args.output)
    check_output_folder(folder)
    outputs = [folder / (p.stem + ".tif") for p in images]
    names = {}
    for p, o in zip(images, outputs):
        if o.name in names:
            raise selfcal.InputError(f"{p}: would be written to the same file as {names[o.name]}"
                                     f" ({o})")
        names[o.name] = p
    vignetting = vignetting_argument(args.vignetting)
    inputs = images + [Path(args.model)] + ([vignetting] if isinstance(vignetting, Path)
                                            else [])
    check_outputs(outputs, inputs, args.force, create_folder=True)
    for p in images:
        if not p.is_file():
            raise selfcal.InputError("no such file" if not p.exists() else "not a file", p)
    model = selfcal.load_model(args.model)
    bar = progress_bar("linearize")
    with StagedOutputs(force=args.force, inputs=inputs) as staged:
        records: list = []
        for (src, linear), o in zip(linearize_images(images, model, vignetting=vignetting,
                                                     records=records, progress=bar),
                                    outputs):
            info = read_exposure_info(src)
            staged.write(o, lambda tmp, linear=linear: write_linear(
                tmp, linear, float32=args.float, force=True,
                exposure_time=info.exposure_time, f_number=info.f_number, iso=info.iso))
            del linear
        interrupts.check()
    interrupts.committed()
    written = staged.written
    kind = "float32" if args.float else "16-bit"
    say(f"linearised {len(written)} images with {args.model} ({kind} linear TIFF, "
         "f⁻¹(max code) = 1, EXIF exposure tags kept) -> " + f"{folder}/")
    for record in records:
        say_vignetting(record, frame=Path(record["frame"]).name)
    for o in written:
        say(f"wrote {o}")
    return EXIT_OK


# ------------------------------------------------------------------------- parser

def _stage_radiance(staged, result, out, sig_out, args):
    """Stage the radiance file (with its sigma layer for an EXR with ``--sigma``) and, for
    other formats with ``--sigma``, ``OUT.sigma.tiff``; returns the RadianceFile."""
    from selfcal.hdr.io import write_radiance, write_radiance_sigma, write_sigma_tiff

    if args.sigma and sig_out is None:           # EXR: a sigma layer
        written = staged.write(out, lambda tmp: write_radiance_sigma(
            tmp, result.radiance, result.sigma, force=True, half=args.half,
            units=result.units)[0])
    else:
        written = staged.write(out, lambda tmp: write_radiance(
            tmp, result.radiance, force=True, half=args.half, units=result.units))
    if sig_out is not None:                        # TIFF (or RGBE): OUT.sigma.tiff
        staged.write(sig_out, lambda tmp: write_sigma_tiff(
            tmp, result.sigma, scale=written.scale, half=args.half, force=True))
    return written


def _parse_reading(text: str):
    """``--reading``: a :class:`selfcal.lens.ReferenceReading` (the meter accuracy is set
    later from ``--meter-accuracy``)."""
    from selfcal.errors import InputError
    from selfcal.lens.luminance import parse_reference

    try:
        return parse_reference(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _percent(text: str) -> float:
    """``--meter-accuracy``: a percentage in [0, 100)."""
    try:
        value = float(text.rstrip("%"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a percentage") from None
    if not (math.isfinite(value) and 0 <= value < 100):
        raise argparse.ArgumentTypeError(f"{text!r} must be in [0, 100) percent")
    return value


def _check_luminance_arguments(args, images) -> None:
    """The absolute-luminance arguments, before any work: usage errors (exit 2) naming them."""
    from selfcal.io import read_exposure_info

    err = args.parser.error
    if args.falsecolor and Path(args.falsecolor).suffix.lower() != ".png":
        err(f"argument --falsecolor: the picture is a .png, not {args.falsecolor!r}")
    if args.save_scale and Path(args.save_scale).suffix.lower() != ".json":
        err(f"argument --save-scale: a model file (.json), not {args.save_scale!r}")
    if args.reading is not None and args.luminance not in ("auto",):
        err(f"argument --reading: sets the scale itself; not with --luminance "
            f"{args.luminance}")
    if args.save_scale and (args.linear or args.luminance in ("none", "model")
                            or (args.reading is None and args.luminance != "exif")):
        err("argument --save-scale: needs a scale to save (--reading, or --luminance exif) "
            "and a response model (not --linear)")
    if args.luminance == "exif":
        if args.times is not None:
            err("argument --luminance: exif needs the EXIF exposures (time, f-number, ISO), "
                "not --times")
        info = read_exposure_info(images[0]) if images[0].is_file() else None
        if info is not None and info.exposure_time is None:
            err(f"argument --luminance: exif, but {images[0]} has no EXIF exposure time")
    if args.luminance == "model" and not args.model:
        err("argument --luminance: model needs --model (a model holding a luminance scale)")
    if args.reading is not None:
        size = _image_size(images[0])
        x0, y0, x1, y1 = args.reading.region
        if size is not None and (x1 > size[0] or y1 > size[1]):
            err(f"argument --reading: region {x0},{y0},{x1},{y1} lies outside the "
                f"{size[0]}x{size[1]} frames")


def _image_size(path):
    """(width, height) of an image file from its header (Pillow), None if unreadable."""
    try:
        from PIL import Image

        with Image.open(path) as im:
            return im.size
    except Exception:       # raws and odd files: the merge names them later
        return None


def _luminance_option(args, images, model):
    """``MergeOptions.luminance`` from ``--luminance``, ``--reading``, ``--meter-accuracy``
    and the model (``auto``: the model's stored scale when it has one)."""
    import dataclasses

    if args.reading is not None:
        return dataclasses.replace(args.reading, accuracy=args.meter_accuracy / 100.0)
    has = getattr(model, "luminance", None) is not None
    if args.luminance == "model" and not has:
        args.parser.error(f"argument --luminance: model, but {args.model} holds no "
                          "luminance scale (save one with --reading ... --save-scale)")
    if args.luminance == "auto":
        return "model" if has else None
    return {"none": None, "exif": "exif", "model": "model"}[args.luminance]


def _stage_luminance_outputs(staged, result, args) -> None:
    """Stage ``--falsecolor`` and ``--save-scale`` (the model with the merge's scale)."""
    import dataclasses

    from selfcal.lens import LuminanceScale
    from selfcal.report.falsecolor import write_falsecolor

    if args.falsecolor:
        staged.write(args.falsecolor, lambda tmp: write_falsecolor(
            tmp, result.radiance, units=result.units, mask=result.unmeasured, force=True))
    if args.save_scale:
        from selfcal.errors import InputError
        from selfcal.response.model import ResponseModel

        lum = result.diagnostics.get("luminance")
        if lum is None or not isinstance(result.model, ResponseModel):
            raise InputError("--save-scale: this merge has no response model to hold "
                             "the scale (linear frames, or a RAW-path model)")
        model = dataclasses.replace(result.model, luminance=LuminanceScale.from_dict(lum))
        staged.write(args.save_scale, lambda tmp: model.save(tmp, force=True))


def _say_sigma(result, out, sig_out) -> None:
    """The summary line of ``--sigma``."""
    import numpy as np

    measured = ~result.unmeasured
    rel = result.sigma[measured] / np.maximum(result.radiance[measured], 1e-30)
    rel = rel[np.isfinite(rel)]
    say(f"sigma: median {100 * float(np.median(rel)) if rel.size else float('nan'):.2g}% "
        "of the radiance (noise, exposures"
        + (", curve band" if result.diagnostics.get("sigma_curve_band") else
           "; the model has no curve band") + "); +inf where unmeasured; "
        + (f"wrote {sig_out}" if sig_out is not None else
           f"in {out.name}'s sigma layer (sigma.R, sigma.G, sigma.B)"))


def register(subparsers) -> None:
    """Add the ``merge`` and ``linearize`` commands to the main parser's subparsers."""
    p = subparsers.add_parser(
        "merge", help="merge a bracketed stack into an HDR radiance map",
        description="Merge a bracketed exposure stack into a radiance map: the weighted mean "
                    "of f⁻¹(I)/t (Debevec & Malik 1997) with clipped pixels given no weight; "
                    f"output {RADIANCE_FORMATS}.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", metavar="IMAGE", help="frames of one scene")
    p.add_argument("-o", "--output", required=True, metavar="OUT.exr",
                   help="radiance map to write (.exr, .hdr or .tif)")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--model", metavar="MODEL.json",
                      help="response model (default: calibrate on these frames)")
    p.add_argument("--times", nargs="+", type=parse_time, metavar="T",
                   help="exposure time per image (1/250, 0.004, or ? for unknown); "
                        "default: EXIF (time, f-number and ISO)")
    p.add_argument("--align", choices=("mtb", "homography"),
                   help="align handheld frames to the reference: translation (median "
                        "threshold bitmaps) or homography (ECC)")
    p.add_argument("--deghost", action="store_true",
                   help="exclude frames that disagree with the reference frame (moving things)")
    p.add_argument("--weighting", choices=("noise", "hat"), default="noise",
                   help="noise: inverse variance of each frame's radiance under a noise "
                        "model (Granados 2010); hat: Debevec's triangle (default %(default)s)")
    kind.add_argument("--linear", action="store_true",
                      help="the images are linear already (e.g. from selfcal linearize or "
                           "a raw converter; raw files and TIFFs found linear are merged "
                           "so without it); no response model")
    add_exposure_flags(p)
    p.add_argument("--reference", type=int, metavar="K",
                   help="index of the reference frame (default: the middle exposure)")
    add_vignetting_argument(p)
    p.add_argument("--half", action="store_true",
                   help="16-bit half floats (EXR, TIFF); values beyond half range are "
                        "stored divided by a power of two, recorded in the file "
                        "(selfcalRadianceScale) and said in the summary")
    p.add_argument("--sigma", action="store_true",
                   help="also write each value's standard deviation (noise model, exposure "
                        "uncertainty, the curve's confidence band): a 'sigma' layer of the "
                        "EXR (sigma.R, sigma.G, sigma.B), or OUT.sigma.tiff beside a TIFF "
                        "or RGBE output; +inf where no frame measured the pixel")
    p.add_argument("--preview", metavar="PREVIEW.jpg",
                   help="also write a tone-mapped preview (Reinhard global operator)")
    p.add_argument("--luminance", choices=("auto", "exif", "model", "none"), default="auto",
                   help="absolute luminance (cd/m²): exif = the ISO 12232 standard output "
                        "sensitivity convention from the EXIF time, f-number and ISO "
                        "(±1/3 stop); model = the scale stored in --model; none = relative; "
                        "auto (default) = --reading if given, else the model's scale if it "
                        "has one, else relative")
    p.add_argument("--reading", type=_parse_reading, metavar="SPEC",
                   help="a luminance measured in the scene, over a region x0,y0,x1,y1 of "
                        "the frames (pixels, x1 and y1 exclusive): 'x0,y0,x1,y1=120cd/m2' "
                        "(a spot meter) or 'card:0.18@500lux:x0,y0,x1,y1' (a grey card of "
                        "reflectance 0.18 under 500 lux: L = 0.18*500/pi)")
    p.add_argument("--meter-accuracy", type=_percent, default=3.0, metavar="PCT",
                   help="the meter's accuracy, one sigma in percent (default %(default)g)")
    p.add_argument("--save-scale", metavar="MODEL.json",
                   help="also write the response model with this merge's luminance scale, "
                        "so later merges with --model MODEL.json come out in cd/m²")
    p.add_argument("--falsecolor", metavar="FILE.png",
                   help="also write the luminance in false colour with a log-scale legend "
                        "(cd/m² when absolute)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_merge, parser=p)

    p = subparsers.add_parser(
        "linearize", help="write linearised (f⁻¹) images with a response model",
        description="Apply a model's inverse response to each image and write linear "
                    "16-bit (default) or float32 TIFFs, one per input, named after it.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", metavar="IMAGE", help="images to linearise")
    p.add_argument("--model", required=True, metavar="MODEL.json", help="response model")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="folder for the linear TIFFs (created if missing)")
    p.add_argument("--float", action="store_true", help="float32 TIFF instead of 16-bit")
    add_vignetting_argument(p)
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_linearize)

