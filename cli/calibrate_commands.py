"""``selfcal calibrate`` and ``selfcal demo``: response curves and pipeline models.

Registered on the main parser by :func:`register`; nothing numerical lives here (the work is
:func:`selfcal.calibrate`, which chooses the path, and :func:`selfcal.calibrate_response`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .common import EPILOG, EXIT_OK, fmt_time, parse_time, progress_bar, say


def _print_response_summary(model, out_path=None) -> None:
    d = model.diagnostics
    say(f"frames: {len(model.sources)}  (times from {d['exposure_source']})")
    say(f"{'frame':<32} {'given':>10} {'estimated':>10}")
    for src, given, est in zip(model.sources, model.exposure_times, model.exposures):
        say(f"{Path(src).name:<32} {fmt_time(given):>10} {fmt_time(float(est)):>10}")
    s = d["samples"]
    rej = ", ".join(f"{k} {v}" for k, v in s["rejected"].items())
    say(f"samples: {s['locations']} locations ({s['block_size']}x{s['block_size']} px blocks), "
         f"{s['pair_rows_used']} pair equations used, {s['pair_rows_downweighted']} "
         f"down-weighted as outliers; rejected pairs: {rej}")
    delta = ", ".join(f"{c} {v:.4f}" for c, v in zip("RGB", d["delta_eq12"]))
    say(f"fit: residual {d['residual_rms_log']:.4f} (log units), δ (Eq. 12): {delta}")
    say(f"verdict: {d['verdict']}")
    for w in d["warnings"]:
        say(f"warning: {w}")
    if out_path is not None:
        say(f"wrote {out_path}")


# ------------------------------------------------------------------------- commands

def _pipeline_output_path(out: Path) -> Path:
    return out.with_name(out.stem + ".pipeline" + (out.suffix or ".json"))


def cmd_calibrate(args) -> int:
    import selfcal

    images = [Path(p) for p in args.images]
    times = args.times
    if args.unknown_exposures and times is not None:
        raise selfcal.InputError("--times and --unknown-exposures contradict each other")
    out = Path(args.output)
    pipeline_out = Path(args.pipeline_output) if args.pipeline_output else \
        _pipeline_output_path(out)
    for target in (out, pipeline_out):
        if any(target.resolve() == p.resolve() for p in images):
            raise selfcal.OutputExistsError(f"{target}: refusing to write over an input file")
    if out.exists() and not args.force:
        raise selfcal.OutputExistsError(f"{out}: exists already (use --force to overwrite)")
    result = selfcal.calibrate(
        images, exposure_times=times, progress=progress_bar("calibrate"),
        exposure_source="unknown" if args.unknown_exposures else "auto",
        refine_exposures=args.refine_exposures, n_components=args.components,
        saturation_threshold=args.saturation_threshold, basis=args.basis,
        **({"align": args.align} if args.align else {}))
    for line in result.summary_lines():
        say(line)
    written = []
    if result.response is not None:
        result.response.save(out, force=args.force)
        written.append(out)
        if args.plot:
            from selfcal.report import plot_response

            plot_response(result.response, args.plot, force=args.force)
            written.append(Path(args.plot))
        _print_response_summary(result.response)
    if result.pipeline is not None:
        target = out if result.response is None else pipeline_out
        result.pipeline.save(target, force=args.force)
        written.append(target)
    for path in written:
        say(f"wrote {path}")
    return EXIT_OK


def cmd_demo(args) -> int:
    import numpy as np

    import selfcal
    from selfcal import synth

    out = Path(args.output)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise selfcal.OutputExistsError(
            f"{out}: exists and is not empty (use --force to overwrite its files)")
    stack = synth.demo_stack(seed=args.seed)
    paths = stack.write(out, force=args.force)
    say(f"simulated a {len(paths)}-frame bracketed JPEG stack "
         f"({', '.join(fmt_time(t) for t in stack.exposure_times)} s, ±3% shutter jitter) "
         f"-> {out}/")
    model = selfcal.calibrate_response(paths, progress=progress_bar("calibrate"))
    model_path = out / "model.json"
    model.save(model_path, force=args.force)
    truth = stack.inverse_response()
    est = model.inverse_response()
    codes = slice(1, stack.max_code)
    rmse = np.sqrt(np.mean((est[codes] - truth[codes]) ** 2, axis=0))
    from selfcal.report import plot_response

    plot_path = out / "response.png"
    plot_response(model, plot_path, truth=truth, force=args.force)
    _print_response_summary(model, model_path)
    say(f"wrote {plot_path}")
    say("error against the simulator's truth, RMSE of f⁻¹ over codes 1..254: "
         + ", ".join(f"{c} {v:.4f}" for c, v in zip("RGB", rmse)))
    exp_err = np.abs(model.exposures / stack.true_exposures - 1)
    say(f"exposures: largest error against the true (jittered) exposures {100 * exp_err.max():.1f}% "
         "(times were fixed at the EXIF values; try --refine-exposures on real stacks)")
    return EXIT_OK


# ------------------------------------------------------------------------- parser

def register(sub) -> None:
    """Add the ``demo`` and ``calibrate`` commands to the main parser's subparsers."""
    from selfcal.response.calibrate import DEFAULT_N_COMPONENTS
    from selfcal.response.solver import DEFAULT_SATURATION_THRESHOLD

    p = sub.add_parser(
        "demo", help="simulate a bracketed stack, calibrate it, report the error",
        description="Simulate a bracketed JPEG stack with the camera simulator, calibrate "
                    "its response from the files, and report the error against the truth.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--output", default="selfcal-demo",
                   help="folder for the stack, model and plot (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
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
    p.add_argument("--times", nargs="+", type=parse_time, metavar="T",
                   help="exposure time per image (1/250, 0.004, or ? for unknown); "
                        "default: EXIF")
    p.add_argument("--unknown-exposures", action="store_true",
                   help="ignore EXIF; solve the exposures jointly with the curves")
    p.add_argument("--refine-exposures", action="store_true",
                   help="treat the given times as a prior and re-estimate them")
    p.add_argument("--align", choices=("mtb", "homography"),
                   help="align handheld frames before calibrating the response: "
                        "translation (median threshold bitmaps) or homography (ECC)")
    p.add_argument("--saturation-threshold", type=float,
                   default=DEFAULT_SATURATION_THRESHOLD, metavar="B",
                   help="reject samples with HSV saturation above B (default %(default)s)")
    p.add_argument("--components", type=int, default=DEFAULT_N_COMPONENTS, metavar="N",
                   help="PCA basis functions per channel (default %(default)s)")
    p.add_argument("--basis", metavar="FILE",
                   help="response basis: invemor.txt (Grossberg-Nayar) or a selfcal .npz")
    p.add_argument("--plot", metavar="PNG", help="write curves and a BTF scatter here")
    p.add_argument("--pipeline-output", metavar="PIPELINE.json",
                   help="where the RAW-path model goes when both paths are taken "
                        "(default: MODEL.pipeline.json)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=cmd_calibrate)
