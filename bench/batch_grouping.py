"""Sessions found by content (``selfcal.batch.grouping``): tuning card, reporting cards, real card.

1. **Tuning card** (:func:`selfcal.sim.mixed_cards.write_mixed_card`, seed 11): the
   thumbnail correlation (:func:`selfcal.batch.grouping.similarity`) of every pair of
   frames of one body at most 2 stops apart, split by truth (same scene or not): the
   thresholds ``match`` and ``differ`` of :class:`~selfcal.batch.grouping.GroupingRule`
   were chosen in the gap between the two.
2. **Reporting cards** (seed 23, and seeds 1-10): sessions exactly found, frames left
   out, sessions marked unsure -- by content, and by the 10 s time rule alone.
3. **Real card** (when ``../shared/data/real_brackets`` is present): each camera's scenes
   copied flat into one ``DCIM`` folder (EXIF and file times kept), as a new user would;
   sessions found, frames left out, by content and by time.  With ``--real-batch``, the
   whole ``selfcal batch`` on it (``--scheduler serial``): sessions done and the pooled
   curve per camera.

    python3 -m bench.batch_grouping
    python3 -m bench.batch_grouping --real-batch
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from .data import SHARED_DATA
from .tables import finish, start, table

TUNING, REPORTING = 11, 23


def _full_search():
    """The default rule, with the shift search never cut short (the best correlation)."""
    from dataclasses import replace

    from selfcal.batch.grouping import GroupingRule

    return replace(GroupingRule(), match=float("inf"))


def pair_correlations(lib):
    """Best correlations (the whole shift search) of frame pairs of one body ≤ 2 stops
    apart: (same scene, different scenes)."""
    from selfcal.batch import read_frame_info
    from selfcal.batch.grouping import similarity, thumbnail

    frames = [(k, p) for k, s in enumerate(lib.sessions) for p in s.frames]
    info = {p: read_frame_info(p) for _, p in frames}
    thumb = {p: thumbnail(p) for _, p in frames}
    same, other = [], []
    full = _full_search()
    for i, (si, a) in enumerate(frames):
        for sj, b in frames[i + 1:]:
            if info[a].camera != info[b].camera:
                continue
            stops = abs(np.log2(info[a].relative_exposure / info[b].relative_exposure))
            if not 0.1 < stops <= 2.05:
                continue
            c, _ = similarity(thumb[a], thumb[b], full)
            if c is not None:
                (same if si == sj else other).append(c)
    return np.array(same), np.array(other)


def score(found, truth_sessions):
    truth = {tuple(sorted(map(str, s))) for s in truth_sessions}
    got = [tuple(sorted(map(str, s.paths))) for s in found.sessions]
    return (sum(g in truth for g in got), len(got), len(truth), len(found.unassigned),
            sum(s.unsure for s in found.sessions))


def simulated(seeds, work: Path):
    from selfcal.batch import discover
    from selfcal.sim.mixed_cards import write_mixed_card

    rows = []
    for seed in seeds:
        lib = write_mixed_card(work / f"card{seed}", seed=seed)
        truth = [s.frames for s in lib.sessions]
        frames = sum(len(s) for s in truth)
        for how in ("content", "time"):
            exact, got, n, loose, unsure = score(
                discover([lib.root], by_content=how == "content"), truth)
            rows.append((f"{seed} ({'tuning' if seed == TUNING else 'reporting'})", how,
                         frames, n, got, exact, loose, unsure if how == "content" else "-"))
    return rows


def real_card(work: Path):
    real = SHARED_DATA / "real_brackets"
    if not real.is_dir():
        return None, None
    truth = []
    root = work / "real"
    for camera in sorted(p for p in real.iterdir() if p.is_dir()):
        dcim = root / camera.name / "DCIM"
        dcim.mkdir(parents=True)
        for scene in sorted(p for p in camera.iterdir() if p.is_dir()):
            files = sorted(scene.iterdir())
            for f in files:
                shutil.copy2(f, dcim / f.name)
            truth.append([dcim / f.name for f in files])
    return root, truth


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-batch", action="store_true",
                    help="also run the whole batch on the real card (minutes)")
    args = ap.parse_args(argv)
    start("batch_grouping", "none")
    from selfcal.batch import discover
    from selfcal.batch.grouping import GroupingRule
    from selfcal.sim.mixed_cards import write_mixed_card

    print("load average 1/5/15 min: " + "/".join(f"{x:.1f}" for x in os.getloadavg()))
    work = Path(tempfile.mkdtemp(prefix="bench-grouping-"))
    rule = GroupingRule()
    same, other = pair_correlations(write_mixed_card(work / "tuning", seed=TUNING))
    print(f"\ntuning card (seed {TUNING}): thumbnail correlation of frame pairs of one body "
          "0.1-2 stops apart")
    print(table(["pairs", "n", "min", "1 %", "median", "99 %", "max"],
                [(name, len(x), *(f"{v:.3f}" for v in np.percentile(x, [0, 1, 50, 99, 100])))
                 for name, x in (("same scene", same), ("different scenes", other))]))
    print(f"thresholds: match >= {rule.match}, differ < {rule.differ} (time decides in "
          f"between, and when < {rule.min_overlap:.0%} of the pixels are well exposed in "
          f"both); max gap {rule.max_gap:g} s, window {rule.window:g} s")

    print("\nsimulated cards: sessions exactly found")
    print(table(["seed", "grouping", "frames", "sessions", "found", "exact", "left out",
                 "unsure"], simulated([TUNING, REPORTING] + list(range(1, 11)), work)))

    root, truth = real_card(work)
    if root is None:
        print("\nreal card: ../shared/data/real_brackets absent")
        return
    rows = []
    for how in ("content", "time"):
        t0 = time.perf_counter()
        found = discover([root], by_content=how == "content")
        exact, got, n, loose, unsure = score(found, truth)
        rows.append((how, sum(map(len, truth)), n, got, exact, loose,
                     unsure if how == "content" else "-", f"{time.perf_counter() - t0:.1f}"))
    print("\nreal card (Sony ILCE-6400 3 scenes, Fujifilm X-H1 3 scenes; one DCIM per camera)")
    print(table(["grouping", "frames", "sessions", "found", "exact", "left out", "unsure",
                 "s"], rows))
    if args.real_batch:
        from selfcal.batch import run_batch

        t0 = time.perf_counter()
        result = run_batch([root], work / "out", scheduler="serial")
        print(f"\nselfcal batch --scheduler serial on the real card: {len(result.rows)} "
              f"sessions, {result.count('ok')} ok, {result.count('failed')} failed, "
              f"{len(result.unassigned)} files in none, {time.perf_counter() - t0:.0f} s")
        print(table(["camera", "sessions", "pooled", "flagged", "model", "residual rms"],
                    [(c["camera_label"], c["sessions"], len(c["pooled_sessions"]),
                      len(c["flagged_sessions"]), "one pooled curve" if c["model_file"]
                      else "none", f"{c['residual_rms_log']:.4f}"
                      if c["residual_rms_log"] is not None else "-")
                     for c in result.cameras]))


if __name__ == "__main__":
    main()
    finish()
