"""What the ``selfcal`` subcommands share: exit codes, messages, progress bars, argument
types and the check of outputs before any work starts.

Nothing numerical lives in ``cli/``; this module sits below every command module and
imports none of them.
"""

from __future__ import annotations

import argparse
import math
import sys
from fractions import Fraction
from pathlib import Path

EXIT_OK = 0
EXIT_USAGE = 2          # argparse's own code for bad arguments
EXIT_INPUT = 3          # an input file or value is bad
EXIT_CALIBRATION = 4    # the data cannot determine what was asked
EXIT_OUTPUT = 5         # an output exists (use --force) or cannot be written

EPILOG = """exit codes: 0 success, 2 bad arguments, 3 bad input (file or value),
4 the data cannot be calibrated, 5 output exists or cannot be written."""


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


def fmt_time(t) -> str:
    """Seconds as a photographer writes them: 1/250, 0.5 -> 1/2, 2; None -> '?'."""
    if t is None or (isinstance(t, float) and not math.isfinite(t)):
        return "?"
    if t < 1:
        return f"1/{1 / t:.4g}"
    return f"{t:.4g}"


def progress_bar(desc: str):
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


def check_outputs(outputs, inputs, force: bool) -> None:
    """Refuse before any work: outputs over inputs, existing outputs without --force."""
    import selfcal

    resolved_inputs = {Path(p).resolve() for p in inputs}
    seen = set()
    for out in outputs:
        if out is None:
            continue
        out = Path(out)
        r = out.resolve()
        if r in resolved_inputs:
            raise selfcal.OutputExistsError(f"{out}: refusing to write over an input file")
        if r in seen:
            raise selfcal.InputError(f"{out}: named as two different outputs")
        seen.add(r)
        if out.is_dir():
            raise selfcal.OutputExistsError(f"{out}: is a directory")
        if out.exists() and not force:
            raise selfcal.OutputExistsError(f"{out}: exists already (use --force to overwrite)")
