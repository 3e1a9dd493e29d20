"""Path choice (selfcal.calibrate): grouping by name, stack only, pair only, bracketed
RAW+JPEG sessions, and what is missing when neither path applies.

The pipeline path runs the real :func:`selfcal.pipeline.fit_pipeline` (with options that
make it fast, :data:`FAST_FIT`); a recording wrapper only notes what it was given.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import selfcal
import selfcal.choose.paths
from selfcal import sim
from selfcal.choose import PairOptions, calibrate, calibrate_pipeline, group_inputs
from selfcal.errors import CalibrationError, InputError, SelfcalWarning
from selfcal.io import read_image, write_bytes_atomic, write_image
from selfcal.pipeline import PipelineModel, PipelineOptions

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CANON = SHARED / "raw" / "colorchart_canon550d.dng"


#: Options the real fit_pipeline takes that make it fast (about 1 s on 600-1,000 samples
#: instead of about 5-25 s): two matrix sets, the lattice backward variant (no RBF), fixed
#: regulariser weights (no leave-one-out search), a 17³ baked table.
FAST_KNOBS = dict(n_sets=2, backward="lut", bake_size=17, inverse_smoothness=1e-4,
                  lut_smoothness=3e-3)
FAST_FIT = PipelineOptions(**FAST_KNOBS)


def assert_model_fits_its_samples(model, raw, rendered):
    """The fitted pipeline reproduces its own training samples: forwards, backwards, and
    there and back.

    Measured with FAST_FIT (fixtures/pair at seeds 0 and 3, two simulated sessions, two
    simulated pairs): forward RMSE 0.87-1.29 codes, backward median |Δraw| 0.0008-0.0011,
    render(to_raw(P)) median 0.50-1.17 codes.  The floor is the JPEG itself: the true
    pipeline of a simulated pair misses its own samples by median 0.43, p95 1.45 codes.
    A model of another (similar, simulated) camera misses by 2.2-6.5 codes RMSE forwards
    and 0.0012-0.0022 backwards; samples out of correspondence by 53 codes.  Every fit
    here is seeded, so the margins only absorb differences between numerical libraries.
    """
    assert isinstance(model, PipelineModel)
    forward_rmse = np.sqrt(np.mean((model.render(raw) - rendered) ** 2)) * 255
    assert forward_rmse < 1.6
    assert np.median(np.abs(model.to_raw(rendered) - raw)) < 0.0015
    unclipped = np.all((rendered > 0.5 / 255) & (rendered < 254.5 / 255), axis=1)
    cycle = model.render(model.to_raw(rendered[unclipped])) - rendered[unclipped]
    assert np.median(np.abs(cycle)) * 255 < 1.5


def write_raw_tiff(path, raw):
    write_image(path, (np.asarray(raw, np.float64) * 65535).round().astype(np.uint16))


def make_session(folder, times, *, jitter=0.05, raws=True, seed=5, prefix="IMG",
                 raw_suffix=".tiff"):
    """A bracketed session: JPEGs with EXIF (nominal times) and, optionally, raws as
    16-bit linear TIFFs of the same names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scene = sim.make_scene(96, 144, dynamic_range_stops=10.0, saturation=0.5, seed=seed)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=seed), times,
                                 jitter=jitter, jpeg_quality=95, seed=seed)
    jpgs = stack.write(folder, fmt="jpg", prefix=prefix)
    raw_paths = []
    if raws:
        for jpg, raw in zip(jpgs, stack.raws):
            path = jpg.with_suffix(raw_suffix)
            write_raw_tiff(path, raw)
            raw_paths.append(path)
    return stack, jpgs, raw_paths


# ------------------------------------------------------------------ grouping

def test_grouping_by_stem_case_insensitive_same_folder(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    for p in (a / "IMG_1.CR2", a / "img_1.JPG", a / "IMG_2.NEF", b / "IMG_2.jpg",
              a / "IMG_3.jpg", a / "IMG_3.png"):
        p.write_bytes(b"x")
    g = group_inputs([a / "IMG_1.CR2", a / "img_1.JPG", a / "IMG_2.NEF", b / "IMG_2.jpg",
                      a / "IMG_3.png", a / "IMG_3.jpg"])
    assert g.pairs == [(a / "IMG_1.CR2", a / "img_1.JPG")]
    assert g.unpaired_raws == [a / "IMG_2.NEF"]          # its JPEG is in another folder
    assert g.rendered == [a / "img_1.JPG", b / "IMG_2.jpg", a / "IMG_3.png",
                          a / "IMG_3.jpg"]


def test_grouping_16bit_tiff_is_the_raw_of_its_jpeg(tmp_path):
    g = group_inputs([FIXTURES / "pair" / "pair.tiff", FIXTURES / "pair" / "pair.jpg"])
    assert g.pairs == [(FIXTURES / "pair" / "pair.tiff", FIXTURES / "pair" / "pair.jpg")]
    # alone, a 16-bit TIFF is a rendered frame
    g = group_inputs([FIXTURES / "pair" / "pair.tiff"])
    assert g.pairs == [] and g.rendered == [FIXTURES / "pair" / "pair.tiff"]


def test_grouping_folders_duplicates_and_bad_files(tmp_path):
    g = group_inputs([FIXTURES / "stack", FIXTURES / "stack" / "frame_00.jpg"])
    assert len(g.rendered) == 6 and len(g.ignored) == 1
    note = tmp_path / "notes.txt"
    note.write_text("hello")
    with pytest.raises(InputError, match="not an image or raw file") as info:
        group_inputs([note])
    assert "notes.txt" in str(info.value)
    with pytest.raises(InputError, match="no such file"):
        group_inputs([tmp_path / "missing.jpg"])


# ------------------------------------------------------------------ path choice

def test_stack_only_takes_the_response_path(fit_calls):
    result = selfcal.calibrate(sorted((FIXTURES / "stack").glob("*.jpg")))
    assert result.taken == ("response",)
    assert result.response is not None and result.pipeline is None
    assert result.exposure_source == "exif"
    assert result.reasons[0].startswith("response path: 6 JPEGs of one scene at 6 exposures")
    assert not fit_calls and result.n_pipeline_samples == 0


def test_pair_only_takes_the_pipeline_path(fit_calls):
    result = selfcal.calibrate([FIXTURES / "pair" / "pair.tiff",
                                FIXTURES / "pair" / "pair.jpg"], seed=3,
                               pipeline_options=FAST_FIT)
    assert result.taken == ("pipeline",) and result.response is None
    assert result.reasons == [
        "no response path: 1 JPEG (pair.jpg) only",
        f"pipeline path: 1 RAW+JPEG pair(s) (pair.jpg); {result.n_pipeline_samples} samples"]
    (raw, ren, options), = fit_calls
    assert options == {"seed": 3, "progress": None, **FAST_KNOBS}
    assert raw.shape == ren.shape and raw.shape[1] == 3 and len(raw) >= 200
    assert len(raw) == result.n_pipeline_samples == result.pipeline.diagnostics[
        "samples"]["used"]
    assert 0 <= raw.min() and raw.max() < 0.98 and 1 / 255 < ren.min() and ren.max() < 254 / 255
    assert result.pipeline.diagnostics["seed"] == 3
    assert_model_fits_its_samples(result.pipeline, raw, ren)
    # the whole training JPEG, there and back (clipped pixels, where the code does not
    # determine the raw, left out): measured median 0.63 codes
    jpg = read_image(FIXTURES / "pair" / "pair.jpg")
    codes = jpg.reshape(-1, 3).astype(np.float64) / 255
    unclipped = np.all((jpg > 0) & (jpg < 255), axis=2).ravel()
    back = result.pipeline.render(result.pipeline.to_raw(jpg)).reshape(-1, 3)
    assert np.median(np.abs(back - codes)[unclipped]) * 255 < 1.5
    (pair,) = result.pairs
    assert pair.registration.ok and abs(pair.registration.scale - 1) < 0.005
    assert any("pair pair.tiff + pair.jpg" in line for line in result.summary_lines())


def test_bracketed_raw_jpeg_session_takes_both_with_raw_exposure_ratios(tmp_path, fit_calls):
    times = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15]
    stack, jpgs, raws = make_session(tmp_path / "s", times, jitter=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SelfcalWarning)
        result = calibrate([tmp_path / "s"], pipeline_options=FAST_FIT)
    assert result.taken == ("response", "pipeline")
    assert result.exposure_source == "raw"
    assert result.response_frames == jpgs
    used = np.array(result.exposure_times)
    truth = stack.true_exposures
    exif = stack.exposure_times
    err_raw = np.abs(np.log(used / used[0]) - np.log(truth / truth[0])).max()
    err_exif = np.abs(np.log(exif / exif[0]) - np.log(truth / truth[0])).max()
    assert err_raw < 0.01 and err_raw < err_exif / 3
    # in seconds (anchored on the EXIF times), and what the response model used
    assert abs(np.log(used[2] / exif[2])) < 0.1
    np.testing.assert_allclose(result.response.exposures, used, rtol=1e-6)
    assert any("exposure ratios from the raws" in r for r in result.reasons)
    assert len(result.pairs) == 5 and all(p.registration.ok for p in result.pairs)
    assert result.reasons[0].startswith("response path: 5 JPEGs of one scene at 5 exposures")
    assert result.reasons[-1].startswith("pipeline path: 5 RAW+JPEG pair(s)")
    (raw, ren, _), = fit_calls
    assert len(raw) == result.n_pipeline_samples
    assert_model_fits_its_samples(result.pipeline, raw, ren)


def test_bracketed_session_exposure_source_options(tmp_path, fit_calls):
    stack, jpgs, raws = make_session(tmp_path / "s", [1 / 125, 1 / 60, 1 / 30], jitter=0.05)
    r = calibrate([tmp_path / "s"], exposure_source="exif", pipeline_options=FAST_FIT)
    assert r.exposure_source == "exif" and r.exposure_times is None
    assert r.taken == ("response", "pipeline") and "exposure times: EXIF" in r.reasons
    r = calibrate([tmp_path / "s"], exposure_times={str(p): t for p, t in
                                                    zip(jpgs, [0.008, 0.016, 0.032])},
                  pipeline_options=FAST_FIT)
    assert r.exposure_source == "given" and r.exposure_times == [0.008, 0.016, 0.032]
    assert r.taken == ("response", "pipeline")
    assert "exposure times: given by the caller" in r.reasons
    with pytest.raises(CalibrationError, match="exposure_source='raw'"):
        calibrate(jpgs, exposure_source="raw")


def test_neither_path_says_what_is_missing(tmp_path):
    scene = sim.make_scene(64, 96, seed=1)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=1), [1 / 60],
                                 repeats=3, jitter=0.0, seed=1)
    paths = stack.write(tmp_path, fmt="jpg")
    with pytest.raises(CalibrationError) as info:
        calibrate(paths)
    assert str(info.value) == ("3 JPEGs all at 1/60 s and no raw files: need frames at "
                               "≥ 2 exposures, or a RAW+JPEG pair")
    with pytest.raises(CalibrationError, match=r"^1 JPEG \(frame_00.jpg\) only and no raw "
                                               "files: need frames at ≥ 2 exposures"):
        calibrate(paths[:1])


def test_frames_without_exif_are_judged_by_their_brightness(tmp_path):
    scene = sim.make_scene(96, 144, seed=1)
    pipe = sim.default_pipeline(seed=1)
    bracket = sim.simulate_stack(scene, pipe, [1 / 125, 1 / 60, 1 / 30, 1 / 15],
                                   jitter=0.0, seed=1)
    paths = [write_image(tmp_path / f"b{k}.png", im) for k, im in enumerate(bracket.images)]
    result = calibrate(paths)                       # PNGs without EXIF
    assert result.taken == ("response",) and result.exposure_source == "unknown"
    same = sim.simulate_stack(scene, pipe, [1 / 60], repeats=3, jitter=0.0, seed=1)
    paths = [write_image(tmp_path / f"s{k}.png", im) for k, im in enumerate(same.images)]
    with pytest.raises(CalibrationError) as info:
        calibrate(paths)
    assert str(info.value) == (
        "3 PNGs with no exposure times (EXIF) nor any brightness change between them and "
        "no raw files: need frames at ≥ 2 exposures, or a RAW+JPEG pair")


def test_raw_without_jpeg_warns_and_is_an_error_alone(tmp_path):
    orphan = tmp_path / "IMG_9.CR2"
    orphan.write_bytes(b"not read: it has no JPEG")
    with pytest.warns(SelfcalWarning):
        result = calibrate(sorted((FIXTURES / "stack").glob("*.jpg")) + [orphan])
    assert result.taken == ("response",)
    assert result.groups.unpaired_raws == [orphan]
    with pytest.warns(SelfcalWarning), pytest.raises(CalibrationError) as info:
        calibrate([orphan])
    assert "IMG_9.CR2" in str(info.value) and "without a JPEG of the same name" in str(
        info.value)
    # with one other JPEG, the message names both what is there and what is missing
    with pytest.warns(SelfcalWarning), pytest.raises(CalibrationError) as info:
        calibrate([orphan, FIXTURES / "stack" / "frame_00.jpg"])
    assert str(info.value).startswith("1 JPEG (frame_00.jpg) only and no RAW+JPEG pair "
                                      "(IMG_9.CR2 has no JPEG")


def test_unreadable_raw_in_a_pair_names_it(tmp_path):
    bad = tmp_path / "IMG_1.CR2"
    bad.write_bytes(b"garbage" * 200)
    write_image(tmp_path / "IMG_1.jpg", np.full((32, 48, 3), 128, np.uint8))
    with pytest.raises(InputError, match="not a raw file LibRaw can read") as info:
        calibrate([bad, tmp_path / "IMG_1.jpg"])
    assert "IMG_1.CR2" in str(info.value)


def test_mismatched_pair_in_calibrate_names_both(tmp_path):
    pair = sim.simulate_raw_jpeg_pair(sim.make_scene(96, 144, seed=2), seed=2)
    write_raw_tiff(tmp_path / "DSC_7.tiff", pair["raw"])
    write_image(tmp_path / "DSC_7.jpg", np.ascontiguousarray(pair["rendered"][::-1, ::-1]))
    with pytest.raises(InputError, match="does not match its raw") as info:
        calibrate([tmp_path / "DSC_7.tiff", tmp_path / "DSC_7.jpg"])
    assert "DSC_7.jpg" in str(info.value) and "DSC_7.tiff" in str(info.value)


def test_clipped_out_pair_is_a_clear_error(tmp_path):
    pair = sim.simulate_raw_jpeg_pair(sim.make_scene(96, 144, seed=2), exposure=400.0,
                                        seed=2)
    write_raw_tiff(tmp_path / "hot.tiff", pair["raw"])
    write_bytes_atomic(tmp_path / "hot.jpg", pair["encoded"])
    with pytest.warns(SelfcalWarning, match="hot.jpg: only"), \
            pytest.raises(CalibrationError, match="usable raw/JPEG samples"):
        calibrate([tmp_path / "hot.tiff", tmp_path / "hot.jpg"])


def test_too_few_pair_samples_skip_the_pipeline_path_after_the_response(tmp_path,
                                                                        fit_calls):
    make_session(tmp_path / "s", [1 / 125, 1 / 60, 1 / 30])
    # 150 samples in all: fewer than the pipeline path needs (MIN_PIPELINE_SAMPLES, 200)
    with pytest.warns(SelfcalWarning, match="pipeline path skipped: only 150 usable"):
        result = calibrate([tmp_path / "s"], pairs=PairOptions(max_pair_samples=150))
    assert result.taken == ("response",) and result.exposure_source == "raw"
    assert result.pipeline is None and not fit_calls
    assert any(r.startswith("pipeline path skipped: only 150 usable raw/JPEG samples from "
                            "3 pair(s)") for r in result.reasons)
    # with the pairs alone it is an error, saying the same
    with pytest.raises(CalibrationError, match="only 150 usable raw/JPEG samples"):
        calibrate([FIXTURES / "pair" / "pair.tiff", FIXTURES / "pair" / "pair.jpg"],
                  pairs=PairOptions(max_pair_samples=150))
    assert not fit_calls


def test_each_path_gets_its_options_object(fit_calls):
    paths = [FIXTURES / "pair" / "pair.tiff", FIXTURES / "pair" / "pair.jpg"]
    result = calibrate(paths, pipeline_options=FAST_FIT)
    assert fit_calls[-1][2] == {"seed": 0, "progress": None, **FAST_KNOBS}
    d = result.pipeline.diagnostics
    assert d["matrix_search"]["n_sets"] == 2 and d["backward"] == "lut"
    assert d["forward_lut_smoothness"] == 3e-3 and d["inverse_tone_smoothness"] == 1e-4
    # a knob by name is no option of calibrate (the 0.x routing by name is gone)
    with pytest.raises(TypeError, match="n_sets"):
        calibrate(paths, n_sets=2)
    assert len(fit_calls) == 1
    with pytest.raises(InputError, match="must be auto, raw, exif or unknown"):
        calibrate(paths, exposure_source="guess")


@pytest.mark.skipif(not CANON.exists(), reason=f"real raw data not present ({CANON})")
def test_real_dng_with_a_cropped_jpeg_takes_the_pipeline_path(tmp_path, fit_calls):
    import cv2
    import rawpy

    dng = tmp_path / "chart.dng"
    dng.symlink_to(CANON)             # a link, not a copy (the data stays out of the repo)
    with rawpy.imread(str(CANON)) as r:
        rendered = r.postprocess(use_camera_wb=True, user_flip=0)
    h, w = rendered.shape[:2]
    part = rendered[int(0.02 * h):h - int(0.02 * h), int(0.02 * w):w - int(0.02 * w)]
    small = cv2.resize(part, (int(part.shape[1] * 0.7), int(part.shape[0] * 0.7)),
                       interpolation=cv2.INTER_AREA)
    write_image(tmp_path / "CHART.JPG", small, jpeg_quality=92)
    result = calibrate([dng, tmp_path / "CHART.JPG"], pipeline_options=FAST_FIT)
    assert result.taken == ("pipeline",)
    (pair,) = result.pairs
    assert pair.registration.ok and pair.registration.residual < 0.2
    (raw, ren, _), = fit_calls
    assert len(raw) >= 1000 and raw.max() < 0.98
    # not white balanced: the raw samples are greenish where the rendering is neutral
    neutral = np.ptp(ren, axis=1) < 0.03
    assert neutral.sum() > 50
    g_over_r = np.median(raw[neutral, 1] / np.maximum(raw[neutral, 0], 1e-4))
    assert g_over_r > 1.5


# ------------------------------------------------------------------ calibrate_pipeline

def test_calibrate_pipeline_with_arrays_and_paths(fit_calls):
    pair = sim.simulate_raw_jpeg_pair(sim.make_scene(160, 240, seed=4), seed=4)
    pm = selfcal.calibrate_pipeline(pair["raw"], pair["rendered"], seed=2, options=FAST_FIT)
    raw, ren, options = fit_calls[-1]
    assert options == {"seed": 2, "progress": None, **FAST_KNOBS}
    assert pm.diagnostics["seed"] == 2 and pm.diagnostics["backward"] == "lut"
    # the samples correspond: the simulator's own pipeline renders them (JPEG noise only)
    err = np.abs(pair["pipeline"].render(raw.astype(np.float32)[None])[0] - ren) * 255
    assert np.median(err) < 1.0
    assert_model_fits_its_samples(pm, raw, ren)
    # the same with the fixture files, and arrays of different sizes get registered
    pm = selfcal.calibrate_pipeline([FIXTURES / "pair" / "pair.tiff"],
                                    [FIXTURES / "pair" / "pair.jpg"], options=FAST_FIT)
    assert_model_fits_its_samples(pm, *fit_calls[-1][:2])
    import cv2

    smaller = cv2.resize(pair["rendered"], (180, 120), interpolation=cv2.INTER_AREA)
    pm = selfcal.calibrate_pipeline([pair["raw"]], [smaller], options=FAST_FIT)
    raw, ren, _ = fit_calls[-1]
    err = np.abs(pair["pipeline"].render(raw.astype(np.float32)[None])[0] - ren) * 255
    assert np.median(err) < 1.5
    with pytest.raises(InputError, match="2 raws but 1 rendered"):
        calibrate_pipeline([pair["raw"], pair["raw"]], [pair["rendered"]])
    with pytest.raises(TypeError, match="knots"):     # no keyword of calibrate_pipeline
        calibrate_pipeline(pair["raw"], pair["rendered"], knots=7)
