"""The path a bracket's exposure times take through the library: modules and package switches.

Runs ``selfcal.merge_hdr(paths)`` (no model: it calibrates on the fly) and
``selfcal.calibrate_response(paths)`` on the fixture stack (``fixtures/stack``, EXIF times)
under :func:`sys.setprofile`, and records every call of a function of ``selfcal`` that is
handed the exposures.  A call is on the exposure path when one of its arguments (or an item
of a list, tuple or dict argument), or the value it returns, *is* the exposures in some
form:

* an object of :mod:`selfcal.exposure`'s record types (anything whose class is defined in
  a module of ``selfcal.exposure`` and whose name ends in ``Exposures``, ``Exposure`` or
  ``Times``);
* a sequence of one number per frame (None or NaN allowed) proportional to the EXIF times
  within 10 % (any unit: seconds, t·ISO/100/N², measured exposures), or their logarithms
  up to a constant;
* a model or options object that merely holds exposures among its fields is not counted
  (handing a model to a function that reads its curve is not handing on the times), and
  neither are file paths (reading a file is not handing the times on).

The calls are taken in the order they run; the package of each (``selfcal.hdr``,
``selfcal.exposure``, ...) forms a sequence, and a *switch* is two consecutive calls in
different packages.  The count depends on this definition (by value, not by name: renaming
a parameter changes nothing), which is why the script is committed: issue 43's figures
(today ≤ 8 switches for the merge, ≤ 5 for the calibration) are what it prints.

Run ``python3 scripts/trace_exposures.py`` (``--calls`` lists every call on the path).
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
FIXTURES = REPO / "fixtures" / "stack"
#: Relative tolerance of "proportional to the times" (measured exposures move by a few %).
TOLERANCE = math.log(1.10)


def _exif_times(paths) -> np.ndarray:
    from PIL import Image

    out = []
    for p in paths:
        with Image.open(p) as im:
            value = im.getexif().get_ifd(0x8769).get(0x829A)
        out.append(float(value))
    return np.log(np.asarray(out))


def _numbers(value, n: int) -> np.ndarray | None:
    """``value`` as n floats (NaN for None), or None when it is not one number per frame."""
    if isinstance(value, np.ndarray):
        if value.ndim != 1 or value.shape[0] != n or not np.issubdtype(value.dtype, np.number):
            return None
        return value.astype(float)
    if isinstance(value, (list, tuple)) and len(value) == n and value and \
            all(v is None or (isinstance(v, (int, float, np.floating)) and not isinstance(v, bool))
                for v in value):
        return np.array([np.nan if v is None else float(v) for v in value])
    return None


def _is_times(values: np.ndarray, log_times: np.ndarray) -> bool:
    ok = np.isfinite(values)
    if ok.sum() < 2:
        return False
    v, lt = values[ok], log_times[ok]
    if np.ptp(lt) < 1e-9:
        return False
    if np.all(v > 0):        # proportional: log v − log t constant
        d = np.log(v) - lt
        if np.ptp(d) < TOLERANCE:
            return True
    d = v - lt               # logarithms up to a constant
    return bool(np.ptp(d) < TOLERANCE)


def _is_record(value) -> bool:
    cls = type(value)
    return (cls.__module__.startswith("selfcal.exposure")
            and cls.__name__.endswith(("Exposures", "Exposure", "Times")))


def _carries(value, log_times, n: int, depth: int = 0) -> bool:
    if _is_record(value):
        return True
    values = _numbers(value, n)
    if values is not None:
        return _is_times(values, log_times)
    if depth >= 1:
        return False
    if isinstance(value, dict):
        return any(_carries(v, log_times, n, depth + 1) for v in value.values())
    if isinstance(value, (list, tuple)) and len(value) < 64:
        return any(_carries(v, log_times, n, depth + 1) for v in value)
    return False


def trace(call, log_times) -> list[tuple[str, str]]:
    """(module, function) of every selfcal call handed the exposures, in order."""
    n = len(log_times)
    seen: list[tuple[str, str]] = []

    counted: set[int] = set()

    def profile(frame, event, arg):
        if event not in ("call", "return"):
            return
        module = frame.f_globals.get("__name__", "")
        code = frame.f_code
        if not module.startswith("selfcal.") or code.co_name.startswith("<") or \
                "__create_fn__" in getattr(code, "co_qualname", ""):
            return
        name = (module, getattr(code, "co_qualname", code.co_name))
        if event == "call":
            names = code.co_varnames[:code.co_argcount + code.co_kwonlyargcount]
            args = [frame.f_locals.get(a) for a in names if a not in ("self", "cls")]
            if any(_carries(a, log_times, n) for a in args):
                counted.add(id(frame))
                seen.append(name)
        elif id(frame) not in counted and _carries(arg, log_times, n):
            seen.append(name)      # handed the exposures back (at its return)
        counted.discard(id(frame))

    sys.setprofile(profile)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            call()
    finally:
        sys.setprofile(None)
    return seen


def package_of(module: str) -> str:
    return ".".join(module.split(".")[:2])


def summary(name: str, calls, show_calls: bool) -> str:
    packages = [package_of(m) for m, _ in calls]
    switches = sum(1 for a, b in zip(packages, packages[1:]) if a != b)
    runs = [p for i, p in enumerate(packages) if i == 0 or packages[i - 1] != p]
    lines = [f"{name}: {len(calls)} calls, {len(set(m for m, _ in calls))} modules, "
             f"{switches} package switches",
             "  " + " → ".join(p.replace("selfcal.", "") for p in runs)]
    if show_calls:
        lines += [f"    {m}.{f}" for m, f in calls]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", action="store_true", help="list every call on the path")
    args = parser.parse_args(argv)
    import selfcal

    paths = sorted(str(p) for p in FIXTURES.glob("frame_*.jpg"))
    log_times = _exif_times(paths)
    for name, call in (("merge_hdr(paths)", lambda: selfcal.merge_hdr(paths)),
                       ("calibrate_response(paths)",
                        lambda: selfcal.calibrate_response(paths))):
        print(summary(name, trace(call, log_times), args.calls))
    return 0


if __name__ == "__main__":
    sys.exit(main())
