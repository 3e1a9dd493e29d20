"""Small frames: a frame's block grid and sample plan stay bounded, and blocks sit
where they say they do (also when the JPEG is decoded at half size by DCT scaling).

Synthetic stacks only (:mod:`selfcal.sim`); no shared data.
"""

from __future__ import annotations

import numpy as np
import pytest

import selfcal
from selfcal import sim
from selfcal.io import read_image
from selfcal.response.options import DEFAULT_MAX_SAMPLES
from selfcal.stack.samples import (TARGET_BLOCKS, THUMBNAIL_SIDE, collect_samples,
                             working_block_size)

TIMES = [1 / 250, 1 / 60, 1 / 15, 1 / 4]


@pytest.fixture(scope="module")
def small_jpegs(tmp_path_factory):
    """A 640×960 (0.6 MP) JPEG stack with EXIF times, and its ground truth."""
    pipe = sim.default_pipeline(seed=7)
    scene = sim.make_scene(640, 960, seed=7)
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=0.0, jpeg_quality=95, seed=7)
    return stack, stack.write(tmp_path_factory.mktemp("small"))


def test_block_grid_stays_near_the_target():
    rng = np.random.default_rng(0)
    shapes = [(int(h), int(w)) for h, w in rng.integers(64, 8000, size=(300, 2))]
    shapes += [(1000, 1500), (864, 1152), (512, 768), (632, 633), (4000, 6000)]
    for h, w in shapes:
        b = working_block_size((h, w))
        # rounded down: fewer than four times the target's blocks, and at least the
        # target's when the frame has that many pixels
        assert h * w / b ** 2 < 4 * TARGET_BLOCKS, (h, w, b)
        assert h * w / (b + 1) ** 2 < TARGET_BLOCKS, (h, w, b)
        if b > 1:
            assert h * w / b ** 2 >= TARGET_BLOCKS, (h, w, b)
    assert working_block_size((4000, 6000)) == 7      # read at half size: 8 (below)
    assert working_block_size((1000, 1500)) == 1


def test_small_stack_plan_is_bounded(small_jpegs):
    stack, paths = small_jpegs
    samples = collect_samples(paths, max_samples=DEFAULT_MAX_SAMPLES)
    h, w = stack.images[0].shape[:2]
    assert samples.block == working_block_size((h, w)) == 1
    assert (h // samples.block) * (w // samples.block) < 4 * TARGET_BLOCKS
    assert samples.locations[:, 0].max() < h // samples.block
    assert samples.locations[:, 1].max() < w // samples.block
    assert max(samples.thumbnails[0].shape) <= THUMBNAIL_SIDE
    # the solve's size does not grow with the pixels: at most 48 bins x 6 per frame
    assert 100 <= samples.n_samples <= min(DEFAULT_MAX_SAMPLES, 48 * 6 * len(paths))
    model = selfcal.calibrate_response(paths)
    assert model.diagnostics["samples"]["block_size"] == 1
    assert model.diagnostics["samples"]["locations"] == samples.n_samples
    truth = stack.inverse_response()
    rmse = np.sqrt(np.mean((model.inverse_response()[1:255] - truth[1:255]) ** 2))
    assert rmse < 0.02, rmse


# slow: a 24 MP JPEG
@pytest.mark.slow
def test_a_24_mp_jpeg_block_is_a_whole_number_of_half_size_pixels(tmp_path):
    """6000x4000 JPEGs: block 7 by the target, read at half size, so 8 (4 reduced px)."""
    from selfcal.io import encode_image

    rng = np.random.default_rng(3)
    small = rng.integers(30, 220, size=(50, 75, 3)).astype(np.uint8)
    big = np.repeat(np.repeat(small, 80, axis=0), 80, axis=1)        # 4000 x 6000
    paths = []
    for k, gain in enumerate((0.6, 1.0)):
        frame = np.clip(big * gain, 0, 255).astype(np.uint8)
        paths.append(tmp_path / f"f{k}.jpg")
        paths[-1].write_bytes(encode_image(frame, ".jpg", jpeg_quality=90))
    samples = collect_samples(paths)
    assert samples.block == 8
    r, c = samples.locations[:, 0], samples.locations[:, 1]
    # every sample's block lies in one flat 80x80 patch; its mean is that patch's code
    expected = small[(r * 8 + 4) // 80, (c * 8 + 4) // 80] * 1.0
    assert np.median(np.abs(samples.values[1] * 255 - expected)) < 1.5


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


def test_near_clip_radius_marks_the_neighbours_of_a_clipped_block():
    """near_clip_blocks (ResponseOptions.near_clip_blocks): off, only the clipped block is;
    at 1, its 8 neighbours."""
    import numpy as np

    from selfcal.stack import samples

    image = np.full((40, 40, 3), 120, np.uint8)
    image[16:24, 16:24] = 255                      # one clipped 8x8 block
    alone = samples.reduce_frame(image, block=8).block_max >= 254
    near = samples.reduce_frame(image, block=8, near_clip_blocks=1).block_max >= 254
    assert alone.sum() == 1 and alone[2, 2]
    assert near.sum() == 9 and near[1:4, 1:4].all()
