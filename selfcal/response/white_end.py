"""How far JPEG damage next to clipped areas reaches, measured per stack (selfcal's).

A JPEG encoder codes a clipped highlight and its surroundings in the same 8×8 (chroma:
16×16 with 4:2:0) blocks; the quantised DCT rings, so codes next to a clipped area are
moved by several codes -- exactly where the top of the curve is observed.  A fixed
margin around clipped areas either leaves that damage in (small margin) or throws away
the top of the curve on clean stacks (large margin).  Instead the reach is measured on the
stack itself, after a first fit (Eq. 8 of [Lin2011] with every unclipped sample):

1. for every pair row, the residual ``g(I′) − g(I) − (K′ − K)`` in codes of the brighter
   frame (divided by the slope of g there) and the row's distance, in blocks, to the
   nearest clipped block in either frame (``SampleSet.clip_distance``);
2. the reference is the median absolute residual of the rows farther than
   :data:`MAX_REACH` blocks from any clipped block, per level (the brighter frame's code
   in :data:`LEVEL_BINS` bins: rows near clipped areas are mostly bright ones);
3. the reach is the largest distance ``d ≤ MAX_REACH`` whose rows (at least
   :data:`MIN_ROWS`) have a median absolute residual above :data:`EXCESS` times the
   reference of their levels *and* a signed median beyond :data:`BIAS` times it (JPEG
   damage moves codes one way; rows that are only noisier are left to the Huber loss);
   0 when none has.

The samples within the reach of a clipped block in a frame then count as clipped there,
and the curves are solved again (:func:`selfcal.response.calibrate.calibrate_response`).
The statistic and its constants are ours.
"""

from __future__ import annotations

import numpy as np

#: Farthest reach (blocks) tested; rows farther than this are the clean reference.
MAX_REACH = 6
#: A distance's rows are damaged when their median |residual| exceeds this times the
#: reference's.
EXCESS = 1.5
#: ... and their median residual (signed) exceeds this times the reference: ringing
#: moves codes one way (down next to a clipped highlight), noise both ways.
BIAS = 0.6
#: Rows a distance (or a level bin of the reference) needs before it is judged.
MIN_ROWS = 20
#: Level bins of the reference (codes of the brighter frame).
LEVEL_BINS = 8


def pair_row_residuals(samples, valid, result, grid, inverse, max_rank_gap: int = 3):
    """Residuals (codes of the brighter frame), clip distances and levels of every pair row.

    Returns
    -------
    residual, distance, level : ndarray
        One entry per (frame pair, sample, channel) valid in both frames, over the pairs
        of the solve (``result.pair_frames``).
    """
    g = np.log(np.maximum(inverse, 1e-12)).T            # (3, K)
    slope = np.gradient(g, grid, axis=1)
    K = result.log_exposures
    res, dist, level = [], [], []
    for a, b in result.pair_frames:
        ok = valid[a] & valid[b]
        if not ok.any():
            continue
        d = np.minimum(samples.clip_distance[a, ok], samples.clip_distance[b, ok])
        for c in range(3):
            ia, ib = samples.values[a, ok, c], samples.values[b, ok, c]
            r = np.interp(ib, grid, g[c]) - np.interp(ia, grid, g[c]) - (K[b] - K[a])
            s = np.maximum(np.interp(ib, grid, slope[c]), 1e-6) / samples.max_code
            res.append(r / s)
            dist.append(d)
            level.append(ib)
    if not res:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    return np.concatenate(res), np.concatenate(dist), np.concatenate(level)


def ringing_reach(residual: np.ndarray, distance: np.ndarray, level: np.ndarray) -> int:
    """The reach (blocks) of damage next to clipped areas from the rows' residuals; 0: none.

    The rows near clipped areas are mostly bright ones, so each is compared with the far
    rows of its own level (eight bins of the brighter frame's code): the expected |residual|
    of a distance's rows is the median of their levels' far medians.
    """
    far = distance > MAX_REACH
    if far.sum() < MIN_ROWS:
        return 0
    bins = np.minimum((level * LEVEL_BINS).astype(int), LEVEL_BINS - 1)
    overall = float(np.median(np.abs(residual[far])))
    ref = np.full(LEVEL_BINS, overall)
    for k in range(LEVEL_BINS):
        sel = far & (bins == k)
        if sel.sum() >= MIN_ROWS:
            ref[k] = np.median(np.abs(residual[sel]))
    reach = 0
    for d in range(1, MAX_REACH + 1):
        sel = (distance > d - 1) & (distance <= d)
        if sel.sum() < MIN_ROWS:
            continue
        scale = np.median(ref[bins[sel]])
        if (np.median(np.abs(residual[sel])) > EXCESS * scale
                and abs(np.median(residual[sel])) > BIAS * scale):
            reach = d
    return reach


def near_clip_mask(samples, reach: int) -> np.ndarray:
    """(F, n) True where a sample lies within ``reach`` blocks of a clipped block."""
    if reach <= 0 or samples.clip_distance is None:
        return np.zeros(samples.values.shape[:2], bool)
    return samples.clip_distance <= reach


def mask_near_clip(samples, masks: dict, result, grid, inverse) -> int:
    """Measure the reach on a fit and mark the samples within it clipped, in ``masks``.

    ``masks`` (``"clipped"``, ``"saturated"``, as :func:`selfcal.stack.samples.frame_masks`) are
    replaced in the dict (the caller's solve reads them from there).  Returns the reach in
    blocks (0: none, masks unchanged).
    """
    if samples.clip_distance is None:
        return 0
    valid = ~(masks["clipped"] | masks["saturated"])
    reach = ringing_reach(*pair_row_residuals(samples, valid, result, grid, inverse))
    if reach:
        masks["clipped"] = masks["clipped"] | near_clip_mask(samples, reach)
        masks["saturated"] = masks["saturated"] & ~masks["clipped"]
    return reach
