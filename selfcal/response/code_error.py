"""How far the fitted curve is off at each code level, measured on its own samples (ours).

The solve of [Lin2011]_ (§5, Eq. 8) leaves a residual on every pair row,
``r = g(I′) − g(I) − (K′ − K)`` with ``g = log f⁻¹``.  The samples are block means of flat
regions (:mod:`selfcal.stack.samples`), so sensor and JPEG noise are mostly averaged away
and what is left is how far ``g`` at those two codes is from the pixels: the curve's
misfit, JPEG damage that does not average out (ringing, chroma bleed next to highlights),
the camera's colour processing.  A merge that trusts one code more than another
(:mod:`selfcal.hdr.weights`) should know how wrong ``g`` is there.

With ``s(I)`` the standard deviation of the error of ``g`` at level ``I`` and errors at
different codes independent, ``E[r²] = s(I)² + s(I′)²``.  The codes are cut into
:data:`LEVELS` bins; per channel and pair of bins (the two codes of a row), the mean of
``r²`` is estimated robustly as ``median(r²) / 0.4549`` (the median of a χ²₁ variable:
heavy-tailed rows, a moved object, do not set it); ``s²`` per bin is the non-negative
least-squares solution (``scipy.optimize.nnls``) of ``m_ab = s_a² + s_b²`` over the cells
with at least :data:`MIN_ROWS` rows, each weighted by ``√n / m``.  Bins that no cell
reaches get the value of the nearest bin that one does.

The profile is kept in the model's diagnostics (``"code_error_log"``) and used by the
merge (:mod:`selfcal.hdr.weights`) and its σ (:mod:`selfcal.hdr.sigma`).  The statistic
is ours; nothing in [Lin2011]_ measures the fit's error per code.
"""

from __future__ import annotations

import numpy as np

__all__ = ["code_error_profile", "code_error_at"]

#: Code bins of the profile.
LEVELS = 16
#: Rows a (bin, bin) cell needs before it enters the solve.
MIN_ROWS = 20
#: Median of a χ²₁ variable: median(r²) / this estimates E[r²] for Gaussian r.
_CHI2_MEDIAN = 0.45494


def code_error_profile(samples, valid, result, grid, inverse) -> dict | None:
    """``s(I)``, the error of log f⁻¹ per code level and channel, from the pair rows.

    Parameters
    ----------
    samples : SampleSet
        The samples of the solve (values normalised to [0, 1]).
    valid : ndarray of bool, shape (F, n)
        Samples the solve used (not clipped, not saturated).
    result : SolveResult
        The fit: ``pair_frames`` and ``log_exposures``.
    grid, inverse : ndarray
        The fitted f⁻¹ on its grid, ``(K,)`` and ``(K, 3)``.

    Returns
    -------
    dict or None
        ``{"levels": [LEVELS bin centres], "sigma": [[s_R, s_G, s_B] per bin]}``
        (JSON-ready, for the model's diagnostics); None when no channel has a cell with
        :data:`MIN_ROWS` rows.
    """
    g = np.log(np.maximum(np.asarray(inverse, float), 1e-12))
    K = np.asarray(result.log_exposures, float)
    rows: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = [[], [], []]
    for a, b in result.pair_frames:
        ok = valid[a] & valid[b]
        if not ok.any():
            continue
        for c in range(3):
            ia, ib = samples.values[a, ok, c], samples.values[b, ok, c]
            r = np.interp(ib, grid, g[:, c]) - np.interp(ia, grid, g[:, c]) - (K[b] - K[a])
            rows[c].append((_bins(ia), _bins(ib), r))
    sigma = np.full((LEVELS, 3), np.nan)
    for c in range(3):
        if rows[c]:
            sigma[:, c] = _solve_levels(*(np.concatenate(v) for v in zip(*rows[c])))
    if np.isnan(sigma).all():
        return None
    # a channel without data takes the others' (pooled) values
    pooled = np.nanmedian(sigma, axis=1)
    sigma = np.where(np.isnan(sigma), pooled[:, None], sigma)
    centres = (np.arange(LEVELS) + 0.5) / LEVELS
    return {"levels": np.round(centres, 6).tolist(), "sigma": np.round(sigma, 6).tolist(),
            "block": int(getattr(samples, "block", 1) or 1)}


def code_error_at(profile: dict | None, max_code: int) -> np.ndarray | None:
    """The profile's ``s`` at every code 0 … ``max_code``, ``(max_code + 1, 3)``; None
    without a profile.  Linear between bin centres, constant beyond the outer ones."""
    if not profile:
        return None
    levels = np.asarray(profile["levels"], float)
    sigma = np.asarray(profile["sigma"], float)
    z = np.arange(max_code + 1) / max_code
    return np.stack([np.interp(z, levels, sigma[:, c]) for c in range(3)], axis=-1)


def _bins(values) -> np.ndarray:
    return np.minimum((np.asarray(values) * LEVELS).astype(int), LEVELS - 1)


def _solve_levels(ba, bb, r) -> np.ndarray:
    """s per bin (NaN where no cell reaches it) from rows (bin a, bin b, residual)."""
    from scipy.optimize import nnls

    lo, hi = np.minimum(ba, bb), np.maximum(ba, bb)
    cell = lo * LEVELS + hi
    order = np.argsort(cell, kind="stable")
    cell, r2 = cell[order], (r[order]) ** 2
    starts = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
    counts = np.diff(np.r_[starts, cell.size])
    a_rows: list[np.ndarray] = []
    m_rows: list[float] = []
    wt_rows: list[float] = []
    for s0, n in zip(starts, counts):
        if n < MIN_ROWS:
            continue
        est = float(np.median(r2[s0:s0 + n])) / _CHI2_MEDIAN
        if est <= 0:
            continue
        row = np.zeros(LEVELS)
        row[cell[s0] // LEVELS] += 1.0
        row[cell[s0] % LEVELS] += 1.0
        a_rows.append(row)
        m_rows.append(est)
        wt_rows.append(np.sqrt(n) / est)
    out = np.full(LEVELS, np.nan)
    if not a_rows:
        return out
    A, m, wt = np.array(a_rows), np.array(m_rows), np.array(wt_rows)
    s2, _ = nnls(A * wt[:, None], m * wt)
    reached = A.sum(axis=0) > 0
    out[reached] = np.sqrt(s2[reached])
    idx = np.flatnonzero(reached)
    missing = np.flatnonzero(~reached)
    if missing.size:
        nearest = idx[np.abs(missing[:, None] - idx[None, :]).argmin(axis=1)]
        out[missing] = out[nearest]
    return out
