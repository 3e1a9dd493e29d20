"""The rows of the Eq. 8 system: pair rows of [Lin2011] and selfcal's censored threshold rows.

Lin, Kim, Süsstrunk & Brown, *Revisiting Radiometric Calibration for Color Computer Vision*,
ICCV 2011, §5: with the log-domain PCA model of Eq. 7, ``g(I) = g₀(I) + H(I) c``, every pair
of samples (I, I′) of one scene point in two frames gives one linear row of Eq. 8,

    g(I′) − g(I) = K′ − K   ⇔   [H(I′) − H(I)] c − K′ + K = g₀(I) − g₀(I′),

per channel, with K the log exposure of each frame.  This module builds those rows
(:func:`build_pair_rows`, the paper's) and selfcal's own *censored* rows that locate where
each channel starts to clip at the top code (:func:`white_thresholds`,
:class:`ThresholdRows`), and assembles the weighted normal equations of both
(:class:`NormalEquations`).  The unknowns are ordered ``[c_R, c_G, c_B, K]``: 3·N
coefficients, then one log exposure per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import CalibrationError
from .stuck_codes import STUCK_CODES, STUCK_RATIO


def frame_pairs(order: np.ndarray, max_rank_gap: int):
    """Frame pairs (a, b), b brighter: each frame with the next ``max_rank_gap`` in exposure order.

    Yields the pairs by rank gap, then by rank; every part of the solve (pair rows,
    rejection counts, threshold rows) walks the same pairs in this order.
    """
    F = len(order)
    for gap in range(1, min(max_rank_gap, F - 1) + 1):
        for r in range(F - gap):
            yield order[r], order[r + gap]


@dataclass(frozen=True, eq=False)
class Interpolation:
    """A fixed linear interpolation: ``W @ table == np.interp(x, grid, table)`` (to rounding).

    Each point reads two neighbouring grid entries: ``left · table[index] + right ·
    table[index + 1]``, with the weights of the degree-1 B-spline on the grid, formed as
    scipy's ``BSpline.design_matrix`` forms them (so the products are the same, bit for
    bit, as that sparse matrix's), without building a sparse matrix (ours: built in
    every solve, it cost more than the products it serves).
    """

    index: np.ndarray       # (M,) left grid point of each x's interval
    left: np.ndarray        # (M,) weight of grid[index]
    right: np.ndarray       # (M,) weight of grid[index + 1]

    def __matmul__(self, table: np.ndarray) -> np.ndarray:
        return self.left * table[self.index] + self.right * table[self.index + 1]


def interpolation_matrix(grid: np.ndarray, x: np.ndarray) -> Interpolation:
    """``W`` with ``W @ table == np.interp(x, grid, table)`` for any table on grid.

    The noise weights re-read the slope of g at the same sample codes in every IRLS
    iteration; the interpolation weights are fixed, so they are formed once.  ``x`` is
    clipped to the grid; the last grid point belongs to the last interval.
    """
    x = np.clip(x, grid[0], grid[-1])
    i = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, grid.size - 2)
    lo, hi = grid[i], grid[i + 1]
    w = 1.0 / (hi - lo)
    return Interpolation(index=i, left=w * (hi - x), right=w * (x - lo))


def _build_pairs(valid: np.ndarray, order: np.ndarray, max_rank_gap: int,
                 values: np.ndarray, log_exposures: np.ndarray,
                 stuck_ratio: float = STUCK_RATIO, stuck_codes: float = STUCK_CODES / 255):
    """Frame pairs (a, b), b brighter, and the samples valid in both.

    A sample whose code in some channel does not move between two frames whose exposures
    differ by ``stuck_ratio`` or more is clipped in that channel, whatever its code: this
    catches black floors and white ceilings away from 0 and the maximum code (scanned
    film, cameras that crush black at a pedestal, stacks saved with a black offset).
    (selfcal's addition to the clipping test of §5, which looks at 0 and 255 only.)

    Returns
    -------
    pairs : list of (a, b, sample indices)
    stuck : int
        Sample pairs dropped as not responding to the exposure change.
    """
    pairs = []
    stuck = 0
    for a, b in frame_pairs(order, max_rank_gap):
        ok = valid[a] & valid[b]
        if log_exposures[b] - log_exposures[a] >= np.log(stuck_ratio):
            frozen = (np.abs(values[b] - values[a]) < stuck_codes).any(axis=1)
            stuck += int((ok & frozen).sum())
            ok &= ~frozen
        both = np.flatnonzero(ok)
        if both.size:
            pairs.append((a, b, both))
    return pairs, stuck


@dataclass(frozen=True, eq=False)
class PairRows:
    """The pair rows of Eq. 8 ([Lin2011] §5), one per sample, frame pair and channel.

    Row i of channel c reads ``dH[c][i] · c_c − K[pb[i]] + K[pa[i]] = rhs[c][i]``.
    """

    pairs: list                 # (a, b, sample indices) per frame pair, b brighter
    stuck: int                  # sample pairs dropped as not moving with the exposure
    pa: np.ndarray              # (m,) darker frame of each row
    pb: np.ndarray              # (m,) brighter frame of each row
    pair_id: np.ndarray         # (m,) index into ``pairs``
    Ia: np.ndarray              # (m, 3) codes in the darker frame (normalised)
    Ib: np.ndarray              # (m, 3) codes in the brighter frame
    dH: list                    # per channel (m, N): H(I′) − H(I)
    rhs: list                   # per channel (m,): −(g₀(I′) − g₀(I))
    weight: np.ndarray | None = None    # (3·m,) row weights, channel by channel; None: 1

    @property
    def m(self) -> int:
        """Rows per channel."""
        return self.pa.size


def build_pair_rows(values, valid, order, log_exposures, basis, N: int,
                    max_rank_gap: int, sample_weights=None) -> PairRows:
    """Eq. 8 rows of every sample valid in both frames of each pair, with Eq. 7 put in.

    Each frame is paired with the next ``max_rank_gap`` frames in the exposure order
    ``order`` (not only its neighbour: the pairs across larger exposure ratios tie the
    ends of the curve together).  The basis is read at the sample codes by linear
    interpolation on its grid (``basis.design``).  ``sample_weights`` ``(n, 3)``, when
    given, weight each sample's row per channel (histogram correspondences,
    :mod:`.histogram_samples`: 0 for padding).

    Raises
    ------
    CalibrationError
        When no pair, or fewer than 20 sample pairs, remain to fit.
    """
    pairs, stuck = _build_pairs(valid, order, max_rank_gap, values, log_exposures)
    if not pairs:
        raise CalibrationError("no sample is unclipped and unsaturated in two frames: "
                               "the stack cannot determine a response")
    pa = np.concatenate([np.full(p[2].size, p[0]) for p in pairs])
    pb = np.concatenate([np.full(p[2].size, p[1]) for p in pairs])
    ps = np.concatenate([p[2] for p in pairs])
    pair_id = np.concatenate([np.full(p[2].size, k) for k, p in enumerate(pairs)])
    m = ps.size
    if m < 20:
        raise CalibrationError(f"only {m} usable sample pairs: too few to fit a response")

    # per-channel design: dH = H(I') - H(I), rhs = -(g0(I') - g0(I))
    Ia = values[pa, ps]  # (m, 3)
    Ib = values[pb, ps]
    dH, rhs = [], []
    for c in range(3):
        g0a, Ha = basis.design(Ia[:, c], N)
        g0b, Hb = basis.design(Ib[:, c], N)
        dH.append(Hb - Ha)
        rhs.append(-(g0b - g0a))
    weight = (None if sample_weights is None
              else np.concatenate([sample_weights[ps, c] for c in range(3)]))
    return PairRows(pairs=pairs, stuck=stuck, pa=pa, pb=pb, pair_id=pair_id, Ia=Ia, Ib=Ib,
                    dH=dH, rhs=rhs, weight=weight)


def rejection_counts(clipped, saturated, order, max_rank_gap: int, stuck: int) -> dict:
    """(pair, sample) rows dropped as outliers of §5, by reason, over the solve's frame pairs.

    A sample clipped in either frame of a pair counts as ``"clipped"`` (with the ``stuck``
    ones of :func:`_build_pairs`), else one whose HSV saturation exceeds β in either frame
    as ``"saturated"``.
    """
    rejections = {"clipped": stuck, "saturated": 0}
    for a, b in frame_pairs(order, max_rank_gap):
        c_ab = clipped[a] | clipped[b]
        rejections["clipped"] += int(c_ab.sum())
        rejections["saturated"] += int(((saturated[a] | saturated[b]) & ~c_ab).sum())
    return rejections


def white_thresholds(values, valid, order, max_rank_gap, max_code, margin,
                      min_each=5):
    """Where each channel starts to clip at the top code, as Eq.-8 rows (censored data).

    selfcal's, not [Lin2011]'s.  The normalisation f⁻¹(max code) = 1 is an extrapolation
    over the last codes, which are never observed unclipped.  What the stack does show is
    *where* a channel reaches the top code: in a pair (a, b), b brighter, a sample is at
    the top code in b exactly when g(I_a) + K_b − K_a ≥ g(τ), τ the top code less half a
    code.  The code θ of frame a at which the share of top-code samples in b crosses one
    half (isotonic regression of the indicator on I_a) therefore satisfies Eq. 8 with
    I = θ, I′ = τ, which ties the scale of f⁻¹ to observed data up to the last half code.

    The samples bracket the crossing between the last code of frame a below it and the
    first above (``gap_lo``, ``gap_hi``).  In a scene of flat patches that gap can be wide
    and θ, its interpolated midpoint, a guess; the solver therefore uses the rows as
    censored data (:class:`ThresholdRows`): no pull while the curve's own crossing lies in
    the gap, a pull to the nearer end when it does not.

    Returns
    -------
    list of (channel, a, b, theta, theta_sigma, gap_lo, gap_hi)
        Codes normalised like ``values``.
    """
    from scipy.optimize import isotonic_regression

    top = (max_code - 0.5) / max_code
    code = 1.0 / max_code
    rows = []
    for a, b in frame_pairs(order, max_rank_gap):
        for c in range(values.shape[2]):
            x = values[a, :, c]
            use = valid[a] & (x > margin)
            if use.sum() < 2 * min_each:
                continue
            x = x[use]
            y = (values[b, use, c] >= top).astype(float)
            if y.sum() < min_each or (1 - y).sum() < min_each:
                continue
            srt = np.argsort(x, kind="stable")
            xs, p = x[srt], isotonic_regression(y[srt]).x
            above = np.flatnonzero(p >= 0.5)
            if above.size == 0 or above[0] == 0:
                continue
            k = above[0]
            # interpolate the crossing between the last point below and the first above
            x0, x1, p0, p1 = xs[k - 1], xs[k], p[k - 1], p[k]
            theta = x0 + (0.5 - p0) / max(p1 - p0, 1e-12) * (x1 - x0)
            lo = xs[np.searchsorted(p, 0.1, side="left")]
            hi = xs[min(np.searchsorted(p, 0.9, side="left"), xs.size - 1)]
            width = max(hi - lo, code)
            near = int(np.sum(np.abs(xs - theta) <= max(width, 2 * code)))
            if near < 2:
                continue
            rows.append((c, int(a), int(b), float(theta),
                         max(width / np.sqrt(near), 0.25 * code), float(x0), float(x1)))
    return rows


class ThresholdRows:
    """The censored white-threshold rows ``g(θ) − g(τ) + K_b − K_a = 0`` (selfcal's).

    One row per (channel, frame pair) found by :func:`white_thresholds`.  They are
    *censored*: the samples locate the crossing only between ``gap_lo`` and ``gap_hi``, so
    before every IRLS iteration :meth:`censor` moves θ to where the current curve crosses,
    clipped into the gap, and marks a row ``active`` only when that crossing lies outside
    the gap (an inactive row gets weight 0: the data agree with the curve there).
    Not to be confused with the white-continuation prior (:mod:`.priors`), which acts on
    the curve beyond the brightest valid sample, not on where the channels clip.
    """

    def __init__(self, thresholds, F: int, max_code: int, basis, N: int):
        self.N = N
        self.ncols = 3 * N + F
        self.channel = np.array([t[0] for t in thresholds])
        self.frame_a = np.array([t[1] for t in thresholds])
        self.frame_b = np.array([t[2] for t in thresholds])
        self.theta = np.array([t[3] for t in thresholds])
        # Each threshold row is a statistic over many sample locations, while the pair
        # rows of one location (3 channels × up to F−1 partners) are correlated yet
        # weighted as independent; the threshold rows get the same factor (in variance)
        # so that the two kinds of rows keep their relative evidential weight (see
        # ``prior_weight``, which is scaled up for the same reason).
        self.theta_sigma = (np.array([t[4] for t in thresholds])
                            / np.sqrt(3.0 * max(F - 1, 1)))
        self.tau = np.full(self.theta.size, (max_code - 0.5) / max_code)
        self.gap_lo = np.array([t[5] for t in thresholds])
        self.gap_hi = np.array([t[6] for t in thresholds])
        self.g0_tau, self.H_tau = basis.design(self.tau, N)
        self.basis = basis
        self.active = np.ones(self.size)

    @property
    def size(self) -> int:
        return self.theta.size

    def censor(self, g_grid: np.ndarray, grid: np.ndarray, K: np.ndarray) -> None:
        """Move θ to the current curve's crossing, clipped into the gap; set ``active``.

        Censored data: frame b reads the top code where g(I_a) + K_b − K_a ≥ g(τ), and
        the samples locate that crossing only between the last code of frame a seen
        unclipped in b and the first seen clipped (a scene of flat patches can leave a
        wide gap).  A crossing of the current curve inside the gap agrees with the data:
        no row.  Outside, the row pulls it to the nearer end.
        """
        tc, ta, tb = self.channel, self.frame_a, self.frame_b
        for c in range(3):
            sel = np.flatnonzero(tc == c)
            if not sel.size:
                continue
            g_c = np.maximum.accumulate(g_grid[c])
            target = np.interp(self.tau[sel], grid, g_c) - (K[tb[sel]] - K[ta[sel]])
            crossing = np.interp(target, g_c, grid)
            self.theta[sel] = np.clip(crossing, self.gap_lo[sel], self.gap_hi[sel])
            self.active[sel] = ((crossing < self.gap_lo[sel])
                                | (crossing > self.gap_hi[sel]))

    def rows(self):
        """Sparse ``A_thr`` and ``b_thr`` of the rows at the current θ."""
        N, nt = self.N, self.size
        trows = np.arange(nt)
        g0t, Ht = self.basis.design(self.theta, N)
        A_thr = sp.csr_matrix(
            (np.concatenate([(self.H_tau - Ht).ravel(), -np.ones(nt), np.ones(nt)]),
             (np.concatenate([np.repeat(trows, N), trows, trows]),
              np.concatenate([(self.channel[:, None] * N + np.arange(N)[None, :]).ravel(),
                              3 * N + self.frame_b, 3 * N + self.frame_a]))),
            shape=(nt, self.ncols))
        return A_thr, -(self.g0_tau - g0t)

    def variance(self, dg_grid: np.ndarray, grid: np.ndarray) -> np.ndarray:
        """Variance of each row in log units: θ's uncertainty through the slope of g at θ."""
        var = np.empty(self.size)
        for c in range(3):
            sel = self.channel == c
            var[sel] = (self.theta_sigma[sel] * np.interp(self.theta[sel], grid, dg_grid[c])) ** 2
        return var


class NormalEquations:
    """Weighted normal equations of the Eq. 8 system, assembled from its structure.

    Pair rows of channel c read ``dH_c[i] · c_c − K[pb_i] + K[pa_i] = rhs_c[i]``: a dense
    block of N coefficients and two ±1 exposure entries.  Forming ``AᵀWA`` through a
    general sparse product costs most of a calibration of a large stack; by blocks it is a
    few BLAS products and bincounts.  Threshold rows (few) go through the sparse matrix.
    """

    def __init__(self, dH, rhs, pa, pb, F, N, A_thr=None, b_thr=None):
        self.dH, self.rhs, self.pa, self.pb = dH, rhs, pa, pb
        self.F, self.N = F, N
        self.m = pa.size
        self.A_thr, self.b_thr = A_thr, b_thr
        m = self.m
        # incidence of the exposure columns: -1 at pb, +1 at pa; its transpose is what the
        # products read, formed once (a sparse transpose is a new matrix, checked, every
        # time: 6 per assembly cost more than the products with it)
        self.S = sp.csr_matrix((np.concatenate([-np.ones(m), np.ones(m)]),
                                (np.concatenate([np.arange(m)] * 2),
                                 np.concatenate([pb, pa]))), shape=(m, F))
        self.S_T = self.S.T

    def __call__(self, w):
        N, F, m = self.N, self.F, self.m
        ncols = 3 * N + F
        Q = np.zeros((ncols, ncols))
        q = np.zeros(ncols)
        wsum = np.zeros(m)
        for c in range(3):
            wc = w[c * m:(c + 1) * m]
            WD = self.dH[c] * wc[:, None]
            blk = slice(c * N, (c + 1) * N)
            Q[blk, blk] = self.dH[c].T @ WD
            cross = np.asarray(self.S_T @ WD)           # (F, N)
            Q[3 * N:, blk] = cross
            Q[blk, 3 * N:] = cross.T
            wy = wc * self.rhs[c]
            q[blk] = self.dH[c].T @ wy
            q[3 * N:] += self.S_T @ wy
            wsum += wc
        # exposure block: a weighted graph Laplacian of the frame pairs
        lap = np.bincount(self.pa * F + self.pb, weights=wsum, minlength=F * F).reshape(F, F)
        Q[3 * N:, 3 * N:] = (np.diag(lap.sum(axis=0) + lap.sum(axis=1)) - lap - lap.T)
        if self.A_thr is not None and self.A_thr.shape[0]:
            wt = w[3 * m:]
            At = self.A_thr
            Q += np.asarray((At.T @ (sp.diags(wt) @ At)).todense())
            q += np.asarray(At.T @ (wt * self.b_thr)).ravel()
        return Q, q

    def residual(self, x):
        """A x − b, pair rows (channel by channel) then threshold rows."""
        N = self.N
        K = x[3 * N:]
        dK = K[self.pa] - K[self.pb]
        parts = [self.dH[c] @ x[c * N:(c + 1) * N] + dK - self.rhs[c] for c in range(3)]
        if self.A_thr is not None and self.A_thr.shape[0]:
            parts.append(self.A_thr @ x - self.b_thr)
        return np.concatenate(parts)
