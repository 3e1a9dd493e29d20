"""Exposure ratios of a bracket measured from its linear raw pixels.

[Lin2011] §5: "with RAW images, the exposure ratio can be directly computed by dividing the
raw values between two images".  :func:`raw_exposure_ratios` takes the ratios of aligned
linear frames over the values unclipped and well exposed in both and solves for the
relative exposures; :func:`split_thumbnails` gives it small copies of a frame made from two
disjoint halves of its pixels, so that the pixels are chosen on one half and measured on the
other (ours: free of the selection bias of choosing and measuring on the same noisy
values); :func:`raw_thumbnail` is the reduction both use.

Used by the linear HDR path (:mod:`selfcal.exposure.linear`), the path choice
(:mod:`selfcal.choose.paths`) and the RAW+JPEG pairs (:mod:`selfcal.pipeline.pairs`), for
any bracket of linear frames -- nothing here is about pairs.

Citation keys are those of ``docs/references.md``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import InputError
from ..io.images import import_cv2

__all__ = ["check_linear_raw", "raw_thumbnail", "split_thumbnails", "raw_exposure_ratios",
           "PAIR_THREADS"]

#: Threads measuring the pairs of frames of :func:`raw_exposure_ratios` side by side (each
#: pair's result is its own: the same numbers with one thread).
PAIR_THREADS = 2


def check_linear_raw(raw_rgb: np.ndarray) -> np.ndarray:
    """The first three channels of an ``HxWxC`` float linear raw (InputError otherwise)."""
    raw = np.asarray(raw_rgb)
    if raw.ndim != 3 or raw.shape[2] < 3:
        raise InputError(f"expected an HxWx3 linear raw image, got shape {raw.shape}")
    raw = raw[..., :3]
    if not np.issubdtype(raw.dtype, np.floating):
        raise InputError(f"the raw image must be float linear RGB in [0, 1], got {raw.dtype}")
    return raw


def raw_thumbnail(raw_rgb: np.ndarray, *, max_side: int = 512, clip_level: float = 0.98) -> np.ndarray:
    """An area-averaged small copy of a linear raw, NaN where a clipped pixel contributed.

    Per channel: a thumbnail pixel is NaN when any raw pixel averaged into it has that
    channel ``≥ clip_level``, so the ratios of :func:`raw_exposure_ratios` never mix
    clipped values in.
    """
    cv2 = import_cv2()
    raw = check_linear_raw(raw_rgb).astype(np.float32)     # a copy
    h, w = raw.shape[:2]
    f = max(1.0, max(h, w) / float(max_side))
    if f > 1.0:
        clip = (raw >= clip_level).astype(np.float32)
        size = (max(1, int(round(w / f))), max(1, int(round(h / f))))
        small = cv2.resize(raw, size, interpolation=cv2.INTER_AREA)
        clip = cv2.resize(clip, size, interpolation=cv2.INTER_AREA)
        small[clip > 1e-6] = np.nan
    else:       # nothing averaged: NaN where the value itself is clipped
        small = raw
        np.copyto(small, np.float32(np.nan), where=raw >= clip_level)
    return small


def split_thumbnails(raw_rgb: np.ndarray, *, max_side: int = 512,
                     clip_level: float = 0.98) -> tuple[np.ndarray, np.ndarray]:
    """Thumbnails of a linear raw from two disjoint sets of its pixels, for unbiased ratios.

    The even and the odd columns are reduced apart (:func:`raw_thumbnail`, NaN where a
    clipped value went in) and stacked twice, ``values = [even; odd]`` and ``selection =
    [odd; even]``: row for row the two show the same scene with independent noise.  Pass
    them to :func:`raw_exposure_ratios` (``select=``) and a pixel is chosen (unclipped,
    well exposed) by one half and measured on the other.  Choosing pixels by the very
    values whose ratio is taken prefers those the noise pushed into the band -- up at its
    dark end, down at its bright end -- which lowers the measured ratio, by a few per cent
    at high ISO on small frames (this split is ours).

    Returns
    -------
    values, selection : numpy.ndarray
        Float32 arrays of one shape, ``(2h, w, 3)``.
    """
    raw = check_linear_raw(raw_rgb)
    width = raw.shape[1] - raw.shape[1] % 2
    if width < 2:
        raise InputError("a frame one pixel wide has no two halves to measure on")
    even = raw_thumbnail(raw[:, 0:width:2], max_side=max_side, clip_level=clip_level)
    odd = raw_thumbnail(raw[:, 1:width:2], max_side=max_side, clip_level=clip_level)
    return np.concatenate([even, odd]), np.concatenate([odd, even])


def _pair_log_ratio(vi, vj, positive, statistic: str):
    """log(v_j / v_i) over the chosen values ``vi``, ``vj`` (float64, gathered; ``positive``
    where both are above zero): the median of the log ratios, or (``"sum"``) the log
    ratio of the values' sums -- values at or below zero included, as leaving them out
    would bias it -- after dropping log ratios beyond 5 robust deviations of the median (a
    moving object, a hot pixel); and the median absolute deviation of the log ratios."""
    every = bool(positive.all())        # the usual case: no gathering again
    d = (np.log(vj) - np.log(vi)) if every else (np.log(vj[positive]) - np.log(vi[positive]))
    med = float(np.median(d))
    mad = float(np.median(np.abs(d - med)))
    if statistic == "median":
        return med, mad
    near = np.abs(d - med) <= 5.0 * 1.4826 * max(mad, 1e-6)
    if every:
        keep = near
    else:
        keep = ~positive
        keep[positive] = near
    return float(np.log(vj[keep].sum() / vi[keep].sum())), mad


def _measured_pairs(values, chosen, max_gap, min_count: int, statistic: str):
    """``(edges, spreads)`` of :func:`raw_exposure_ratios`: ``(i, j, log ratio, count)``
    and the median absolute deviation of every pair of frames at most ``max_gap`` apart
    sharing ``min_count`` chosen values, measured in :data:`PAIR_THREADS` threads (their
    medians' partitions release the GIL; each pair's result is its own, kept in order)."""
    n = len(values)

    def pair(ij):
        i, j = ij
        both = np.flatnonzero(chosen[i] & chosen[j])
        if both.size < min_count:
            return None
        vi = values[i][both].astype(np.float64)
        vj = values[j][both].astype(np.float64)
        positive = (vi > 0) & (vj > 0)
        if not positive.any():
            return None
        return (i, j, *_pair_log_ratio(vi, vj, positive, statistic), int(both.size))

    candidates = [(i, j) for i in range(n)
                  for j in range(i + 1, n if max_gap is None else min(n, i + 1 + max_gap))]
    with ThreadPoolExecutor(max_workers=max(1, min(PAIR_THREADS, len(candidates)))) as pool:
        measured = [m for m in pool.map(pair, candidates) if m is not None]
    return ([(i, j, med, cnt) for i, j, med, _, cnt in measured],
            [mad for _, _, _, mad, _ in measured])


def raw_exposure_ratios(raws: Sequence[np.ndarray], *, low: float = 0.02, high: float = 0.9,
                        min_count: int = 100, max_side: int = 512,
                        select: Sequence[np.ndarray] | None = None,
                        statistic: str = "median",
                        max_gap: int | None = None) -> tuple[np.ndarray, dict]:
    """Relative exposures of aligned raw frames from the ratios of their values.

    [Lin2011] §5: "with RAW images, the exposure ratio can be directly computed by dividing
    the raw values between two images" -- which also fixes the exponential ambiguity of a
    response solved with unknown exposures and the inaccuracy of shutter speeds.  For every
    pair of frames, the log ratio is the median of ``log(raw_j / raw_i)`` over the thumbnail
    pixels and channels unclipped and well exposed (``low ≤ value ≤ high``) in both; the log
    exposures then follow by weighted least squares over all pairs with at least
    ``min_count`` such values (weight = count), frame by frame within each connected set of
    frames.

    Parameters
    ----------
    raws : sequence of numpy.ndarray
        ``HxWx3`` linear raws of one scene, all the same size (full images, or thumbnails
        from :func:`raw_thumbnail`, NaN marking clipped values).
    low, high : float
        The well-exposed band of raw values.
    min_count : int
        Fewest shared values for a pair to count.
    max_side : int
        Larger inputs are reduced with :func:`raw_thumbnail` first.
    select : sequence of numpy.ndarray, optional
        Per frame, values of the same shape as the (reduced) raws that decide which are
        unclipped and well exposed (default: the raws themselves); the other half of
        :func:`split_thumbnails` makes the choice independent of the measured values'
        noise.
    statistic : {"median", "sum"}
        Per pair, the median of the log ratios ([Lin2011]'s), or the log of the ratio
        of the chosen values' sums (unbiased under noise when the choice is independent of
        it; ours), after dropping outliers.

    Returns
    -------
    exposures : numpy.ndarray
        ``(n,)`` relative exposures; within each connected set the first frame is 1
        (``component`` tells the sets apart); NaN for a frame with no usable pair.
    report : dict
        ``component`` (per frame, -1 when isolated), ``pairs`` (``(i, j, ratio, count)``),
        ``spread`` (per pair, median absolute deviation of the log ratios).
    """
    if statistic not in ("median", "sum"):
        raise InputError(f"statistic must be 'median' or 'sum', got {statistic!r}")

    def reduced(arrays):
        out = []
        for r in arrays:
            r = np.asarray(r, dtype=np.float32)
            if max(r.shape[:2]) > max_side:
                r = raw_thumbnail(r, max_side=max_side)
            out.append(r)
        return out

    thumbs = reduced(raws)
    n = len(thumbs)
    if n == 0:
        return np.zeros(0), {"component": [], "pairs": [], "spread": []}
    chooser = thumbs if select is None else reduced(select)
    shape = thumbs[0].shape
    for k, (t, c) in enumerate(zip(thumbs, chooser)):
        if t.shape != shape or c.shape != shape:
            raise InputError(f"raw #{k} has size {t.shape[:2]}, raw #0 {shape[:2]}: the "
                             "exposure ratios need frames of the same size")
    values, chosen = [], []
    # float32 values, compared with the float64 band and gathered before they turn to
    # float64: the numbers of a float64 copy of every value, without the copy
    lo64, hi64 = np.float64(low), np.float64(high)
    for t, c in zip(thumbs, chooser):
        v = t.reshape(-1)
        c = c.reshape(-1)
        values.append(v)
        ok = np.isfinite(c) & (c >= lo64) & (c <= hi64) & np.isfinite(v)
        if statistic == "median":
            ok &= v > 0
        chosen.append(ok)
    edges, spreads = _measured_pairs(values, chosen, max_gap, min_count, statistic)
    # connected components
    parent = list(range(n))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i, j, _, _ in edges:
        parent[find(i)] = find(j)
    roots: dict[int, int] = {}
    component = []
    for k in range(n):
        has_edge = any(k in (i, j) for i, j, _, _ in edges)
        if not has_edge:
            component.append(-1)
            continue
        component.append(roots.setdefault(find(k), len(roots)))
    exposures = np.full(n, np.nan)
    for c in range(len(roots)):
        members = [k for k in range(n) if component[k] == c]
        index = {k: q for q, k in enumerate(members)}
        rows, rhs, wts = [], [], []
        for i, j, med, cnt in edges:
            if i in index and j in index:
                row = np.zeros(len(members))
                row[index[j]], row[index[i]] = 1.0, -1.0
                rows.append(row)
                rhs.append(med)
                wts.append(math.sqrt(cnt))
        # pin the first member at log exposure 0
        row = np.zeros(len(members))
        row[0] = 1.0
        rows.append(row)
        rhs.append(0.0)
        wts.append(1e3)
        a = np.array(rows) * np.array(wts)[:, None]
        bvec = np.array(rhs) * np.array(wts)
        sol, *_ = np.linalg.lstsq(a, bvec, rcond=None)
        sol -= sol[0]
        exposures[members] = np.exp(sol)
    report = {"component": component,
              "pairs": [(i, j, math.exp(med), cnt) for i, j, med, cnt in edges],
              "spread": spreads}
    return exposures, report
