"""Correspondences from every usable pixel: brightness transfer functions by histogram matching.

Grossberg & Nayar, *What can be known about the radiometric response from images?*, ECCV
2002 / *Determining the camera response from images: what is knowable?*, PAMI 2003, §4
([Grossberg2003]): when the scene does not change between two exposures, the brightness
transfer function ``T`` with ``I′ = T(I)`` (monotone) is fixed by the two frames'
histograms alone, ``T = H′⁻¹ ∘ H`` with ``H, H′`` the cumulative histograms; no pixel
has to be paired with its own value in the other frame.  Matching quantiles has none of
the errors-in-variables bias of pairing noisy pixel values (a noisy dark value paired
with its noisy bright value regresses towards the mean), and it reads every pixel: the
data grow with the frame until noise, not sampling, limits the curve.

Each point of ``T`` is then one row of Eq. 8 of [Lin2011] (``g(T(I)) − g(I) = K′ − K``),
solved with the log-PCA model of Eq. 7 exactly as the block samples are
(:func:`selfcal.response.solver.solve_exposure_equations`).

selfcal's choices (ours; against the block samples: ``python3 -m bench.response_matrix
--correspondences histogram``, docs/decisions.md, "Correspondences: block samples, not
histograms"):

* The pixels of channel ``c`` in pair ``(a, b)``: those whose *other* channels are
  unclipped in both frames (a grown clip map, :data:`CLIP_GROW`) and whose HSV saturation
  is at most β in both frames (the §5 rejection of [Lin2011]).  The channel's own clipping
  is *not* a pixel mask: a cut on a pixel's own noisy value truncates one frame's
  histogram sharply and the other's softly, which biases the quantiles at the cut.  It is
  left to the histograms instead (clipping is monotone too): points where either frame's
  quantile lies within ``clip_margin`` of 0 or the top code are no pair rows, and those
  where the brighter frame reads the top code become censored threshold data
  (:func:`selfcal.response.equations.white_thresholds` then finds where the channel
  clips to a fraction of a code).
* Points: at every code of the darker frame mapped forward and every code of the
  brighter frame mapped back (the two directions sample the curve where each frame
  resolves it best), the cumulative histograms linear within code bins.  Weight of a
  point: the pixels at its code over :data:`FULL_WEIGHT_PIXELS`, at most 1.
* Frames larger than 1.6 MP arrive as block means (``selfcal.stack.samples.reduce_frame``);
  their histograms use quarter-code bins.  The rows number a few hundred per pair and
  channel whatever the frame size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..stack.frames import DEFAULT_CLIP_MARGIN
from ..stack.samples import FrameSamples, hsv_saturation
from .solver import DEFAULT_SATURATION_THRESHOLD

#: Pixels at a code for a histogram point to get full weight (fewer: proportionally less).
FULL_WEIGHT_PIXELS = 20.0
#: β of the histogram pixels relative to the solve's (the histograms take every pixel, so
#: they can afford a stricter cut than the block samples).
SATURATION_FACTOR = 0.6
#: Share of the usable pixels that enter the histograms (a random subset, seeded; 1: all),
#: for the curve of error against pixels used (docs/decisions.md, "Correspondences: block
#: samples, not histograms").
PIXEL_FRACTION = 1.0
#: Weight of a full histogram point relative to one block-sample row (the data's weight
#: against the priors of the solve).
ROW_WEIGHT = 10.0
#: Blocks by which the other channels' clip maps are grown (JPEG damage next to clipped
#: areas reaches a few pixels; 0: no growth).
CLIP_GROW = 1
#: Frame pairs: each frame with the next this many in brightness order (the solver pairs
#: frames up to 3 ranks apart).
MAX_RANK_GAP = 3


@dataclass
class HistogramSamples(FrameSamples):
    """Histogram-matched correspondences laid out as a solver sample set.

    Each sample belongs to one frame pair; column ``c`` of ``values`` holds a point of
    channel ``c``'s transfer function (the three columns of one sample are unrelated
    points).  ``clipped[f, s]`` is True for every frame but the pair's (and for the
    brighter frame of a censored point); ``weights[s, c]`` is the row weight (0 for
    padding).

    Attributes
    ----------
    values : ndarray (F, n, 3)
        Codes normalised to [0, 1].
    clipped : ndarray (F, n) of bool
    weights : ndarray (n, 3)
    pair : ndarray (n, 2) of int
        The frame pair of each sample.
    pixels : int
        Pixel (or block) values that entered the histograms, summed over pairs and channels.
    max_code : int
    """

    values: np.ndarray
    clipped: np.ndarray
    weights: np.ndarray
    pair: np.ndarray
    pixels: int
    max_code: int

    def subset(self, keep) -> "HistogramSamples":
        """The samples of the frames ``keep`` (in that order), pairs outside dropped."""
        keep = list(keep)
        index = {f: k for k, f in enumerate(keep)}
        sel = np.array([a in index and b in index for a, b in self.pair], dtype=bool)
        pair = np.array([(index[a], index[b]) for a, b in self.pair[sel]],
                        dtype=np.int64).reshape(-1, 2)
        return HistogramSamples(values=self.values[keep][:, sel],
                                clipped=self.clipped[keep][:, sel],
                                weights=self.weights[sel], pair=pair, pixels=self.pixels,
                                max_code=self.max_code)

    def masks(self) -> dict:
        """``clipped`` / ``saturated`` masks in the form of ``selfcal.stack.samples.frame_masks``."""
        return {"clipped": self.clipped.copy(),
                "saturated": np.zeros_like(self.clipped)}


def _cdf(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Cumulative share of ``x`` at ``edges`` (linear within the bins between them)."""
    hist, _ = np.histogram(x, bins=edges)
    return np.concatenate([[0.0], np.cumsum(hist)]) / max(x.size, 1)


def transfer_points(xa: np.ndarray, xb: np.ndarray, max_code: int, sub: int = 1):
    """Points of the brightness transfer function from ``xa`` (darker) to ``xb`` [Grossberg2003].

    ``T = H_b⁻¹ ∘ H_a`` with the cumulative histograms ``H`` linear within bins of
    ``1/sub`` code (bins centred on the codes, so integer codes sit mid-bin and map to
    the middle of their mass).  Evaluated at every code of ``a`` that has pixels (forward)
    and at every code of ``b`` that has pixels (backward).

    Returns
    -------
    ia, ib : ndarray
        Codes (not normalised) of the points, ``ib = T(ia)``.
    count : ndarray
        Pixels at each point's given code (within ±0.5 code).
    """
    edges = (np.arange(0, max_code * sub + 2) - 0.5) / sub
    ca, cb = _cdf(xa, edges), _cdf(xb, edges)
    codes = np.arange(max_code + 1, dtype=np.float64)
    unit = np.arange(max_code + 2) - 0.5
    na = np.diff(_cdf(xa, unit)) * xa.size
    nb = np.diff(_cdf(xb, unit)) * xb.size
    fa = np.interp(codes, edges, ca)
    fb = np.interp(codes, edges, cb)
    fwd = na > 0
    bwd = nb > 0
    ib_fwd = _quantile(fa[fwd], cb, edges)
    ia_bwd = _quantile(fb[bwd], ca, edges)
    ia = np.concatenate([codes[fwd], ia_bwd])
    ib = np.concatenate([ib_fwd, codes[bwd]])
    return ia, ib, np.concatenate([na[fwd], nb[bwd]])


def _quantile(q: np.ndarray, cdf: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Inverse of a piecewise-linear CDF: the value at share ``q`` (empty bins skipped)."""
    keep = np.concatenate([[True], np.diff(cdf) > 0])
    return np.interp(q, cdf[keep], edges[keep])


def _channel_mask(frame_clip, sat_ok, a, b, c):
    """Pixels of channel ``c`` in pair (a, b): other channels unclipped, not saturated."""
    others = [c] if CLIP_MASK == "ring" else [k for k in range(3) if k != c]
    ok = sat_ok[a] & sat_ok[b]
    for k in others:
        ok &= ~frame_clip[a][k] & ~frame_clip[b][k]
    return ok


#: How the clip maps are read: "grown" (blocks touching a clipped code), "smoothed" (the
#: 3x3 mean of the codes near a clipped level: a cut on the scene, less on one pixel's own
#: noise) or "none" (no clip mask; the quantiles alone handle clipping).
CLIP_MASK = "grown"


def _clip_maps(reduced, margin_codes: float, grow: int):
    """Per frame and channel, the (grown) map of blocks touching 0 or the top code."""
    import cv2

    maps = []
    kernel = np.ones((2 * grow + 1,) * 2, np.uint8) if grow > 0 else None
    for r in reduced:
        hi = r.max_code - margin_codes
        cmax = r.channel_max if r.channel_max is not None else r.blocks
        cmin = r.channel_min if r.channel_min is not None else r.blocks
        if CLIP_MASK == "none":
            maps.append([np.zeros(r.blocks.shape[:2], bool)] * 3)
            continue
        if CLIP_MASK == "smoothed":
            cmax = cmin = cv2.blur(np.asarray(r.blocks, np.float32), (3, 3))
        if CLIP_MASK == "ring":
            maps.append(_ring_maps(cmax, cmin, hi, margin_codes, r))
            continue
        per = []
        for c in range(3):
            m = ((cmax[..., c] >= hi) | (cmin[..., c] <= margin_codes)).astype(np.uint8)
            if kernel is not None:
                m = cv2.dilate(m, kernel)
            per.append(m.astype(bool))
        maps.append(per)
    return maps


#: Frame pixels around a clipped pixel whose codes JPEG may have moved ("ring" maps).
RING_PIXELS = 3


def _ring_maps(cmax, cmin, hi, lo, r):
    """Per channel: pixels within :data:`RING_PIXELS` of a pixel clipped in any channel,
    except those clipped in this channel themselves (they stay, at the top or bottom of the
    histogram, so that the ranks above the cut keep their place)."""
    import cv2

    block = max(1, r.shape[0] // max(1, r.blocks.shape[0]))
    reach = int(np.ceil(RING_PIXELS / block))
    own = (cmax >= hi) | (cmin <= lo)                  # (h, w, 3)
    near = np.any(own, axis=-1).astype(np.uint8)
    if reach > 0:
        near = cv2.dilate(near, np.ones((2 * reach + 1,) * 2, np.uint8))
    near = near.astype(bool)
    return [near & ~own[..., c] for c in range(3)]


def _pair_order(reduced) -> list:
    """Frame pairs (a, b), b brighter by mean code, up to :data:`MAX_RANK_GAP` ranks apart."""
    means = [float(np.mean(r.blocks)) for r in reduced]
    order = np.argsort(means, kind="stable")
    pairs = []
    for gap in range(1, min(MAX_RANK_GAP, len(order) - 1) + 1):
        for k in range(len(order) - gap):
            pairs.append((int(order[k]), int(order[k + gap])))
    return pairs


#: Codes (8-bit scale) by which a pixel may miss a first fit's prediction and still count
#: (:func:`histogram_correspondences` with ``prediction``); 0: no gate.
GATE_CODES = 3.0


def _predicted_codes(prediction, a, b, c, xa, max_code):
    """Frame b's codes predicted from frame a's through a first fit: f(f⁻¹(I) K_b/K_a)."""
    grid, inverse, log_exposures = prediction
    lin = np.interp(xa / max_code, grid, inverse[:, c]) * np.exp(
        log_exposures[b] - log_exposures[a])
    inv = np.maximum.accumulate(inverse[:, c])
    return np.interp(np.minimum(lin, 1.0), inv, grid) * max_code


def histogram_correspondences(reduced, *, clip_margin: float = DEFAULT_CLIP_MARGIN,
                              saturation_threshold: float = DEFAULT_SATURATION_THRESHOLD,
                              grow: int | None = None, prediction=None) -> HistogramSamples:
    """Transfer-function points of every frame pair and channel from the reduced frames.

    Parameters
    ----------
    reduced : list of selfcal.stack.samples.ReducedFrame
        The stack's frames (every pixel, or block means for large frames).
    clip_margin : float
        Codes (8-bit scale) from 0 or the top code that count as clipped.  Default
        :data:`selfcal.stack.frames.DEFAULT_CLIP_MARGIN`.
    saturation_threshold : float
        β of [Lin2011] §5: pixels whose HSV saturation exceeds it in either frame are left
        out (≥ 1: none).  Default :data:`.solver.DEFAULT_SATURATION_THRESHOLD`.
    grow : int, optional
        Blocks the other channels' clip maps are grown by (default :data:`CLIP_GROW`).
    prediction : tuple, optional
        ``(grid, inverse (K, 3), log exposures (F,))`` of a first fit: pixels whose code
        in the brighter frame misses its prediction by more than :data:`GATE_CODES` are
        left out (pixels the colour processing or JPEG moved off the per-channel curve:
        one such pixel shifts the rank of every pixel above it).  A symmetric, wide gate
        around the prediction, so it cuts little of the noise itself.

    Returns
    -------
    HistogramSamples
    """
    max_code = reduced[0].max_code
    scale = max_code / 255.0
    margin = clip_margin * scale
    lo, hi = margin, max_code - margin
    integer = all(r.blocks.dtype.kind in "fc" and r.shape == r.blocks.shape[:2]
                  for r in reduced)
    sub = 1 if integer else 4
    clip = _clip_maps(reduced, margin, CLIP_GROW if grow is None else grow)
    beta = saturation_threshold * SATURATION_FACTOR
    sat_ok = [hsv_saturation(r.blocks) <= beta for r in reduced]
    groups, total = [], 0
    subset = None
    if PIXEL_FRACTION < 1.0:
        rng = np.random.default_rng(0)
        subset = rng.uniform(size=reduced[0].blocks.shape[:2]) < PIXEL_FRACTION
        sat_ok = [ok & subset for ok in sat_ok]
    for a, b in _pair_order(reduced):
        per_channel: list[tuple | None] = []
        for c in range(3):
            ok = _channel_mask(clip, sat_ok, a, b, c)
            xa = reduced[a].blocks[..., c][ok]
            xb = reduced[b].blocks[..., c][ok]
            if prediction is not None and GATE_CODES > 0:
                near = np.abs(xb - _predicted_codes(prediction, a, b, c, xa, max_code)) \
                    <= GATE_CODES * scale
                xa, xb = xa[near], xb[near]
            total += 2 * xa.size
            if xa.size < 50:
                per_channel.append(None)
                continue
            ia, ib, count = transfer_points(xa, xb, max_code, sub)
            w = ROW_WEIGHT * np.minimum(count / FULL_WEIGHT_PIXELS, 1.0)
            inside_a = (ia > lo) & (ia < hi)
            pair_ok = inside_a & (ib > lo) & (ib < hi)
            censored = inside_a & (ib >= hi)
            per_channel.append((ia[pair_ok], ib[pair_ok], w[pair_ok],
                                ia[censored], ib[censored]))
        groups.append((a, b, per_channel))
    return _layout(groups, len(reduced), max_code, total)


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    """``x`` repeated cyclically to length ``n``."""
    return x[np.arange(n) % x.size]


def _layout(groups, F: int, max_code: int, total: int) -> HistogramSamples:
    """Per pair, the channels' points side by side (padded with zero weight) as samples."""
    vals, clips, weights, pairs = [], [], [], []
    for a, b, per_channel in groups:
        if all(p is None or p[0].size == 0 for p in per_channel):
            continue
        n = max(p[0].size for p in per_channel if p is not None)
        nt = max((p[3].size for p in per_channel if p is not None), default=0)
        for kind, count in (("rows", n), ("censored", nt)):
            if count == 0:
                continue
            v = np.full((F, count, 3), 0.5)
            w = np.zeros((count, 3))
            for c, p in enumerate(per_channel):
                if p is None or p[0].size == 0:
                    continue
                if kind == "rows":
                    v[a, :, c], v[b, :, c] = _pad(p[0], count), _pad(p[1], count)
                    w[:, c] = np.where(np.arange(count) < p[0].size, _pad(p[2], count), 0.0)
                elif p[3].size:
                    v[a, :, c], v[b, :, c] = _pad(p[3], count), _pad(p[4], count)
                else:       # no censored point: the channel's pair points (never clipped)
                    v[a, :, c], v[b, :, c] = _pad(p[0], count), _pad(p[1], count)
            cl = np.ones((F, count), dtype=bool)
            cl[a] = False
            cl[b] = kind == "censored"
            vals.append(v / max_code)
            clips.append(cl)
            weights.append(w)
            pairs.append(np.tile([a, b], (count, 1)))
    if not vals:
        return HistogramSamples(values=np.zeros((F, 0, 3)), clipped=np.ones((F, 0), bool),
                                weights=np.zeros((0, 3)), pair=np.zeros((0, 2), np.int64),
                                pixels=total, max_code=max_code)
    return HistogramSamples(values=np.concatenate(vals, axis=1),
                            clipped=np.concatenate(clips, axis=1),
                            weights=np.concatenate(weights), pair=np.concatenate(pairs),
                            pixels=total, max_code=max_code)


def solve_data(samples, keep, prediction, *, clip_margin: float, saturation_threshold: float,
               blocks=None):
    """What the solver takes from the histograms of the frames ``keep``: (data, masks, weights).

    ``samples.reduced`` (kept by ``collect_samples(keep=KeptData(reduced=True))``) is released.
    ``prediction`` as :func:`histogram_correspondences`.  With ``blocks`` = (block
    samples, their masks) of the same frames, both sets of rows go into one solve (block
    rows at weight 1).
    """
    from types import SimpleNamespace

    reduced = [samples.reduced[k] for k in keep]
    samples.reduced = None
    hist = histogram_correspondences(reduced, clip_margin=clip_margin,
                                     saturation_threshold=saturation_threshold,
                                     prediction=prediction)
    del reduced
    values, masks, weights = hist.values, hist.masks(), hist.weights
    if blocks is not None:
        sub, sub_masks = blocks
        values = np.concatenate([sub.values, values], axis=1)
        masks = {k: np.concatenate([sub_masks[k], masks[k]], axis=1) for k in masks}
        weights = np.concatenate([np.ones((sub.values.shape[1], 3)), weights])
    return SimpleNamespace(values=values, max_code=hist.max_code), masks, weights
