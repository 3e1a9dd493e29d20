"""Joint solve for log-domain PCA response coefficients and log exposures.

Implements Lin, Kim, Süsstrunk & Brown, *Revisiting Radiometric Calibration for Color
Computer Vision*, ICCV 2011, §5: the response of each channel is modelled in the log domain
with a PCA basis (Eq. 7),

    g(I) = log f⁻¹(I) = g₀(I) + Σₙ hₙ(I) cₙ,

and every pair of samples (I, I′) of one scene point in two frames gives (Eq. 8)

    g(I′) − g(I) = K′ − K,          K = log(exposure).

The log exposures are shared by the three channels and are either fixed (times known),
refined around the given times (a Gaussian prior: shutters are inaccurate), or unknown and
solved jointly, as in Kim & Pollefeys (PAMI 2008).  The equations are linear in the
coefficients and the log exposures together, so the whole problem is one weighted linear
least-squares fit; monotonicity of f⁻¹ is imposed as linear inequalities (a small QP solved
with cvxpy) only when the unconstrained fit violates it.

Outliers (§5): a sample is dropped from a pair when any channel is clipped in either frame,
or when its HSV saturation exceeds β in either frame; what remains is fitted with a Huber
loss by iteratively reweighted least squares (misalignment, motion, noise, JPEG).

Normalisation: every basis function and the mean vanish at I = 1, so f⁻¹(1) = 1 holds by
construction and the additive gauge of Eq. 8 is fixed.  With known exposures the pair rows
fix f⁻¹ only up to that normalisation, and the last codes below the maximum are never
observed unclipped, so the *scale* of f⁻¹ would be an extrapolation; censored rows that
locate where each channel starts to clip at the top code (:func:`_white_thresholds`) tie it
to the data instead, up to the last half code.  The remaining *exponential*
ambiguity (f⁻¹ → (f⁻¹)^γ with all exposure ratios raised to γ, §5) is fixed by any two
known exposure times.  With fewer than two, it is resolved by a ridge prior pulling the
coefficients towards the basis mean (the most typical response of the curve database) and
the result says so in its warnings.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..errors import CalibrationError
from ..samples import SampleSet, frame_masks

#: Default HSV saturation threshold β.  Lin et al. (§7) use 0.4 for cameras with strong
#: colour mapping and above 0.7 for most others; 0.5 drops the colours gamut mapping is
#: most likely to have moved while keeping enough samples in ordinary scenes.
DEFAULT_SATURATION_THRESHOLD = 0.5

#: Std of code noise (normalised units) assumed for block means when weighting Eq. 8.
CODE_NOISE = 1.0 / 255.0


@dataclass
class SolveResult:
    """What the joint solve found, with everything needed for diagnostics."""

    coefficients: np.ndarray            # (3, N)
    log_exposures: np.ndarray           # (F,)
    exposure_fixed: np.ndarray          # (F,) bool: held at the given time
    pair_frames: np.ndarray             # (P, 2) frame indices of each row group
    residual_rms: float                 # weighted RMS of Eq. 8 residuals (log units)
    per_pair_rms: dict                  # (a, b) -> RMS of log residual
    rejections: dict                    # reason -> count of (pair, sample) rows dropped
    rows_used: int
    rows_downweighted: int
    monotone_constrained: bool
    warnings: list = field(default_factory=list)
    ambiguity_prior: bool = False


def _interpolation_matrix(grid: np.ndarray, x: np.ndarray):
    """Sparse ``W`` with ``W @ table == np.interp(x, grid, table)`` for any table on grid.

    The noise weights re-read the slope of g at the same sample codes in every IRLS
    iteration; the interpolation weights are fixed, so they are formed once (the design
    matrix of the degree-1 B-spline on the grid).
    """
    from scipy.interpolate import BSpline

    knots = np.concatenate([grid[:1], grid, grid[-1:]])
    return BSpline.design_matrix(np.clip(x, grid[0], grid[-1]), knots, 1)


def _build_pairs(valid: np.ndarray, order: np.ndarray, max_rank_gap: int,
                 values: np.ndarray, log_exposures: np.ndarray,
                 stuck_ratio: float = 1.5, stuck_codes: float = 1.0 / 255):
    """Frame pairs (a, b), b brighter, and the samples valid in both.

    A sample whose code in some channel does not move between two frames whose exposures
    differ by ``stuck_ratio`` or more is clipped in that channel, whatever its code: this
    catches black floors and white ceilings away from 0 and the maximum code (scanned
    film, cameras that crush black at a pedestal, stacks saved with a black offset).

    Returns
    -------
    pairs : list of (a, b, sample indices)
    stuck : int
        Sample pairs dropped as not responding to the exposure change.
    """
    pairs = []
    stuck = 0
    F = len(order)
    for gap in range(1, min(max_rank_gap, F - 1) + 1):
        for r in range(F - gap):
            a, b = order[r], order[r + gap]
            ok = valid[a] & valid[b]
            if log_exposures[b] - log_exposures[a] >= np.log(stuck_ratio):
                frozen = (np.abs(values[b] - values[a]) < stuck_codes).any(axis=1)
                stuck += int((ok & frozen).sum())
                ok &= ~frozen
            both = np.flatnonzero(ok)
            if both.size:
                pairs.append((a, b, both))
    return pairs, stuck


def _white_thresholds(values, valid, order, max_rank_gap, max_code, margin,
                      min_each=5):
    """Where each channel starts to clip at the top code, as Eq.-8 rows (censored data).

    The normalisation f⁻¹(max code) = 1 is an extrapolation over the last codes, which are
    never observed unclipped.  What the stack does show is *where* a channel reaches the
    top code: in a pair (a, b), b brighter, a sample is at the top code in b exactly when
    g(I_a) + K_b − K_a ≥ g(τ), τ the top code less half a code.  The code θ of frame a at
    which the share of top-code samples in b crosses one half (isotonic regression of the
    indicator on I_a) therefore satisfies Eq. 8 with I = θ, I′ = τ, which ties the scale
    of f⁻¹ to observed data up to the last half code.

    The samples bracket the crossing between the last code of frame a below it and the
    first above (``gap_lo``, ``gap_hi``).  In a scene of flat patches that gap can be wide
    and θ, its interpolated midpoint, a guess; the solver therefore uses the rows as
    censored data: no pull while the curve's own crossing lies in the gap, a pull to the
    nearer end when it does not.

    Returns
    -------
    list of (channel, a, b, theta, theta_sigma, gap_lo, gap_hi)
        Codes normalised like ``values``.
    """
    from scipy.optimize import isotonic_regression

    top = (max_code - 0.5) / max_code
    code = 1.0 / max_code
    rows = []
    F = len(order)
    for gap in range(1, min(max_rank_gap, F - 1) + 1):
        for r in range(F - gap):
            a, b = order[r], order[r + gap]
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


def _initial_log_exposures(values, valid, basis, log_times):
    """Exposure guesses from the mean response where times are unknown (median ratios)."""
    F = values.shape[0]
    g0 = np.interp(values, basis.intensity, basis.mean)  # (F, n, 3)
    est = np.where(np.isfinite(log_times), log_times, np.nan)
    if np.all(np.isnan(est)):
        # the brightest-looking frame sets the origin
        est[int(np.argmax(np.nanmedian(np.where(valid[..., None], g0, np.nan), axis=(1, 2))))] = 0.0
    for _ in range(F):
        missing = np.flatnonzero(np.isnan(est))
        if missing.size == 0:
            break
        known = np.flatnonzero(~np.isnan(est))
        progressed = False
        for j in missing:
            best = None
            for k in known:
                both = valid[j] & valid[k]
                if both.sum() >= 5 and (best is None or both.sum() > best[1]):
                    best = (k, both.sum(), both)
            if best is None:
                continue
            k, _, both = best
            est[j] = est[k] + np.median(g0[j][both] - g0[k][both])
            progressed = True
        if not progressed:
            break
    if np.any(np.isnan(est)):
        raise CalibrationError(
            "some frames share no usable (unclipped, unsaturated) samples with any other "
            "frame, so their exposures cannot be estimated")
    return est


class _NormalEquations:
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
        # incidence of the exposure columns: -1 at pb, +1 at pa
        self.S = sp.csr_matrix((np.concatenate([-np.ones(m), np.ones(m)]),
                                (np.concatenate([np.arange(m)] * 2),
                                 np.concatenate([pb, pa]))), shape=(m, F))

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
            cross = np.asarray(self.S.T @ WD)           # (F, N)
            Q[3 * N:, blk] = cross
            Q[blk, 3 * N:] = cross.T
            wy = wc * self.rhs[c]
            q[blk] = self.dH[c].T @ wy
            q[3 * N:] += self.S.T @ wy
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


def solve_exposure_equations(samples: SampleSet, basis, log_times: np.ndarray, *,
                             n_components: int = 5, refine_exposures: bool = False,
                             saturation_threshold: float = DEFAULT_SATURATION_THRESHOLD,
                             clip_margin: float = 2.0, exposure_prior_sigma: float = 0.05,
                             max_rank_gap: int = 3, huber_k: float = 1.345,
                             max_iterations: int = 8, ridge: float = 1e-4,
                             white_sigma: float = 0.03, prior_weight: float = 100.0,
                             monotone: bool = True, white_threshold: bool = True,
                             masks: dict | None = None) -> SolveResult:
    """Solve Eq. 8 of Lin et al. (ICCV 2011) for three channels' coefficients and exposures.

    Parameters
    ----------
    samples : SampleSet
        Block-mean intensities across the stack (normalised to [0, 1]).
    basis : ResponseBasis
        A log-domain basis (``basis.domain == "log"``), Eq. 7.
    log_times : ndarray, shape (F,)
        Log of the given exposure of each frame, NaN where unknown.
    n_components : int
        Number of basis functions N in Eq. 7.
    refine_exposures : bool
        Treat given times as a prior (std ``exposure_prior_sigma`` in log units) and
        re-estimate them; otherwise they are fixed.
    saturation_threshold : float
        β of §5: samples whose HSV saturation exceeds it are dropped.
    clip_margin : float
        Codes (8-bit scale) from 0 or the maximum that count as clipped.
    max_rank_gap : int
        Each frame is paired with the next ``max_rank_gap`` frames in exposure order.
    huber_k : float
        Huber threshold in robust standard deviations (IRLS).
    ridge : float
        Weight of the ridge prior on the coefficients, relative to the mean data weight.
    white_sigma : float
        Std (log units) of the prior that the observed curve continues straight from the
        brightest valid sample to g(1) = 0.
    prior_weight : float
        Scale of the Gaussian prior c_n ~ N(0, λ_n / prior_weight) from the basis' PCA
        variances λ_n.  The data term counts every pair equation as independent, but one
        sample location enters up to 3·(F−1) correlated equations (channels, pairs) and
        JPEG errors are spatially correlated, so the prior is weighted up by about that
        factor; 100 was chosen on synthetic stacks (every 10th DoRF curve rendered by
        selfcal.synth, see bench/bench_response_synthetic.py) between 30 and 1000.
    monotone : bool
        Constrain f⁻¹ to be non-decreasing (a QP when the plain fit is not).
    white_threshold : bool
        Add the censored rows of :func:`_white_thresholds` (where each channel starts to
        clip at the top code), which tie the scale of f⁻¹ to the data.

    Returns
    -------
    SolveResult
    """
    if basis.domain != "log":
        raise CalibrationError(
            f"basis {basis.name!r} is a {basis.domain}-domain basis; Eq. 8 needs a "
            "log-domain basis (convert it with ResponseBasis.to_log_domain)")
    values = samples.values
    F, n, _ = values.shape
    N = int(n_components)
    log_times = np.asarray(log_times, dtype=float)
    if masks is None:
        masks = frame_masks(samples, clip_margin=clip_margin,
                            saturation_threshold=saturation_threshold)
    clipped, saturated = masks["clipped"], masks["saturated"]
    valid = ~(clipped | saturated)

    known = np.isfinite(log_times)
    fixed = known.copy() if not refine_exposures else np.zeros(F, bool)
    warnings: list[str] = []
    ambiguity_prior = False
    if known.sum() < 2:
        ambiguity_prior = True
        warnings.append(
            "fewer than two exposure times are known: the exponential ambiguity of the "
            "response (Lin et al. §5) was resolved by a prior towards the basis mean "
            "response, a guess that can leave f⁻¹ raised to a wrong power; exposures are "
            "relative" + (" to the frame with a known time" if known.sum() == 1 else "")
            + "; two known exposure times fix it")

    init = _initial_log_exposures(values, valid, basis, log_times)
    gauge = None
    if not fixed.any() and not (refine_exposures and known.any()):
        # fix the additive gauge of K: the first known frame, else the frame chosen above
        gauge = int(np.flatnonzero(known)[0]) if known.any() else int(np.argmin(np.abs(init)))
        fixed[gauge] = True
        if not known.any():
            log_times = log_times.copy()
            log_times[gauge] = 0.0
    order = np.argsort(init, kind="stable")
    pairs, stuck = _build_pairs(valid, order, max_rank_gap, values, init)
    # rejection counts, over the same frame pairs the solve uses
    rejections = {"clipped": stuck, "saturated": 0}
    for gap in range(1, min(max_rank_gap, F - 1) + 1):
        for r in range(F - gap):
            a, b = order[r], order[r + gap]
            c_ab = clipped[a] | clipped[b]
            rejections["clipped"] += int(c_ab.sum())
            rejections["saturated"] += int(((saturated[a] | saturated[b]) & ~c_ab).sum())
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
    n_free_k = F
    ncols = 3 * N + n_free_k
    thresholds = (_white_thresholds(values, valid, order, max_rank_gap, samples.max_code,
                                    clip_margin / 255.0) if white_threshold else [])
    if thresholds:
        tc = np.array([t[0] for t in thresholds])
        ta = np.array([t[1] for t in thresholds])
        tb = np.array([t[2] for t in thresholds])
        theta = np.array([t[3] for t in thresholds])
        # Each threshold row is a statistic over many sample locations, while the pair
        # rows of one location (3 channels × up to F−1 partners) are correlated yet
        # weighted as independent; the threshold rows get the same factor (in variance)
        # so that the two kinds of rows keep their relative evidential weight (see
        # ``prior_weight``, which is scaled up for the same reason).
        theta_sigma = (np.array([t[4] for t in thresholds])
                       / np.sqrt(3.0 * max(F - 1, 1)))
        tau = np.full(theta.size, (samples.max_code - 0.5) / samples.max_code)
        gap_lo = np.array([t[5] for t in thresholds])
        gap_hi = np.array([t[6] for t in thresholds])
        g0u, Hu = basis.design(tau, N)
        nt = theta.size
        trows = np.arange(nt)

        def threshold_rows(th):
            """Rows g(θ) − g(τ) + K_b − K_a = 0 of every threshold, at the codes ``th``."""
            g0t, Ht = basis.design(th, N)
            A_thr = sp.csr_matrix(
                (np.concatenate([(Hu - Ht).ravel(), -np.ones(nt), np.ones(nt)]),
                 (np.concatenate([np.repeat(trows, N), trows, trows]),
                  np.concatenate([(tc[:, None] * N + np.arange(N)[None, :]).ravel(),
                                  3 * N + tb, 3 * N + ta]))),
                shape=(nt, ncols))
            return A_thr, -(g0u - g0t)
    else:
        nt = 0
    # the threshold rows (if any) are set at the start of every IRLS iteration
    normal = _NormalEquations(dH, rhs, pa, pb, F, N)

    grid = basis.intensity
    g0_grid = basis.mean
    H_grid = basis.components[:N].T  # (K, N)
    # monotone over the whole grid: the dark end below the first code has no data, and an
    # unconstrained fit there can shoot up
    # (every 4th grid point: a quarter of the QP's constraints, and the table is made
    # non-decreasing between them afterwards)
    mono_idx = np.unique(np.append(np.arange(0, len(grid), 4), len(grid) - 1))
    D = np.diff(np.eye(len(mono_idx)), axis=0)
    if not monotone:
        D = D[:0]

    # Beyond the brightest valid sample (clipping keeps the last codes unobserved) the
    # normalisation f⁻¹(1) = 1 is pure extrapolation, and a basis that can bend sharply in
    # the last codes makes a constant shift of g over the observed range (the scale of
    # f⁻¹) almost free.  A Gaussian prior (std ``white_sigma``) on
    #     J(c) = g(top) + s·(1 − top),   s = (g(top) − g(top − w)) / w,
    # i.e. on how far the straight continuation of the observed curve misses g(1) = 0,
    # removes that freedom.
    white_terms = []
    window = 8.0 / 255.0
    for c in range(3):
        vals = np.where(valid, values[..., c], np.nan)
        if not np.isfinite(vals).any():
            continue
        top = float(min(np.nanmax(vals), grid[-2]))
        lo_pt = max(top - window, 0.0)
        r = (1.0 - top) / max(top - lo_pt, 1e-6)
        g0_pts, H_pts = basis.design(np.array([top, lo_pt]), N)
        a = H_pts[0] * (1 + r) - H_pts[1] * r
        b0 = g0_pts[0] * (1 + r) - g0_pts[1] * r
        white_terms.append((c, a, b0))

    ev = getattr(basis, "explained_variance", None)
    prior_precision = (prior_weight / np.asarray(ev[:N], dtype=float)
                       if ev is not None and prior_weight > 0 else None)

    alternate = bool((refine_exposures or known.sum() < 2) and not fixed.all())
    coeffs = np.zeros((3, N))
    noise_scale = 1.0
    K = init.copy()
    K[fixed] = log_times[fixed]
    robust = np.ones(3 * m + nt)
    monotone_constrained = False
    interp_a = [_interpolation_matrix(grid, Ia[:, c]) for c in range(3)]
    interp_b = [_interpolation_matrix(grid, Ib[:, c]) for c in range(3)]
    active = np.ones(nt)
    for it in range(max_iterations):
        g_grid = g0_grid[None, :] + coeffs @ H_grid.T          # (3, K)
        dg_grid = np.gradient(g_grid, grid, axis=1)
        if nt:
            # Censored data: frame b reads the top code where g(I_a) + K_b − K_a ≥ g(τ),
            # and the samples locate that crossing only between the last code of frame a
            # seen unclipped in b and the first seen clipped (a scene of flat patches can
            # leave a wide gap).  A crossing of the current curve inside the gap agrees
            # with the data: no row.  Outside, the row pulls it to the nearer end.
            for c in range(3):
                sel = np.flatnonzero(tc == c)
                if not sel.size:
                    continue
                g_c = np.maximum.accumulate(g_grid[c])
                target = np.interp(tau[sel], grid, g_c) - (K[tb[sel]] - K[ta[sel]])
                crossing = np.interp(target, g_c, grid)
                theta[sel] = np.clip(crossing, gap_lo[sel], gap_hi[sel])
                active[sel] = (crossing < gap_lo[sel]) | (crossing > gap_hi[sel])
            normal.A_thr, normal.b_thr = threshold_rows(theta)
        # noise weights: var of g(I) from code noise through the slope of the current g
        var = np.empty(3 * m + nt)
        for c in range(3):
            slope_a = interp_a[c] @ dg_grid[c]
            slope_b = interp_b[c] @ dg_grid[c]
            var[c * m:(c + 1) * m] = (CODE_NOISE ** 2) * (slope_a ** 2 + slope_b ** 2)
            if nt:
                sel = tc == c
                var[3 * m:][sel] = (theta_sigma[sel]
                                    * np.interp(theta[sel], grid, dg_grid[c])) ** 2
        # Residuals in code units (errors-in-variables): scaling g and K together by γ
        # scales var by γ², so the data term cannot shrink the exponential ambiguity
        # towards γ → 0; the floor is relative for the same reason.
        var[:3 * m] = np.maximum(var[:3 * m], 0.05 * np.median(var[:3 * m]))
        # the data term is a likelihood only with the noise at its measured level
        w = robust / (var * noise_scale ** 2)
        if nt:
            w[3 * m:] *= active
        if alternate:
            # Block coordinate descent: curves with the exposures held, then exposures
            # with the curves held.  A joint step could rescale g and K together along
            # the exponential ambiguity, which the (slope-weighted) data barely oppose;
            # alternating leaves the scale where the times (or the mean curve) put it.
            Qq = normal(w)
            x, constrained = _weighted_solve(Qq, np.ones(F, bool), K, known, False,
                                             exposure_prior_sigma, ridge, N,
                                             g0_grid[mono_idx], H_grid[mono_idx], D,
                                             white_terms, white_sigma, prior_precision)
            x[3 * N:] = _exposure_step(Qq, x, N, fixed, K, log_times, known,
                                       refine_exposures, exposure_prior_sigma)
        else:
            x, constrained = _weighted_solve(normal(w), fixed, log_times, known,
                                             refine_exposures, exposure_prior_sigma, ridge,
                                             N, g0_grid[mono_idx], H_grid[mono_idx], D,
                                             white_terms, white_sigma, prior_precision)
        monotone_constrained |= constrained
        new_coeffs = x[:3 * N].reshape(3, N)
        K = x[3 * N:]
        resid = normal.residual(x)
        u = resid / np.sqrt(var)
        scale = 1.4826 * np.median(np.abs(u)) + 1e-12
        new_robust = np.minimum(1.0, huber_k * scale / np.maximum(np.abs(u), 1e-12))
        noise_scale = max(scale, 1e-3)
        change = np.max(np.abs(new_coeffs - coeffs))
        coeffs = new_coeffs
        robust = new_robust
        if it > 0 and change < 1e-5:
            break
    if refine_exposures and known.sum() >= 2:
        # The data fix exposure *ratios* only up to the exponential ambiguity (γ), which
        # the alternation above drifts along slowly; the given times fix it: take γ and
        # the offset from a fit of the estimates to the given times, keep the per-frame
        # deviations (the shutter errors), and refit the curves with those exposures.
        from scipy.stats import theilslopes

        # Theil–Sen: one lying EXIF time must not tilt the scale of all the others
        L = log_times[known]
        gamma, alpha = theilslopes(K[known], L)[:2]
        if gamma > 0:
            K = (K - alpha) / gamma
            x, _ = _weighted_solve(normal(w), np.ones(F, bool), K, known, False,
                                   exposure_prior_sigma, ridge, N, g0_grid[mono_idx],
                                   H_grid[mono_idx], D, white_terms, white_sigma,
                                   prior_precision)
            coeffs = x[:3 * N].reshape(3, N)
    resid = normal.residual(np.concatenate([coeffs.ravel(), K]))
    w = robust / var
    residual_rms = float(np.sqrt(np.average(resid ** 2, weights=w)))
    per_pair = {}
    r3 = resid[:3 * m].reshape(3, m)
    for k, (a, bb, _) in enumerate(pairs):
        sel = pair_id == k
        per_pair[(int(a), int(bb))] = float(np.sqrt(np.mean(r3[:, sel] ** 2)))
    return SolveResult(coefficients=coeffs, log_exposures=K, exposure_fixed=fixed,
                       pair_frames=np.array([(a, bb) for a, bb, _ in pairs]),
                       residual_rms=residual_rms, per_pair_rms=per_pair,
                       rejections=rejections, rows_used=int(3 * m),
                       rows_downweighted=int(np.sum(robust < 0.5)),
                       monotone_constrained=monotone_constrained, warnings=warnings,
                       ambiguity_prior=ambiguity_prior)


def _exposure_step(normal_eq, x, N, fixed, K, log_times, known, refine, prior_sigma):
    """Log exposures minimising the weighted Eq. 8 residuals with the curves held."""
    Qfull, qfull = normal_eq
    Q = Qfull[3 * N:, 3 * N:].copy()
    q = qfull[3 * N:] - Qfull[3 * N:, :3 * N] @ x[:3 * N]
    if refine:
        kk = np.flatnonzero(known)
        Q[kk, kk] += 1.0 / prior_sigma ** 2
        q[kk] += log_times[kk] / prior_sigma ** 2
    out = K.copy()
    free = ~fixed
    if free.any():
        qf = q[free] - Q[np.ix_(free, fixed)] @ K[fixed]
        out[free] = np.linalg.lstsq(Q[np.ix_(free, free)], qf, rcond=None)[0]
    return out


def _weighted_solve(normal_eq, fixed, log_times, known, refine, prior_sigma, ridge, N,
                    g0_mono, H_mono, D, white_terms=(), white_sigma=0.01,
                    prior_precision=None):
    """Minimise Σ w r² + priors, with exposures in ``fixed`` held; QP if not monotone.

    ``normal_eq`` is ``(AᵀWA, AᵀWb)`` of the Eq. 8 system (see :class:`_NormalEquations`).
    """
    Q, q = normal_eq[0].copy(), normal_eq[1].copy()
    scale = np.trace(Q[:3 * N, :3 * N]) / (3 * N) if N else 1.0
    if prior_precision is not None:
        # Gaussian prior c_n ~ N(0, λ_n) from the curve database's PCA variances: it
        # decides what the data leave open (the bend in the never-observed last codes)
        Q[:3 * N, :3 * N] += np.diag(np.tile(prior_precision, 3))
    else:
        Q[:3 * N, :3 * N] += ridge * scale * np.eye(3 * N)
    for c, a, b0 in white_terms:
        blk = slice(c * N, (c + 1) * N)
        Q[blk, blk] += np.outer(a, a) / white_sigma ** 2
        q[blk] -= a * b0 / white_sigma ** 2
    if refine:
        kk = np.flatnonzero(known)
        # same units as the data term (noise-scaled weights): a proper Gaussian prior
        prior_w = 1.0 / prior_sigma ** 2
        Q[3 * N + kk, 3 * N + kk] += prior_w
        q[3 * N + kk] += prior_w * log_times[kk]
    free = np.concatenate([np.ones(3 * N, bool), ~fixed])
    xf = np.where(fixed, log_times, 0.0)
    x_fixed = np.concatenate([np.zeros(3 * N), xf])
    # eliminate fixed exposures
    qf = q[free] - Q[np.ix_(free, ~free)] @ x_fixed[~free]
    Qf = Q[np.ix_(free, free)]
    Qf = 0.5 * (Qf + Qf.T)
    try:
        z = np.linalg.solve(Qf, qf)
    except np.linalg.LinAlgError:
        z = np.linalg.lstsq(Qf, qf, rcond=None)[0]
    x = x_fixed.copy()
    x[free] = z
    constrained = False
    DH = D @ H_mono
    Dg0 = D @ g0_mono
    eps = 1e-7
    slopes = [Dg0 + DH @ x[c * N:(c + 1) * N] for c in range(3)]
    if D.shape[0] and min(s.min() for s in slopes) < eps:
        import cvxpy as cp

        constrained = True
        L = np.linalg.cholesky(Qf + 1e-12 * np.eye(len(qf)) * np.trace(Qf) / len(qf))
        zv = cp.Variable(len(qf))
        # ||Lᵀz||² − 2qᵀz has the same minimiser as the weighted least squares
        objective = cp.Minimize(cp.sum_squares(L.T @ zv) - 2 * qf @ zv)
        cons = [DH @ zv[c * N:(c + 1) * N] >= eps - Dg0 for c in range(3)]
        prob = cp.Problem(objective, cons)
        try:
            prob.solve(solver=cp.CLARABEL)
        except Exception:  # pragma: no cover - fall back to the other bundled solver
            prob.solve(solver=cp.OSQP, eps_abs=1e-9, eps_rel=1e-9, max_iter=200000)
        if zv.value is None:
            raise CalibrationError("the monotone response fit did not converge "
                                   f"(solver status {prob.status})")
        x[free] = zv.value
    return x, constrained

