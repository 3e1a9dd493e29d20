"""Faults a batch survives: interruption, lost workers, leftovers of killed writers.

* :class:`Journal` -- the manifest written as the batch goes: one JSON line appended per
  finished session (O(1) each, flushed), so that an interrupted run still tells what it
  finished; the sorted manifest replaces it at the end (:func:`.run.write_manifest`).
* :func:`interrupted_rows` -- the rows of the sessions an interrupted run did not finish
  (status ``interrupted``): the manifest of an interrupted run names every session.
* :func:`sweep_partial` -- every session's outputs appear together or not at all
  (:class:`selfcal.io.StagedOutputs`), but a process killed while it writes (a worker's
  SIGKILL) leaves its hidden temporary files behind; they are removed before and after
  every run, with the session folders they alone occupied.

What a lost worker costs is Dask's own resilience: the scheduler runs the tasks the
worker held, and those whose results died with it, on the others
(``distributed.scheduler.allowed-failures`` times at most).  Ours.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from ..io.model_file import jsonable

#: Name of the journal of a run in progress (beside the manifest).
JOURNAL = "manifest.partial.jsonl"

# StagedOutputs' temporaries: ".<target name>.<random><suffix>" beside the target
_TEMP = re.compile(r"^\.(.+)\.[A-Za-z0-9_]{6,}(\.[A-Za-z0-9]+)?$")


class Journal:
    """Rows appended to ``out_dir/manifest.partial.jsonl`` as sessions finish.

    Parameters
    ----------
    out_dir : path
        The batch folder (created, with the journal, at the first row: a run that fails
        before any session finishes -- the cluster unreachable -- writes nothing).
    """

    def __init__(self, out_dir):
        self.path = Path(out_dir) / JOURNAL
        self._fh = None

    def add(self, row: dict) -> None:
        """Append one row (one line) and flush it to the operating system."""
        if self._fh is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "a", encoding="utf-8")
        self._fh.write(json.dumps(jsonable(row), allow_nan=False, default=str) + "\n")
        self._fh.flush()

    def close(self, *, remove: bool = False) -> None:
        """Close; ``remove`` deletes the journal (the full manifest is written)."""
        if self._fh is not None and not self._fh.closed:
            self._fh.close()
        if remove:
            try:
                self.path.unlink()
            except OSError:
                pass


def interrupted_rows(todo, rows) -> list:
    """Rows (status ``interrupted``) for the plans in ``todo`` with no row in ``rows``."""
    from .run import plan_row

    done = {r["session"] for r in rows}
    out = []
    for plan in todo:
        if plan.id not in done:
            row = plan_row(plan)
            row.update(status="interrupted", error="the run was interrupted before this "
                                                   "session finished (a rerun does it)")
            out.append(row)
    return out


def _is_temp(name: str) -> bool:
    return bool(_TEMP.match(name)) or name.startswith(".selfcal-check.")


def sweep_partial(out_dir) -> list:
    """Remove leftover temporary outputs under ``out_dir/sessions`` and ``cameras``.

    Only hidden files of the temporary-name pattern of :class:`selfcal.io.StagedOutputs`
    are removed, then the folders (under those two) left empty.  Never raises.

    Returns
    -------
    list of pathlib.Path
        What was removed.
    """
    removed = []
    for top in ("sessions", "cameras"):
        base = Path(out_dir) / top
        if not base.is_dir():
            continue
        for folder, dirs, names in os.walk(base, topdown=False):
            here = Path(folder)
            for n in names:
                if _is_temp(n):
                    try:
                        (here / n).unlink()
                        removed.append(here / n)
                    except OSError:
                        pass
            if here != base:
                try:
                    here.rmdir()             # only when empty
                    removed.append(here)
                except OSError:
                    pass
    return removed
