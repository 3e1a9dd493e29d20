"""The named parts of the Eq. 8 solver, each on data with a known answer.

Pair rows ([Lin2011] §5, Eq. 8 with Eq. 7 put in) on a noiseless stack rendered from a
known curve; selfcal's censored threshold rows, priors, noise weights, Huber weights, block
alternation, initial exposures and Theil–Sen rescale against independent formulations.
"""

from __future__ import annotations

import numpy as np
import pytest

from selfcal.response.basis import builtin_basis
from selfcal.response.equations import (
    ThresholdRows,
    interpolation_matrix,
    NormalEquations,
    build_pair_rows,
    frame_pairs,
    rejection_counts,
)
from selfcal.response.priors import (
    ExposurePrior,
    PriorTerms,
    WhiteContinuation,
    pca_variance_precision,
)
from selfcal.response.solver import (
    CODE_NOISE,
    MonotoneConstraint,
    SolveSettings,
    _exposure_step,
    _Exposures,
    _huber_weights,
    _initial_log_exposures,
    _monotone_qp,
    _noise_variance,
    _theil_sen_rescale,
    _weighted_solve,
)

N = 4
TIMES = np.array([1.0, 1.7, 2.9, 5.0])


@pytest.fixture(scope="module")
def basis():
    return builtin_basis()


def _curves(basis, coeffs):
    """g of each channel on the basis grid, (3, K)."""
    return basis.mean[None, :] + coeffs @ basis.components[:N]


def _render(basis, coeffs, log_exposures, n=150, seed=0):
    """Noiseless normalised codes (F, n, 3) of random radiances under the curves ``coeffs``."""
    rng = np.random.default_rng(seed)
    grid = basis.intensity
    g = _curves(basis, coeffs)
    values = np.empty((log_exposures.size, n, 3))
    for c in range(3):
        assert np.all(np.diff(g[c]) > 0)
        lo = np.interp(0.05, grid, g[c]) - log_exposures.min()
        hi = np.interp(0.95, grid, g[c]) - log_exposures.max()
        log_radiance = rng.uniform(lo, hi, n)
        for f, k in enumerate(log_exposures):
            values[f, :, c] = np.interp(log_radiance + k, g[c], grid)
    return values


@pytest.fixture(scope="module")
def true_coeffs(basis):
    rng = np.random.default_rng(1)
    return rng.normal(size=(3, N)) * np.sqrt(basis.explained_variance[:N]) * 0.5


@pytest.fixture(scope="module")
def noiseless(basis, true_coeffs):
    K = np.log(TIMES)
    values = _render(basis, true_coeffs, K)
    valid = np.ones(values.shape[:2], bool)
    order = np.argsort(K)
    rows = build_pair_rows(values, valid, order, K, basis, N, max_rank_gap=2)
    return values, valid, order, K, rows


def _no_priors(exposure=None):
    return PriorTerms(coefficient_precision=None, ridge=0.0, white_continuation=(),
                      white_continuation_sigma=0.03,
                      exposure=exposure or ExposurePrior(np.full(4, np.nan),
                                                         np.zeros(4, bool), 0.05))


def _unconstrained(N_):
    return MonotoneConstraint(DH=np.zeros((0, N_)), Dg0=np.zeros(0))


def _dense_rows(dH, rhs, pa, pb, F):
    """The pair rows written out as a dense matrix: dH_c · c_c − K[pb] + K[pa] = rhs_c."""
    m, N_ = dH[0].shape
    S = np.zeros((m, F))
    S[np.arange(m), pb] -= 1
    S[np.arange(m), pa] += 1
    A = np.vstack([np.hstack([np.zeros((m, c * N_)), dH[c], np.zeros((m, (2 - c) * N_)), S])
                   for c in range(3)])
    return A, np.concatenate(rhs)


# --- pair rows of Eq. 8 -------------------------------------------------------------------

def test_frame_pairs_walk_rank_gaps_in_exposure_order():
    order = np.array([2, 0, 1, 3])
    assert list(frame_pairs(order, 2)) == [(2, 0), (0, 1), (1, 3), (2, 1), (0, 3)]
    assert len(list(frame_pairs(order, 9))) == 6          # every pair once


def test_pair_rows_of_a_noiseless_stack_hold_at_the_true_curve(noiseless, true_coeffs):
    values, valid, order, K, rows = noiseless
    assert len(rows.pairs) == 3 + 2 and rows.m == 5 * values.shape[1]
    normal = NormalEquations(rows.dH, rows.rhs, rows.pa, rows.pb, K.size, N)
    truth = np.concatenate([true_coeffs.ravel(), K])
    assert np.max(np.abs(normal.residual(truth))) < 1e-9
    # the mean curve (c = 0) or exposures off by 10 % do not satisfy them
    assert np.max(np.abs(normal.residual(np.concatenate([np.zeros(3 * N), K])))) > 1e-2
    assert np.max(np.abs(normal.residual(truth + np.r_[np.zeros(3 * N),
                                                       0, 0, 0.1, 0]))) > 0.09


def test_rejections_count_clipped_before_saturated():
    clipped = np.zeros((3, 4), bool)
    saturated = np.zeros((3, 4), bool)
    clipped[0, 0] = True                 # in pairs (0, 1), (0, 2)
    saturated[0, 0] = saturated[1, 1] = True
    counts = rejection_counts(clipped, saturated, np.arange(3), 2, stuck=7)
    assert counts == {"clipped": 7 + 2, "saturated": 2}   # sample 1 in (0, 1), (1, 2)


# --- censored white-threshold rows --------------------------------------------------------

def _one_threshold(basis, gap):
    """A threshold row of channel 0 in the pair (0, 1) with the given gap, and its crossing."""
    tau = 254.5 / 255
    K = np.array([0.0, np.log(2.0)])
    g0 = basis.mean
    crossing = np.interp(np.interp(tau, basis.intensity, g0) - K[1], g0, basis.intensity)
    lo, hi = crossing + gap[0], crossing + gap[1]
    rows = ThresholdRows([(0, 0, 1, 0.5 * (lo + hi), 0.01, lo, hi)], 2, 255, basis, N)
    return rows, K, crossing


@pytest.mark.parametrize("gap", [(-0.02, 0.02), (-0.2, 0.001)])
def test_threshold_rows_exert_no_pull_when_the_crossing_lies_in_the_gap(basis, gap):
    rows, K, crossing = _one_threshold(basis, gap)
    g_grid = np.repeat(basis.mean[None, :], 3, axis=0)
    rows.censor(g_grid, basis.intensity, K)
    assert rows.active[0] == 0
    assert rows.theta[0] == pytest.approx(crossing, abs=1e-9)
    # weighted by ``active``, the row adds exactly nothing to the normal equations
    rng = np.random.default_rng(0)
    m = 50
    dH = [rng.normal(size=(m, N)) for _ in range(3)]
    rhs = [rng.normal(size=m) for _ in range(3)]
    pa, pb = np.zeros(m, int), np.ones(m, int)
    plain = NormalEquations(dH, rhs, pa, pb, 2, N)
    censored = NormalEquations(dH, rhs, pa, pb, 2, N, *rows.rows())
    w = np.ones(3 * m + 1)
    w[3 * m:] *= rows.active
    for a, b in zip(plain(w[:3 * m]), censored(w)):
        np.testing.assert_array_equal(a, b)


def test_threshold_rows_pull_to_the_nearer_end_when_the_crossing_is_outside(basis):
    rows, K, crossing = _one_threshold(basis, (-0.06, -0.03))   # gap below the crossing
    rows.censor(np.repeat(basis.mean[None, :], 3, axis=0), basis.intensity, K)
    assert rows.active[0] == 1
    assert rows.theta[0] == pytest.approx(crossing - 0.03)
    A_thr, b_thr = rows.rows()
    x = np.concatenate([np.zeros(3 * N), K])
    # the row reads g(τ) − g(θ) = K_b − K_a; θ below the curve's crossing leaves it short
    assert (A_thr @ x - b_thr)[0] > 1e-3


# --- priors -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def random_system():
    rng = np.random.default_rng(3)
    F, m = 4, 120
    pa = rng.integers(0, F, m)
    pb = (pa + rng.integers(1, F, m)) % F
    dH = [rng.normal(size=(m, N)) for _ in range(3)]
    rhs = [rng.normal(size=m) for _ in range(3)]
    w = rng.uniform(0.5, 2.0, 3 * m)
    A, b = _dense_rows(dH, rhs, pa, pb, F)
    return NormalEquations(dH, rhs, pa, pb, F, N), w, A, b


def _lstsq_with_rows(A, b, w, fixed, held, extra_A=None, extra_b=None):
    """Plain weighted least squares, fixed exposures moved to the right-hand side."""
    F = fixed.size
    hold = np.concatenate([np.zeros(3 * N, bool), fixed])
    x_hold = np.concatenate([np.zeros(3 * N), np.where(fixed, held, 0.0)])
    rw = np.sqrt(w)
    M, y = rw[:, None] * A, rw * b
    if extra_A is not None:
        M, y = np.vstack([M, extra_A]), np.concatenate([y, extra_b])
    y = y - M[:, hold] @ x_hold[hold]
    x = x_hold.copy()
    x[~hold] = np.linalg.lstsq(M[:, ~hold], y, rcond=None)[0]
    assert x.size == 3 * N + F
    return x


def test_zero_weight_priors_leave_the_plain_least_squares_solution(random_system):
    normal, w, A, b = random_system
    fixed = np.array([True, False, False, False])
    held = np.array([0.3, np.nan, np.nan, np.nan])
    settings = SolveSettings(N=N, priors=_no_priors(), monotone=_unconstrained(N))
    x, constrained = _weighted_solve(normal(w), settings, fixed, held, False)
    assert not constrained
    np.testing.assert_allclose(x, _lstsq_with_rows(A, b, w, fixed, held),
                               rtol=1e-9, atol=1e-11)


def test_each_prior_term_is_an_extra_least_squares_row(random_system, basis):
    """PCA-variance, white-continuation and exposure priors equal rows appended to Eq. 8."""
    normal, w, A, b = random_system
    F = 4
    rng = np.random.default_rng(5)
    precision = pca_variance_precision(basis, N, prior_weight=100.0)
    np.testing.assert_allclose(precision, 100.0 / basis.explained_variance[:N])
    assert pca_variance_precision(basis, N, prior_weight=0.0) is None
    white = (WhiteContinuation(1, rng.normal(size=N), 0.4),)
    sigma, exp_sigma = 0.05, 0.1
    times = np.array([0.0, 0.5, np.nan, 1.6])
    exposure = ExposurePrior(mean=times, frames=np.isfinite(times), sigma=exp_sigma)
    priors = PriorTerms(coefficient_precision=precision, ridge=1.0,
                        white_continuation=white, white_continuation_sigma=sigma,
                        exposure=exposure)
    settings = SolveSettings(N=N, priors=priors, monotone=_unconstrained(N))
    fixed = np.zeros(F, bool)
    x, _ = _weighted_solve(normal(w), settings, fixed, np.zeros(F), True)
    extra_A, extra_b = [], []
    for c in range(3):                         # c_n ~ N(0, 1 / precision_n)
        rows = np.zeros((N, 3 * N + F))
        rows[:, c * N:(c + 1) * N] = np.diag(np.sqrt(precision))
        extra_A.append(rows)
        extra_b.append(np.zeros(N))
    row = np.zeros((1, 3 * N + F))             # (a · c_1 + b0) / σ = 0
    row[0, N:2 * N] = white[0].a / sigma
    extra_A.append(row)
    extra_b.append([-white[0].b0 / sigma])
    for k in np.flatnonzero(exposure.frames):  # K_k ~ N(log t_k, σ²)
        row = np.zeros((1, 3 * N + F))
        row[0, 3 * N + k] = 1 / exp_sigma
        extra_A.append(row)
        extra_b.append([times[k] / exp_sigma])
    expected = _lstsq_with_rows(A, b, w, fixed, np.zeros(F), np.vstack(extra_A),
                                np.concatenate(extra_b))
    np.testing.assert_allclose(x, expected, rtol=1e-8, atol=1e-10)
    # and the terms did something: without them the solution is another
    plain, _ = _weighted_solve(normal(w), SolveSettings(N, _no_priors(), _unconstrained(N)),
                               np.array([True, False, False, False]), np.zeros(F), False)
    assert np.max(np.abs(plain[:3 * N] - x[:3 * N])) > 1e-3


def test_ridge_acts_only_without_pca_variances(random_system):
    normal, w, _, _ = random_system
    F = 4
    fixed = np.array([True, False, False, False])

    def solve(precision, ridge):
        priors = PriorTerms(precision, ridge, (), 0.03, _no_priors().exposure)
        return _weighted_solve(normal(w), SolveSettings(N, priors, _unconstrained(N)),
                               fixed, np.zeros(F), False)[0]

    with_pca = solve(np.full(N, 2.0), 0.0)
    np.testing.assert_array_equal(solve(np.full(N, 2.0), 50.0), with_pca)
    assert np.max(np.abs(solve(None, 50.0) - solve(None, 0.0))) > 1e-3


# --- the monotone QP ----------------------------------------------------------------------

@pytest.mark.parametrize("F", [0, 3])
def test_monotone_qp_is_cvxpys_model_solved_by_clarabel(basis, F):
    """The direct Clarabel call solves the cvxpy model it replaced, to solver tolerance."""
    import cvxpy as cp

    rng = np.random.default_rng(5)
    n = 3 * N + F
    M = rng.normal(size=(n + 20, n)) * rng.uniform(1, 30, n)
    Qf = M.T @ M
    z_bent = rng.normal(size=n) * 3       # a least-squares minimiser far from monotone
    qf = Qf @ z_bent
    mono = MonotoneConstraint.on_grid(basis, N, True)
    eps = 1e-7
    z = _monotone_qp(Qf, qf, mono, N, eps)
    for c in range(3):
        assert np.min(mono.Dg0 + mono.DH @ z[c * N:(c + 1) * N]) > eps - 1e-8
    assert np.any(mono.Dg0 + mono.DH @ z_bent[:N] < 0)
    L = np.linalg.cholesky(Qf + 1e-12 * np.eye(n) * np.trace(Qf) / n)
    zv = cp.Variable(n)
    cp.Problem(cp.Minimize(cp.sum_squares(L.T @ zv) - 2 * qf @ zv),
               [mono.DH @ zv[c * N:(c + 1) * N] >= eps - mono.Dg0
                for c in range(3)]).solve(solver=cp.CLARABEL)
    np.testing.assert_allclose(z, zv.value, rtol=0, atol=1e-6 * np.abs(zv.value).max())


def test_interpolation_reads_tables_as_np_interp_and_the_degree_1_bspline():
    from scipy.interpolate import BSpline

    rng = np.random.default_rng(4)
    grid = np.sort(np.concatenate([[0.0, 1.0], rng.uniform(0, 1, 60)]))
    x = np.concatenate([rng.uniform(-0.1, 1.1, 500), grid])   # outside, inside, on nodes
    table = rng.normal(size=grid.size)
    W = interpolation_matrix(grid, x)
    np.testing.assert_allclose(W @ table, np.interp(x, grid, table), rtol=0, atol=1e-14)
    knots = np.concatenate([grid[:1], grid, grid[-1:]])
    B = BSpline.design_matrix(np.clip(x, 0, 1), knots, 1)
    np.testing.assert_allclose(W @ table, B @ table, rtol=0, atol=1e-15)


# --- noise weights, Huber weights ---------------------------------------------------------

def test_noise_variance_reads_the_slope_of_g_at_both_codes():
    grid = np.linspace(0, 1, 101)
    rng = np.random.default_rng(2)
    Ia, Ib = rng.uniform(0, 1, (40, 3)), rng.uniform(0, 1, (40, 3))
    # g = s·x² per channel: slope 2·s·x
    s = np.array([1.0, 2.0, 3.0])
    dg_grid = 2 * s[:, None] * grid[None, :]
    interp_a = [interpolation_matrix(grid, Ia[:, c]) for c in range(3)]
    interp_b = [interpolation_matrix(grid, Ib[:, c]) for c in range(3)]
    var = _noise_variance(dg_grid, interp_a, interp_b, 40, None, grid)
    expected = (CODE_NOISE ** 2 * ((2 * s * Ia) ** 2 + (2 * s * Ib) ** 2)).T.ravel()
    expected = np.maximum(expected, 0.05 * np.median(expected))
    np.testing.assert_allclose(var, expected, rtol=1e-12)


def test_huber_weights_downweight_only_the_outlier():
    rng = np.random.default_rng(0)
    resid = rng.normal(size=400) * 0.01
    resid[7] = 1.0
    var = np.full(resid.size, 0.01 ** 2)
    robust, scale = _huber_weights(resid, var, 1.345)
    assert scale == pytest.approx(1.0, rel=0.15)
    assert robust[7] < 0.02
    assert np.mean(robust[np.arange(400) != 7] == 1.0) > 0.75
    np.testing.assert_allclose(robust[7], 1.345 * scale / 100, rtol=1e-12)


# --- block alternation, initial exposures, Theil–Sen --------------------------------------

def test_alternation_is_used_where_the_times_do_not_fix_the_scale():
    def exposures(known, refine, fixed):
        return _Exposures(np.zeros(4), np.array(known), np.array(fixed), refine, np.zeros(4))

    assert not exposures([1, 1, 0, 0], False, [1, 1, 0, 0]).alternate
    assert exposures([1, 0, 0, 0], False, [1, 0, 0, 0]).alternate
    assert exposures([1, 1, 1, 1], True, [0, 0, 0, 0]).alternate
    assert not exposures([1, 1, 1, 1], False, [1, 1, 1, 1]).alternate


def test_exposure_step_recovers_the_exposures_with_the_true_curves_held(noiseless,
                                                                       true_coeffs):
    values, valid, order, K, rows = noiseless
    normal = NormalEquations(rows.dH, rows.rhs, rows.pa, rows.pb, K.size, N)
    x = np.concatenate([true_coeffs.ravel(), np.zeros(K.size)])
    fixed = np.array([True, False, False, False])
    start = K + np.array([0.0, 0.3, -0.2, 0.5])
    out = _exposure_step(normal(np.ones(3 * rows.m)), x, N, fixed, start, None)
    np.testing.assert_allclose(out, K, atol=1e-9)


def test_initial_exposures_are_exact_for_a_stack_of_the_mean_curve(basis):
    K = np.log(TIMES)
    values = _render(basis, np.zeros((3, N)), K)
    valid = np.ones(values.shape[:2], bool)
    given = np.array([K[0], np.nan, np.nan, np.nan])
    np.testing.assert_allclose(_initial_log_exposures(values, valid, basis, given), K,
                               atol=1e-9)


def test_theil_sen_rescale_matches_scipy_and_ignores_one_lying_time():
    from scipy.stats import theilslopes

    L = np.log(np.array([1 / 250, 1 / 125, 1 / 60, 1 / 30, 1 / 15, 1 / 8, np.nan]))
    known = np.isfinite(L)
    gamma, alpha = 0.8, -0.4
    K = gamma * np.nan_to_num(L) + alpha
    K[6] = 1.0                            # a frame without a time
    K[2] += 0.5                           # one shutter (or EXIF tag) that lies
    slope, intercept = theilslopes(K[known], L[known])[:2]
    out = _theil_sen_rescale(K, L, known)
    np.testing.assert_array_equal(out, (K - intercept) / slope)
    # the lie does not tilt the scale: the other frames keep the ratios of their times
    inliers = known.copy()
    inliers[2] = False
    assert np.ptp(out[inliers] - L[inliers]) < 1e-12
    assert abs(out[2] - L[2] - (out[0] - L[0]) - 0.5 / gamma) < 1e-12
    assert _theil_sen_rescale(-K, L, known) is None       # γ ≤ 0: no rescale
