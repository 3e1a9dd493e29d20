"""``selfcal calibrate`` and ``selfcal demo``: response curves and pipeline models.

Registered on the main parser by :func:`register`; nothing numerical lives here (the work is
:func:`selfcal.calibrate`, which chooses the path, and :func:`selfcal.calibrate_response`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from selfcal.io import format_exposure_time as fmt_time

from . import interrupts
from selfcal.exposure import exposure_message

from .common import (EPILOG, EXIT_OK, add_exposure_flags, check_output_folder, check_outputs,
                     exposure_rule, float_range, int_range, parse_time, progress_bar, say,
                     say_verdict, verdict_of, warn)


def _print_response_summary(model) -> None:
    d = model.diagnostics
    record = model.exposure_record
    origin = {"exif": "EXIF", "given": "--times", "raw": "the raw files' ratios",
              "unknown": "nowhere: solved"}.get(record.origin, record.origin)
    say(f"frames: {len(model.sources)}  (times from {origin}; "
        + ("held as given, --hold-times)" if record.rule == "held"
           else "exposures measured from the pixels; --hold-times keeps the times)"))
    say(f"{'frame':<32} {'given':>10} {'used':>10}  from")
    for f in record.frames:
        say(f"{Path(f.source).name:<32} {fmt_time(f.given):>10} "
            f"{fmt_time(f.used if f.used is not None else float('nan')):>10}  "
            f"{f.used_from if f.used is not None else 'not used'}")
    line = exposure_message(record)
    if line:
        warn(line)
    s = d["samples"]
    rej = ", ".join(f"{k} {v}" for k, v in s["rejected"].items())
    say(f"samples: {s['locations']} locations ({s['block_size']}x{s['block_size']} px blocks), "
         f"{s['pair_rows_used']} pair equations used, {s['pair_rows_downweighted']} "
         f"down-weighted as outliers; rejected pairs: {rej}")
    delta = ", ".join(f"{c} {v:.4f}" for c, v in zip("RGB", d["delta_eq12"]))
    say(f"fit: residual {d['residual_rms_log']:.4f} (log units), δ (Eq. 12): {delta}")
    _say_vignetting_fit(model)
    _, reasons = verdict_of(d)
    for w in d["warnings"]:
        if w not in reasons and not (reasons and all(r in w for r in reasons)):
            warn(w)       # the verdict's reasons are said with it


def _say_vignetting_fit(model) -> None:
    """The vignetting the calibration fitted, or why it fitted none (aligned runs only)."""
    said = model.diagnostics.get("vignetting")
    if model.vignetting is not None:
        stops = " ".join(f"{c} {s:.2f}" for c, s in zip("RGB", model.vignetting.corner_stops()))
        say(f"vignetting: {model.vignetting.description}; corner falloff {stops} stops "
            "(selfcal show --plot draws it)")
    elif isinstance(said, dict) and said.get("reason"):
        say(f"vignetting: not observable: {said['reason']}")


# ------------------------------------------------------------------------- commands

def _pipeline_output_path(out: Path) -> Path:
    return out.with_name(out.stem + ".pipeline" + (out.suffix or ".json"))


def _basis_for(args):
    """The --basis file, loaded (so a bad file is refused before any work), with
    --components checked against its size; None for the built-in basis."""
    import selfcal

    if args.basis is None:
        return None
    from selfcal.response.basis import load_basis_file

    basis = load_basis_file(args.basis)
    if args.components > basis.n_components:
        raise selfcal.InputError(f"has {basis.n_components} components; --components "
                                 f"{args.components} asks for more", args.basis)
    return basis


def _calibrate_outputs(args, groups, images):
    """The outputs (model, plot, RAW-path model) and the inputs they must not replace."""
    out = Path(args.output)
    plot = Path(args.plot) if args.plot else None
    pipeline_out = Path(args.pipeline_output) if args.pipeline_output else None
    if pipeline_out is None and groups.pairs and len(groups.rendered) >= 2:
        pipeline_out = _pipeline_output_path(out)    # both paths may be taken
    inputs = [p for p in images if not p.is_dir()] + sorted(groups.from_folder) + [p for p, _ in groups.pairs] + \
        list(groups.unpaired_raws) + ([Path(args.basis)] if args.basis else [])
    return out, plot, pipeline_out, inputs


def cmd_calibrate(args) -> int:
    import selfcal
    from selfcal.response import SolverOptions
    from selfcal.choose import group_inputs
    from selfcal.io import StagedOutputs

    images = [Path(p) for p in args.images]
    groups = group_inputs(images)
    out, plot, pipeline_out, inputs = _calibrate_outputs(args, groups, images)
    if plot is not None and plot.suffix.lower() != ".png":
        raise selfcal.InputError(f"{plot}: the plot is a .png file")
    check_outputs([out, plot, pipeline_out], inputs, args.force)
    basis = _basis_for(args)
    result = selfcal.calibrate(
        images, exposure_times=args.times, progress=progress_bar("calibrate"),
        exposure_source="unknown" if args.unknown_exposures else "auto",
        exposures=exposure_rule(args), align=args.align or False,
        response_options=selfcal.ResponseOptions(
            solver=SolverOptions(n_components=args.components,
                                 saturation_threshold=args.saturation_threshold),
            basis=basis))
    for line in result.summary_lines():
        say(line)
    if result.response is not None:
        _print_response_summary(result.response)
        say_verdict(result.response.diagnostics, args.force)
    with StagedOutputs(force=args.force, inputs=inputs) as staged:
        if result.response is not None:
            staged.write(out, lambda tmp: result.response.save(tmp, force=True))
            if plot is not None:
                from selfcal.report import plot_response

                staged.write(plot, lambda tmp: plot_response(result.response, tmp,
                                                              force=True))
        if result.pipeline is not None:
            target = out if result.response is None else \
                (pipeline_out or _pipeline_output_path(out))
            staged.write(target, lambda tmp: result.pipeline.save(tmp, force=True))
        interrupts.check()
    interrupts.committed()
    for path in staged.written:
        say(f"wrote {path}")
    return EXIT_OK


def cmd_demo(args) -> int:
    import numpy as np

    import selfcal
    from selfcal import sim
    from selfcal.report import plot_response

    out = Path(args.output)
    check_output_folder(out)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise selfcal.OutputExistsError(
            f"{out}: exists and is not empty (use --force to overwrite its files)")
    check_outputs([out / "model.json", out / "response.png"], [], args.force,
                  create_folder=True)
    created = [d for d in (out, *out.parents) if not d.exists()]   # made here, deepest first
    before = set(out.iterdir()) if out.exists() else set()
    try:
        stack = sim.demo_stack(seed=args.seed)
        paths = stack.write(out, force=args.force)
        say(f"simulated a {len(paths)}-frame bracketed JPEG stack "
            f"({', '.join(fmt_time(t) for t in stack.exposure_times)} s, ±3% shutter "
            f"jitter) -> {out}/")
        model = selfcal.calibrate_response(paths, progress=progress_bar("calibrate"))
        model_path = out / "model.json"
        plot_path = out / "response.png"
        truth = stack.inverse_response()
        from selfcal.io import StagedOutputs

        with StagedOutputs(force=args.force, inputs=paths) as staged:
            staged.write(model_path, lambda tmp: model.save(tmp, force=True))
            staged.write(plot_path, lambda tmp: plot_response(model, tmp, truth=truth,
                                                              force=True))
            interrupts.check()
    except BaseException:
        # nothing new left behind: the frames written, and the folder if it was made here
        for p in (set(out.iterdir()) if out.exists() else set()) - before:
            p.unlink(missing_ok=True)
        for folder in created:
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        raise
    interrupts.committed()
    _print_response_summary(model)
    say_verdict(model.diagnostics, True)
    say(f"wrote {model_path}")
    say(f"wrote {plot_path}")
    est = model.inverse_response()
    codes = slice(1, stack.max_code)
    rmse = np.sqrt(np.mean((est[codes] - truth[codes]) ** 2, axis=0))
    say("error against the simulator's truth, RMSE of f⁻¹ over codes 1..254: "
         + ", ".join(f"{c} {v:.4f}" for c, v in zip("RGB", rmse)))
    exp_err = np.abs(model.exposures / stack.true_exposures - 1)
    say(f"exposures: largest error against the true (jittered) exposures {100 * exp_err.max():.1f}% "
         "(measured from the pixels through the curve, the EXIF times keeping their scale and "
         "trend; calibrate --hold-times uses the times as they are)")
    return EXIT_OK


# ------------------------------------------------------------------------- parser

def _max_components() -> int:
    """The built-in basis's size (a --basis file is checked against its own)."""
    from selfcal.response.basis import builtin_basis

    return builtin_basis().n_components


def _seed(text: str) -> int:
    """``--seed``: a non-negative whole number (the simulator's numpy seed)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"the seed must be a whole number from 0, not "
                                         f"{text!r}")
    return value


def register(sub) -> None:
    """Add the ``demo`` and ``calibrate`` commands to the main parser's subparsers."""
    from selfcal.response.solver import DEFAULT_N_COMPONENTS
    from selfcal.response.solver import DEFAULT_SATURATION_THRESHOLD

    p = sub.add_parser(
        "demo", help="simulate a bracketed stack, calibrate it, report the error",
        description="Simulate a bracketed JPEG stack with the camera simulator, calibrate "
                    "its response from the files, and report the error against the truth.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--output", default="selfcal-demo",
                   help="folder for the stack, model and plot (default: %(default)s)")
    p.add_argument("--seed", type=_seed, default=0,
                   help="simulation seed, a whole number from 0 (default 0)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser(
        "calibrate", help="calibrate a camera from a bracketed stack and/or RAW+JPEG pairs",
        description="Calibrate a camera from what is given, choosing the path itself: "
                    "frames at >= 2 exposures -> per-channel response curves (log-PCA "
                    "model, Lin et al. ICCV 2011 §5); RAW+JPEG pairs (same file stem) -> "
                    "the RAW pipeline model (rank-based matrix, tone curves, gamut LUT, "
                    "RBF inverse colour mapping); a bracketed RAW+JPEG session -> both.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("images", nargs="+", metavar="FILE",
                   help="frames of one scene, raw files (paired with the JPEG of the same "
                        "stem), or folders")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json",
                   help="model file to write")
    times = p.add_mutually_exclusive_group()
    times.add_argument("--times", nargs="+", type=parse_time, metavar="T",
                       help="exposure time per image (1/250, 0.004, or ? for unknown); "
                            "default: EXIF")
    times.add_argument("--unknown-exposures", action="store_true",
                       help="ignore EXIF; solve the exposures jointly with the curves")
    add_exposure_flags(p)
    p.add_argument("--align", choices=("mtb", "homography"),
                   help="align handheld frames before calibrating the response: "
                        "translation (median threshold bitmaps) or homography (ECC)")
    p.add_argument("--saturation-threshold", default=DEFAULT_SATURATION_THRESHOLD,
                   type=float_range(0.0, 1.0, "the saturation threshold"), metavar="B",
                   help="reject samples with HSV saturation above B, 0 to 1 "
                        "(default %(default)s)")
    p.add_argument("--components", default=DEFAULT_N_COMPONENTS, metavar="N",
                   type=int_range(1, _max_components, "the number of components"),
                   help="PCA basis functions per channel, 1 to the basis's size (25 for "
                        "the built-in basis; default %(default)s)")
    p.add_argument("--basis", metavar="FILE",
                   help="response basis: invemor.txt (Grossberg-Nayar) or a selfcal .npz")
    p.add_argument("--plot", metavar="PNG", help="write curves and a BTF scatter here")
    p.add_argument("--pipeline-output", metavar="PIPELINE.json",
                   help="where the RAW-path model goes when both paths are taken "
                        "(default: MODEL.pipeline.json)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_calibrate)
