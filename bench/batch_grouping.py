"""Sessions found by content (``selfcal.batch.grouping``): hard simulated cards, copies, the real card.

1. **Pair evidence** (the hard card of seed 1, tuning): the thumbnail correlation after
   registration (:func:`selfcal.batch.grouping.similarity`, the whole search) of every
   pair of frames of one body at most 2 stops apart, both with at least
   ``min_visible`` of their pixels well exposed, split by truth (same scene or not):
   ``match`` and ``differ`` of :class:`~selfcal.batch.grouping.GroupingRule` lie in the
   gap between the two.
2. **Simulated cards**: the hard card (:func:`selfcal.sim.hard_cards.write_hard_card`:
   slow manual brackets with 10-120 s between frames, long 1/3-stop tripod brackets
   whose ends are black or white, handheld phone brackets that move and turn,
   brackets of different scenes one minute apart, a last frame 20-40 s late, AEB
   bursts) and the mixed card of the earlier issue
   (:func:`selfcal.sim.mixed_cards.write_mixed_card`: AEB bursts, manual brackets with
   pauses of minutes, two scenes 5 s apart, two scenes shot frame about), tuning seeds
   (< 1000) and held-out seeds (>= 1000): brackets, sessions found, exact, frames left
   out, unsure, seconds (reading included) -- by content, by the content grouping as it
   was before issue 37 (commit aa4f879), and by the 10 s time rule.
3. **Copies**: a held-out hard card and a copy of it in a second folder, one root:
   sessions found once, each from one copy, the copies skipped.
4. **Real card** (when ``../shared/data/real_brackets`` is present; held out: reported,
   not tuned on): each camera's scenes copied flat into one ``DCIM`` folder (EXIF and
   file times kept), as a new user would.  With ``--real-batch``, the whole
   ``selfcal batch`` on it (``--scheduler serial``).

    python3 -m bench.batch_grouping
    python3 -m bench.batch_grouping --real-batch
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np

from .data import SHARED_DATA
from .tables import REPO, finish, start, table

TUNING_HARD = tuple(range(1, 11))
HELDOUT_HARD = tuple(range(1000, 1010))
TUNING_MIXED = (11, 23)
HELDOUT_MIXED = (1000, 1001, 1002)
#: The content grouping before issue 37 (the baseline).
BEFORE = "aa4f879"


def _before():
    """``selfcal.batch.grouping`` as it was at :data:`BEFORE` (None without git)."""
    try:
        text = subprocess.run(["git", "show", f"{BEFORE}:selfcal/batch/grouping.py"],
                              cwd=REPO, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    mod = types.ModuleType("selfcal.batch._grouping_before")
    mod.__package__ = "selfcal.batch"
    sys.modules[mod.__name__] = mod           # dataclasses look their module up
    exec(compile(text, "grouping@" + BEFORE, "exec"), mod.__dict__)  # noqa: S102
    return mod


def _full_search():
    from dataclasses import replace

    from selfcal.batch.grouping import GroupingRule

    return replace(GroupingRule(), match=float("inf"))


def pair_correlations(lib):
    """Best correlations (the whole search) of comparable frame pairs of one body
    ≤ 2 stops apart: (same scene, different scenes)."""
    from selfcal.batch import read_frame_info
    from selfcal.batch.grouping import similarity, well_exposed
    from selfcal.batch.thumbnails import thumbnail

    full = _full_search()
    frames = [(k, p) for k, s in enumerate(lib.sessions) for p in s.frames]
    info = {p: read_frame_info(p) for _, p in frames}
    thumb = {p: thumbnail(p) for _, p in frames}
    frames = [(k, p) for k, p in frames if well_exposed(thumb[p], full) >= full.min_visible]
    same, other = [], []
    for i, (si, a) in enumerate(frames):
        for sj, b in frames[i + 1:]:
            if info[a].camera != info[b].camera or info[a].size != info[b].size:
                continue
            stops = abs(np.log2(info[a].relative_exposure / info[b].relative_exposure))
            if not 0.1 < stops <= 2.05:
                continue
            c, _ = similarity(thumb[a], thumb[b], full)
            if c is not None:
                (same if si == sj else other).append(c)
    return np.array(same), np.array(other)


def score(sessions, unassigned, truth_sessions):
    """(exact, found, brackets, left out, unsure)."""
    truth = {tuple(sorted(map(str, s))) for s in truth_sessions}
    got = [tuple(sorted(str(f.path) for f in s.frames)) for s in sessions]
    return (sum(g in truth for g in got), len(got), len(truth), len(unassigned),
            sum(bool(getattr(s, "unsure", False)) for s in sessions))


def group_all(root, before):
    """``{method: (sessions, unassigned, seconds)}`` for content, before, time."""
    from selfcal.batch import discover
    from selfcal.batch.discover import _pair_raws, _walk, read_frame
    from selfcal.batch.thumbnails import read_frames

    out = {}
    t0 = time.perf_counter()
    lib = discover([root])
    out["content"] = (lib.sessions, lib.unassigned, time.perf_counter() - t0)
    if before is not None:
        t0 = time.perf_counter()
        read = read_frames(_pair_raws(_walk([root], ()), []), read_frame)
        ok = [(i, t) for i, t in read if not isinstance(i, Exception)
              and i.exposure_time is not None]
        groups, loose = before.group_by_content([i for i, _ in ok], [t for _, t in ok])
        out[f"content before ({BEFORE})"] = (groups, loose, time.perf_counter() - t0)
    t0 = time.perf_counter()
    lib = discover([root], by_content=False)
    out["time (10 s)"] = (lib.sessions, lib.unassigned, time.perf_counter() - t0)
    return out


def simulated(cards, work: Path, before):
    from selfcal.sim.hard_cards import write_hard_card
    from selfcal.sim.mixed_cards import write_mixed_card

    rows = []
    for kind, seed in cards:
        write = write_hard_card if kind == "hard" else write_mixed_card
        lib = write(work / f"{kind}{seed}", seed=seed)
        truth = [s.frames for s in lib.sessions]
        split = "tuning" if seed < 1000 else "held-out"
        for how, (sessions, loose, sec) in group_all(lib.root, before).items():
            exact, got, n, left, unsure = score(sessions, loose, truth)
            rows.append((kind, seed, split, how, sum(map(len, truth)), n, got, exact, left,
                         unsure if how.startswith("content") else "-", f"{sec:.1f}"))
    return rows


def copies(work: Path, seed: int):
    from selfcal.batch import discover
    from selfcal.sim.hard_cards import copy_card, write_hard_card

    lib = write_hard_card(work / "library" / "card", seed=seed)
    copy = copy_card(lib, work / "library" / "backup")
    t0 = time.perf_counter()
    found = discover([work / "library"])
    sec = time.perf_counter() - t0
    a = {tuple(sorted(map(str, s.frames))) for s in lib.sessions}
    b = {tuple(sorted(map(str, s.frames))) for s in copy.sessions}
    got = [tuple(sorted(map(str, s.paths))) for s in found.sessions]
    one = sum(g in a or g in b for g in got)
    return (seed, sum(len(s.frames) for s in lib.sessions) * 2, len(lib.sessions), len(got),
            one, len(found.unassigned), len(found.copies), f"{sec:.1f}")


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
    start("batch_grouping", "both")
    from selfcal.batch.grouping import GroupingRule
    from selfcal.sim.hard_cards import write_hard_card

    print("load average 1/5/15 min: " + "/".join(f"{x:.1f}" for x in os.getloadavg()))
    work = Path(tempfile.mkdtemp(prefix="bench-grouping-"))
    before = _before()
    rule = GroupingRule()
    same, other = pair_correlations(write_hard_card(work / "pairs", seed=TUNING_HARD[0]))
    print(f"\nhard card (seed {TUNING_HARD[0]}, tuning): thumbnail correlation after "
          "registration of frame pairs of one body 0.1-2 stops apart, both with >= "
          f"{rule.min_visible:.0%} of their pixels well exposed")
    print(table(["pairs", "n", "min", "1 %", "median", "99 %", "max"],
                [(name, len(x), *(f"{v:.3f}" for v in np.percentile(x, [0, 1, 50, 99, 100])))
                 for name, x in (("same scene", same), ("different scenes", other))]))
    print(f"thresholds: match >= {rule.match}, differ < {rule.differ}; shifts <= "
          f"{rule.max_shift} px, turns {rule.rotations} deg; a frame with < "
          f"{rule.min_visible:.0%} of its pixels well exposed continues a session <= "
          f"{rule.continue_stops} stops past its end, visible pixels at rank >= "
          f"{rule.continue_rank}; max gap {rule.max_gap:g} s (unreadable thumbnails), "
          f"window {rule.window:g} s")

    cards = ([("hard", s) for s in TUNING_HARD] + [("mixed", s) for s in TUNING_MIXED]
             + [("hard", s) for s in HELDOUT_HARD] + [("mixed", s) for s in HELDOUT_MIXED])
    rows = simulated(cards, work, before)
    print("\nsimulated cards: brackets exactly found")
    print(table(["card", "seed", "split", "grouping", "frames", "brackets", "found",
                 "exact", "left out", "unsure", "s"], rows))
    summary = []
    for split in ("tuning", "held-out"):
        for how in sorted({r[3] for r in rows}):
            sel = [r for r in rows if r[2] == split and r[3] == how]
            summary.append((split, how, len(sel), sum(r[5] for r in sel),
                            sum(r[7] for r in sel), sum(r[8] for r in sel),
                            sum(r[9] for r in sel if r[9] != "-") if how.startswith(
                                "content") else "-"))
    print("\nsummed over the cards of each split")
    print(table(["split", "grouping", "cards", "brackets", "exact", "left out", "unsure"],
                summary))

    print("\ncopies: a held-out hard card and a copy of it in a second folder, one root")
    print(table(["seed", "files", "brackets", "found", "exact, from one copy", "left out",
                 "copies skipped", "s"], [copies(work / "copies", HELDOUT_HARD[0])]))

    root, truth = real_card(work)
    if root is None:
        print("\nreal card: ../shared/data/real_brackets absent")
        return
    rows = []
    for how, (sessions, loose, sec) in group_all(root, before).items():
        exact, got, n, left, unsure = score(sessions, loose, truth)
        rows.append((how, sum(map(len, truth)), n, got, exact, left,
                     unsure if how.startswith("content") else "-", f"{sec:.1f}"))
    print("\nreal card, held out (Sony ILCE-6400 3 scenes, Fujifilm X-H1 3 scenes; one "
          "DCIM per camera)")
    print(table(["grouping", "frames", "brackets", "found", "exact", "left out", "unsure",
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
