"""The merge divides the lens's vignetting out: tripod stacks after the merge, moved frames
per frame at their own pixels, and σ grows by the vignetting's uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.hdr.merge import MergeOptions
from selfcal.lens import Vignetting

H, W = 128, 192
TIMES = [1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15]


def _vignetting(cov=1e-6) -> Vignetting:
    k = np.array([[-0.55, 0.05, -0.02], [-0.5, 0.0, 0.0], [-0.45, 0.0, 0.0]])
    return Vignetting(k, [0.06, -0.04], "flat", covariance=np.eye(11) * cov, aspect=W / H)


def _radius():
    yy, xx = np.mgrid[0:H, 0:W]
    return np.hypot(xx - W / 2, yy - H / 2) / np.hypot(W / 2, H / 2)


@pytest.fixture(scope="module")
def scene_and_pipeline():
    pad = 16
    big = sim.make_scene(H + 2 * pad, W + 2 * pad, dynamic_range_stops=9.0, saturation=0.3,
                         seed=7)
    return big, pad, sim.default_pipeline(seed=7)


def _frames(big, pad, pipe, shifts, vignetting):
    """One frame per time, each cropped at its shift (the camera moved), the lens's
    falloff applied in the frame's own pixels, then rendered."""
    centre = big[pad:pad + H, pad:pad + W]
    scale = 0.18 / (np.median(centre.mean(-1)) * np.sqrt(TIMES[0] * TIMES[-1]))
    fall = np.ones((H, W, 3), np.float32) if vignetting is None else vignetting.map(H, W)
    out = []
    for k, (t, (dx, dy)) in enumerate(zip(TIMES, shifts)):
        crop = big[pad + dy:pad + dy + H, pad + dx:pad + dx + W]
        out.append(sim.simulate_stack(crop * fall, pipe, [t], jitter=0.0, exposure_scale=scale,
                                      seed=k).images[0])
    return out


@pytest.fixture(scope="module")
def tripod(scene_and_pipeline):
    big, pad, pipe = scene_and_pipeline
    still = [(0, 0)] * len(TIMES)
    plain = _frames(big, pad, pipe, still, None)
    model = selfcal.calibrate_response(plain, TIMES)
    base = selfcal.merge_hdr(plain, TIMES, model, options=MergeOptions(vignetting="none"))
    return model, base, _frames(big, pad, pipe, still, _vignetting())


def _error(result, base, where):
    ok = ~result.unmeasured & ~base.unmeasured & where
    return float(np.median(np.log(result.radiance[ok] / base.radiance[ok])))


def test_tripod_merge_divides_the_falloff_out(tripod):
    model, base, frames = tripod
    r = _radius()
    kept = selfcal.merge_hdr(frames, TIMES, model, options=MergeOptions(vignetting="none"))
    divided = selfcal.merge_hdr(frames, TIMES, model,
                                options=MergeOptions(vignetting=_vignetting()))
    assert _error(kept, base, r > 0.85) < -0.25       # the corners are dark without
    assert abs(_error(divided, base, r > 0.85)) < 0.03
    assert abs(_error(divided, base, r < 0.2)) < 0.02
    assert divided.diagnostics["vignetting"]["divided"] == "after the merge"
    assert divided.diagnostics["vignetting"]["source"] == "flat"


def test_moved_frames_divide_it_per_frame(scene_and_pipeline, tripod):
    big, pad, pipe = scene_and_pipeline
    model, base, _ = tripod
    shifts = [(-10, -6), (8, -5), (0, 0), (-6, 9), (10, 7)]
    frames = _frames(big, pad, pipe, shifts, _vignetting())
    r = _radius()
    divided = selfcal.merge_hdr(frames, TIMES, model, align="mtb",
                                options=MergeOptions(vignetting=_vignetting()))
    assert divided.diagnostics["vignetting"]["divided"] == "per frame"
    # the reference frame's corners hold other frames' brighter middles: still right
    assert abs(_error(divided, base, (r > 0.8) & (r < 0.95))) < 0.04
    assert abs(_error(divided, base, r < 0.2)) < 0.03


def test_sigma_grows_with_the_vignetting_band(tripod):
    model, _, frames = tripod
    narrow = selfcal.merge_hdr(frames, TIMES, model,
                               options=MergeOptions(vignetting=_vignetting(1e-8), sigma=True))
    wide = selfcal.merge_hdr(frames, TIMES, model,
                             options=MergeOptions(vignetting=_vignetting(1e-2), sigma=True))
    r = _radius()
    ok = ~narrow.unmeasured & (r > 0.8)
    rel_narrow = np.median((narrow.sigma / narrow.radiance)[ok])
    rel_wide = np.median((wide.sigma / wide.radiance)[ok])
    assert rel_wide > rel_narrow + 0.05
    # at the optical centre the falloff is 1 by definition: its σ is nothing there
    assert wide.diagnostics["vignetting"]["log_sigma_median"] > 0


def test_self_without_a_fitted_vignetting_says_why(tripod):
    model, _, frames = tripod
    with pytest.raises(selfcal.InputError, match="self-calibration"):
        selfcal.merge_hdr(frames, TIMES, model, options=MergeOptions(vignetting="self"))
    with pytest.raises(selfcal.InputError, match="vignetting must be one of"):
        selfcal.merge_hdr(frames, TIMES, model, options=MergeOptions(vignetting="sometimes"))


def test_auto_on_arrays_finds_none_and_records_why(tripod):
    model, base, frames = tripod
    result = selfcal.merge_hdr(frames, TIMES, model)
    record = result.diagnostics["vignetting"]
    assert record["source"] is None and record["chosen_by"] == "auto"
    assert any("arrays" in reason for reason in record["reasons"])


def test_a_vignetting_for_another_aspect_is_refused(tripod):
    model, _, frames = tripod
    other = Vignetting(np.zeros((3, 3)), np.zeros(2), "flat", aspect=1.0)
    with pytest.raises(selfcal.InputError, match="aspect"):
        selfcal.merge_hdr(frames, TIMES, model, options=MergeOptions(vignetting=other))


def _write_with_lens(folder, frames, times, *, lens=True):
    """The frames as JPEG files whose EXIF names a Canon 5D Mark II with an EF 50mm f/1.8
    II at f/1.8 (a lens lensfun holds vignetting data for), or no lens."""
    import cv2

    from selfcal.io.images import exif_bytes
    from selfcal.sim.encoding import jpeg_with_exif

    paths = []
    for k, (im, t) in enumerate(zip(frames, times)):
        ok, data = cv2.imencode(".jpg", np.ascontiguousarray(im[:, :, ::-1]),
                                [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        exif = exif_bytes(t, 1.8, 100, make="Canon", model="Canon EOS 5D Mark II",
                          **({"lens_make": "Canon", "lens_model": "EF50mm f/1.8 II",
                              "focal_length": 50, "focus_distance": 3.0} if lens else {}))
        path = folder / f"frame{k}.jpg"
        path.write_bytes(jpeg_with_exif(data.tobytes(), exif))
        paths.append(path)
    return paths


def test_auto_applies_the_lens_profile_the_exif_names(tmp_path, scene_and_pipeline, tripod):
    from selfcal.lens import lens_vignetting

    big, pad, pipe = scene_and_pipeline
    model, base, _ = tripod
    probe = _write_with_lens(tmp_path, [np.zeros((H, W, 3), np.uint8)], [TIMES[0]])[0]
    profile, match = lens_vignetting(probe)
    assert profile is not None, match.reason
    # the bracket shot through that lens carries its falloff
    frames = _frames(big, pad, pipe, [(0, 0)] * len(TIMES), profile)
    with_lens = _write_with_lens(tmp_path, frames, TIMES)
    (tmp_path / "plain").mkdir()
    without_lens = _write_with_lens(tmp_path / "plain", frames, TIMES, lens=False)
    r = _radius()

    result = selfcal.merge_hdr(with_lens, TIMES, model)
    record = result.diagnostics["vignetting"]
    assert record["source"] == "lens" and "50mm" in record["description"]
    assert abs(_error(result, base, r > 0.85)) < 0.04

    kept = selfcal.merge_hdr(without_lens, TIMES, model)
    assert kept.diagnostics["vignetting"]["source"] is None
    assert any("lens" in why for why in kept.diagnostics["vignetting"]["reasons"])
    assert _error(kept, base, r > 0.85) < -0.3       # the falloff at f/1.8, left in


# slow: two handheld merges with the fit on the fly (test_vignetting_fit fits fast)
@pytest.mark.slow
def test_a_handheld_merge_on_the_fly_fits_and_divides_the_falloff():
    """merge_hdr(align="homography") without a model: the calibration on the fly fits the
    vignetting from the frames' motion, and auto divides it out per frame."""
    times = [1 / 200, 1 / 100, 1 / 50, 1 / 25, 1 / 12]
    scene = sim.make_scene(300, 440, dynamic_range_stops=10.0, saturation=0.5, seed=4)
    truth = sim.random_vignetting(4, corner_stops=(1.5, 1.5), aspect=306 / 208)
    stack = sim.simulate_handheld_stack(scene, sim.default_pipeline(seed=4), times,
                                        frame_shape=(208, 306), vignetting=truth, seed=4)
    result = selfcal.merge_hdr(stack.images, times, align="homography")
    record = result.diagnostics["vignetting"]
    assert record["source"] == "self" and record["divided"] == "per frame"
    fitted = result.model.vignetting
    assert sim.vignetting_rms(fitted, truth, 208, 306) < 0.05
    kept = selfcal.merge_hdr(stack.images, times, result.model, align="homography",
                             options=MergeOptions(vignetting="none"))
    # against the scene itself: the corners come out right only with the falloff divided
    e_true = stack.radiance @ stack.pipeline.matrix.T
    yy, xx = np.mgrid[0:208, 0:306]
    r = np.hypot(xx - 152.5, yy - 103.5) / (0.5 * np.hypot(208, 306))

    def bias(res):
        ok = ~res.unmeasured & (e_true.min(axis=2) > 0)
        log = np.log(np.maximum(res.radiance, 1e-12) / np.maximum(e_true, 1e-12))
        return float(np.median(log[ok & (r > 0.8)]) - np.median(log[ok & (r < 0.3)]))

    assert bias(kept) < -0.3
    assert abs(bias(result)) < 0.1


@pytest.mark.parametrize("shape", [(600, 900), (208, 306), (13, 17), (1, 5)])
def test_the_merge_evaluates_the_falloff_from_its_coarse_grid_within_5e_4(shape):
    """SmoothField (a coarse grid every power-of-two pixels, one OpenCV remap per strip)
    against the falloff evaluated exactly at every pixel, strip by strip as the merge
    asks for it, on a strong off-centre falloff (about 2 stops at the corner)."""
    from selfcal.hdr.vignetting import SmoothField

    hh, ww = shape
    v = sim.random_vignetting(3)
    field = SmoothField(lambda xs, ys: v.at(hh, ww, xs, ys), shape)
    assert field.step & (field.step - 1) == 0
    xs = np.arange(ww, dtype=float)[None, :]
    for y in range(0, hh, 96):
        s = slice(y, min(y + 96, hh))
        exact = v.at(hh, ww, xs, np.arange(s.start, s.stop, dtype=float)[:, None])
        np.testing.assert_allclose(field.strip(s), exact, rtol=5e-4, atol=0)
    with pytest.raises(ValueError, match="power of two"):
        SmoothField(lambda xs, ys: v.at(hh, ww, xs, ys), shape, step=6)
