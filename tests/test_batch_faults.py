"""``selfcal batch`` on a real cluster, with real faults: processes, signals, files.

The cluster: a scheduler and two single-threaded workers started as separate processes
with Dask's own command-line tools (``python -m distributed.cli.dask_scheduler`` and
``dask_worker``, what ``dask scheduler`` / ``dask worker`` run), without nannies so
that a SIGKILL takes a worker away for good; the tests share it, and the SIGKILL test
adds a third worker and kills that one.  The batch: ``selfcal batch --scheduler
tcp://...`` in its own process.  Tasks carry paths; the workers read the frames
themselves.  The card: simulated, tiny frames (48 x 72), so that each test takes
seconds.

Every test ends with a manifest that names every session and no partial output (no
temporary file, no session folder without its record) anywhere.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import selfcal
import selfcal_cli
from selfcal.batch import discover
from selfcal.batch.faults import JOURNAL
from selfcal.sim.cards import Shots, write_library

distributed = pytest.importorskip("distributed", reason='needs pip install "selfcal[batch]"')

#: A cluster of processes and a batch in its own, killed and signalled: `-m slow` (.ci/run);
#: test_batch.py keeps the faults of a session in the default run.
pytestmark = pytest.mark.slow

SHOTS = Shots(height=48, width=72)


def _env() -> dict:
    """This interpreter's view of selfcal for the child processes (PYTHONPATH first)."""
    paths = [str(Path(m.__file__).parent.parent) for m in (selfcal, selfcal_cli)]
    old = os.environ.get("PYTHONPATH", "")
    return {**os.environ, "PYTHONPATH": os.pathsep.join(dict.fromkeys(
        paths + ([old] if old else [])))}


class Cluster:
    """A scheduler and workers as separate processes (Dask's CLI), stopped by their pid."""

    def __init__(self, folder: Path, n_workers: int = 2):
        self.folder = folder
        self.file = folder / "scheduler.json"
        self.procs = []
        self.scheduler = self._start("dask_scheduler", "--host", "127.0.0.1", "--port", "0",
                                     "--no-dashboard", "--scheduler-file", str(self.file))
        deadline = time.time() + 60
        while not self.file.exists():
            assert time.time() < deadline, "the scheduler did not start"
            assert self.scheduler.poll() is None, self._log("scheduler")
            time.sleep(0.2)
        self.address = json.loads(self.file.read_text())["address"]
        self.workers = [self.add_worker(f"w{i}") for i in range(n_workers)]
        self.client = distributed.Client(self.address, timeout="30s")
        self.client.wait_for_workers(n_workers, timeout=90)

    def _start(self, tool, *args, name=None):
        log = open(self.folder / f"{name or tool}.log", "w")
        p = subprocess.Popen([sys.executable, "-m", f"distributed.cli.{tool}", *args],
                             stdout=log, stderr=subprocess.STDOUT, env=_env())
        self.procs.append(p)
        return p

    def _log(self, name) -> str:
        return (self.folder / f"{name}.log").read_text()[-2000:]

    def add_worker(self, name):
        return self._start("dask_worker", "--scheduler-file", str(self.file), "--nthreads",
                           "1", "--no-nanny", "--no-dashboard", "--name", name,
                           "--memory-limit", "0", name=name)

    def pids(self) -> dict:
        """Worker address → pid."""
        return self.client.run(os.getpid)

    def idle(self, timeout=60.0) -> None:
        """Wait until no worker processes a task (work of a client that left included)."""
        deadline = time.time() + timeout
        while any(self.client.processing().values()):
            assert time.time() < deadline, "the cluster stays busy"
            time.sleep(0.2)

    def close(self):
        self.client.close()
        for p in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=3)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """Shared by the tests; the SIGKILL test kills a worker of its own."""
    c = Cluster(tmp_path_factory.mktemp("cluster"))
    yield c
    c.close()


def _batch(root, out, address, *extra):
    """``selfcal batch`` in its own process (its output in ``out.log``)."""
    log = open(str(out) + ".log", "w")
    return subprocess.Popen([sys.executable, "-m", "selfcal_cli", "batch", str(root), "-o",
                             str(out), "--scheduler", address, *extra], stdout=log,
                            stderr=subprocess.STDOUT, env=_env())


def _text(out) -> str:
    return Path(str(out) + ".log").read_text()


def _manifest(out) -> dict:
    lines = (Path(out) / "manifest.jsonl").read_text().splitlines()
    return {r["session"]: r for r in map(json.loads, lines)}


def _no_partial_output(out, rows) -> None:
    """No temporary file; a session folder only with its record and every output."""
    leftovers = [p for p in Path(out).rglob(".*") if p.is_file()]
    assert leftovers == []
    assert not (Path(out) / JOURNAL).exists()
    for folder in (Path(out) / "sessions").iterdir():
        if folder.is_file():             # the obstacle of the unwritable-output test
            continue
        record = json.loads((folder / "session.json").read_text())
        assert record["status"] == "ok"
        assert all(Path(p).is_file() for p in record["outputs"])
        assert rows[folder.name]["status"] in ("ok", "skipped", "interrupted")


@pytest.fixture
def card(tmp_path, request):
    """Ten sessions of two bodies (six with ``@pytest.mark.parametrize("card", [3])``)."""
    per_body = getattr(request, "param", 5)
    return write_library(tmp_path / "card", sessions_per_body=per_body, shots=SHOTS)


def _wait(proc, timeout=240):
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise


def test_a_worker_killed_mid_run_its_sessions_run_elsewhere(card, cluster, tmp_path):
    before = set(cluster.pids())
    killed = cluster.add_worker("victim")
    cluster.client.wait_for_workers(len(before) + 1, timeout=90)
    pids = cluster.pids()
    victim = next(a for a in pids if a not in before)
    assert pids[victim] == killed.pid
    out = tmp_path / "out"
    proc = _batch(card.root, out, cluster.address)
    deadline = time.time() + 120
    while not cluster.client.processing().get(victim):
        assert proc.poll() is None and time.time() < deadline, _text(out)
        time.sleep(0.05)
    held = list(cluster.client.processing()[victim])
    killed.send_signal(signal.SIGKILL)
    code = _wait(proc)
    text = _text(out)
    assert code == 0, text
    assert "Traceback" not in text
    assert held, "the killed worker held a task"
    rows = _manifest(out)
    assert len(rows) == len(card.sessions) == 10
    assert set(cluster.pids()) == before          # the others still serve
    assert {r["status"] for r in rows.values()} == {"ok"}
    assert not any(r["worker"].endswith(f":{proc.pid}") for r in rows.values())
    survivors = {pids[a] for a in before}
    late = [r for r in rows.values() if int(r["worker"].rsplit(":", 1)[1]) in survivors]
    assert late, "the surviving workers finished sessions"
    assert killed.wait(timeout=10) == -signal.SIGKILL
    _no_partial_output(out, rows)


def test_client_sigterm_keeps_what_is_done_and_the_rerun_does_the_rest(card, cluster,
                                                                       tmp_path):
    out = tmp_path / "out"
    proc = _batch(card.root, out, cluster.address)
    journal = out / JOURNAL
    deadline = time.time() + 120
    while not (journal.exists() and len(journal.read_text().splitlines()) >= 2):
        assert proc.poll() is None and time.time() < deadline, _text(out)
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    code = _wait(proc)
    text = _text(out)
    assert code == 143, text
    assert "interrupted" in text and "Traceback" not in text
    cluster.idle()                     # tasks running when the client left finish
    rows = _manifest(out)
    assert len(rows) == len(card.sessions)
    status = [r["status"] for r in rows.values()]
    assert status.count("ok") >= 2 and status.count("interrupted") >= 1
    _no_partial_output(out, rows)
    finished = {f.name: {p: Path(p).stat().st_mtime_ns for p in json.loads(
        (f / "session.json").read_text())["outputs"]} for f in (out / "sessions").iterdir()}
    again = _batch(card.root, out, cluster.address)
    assert _wait(again) == 0, _text(out)
    rows = _manifest(out)
    assert len(rows) == len(card.sessions)
    for sid, row in rows.items():
        if sid in finished:
            assert row["status"] == "skipped", sid
            assert {p: Path(p).stat().st_mtime_ns for p in finished[sid]} == finished[sid]
        else:
            assert row["status"] == "ok", sid
    assert f"{len(card.sessions) - len(finished)} done, {len(finished)} skipped" in _text(out)
    _no_partial_output(out, rows)


@pytest.mark.parametrize("card", [3], indirect=True)
def test_an_unwritable_output_and_a_corrupt_frame_fail_their_sessions_only(card, cluster,
                                                                            tmp_path):
    out = tmp_path / "out"
    sessions = discover([card.root]).sessions
    corrupt = sessions[0].frames[2].path
    data = corrupt.read_bytes()
    corrupt.write_bytes(data[: len(data) // 2])
    blocked = out / "sessions" / sessions[-1].id
    blocked.parent.mkdir(parents=True)
    blocked.write_text("a file where the session's folder goes")
    code = _wait(_batch(card.root, out, str(cluster.file)))      # the scheduler file
    text = _text(out)
    assert code == 6, text
    assert cluster.address in text
    assert "Traceback" not in text
    rows = _manifest(out)
    assert len(rows) == len(card.sessions)
    bad = rows.pop(sessions[0].id)
    assert bad["status"] == "failed" and corrupt.name in bad["error"]
    assert "truncated" in bad["error"]
    unwritable = rows.pop(sessions[-1].id)
    assert unwritable["status"] == "failed"
    assert str(blocked) in unwritable["error"] and "cannot be written" in unwritable["error"]
    assert {r["status"] for r in rows.values()} == {"ok"}
    assert not (out / "sessions" / sessions[0].id).exists()
    assert blocked.read_text().startswith("a file")
    _no_partial_output(out, _manifest(out))
