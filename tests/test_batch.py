"""``selfcal batch`` on a real Dask LocalCluster over a simulated photo library.

The library (:func:`selfcal.sim.cards.write_library`): two camera bodies with
different responses, three bracketed sessions each, EXIF as cameras write it, every
frame flat in two ``DCIM`` folders (sessions cross them); one session of the first body
is rendered with another curve (a picture style EXIF does not tell: it must be flagged),
one frame of the second body is truncated (its session must fail, alone), plus a
paired raw, an unpaired raw, a lone frame and a text file.

The cluster: ``LocalCluster(n_workers=2, threads_per_worker=1, processes=True)``, the
default of ``selfcal batch``.  It starts in ~4 s here (each worker process then imports
selfcal once, ~2 s), which the whole module shares.
"""

from __future__ import annotations

import io
import json
import logging
import os
import shutil
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.batch import ClusterOptions, discover, run_batch
from selfcal.sim.cards import camera_exif, default_bodies, write_library
from selfcal_cli.main import main


BROKEN = "DSC_0008.JPG"     # the third frame of the second body's second session


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """The simulated card dump and its truth (frames of each session, per body)."""
    import piexif

    root = tmp_path_factory.mktemp("card")
    bodies = default_bodies()
    styled = sim.default_pipeline(curves=sim.ToneCurve.srgb(), seed=1)
    lib = write_library(root, bodies=bodies, sessions_per_body=3, pipelines={(0, 2): styled})
    dcim = root / "DCIM" / "100SIMCM"
    broken = dcim / BROKEN
    data = broken.read_bytes()
    broken.write_bytes(data[: len(data) * 2 // 3])
    # a raw beside a session frame, a raw alone, a lone frame, a text file
    (dcim / "IMG_0001.CR2").write_bytes(b"II*\x00 not really a raw")
    (dcim / "IMG_9999.CR2").write_bytes(b"II*\x00 not really a raw")
    (root / "DCIM" / "README.txt").write_text("card notes")
    lone = dcim / "IMG_0100.JPG"
    out = io.BytesIO()
    piexif.insert(camera_exif(bodies[0], when=datetime(2024, 5, 1, 15, 0, 0),
                              exposure_time=1 / 60), (dcim / "IMG_0002.JPG").read_bytes(), out)
    lone.write_bytes(out.getvalue())
    return {"root": root, "lib": lib, "broken": broken, "lone": lone,
            "raw": dcim / "IMG_0001.CR2", "unpaired_raw": dcim / "IMG_9999.CR2"}


@pytest.fixture(scope="module")
def client():
    """A real LocalCluster of two worker processes (only the tests that use it need Dask)."""
    distributed = pytest.importorskip("distributed",
                                      reason='needs pip install "selfcal[batch]"')
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def batch(library, client, tmp_path_factory):
    out = tmp_path_factory.mktemp("batch")
    result = run_batch([library["root"]], out, cluster=ClusterOptions(client=client))
    return {"out": out, "result": result, "rows": {r["session"]: r for r in result.rows}}


def _session_of(rows, frame: Path) -> dict:
    return next(r for r in rows.values() if str(frame) in r["frames"])


# ------------------------------------------------------------------------ discovery

def test_discovery_groups_the_card_exactly(library):
    found = discover([library["root"]])
    truth = sorted(tuple(str(p) for p in s.frames) for s in library["lib"].sessions)
    assert sorted(tuple(str(p) for p in s.paths) for s in found.sessions) == truth
    assert len({s.camera for s in found.sessions}) == 2
    for s in found.sessions:          # one body per session, named by its EXIF
        assert len({f.serial for f in s.frames}) == 1
        assert {f.path.parent.name for f in s.frames} <= {"100SIMCM", "101SIMCM"}
    crossing = [s for s in found.sessions if len({f.path.parent for f in s.frames}) == 2]
    assert crossing, "the simulated card has sessions across its two folders"
    first = next(s for s in found.sessions if s.frames[0].path.name == "IMG_0001.JPG")
    assert first.raws == [library["raw"]]
    assert first.frames[0].lens == "Simlens 35mm F2" and first.frames[0].iso == 100
    assert first.exposure_times == pytest.approx([1 / 250, 1 / 60, 1 / 15, 1 / 4, 1.0],
                                                 rel=1e-4)
    why = {p.name: reason for p, reason in found.unassigned}
    assert set(why) == {"IMG_0100.JPG", "IMG_9999.CR2", "README.txt"}
    assert "single frame" in why["IMG_0100.JPG"]
    assert "raw file without a rendered image" in why["IMG_9999.CR2"]
    assert "not an image" in why["README.txt"]


def test_a_repeated_exposure_starts_the_next_bracket(library):
    """Two brackets shot back to back (no time gap) are two sessions."""
    frames = discover([library["root"]]).sessions[0].frames
    from dataclasses import replace

    twice = frames + [replace(f, path=f.path.with_name("X" + f.path.name),
                              time=f.time + 12.0) for f in frames]
    from selfcal.batch import group_sessions

    sessions, loose = group_sessions(twice, max_gap=30.0)
    assert [len(s.frames) for s in sessions] == [5, 5] and not loose


# ------------------------------------------------------------------------ the pooled fit

def test_pooled_fit_of_one_session_is_the_single_session_solve(library):
    from selfcal.batch.pooled import fit_shared_response, session_samples
    from selfcal.response.basis import builtin_basis
    from selfcal.response.solver import SolverOptions, solve_exposure_equations
    from selfcal.stack.samples import SampleSet

    s = library["lib"].sessions[0]
    samples = session_samples(s.frames, s.exposure_times, session="a")
    fit = fit_shared_response([samples])
    alone = solve_exposure_equations(
        SampleSet(values=samples.values.astype(float), block_max=None, block_min=None,
                  flatness=None, locations=None, max_code=255, sources=samples.sources,
                  block=1, frame_shape=(1, 1)),
        builtin_basis(), samples.log_times, options=SolverOptions(n_components=5),
        masks={"clipped": samples.clipped, "saturated": samples.saturated})
    assert np.array_equal(fit.coefficients, alone.coefficients)


# ------------------------------------------------------------------------ the batch

def test_every_session_done_but_the_broken_one(batch, library):
    rows = batch["rows"]
    assert len(rows) == 6
    broken = _session_of(rows, library["broken"])
    assert broken["status"] == "failed"
    assert BROKEN in broken["error"] and "truncated" in broken["error"]
    others = [r for r in rows.values() if r is not broken]
    assert [r["status"] for r in others] == ["ok"] * 5
    for r in others:
        assert all(Path(p).is_file() for p in r["outputs"])
    assert not (Path(batch["out"]) / "sessions" / broken["session"]).exists()
    assert broken["session"] in {r["session"] for r in batch["result"].failed}


def test_the_session_of_another_curve_is_flagged_and_fitted_alone(batch, library):
    rows = batch["rows"]
    styled = library["lib"].sessions[4]          # body 0, session 2 (bodies alternate)
    assert styled.pipeline is not styled.body.pipeline
    row = _session_of(rows, styled.frames[0])
    assert row["flagged"] and row["model_kind"] == "own"
    assert row["agreement_shared"] > 1.5 * row["agreement_own"]
    assert Path(row["model_file"]).parent.name == row["session"]
    for r in rows.values():
        if r["status"] == "ok" and r is not row:
            assert r["model_kind"] == "camera" and not r["flagged"] and r["pooled"]
            assert r["agreement_shared"] < 1.5 * r["agreement_own"]


def test_the_manifest_is_read_by_plain_json_and_csv(batch, library):
    import csv

    out = Path(batch["out"])
    lines = (out / "manifest.jsonl").read_text().splitlines()
    rows = [json.loads(x) for x in lines]
    assert sorted(r["session"] for r in rows) == sorted(batch["rows"])
    assert all(isinstance(r["frames"], list) for r in rows)
    with open(out / "manifest.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [t["session"] for t in table] == [r["session"] for r in rows]
    assert {t["status"] for t in table} == {"ok", "failed"}
    with open(out / "cameras.csv", newline="") as fh:
        cams = list(csv.DictReader(fh))
    assert sorted(c["camera_label"] for c in cams) == ["Simcam S1 #1001", "Simcam S2 #2002"]
    assert [int(c["failed"]) for c in cams] == [0, 1]
    with open(out / "unassigned.csv", newline="") as fh:
        loose = {Path(t["path"]).name: t["reason"] for t in csv.DictReader(fh)}
    assert "single frame" in loose["IMG_0100.JPG"]


def _read(path):
    from selfcal.hdr.io import read_radiance

    return read_radiance(path)


def test_outputs_identical_to_calibrate_and_merge_by_hand(batch, tmp_path, capsys):
    rows = batch["rows"]
    pooled = next(r for r in rows.values() if r["model_kind"] == "camera")
    alone = next(r for r in rows.values() if r["model_kind"] == "own")
    folder = Path(batch["out"]) / "sessions"
    # a pooled session: `selfcal merge --model <the camera's model>`
    exr, jpg = tmp_path / "p.exr", tmp_path / "p.jpg"
    assert main(["merge", *pooled["frames"], "--model", pooled["model_file"], "-o", str(exr),
                 "--preview", str(jpg)]) == 0
    mine = folder / pooled["session"]
    assert np.array_equal(_read(exr), _read(mine / "radiance.exr"))
    assert jpg.read_bytes() == (mine / "preview.jpg").read_bytes()
    # a session fitted alone: `selfcal calibrate`, then `selfcal merge`
    model, exr2 = tmp_path / "m.json", tmp_path / "a.exr"
    assert main(["calibrate", *alone["frames"], "-o", str(model)]) == 0
    assert main(["merge", *alone["frames"], "--model", str(model), "-o", str(exr2)]) == 0
    capsys.readouterr()
    by_hand = json.loads(model.read_text())
    batch_model = json.loads(Path(alone["model_file"]).read_text())
    # Dask's workers run BLAS with one thread, this process with more: with some BLAS builds
    # (OpenBLAS of numpy 1.26) the solve's last bits differ (scripts/golden_spread.py)
    np.testing.assert_allclose(by_hand["inverse_response"], batch_model["inverse_response"],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(_read(exr2), _read(folder / alone["session"] / "radiance.exr"),
                               rtol=1e-6)


def test_a_rerun_skips_finished_sessions_and_retries_the_failed(batch, library, client):
    out = Path(batch["out"])
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()
              and p.parent.parent.name in ("sessions", "cameras")}
    again = run_batch([library["root"]], out, cluster=ClusterOptions(client=client))
    status = {r["session"]: r["status"] for r in again.rows}
    broken = _session_of(batch["rows"], library["broken"])["session"]
    assert status.pop(broken) == "failed"
    assert set(status.values()) == {"skipped"}
    after = {p: p.stat().st_mtime_ns for p in before}
    assert after == before
    # a frame copied anew (newer than the outputs) redoes its camera, not the other
    touched = library["lib"].sessions[1].frames[0]          # second body
    stamp = touched.stat()
    later = time.time() + 2           # now, as a copy would be
    os.utime(touched, (later, later))
    try:
        third = run_batch([library["root"]], out, cluster=ClusterOptions(client=client))
    finally:
        # the library is shared: a frame from the future would make the outputs of a
        # later test that copies it (mtimes kept) look older than their input
        os.utime(touched, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
    for r in third.rows:
        expected = ("skipped" if r["camera"].startswith("simcam-s1")
                    else "failed" if r["session"] == broken else "ok")
        assert r["status"] == expected, r["session"]


def test_cli_batch_on_a_running_scheduler(library, client, tmp_path, capsys):
    """--scheduler ADDRESS, --linearize, an output folder inside the root it walks."""
    root = tmp_path / "card"
    shutil.copytree(library["root"] / "DCIM", root / "DCIM")
    (root / "DCIM" / "100SIMCM" / BROKEN).unlink()        # its session now has 4 frames
    out = root / "batch"
    argv = ["batch", str(root), "-o", str(out), "--scheduler", client.scheduler.address,
            "--no-pool", "--linearize"]
    code = main(argv)
    text = capsys.readouterr().err
    assert code == 0, text
    assert "sessions: 6 (6 done, 0 skipped" in text
    assert "wrote " + str(out / "manifest.csv") in text
    rows = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    for r in rows:
        linear = sorted(p.name for p in (out / "sessions" / r["session"] / "linear").iterdir())
        assert linear == sorted(Path(f).stem + ".tif" for f in r["frames"])
    assert main(argv) == 0                  # again: all skipped, its own outputs not found
    assert "sessions: 6 (0 done, 6 skipped" in capsys.readouterr().err
    assert str(out) not in (out / "unassigned.csv").read_text()


def test_cli_says_how_to_install_dask_when_it_is_missing(library, tmp_path, capsys,
                                                         monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)
    code = main(["batch", str(library["root"]), "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 7
    assert 'pip install "selfcal[batch]"' in err and "Traceback" not in err


def test_cli_exit_code_says_some_sessions_failed(library, tmp_path, capsys):
    """The broken session alone, without Dask: exit 6, the session and file named."""
    root = tmp_path / "card"
    root.mkdir()
    session = next(s for s in library["lib"].sessions if library["broken"] in s.frames)
    for f in session.frames:
        shutil.copy2(f, root / f.name)
    code = main(["batch", str(root), "-o", str(tmp_path / "out"), "--scheduler", "serial"])
    err = capsys.readouterr().err
    assert code == 6
    assert "failed: simcam-s2-2002" in err and BROKEN in err and "truncated" in err


def test_a_plot_per_camera_beside_cameras_csv(batch, library):
    """Each session's own curve over the pooled one; the flagged session stands out."""
    import csv

    from PIL import Image

    from selfcal.batch.camera_plot import CURVE_POINTS, _shared_curve

    out = Path(batch["out"])
    with open(out / "cameras.csv", newline="") as fh:
        cams = list(csv.DictReader(fh))
    for cam in cams:
        plot = Path(cam["plot"])
        assert plot.parent == out and plot.name == f"camera-{cam['camera']}.png"
        with Image.open(plot) as im:
            assert im.format == "PNG" and im.size[0] > 400
    rows = batch["rows"]
    styled = _session_of(rows, library["lib"].sessions[4].frames[0])
    shared = np.array(_shared_curve(styled["model"] if "model" in styled else
                                    next(c["model_file"] for c in cams
                                         if c["camera"] == styled["camera"])))

    def off(row):
        return float(np.abs(np.array(row["own_curve"]) - shared).max())

    same = [r for r in rows.values() if r["camera"] == styled["camera"]
            and r["status"] == "ok" and not r["flagged"]]
    for r in same + [styled]:
        curve = np.array(r["own_curve"])
        assert curve.shape == (CURVE_POINTS,) and np.all(np.diff(curve) >= -1e-6)
    assert off(styled) > 2 * max(off(r) for r in same)


def test_a_cameras_reference_scale_puts_its_sessions_in_cd_m2(library, tmp_path, capsys):
    """--luminance-scale CAMERA=MODEL.json: that camera's sessions come out in cd/m² with
    the stored constant, the other camera's stay relative; a model without a scale is
    refused (exit 2, the file named) before any work."""
    import dataclasses

    from selfcal.lens import LuminanceScale

    root = tmp_path / "card"
    root.mkdir()
    by_body = {}
    for s in library["lib"].sessions:
        if library["broken"] not in s.frames:
            by_body.setdefault(s.body.model, s)
    for s in by_body.values():
        for f in s.frames:
            shutil.copy2(f, root / f.name)
    model = selfcal.calibrate_response(by_body["S1"].frames)
    plain = model.save(tmp_path / "plain.json")
    scale = LuminanceScale(scale=3.5, log_sigma=0.03, source="reference",
                           description="test: a spot meter")
    scaled = dataclasses.replace(model, luminance=scale).save(tmp_path / "scaled.json")

    with pytest.raises(SystemExit) as exited:
        main(["batch", str(root), "-o", str(tmp_path / "never"), "--scheduler", "serial",
              "--luminance-scale", f"S1={plain}"])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and "plain.json" in err and "no luminance scale" in err
    assert not (tmp_path / "never").exists()

    out = tmp_path / "out"
    code = main(["batch", str(root), "-o", str(out), "--scheduler", "serial", "--no-pool",
                 "--luminance-scale", f"S1={scaled}"])
    assert code == 0, capsys.readouterr().err
    rows = [json.loads(x) for x in (out / "manifest.jsonl").read_text().splitlines()]
    units = {r["camera_label"].split()[1]: (r["units"], r.get("luminance_scale"))
             for r in rows}
    assert units["S1"] == ("cd/m2", pytest.approx(3.5))
    assert units["S2"][0] == "relative"
