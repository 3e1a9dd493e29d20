"""Sessions by content on the hard card (issue 37): slow manual and long tripod brackets,
handheld phone brackets, neighbouring scenes a minute apart, copies of a card.

The hard card is :func:`selfcal.sim.hard_cards.write_hard_card`; its thresholds were
tuned on seeds < 1000 (``python3 -m bench.batch_grouping``), and the card of a held-out
seed is checked here too.  No Dask needed.
"""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from selfcal.batch import discover, read_frame_info
from selfcal.batch.grouping import GroupingRule, group_by_content, similarity, well_exposed
from selfcal.batch.thumbnails import ThumbnailSpool, thumbnail
from selfcal.sim.hard_cards import copy_card, write_hard_card
from selfcal_cli.main import main

TUNING_SEED, HELDOUT_SEED = 7, 1003


def _sets(paths_per_session):
    return sorted(tuple(sorted(map(str, s))) for s in paths_per_session)


@pytest.fixture(scope="module", params=[TUNING_SEED, HELDOUT_SEED],
                ids=["tuning", "held-out"])
def hard(request, tmp_path_factory):
    return write_hard_card(tmp_path_factory.mktemp(f"hard{request.param}"),
                           seed=request.param)


def test_every_bracket_of_the_hard_card_is_found_exactly(hard):
    found = discover([hard.root])
    assert _sets(s.paths for s in found.sessions) == _sets(s.frames for s in hard.sessions)
    assert found.unassigned == [] and found.copies == []
    # the card has what the clock gets wrong
    times = {p: read_frame_info(p).time for s in hard.sessions for p in s.frames}
    assert max(len(s.frames) for s in hard.sessions) >= 30          # a long bracket
    assert max(max(np.diff([times[p] for p in s.frames])) for s in hard.sessions) > 60
    assert any(s.body.make == "Simphone" for s in hard.sessions)
    ends = sorted((times[s.frames[0]], times[s.frames[-1]], s.body.serial)
                  for s in hard.sessions)
    assert any(0 < b[0] - a[1] < 90 and a[2] == b[2] for a, b in zip(ends, ends[1:]))
    reasons = [r for s in found.sessions for r in s.reasons]
    blank = [p for p in times if well_exposed(thumbnail(p)) < GroupingRule().min_visible]
    assert len([r for r in reasons if " to compare" in r]) >= bool(blank)
    for s in found.sessions:                    # a reason for every frame
        names = {f.path.name for f in s.frames}
        assert names <= {r.split(":")[0] for r in s.reasons}


def test_a_phone_bracket_that_moved_and_turned_is_one_session(hard):
    phone = [s for s in hard.sessions if s.body.make == "Simphone"]
    found = discover([hard.root])
    got = _sets(s.paths for s in found.sessions)
    assert phone and all(tuple(sorted(map(str, s.frames))) in got for s in phone)


def test_registration_finds_a_moved_and_turned_frame(hard):
    import cv2

    s = next(x for x in hard.sessions if x.body.make != "Simphone" and len(x.frames) >= 5)
    order = np.argsort(s.exposure_times)
    a, b = (thumbnail(s.frames[order[k]]) for k in (len(order) // 2, len(order) // 2 + 1))
    h, w = b.shape
    m = cv2.getRotationMatrix2D((w / 2, h / 2), 2.5, 1.0)
    m[:, 2] += (4, -3)
    moved = cv2.warpAffine(b, m, (w, h), borderMode=cv2.BORDER_REFLECT)
    rule = GroupingRule()
    assert similarity(a, b, rule)[0] >= rule.match
    assert similarity(a, moved, rule, register=False)[0] < rule.match
    c, used = similarity(a, moved, rule)
    assert c >= rule.match and used >= rule.min_visible


def test_two_scenes_a_minute_apart_are_two_sessions(hard):
    infos = {p: read_frame_info(p) for s in hard.sessions for p in s.frames}
    body = [s for s in hard.sessions if s.body.model == "T1"]
    pairs = [(a, b) for a, b in zip(body, body[1:])
             if 0 < infos[b.frames[0]].time - infos[a.frames[-1]].time < 90]
    if not pairs:
        pytest.skip("no neighbouring brackets on this body's card")
    a, b = pairs[0]
    frames = [infos[p] for p in a.frames + b.frames]
    groups, loose = group_by_content(frames, [thumbnail(f.path) for f in frames])
    assert _sets([f.path for f in g.frames] for g in groups) == _sets([a.frames, b.frames])
    assert not loose
    assert sum("starts a session" in r for g in groups for r in g.reasons) == 2


def test_the_search_holds_only_the_open_sessions_thumbnails(hard):
    infos = [read_frame_info(p) for s in hard.sessions for p in s.frames]
    alive, most = [], [0]

    def thumb_of(i):
        most[0] = max(most[0], sum(r() is not None for r in alive))
        t = thumbnail(infos[i].path)
        alive.append(weakref.ref(t))
        return t

    groups, loose = group_by_content(infos, thumb_of)
    assert len(alive) == len(infos)                 # each asked for once
    assert _sets([f.path for f in g.frames] for g in groups) == \
        _sets(s.frames for s in hard.sessions)
    # the open sessions' thumbnails at most (51 of 133 and 37 of 122 on these cards)
    assert most[0] < len(infos) // 2
    gc.collect()
    assert sum(r() is not None for r in alive) == 0    # nothing kept at the end


def test_discovery_keeps_thumbnails_on_disk_and_reads_them_back_exactly():
    """Discovery spools the thumbnails to a temporary file (it holds none of them in
    memory): each reads back byte for byte, in any order, and None stays None."""
    rng = np.random.default_rng(3)
    thumbs = [rng.integers(0, 256, (rng.integers(20, 50), 64), dtype=np.uint8)
              for _ in range(40)] + [None]
    with ThumbnailSpool() as spool:
        keys = [spool.add(t) for t in thumbs]
        assert keys[-1] is None and spool[None] is None
        for k in rng.permutation(40):
            np.testing.assert_array_equal(spool[keys[k]], thumbs[k])


@pytest.fixture(scope="module")
def copied(tmp_path_factory):
    root = tmp_path_factory.mktemp("library")
    lib = write_hard_card(root / "card", seed=TUNING_SEED, events_per_body=2)
    return root, lib, copy_card(lib, root / "backup")


def test_copies_of_a_card_give_each_session_once_from_one_copy(copied):
    root, lib, copy = copied
    found = discover([root])
    got = _sets(s.paths for s in found.sessions)
    assert len(got) == len(lib.sessions)
    assert all(g in _sets(s.frames for s in lib.sessions)
               or g in _sets(s.frames for s in copy.sessions) for g in got)
    assert found.unassigned == []
    n = sum(len(s.frames) for s in lib.sessions)
    assert len(found.copies) == n                   # every frame's other copy, named
    used = {p for s in found.sessions for p in s.paths}
    assert all(skipped not in used and kept in used for skipped, kept in found.copies)
    assert all(any(r.startswith("copies: ") and "skipped in" in r for r in s.reasons)
               for s in found.sessions)


def test_the_time_rule_takes_one_copy_too(copied):
    root, lib, _ = copied
    found = discover([root], by_content=False)
    for s in found.sessions:
        assert len({p.parents[2] for p in s.paths}) == 1        # card/ or backup/
        assert len({p.name for p in s.paths}) == len(s.paths)


def test_dry_run_gives_every_frame_its_reason_and_names_the_copies(copied, tmp_path,
                                                                    capsys):
    root, lib, _ = copied
    code = main(["batch", str(root), "-o", str(tmp_path / "out"), "--dry-run"])
    err = capsys.readouterr().err
    assert code == 0
    n = sum(len(s.frames) for s in lib.sessions)
    assert f"dry run: {len(lib.sessions)} sessions" in err and f"{n} copies skipped" in err
    assert err.count("copy skipped: ") == n
    lines = [x.strip() for x in err.splitlines() if x.startswith("      ")]
    for s in lib.sessions:
        for p in s.frames:
            assert any(x.startswith(p.name + ":") for x in lines), p.name
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("order", ["as shot", "darkest first", "brightest first"])
def test_a_long_bracket_with_black_or_white_ends_is_one_session(hard, order):
    """The frames too dark or bright to compare join the bracket they continue, also
    when the bracket begins with them (30 s between frames: the clock does not help)."""
    from dataclasses import replace

    long = max(hard.sessions, key=lambda s: len(s.frames))
    infos = [read_frame_info(p) for p in long.frames]
    thumbs = {f.path: thumbnail(f.path) for f in infos}
    if all(well_exposed(t) >= GroupingRule().min_visible for t in thumbs.values()):
        pytest.skip("this card's long bracket shows enough at every exposure")
    if order != "as shot":
        infos = sorted(infos, key=lambda f: f.relative_exposure,
                       reverse=order == "brightest first")
        infos = [replace(f, time=1e9 + 30.0 * k) for k, f in enumerate(infos)]
    groups, loose = group_by_content(infos, [thumbs[f.path] for f in infos])
    assert [len(g.frames) for g in groups] == [len(infos)] and not loose
    cont = [r for r in groups[0].reasons if "to compare" in r]
    assert cont and groups[0].unsure
    for r in cont:                      # stops past the session's end, in its direction
        stops = float(r.split("(", 2)[2].split(" stops")[0])
        assert 0 < stops <= GroupingRule().continue_stops + 1e-9
