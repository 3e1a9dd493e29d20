"""Exposures of a rendered bracket measured from its pixels (selfcal.exposure.measured):
simulator ground truth with times off by 12-20 %, from arrays and from files."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import selfcal  # noqa: E402
from selfcal import sim  # noqa: E402
from selfcal.hdr import MergeOptions  # noqa: E402
from selfcal.exposure.linear import MIN_LOG_SIGMA  # noqa: E402
from selfcal.exposure.measured import _prepass_reduce  # noqa: E402
from selfcal.stack.frames import StackFrames  # noqa: E402
from test_hdr import true_model, truth_radiance  # noqa: E402

#: The given times are the true exposures times these (off by 12-20 %).
OFF = np.array([1.15, 0.88, 1.0, 1.18, 0.85, 1.12])


@pytest.fixture(scope="module")
def stack():
    scene = sim.make_scene(256, 1024, dynamic_range_stops=14.0, saturation=0.5, seed=5)
    return sim.simulate_stack(scene, sim.default_pipeline(gamut="smooth", seed=5),
                              sim.stacks.DEMO_EXPOSURE_TIMES, jitter=0.0, jpeg_quality=92,
                              seed=5)


def _relative(e, true):
    """Exposures over the truth, divided by their geometric mean (the scale is the times')."""
    r = np.asarray(e, float) / np.asarray(true, float)
    return r / np.exp(np.mean(np.log(r)))


def _radiance_error(result, truth):
    """Median relative error of the measured pixels after one global scale."""
    ok = ~result.unmeasured
    rad, tr = result.radiance[ok].astype(float), truth[ok]
    keep = (rad > 0) & (tr > 0)
    g = np.exp(np.median(np.log(rad[keep] / tr[keep])))
    return float(np.median(np.abs(rad[keep] / (g * tr[keep]) - 1.0)))


def test_measured_exposures_recover_the_truth_from_arrays(stack):
    true = np.asarray(stack.true_exposures, float)
    times = list(true * OFF)
    model = true_model(stack)
    truth = truth_radiance(stack)
    plain = selfcal.merge_hdr(stack.images, times, model,
                              options=MergeOptions(exposures=selfcal.ExposureRule(times="held")))
    meas = selfcal.merge_hdr(stack.images, times, model, options=MergeOptions(sigma=True))
    assert np.abs(_relative(plain.exposures, true) - 1).max() > 0.1      # the times' error
    assert np.abs(_relative(meas.exposures, true) - 1).max() < 0.015
    # the scale stays the times': the median log difference is zero
    assert abs(np.median(np.log(meas.exposures / np.asarray(times)))) < 1e-9
    assert _radiance_error(meas, truth) < 0.7 * _radiance_error(plain, truth)
    spread = meas.exposure_record.spread
    assert spread.reduce == 1 and spread.by == "merge"
    assert spread.log_sigma >= MIN_LOG_SIGMA
    assert meas.exposure_source == "measured+given"
    assert max(abs(f.moved) for f in meas.exposure_record.frames) > 0.1
    assert len([w for w in meas.warnings if "--hold-times" in w]) == 1
    # held times are left alone
    np.testing.assert_allclose(plain.exposures, times)


def test_measured_exposures_from_files_use_a_reduced_prepass(stack, tmp_path):
    from selfcal.exposure.measured import measure_response_exposures

    true = np.asarray(stack.true_exposures, float)
    times = np.array(true * OFF)
    paths = stack.write(tmp_path, fmt="jpg")
    frames = StackFrames(paths, False)
    assert _prepass_reduce(frames, min_side=512) == 2   # 1024 px -> 512
    assert _prepass_reduce(frames) == 1                 # below PREPASS_MIN_SIDE: full size
    out, summary = measure_response_exposures(frames, true_model(stack), times,
                                              range(len(paths)), clip_margin=2.0, reduce=2)
    # block means of codes, linearised: biased on texture, still well within the times'
    assert np.abs(_relative(out, true) - 1).max() < 0.03
    assert summary["reduce"] == 2


def test_times_that_are_right_are_barely_moved(stack):
    true = np.asarray(stack.true_exposures, float)
    meas = selfcal.merge_hdr(stack.images, list(true), true_model(stack),
                             options=MergeOptions(exposures=selfcal.ExposureRule()))
    assert np.abs(meas.exposures / true - 1).max() < 0.015


def test_times_trend_keeps_exact_times_and_follows_jittered_ones():
    from selfcal.exposure.measured import _times_trend

    rng = np.random.default_rng(3)
    times = 2.0 ** np.arange(8) / 250
    # deviations no larger than the measurement's scatter: the times stay as they are
    noise = np.exp(rng.normal(0, 0.002, times.size))
    out, fit = _times_trend(times * noise, times, 0.004)
    np.testing.assert_allclose(out, times, rtol=1e-12)
    assert fit["shrink"] == 0.0 and fit["log_sigma"] >= 0.002
    # a shutter off by ±8 %: the pixels' deviations are kept almost whole
    jitter = np.exp(rng.uniform(-0.08, 0.08, times.size))
    out, fit = _times_trend(times * jitter, times, 0.004)
    # ... beyond the jitter's own trend over the bracket, which the times keep
    x = np.log(times)
    dev = np.log(out / times) - np.log(jitter)
    dev -= np.polyval(np.polyfit(x, dev, 1), x)
    assert fit["shrink"] > 0.9
    assert np.abs(dev).max() < 0.01
    assert fit["trend_log_sigma"] > 0.005          # the trend's own uncertainty is said


def test_times_trend_is_not_pulled_by_one_frame():
    from selfcal.exposure.measured import _times_trend

    times = 2.0 ** np.arange(6) / 250
    measured = times.copy()
    measured[0] *= 1.6                             # one frame's time is far off
    out, fit = _times_trend(measured, times, 0.002)
    # Theil-Sen keeps the others on their times; the odd frame follows its pixels
    np.testing.assert_allclose(out[1:], times[1:], rtol=1e-9)
    assert out[0] / times[0] == pytest.approx(1.6, rel=1e-3)


def test_the_merge_takes_the_calibrations_own_numbers(stack, tmp_path):
    jittered = np.asarray(stack.true_exposures, float) * OFF
    model = selfcal.calibrate_response(stack.images, list(jittered))
    assert model.exposure_record.spread.trend == "times"
    # arrays: recognised by their content, nothing measured again
    r = selfcal.merge_hdr(stack.images, list(jittered), model)
    assert r.exposure_record.spread.by == "calibration"
    np.testing.assert_allclose(r.exposures, model.exposures, rtol=1e-12)
    # other frames (one changed): measured by the merge's own pre-pass
    other = [im.copy() for im in stack.images]
    other[0][0, 0] ^= 1
    r = selfcal.merge_hdr(other, list(jittered), model)
    assert r.exposure_record.spread.by == "merge"
    # files, after the model went through its file
    paths = stack.write(tmp_path / "files", fmt="png")
    model = selfcal.calibrate_response(paths, list(jittered))
    model.save(tmp_path / "model.json")
    loaded = selfcal.load_model(tmp_path / "model.json")
    r = selfcal.merge_hdr(paths, list(jittered), loaded)
    assert r.exposure_record.spread.by == "calibration"
    np.testing.assert_allclose(r.exposures, model.exposures, rtol=1e-9)


def test_prepass_measures_a_subsample_of_codes_as_every_pixel_would(stack):
    """Issue 43: the pre-pass linearises a strided subsample of an array's codes
    (PREPASS_CODES_SIDE a side), not every pixel, before averaging to the thumbnails; on
    the simulator it agrees with the truth and with every pixel."""
    from selfcal.exposure import measured

    true = np.asarray(stack.true_exposures, float)
    times = true * OFF
    model = true_model(stack)
    frames = StackFrames(stack.images, False)
    kw = dict(clip_margin=2.0, trend="pixels")
    # before issue 43: every pixel linearised, then area-averaged to the thumbnails
    every = {k: measured._linear_thumbnails(stack.images[k], model, 2.0, None)
             for k in range(6)}
    old, _ = measured._measured_from_thumbnails(every, frames, times, trend="pixels",
                                                reduce=1)
    # frames up to PREPASS_CODES_SIDE a side: every pixel, the same numbers
    assert max(frames.shape) <= measured.PREPASS_CODES_SIDE
    same, _ = measured.measure_response_exposures(frames, model, times, range(6), **kw)
    np.testing.assert_array_equal(same, old)
    # a subsample (every other row and column here), as measure_response_exposures
    # measures frames over PREPASS_CODES_SIDE a side
    sub = measured.code_subsample(stack.images[0], 512)
    np.testing.assert_array_equal(sub, stack.images[0][::2, ::2])
    made = {k: measured._linear_thumbnails(measured.code_subsample(stack.images[k], 512),
                                           model, 2.0, None) for k in range(6)}
    new, summary = measured._measured_from_thumbnails(made, frames, times, trend="pixels",
                                                      reduce=1)
    # the subsample's codes are the frame's own, unaveraged: block means of 4×4 codes,
    # linearised, are off by 0.009 here
    assert np.abs(np.log(_relative(new, true))).max() < 0.004      # the truth
    assert np.abs(np.log(_relative(new, old))).max() < 0.001      # every pixel
    assert 0 < np.abs(np.log(new / old)).max()                   # (it was a subsample)
    assert summary["measurement_log_sigma"] < 0.01


def test_prepass_threads_do_not_change_the_numbers(stack, tmp_path):
    from selfcal.exposure import measured

    true = np.asarray(stack.true_exposures, float)
    paths = stack.write(tmp_path, fmt="jpg")
    frames = StackFrames(paths, False)
    model, times = true_model(stack), true * OFF
    two, s2 = measured.measure_response_exposures(frames, model, times, range(len(paths)),
                                                  clip_margin=2.0)
    assert measured.PREPASS_THREADS > 1
    # the frames' thumbnails one after another, in this thread
    made = {k: measured._thumbnail(frames, k, model, 2.0, None, s2["reduce"])
            for k in range(len(paths))}
    one, s1 = measured._measured_from_thumbnails(made, frames, times, trend="times",
                                                 reduce=s2["reduce"])
    np.testing.assert_array_equal(one, two)
    assert s1 == s2
    assert np.abs(_relative(two, true) - 1).max() < 0.015
