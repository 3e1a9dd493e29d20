"""Printing the benchmarks' tables and recording each run as JSON.

A script prints as it always did (:func:`table` returns a Markdown table as text) inside
:func:`recording`, which also keeps what it printed: the tables as rows, the lines around
them as text, in order.  At the end of the run it writes ``bench/results/<name>.json``
(``<name>.<variant>.json`` for a run with a variant flag): those blocks, the exact command
line, the commit it ran at (``git rev-parse --short HEAD``, ``+dirty`` when a tracked or
untracked file outside ``bench/results/`` and ``bench/BENCHMARKS.md`` differs from it),
the date, the split (``tuning``, ``held-out``, ``both``, or ``none`` for a bench that
tunes nothing) and the wall time.  :mod:`bench.report` renders those files.
"""

from __future__ import annotations

import contextlib
import datetime
import io
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results"
#: Outputs of the benches: a change there does not make the code a run measured dirty.
OUTPUTS = ("bench/results/", "bench/BENCHMARKS.md")
SPLITS = ("tuning", "held-out", "both", "none")

_active: list = []


def table(headers, rows) -> str:
    """A plain-text table (also valid Markdown); recorded as rows by an active
    :func:`recording` when it is printed."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(cells[0], widths)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    for r in cells[1:]:
        lines.append("| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |")
    text = "\n".join(lines)
    if _active:
        _active[-1].tables[text] = {"headers": cells[0], "rows": cells[1:]}
    return text


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.t0


def best_of(call, repeats: int) -> float:
    """The shortest of ``repeats`` wall-clock timings of ``call()`` (seconds)."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        out.append(time.perf_counter() - t0)
    return min(out)


def git_commit() -> str:
    """``git rev-parse --short HEAD``, with ``+dirty`` when the code differs from it."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True,
                              check=True).stdout

    try:
        commit = git("rev-parse", "--short", "HEAD").strip()
        status = [line[3:] for line in git("status", "--porcelain").splitlines()]
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    dirty = [p for p in status if not p.startswith(OUTPUTS)]
    return commit + ("+dirty" if dirty else "")


class _Tee(io.TextIOBase):
    def __init__(self, stream, sink):
        self.stream, self.sink = stream, sink

    def write(self, text):
        self.sink.append(text)
        return self.stream.write(text)

    def flush(self):
        self.stream.flush()


class Recording:
    def __init__(self, name, split, variant):
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        self.name, self.split, self.variant = name, split, variant
        self.tables: dict = {}
        self.printed: list = []
        self.commit = git_commit()
        self.date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        self.t0 = time.perf_counter()

    def blocks(self) -> list:
        """What was printed, in order: ``{"text": ...}`` and ``{"table": {...}}``."""
        text = "".join(self.printed)
        out = []
        while True:
            hits = [(text.find(t), t) for t in self.tables if t in text]
            if not hits:
                break
            at, t = min(hits)
            if text[:at].strip("\n"):
                out.append({"text": text[:at].strip("\n")})
            out.append({"table": self.tables[t]})
            text = text[at + len(t):]
        if text.strip("\n"):
            out.append({"text": text.strip("\n")})
        return out

    def path(self) -> Path:
        return RESULTS / (self.name + (f".{self.variant}" if self.variant else "") + ".json")

    def write(self):
        argv = [a for a in sys.argv[1:]]
        record = {"name": self.name, "variant": self.variant,
                  "command": " ".join(["python3 -m", f"bench.{self.name}", *argv]),
                  "commit": self.commit, "date": self.date, "split": self.split,
                  "seconds": round(time.perf_counter() - self.t0, 1),
                  "blocks": self.blocks()}
        RESULTS.mkdir(parents=True, exist_ok=True)
        self.path().write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n",
                               encoding="utf-8")
        print(f"(recorded in {self.path().relative_to(REPO)})", file=sys.stderr)


@contextlib.contextmanager
def recording(name: str, split: str, variant: str | None = None):
    """Keep what the block prints and write it to ``bench/results/`` when it ends without
    an exception (a failed or interrupted run leaves the last good record in place)."""
    rec = Recording(name, split, variant)
    _active.append(rec)
    old = sys.stdout
    sys.stdout = _Tee(old, rec.printed)
    try:
        yield rec
    finally:
        sys.stdout = old
        _active.pop()
    rec.write()


_started: list = []


def start(name: str, split: str, variant: str | None = None) -> None:
    """Begin recording a script's run (call it once its arguments are parsed); ``split``
    may be spelt as the scripts' flags spell it (``heldout``, ``all``).  :func:`finish`
    writes the record; a run that fails before it writes nothing."""
    split = {"heldout": "held-out", "all": "both"}.get(split or "", split or "both")
    if variant is None:
        variant = _variant(sys.argv[1:])
    rec = Recording(name, split, variant)
    _active.append(rec)
    rec.stdout = sys.stdout
    sys.stdout = _Tee(sys.stdout, rec.printed)
    _started.append(rec)


def finish() -> None:
    """Write the record of the run :func:`start` began (nothing when none was begun)."""
    if not _started:
        return
    rec = _started.pop()
    sys.stdout = rec.stdout
    _active.remove(rec)
    rec.write()


def _variant(argv) -> str | None:
    """A file-name suffix naming a run's flags: ``--split tuning --curves 3`` ->
    ``split-tuning.curves-3``; None without flags (the default run)."""
    import re

    words = [re.sub(r"[^A-Za-z0-9_,.=-]+", "_", a.lstrip("-")) for a in argv]
    # --jobs N does not change a result: leave it (and its value) out of the name
    out, skip = [], False
    for a, w in zip(argv, words):
        if skip:
            skip = False
            continue
        if a == "--jobs" or a.startswith("--jobs="):
            skip = a == "--jobs"
            continue
        if a.startswith("-") and out:
            out.append("." + w)
        elif out:
            out.append("-" + w)
        else:
            out.append(w)
    return "".join(out).replace(",", "_") or None
