"""HDR merge (selfcal.hdr), alignment (selfcal.stack.align), radiance files (selfcal.hdr.io), CLI."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402

import selfcal  # noqa: E402
from selfcal import sim  # noqa: E402
from selfcal.stack.align import estimate_alignment, warp_to_reference  # noqa: E402
from selfcal.hdr import (HDRResult, MergeOptions, NoiseModel, linearize_images,  # noqa: E402
                         merge_hdr)
from selfcal.hdr.deghost import MISALIGNMENT_GAIN  # noqa: E402
from selfcal.hdr.io import (  # noqa: E402
    OutputWriteError,
    read_radiance,
    write_linear,
    write_preview,
    write_radiance,
)
from selfcal.response import SolverOptions  # noqa: E402
from selfcal.response.model import ResponseModel  # noqa: E402

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
TIMES = [1 / 250, 1 / 60, 1 / 15, 1 / 4]
CURVES = (sim.ToneCurve.film(contrast=0.97, toe=0.09, shoulder=0.79, exposure=1.08),
          sim.ToneCurve.film(contrast=1.00, toe=0.10, shoulder=0.80, exposure=1.00),
          sim.ToneCurve.film(contrast=1.03, toe=0.11, shoulder=0.81, exposure=0.95))


def true_model(stack, n=None) -> ResponseModel:
    """A ResponseModel holding the simulator's true inverse response."""
    n = len(stack.images) if n is None else n
    return ResponseModel(intensity=np.arange(256) / 255.0, inverse=stack.inverse_response(),
                         coefficients=np.zeros((3, 1)), basis_name="truth",
                         exposures=np.asarray(stack.true_exposures, dtype=float),
                         exposure_times=list(stack.exposure_times),
                         sources=[f"array #{k}" for k in range(n)])


def truth_radiance(stack) -> np.ndarray:
    """f⁻¹(I)/t of the simulator: M·ρ·exposure_scale (gamut mapping aside)."""
    return (stack.radiance.astype(np.float64) @ stack.pipeline.matrix.T) * stack.exposure_scale


def simple_pipeline():
    return sim.CameraPipeline(matrix=np.eye(3), curves=CURVES, gamut="clip")


@pytest.fixture(scope="module")
def stack():
    scene = sim.make_scene(96, 144, dynamic_range_stops=12, saturation=0.3, seed=3)
    return sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0, jpeg_quality=90,
                                seed=3)


def rel_error(estimate, truth, mask, scale=None):
    ratio = estimate[mask] / truth[mask]
    if scale is None:
        scale = 1.0
    elif scale == "best":
        scale = float(np.median(ratio))
    return float(np.median(np.abs(ratio / scale - 1)))


# ------------------------------------------------------------------ radiance accuracy

@pytest.mark.parametrize("weighting", ["hat", "noise"])
def test_radiance_matches_truth_with_true_response(stack, weighting):
    # the merge's arithmetic with the truth: the true exposures as they are
    result = merge_hdr(stack.images, stack.true_exposures, true_model(stack),
                       weighting=weighting,
                       options=MergeOptions(exposures=selfcal.ExposureRule(times="held")))
    assert isinstance(result, HDRResult)
    assert result.radiance.dtype == np.float32 and result.radiance.shape == (96, 144, 3)
    assert result.unmeasured.dtype == bool and result.unmeasured.shape == (96, 144)
    truth = truth_radiance(stack)
    err = rel_error(result.radiance, truth, ~result.unmeasured)
    assert err < 0.03, err
    assert result.exposure_source == "given"
    np.testing.assert_allclose(result.exposures, stack.true_exposures)


def test_radiance_with_on_the_fly_calibration(stack):
    stages = []
    result = merge_hdr(stack.images, stack.exposure_times,
                       progress=lambda stage, done, total, detail="": stages.append(stage))
    assert "merge" in stages and "read" in stages
    truth = truth_radiance(stack)
    mask = ~result.unmeasured
    assert rel_error(result.radiance, truth, mask, scale="best") < 0.06
    # f⁻¹(white) = 1 and times in seconds: the scale is the simulator's, within 10 %
    assert abs(np.median(result.radiance[mask] / truth[mask]) - 1) < 0.1
    assert result.model is not None and result.diagnostics["model_verdict"] == "ok"


def test_on_the_fly_calibration_takes_the_merges_clip_margin(stack):
    # one clip margin per merge (issue 43): the calibration's is the merge's, whatever
    # calibrate_options say
    opts = MergeOptions(clip_margin=4, calibrate_options=selfcal.ResponseOptions(
        solver=SolverOptions(clip_margin=1)))
    result = merge_hdr(stack.images, stack.exposure_times, options=opts)
    assert result.model.diagnostics["clip_margin"] == 4
    assert MergeOptions().clip_margin == selfcal.ResponseOptions().solver.clip_margin


def test_noise_weighting_formula():
    from selfcal.hdr.weights import noise_variance

    nm = NoiseModel(shot=1e-4, read=1e-3, code=1.0, relative=0.0)
    v = noise_variance(np.array([0.25]), np.array([2.0]), 0.5, nm)
    expected = (1e-4 * 0.25 + 1e-6 + (2.0 / 255) ** 2) / 0.25
    np.testing.assert_allclose(v, expected)
    with pytest.raises(selfcal.InputError):
        NoiseModel(shot=-1)


def test_the_default_noise_model_is_noise_model_with_its_own_defaults():
    # one default (issue 43): NoiseModel()'s fields are the merge's noise model, 3 % relative
    from selfcal.hdr.weights import DEFAULT_NOISE

    assert NoiseModel() == DEFAULT_NOISE and NoiseModel().relative == 0.03


def test_weighting_callable(stack):
    model = true_model(stack)
    flat = merge_hdr(stack.images, stack.true_exposures, model,
                     weighting=lambda z: np.ones_like(z))
    truth = truth_radiance(stack)
    assert rel_error(flat.radiance, truth, ~flat.unmeasured) < 0.05
    with pytest.raises(selfcal.InputError, match="weighting"):
        merge_hdr(stack.images, stack.true_exposures, model, weighting=lambda z: -z)
    with pytest.raises(selfcal.InputError, match="weighting"):
        merge_hdr(stack.images, stack.true_exposures, model, weighting="median")


def test_linear_raw_frames(stack):
    result = merge_hdr(stack.raws, stack.true_exposures, linear=True, weighting="noise")
    truth = stack.radiance.astype(np.float64) * stack.exposure_scale
    assert rel_error(result.radiance, truth, ~result.unmeasured) < 0.01
    with pytest.raises(selfcal.InputError, match="linear"):
        merge_hdr(stack.raws, stack.true_exposures, true_model(stack), linear=True)
    with pytest.raises(selfcal.InputError, match="linear=True"):
        merge_hdr(stack.raws, stack.true_exposures)


def test_pipeline_model_with_to_raw(stack):
    """A model with only ``to_raw`` (the RAW path's backward model) plugs in."""
    model = true_model(stack)

    class Backward:
        def to_raw(self, rendered):
            return model.linearize(rendered)

    a = merge_hdr(stack.images, stack.true_exposures, model)
    b = merge_hdr(stack.images, stack.true_exposures, Backward())
    np.testing.assert_allclose(b.radiance, a.radiance, rtol=1e-5)
    np.testing.assert_array_equal(a.unmeasured, b.unmeasured)


# ------------------------------------------------------------------ clipping

def test_clipped_channel_gives_zero_weight():
    """A frame clipped in one channel contributes nothing at that pixel (any channel)."""
    model = ResponseModel(intensity=np.linspace(0, 1, 256), inverse=np.repeat(
        (np.linspace(0, 1, 256) ** 2.2)[:, None], 3, axis=1), coefficients=np.zeros((3, 1)),
        basis_name="gamma", exposures=np.array([1.0, 4.0]), exposure_times=[1.0, 4.0],
        sources=["a", "b"])
    short = np.full((4, 5, 3), 100, np.uint8)
    long = np.full((4, 5, 3), 180, np.uint8)
    long[1, 2, 0] = 255          # red clipped in the long frame at one pixel
    long[2, 3, 2] = 1            # blue crushed in the long frame at another
    # lossless frames: no widening of the clipped pixel (it would cover this tiny frame)
    result = merge_hdr([short, long], [1.0, 4.0], model, options=MergeOptions(lossy=False))
    lin = model.inverse_response()
    only_short = lin[100] / 1.0
    for y, x in [(1, 2), (2, 3)]:
        np.testing.assert_allclose(result.radiance[y, x], only_short, rtol=1e-6)
        assert result.frame_count[y, x] == 1
    mixed = result.radiance[0, 0]
    assert not np.allclose(mixed, only_short)
    assert result.frame_count[0, 0] == 2
    assert not result.unmeasured.any()
    # the 0.x keyword form is gone: the setting is MergeOptions.lossy
    with pytest.raises(TypeError, match="lossy"):
        merge_hdr([short, long], [1.0, 4.0], model, lossy=False)


def test_unmeasured_region_flagged_and_filled():
    scene = sim.make_scene(64, 96, dynamic_range_stops=8, saturation=0.2, seed=5)
    scene[8:24, 10:30] = 500.0      # far brighter than white in the shortest frame
    scene[40:56, 60:80] = 0.0       # black in the longest frame
    st = sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0,
                              jpeg_quality=None, seed=5,
                              sensor=sim.SensorModel(read_noise=0.0))
    result = merge_hdr(st.images, st.true_exposures, true_model(st))
    assert result.unmeasured[10:22, 12:28].all()
    assert result.unmeasured[42:54, 62:78].all()
    outside = np.ones(result.unmeasured.shape, bool)
    outside[6:26, 8:32] = False
    outside[38:58, 58:82] = False
    assert result.unmeasured[outside].mean() < 0.02
    # highlights come from the darkest frame (f⁻¹(white)/e_min, a lower bound) ...
    np.testing.assert_allclose(result.radiance[15, 20], 1.0 / st.true_exposures[0], rtol=1e-5)
    # ... shadows from the brightest frame
    np.testing.assert_allclose(result.radiance[48, 70], 0.0, atol=1e-6)


# ------------------------------------------------------------------ exposures

def test_exif_exposure_scale_across_sessions(tmp_path):
    """t·ISO/100/N² puts two brackets with different apertures on one scale."""
    scene = sim.make_scene(64, 96, dynamic_range_stops=10, saturation=0.2, seed=2)
    a = sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0, seed=2)
    # session b: f/16 (a quarter of the light) at 4x the times: the same pixels
    b = sim.simulate_stack(scene, simple_pipeline(), [4 * t for t in TIMES], jitter=0.0,
                             exposure_scale=a.exposure_scale / 4, seed=2)
    b.f_number = 16.0
    pa = a.write(tmp_path / "a")
    pb = b.write(tmp_path / "b")
    model = true_model(a)
    ra = merge_hdr(pa, model=model)
    rb = merge_hdr(pb, model=model)
    # the exposures measured from the pixels keep the times' scale: the median ratio is 1
    assert ra.exposure_source == rb.exposure_source == "measured+exif"
    assert {f.used_from for f in ra.exposure_record.frames} == {"measured"}
    assert abs(np.median(np.log(ra.exposures / (np.array(TIMES) / 64)))) < 1e-9
    np.testing.assert_allclose(ra.exposures, np.array(TIMES) / 64, rtol=0.02)
    mask = ~(ra.unmeasured | rb.unmeasured)
    ratio = np.median(rb.radiance[mask] / ra.radiance[mask])
    assert abs(ratio - 1) < 0.02, ratio


def test_contradicted_exif_time_uses_model_estimate(tmp_path):
    scene = sim.make_scene(96, 144, dynamic_range_stops=12, saturation=0.3, seed=4)
    st = sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0, seed=4)
    st.exposure_times = np.array(st.exposure_times)
    st.exposure_times[2] *= 2.0          # a wrong EXIF time
    paths = st.write(tmp_path)
    result = merge_hdr(paths)
    # the calibration measured every frame's exposure: the merge uses those, and says so
    # in one line
    frame = result.exposure_record.frames[2]
    assert frame.used_from == "measured" and frame.contradicted is not None
    assert abs(frame.moved + 0.5) < 0.1, frame
    assert len([w for w in result.warnings if "--hold-times" in w]) == 1, result.warnings
    assert result.exposure_source == "measured+exif"
    rel = result.exposures / (np.array(TIMES) / 64)
    assert abs(rel[2] - 1) < 0.1, rel
    # (the curve calibrated with a wrong time is itself less accurate than usual)
    truth = truth_radiance(st)
    assert rel_error(result.radiance, truth, ~result.unmeasured, scale="best") < 0.12


def test_refined_exposures_are_used_and_said_once(stack):
    given = np.array(stack.exposure_times) * [1, 1.05, 1, 1]
    result = merge_hdr(stack.images, given,
                       options=MergeOptions(exposures=selfcal.ExposureRule(refine=True)))
    record = result.exposure_record
    assert record.refined and record.rule == "measured"
    assert [f.given for f in record.frames] == pytest.approx(list(given))
    assert len([w for w in result.warnings if "--hold-times" in w]) <= 1, result.warnings
    held = merge_hdr(stack.images, given,
                     options=MergeOptions(exposures=selfcal.ExposureRule(times="held")))
    np.testing.assert_allclose(held.exposures, given, rtol=1e-12)
    assert not any("--hold-times" in w for w in held.warnings)


def test_unknown_exposures_need_a_model(stack):
    other = true_model(stack)
    other.sources = ["x.jpg", "y.jpg", "z.jpg", "w.jpg"]
    with pytest.raises(selfcal.CalibrationError, match="array #0"):
        merge_hdr(stack.images, None, other)


def test_bad_inputs_name_the_file(stack, tmp_path):
    small = stack.images[1][:50]
    with pytest.raises(selfcal.InputError, match="array #1"):
        merge_hdr([stack.images[0], small], [1, 2], true_model(stack))
    with pytest.raises(selfcal.InputError, match="missing.jpg"):
        merge_hdr([tmp_path / "missing.jpg"], [1], true_model(stack))
    bad = tmp_path / "cut.jpg"
    bad.write_bytes((FIXTURES / "stack" / "frame_00.jpg").read_bytes()[:2000])
    with pytest.raises(selfcal.InputError, match="cut.jpg"):
        merge_hdr([bad, FIXTURES / "stack" / "frame_01.jpg"], [1, 2], true_model(stack))


# ------------------------------------------------------------------ alignment

def _shifted_stack(shifts, seed=6):
    big = sim.make_scene(128, 176, dynamic_range_stops=10, saturation=0.3, seed=seed)
    st = sim.simulate_stack(big, simple_pipeline(), TIMES, jitter=0.0, jpeg_quality=None,
                              seed=seed)
    y0, x0 = 16, 16
    frames = [im[y0 + dy:y0 + dy + 96, x0 + dx:x0 + dx + 144]
              for im, (dx, dy) in zip(st.images, shifts)]
    return st, frames


def test_mtb_recovers_integer_shift():
    shifts = [(5, -3), (0, 0), (0, 0), (-4, 6)]
    st, frames = _shifted_stack(shifts)
    transforms = estimate_alignment(frames, st.true_exposures, method="mtb", reference=1)
    for (dx, dy), t in zip(shifts, transforms):
        np.testing.assert_allclose(t[:2, 2], [-dx, -dy], atol=0.01)
        np.testing.assert_allclose(t[:2, :2], np.eye(2))
    # the merge with alignment agrees with the truth much better than without
    truth = truth_radiance(st)[16:112, 16:160]
    model = true_model(st)
    plain = merge_hdr(frames, st.true_exposures, model, options=MergeOptions(reference=1))
    aligned = merge_hdr(frames, st.true_exposures, model, align="mtb", options=MergeOptions(reference=1))
    inner = np.zeros((96, 144), bool)
    inner[8:-8, 8:-8] = True
    e_plain = rel_error(plain.radiance, truth, inner & ~plain.unmeasured)
    e_aligned = rel_error(aligned.radiance, truth, inner & ~aligned.unmeasured)
    assert e_aligned < 0.5 * e_plain, (e_aligned, e_plain)


def textured_scene(h, w, seed):
    """Log-normal texture at two scales, with slowly varying colour."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    fine = gaussian_filter(rng.standard_normal((h, w)), 2.0)
    coarse = gaussian_filter(rng.standard_normal((h, w)), 12.0)
    lum = np.exp2(fine / fine.std() + 2.5 * coarse / coarse.std() - 5)
    colour = gaussian_filter(rng.standard_normal((h, w, 3)), (6, 6, 0))
    colour = np.clip(1 + 0.2 * colour / colour.std(), 0.5, 1.5)
    return (lum[..., None] * colour).astype(np.float32)


def test_on_the_fly_calibration_uses_aligned_frames():
    shifts = [(5, -3), (0, 0), (0, 0), (-4, 6)]
    st, frames = _shifted_stack(shifts)
    result = merge_hdr(frames, st.true_exposures, align="mtb", options=MergeOptions(reference=1))
    assert "aligned" in result.diagnostics["calibrated_on"]
    assert not any("contradict" in w for w in result.warnings), result.warnings
    for (dx, dy), t in zip(shifts, result.transforms):
        np.testing.assert_allclose(t[:2, 2], [-dx, -dy])
    truth = truth_radiance(st)[16:112, 16:160]
    inner = np.zeros((96, 144), bool)
    inner[8:-8, 8:-8] = True
    assert rel_error(result.radiance, truth, inner & ~result.unmeasured, scale="best") < 0.06


def test_mtb_on_featureless_dark_frames_keeps_zero_shift():
    """OpenCV's MTB returns its largest shift when the bitmaps carry nothing; we keep 0."""
    rng = np.random.default_rng(0)
    dark = [rng.integers(0, 3, (96, 144, 3)).astype(np.uint8) for _ in range(2)]
    transforms = estimate_alignment(dark, [1.0, 2.0], method="mtb", reference=0)
    np.testing.assert_allclose(transforms[1], np.eye(3))


@pytest.mark.parametrize("working_size", [1024, 130])      # 130: estimated on a smaller grid
def test_homography_alignment_recovers_small_warp(working_size):
    scene = textured_scene(128, 192, seed=8)
    pipe = simple_pipeline()
    m = np.array([[1.01, 0.012, -2.5], [-0.008, 0.995, 1.7], [2e-5, -1.5e-5, 1.0]])
    warped = cv2.warpPerspective(scene, m, (192, 128), flags=cv2.INTER_LINEAR
                                 | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    a = sim.simulate_stack(scene, pipe, TIMES, jitter=0.0, seed=8)
    b = sim.simulate_stack(warped, pipe, TIMES, jitter=0.0, seed=8)
    frames = [b.images[0], a.images[1], a.images[2], b.images[3]]
    transforms = estimate_alignment(frames, a.true_exposures, true_model(a),
                                    method="homography", reference=1,
                                    working_size=working_size)
    expected = np.linalg.inv(m)
    corners = np.array([[16, 16, 1], [176, 16, 1], [16, 112, 1], [176, 112, 1]], float)
    for k in (0, 3):
        got = corners @ transforms[k].T
        want = corners @ expected.T
        err = np.hypot(*(got[:, :2] / got[:, 2:] - want[:, :2] / want[:, 2:]).T)
        assert err.max() < 0.25, (k, err)
    np.testing.assert_allclose(transforms[1], np.eye(3))


def test_warp_to_reference_integer_and_general():
    img = np.arange(5 * 7 * 3, dtype=np.uint8).reshape(5, 7, 3)
    t = np.array([[1, 0, 2], [0, 1, -1], [0, 0, 1]], float)
    out = warp_to_reference(img, t)
    np.testing.assert_array_equal(out[1:, :5], img[:4, 2:])
    assert (out[0] == 0).all()
    h = np.array([[1, 0, 0.5], [0, 1, 0], [0, 0, 1]], float)
    out = warp_to_reference(img.astype(np.float32), h)
    np.testing.assert_allclose(out[:, :-1], (img[:, :-1] + img[:, 1:]) / 2.0, atol=1e-3)


# ------------------------------------------------------------------ deghosting

def test_deghosting_flags_a_moving_object():
    scene = sim.make_scene(96, 144, dynamic_range_stops=10, saturation=0.3, seed=9)
    moved = scene.copy()
    moved[30:60, 90:120] = scene[30:60, 90:120] * 0.25     # a dark object, in frame 2 only
    pipe = simple_pipeline()
    a = sim.simulate_stack(scene, pipe, TIMES, jitter=0.0, seed=9)
    b = sim.simulate_stack(moved, pipe, TIMES, jitter=0.0, seed=9)
    frames = list(a.images)
    frames[2] = b.images[2]
    model = true_model(a)
    truth = truth_radiance(a)
    # lossy=False: `usable` below is the clip test alone, without the widening of clipped
    # regions for JPEG ringing (which takes pixels near them from frame 2 before deghosting)
    plain = merge_hdr(frames, a.true_exposures, model, options=MergeOptions(reference=1, lossy=False))
    clean = merge_hdr(frames, a.true_exposures, model, deghost=True, options=MergeOptions(reference=1, lossy=False))
    obj = np.zeros((96, 144), bool)
    obj[32:58, 92:118] = True
    # where frame 2 saw the object and the reference frame is unclipped
    usable = obj & (((b.images[2] > 2) & (b.images[2] < 253)).all(axis=2)
                    & ((a.images[1] > 2) & (a.images[1] < 253)).all(axis=2))
    assert usable.sum() > 300
    assert clean.ghost[usable].mean() > 0.9
    away = np.ones(obj.shape, bool)
    away[28:62, 88:122] = False
    assert clean.ghost[away].mean() < 0.005
    assert clean.diagnostics["deghost_excluded_fraction"][2] > 0
    e_plain = rel_error(plain.radiance, truth, obj & ~plain.unmeasured)
    e_clean = rel_error(clean.radiance, truth, obj & ~clean.unmeasured)
    assert e_clean < 0.05 < e_plain, (e_clean, e_plain)
    assert not plain.ghost.any()


# ------------------------------------------------------------------ output files

@pytest.mark.parametrize("name,half,rtol", [("r.exr", False, 0), ("r.exr", True, 1e-3),
                                            ("r.hdr", False, 1e-2), ("r.tif", False, 0),
                                            ("r.tiff", True, 1e-3)])
def test_radiance_round_trip(tmp_path, name, half, rtol):
    rng = np.random.default_rng(0)
    radiance = np.exp(rng.uniform(-6, 6, (20, 30, 3))).astype(np.float32)
    path = write_radiance(tmp_path / name, radiance, half=half)
    back = read_radiance(path)
    assert back.shape == radiance.shape and back.dtype == np.float32
    if rtol == 0:
        np.testing.assert_array_equal(back, radiance)
    elif name.endswith(".hdr"):
        # RGBE: 8-bit mantissas sharing the largest channel's exponent
        peak = radiance.max(axis=2, keepdims=True)
        assert np.all(np.abs(back - radiance) <= rtol * peak)
    else:
        np.testing.assert_allclose(back, radiance, rtol=rtol)
    if name.endswith(".exr"):
        bgr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        np.testing.assert_allclose(bgr[:, :, ::-1], back)
    if name.endswith((".tif", ".tiff")):
        import tifffile

        assert tifffile.imread(path).dtype == (np.float16 if half else np.float32)
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


def test_outputs_atomic_and_not_overwritten(tmp_path, monkeypatch):
    radiance = np.ones((8, 8, 3), np.float32)
    out = tmp_path / "r.exr"
    out.write_bytes(b"old")
    with pytest.raises(selfcal.OutputExistsError):
        write_radiance(out, radiance)
    assert out.read_bytes() == b"old"
    with pytest.raises(selfcal.OutputExistsError, match="input"):
        write_radiance(out, radiance, force=True, inputs=[out])
    # an encoder failure leaves the old file and no temporary file
    monkeypatch.setattr(cv2, "imwrite", lambda *a, **k: False)
    with pytest.raises(OutputWriteError):
        write_radiance(out, radiance, force=True)
    monkeypatch.undo()
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.exr"]
    write_radiance(out, radiance, force=True)
    np.testing.assert_array_equal(read_radiance(out), radiance)
    with pytest.raises(selfcal.InputError, match="format"):
        write_radiance(tmp_path / "r.png", radiance)
    with pytest.raises(selfcal.InputError, match="NaN"):
        write_radiance(tmp_path / "n.exr", np.full((2, 2, 3), np.nan, np.float32))
    preview = write_preview(tmp_path / "p.jpg", radiance * 10)
    assert cv2.imread(str(preview)).shape == (8, 8, 3)
    with pytest.raises(selfcal.OutputExistsError):
        write_preview(tmp_path / "p.jpg", radiance)


def test_linearize_images_and_linear_tiff(stack, tmp_path):
    model = true_model(stack)
    out = list(linearize_images(stack.images[:2], model))
    assert [s for s, _ in out] == ["array #0", "array #1"]
    np.testing.assert_array_equal(out[0][1], model.linearize(stack.images[0]))
    path = write_linear(tmp_path / "l.tif", out[0][1], exposure_time=1 / 250, f_number=8,
                        iso=100)
    import tifffile

    back = tifffile.imread(path)
    assert back.dtype == np.uint16
    np.testing.assert_allclose(back / 65535.0, out[0][1], atol=1 / 65535)
    info = selfcal.io.read_exposure_info(path)
    assert info.exposure_time == pytest.approx(1 / 250) and info.f_number == 8
    fpath = write_linear(tmp_path / "f.tif", out[0][1], float32=True)
    np.testing.assert_array_equal(tifffile.imread(fpath), out[0][1])


# ------------------------------------------------------------------ command line

def run_cli(argv, capsys):
    from selfcal_cli import main as cli_main

    code = cli_main.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out + captured.err


@pytest.fixture(scope="module")
def fixture_model(tmp_path_factory):
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    path = tmp_path_factory.mktemp("model") / "model.json"
    selfcal.calibrate_response(frames).save(path)
    return path


def test_cli_merge(fixture_model, tmp_path, capsys):
    from selfcal_cli.main import EXIT_INPUT, EXIT_OUTPUT

    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    out = tmp_path / "out.exr"
    preview = tmp_path / "p.jpg"
    code, text = run_cli(["merge", *frames, "--model", fixture_model, "-o", out,
                          "--preview", preview, "--align", "mtb", "--deghost",
                          "--weighting", "noise"], capsys)
    assert code == 0, text
    radiance = read_radiance(out)
    assert radiance.shape == (128, 192, 3) and np.isfinite(radiance).all()
    assert cv2.imread(str(preview)) is not None
    assert "unmeasured" in text and "wrote" in text and "EXIF" in text
    before = out.read_bytes()
    code, text = run_cli(["merge", *frames, "--model", fixture_model, "-o", out], capsys)
    assert code == EXIT_OUTPUT and "--force" in text and str(out) in text
    assert out.read_bytes() == before
    code, text = run_cli(["merge", *frames, "-o", out, "--force", "--half"], capsys)
    assert code == 0, text
    assert "calibrated on the fly" in text
    # bad input: a truncated frame is named
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(frames[0].read_bytes()[:3000])
    code, text = run_cli(["merge", cut, *frames[1:], "--model", fixture_model,
                          "-o", tmp_path / "x.exr"], capsys)
    assert code == EXIT_INPUT and "cut.jpg" in text
    assert not (tmp_path / "x.exr").exists()
    code, text = run_cli(["merge", *frames, "-o", tmp_path / "x.png"], capsys)
    assert code == EXIT_INPUT and "x.png" in text
    code, text = run_cli(["merge", *frames, "--model", tmp_path / "none.json",
                          "-o", tmp_path / "x.exr"], capsys)
    assert code == EXIT_INPUT and "none.json" in text
    # never over an input
    tif = tmp_path / "frame.tif"
    selfcal.io.write_image(tif, selfcal.io.read_image(frames[0]))
    code, text = run_cli(["merge", tif, *frames[1:], "-o", tif, "--force"], capsys)
    assert code == EXIT_OUTPUT and "input" in text


def test_cli_linearize(fixture_model, tmp_path, capsys):
    import tifffile

    from selfcal_cli.main import EXIT_INPUT, EXIT_OUTPUT

    frames = sorted((FIXTURES / "stack").glob("*.jpg"))[:3]
    out = tmp_path / "lin"
    code, text = run_cli(["linearize", "--model", fixture_model, *frames, "-o", out], capsys)
    assert code == 0, text
    files = sorted(out.iterdir())
    assert [f.name for f in files] == [f.stem + ".tif" for f in frames]
    model = selfcal.load_model(fixture_model)
    data = tifffile.imread(files[0])
    assert data.dtype == np.uint16
    expected = model.linearize(selfcal.io.read_image(frames[0]))
    np.testing.assert_allclose(data / 65535.0, expected, atol=1 / 65535)
    code, text = run_cli(["linearize", "--model", fixture_model, *frames, "-o", out], capsys)
    assert code == EXIT_OUTPUT and frames[0].stem in text
    code, text = run_cli(["linearize", "--model", fixture_model, *frames, "-o", out,
                          "--float", "--force"], capsys)
    assert code == 0, text
    assert tifffile.imread(files[0]).dtype == np.float32
    code, text = run_cli(["linearize", "--model", tmp_path / "nope.json", *frames,
                          "-o", tmp_path / "l2"], capsys)
    assert code == EXIT_INPUT and "nope.json" in text
    # a TIFF input in the output folder would be overwritten by its own output: refused
    src = tmp_path / "same" / "frame.tif"
    src.parent.mkdir()
    shutil.copy(files[0], src)
    code, text = run_cli(["linearize", "--model", fixture_model, src, "-o", src.parent,
                          "--force"], capsys)
    assert code == EXIT_OUTPUT and "input" in text


def test_cli_merge_times_and_help(tmp_path, capsys):
    from selfcal_cli import main as cli_main

    with pytest.raises(SystemExit) as info:
        cli_main.main(["merge", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for option in ("--model", "--align", "--deghost", "--weighting", "--preview", "--force",
                   "--times"):
        assert option in out
    frames = sorted((FIXTURES / "stack").glob("*.jpg"))
    code, text = run_cli(["merge", *frames, "--times", "1/250", "-o", tmp_path / "a.exr"],
                         capsys)
    assert code == 3 and "--times" in text


def test_merge_raw_files_directly(tmp_path):
    """Raw files are merged as linear camera RGB: radiance = raw / t, no response needed."""
    import shutil

    dng = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "raw" / \
        "colorchart_canon550d.dng"
    if not dng.exists():
        pytest.skip(f"real raw not available ({dng})")
    frames = [tmp_path / "a.dng", tmp_path / "b.dng"]
    for f in frames:
        shutil.copy(dng, f)
    result = selfcal.merge_hdr(frames, exposure_times=[0.02, 0.02])
    raw = selfcal.read_raw_linear(dng).rgb
    usable = (raw > 0.01).all(axis=2) & (raw < 0.9).all(axis=2)
    ratio = result.radiance[usable] / (raw[usable] / 0.02)
    assert np.median(np.abs(ratio - 1)) < 1e-3
    with pytest.raises(selfcal.InputError, match="raw files and rendered"):
        selfcal.merge_hdr([frames[0], FIXTURES / "stack" / "frame_00.jpg"])


def test_merge_with_pipeline_model_gives_camera_raw_radiance():
    """With a RAW-path model the merge is in the camera's raw space (through to_raw).

    A small fit (three matrix sets, the LUT backward: a tenth of the defaults' time) is
    enough: the merge lands within 3 % of the raw signal (median; the bound allows 10 %)."""
    from selfcal.pipeline import PipelineOptions

    pipe = sim.default_pipeline(gamut="smooth", seed=11)
    pair = sim.simulate_raw_jpeg_pair(sim.make_scene(192, 288, saturation=0.4, seed=11),
                                        pipe, seed=11)
    model = selfcal.calibrate_pipeline([pair["raw"]], [pair["rendered"]], seed=0,
                                       options=PipelineOptions(n_sets=3, backward="lut"))
    times = [1 / 250, 1 / 60, 1 / 15]
    stack = sim.simulate_stack(sim.make_scene(192, 288, saturation=0.4, seed=12), pipe,
                                 times, jitter=0.0, jpeg_quality=90, seed=12)
    result = selfcal.merge_hdr(stack.images, times, model=model)
    truth = stack.radiance * stack.exposure_scale   # raw signal per second
    measured = ~result.unmeasured & (truth > 1e-3).all(axis=2)
    rel = np.abs(result.radiance[measured] / truth[measured] - 1)
    assert np.median(rel) < 0.1


def test_calibrate_response_aligns_handheld_frames_first():
    shifts = [(5, -3), (0, 0), (0, 0), (-4, 6)]
    st, frames = _shifted_stack(shifts)
    times = list(st.true_exposures)
    unaligned = selfcal.calibrate_response(frames, times)
    aligned = selfcal.calibrate_response(frames, times, align="mtb")
    assert "aligned" in aligned.diagnostics["calibrated_on"]
    moves = [t[0][2] for t in aligned.diagnostics["alignment"]["transforms"]]
    np.testing.assert_allclose(moves, [-dx for dx, _ in shifts])
    # misregistered correspondences inflate the fit residual; aligned ones do not
    assert (aligned.diagnostics["residual_rms_log"]
            < 0.5 * unaligned.diagnostics["residual_rms_log"])
    assert unaligned.exposure_record.contradictions()
    assert not aligned.exposure_record.contradictions()
    truth = st.inverse_response()

    def err(m):
        return np.sqrt(np.mean((m.inverse_response()[1:255] - truth[1:255]) ** 2))

    assert err(aligned) < 0.008 < err(unaligned)
    # the calibration options reach the solve on the aligned frames
    margin4 = selfcal.calibrate_response(frames, times, align="mtb",
                                         options=selfcal.ResponseOptions(
                                             solver=SolverOptions(clip_margin=4)))
    assert margin4.diagnostics["clip_margin"] == 4
    with pytest.raises(selfcal.InputError, match="unknown alignment"):
        selfcal.calibrate_response(frames, times, align="sift")


# ------------------------------------------------------------------ right by default

FLOOR = np.array([14, 18, 16], np.uint8)       # per-channel black pedestal, as memorial's
LONG_TIMES = [1 / 4096, 1 / 1024, 1 / 256, 1 / 64, 1 / 16, 1 / 4, 1]


@pytest.fixture(scope="module")
def floored():
    """A lossless stack whose codes never go below a per-channel black floor."""
    scene = sim.make_scene(96, 144, dynamic_range_stops=14, saturation=0.3, seed=11)
    st = sim.simulate_stack(scene, simple_pipeline(), LONG_TIMES, jitter=0.0,
                              jpeg_quality=None, seed=11)
    st.images = [np.maximum(im, FLOOR) for im in st.images]
    return st


def test_black_floor_detected_and_given_zero_weight(floored):
    """Default weights (inverse variance, floors at zero) beat the hat on a floored stack.

    The hat merge as it was (no floor: ``stuck_codes=False``) lets f⁻¹(floor)/e of the
    short frames into the shadows, as on memorial.
    """
    truth = truth_radiance(floored)
    model = true_model(floored)
    default = merge_hdr(floored.images, floored.true_exposures, model)
    hat = merge_hdr(floored.images, floored.true_exposures, model, weighting="hat", options=MergeOptions(stuck_codes=False))
    floor = np.asarray(default.diagnostics["stuck_codes"]["floor"])
    assert np.all(floor >= FLOOR) and np.all(floor <= FLOOR + 4), floor
    mask = ~default.unmeasured
    e_default = rel_error(default.radiance, truth, mask)
    e_hat = rel_error(hat.radiance, truth, mask)
    assert e_default < 0.02 and e_default < 0.2 * e_hat, (e_default, e_hat)
    # pixels at the floor in every frame are bounds, not measurements: flagged
    dark = [im.copy() for im in floored.images]
    for im in dark:
        im[40:50, 40:60] = FLOOR
    flagged = merge_hdr(dark, floored.true_exposures, model)
    assert flagged.unmeasured[40:50, 40:60].all()
    assert flagged.unmeasured.mean() < 0.03
    # the calibration finds the same floor and hands it to the merge
    cal = selfcal.calibrate_response(floored.images, floored.exposure_times)
    cal_floor = 255 * np.asarray(cal.diagnostics["stuck_codes"]["floor"])
    assert np.all(cal_floor >= FLOOR) and np.all(cal_floor <= FLOOR + 4), cal_floor
    assert merge_hdr(floored.images, floored.exposure_times, cal).diagnostics[
        "stuck_codes"]["from"] == "model"


@pytest.fixture(scope="module")
def highlights():
    """A JPEG stack with sharp highlight edges, and its truth."""
    scene = sim.make_scene(96, 144, dynamic_range_stops=8, saturation=0.2, seed=12)
    st0 = sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0, seed=12)
    e_short = st0.exposure_scale * st0.true_exposures[0]
    scene[8:88, 8:72] = 3.0 / e_short           # clipped in every frame, around ...
    scene[22:74, 21:59] = 0.85 / e_short        # ... highlights the shortest frame measures
    st = sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0, jpeg_quality=85,
                              seed=12)
    return st


def test_pixels_clipped_in_every_frame_are_flagged(highlights):
    st = highlights
    result = merge_hdr(st.images, st.true_exposures, true_model(st))
    clipped_everywhere = np.all([(raw >= 1.0).any(axis=2) for raw in st.raws], axis=0)
    assert clipped_everywhere.sum() > 500
    assert result.unmeasured[clipped_everywhere].all()
    # without the widening for JPEG ringing, some are not (the fault)
    plain = merge_hdr(st.images, st.true_exposures, true_model(st), options=MergeOptions(lossy=False))
    assert not plain.unmeasured[clipped_everywhere].all()


def test_shortest_frame_only_pixels_within_five_percent(highlights):
    st = highlights
    result = merge_hdr(st.images, st.true_exposures, true_model(st))
    clipped = [(raw >= 1.0).any(axis=2) for raw in st.raws]
    only_short = ~clipped[0] & np.all(clipped[1:], axis=0) & ~result.unmeasured
    assert only_short.sum() > 300
    truth = truth_radiance(st)
    y = result.radiance[only_short] @ [0.2126, 0.7152, 0.0722]
    y_true = truth[only_short] @ [0.2126, 0.7152, 0.0722]
    assert np.max(np.abs(y / y_true - 1)) <= 0.05
    # without the widening for JPEG ringing, some are not (the fault)
    plain = merge_hdr(st.images, st.true_exposures, true_model(st), options=MergeOptions(lossy=False))
    both = ~clipped[0] & np.all(clipped[1:], axis=0) & ~plain.unmeasured
    y = plain.radiance[both] @ [0.2126, 0.7152, 0.0722]
    y_true = truth[both] @ [0.2126, 0.7152, 0.0722]
    assert np.max(np.abs(y / y_true - 1)) > 0.05


def far_bracket():
    """Four bracketed frames (``TIMES``) and one of 512 s far beyond them, of a scene whose
    right half is 2⁻¹⁷ of its left: black in the bracket, measured by the long frame alone."""
    base = sim.make_scene(96, 144, dynamic_range_stops=6, saturation=0.3, seed=3)
    scene = base.copy()
    scene[:, 72:] = base[:, :72] * 2.0 ** -17
    st = sim.simulate_stack(scene, simple_pipeline(), TIMES, jitter=0.0, jpeg_quality=90,
                            seed=3, exposure_scale=100.0)
    far = sim.simulate_stack(scene, simple_pipeline(), [512.0], jitter=0.0, jpeg_quality=90,
                             seed=3, exposure_scale=100.0)
    return st, far


def test_frame_too_far_from_the_bracket_is_merged_unchecked(monkeypatch):
    """A frame far beyond the bracket (ntu's 8 s one): the right half of the scene is 2⁻¹⁷
    of the left, black in the four bracketed frames and measured by the long frame alone,
    which is white on the left.  The calibration ignores that frame (no unclipped sample
    in common: its exposure cannot be checked against the pixels); the merge uses its
    time, says so, and flags the pixels it alone measures -- which follow the truth."""
    st, far = far_bracket()
    result = merge_hdr(list(st.images) + far.images, list(st.exposure_times) + [512.0])
    assert result.model.diagnostics["frames_used"] == [f"array #{k}" for k in range(4)]
    assert result.diagnostics["frames_unchecked"] == ["array #4"]
    assert "frames_ignored" not in result.diagnostics
    assert result.diagnostics["frame_used_fraction"][4] > 0.3
    assert any(w.startswith("array #4: merged with its exposure time")
               and "unchecked" in w for w in result.warnings), result.warnings

    # the flagged pixels are the ones only the far frame measures: unmeasured without it
    flagged = result.unchecked
    without = merge_hdr(list(st.images), list(st.exposure_times), result.model)
    assert without.unchecked is None
    assert 0.3 < flagged.mean() < 0.5
    assert flagged[:, :72].mean() < 0.01
    assert without.unmeasured[flagged].mean() > 0.99
    assert not np.any(result.unmeasured & flagged)
    # ... and their values follow the truth on the scale of the checked pixels
    truth = truth_radiance(st)
    checked = ~result.unmeasured & ~flagged
    scale = float(np.median(result.radiance[checked] / truth[checked]))
    err = np.abs(result.radiance[flagged] / (scale * truth[flagged]) - 1)
    assert np.median(err) < 0.06, np.median(err)

    # the unchecked frame's weights from its kept codes (the default) and from a float32
    # sum (more than MergeSums.unchecked_codes_limit such frames) flag the same pixels
    from selfcal.hdr import accumulate

    monkeypatch.setattr(accumulate.MergeSums, "unchecked_codes_limit", 0)
    summed = merge_hdr(list(st.images) + far.images, list(st.exposure_times) + [512.0])
    np.testing.assert_array_equal(result.unchecked, summed.unchecked)
    np.testing.assert_array_equal(result.radiance, summed.radiance)


def test_frame_the_calibration_ignores_as_a_duplicate_is_not_merged(stack):
    images = list(stack.images) + [stack.images[1].copy()]
    times = list(stack.exposure_times) + [stack.exposure_times[1]]
    result = merge_hdr(images, times)
    assert result.diagnostics["frames_ignored"] == ["array #4"]
    assert result.diagnostics["frame_used_fraction"][4] == 0
    assert result.unchecked is None


def test_misaligned_stack_warns_to_align():
    st, aligned = _shifted_stack([(0, 0)] * 4)
    _, shifted = _shifted_stack([(0, 0), (3, 1), (0, 0), (-2, 2)])
    model = true_model(st)
    def gains(result):
        return [pair["gain"] for pair in result.diagnostics["neighbour_residuals"]]

    r = merge_hdr(aligned, st.true_exposures, model)
    assert len(gains(r)) == 3 and max(gains(r)) <= MISALIGNMENT_GAIN, gains(r)
    r = merge_hdr(shifted, st.true_exposures, model)
    assert min(gains(r)) > MISALIGNMENT_GAIN, gains(r)
    assert any("--align" in w for w in r.warnings), r.warnings      # the remedy, named
    r = merge_hdr(shifted, st.true_exposures, model, align="mtb")
    assert max(gains(r)) <= MISALIGNMENT_GAIN, gains(r)
