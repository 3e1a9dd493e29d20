"""What the ``selfcal`` subcommands share: exit codes, messages, progress bars, argument
types and the check of outputs before any work starts.

Nothing numerical lives in ``selfcal_cli/``; this module sits below every command module and
imports none of them.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from fractions import Fraction
from pathlib import Path

from . import interrupts

EXIT_OK = 0
EXIT_USAGE = 2          # argparse's own code for bad arguments
EXIT_INPUT = 3          # an input file or value is bad
EXIT_CALIBRATION = 4    # the data cannot determine what was asked
EXIT_OUTPUT = 5         # an output exists (use --force) or cannot be written

EPILOG = """exit codes: 0 success, 2 bad arguments, 3 bad input (file or value),
4 the data cannot be calibrated (or the verdict is unusable; --force writes it anyway),
5 an output exists (use --force) or cannot be written, 130 interrupted (Ctrl-C: nothing
written). Every output is checked before the work starts and written at the end, all
or nothing."""


def say(msg: str = "") -> None:
    """The one place the command line talks: a line on stderr (stdout stays clean)."""
    print(msg, file=sys.stderr)


def parse_time(text: str) -> float | None:
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


def progress_bar(desc: str):
    """A tqdm progress callback for the library's ``progress(stage, done, total, detail)``."""
    from tqdm import tqdm

    bars = {}

    def callback(stage, done, total, detail=""):
        interrupts.check()          # a Ctrl-C a library swallowed stops the work here
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


def check_outputs(outputs, inputs, force: bool, *, create_folder: bool = False) -> None:
    """Refuse before any work what writing the outputs would refuse at the end.

    Each output (None ones are skipped) is checked by :func:`selfcal.io.check_output_path`:
    not an input, not a directory, not an existing file without ``--force``, its folder
    exists (or, with ``create_folder``, can be created) and a file can really be created
    in it.  Two outputs naming one file are refused too.
    """
    import selfcal
    from selfcal.io import check_output_path

    inputs = [Path(p) for p in inputs]
    seen = set()
    for out in outputs:
        if out is None:
            continue
        out = Path(out)
        r = out.resolve()
        if r in seen:
            raise selfcal.InputError(f"{out}: named as two different outputs")
        seen.add(r)
        check_output_path(out, force=force, inputs=inputs, create_folder=create_folder)


def check_output_folder(folder) -> None:
    """An output folder (``-o DIR``) may be missing (it is created at the end), not a file."""
    from selfcal.io import OutputWriteError

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputWriteError(path=folder,
                               message=f"cannot be the output folder (it is a file)")


# ------------------------------------------------------------------------- argument types

def int_range(lo: int, hi, what: str):
    """An argparse type: an integer from ``lo`` to ``hi`` (``hi`` may be a callable giving
    it, looked up only when the option is used)."""

    def parse(text: str) -> int:
        top = hi() if callable(hi) else hi
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not lo <= value <= top:
            raise argparse.ArgumentTypeError(
                f"{what} must be a whole number from {lo} to {top}, not {text!r}")
        return value

    return parse


def float_range(lo: float, hi: float, what: str):
    """An argparse type: a number from ``lo`` to ``hi``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(
                f"{what} must be a number from {lo:g} to {hi:g}, not {text!r}")
        return value

    return parse


_NUMBER_LIKE = re.compile(r"^-(\d|\.\d|inf|nan)", re.IGNORECASE)


def negative_times(argv) -> str | None:
    """A value like ``-1/60`` after ``--times``, which argparse would read as an option.

    argparse takes ``-1`` and ``-0.5`` as values (then :func:`parse_time` refuses them),
    but ``-1/60`` for an unknown option; this finds it so that the error names it.
    """
    in_times = False
    for tok in argv:
        if tok == "--":
            return None
        if tok.startswith("--"):
            in_times = len(tok) > 3 and "--times".startswith(tok)
        elif in_times and _NUMBER_LIKE.match(tok):
            return tok
        elif tok.startswith("-") and len(tok) > 1:
            in_times = False
    return None


# ------------------------------------------------------------------------- verdicts

def verdict_of(diagnostics):
    """:func:`selfcal.response.verdict.verdict_of` (imported when first used: this module
    is imported while the ``selfcal`` command starts)."""
    from selfcal.response.verdict import verdict_of as of

    return of(diagnostics)


def say_verdict(diagnostics, force: bool, what: str = "the calibration") -> None:
    """Print ``verdict: <level>`` and its reasons; refuse an unusable one without --force.

    ``ok``: the line only.  ``doubtful``: each reason as a warning (the command goes on,
    exit 0).  ``unusable``: each reason, then :class:`~selfcal.errors.CalibrationError`
    (exit 4, nothing written) unless ``force``, when it is a warning and the work goes on.
    """
    import selfcal

    level, reasons = verdict_of(diagnostics)
    if level is None:
        return
    say(f"verdict: {level}")
    if level == "doubtful":
        for r in reasons:
            warn(r)
    else:
        for r in reasons:
            say(f"  - {r}")
            _said_warnings.add(r)   # the library warns them too: said once
    if level == "unusable":
        why = (reasons[0] if reasons else "no reason given") + (
            f" (and {len(reasons) - 1} more reason(s) above)" if len(reasons) > 1 else "")
        if not force:
            raise selfcal.CalibrationError(
                f"{what} is unusable: {why}; nothing written (--force writes it anyway)")
        warn(f"{what} is unusable: {why}; written anyway (--force)")


_said_warnings: set = set()


def warn(msg: str) -> None:
    """Say a warning once (the front end skips library warnings already said)."""
    if msg in _said_warnings:
        return
    _said_warnings.add(msg)
    say(f"warning: {msg}")


def reset_warnings() -> None:
    """Forget the warnings said (one command per call of the front end)."""
    _said_warnings.clear()


class _VignettingAction(argparse.Action):
    """``--vignetting auto|self|lens|none`` or ``--vignetting flat FILE`` (exit 2 otherwise)."""

    def __call__(self, parser, namespace, values, option_string=None):
        kind, rest = values[0], values[1:]
        if kind not in VIGNETTING_WORDS:
            parser.error(f"{option_string}: {kind!r} is not one of "
                         f"{', '.join(VIGNETTING_WORDS)}")
        if kind == "flat" and len(rest) != 1:
            parser.error(f"{option_string} flat takes one file: the flat-field frame")
        if kind != "flat" and rest:
            parser.error(f"{option_string} {kind} takes no file (got {' '.join(rest)}); "
                         "put the frames before the options")
        setattr(namespace, self.dest, values)


#: The words of ``--vignetting`` (``flat`` takes a file).
VIGNETTING_WORDS = ("auto", "self", "lens", "flat", "none")


def add_vignetting_argument(parser) -> None:
    """``--vignetting`` of ``selfcal merge`` and ``selfcal linearize``."""
    parser.add_argument(
        "--vignetting", nargs="+", action=_VignettingAction, default=["auto"],
        metavar="SOURCE",
        help="the lens's falloff to divide out: auto (default: self-calibrated when the "
             "model holds one, else the lens database's profile for the EXIF lens, else "
             "none), self, lens, flat FILE (a frame of a uniform surface), or none")


def vignetting_argument(values):
    """``MergeOptions.vignetting`` from ``--vignetting``: a word, or the flat frame's Path."""
    import selfcal

    if values[0] != "flat":
        return values[0]
    flat = Path(values[1])
    if not flat.is_file():
        raise selfcal.InputError("no such file" if not flat.exists() else "not a file", flat)
    return flat


def say_vignetting(record, *, frame: str | None = None) -> None:
    """One line: which vignetting was divided out, and why the others were not."""
    if not record:
        return
    where = f"{frame}: " if frame else ""
    if record.get("source") is None:
        if record.get("chosen_by") == "none":
            return
        why = "; ".join(record.get("reasons", [])) or "none found"
        say(f"{where}vignetting: none divided out ({why})")
        return
    passed = "; ".join(record.get("reasons", []))
    say(f"{where}vignetting: {record['source']} ({record.get('description') or 'no description'})"
        + (f" -- passed over: {passed}" if passed else ""))


def add_exposure_flags(parser) -> None:
    """The rule for given times, one flag for every command that takes times
    (:class:`selfcal.exposure.ExposureRule`): ``--hold-times``, and the solve's finer
    ``--refine-exposures``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--hold-times", action="store_true",
                       help="use every exposure time (EXIF or --times) exactly as given "
                            "(default: the exposures are measured from the pixels, the "
                            "times keeping their scale and trend; times the pixels "
                            "contradict are refined)")
    group.add_argument("--refine-exposures", action="store_true",
                       help="treat every time as a prior in the response solve, not only "
                            "those the pixels contradict")
    # 1.0's flags, until 2.0: each means --hold-times (or the default), said when used
    group.add_argument("--no-refine-exposures", dest="legacy_hold", action="append_const",
                       const="--no-refine-exposures", help=argparse.SUPPRESS)
    parser.add_argument("--no-measure-exposures", dest="legacy_hold", action="append_const",
                        const="--no-measure-exposures", help=argparse.SUPPRESS)
    parser.add_argument("--linear-exposures", dest="legacy_linear",
                        choices=("auto", "measured", "times"), help=argparse.SUPPRESS)


def exposure_rule(args):
    """The :class:`selfcal.exposure.ExposureRule` of ``--hold-times`` / ``--refine-exposures``."""
    from selfcal.exposure import ExposureRule

    legacy = list(getattr(args, "legacy_hold", None) or [])
    if getattr(args, "legacy_linear", None) == "times":
        legacy.append("--linear-exposures times")
    elif getattr(args, "legacy_linear", None):
        warn(f"--linear-exposures {args.legacy_linear} is the 1.0 flag, removed in 2.0: "
             "the exposures are measured by default")
    for flag in legacy:
        warn(f"{flag} is the 1.0 flag, removed in 2.0: write --hold-times")
    if getattr(args, "hold_times", False) or legacy:
        return ExposureRule(times="held")
    return ExposureRule(refine=True if getattr(args, "refine_exposures", False) else "auto")
