"""What lets ``selfcal batch`` scale, without Dask: bounded work in flight, the journal,
the sweep of leftovers (``selfcal.batch.cluster``, ``selfcal.batch.faults``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from selfcal.batch import ClusterOptions, cluster, run_batch
from selfcal.batch.faults import JOURNAL, Journal, sweep_partial
from selfcal.batch.run import BatchOptions
from selfcal.sim.cards import Shots, write_library


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return write_library(tmp_path_factory.mktemp("card"), sessions_per_body=3,
                         shots=Shots(height=48, width=72))


@pytest.mark.parametrize("in_flight,pool_sessions", [(1, 2), (2, 3)])
def test_work_in_flight_is_bounded_and_the_pooled_fits_still_happen(
        small, tmp_path, monkeypatch, in_flight, pool_sessions):
    """One session under way beyond the pool candidates: no camera waits forever."""
    submitted, done = [], []
    real = cluster.SerialExecutor.submit

    def spy(self, fn, *args, key="", priority=0):
        if key.startswith("prepare-"):
            submitted.append((key, len(done)))
        return real(self, fn, *args, key=key, priority=priority)

    monkeypatch.setattr(cluster.SerialExecutor, "submit", spy)
    result = run_batch([small.root], tmp_path / "out", scheduler="serial",
                       cluster=ClusterOptions(max_in_flight=in_flight),
                       options=BatchOptions(pool_sessions=pool_sessions),
                       progress=lambda *a: done.append(a))
    assert result.count("ok") == 6
    assert all(len(c["pooled_sessions"]) == pool_sessions for c in result.cameras)
    assert {r["model_kind"] for r in result.rows} == {"camera"}
    # beyond the 2 × pool_sessions candidates, a prepare only after a session finished
    first = [k for k, n in submitted if n == 1]       # done[0] is the initial progress
    assert len(first) == min(6, 2 * pool_sessions + in_flight)


def test_the_journal_appends_a_line_per_row_and_is_made_at_the_first(tmp_path):
    journal = Journal(tmp_path / "out")
    assert not (tmp_path / "out").exists()
    sizes = []
    for k in range(3):
        journal.add({"session": f"s{k}", "status": "ok", "frames": ["a", "b"]})
        sizes.append((tmp_path / "out" / JOURNAL).stat().st_size)
    lines = (tmp_path / "out" / JOURNAL).read_text().splitlines()
    assert [json.loads(x)["session"] for x in lines] == ["s0", "s1", "s2"]
    assert sizes[2] - sizes[1] == sizes[1] - sizes[0] > 0       # appended, not rewritten
    journal.close(remove=True)
    assert not (tmp_path / "out" / JOURNAL).exists()


def test_the_sweep_removes_only_temporaries_and_folders_they_alone_held(tmp_path):
    s = tmp_path / "sessions"
    (s / "done").mkdir(parents=True)
    (s / "done" / "radiance.exr").write_bytes(b"x")
    (s / "done" / ".preview.jpg.abc123xy.jpg").write_bytes(b"half")
    (s / "killed" / "linear").mkdir(parents=True)
    (s / "killed" / "linear" / ".f1.tif.q9w8e7r6.tif").write_bytes(b"half")
    (s / "killed" / ".radiance.exr.k2j3h4g5.exr").write_bytes(b"half")
    (s / "user-file").write_text("not ours to remove")
    (tmp_path / "cameras" / "cam").mkdir(parents=True)
    (tmp_path / "cameras" / "cam" / ".model.json.zz11yy22.json").write_text("{")
    removed = sweep_partial(tmp_path)
    assert sorted(p.name for p in removed if p.is_absolute() and p.suffix) == sorted(
        [".preview.jpg.abc123xy.jpg", ".f1.tif.q9w8e7r6.tif", ".radiance.exr.k2j3h4g5.exr",
         ".model.json.zz11yy22.json"])
    assert (s / "done" / "radiance.exr").exists() and (s / "user-file").exists()
    assert not (s / "killed").exists() and not (tmp_path / "cameras" / "cam").exists()
    assert sorted(p.name for p in Path(tmp_path).rglob("*") if p.is_file()) == [
        "radiance.exr", "user-file"]


def test_run_batch_takes_its_settings_as_options_objects(tmp_path):
    """The cluster's settings are ClusterOptions, the sessions' BatchOptions: the 0.x
    keywords are gone (a TypeError); a card without a bracket is nothing to do."""
    card = tmp_path / "card"
    card.mkdir()
    result = run_batch([card], tmp_path / "out", scheduler="serial",
                       cluster=ClusterOptions(workers=2), options=BatchOptions(max_gap=30.0))
    assert result.rows == [] and not (tmp_path / "out").exists()
    with pytest.raises(TypeError, match="workers"):
        run_batch([card], tmp_path / "out", scheduler="serial", workers=2)
