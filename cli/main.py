"""The ``selfcal`` command line: argument parsing, progress bars, messages, exit codes.

Nothing numerical lives here; every command calls the library.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from fractions import Fraction
from pathlib import Path

EXIT_OK = 0
EXIT_USAGE = 2          # argparse's own code for bad arguments
EXIT_INPUT = 3          # an input file or value is bad
EXIT_CALIBRATION = 4    # the data cannot determine what was asked
EXIT_OUTPUT = 5         # an output exists (use --force) or cannot be written

EPILOG = """exit codes: 0 success, 2 bad arguments, 3 bad input (file or value),
4 the data cannot be calibrated, 5 output exists or cannot be written."""


def _say(msg: str = "") -> None:
    print(msg, file=sys.stderr)


def _parse_time(text: str) -> float | None:
    """'1/250', '0.004', '2' -> seconds; '?' or 'none' -> unknown."""
    t = text.strip().lower()
    if t in ("?", "none", "unknown", "-"):
        return None
    try:
        value = float(Fraction(t))
    except (ValueError, ZeroDivisionError):
        raise argparse.ArgumentTypeError(
            f"exposure time {text!r} is not a number like 1/250, 0.004 or '?'") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"exposure time {text!r} must be positive")
    return value


def _progress_bar(desc: str):
    """A tqdm progress callback for the library's ``progress(stage, done, total, detail)``."""
    from tqdm import tqdm

    bars = {}

    def callback(stage, done, total, detail=""):
        bar = bars.get(stage)
        if bar is None:
            bar = bars[stage] = tqdm(total=total, desc=f"{desc}: {stage}", unit="frame"
                                     if stage == "read" else "step", file=sys.stderr,
                                     leave=False, disable=None)
        bar.n = done
        if detail:
            bar.set_postfix_str(Path(str(detail)).name, refresh=False)
        bar.refresh()
        if done >= total:
            bar.close()

    return callback


def _fmt_time(t) -> str:
    if t is None or (isinstance(t, float) and not math.isfinite(t)):
        return "?"
    if t < 1:
        return f"1/{1 / t:.4g}"
    return f"{t:.4g}"


def _print_response_summary(model, out_path=None) -> None:
    d = model.diagnostics
    _say(f"frames: {len(model.sources)}  (times from {d['exposure_source']})")
    _say(f"{'frame':<32} {'given':>10} {'estimated':>10}")
    for src, given, est in zip(model.sources, model.exposure_times, model.exposures):
        _say(f"{Path(src).name:<32} {_fmt_time(given):>10} {_fmt_time(float(est)):>10}")
    s = d["samples"]
    rej = ", ".join(f"{k} {v}" for k, v in s["rejected"].items())
    _say(f"samples: {s['locations']} locations ({s['block_size']}x{s['block_size']} px blocks), "
         f"{s['pair_rows_used']} pair equations used, {s['pair_rows_downweighted']} "
         f"down-weighted as outliers; rejected pairs: {rej}")
    delta = ", ".join(f"{c} {v:.4f}" for c, v in zip("RGB", d["delta_eq12"]))
    _say(f"fit: residual {d['residual_rms_log']:.4f} (log units), δ (Eq. 12): {delta}")
    _say(f"verdict: {d['verdict']}")
    for w in d["warnings"]:
        _say(f"warning: {w}")
    if out_path is not None:
        _say(f"wrote {out_path}")


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
        images, exposure_times=times, progress=_progress_bar("calibrate"),
        exposure_source="unknown" if args.unknown_exposures else "auto",
        refine_exposures=args.refine_exposures, n_components=args.components,
        saturation_threshold=args.saturation_threshold, basis=args.basis,
        **({"align": args.align} if args.align else {}))
    for line in result.summary_lines():
        _say(line)
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
        _say(f"wrote {path}")
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
    _say(f"simulated a {len(paths)}-frame bracketed JPEG stack "
         f"({', '.join(_fmt_time(t) for t in stack.exposure_times)} s, ±3% shutter jitter) "
         f"-> {out}/")
    model = selfcal.calibrate_response(paths, progress=_progress_bar("calibrate"))
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
    _say(f"wrote {plot_path}")
    _say("error against the simulator's truth, RMSE of f⁻¹ over codes 1..254: "
         + ", ".join(f"{c} {v:.4f}" for c, v in zip("RGB", rmse)))
    exp_err = np.abs(model.exposures / stack.true_exposures - 1)
    _say(f"exposures: largest error against the true (jittered) exposures {100 * exp_err.max():.1f}% "
         "(times were fixed at the EXIF values; try --refine-exposures on real stacks)")
    return EXIT_OK


# ------------------------------------------------------------------------- parser

def build_parser() -> argparse.ArgumentParser:
    from selfcal import __version__
    from selfcal.response.solver import DEFAULT_SATURATION_THRESHOLD
    from selfcal.response.calibrate import DEFAULT_N_COMPONENTS

    parser = argparse.ArgumentParser(
        prog="selfcal",
        description="Radiometric self-calibration of cameras: response curves from "
                    "bracketed JPEG stacks (Lin et al., ICCV 2011).",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"selfcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

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
    p.add_argument("--times", nargs="+", type=_parse_time, metavar="T",
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

    from .hdr_commands import register as register_hdr_commands

    register_hdr_commands(sub)
    from .pipeline_commands import register as register_pipeline_commands

    register_pipeline_commands(sub)
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
                _say(f"warning: {w.message}")
        return code
    except selfcal.OutputExistsError as exc:
        _say(f"selfcal: error: {exc}")
        return EXIT_OUTPUT
    except selfcal.InputError as exc:
        _say(f"selfcal: error: {exc}")
        return EXIT_INPUT
    except selfcal.CalibrationError as exc:
        _say(f"selfcal: cannot calibrate: {exc}")
        return EXIT_CALIBRATION
    except KeyboardInterrupt:
        _say("selfcal: interrupted")
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
