"""Scores of a calibration or a merge: against the simulator's truth, and on real stacks.

Against the truth (synthetic stacks):

- :func:`rmse`, :func:`best_scale_rmse`: distance of an estimated f⁻¹ from a known one;
- :func:`truth_masks`: the true radiance of a simulated stack and the pixels a merge of it
  can be scored on (what some frame measured, what every frame clipped).

Where the truth is unknown (real stacks, scored with their nominal times; ours):

- :func:`log_linearisation_error` and its split by HSV saturation,
  :func:`log_linearisation_error_by_saturation`: a scale-free linearisation error over
  adjacent exposure pairs;
- :func:`per_code_floor`: the lowest value any per-channel curve can reach on that
  measure (a scale for it, not a calibration).

The linearisation error δ_c of [Lin2011] (§7, Eq. 12) is
:func:`selfcal.response.delta.delta_eq12` (the response path reports it).
"""

from __future__ import annotations

import numpy as np

from ..stack.samples import hsv_saturation

__all__ = ["rmse", "best_scale_rmse", "truth_masks", "log_linearisation_error",
           "log_linearisation_error_by_saturation", "per_code_floor"]

#: :func:`truth_masks`: a scored channel's signal in a measuring frame (fraction of white)
#: and its code before JPEG (a strong toe puts 2⁻⁸ at code 0).
TRUTH_FLOOR = 2.0 ** -8
TRUTH_MIN_CODE = 3
#: :func:`truth_masks`: shortest-only pixels the shortest frame gives to within this
#: (relative, in luminance) through the true curve and time are "readable".
TRUTH_READABLE = 0.02
#: Rec. 709 luma weights (the smooth gamut map keeps luminance).
LUMA = np.array([0.2126, 0.7152, 0.0722])


def rmse(estimate, truth) -> float:
    """Root-mean-square difference, computed in float64.

    Parameters
    ----------
    estimate, truth : array_like
        Arrays of one shape (e.g. f⁻¹ over codes 1 … 254, or images).

    Returns
    -------
    float

    Examples
    --------
    >>> rmse([0.0, 0.5, 1.0], [0.0, 0.5, 0.0])
    0.5773502691896257
    """
    d = np.asarray(estimate, np.float64) - np.asarray(truth, np.float64)
    return float(np.sqrt(np.mean(d * d)))


def best_scale_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMSE after the least-squares scale s minimising ||s·estimate − truth||.

    For curves known only up to a scale (OpenCV's responses have no f⁻¹(1) = 1).

    Parameters
    ----------
    estimate, truth : ndarray
        f⁻¹ over the same codes, e.g. ``lut[1:255]``.

    Returns
    -------
    float

    Examples
    --------
    A curve scaled by a constant is at distance 0:

    >>> truth = np.linspace(0.0, 1.0, 11)
    >>> best_scale_rmse(0.5 * truth, truth)
    0.0
    """
    s = float(np.sum(estimate * truth) / max(np.sum(estimate * estimate), 1e-30))
    return float(np.sqrt(np.mean((s * estimate - truth) ** 2)))


def truth_masks(stack):
    """Per-pixel truth of a simulated stack (:class:`selfcal.sim.SyntheticStack`) for
    scoring a merge of it (ours).

    The true radiance is ``E = M ρ · exposure_scale`` (colour-corrected linear RGB; the
    signal of frame ``j`` is ``E · t_j`` with the jittered time ``t_j``).  Frame ``j``
    *clips* a pixel when a channel of its simulated raw is at white (1.0) or a channel of
    its rendered codes before JPEG is 255.  It *measures* the pixel when it does not clip
    it and the gamut map leaves the noise-free colour ``M ρ s t_j`` unchanged; a channel is
    scored where such a frame sees it at ≥ :data:`TRUTH_FLOOR` of white and at a code ≥
    :data:`TRUTH_MIN_CODE` before JPEG.

    Returns
    -------
    tuple
        ``(e_true, scored, clipped_all, shortest_only, readable, visible)``: ``e_true``
        float64 HxWx3; ``scored`` bool HxWx3 (the channels a median error is taken over);
        bool HxW: ``clipped_all`` (clipped in every frame), ``shortest_only`` (unclipped
        only in the shortest frame), ``readable`` (of those, the ones whose decoded codes
        in the shortest frame give the luminance to within :data:`TRUTH_READABLE` through
        the true inverse response and the true time), ``visible`` (clipped in every frame
        with a code of 255 before JPEG in every frame).
    """
    pipe = stack.pipeline
    rho = stack.radiance.astype(np.float64)
    e_true = (rho @ pipe.matrix.T) * stack.exposure_scale
    h, w = rho.shape[:2]
    scored = np.zeros((h, w, 3), bool)
    clip_masks: list[np.ndarray] = []
    visible = np.ones((h, w), bool)
    for raw, t in zip(stack.raws, stack.true_exposures):
        codes = np.round(pipe.render(raw) * 255)     # before the JPEG round trip
        top = (codes >= 255).any(axis=2)
        clip = (raw >= 1.0).any(axis=2) | top
        clip_masks.append(clip)
        visible &= top
        x = e_true * float(t)                        # noise-free M ρ s t
        in_gamut = np.abs(pipe.apply_gamut(x) - x).max(axis=2) <= 1e-6
        scored |= (~clip & in_gamut)[..., None] & (x >= TRUTH_FLOOR) & (codes >= TRUTH_MIN_CODE)
    clipped = np.array(clip_masks)
    clipped_all = clipped.all(axis=0)
    shortest_only = ~clipped[0] & clipped[1:].all(axis=0)
    inv = stack.inverse_response()
    first = stack.images[0]
    reading = np.stack([inv[first[..., c], c] for c in range(3)], axis=-1) @ LUMA
    reading /= float(stack.true_exposures[0])
    readable = shortest_only & (np.abs(reading / (e_true @ LUMA) - 1) <= TRUTH_READABLE)
    return e_true, scored, clipped_all, shortest_only, readable, visible & clipped_all


def _adjacent_pairs(images_rgb, times, lo, hi):
    """Yield (ia, ib, ok, log(t′/t)) per adjacent exposure pair (sorted by time): ok marks
    the pixels with all channels in [lo, hi] in both frames (the metric's pixels)."""
    order = np.argsort(times)
    for a, b in zip(order[:-1], order[1:]):
        if times[b] == times[a]:
            continue
        ia, ib = images_rgb[a], images_rgb[b]
        ok = ((ia >= lo) & (ia <= hi)).all(axis=2) & ((ib >= lo) & (ib <= hi)).all(axis=2)
        if ok.any():
            yield ia, ib, ok, np.log(times[b] / times[a])


def _pair_log_residuals(images_rgb, times, inverse_lut, lo, hi):
    """Yield (r, ia, ib, ok) per adjacent pair: the residuals r (n, 3) of the pixels ok."""
    log_lut = np.log(np.maximum(inverse_lut, 1e-12))
    for ia, ib, ok, d in _adjacent_pairs(images_rgb, times, lo, hi):
        la = np.stack([log_lut[ia[..., c][ok], c] for c in range(3)], axis=1)
        lb = np.stack([log_lut[ib[..., c][ok], c] for c in range(3)], axis=1)
        yield lb - la - d, ia, ib, ok


def log_linearisation_error(images_rgb, times, inverse_lut: np.ndarray,
                            lo: int = 25, hi: int = 235) -> float:
    """Scale-free linearisation error over adjacent exposure pairs (ours).

    RMS over adjacent pairs (sorted by time) and pixels with all channels in [lo, hi] in
    both frames of log f⁻¹(I′) − log f⁻¹(I) − log(t′/t).  It is Eq. 8 of [Lin2011]
    (g(I′) − g(I) = K′) used as a score: in the log domain, so free of f⁻¹'s scale, and
    with the given times rather than fitted ones.  Not the paper's δ
    (:func:`selfcal.response.delta.delta_eq12`).

    Parameters
    ----------
    images_rgb : sequence of ndarray, each (h, w, 3) uint8
        The frames.
    times : sequence of float
        Exposure time per frame.
    inverse_lut : ndarray, shape (256, 3)
        f⁻¹ per code and channel.
    lo, hi : int
        Codes scored: all channels in [lo, hi] in both frames of a pair.

    Returns
    -------
    float

    Examples
    --------
    A linear camera, scored with the linear f⁻¹:

    >>> dark = np.full((2, 2, 3), 50, np.uint8)
    >>> lut = np.stack([np.arange(256) / 255.0] * 3, axis=1)
    >>> round(log_linearisation_error([dark, 2 * dark], [1.0, 2.0], lut), 12)
    0.0
    """
    total, count = 0.0, 0
    for r, *_ in _pair_log_residuals(images_rgb, times, inverse_lut, lo, hi):
        total += float(np.sum(r ** 2))
        count += r.size
    return float(np.sqrt(total / max(count, 1)))


def log_linearisation_error_by_saturation(images_rgb, times, inverse_lut: np.ndarray,
                                          edges=(0.0, 0.3, 0.5, 1.0), lo: int = 25,
                                          hi: int = 235):
    """:func:`log_linearisation_error` split by HSV saturation (the larger of the pair's).

    [Lin2011] (§5) rejects highly saturated pixels (HSV saturation above β) because the
    camera's colour processing moves them off the per-channel curves; this split (ours)
    shows which population a curve fits.

    Parameters
    ----------
    images_rgb, times, inverse_lut, lo, hi
        As :func:`log_linearisation_error`.
    edges : sequence of float
        Band edges on [0, 1]; band k is [edges[k], edges[k+1]), the last band includes 1.

    Returns
    -------
    rms : ndarray, shape (len(edges) - 1,)
        The metric per band (NaN for an empty band).
    share : ndarray, shape (len(edges) - 1,)
        Fraction of the metric's pixel pairs in each band (sums to 1 over the bands).
    """
    nb = len(edges) - 1
    total, count = np.zeros(nb), np.zeros(nb)
    for r, ia, ib, ok in _pair_log_residuals(images_rgb, times, inverse_lut, lo, hi):
        sat = np.maximum(hsv_saturation(ia[ok] / 255.0), hsv_saturation(ib[ok] / 255.0))
        band = np.clip(np.searchsorted(edges, sat, side="right") - 1, 0, nb - 1)
        total += np.bincount(band, weights=np.sum(r ** 2, axis=1), minlength=nb)
        count += 3 * np.bincount(band, minlength=nb)
    rms = np.sqrt(total / np.maximum(count, 1))
    return np.where(count > 0, rms, np.nan), count / max(count.sum(), 1)


def per_code_floor(images_rgb, times, lo: int = 25, hi: int = 235) -> np.ndarray:
    """The per-channel table that minimises :func:`log_linearisation_error` itself (ours).

    Least squares over the metric's own pixel pairs, one free value of log f⁻¹ per code
    and channel (what any per-channel curve can at best reach on these images): a floor
    for the metric, not a calibration.  Codes no pair uses are interpolated.

    Parameters
    ----------
    images_rgb, times, lo, hi
        As :func:`log_linearisation_error`.

    Returns
    -------
    ndarray, shape (256, 3)
        f⁻¹ per code and channel, largest value 1 per channel.
    """
    counts = np.zeros((3, 256 * 256))
    sums = np.zeros((3, 256 * 256))
    for ia, ib, ok, d in _adjacent_pairs(images_rgb, times, lo, hi):
        for c in range(3):
            cell = ia[..., c][ok].astype(np.int64) * 256 + ib[..., c][ok]
            n = np.bincount(cell, minlength=256 * 256)
            counts[c] += n
            sums[c] += n * d
    log_lut = np.zeros((256, 3))
    for c in range(3):
        nz = np.flatnonzero(counts[c])
        i, j, w = nz // 256, nz % 256, counts[c][nz]
        # normal equations of sum w (G[j] - G[i] - d)^2: a weighted graph Laplacian
        L = np.zeros((256, 256))
        np.add.at(L, (i, i), w)
        np.add.at(L, (j, j), w)
        np.add.at(L, (i, j), -w)
        np.add.at(L, (j, i), -w)
        r = np.zeros(256)
        np.add.at(r, j, sums[c][nz])
        np.add.at(r, i, -sums[c][nz])
        used = np.flatnonzero(np.diag(L) > 0)
        # the additive gauge: pin the first used code (the metric is scale-free)
        Lu, ru = L[np.ix_(used, used)], r[used]
        Lu[0, :] = 0
        Lu[0, 0] = 1
        ru[0] = 0
        g = np.linalg.solve(Lu + 1e-9 * np.eye(used.size), ru)
        log_lut[:, c] = np.interp(np.arange(256), used, g)
    return np.exp(log_lut - log_lut.max(axis=0))
