"""The per-channel-exact benchmark cells (selfcal.sim.exact): the curves act per channel."""

from __future__ import annotations

import numpy as np

from selfcal import sim
from selfcal.sim.exact import EXACT_CONDITIONS, voronoi_scene

CURVE = sim.ToneCurve.film(contrast=1.1, toe=0.05, shoulder=0.85)


def test_codes_are_the_curve_of_the_raw_channel():
    cell = EXACT_CONDITIONS["exact/saturated"]
    stack = cell.simulate(CURVE, seed=3, size=(64, 80))
    pipe = cell.pipeline(CURVE, 3)
    for raw, img in zip(stack.raws, stack.images):
        want = np.stack([pipe.curves[c].forward(raw[..., c].astype(np.float64))
                         for c in range(3)], axis=-1)
        assert np.allclose(pipe.render(raw), want)
        # the codes are that, through JPEG q92 4:2:0 (luma is not subsampled)
        y = np.array([0.299, 0.587, 0.114])
        err = np.abs(img.astype(float) @ y - 255 * want @ y)
        assert np.median(err) < 3.0         # noise in steep shadows loses most
    assert stack.images[-1].max() == 255 and (stack.images[-1] == 255).mean() > 0.05


def test_truth_and_per_channel_draw():
    cell = EXACT_CONDITIONS["exact/neutral"]
    per = [cell.draw(s)["per_channel"] for s in range(60)]
    assert 10 <= sum(per) <= 30              # about one stack in three
    s = next(k for k, p in enumerate(per) if p)
    truth = cell.pipeline(CURVE, s).inverse_response(np.arange(256))
    assert not np.allclose(truth[:, 0], truth[:, 1])
    assert np.all(np.diff(truth, axis=0) >= 0)


def test_scene_is_deterministic_and_spans_the_stops():
    a = voronoi_scene(60, 80, saturated=True, seed=7)
    assert np.array_equal(a, voronoi_scene(60, 80, saturated=True, seed=7))
    lum = a.max(axis=-1)
    assert np.log2(lum.max() / lum.min()) > 9
    grey = voronoi_scene(60, 80, saturated=False, seed=7)
    assert np.allclose(grey[..., 0], grey[..., 2])
