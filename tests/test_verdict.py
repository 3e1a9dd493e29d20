"""What a calibration says about its input: clipped frames, the verdict, where times came from.

* frames white or black (almost) everywhere are said to be so and dropped before
  the duplicate check, which compares every pixel;
* the verdict (``diagnostics["verdict"]``, :mod:`selfcal.response.verdict`) is not
  "ok" on wrong data -- times in reversed order, a handheld stack, two scenes, one stop,
  a flat scene -- and stays "ok" on a good stack; each reason is a SelfcalWarning;
* the exposure record says where the times came from, the ambiguity warning is a
  SelfcalWarning, and refined exposures keep the times of the frames that agree.

Each test here failed on the code before these checks were added (``git archive 83b5507``).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import conftest
import selfcal
from selfcal import sim
from selfcal.errors import CalibrationError, InputError, SelfcalWarning

TIMES = list(sim.DEMO_EXPOSURE_TIMES)
SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def calibrate_quietly(images, times=None, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SelfcalWarning)
        return selfcal.calibrate_response(images, times, **options)


def make_stack(seed=1, times=TIMES, stops=14.0, flip=False):
    pipe = sim.default_pipeline(gamut="smooth", curves=sim.ToneCurve.srgb(), seed=seed)
    scene = sim.make_scene(192, 288, dynamic_range_stops=stops, saturation=0.5, seed=seed)
    if flip:
        scene = np.ascontiguousarray(scene[::-1, ::-1])
    return sim.simulate_stack(scene, pipe, times, jitter=0.03, jpeg_quality=90, seed=seed)


def shake(images, fraction=0.02, degrees=0.5, seed=0):
    """Every frame but the middle one shifted and turned a little (a handheld stack)."""
    return sim.handheld(images, fraction=fraction, degrees=degrees, seed=seed)


@pytest.fixture(scope="module")
def stack():
    return make_stack()


@pytest.fixture(scope="module")
def good_model(stack):
    return calibrate_quietly(stack.images, TIMES)


def rmse_vs_truth(model, stack):
    return conftest.rmse_vs_truth(model, stack, slice(5, 251))


# ------------------------------------------------------------------ point 4

def nearly_white(shape, seed, n_dark=40):
    """A frame white but for ``n_dark`` pixels off the every-7th-pixel grid."""
    rng = np.random.default_rng(seed)
    im = np.full(shape, 255, np.uint8)
    ys = rng.integers(0, shape[0] // 7, n_dark) * 7 + 3
    xs = rng.integers(0, shape[1] // 7, n_dark) * 7 + 3
    im[ys, xs] = rng.integers(100, 250, (n_dark, 3))
    return im


def test_nearly_white_frames_are_clipped_not_duplicates(stack):
    # two frames of a long bracket almost entirely white, differing in a few dozen pixels
    # the old every-7th-pixel fingerprint never looked at: they were refused as a
    # "duplicated file" with two different times (a real 42-frame Canon SX100 stack)
    shape = stack.images[0].shape
    frames = list(stack.images) + [nearly_white(shape, 1), nearly_white(shape, 2)]
    times = TIMES + [0.5, 1.0]
    model = calibrate_quietly(frames, times)
    ignored = {f.source: f.reason for f in model.frames_ignored}
    assert ignored.keys() == {"array #6", "array #7"}, ignored
    assert ignored["array #6"] == "clipped"
    assert ignored["array #7"] in ("clipped", "unchecked")        # clipped or isolated
    assert math.isnan(model.exposures[6]) and math.isnan(model.exposures[7])
    np.testing.assert_allclose(model.exposures[:6], TIMES, rtol=0.03)   # measured


def test_all_black_and_all_white_frames_are_named_as_such(stack):
    black = np.zeros_like(stack.images[0])
    white = np.full_like(stack.images[0], 255)
    frames = [black, black, *stack.images[:3], white, white]
    model = calibrate_quietly(frames, [1e-4, 2e-4, *TIMES[:3], 1.0, 2.0])
    assert [(f.source, f.reason) for f in model.frames_ignored] == [
        (f"array #{k}", "clipped") for k in (0, 1, 5, 6)]        # none a "duplicate"
    # the warnings tell black from white (the model's reason codes do not)
    w = model.diagnostics["warnings"]
    assert any("array #0: all black" in m for m in w), w
    assert any("array #1: all black" in m for m in w), w
    assert any("array #5: all white" in m for m in w), w
    assert any("array #6: all white" in m for m in w), w
    # only black and white frames besides one good one: the error says so, not "duplicate"
    with pytest.raises(CalibrationError, match="all black") as info:
        calibrate_quietly([black, black, stack.images[2], white], [1e-4, 2e-4, 0.01, 1.0])
    assert "identical" not in str(info.value)


def test_duplicates_are_judged_on_every_pixel(stack):
    # a frame that differs from another in pixels off the every-7th grid is no duplicate
    a = stack.images[2]
    b = a.copy()
    b[3::7, 3::7] = np.clip(b[3::7, 3::7].astype(int) + 3, 0, 255).astype(np.uint8)
    model = calibrate_quietly([stack.images[0], a, b, stack.images[4]],
                              [TIMES[0], TIMES[2], TIMES[2] * 1.01, TIMES[4]])
    assert len(model.diagnostics["frames_used"]) == 4
    # an exact copy at another time is still refused, naming both frames
    with pytest.raises(InputError, match="array #2.*identical pixels to array #1"):
        calibrate_quietly([stack.images[0], a, a.copy()], [TIMES[0], TIMES[2], TIMES[3]])


# ------------------------------------------------------------------ point 7

def verdict_of(model):
    d = model.diagnostics
    return d["verdict"], d["verdict_reasons"], d["verdict_evidence"]


def test_good_stack_is_ok_with_its_evidence(good_model, stack):
    verdict, reasons, ev = verdict_of(good_model)
    assert verdict == "ok" and reasons == []
    assert ev["residual_misfit_ratio"] < 2 and ev["time_pairs_reversed"] == 0
    assert ev["scene_pairs_disagreeing"] == 0 and ev["misaligned_pairs"] == 0
    assert min(ev["stops_covered"]) > 6
    assert rmse_vs_truth(good_model, stack) < 0.01
    # the verdict is evidence only: the curve is what it was (fixture stack of
    # test_response.py's test_known_times_recover_truth)


def test_reversed_times_are_unusable(stack):
    with pytest.warns(SelfcalWarning, match="wrong order"):
        model = selfcal.calibrate_response(stack.images, TIMES[::-1])
    verdict, reasons, ev = verdict_of(model)
    assert verdict == "unusable"
    assert ev["time_pairs_reversed"] == ev["time_pairs_checked"] > 0
    # every reason is also a warning of the model
    assert set(reasons) <= set(model.diagnostics["warnings"])


def test_handheld_stack_without_alignment_is_doubtful(stack):
    frames = shake(stack.images, seed=3)
    model = calibrate_quietly(frames, TIMES)
    verdict, reasons, ev = verdict_of(model)
    assert verdict != "ok" and ev["misaligned_pairs"] >= 1
    assert any("align" in r for r in reasons), reasons


def test_two_scenes_fed_together_are_unusable(stack):
    other = make_stack(seed=7, times=[t * 1.4 for t in TIMES], flip=True)
    model = calibrate_quietly(list(stack.images) + list(other.images),
                              TIMES + list(other.exposure_times))
    verdict, reasons, ev = verdict_of(model)
    assert verdict == "unusable"
    assert ev["scene_pairs_disagreeing"] >= 0.25 * ev["scene_pairs_checked"]
    assert any("scenes" in r for r in reasons), reasons


def test_two_frames_one_stop_apart_are_doubtful():
    st = make_stack(seed=2, times=[1 / 60, 1 / 30])
    verdict, reasons, ev = verdict_of(calibrate_quietly(st.images, list(st.exposure_times)))
    assert verdict == "doubtful" and ev["exposure_ratio"] < 3
    assert any("span only" in r for r in reasons), reasons


def test_flat_scene_is_doubtful():
    st = make_stack(seed=3, times=[1 / 60, 1 / 30, 1 / 15], stops=1.0)
    verdict, reasons, ev = verdict_of(calibrate_quietly(st.images, list(st.exposure_times)))
    assert verdict == "doubtful" and min(ev["stops_covered"]) < 5
    assert any("stops of the curve" in r for r in reasons), reasons


def test_one_wrong_time_held_is_doubtful(stack):
    times = list(TIMES)
    times[3] *= 2.0
    held = calibrate_quietly(stack.images, times, exposures=selfcal.ExposureRule(times="held"))
    verdict, reasons, evidence = verdict_of(held)
    assert verdict == "doubtful"
    assert evidence["contradicted_times"] == 1, evidence
    assert [f.source for f in held.exposure_record.contradictions()] == ["array #3"]
    # by default the rule refines it (the verdict sees the corrected time as evidence)
    refined = calibrate_quietly(stack.images, times)
    assert refined.exposure_record.refined
    assert [f.source for f in refined.exposure_record.contradictions()] == ["array #3"]


def test_verdict_is_saved_and_loaded(stack, tmp_path):
    model = calibrate_quietly(stack.images, TIMES[::-1])
    loaded = selfcal.load_model(model.save(tmp_path / "m.json"))
    assert loaded.diagnostics["verdict"] == "unusable"
    assert loaded.diagnostics["verdict_reasons"] == model.diagnostics["verdict_reasons"]


def test_plot_shows_the_verdict(stack, tmp_path):
    from selfcal.report import plot_response, verdict_lines

    model = calibrate_quietly(stack.images, TIMES[::-1])
    lines = verdict_lines(model.diagnostics)
    assert lines[0].startswith("verdict: unusable")
    assert any("wrong order" in line for line in lines[1:])
    path = plot_response(model, tmp_path / "r.png")
    assert Path(path).stat().st_size > 10_000


@pytest.mark.skipif(not (SHARED / "memorial").exists(),
                    reason="../shared/data/memorial absent")
def test_memorial_ok_and_reversed_unusable():
    from fractions import Fraction

    from selfcal.io import read_image

    folder = SHARED / "memorial"
    times = [float(Fraction(t)) for t in (folder / "shutter_times.txt").read_text().split()]
    frames = [read_image(p) for p in sorted(folder.glob("memorial*.png"))]
    assert verdict_of(calibrate_quietly(frames, times))[0] == "ok"
    verdict, reasons, _ = verdict_of(calibrate_quietly(frames, times[::-1]))
    assert verdict == "unusable" and any("wrong order" in r for r in reasons)


# ------------------------------------------------------------------ point 8

def test_exposure_source_says_where_the_times_came_from(stack, tmp_path):
    def origin(*args, **kw):
        return calibrate_quietly(*args, **kw).exposure_record.origin

    assert origin(stack.images, TIMES) == "given"
    assert origin(stack.images, [None] * 6) == "unknown"            # was "given"
    assert origin(stack.images, TIMES, times_source="raw") == "raw"
    assert origin(stack.images) == "unknown"
    # files without EXIF times: unknown, not "exif"
    from selfcal.io import encode_image

    paths = []
    for k, im in enumerate(stack.images):
        paths.append(tmp_path / f"f{k}.png")
        paths[-1].write_bytes(encode_image(im, ".png"))
    model = calibrate_quietly(paths)
    assert model.exposure_record.origin == "unknown"            # was "exif"
    assert sum("no exposure time in EXIF" in w for w in model.diagnostics["warnings"]) == 6
    written = stack.write(tmp_path / "exif")
    assert origin(written) == "exif"


def test_unknown_exposures_through_calibrate_are_labelled_unknown(stack, tmp_path):
    paths = stack.write(tmp_path / "s")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SelfcalWarning)
        result = selfcal.calibrate(paths, exposure_source="unknown")
    assert result.exposure_source == "unknown"
    assert result.response.exposure_record.origin == "unknown"   # was "given"


def test_ambiguity_warning_is_a_selfcal_warning(stack):
    with pytest.warns(SelfcalWarning) as record:
        model = selfcal.calibrate_response(stack.images, [None] * 6)
    assert model.diagnostics["ambiguity_resolved_by_prior"]
    # every warning of the model, the ambiguity's among them, was a SelfcalWarning
    emitted = {str(r.message) for r in record if issubclass(r.category, SelfcalWarning)}
    assert model.diagnostics["warnings"] and set(model.diagnostics["warnings"]) <= emitted


def test_refined_times_keep_the_agreeing_frames_times(stack):
    # one frame's time is wrong (2.5x); refining must correct it without moving the
    # others (the old anchor moved every refined time by up to +58 %)
    for wrong in (2, 3):
        times = list(TIMES)
        times[wrong] *= 2.5
        model = calibrate_quietly(stack.images, times,
                                  exposures=selfcal.ExposureRule(refine=True))
        others = [k for k in range(6) if k != wrong]
        rel = model.exposures[others] / np.array(TIMES)[others]
        assert np.all(np.abs(rel - 1) < 0.06), rel
        # the wrong one comes back near the truth (the shutter jitter is ±3 %)
        assert model.exposures[wrong] / stack.true_exposures[wrong] == pytest.approx(1, abs=0.08)
        assert model.diagnostics["verdict"] == "ok"


# ------------------------------------------- EXIF times the pixels contradict: refined

def exif_stack_with_one_wrong_time(stack, folder, wrong=3, factor=1.6):
    """The stack's files with frame ``wrong``'s EXIF time off by ``factor`` (the shutter
    gave the nominal time, EXIF says another: an inaccurate shutter, as real cameras)."""
    import dataclasses

    times = np.array(stack.exposure_times, dtype=float)
    times[wrong] *= factor
    return dataclasses.replace(stack, exposure_times=times).write(folder)


def test_contradicted_exif_times_are_refined_by_default(stack, tmp_path):
    # refining against holding, alone: the measured ringing reach
    # (ResponseOptions.measure_ringing) and the hidden white samples (hidden_white) act on
    # held exposures only, and on this stack each also hides most of the wrong time
    from selfcal.response import ResponseOptions

    without_reach = ResponseOptions(measure_ringing=False, hidden_white=False)
    paths = exif_stack_with_one_wrong_time(stack, tmp_path / "s")
    model = calibrate_quietly(paths, options=without_reach)
    d = model.diagnostics
    record = model.exposure_record
    assert record.origin == "exif" and record.refined
    assert [f.source for f in record.contradictions()] == [str(paths[3])]
    assert d["verdict"] == "ok", d["verdict_reasons"]
    # the wrong frame comes back near the truth (jitter ±3 %), the others keep EXIF's
    assert model.exposures[3] / stack.true_exposures[3] == pytest.approx(1, abs=0.08)
    others = [0, 1, 2, 4, 5]
    assert np.allclose(model.exposures[others] / np.array(TIMES)[others], 1, atol=0.06)
    held = calibrate_quietly(paths, exposures=selfcal.ExposureRule(times="held"),
                             options=without_reach)
    assert not held.exposure_record.refined and held.exposure_record.rule == "held"
    assert held.diagnostics["verdict"] == "doubtful"
    assert rmse_vs_truth(model, stack) < rmse_vs_truth(held, stack)


def test_times_the_caller_gives_follow_the_rule_exif_times_do(stack):
    """One rule for given times: the caller's contradicted time is refined as an EXIF one
    is, and held (the verdict doubtful) only with ``--hold-times``."""
    times = list(TIMES)
    times[3] *= 1.6
    model = calibrate_quietly(stack.images, times)
    assert model.exposure_record.refined
    assert model.diagnostics["verdict"] == "ok", model.diagnostics["verdict_reasons"]
    measured = model.exposures[3] / model.exposures[2]
    assert abs(measured / (TIMES[3] / TIMES[2]) - 1) < 0.1, measured
    held = calibrate_quietly(stack.images, times, exposures=selfcal.ExposureRule(times="held"))
    assert not held.exposure_record.refined
    assert held.diagnostics["verdict"] == "doubtful"
    np.testing.assert_allclose(held.exposures, times, rtol=1e-12)


def test_exif_times_mostly_contradicted_are_not_refined_away(stack, tmp_path):
    import dataclasses

    # EXIF times in reversed order: refining would hide that they belong to other frames
    reversed_times = np.array(stack.exposure_times, dtype=float)[::-1].copy()
    paths = dataclasses.replace(stack, exposure_times=reversed_times).write(tmp_path / "r")
    model = calibrate_quietly(paths)
    assert not model.exposure_record.refined
    assert model.diagnostics["verdict"] == "unusable"


def test_exposure_rule_is_checked():
    with pytest.raises(selfcal.InputError, match="rule for given times"):
        selfcal.ExposureRule(times="yes")
    with pytest.raises(selfcal.InputError, match="--hold-times"):
        selfcal.ExposureRule(refine=False)
