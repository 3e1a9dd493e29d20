"""The top of the curve from every channel that is not clipped (selfcal's, issue 35).

[Lin2011] §5 drops a sample from a pair when it is clipped in either frame, and selfcal's
:func:`selfcal.stack.samples.frame_masks` calls a sample clipped when *any* of its
channels touches 0 or the maximum code.  That rule costs each channel the top of its
curve: a sample whose green is at 250 is most often one whose red or blue has already
reached white, so the brightest codes a channel keeps are those of the rare samples
where every channel is bright and none is clipped, and the shoulder of f⁻¹ (codes ≈ 230
… 255) is left to the PCA prior's extrapolation (the error per code range:
``python3 -m bench.response_top``).

Here a sample's channel is judged on its own (:func:`channel_clip_mask`): it is clipped in
a frame when its own block mean is within the clip margin of 0 or the maximum code, and,
as :func:`~selfcal.stack.samples.frame_masks` does for whole samples, white in every
brighter frame once white, black in every darker frame once black.  The solve
(:func:`selfcal.response.solver.solve_exposure_equations`) then builds its Eq. 8 rows on
the samples valid in some channel and gives each channel's row weight 0 where that
channel is clipped (:func:`channel_row_weights`); the rows of the channels that are not
clipped keep the top of their curves.  Saturation (β of §5) still rejects the whole
sample, and samples within the measured JPEG ringing reach of a clipped block
(:mod:`.white_end`) stay out.

The per-channel rule is the per-channel model of Eq. 8 taken at its word: f_c acts on
channel c alone, so a clipped red says nothing about green.  In a camera whose colour
matrix mixes a clipped sensor channel into the others that is not so; those rows are
then biased, as every mixed row is under a per-channel model (the natural cells of
``bench.response_matrix`` carry that case).  Ours, not the paper's.
"""

from __future__ import annotations

import numpy as np


def channel_clip_mask(samples, clip_margin: float, propagate: bool = True) -> np.ndarray:
    """(F, n, 3) True where a sample's channel is clipped in a frame, judged on its own.

    Parameters
    ----------
    samples : SampleSet
        Block means ``values`` (F, n, 3), normalised to [0, 1].
    clip_margin : float
        Codes (8-bit scale) from 0 or the maximum code that count as clipped (the margin
        of :func:`selfcal.stack.samples.frame_masks`).
    propagate : bool
        White in every brighter frame once white, black in every darker frame once black
        (frames ordered by their mean code), per channel.

    Returns
    -------
    ndarray of bool, shape (F, n, 3)
    """
    margin = clip_margin / 255.0
    values = samples.values
    white = values >= 1.0 - margin
    black = values <= margin
    if propagate and values.shape[0] > 1:
        order = np.argsort(values.mean(axis=(1, 2)), kind="stable")
        white[order] = np.logical_or.accumulate(white[order], axis=0)
        black[order[::-1]] = np.logical_or.accumulate(black[order[::-1]], axis=0)
    return white | black


def channel_valid(samples, masks: dict, clip_margin: float,
                  saturation_threshold: float) -> np.ndarray:
    """(F, n, 3) True where a sample's channel can enter the pair rows of a frame.

    A channel is valid where it is not clipped on its own (:func:`channel_clip_mask`),
    the sample's HSV saturation is at most β (§5 of [Lin2011], on every sample, clipped
    channel or not), and the sample is not clipped for a reason other than its own codes
    (``masks["clipped"]`` without any channel at a clipped code: a clipped pixel inside
    its block, blocks next to clipped ones, the measured ringing reach of
    :mod:`.white_end`).
    """
    from ..stack.samples import hsv_saturation

    chan = channel_clip_mask(samples, clip_margin)
    other = masks["clipped"] & ~chan.any(axis=2)
    bad = other | (hsv_saturation(samples.values) > saturation_threshold)
    return ~chan & ~bad[..., None]


def channel_row_weights(chan_valid: np.ndarray, pa: np.ndarray, pb: np.ndarray,
                        ps: np.ndarray, frozen: np.ndarray | None = None) -> np.ndarray:
    """Weight (0 or 1) of every pair row, channel after channel (3·m), as the solver's.

    Row i of channel c counts when channel c of sample ``ps[i]`` is valid in both frames
    ``pa[i]``, ``pb[i]`` and (``frozen``, (m, 3)) moves with the exposure.
    """
    ok = chan_valid[pa, ps] & chan_valid[pb, ps]            # (m, 3)
    if frozen is not None:
        ok &= ~frozen
    return np.concatenate([ok[:, c] for c in range(3)]).astype(float)
