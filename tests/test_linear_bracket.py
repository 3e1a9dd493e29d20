"""Raw-only brackets: linear frames merged directly, their exposures measured from the pixels
([Lin2011] §5).  Truth: the simulator's jittered exposures and radiance."""

from __future__ import annotations

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.hdr import MergeOptions
from selfcal.exposure.resolve import REPORT_DIFFERENCE

TIMES = (1 / 125, 1 / 30, 1 / 8, 1 / 2)


def _bracket(tmp_path, *, with_times: bool, seed: int = 7, jitter: float = 0.05):
    """16-bit linear TIFFs of a jittered bracket (a raw converter's output)."""
    scene = sim.make_scene(120, 160, dynamic_range_stops=10, saturation=0.5, seed=seed)
    stack = sim.simulate_stack(scene, sim.default_pipeline(seed=seed), list(TIMES),
                                 jitter=jitter, seed=seed)
    folder = tmp_path / f"lin{seed}{'t' if with_times else ''}"
    return stack.write_raws(folder, with_times=with_times), stack


def _ratios(x):
    x = np.asarray(x, dtype=float)
    return x / x[0]


def _radiance_error(result, stack) -> float:
    """Median relative error of the radiance at its best scale, where the truth is lit."""
    truth = stack.radiance
    ok = (truth > 1e-3).all(axis=2) & ~result.unmeasured
    rad = result.radiance[ok]
    scale = np.median(rad / truth[ok])
    return float(np.median(np.abs(rad / (scale * truth[ok]) - 1)))


def test_ratios_measured_without_times_within_one_percent(tmp_path):
    paths, stack = _bracket(tmp_path, with_times=False)
    result = selfcal.merge_hdr(paths, linear=True)
    true = _ratios(stack.true_exposures)
    assert np.max(np.abs(_ratios(result.exposures) / true - 1)) < 0.01
    # the nominal times are 5 % off: the measurement is what fixes them
    assert np.max(np.abs(_ratios(TIMES) / true - 1)) > 0.02
    assert result.exposure_source == "measured"
    assert any("relative scale" in w for w in result.warnings)
    record = result.exposure_record
    assert record.origin == "unknown" and record.given == [None] * len(TIMES)
    assert {f.used_from for f in record.frames} == {"measured"}
    assert _radiance_error(result, stack) < 0.03


def test_exif_times_scale_the_measured_ratios(tmp_path):
    paths, stack = _bracket(tmp_path, with_times=True)
    result = selfcal.merge_hdr(paths, linear=True)
    assert result.exposure_source == "measured+exif"
    true = _ratios(stack.true_exposures)
    assert np.max(np.abs(_ratios(result.exposures) / true - 1)) < 0.01
    # in the times' units: the median frame agrees with its time
    exif = np.array(TIMES) * (stack.iso / 100) / stack.f_number ** 2   # t · ISO/100 / N²
    assert abs(np.median(np.log(result.exposures / exif))) < 1e-9
    moved = [f.moved for f in result.exposure_record.frames]
    worst = int(np.argmax(np.abs(moved)))
    assert max(abs(d) for d in moved) > REPORT_DIFFERENCE
    assert result.exposure_record.largest_move().source.endswith(f"raw_{worst}.tif")
    assert len([w for w in result.warnings if "--hold-times" in w]) == 1
    # held: the EXIF times as they are
    held = selfcal.merge_hdr(paths, linear=True,
                             options=MergeOptions(exposures=selfcal.ExposureRule(times="held")))
    assert held.exposure_source == "exif"
    np.testing.assert_allclose(held.exposures, exif, rtol=1e-6)


def test_given_times_follow_the_rule_exif_times_do(tmp_path):
    """One rule: --times are measured like EXIF times, and held only when asked."""
    paths, stack = _bracket(tmp_path, with_times=False)
    given = list(TIMES)
    kept = selfcal.merge_hdr(paths, given, linear=True,
                             options=MergeOptions(exposures=selfcal.ExposureRule(times="held")))
    assert kept.exposure_source == "given"
    np.testing.assert_allclose(kept.exposures, given)
    measured = selfcal.merge_hdr(paths, given, linear=True)
    assert measured.exposure_source == "measured+given"
    true = _ratios(stack.true_exposures)
    assert np.max(np.abs(_ratios(measured.exposures) / true - 1)) < 0.01
    # the measured exposures merge closer to the truth than the 5 %-off times
    assert _radiance_error(measured, stack) < _radiance_error(kept, stack)


def test_linear_arrays_and_a_frame_nothing_measures(tmp_path):
    _, stack = _bracket(tmp_path, with_times=False, seed=11)
    arrays = [np.clip(r, 0, 1).astype(np.float32) for r in stack.raws]
    result = selfcal.merge_hdr(arrays, linear=True)
    true = _ratios(stack.true_exposures)
    assert np.max(np.abs(_ratios(result.exposures) / true - 1)) < 0.01
    black = arrays[:2] + [np.zeros_like(arrays[0])]
    with pytest.raises(selfcal.CalibrationError, match=r"array #2: shares too few"):
        selfcal.merge_hdr(black, linear=True)
    with pytest.raises(selfcal.InputError, match="rule for given times"):
        selfcal.merge_hdr(arrays, linear=True,
                          options=MergeOptions(exposures=selfcal.ExposureRule(times="exif")))


def test_cli_merges_a_linear_bracket_and_says_so(tmp_path, capsys):
    from selfcal.hdr.io import read_radiance
    from selfcal_cli.main import main

    paths, stack = _bracket(tmp_path, with_times=True)
    out = tmp_path / "r.exr"
    code = main(["merge", *map(str, paths), "-o", str(out)])
    text = capsys.readouterr()
    text = text.out + text.err
    assert code == 0, text
    assert "are linear data" in text and "follow the exposure times" in text
    assert "measured from the pixels, on the scale of EXIF" in text
    assert "--hold-times keeps the times" in text
    radiance = read_radiance(out)
    truth = stack.radiance
    ok = (truth > 1e-3).all(axis=2)
    scale = np.median(radiance[ok] / truth[ok])
    assert np.median(np.abs(radiance[ok] / (scale * truth[ok]) - 1)) < 0.03


def test_split_halves_remove_the_selection_bias_of_noisy_ratios():
    """Choosing pixels by the values whose ratio is taken biases it (noise pushed into the
    band); choosing by the other half of the pixels does not (selfcal.exposure.raw_ratios)."""
    from selfcal.exposure.raw_ratios import raw_exposure_ratios, split_thumbnails

    scene = sim.make_scene(200, 300, dynamic_range_stops=10, seed=5)
    scene = scene / np.median(scene) * 0.1
    rng = np.random.default_rng(0)
    frames = [np.clip(scene * e + rng.normal(0, 0.02, scene.shape), -1, 1).astype(np.float32)
              for e in (1.0, 4.0)]
    self_chosen, _ = raw_exposure_ratios(frames)
    halves = [split_thumbnails(f) for f in frames]
    split, report = raw_exposure_ratios([v for v, _ in halves], select=[c for _, c in halves],
                                        statistic="sum")
    assert abs(self_chosen[1] / 4 - 1) > 0.02
    assert abs(split[1] / 4 - 1) < 0.01
    assert report["pairs"][0][3] > 1000


def test_merge_hdr_takes_linear_tiffs_for_linear_without_being_told(tmp_path):
    """The library, not only the CLI: linear TIFFs are not calibrated as rendered frames."""
    paths, stack = _bracket(tmp_path, with_times=True)
    result = selfcal.merge_hdr(paths)
    assert "follow the exposure times" in result.diagnostics["linear_evidence"]
    assert any("are linear data" in w for w in result.warnings)
    assert result.model is None and result.exposure_source == "measured+exif"
    true = _ratios(stack.true_exposures)
    assert np.max(np.abs(_ratios(result.exposures) / true - 1)) < 0.01
    # rendered 16-bit TIFFs of the same scene are still calibrated
    rendered = sim.simulate_stack(stack.radiance, stack.pipeline, list(TIMES), seed=7,
                                    output=sim.FrameOutput(bit_depth=16), jpeg_quality=None)
    files = rendered.write(tmp_path / "rendered", fmt="tif")
    assert "linear_evidence" not in selfcal.merge_hdr(files).diagnostics
