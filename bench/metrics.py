"""Measures the benchmark scripts print beyond :mod:`selfcal.sim.scoring`.

* odd/even agreement of two merges of one real stack (truth-free):
  :func:`measured`, :func:`agreement`, :func:`block_agreement`;
* radiance error of a merge against the simulator's truth (:func:`radiance_scores`, after
  :func:`global_scale`, on the masks of :func:`selfcal.sim.scoring.truth_masks`).
"""

from __future__ import annotations

import numpy as np

from selfcal.sim.scoring import LUMA

TRIM = np.log(2.0)         # samples off by more than 2x from the median do not set the scale
OFF = 0.05                 # "off by more than 5 %"


def measured(frames) -> np.ndarray:
    """HxW bool: some frame has every channel strictly inside selfcal's clip limits."""
    from selfcal.stack.frames import DEFAULT_CLIP_MARGIN, clip_limits

    out = np.zeros(frames[0].shape[:2], bool)
    for im in frames:
        max_code = 255 if im.dtype == np.uint8 else 65535
        lo, hi = clip_limits(max_code, DEFAULT_CLIP_MARGIN, linear=False)
        out |= np.all((im > lo) & (im < hi), axis=2)
    return out


def agreement(a: np.ndarray, b: np.ndarray, mask: np.ndarray):
    """(median, p90, bad fraction) of |log(a/b) − s| per channel on ``mask``.

    ``s`` is the median log ratio over the values finite and positive in both maps; the
    others count as an infinite disagreement (their fraction is returned).
    """
    x = a[mask].astype(np.float64).ravel()
    y = b[mask].astype(np.float64).ravel()
    ok = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    dev = np.full(x.shape, np.inf)
    if ok.any():
        lr = np.log(x[ok]) - np.log(y[ok])
        dev[ok] = np.abs(lr - np.median(lr))
    med, p90 = np.percentile(dev, [50, 90], method="higher")
    return float(med), float(p90), float(1 - ok.mean())


def block_mean(a: np.ndarray, b: int) -> np.ndarray:
    """Per-channel mean over non-overlapping b×b blocks; NaN where a value is non-finite or ≤ 0."""
    h, w = (a.shape[0] // b) * b, (a.shape[1] // b) * b
    x = a[:h, :w].astype(np.float64).reshape(h // b, b, w // b, b, -1)
    ok = np.isfinite(x) & (x > 0)
    bad = (~ok).any(axis=(1, 3))
    out = np.where(ok, x, 0.0).mean(axis=(1, 3))
    out[bad] = np.nan
    return out


def block_mask(mask: np.ndarray, b: int) -> np.ndarray:
    """Blocks whose every pixel is in ``mask`` (same blocks as :func:`block_mean`)."""
    h, w = (mask.shape[0] // b) * b, (mask.shape[1] // b) * b
    return mask[:h, :w].reshape(h // b, b, w // b, b).all(axis=(1, 3))


def block_agreement(a, b, mask, size):
    """:func:`agreement` of the ``size``×``size`` block means on blocks fully in ``mask``."""
    bm = block_mask(mask, size)
    if not bm.any():
        return float("nan"), float("nan"), 0.0, 0
    return agreement(block_mean(a, size), block_mean(b, size), bm) + (int(bm.sum()),)


def global_scale(estimate, e_true, scored) -> float:
    """The one scale ``s`` that puts ``estimate`` in the truth's units: least squares in
    log, ``log s = mean(log E_true − log E)`` over the ``scored`` channels where the
    estimate is finite and positive, leaving out the samples more than 2× from the median
    ratio; NaN when no channel qualifies."""
    est = np.asarray(estimate, np.float64)
    fit = scored & (est > 0) & np.isfinite(est)
    if not fit.any():
        return float("nan")
    log_ratio = np.log(e_true[fit]) - np.log(est[fit])
    log_ratio = log_ratio[np.abs(log_ratio - np.median(log_ratio)) <= TRIM]
    return float(np.exp(np.mean(log_ratio)))


def power_scale_error(estimate, e_true, scored) -> float:
    """Median ``|a·E^b / E_true − 1|`` over the ``scored`` channels, ``(log a, b)`` fitted
    by least squares in log on the samples within 2× of the median ratio: the error left
    once the exponential ambiguity of a self-calibration (``E → a E^b``, the curve's
    exponent and the exposures' trend traded against each other) is taken out."""
    est = np.asarray(estimate, np.float64)
    fit = scored & (est > 0) & np.isfinite(est)
    if not fit.any():
        return float("nan")
    lt, le = np.log(e_true[fit]), np.log(est[fit])
    keep = np.abs((lt - le) - np.median(lt - le)) <= TRIM
    b, a = np.polyfit(le[keep], lt[keep], 1)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        err = np.abs(np.exp(a) * est[scored] ** b / e_true[scored] - 1)
    return float(np.median(np.where(np.isfinite(err), err, np.inf)))


def radiance_scores(estimate, e_true, scored, readable, unmeasured=None):
    """Median relative error; readable shortest-only pixels off by > 5 % (how many flagged).

    Returns ``(median, off, off_flagged)``: ``off`` counts the pixels of ``readable``
    whose luminance is off by more than 5 % (NaN counts as off), ``off_flagged`` those of
    them that ``unmeasured`` flags (0 without it).
    """
    est = np.asarray(estimate, np.float64)
    s = global_scale(est, e_true, scored)
    if not np.isfinite(s):
        return float("nan"), int(readable.sum()), 0
    err = np.abs(s * est[scored] / e_true[scored] - 1)
    err = np.where(np.isfinite(err), err, np.inf)
    y_est = s * (est @ LUMA)
    y_true = e_true @ LUMA
    off = readable & ~(np.abs(y_est / y_true - 1) <= OFF)
    flagged = int((off & unmeasured).sum()) if unmeasured is not None else 0
    return float(np.median(err)), int(off.sum()), flagged
