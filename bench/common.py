"""Shared helpers of the benchmark scripts: data location, stacks, OpenCV baselines."""

from __future__ import annotations

import os
import sys
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")


def data_dir(*parts) -> Path:
    """Path into ../shared/data; exit with a clear message when it is absent."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        sys.exit(f"benchmark data not found: {path} (the benchmarks read ../shared/data)")
    return path


def real_stacks():
    """The real stacks of issue 3: name -> (paths, nominal times in seconds)."""
    from selfcal.io import read_exposure_info

    stacks = {}
    mem = data_dir("memorial")
    times = [float(Fraction(t)) for t in (mem / "shutter_times.txt").read_text().split()]
    paths = sorted(mem.glob("memorial*.png"))
    stacks["memorial"] = (paths, times)
    for name, folder, pattern in [("piccante", "piccante_canon_t2i/stack", "*.jpg"),
                                  ("frobisher", "frobisher_canon_5d2", "*.jpg"),
                                  ("ntu", "ntu_canon_m3", "*.JPG")]:
        paths = sorted(data_dir(folder).glob(pattern))
        stacks[name] = (paths, [read_exposure_info(p).exposure_time for p in paths])
    return stacks


def opencv_inverse_response(images_rgb, times, method: str) -> np.ndarray:
    """OpenCV's CalibrateDebevec / CalibrateRobertson response as f⁻¹, (256, 3) RGB."""
    import cv2

    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images_rgb]
    t = np.asarray(times, dtype=np.float32)
    if method == "debevec":
        cal = cv2.createCalibrateDebevec()
    elif method == "robertson":
        cal = cv2.createCalibrateRobertson()
    else:
        raise ValueError(method)
    resp = cal.process(bgr, t).reshape(256, 3)[:, ::-1]
    return resp.astype(np.float64)


def best_scale_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMSE after the least-squares scale s minimising ||s·estimate − truth||."""
    s = float(np.sum(estimate * truth) / max(np.sum(estimate * estimate), 1e-30))
    return float(np.sqrt(np.mean((s * estimate - truth) ** 2)))


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
    """Scale-free linearisation error over adjacent exposure pairs (issue 3, acceptance 2).

    RMS over adjacent pairs (sorted by time) and pixels with all channels in [lo, hi] in
    both frames of log f⁻¹(I′) − log f⁻¹(I) − log(t′/t).
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

    Returns (rms, share): per band [edges[k], edges[k+1]) (the last band includes 1), the
    RMS and the fraction of the metric's pixel pairs in it.  Lin et al. (ICCV 2011, §5)
    reject highly saturated pixels because the camera's colour processing moves them off
    the per-channel curves; this split shows which population a curve fits.
    """
    from selfcal.samples import hsv_saturation

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
    """The per-channel table that minimises :func:`log_linearisation_error` itself.

    Least squares over the metric's own pixel pairs, one free value of log f⁻¹ per code
    and channel (what any per-channel curve can at best reach on these images): a floor
    for the acceptance-2 metric, not a calibration.  Returns f⁻¹ as (256, 3).
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


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.t0


def table(headers, rows) -> str:
    """A plain-text table (also valid Markdown)."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(cells[0], widths)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    for r in cells[1:]:
        lines.append("| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |")
    return "\n".join(lines)
