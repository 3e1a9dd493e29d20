"""``selfcal batch`` on a card of RAW+JPEG brackets: one RAW-path model per camera.

The card (:func:`selfcal.sim.raw_cards.write_raw_card`): three scenes by one simulated
body, each a two-frame bracket with a LinearRaw DNG beside each JPEG.  The batch runs on
a real Dask LocalCluster (two worker processes); reruns and the unwritable output run in
process (``scheduler="serial"``).  The truth is the body's pipeline; the independent
implementation the batch is checked against is the library call
(:func:`selfcal.pipeline.library.fit_pipeline_library`) in this process.
"""

from __future__ import annotations

import json
import logging
import os
import shutil

import numpy as np
import pytest

from selfcal.batch import BatchOptions, ClusterOptions, run_batch
from selfcal.batch.raw_camera import (RAW_COLUMNS, RAW_MODEL, RawLibraryOptions,
                                      plan_raw_cameras, raw_camera_samples)
from selfcal.batch.run import plan_batch
from selfcal.batch.discover import discover
from selfcal.pipeline import PipelineOptions
from selfcal.pipeline.library import LibraryOptions, fit_pipeline_library
from selfcal.sim.raw_cards import raw_card_scene, write_raw_card

# small fits (few samples, three matrix sets) keep the tests fast; the bench runs the defaults
RAW = RawLibraryOptions(fit=LibraryOptions(
    smoothness_grid=(1e-5, 1e-3), scene_samples=300,
    pipeline=PipelineOptions(n_sets=3, backward="lut")))
OPTIONS = BatchOptions(raw_library=RAW)
#: One λ: the unwritable-output test needs a fit, not a choice.
ONE = BatchOptions(raw_library=RawLibraryOptions(fit=LibraryOptions(
    smoothness_grid=(1e-5,), scene_samples=300,
    pipeline=PipelineOptions(n_sets=3, backward="lut"))))


@pytest.fixture(scope="module")
def card(tmp_path_factory):
    return write_raw_card(tmp_path_factory.mktemp("rawcard"), n_scenes=3)


@pytest.fixture(scope="module")
def batch(card, tmp_path_factory):
    distributed = pytest.importorskip("distributed",
                                      reason='needs pip install "selfcal[batch]"')
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=None, silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    out = tmp_path_factory.mktemp("rawbatch")
    try:
        result = run_batch([card.root], out, cluster=ClusterOptions(client=client),
                           options=OPTIONS)
    finally:
        client.close()
        cluster.close()
    return {"out": out, "result": result, "camera": result.cameras[0]}


def _camera_rows(out):
    return [json.loads(line) for line in (out / "cameras.jsonl").read_text().splitlines()]


# slow: the card's batch on a two-process LocalCluster (module fixture)
@pytest.mark.slow
def test_the_camera_model_is_written_beside_the_curve_with_its_loso_figures(batch, card):
    out, cam = batch["out"], batch["camera"]
    assert {r["status"] for r in batch["result"].rows} == {"ok"}
    folder = out / "cameras" / cam["camera"]
    assert cam["raw_model_file"] == str(folder / RAW_MODEL)
    assert (folder / "model.json").is_file() and (folder / RAW_MODEL).is_file()
    assert cam["raw_fit_error"] == "" and len(cam["raw_scenes"]) == len(card.scenes)
    row = _camera_rows(out)[0]
    for k in ("raw_loso_forward", "raw_training_forward", "raw_loso_backward",
              "raw_training_backward"):
        assert np.isfinite(row[k]) and row[k] > 0
    assert row["raw_smoothness"] in (1e-5, 1e-3)
    assert [s["scene"] for s in row["raw_scene_errors"]] == row["raw_scenes"]
    # the training scenes' error is the mean of the scenes' (each scene weighs the same)
    assert row["raw_loso_forward"] == pytest.approx(
        np.mean([s["loso_forward"] for s in row["raw_scene_errors"]]))
    header = (out / "cameras.csv").read_text().splitlines()[0].split(",")
    assert set(RAW_COLUMNS) <= set(header)
    assert os.path.getsize(row["plot"]) > 10_000


@pytest.mark.slow
def test_the_model_renders_a_scene_it_never_saw_close_to_the_truth(batch, card):
    import selfcal
    from selfcal import sim

    model = selfcal.load_model(batch["camera"]["raw_model_file"])
    scene = raw_card_scene(("ramps", 0.5), 96, 144, seed=777)
    pair = sim.simulate_raw_jpeg_pair(scene, card.body.pipeline, exposure=0.8, seed=777)
    truth = card.body.pipeline.render(pair["raw"])
    err = np.sqrt(np.mean((model.render(pair["raw"]) - truth) ** 2)) * 255
    # three small training scenes: a few codes (a model that ignored the raw is ~60 off)
    assert err < 6.0, err


@pytest.mark.slow
def test_batch_model_is_the_library_call_and_cli_reads_it(batch, card, tmp_path):
    """The fit in a worker process equals the library call here (λ, figures, model), and
    ``selfcal to-raw`` / ``render`` with the batch's file give what the library's gives."""
    from selfcal.io import read_image, write_image
    from selfcal.io.raw import read_raw_linear
    from selfcal_cli.main import main

    plans, _ = plan_batch(discover([card.root]), batch["out"], OPTIONS)
    plan = next(iter(plan_raw_cameras(plans, batch["out"], RAW).values()))
    scenes, skipped = raw_camera_samples(plan, RAW, seed=OPTIONS.seed)
    assert skipped == {}
    lib = fit_pipeline_library(scenes, RAW.fit, seed=OPTIONS.seed)
    row = _camera_rows(batch["out"])[0]
    assert lib.smoothness == row["raw_smoothness"]
    assert lib.loso_forward == pytest.approx(row["raw_loso_forward"], rel=1e-9)
    dng, jpg = card.scenes[1].raws[0], card.scenes[1].frames[0]
    model_file = batch["camera"]["raw_model_file"]
    assert main(["to-raw", "--model", model_file, str(jpg), "-o", str(tmp_path / "raw"),
                 "--float"]) == 0
    got = read_raw_linear(tmp_path / "raw" / (jpg.stem + ".tiff")).rgb
    np.testing.assert_allclose(got, lib.model.to_raw(read_image(jpg)), atol=1e-5)
    assert main(["render", "--model", model_file, str(dng), "-o", str(tmp_path / "jpg"),
                 "--quality", "100"]) == 0
    codes = np.clip(np.round(lib.model.render(read_raw_linear(dng).rgb) * 255), 0, 255)
    write_image(tmp_path / "want.jpg", codes.astype(np.uint8), jpeg_quality=100)
    # the same codes through the same JPEG encoder: the same file content
    np.testing.assert_array_equal(read_image(tmp_path / "jpg" / (dng.stem + ".jpg")),
                                  read_image(tmp_path / "want.jpg"))


@pytest.mark.slow
def test_a_rerun_reuses_the_camera_model(batch, card):
    out = batch["out"]
    model = out / "cameras" / batch["camera"]["camera"] / RAW_MODEL
    made = model.stat().st_mtime_ns
    again = run_batch([card.root], out, scheduler="serial", options=OPTIONS)
    cam = again.cameras[0]
    assert cam["raw_fit_reused"] and cam["raw_model_file"] == str(model)
    assert model.stat().st_mtime_ns == made
    assert {r["status"] for r in again.rows} == {"skipped"}
    assert _camera_rows(out)[0]["raw_loso_forward"] == batch["camera"]["raw_loso_forward"]


# slow: two batches with a RAW-path fit each (leaving the library out stays fast)
@pytest.mark.slow
def test_an_unwritable_model_fails_its_fit_cleanly_and_the_rerun_writes_it(card, tmp_path):
    out = tmp_path / "out"
    plans, _ = plan_batch(discover([card.root]), out, ONE)
    camera = plans[0].camera
    blocked = out / "cameras" / camera / RAW_MODEL
    blocked.mkdir(parents=True)                   # a folder where the model goes
    (blocked / "keep").write_text("not empty: the sweep of leftovers keeps it")
    first = run_batch([card.root], out, scheduler="serial", options=ONE)
    cam = first.cameras[0]
    assert {r["status"] for r in first.rows} == {"ok"}      # the sessions are not hurt
    assert cam["raw_model_file"] == "" and str(blocked) in cam["raw_fit_error"]
    assert not (out / "cameras" / camera / "raw_camera.json").exists()
    assert [p for p in out.rglob(".*") if p.is_file()] == []
    shutil.rmtree(blocked)
    second = run_batch([card.root], out, scheduler="serial", options=ONE)
    assert second.cameras[0]["raw_fit_error"] == "" and blocked.is_file()
    assert not second.cameras[0]["raw_fit_reused"]
    assert {r["status"] for r in second.rows} == {"skipped"}


# slow: two batches with a RAW-path fit
@pytest.mark.slow
def test_a_raw_fit_lost_on_the_cluster_is_recorded_and_the_rerun_fits_it(card, tmp_path,
                                                                         monkeypatch):
    """A RAW-path task that dies (as with its worker) fails that fit only: the sessions
    finish, the camera row says why, nothing is written for it, and a rerun fits it."""
    from selfcal.batch import cluster

    def dies(*args):
        raise RuntimeError("worker lost")

    out = tmp_path / "out"
    monkeypatch.setattr(cluster, "fit_raw_camera", dies)
    first = run_batch([card.root], out, scheduler="serial", options=ONE)
    assert {r["status"] for r in first.rows} == {"ok"}
    cam = first.cameras[0]
    assert "failed on the cluster" in cam["raw_fit_error"] and "worker lost" in \
        cam["raw_fit_error"]
    assert not (out / "cameras" / cam["camera"] / RAW_MODEL).exists()
    monkeypatch.undo()
    second = run_batch([card.root], out, scheduler="serial", options=ONE)
    assert second.cameras[0]["raw_fit_error"] == ""
    assert (out / "cameras" / cam["camera"] / RAW_MODEL).is_file()
    assert {r["status"] for r in second.rows} == {"skipped"}


def test_cli_batch_can_leave_the_raw_library_out(card, tmp_path, capsys):
    from selfcal_cli.main import main

    out = tmp_path / "out"
    main(["batch", str(card.root), "-o", str(out), "--scheduler", "serial",
          "--no-raw-library"])
    row = _camera_rows(out)[0]
    assert row["raw_model_file"] == "" and row["raw_scenes"] is None
    assert not list(out.rglob(RAW_MODEL))


# slow: the command line's default RAW-path fit
@pytest.mark.slow
def test_a_card_of_single_raw_jpeg_shots_gets_its_camera_model(tmp_path, capsys):
    """No bracket, so no session: each RAW+JPEG shot is a scene of its camera's library."""
    from selfcal_cli.main import main

    card = write_raw_card(tmp_path / "card", n_scenes=3, lone=3)
    out = tmp_path / "out"
    assert main(["batch", str(card.root), "-o", str(out), "--scheduler", "serial"]) == 0
    said = "".join(capsys.readouterr())
    assert "RAW-path model from 3 scenes" in said and "nothing to do" not in said
    row = _camera_rows(out)[0]
    assert row["sessions"] == 0 and len(row["raw_scenes"]) == 3
    assert all(s.startswith("pair-") for s in row["raw_scenes"])
    assert (out / "cameras" / row["camera"] / RAW_MODEL).is_file()


@pytest.mark.slow
def test_other_fit_settings_fit_again(batch, card):
    from selfcal.batch.raw_camera import reusable_raw_camera_fit

    plans, _ = plan_batch(discover([card.root]), batch["out"], OPTIONS)
    plan = next(iter(plan_raw_cameras(plans, batch["out"], RAW).values()))
    assert reusable_raw_camera_fit(plan, RAW, OPTIONS.seed) is not None
    assert reusable_raw_camera_fit(plan, RAW, OPTIONS.seed + 1) is None
    assert reusable_raw_camera_fit(plan, ONE.raw_library, OPTIONS.seed) is None
