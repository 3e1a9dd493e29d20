"""Issue 15, Build 4: small frames get a bounded block grid, and blocks sit where they say.

Synthetic stacks only (:mod:`selfcal.synth`); no shared data.
"""

from __future__ import annotations

import numpy as np
import pytest

import selfcal
from selfcal import synth
from selfcal.io import read_image
from selfcal.response.calibrate import DEFAULT_MAX_SAMPLES
from selfcal.samples import (TARGET_BLOCKS, THUMBNAIL_SIDE, collect_samples,
                             working_block_size)

TIMES = [1 / 250, 1 / 60, 1 / 15, 1 / 4]


@pytest.fixture(scope="module")
def small_jpegs(tmp_path_factory):
    """A 640×960 (0.6 MP) JPEG stack with EXIF times, and its ground truth."""
    pipe = synth.default_pipeline(seed=7)
    scene = synth.make_scene(640, 960, seed=7)
    stack = synth.simulate_stack(scene, pipe, TIMES, jitter=0.0, jpeg_quality=95, seed=7)
    return stack, stack.write(tmp_path_factory.mktemp("small"))


def test_block_grid_never_exceeds_the_target_and_is_the_finest_that_does():
    rng = np.random.default_rng(0)
    shapes = [(int(h), int(w)) for h, w in rng.integers(64, 8000, size=(300, 2))]
    shapes += [(1000, 1500), (864, 1152), (512, 768), (632, 633), (4000, 6000)]
    for h, w in shapes:
        b = working_block_size((h, w))
        assert (h // b) * (w // b) <= TARGET_BLOCKS, (h, w, b)
        if b > 1:            # one pixel less per block edge would exceed the target
            assert h * w / (b - 1) ** 2 > TARGET_BLOCKS, (h, w, b)
    assert working_block_size((1000, 1500)) == 2      # the 1.5 MP frames
    assert working_block_size((512, 768)) == 1        # at most TARGET_BLOCKS pixels


def test_small_stack_plan_is_bounded(small_jpegs):
    stack, paths = small_jpegs
    samples = collect_samples(paths, max_samples=DEFAULT_MAX_SAMPLES)
    h, w = stack.images[0].shape[:2]
    assert samples.block == 2
    grid = (h // samples.block) * (w // samples.block)
    assert grid <= TARGET_BLOCKS
    assert samples.locations[:, 0].max() < h // samples.block
    assert samples.locations[:, 1].max() < w // samples.block
    assert max(samples.thumbnails[0].shape) <= min(THUMBNAIL_SIDE, w // samples.block)
    # the solve's size: stratified locations, at most 48 bins x 6 per frame
    assert 100 <= samples.n_samples <= min(DEFAULT_MAX_SAMPLES, 48 * 6 * len(paths))
    model = selfcal.calibrate_response(paths)
    assert model.diagnostics["samples"]["block_size"] == 2
    assert model.diagnostics["samples"]["locations"] == samples.n_samples
    truth = stack.inverse_response()
    rmse = np.sqrt(np.mean((model.inverse_response()[1:255] - truth[1:255]) ** 2))
    assert rmse < 0.02, rmse


@pytest.mark.parametrize("block", [4, 6, 7, 8])
def test_block_means_sit_at_their_locations(small_jpegs, block):
    """Each sample is the mean of its block of the full frame, wherever the file was
    decoded by DCT scaling (block 6 and 8: at half size) or not (4, 7)."""
    _, paths = small_jpegs
    samples = collect_samples(paths[:2], block=block)
    assert samples.block == block
    full = read_image(paths[1]).astype(np.float64)
    r, c = samples.locations[:, 0], samples.locations[:, 1]
    means = np.stack([full[i * block:(i + 1) * block, j * block:(j + 1) * block]
                      .reshape(-1, 3).mean(axis=0) for i, j in zip(r, c)])
    err = np.abs(samples.values[1] * 255 - means)
    # DCT scaling is a low-pass, not an exact mean: a few codes on flat blocks
    assert np.median(err) < 1.0, np.median(err)
    assert np.percentile(err, 95) < 4.0, np.percentile(err, 95)
