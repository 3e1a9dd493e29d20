"""Monotone smooth 7th-order tone curves by quadratic programming.

[Gong2018] §3.3, Eq. 9::

    min_f  Σ_i (f(x_i) - y_i)²  +  λ ∫ f''(x)² dx    s.t.  f'(x) >= 0

solved per channel with cvxpy.  The polynomial is written in the Bernstein basis of
degree 7 on ``t = (x - lo) / (hi - lo) ∈ [0, 1]``: the basis is well conditioned there
(every basis function lies in ``[0, 1]`` and they sum to one), unlike raw monomials
(Hilbert-like normal equations; HiGHS failed on such a QP, see DESIGN.md).  Monotonicity
is imposed as ``f'(t_g) >= 0`` on 101 grid points; the smoothness integral is exact
(Gram matrix of the degree-5 Bernstein basis of ``f''``).  The same routine fits the
inverse curves ``f⁻¹`` of §3.5 (rendered value -> colour-corrected raw).

The QP is built once per shape as a parametrised cvxpy problem (DPP) and re-solved with
new data for every channel and every random sample set: 8 variables, 101 constraints,
about 2-5 ms per solve with CLARABEL.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..errors import CalibrationError, InputError

DEGREE = 7
#: Smoothness weight λ of Eq. 9 ([Gong2018] §3.3: "a small weight (e.g. 10⁻⁵)").
SMOOTHNESS = 1e-5
_GRID = np.linspace(0.0, 1.0, 101)


def _binom(n: int) -> np.ndarray:
    return np.array([math.comb(n, i) for i in range(n + 1)], dtype=np.float64)


def bernstein_basis(t, degree: int = DEGREE) -> np.ndarray:
    """Bernstein polynomials ``B_{i,n}(t) = C(n, i) t^i (1 - t)^(n - i)``, shape ``(..., n+1)``."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    i = np.arange(degree + 1)
    return _binom(degree) * t ** i * (1.0 - t) ** (degree - i)


def _derivative_matrix(degree: int, order: int) -> np.ndarray:
    """``D`` such that ``Σ_j (D c)_j B_{j, n-order}`` is the ``order``-th derivative of
    ``Σ_i c_i B_{i, n}``."""
    d = np.eye(degree + 1)
    n = degree
    for _ in range(order):
        d = n * (d[1:] - d[:-1])
        n -= 1
    return d


def _smoothness_gram(degree: int) -> np.ndarray:
    """``R`` with ``c^T R c = ∫_0^1 f''(t)² dt`` for ``f = Σ c_i B_{i,degree}``."""
    m = degree - 2
    b = _binom(m)
    i = np.arange(m + 1)
    gram = np.outer(b, b) / (_binom(2 * m)[i[:, None] + i[None, :]] * (2 * m + 1))
    d2 = _derivative_matrix(degree, 2)
    return d2.T @ gram @ d2


#: Share of the domain, at its top, that ``MonotonePolynomial.top`` governs: half a code.
TOP_SPAN = 0.5 / 255


@dataclass
class MonotonePolynomial:
    """Per-channel monotone polynomials ``f_k(x) = Σ_i c_ki B_i((x - lo_k) / (hi_k - lo_k))``.

    The tone curves of [Gong2018] Eq. 9 (and their inverses, §3.5).  Inputs are clamped to
    the domain ``[lo_k, hi_k]`` before evaluation, so the curves are constant (and monotone)
    outside the fitted range.

    Attributes
    ----------
    coefficients : numpy.ndarray
        ``(3, degree + 1)`` Bernstein coefficients.
    domain : numpy.ndarray
        ``(3, 2)`` input range ``[lo, hi]`` per channel.
    top : numpy.ndarray or None
        ``(3,)`` values at ``hi`` over the last half code (inverse curves: the value a
        clipped top code stands for, see :func:`selfcal.pipeline.fit.fit_pipeline`).  Where
        ``top_k`` exceeds the polynomial at ``hi_k - TOP_SPAN (hi_k - lo_k)``, channel k
        runs linearly from there to ``top_k``; otherwise the polynomial is kept.
    """

    coefficients: np.ndarray
    domain: np.ndarray
    top: np.ndarray | None = None

    def __post_init__(self):
        self.coefficients = np.asarray(self.coefficients, dtype=np.float64)
        self.domain = np.asarray(self.domain, dtype=np.float64)
        if (self.coefficients.ndim != 2 or self.coefficients.shape[0] != 3
                or self.coefficients.shape[1] < 2 or self.domain.shape != (3, 2)):
            raise InputError("a monotone polynomial needs (3, d+1) coefficients and a (3, 2) "
                             "domain")
        if not (np.all(np.isfinite(self.coefficients)) and np.all(np.isfinite(self.domain))
                and np.all(self.domain[:, 1] > self.domain[:, 0])):
            raise InputError("a monotone polynomial needs finite coefficients and lo < hi")
        if self.top is not None:
            self.top = np.asarray(self.top, dtype=np.float64)
            if self.top.shape != (3,) or not np.all(np.isfinite(self.top)):
                raise InputError("a monotone polynomial's top values must be 3 finite numbers")

    @property
    def degree(self) -> int:
        return self.coefficients.shape[1] - 1

    def _t(self, x, k):
        lo, hi = self.domain[k]
        return np.clip((np.asarray(x, dtype=np.float64) - lo) / (hi - lo), 0.0, 1.0)

    def _power(self) -> np.ndarray:
        """Power-basis coefficients in ``t`` per channel (Bernstein -> monomial), cached."""
        if getattr(self, "_power_cache", None) is None:
            n = self.degree
            conv = np.zeros((n + 1, n + 1))
            for i in range(n + 1):
                for j in range(i, n + 1):
                    conv[i, j] = math.comb(n, i) * math.comb(n - i, j - i) * (-1) ** (j - i)
            self._power_cache = self.coefficients @ conv
        return self._power_cache

    def channel(self, x: npt.ArrayLike, k: int) -> np.ndarray:
        """Evaluate channel ``k`` at ``x`` (any shape), float64 (Horner in the power basis;
        exact enough for degree 7 on ``[0, 1]``)."""
        t = self._t(x, k)
        out = self._horner(t, k)
        if self.top is not None:
            t0 = 1.0 - TOP_SPAN
            p0 = float(self._horner(np.array(t0), k))
            if self.top[k] > p0:
                out = np.where(t > t0, p0 + (t - t0) / TOP_SPAN * (self.top[k] - p0), out)
        return out

    def _horner(self, t, k):
        power = self._power()[k]
        out = np.full(np.shape(t), power[-1])
        for j in range(self.degree - 1, -1, -1):
            out *= t
            out += power[j]
        return out

    def __call__(self, x) -> np.ndarray:
        """Evaluate all three channels on ``(..., 3)`` input."""
        x = np.asarray(x, dtype=np.float64)
        return np.stack([self.channel(x[..., k], k) for k in range(3)], axis=-1)

    def table(self, k: int, n: int = 4096) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f_k(x))`` sampled at ``n`` points over the domain."""
        x = np.linspace(self.domain[k, 0], self.domain[k, 1], n)
        return x, self.channel(x, k)

    def to_dict(self) -> dict:
        d = {"basis": f"bernstein{self.degree}", "coefficients": self.coefficients.tolist(),
             "domain": self.domain.tolist()}
        if self.top is not None:
            d["top"] = self.top.tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "MonotonePolynomial":
        top = d.get("top")
        return cls(coefficients=np.asarray(d["coefficients"], dtype=np.float64),
                   domain=np.asarray(d["domain"], dtype=np.float64),
                   top=None if top is None else np.asarray(top, dtype=np.float64))


#: λ values tried by ``smoothness="auto"`` (5-fold cross-validation per channel).
SMOOTHNESS_GRID = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
_FOLDS = 5


def _fit_domain(x, y, domain) -> np.ndarray:
    """Per channel (lo, hi) of the polynomial's input: the samples' range (from ≤ 0)
    unless given."""
    if domain is None:
        with np.errstate(invalid="ignore"):
            lo = np.minimum(0.0, np.nanmin(np.where(np.isnan(y), np.nan, x), axis=0))
            hi = np.nanmax(np.where(np.isnan(y), np.nan, x), axis=0)
        domain = np.stack([lo, hi], axis=1)
    return np.asarray(domain, dtype=np.float64)


def _cross_validated(x, y, w, degree, domain, folds=None) -> MonotonePolynomial:
    """Per channel, the λ of SMOOTHNESS_GRID with the lowest 5-fold cross-validated error
    (fixed, seeded folds; or the given fold labels), then the fit on all samples; scores
    in ``.validation``."""
    n = x.shape[0]
    if folds is None:
        fold = np.random.default_rng(0).permutation(n) % _FOLDS
    else:
        fold = np.unique(np.asarray(folds).reshape(-1), return_inverse=True)[1]
        if fold.shape[0] != n:
            raise InputError(f"folds has {fold.shape[0]} labels for {n} samples")
    domain = _fit_domain(x, y, domain)
    chosen = np.empty(3)
    scores: list[dict[float, float]] = [dict() for _ in range(3)]
    for lam in SMOOTHNESS_GRID:
        sq = np.zeros(3)
        cnt = np.zeros(3)
        for f in range(int(fold.max()) + 1):
            train = fold != f
            test = ~train
            xt = x.copy()
            xt[test] = np.nan    # held out of every channel
            try:
                fit = monotone_tone_curves(xt, y, smoothness=lam, degree=degree,
                                           domain=domain, weights=w)
            except CalibrationError:
                continue
            pred = fit(np.where(np.isnan(x[test]), 0.0, x[test]))
            err = (pred - y[test]) ** 2
            valid = np.isfinite(x[test]) & np.isfinite(y[test])
            sq += np.where(valid, err, 0.0).sum(axis=0)
            cnt += valid.sum(axis=0)
        for k in range(3):
            scores[k][lam] = float(np.sqrt(sq[k] / max(cnt[k], 1)))
    for k in range(3):
        chosen[k] = min(scores[k], key=scores[k].__getitem__)
    coefs = np.empty((3, degree + 1))
    for k in range(3):
        fit = monotone_tone_curves(x, y, smoothness=float(chosen[k]), degree=degree,
                                   domain=domain, weights=w)
        coefs[k] = fit.coefficients[k]
    out = MonotonePolynomial(coefficients=coefs, domain=domain)
    # the cross-validated fit says what it chose (an attribute the plain fit has not: read
    # with getattr by the pipeline's diagnostics)
    out.smoothness = chosen.tolist()  # type: ignore[attr-defined]
    validation = [{str(k): v for k, v in sc.items()} for sc in scores]
    out.validation = validation  # type: ignore[attr-defined]
    return out


class _ToneQP:
    """The parametrised QP of Eq. 9: ``min ||U c - z||²  s.t.  D c >= 0``.

    With ``H = Bᵀ B + λ' R = Uᵀ U`` and ``z = U⁻ᵀ Bᵀ y`` the objective equals the one of
    Eq. 9 up to a constant; ``U`` and ``z`` are cvxpy parameters, so the problem is
    compiled once and re-solved for every channel and sample set.
    """

    def __init__(self, degree: int):
        import cvxpy as cp

        n = degree + 1
        self.c = cp.Variable(n)
        self.u = cp.Parameter((n, n))
        self.z = cp.Parameter(n)
        dmat = bernstein_basis(_GRID, degree - 1) @ _derivative_matrix(degree, 1)
        dmat /= np.abs(dmat).max()
        self.problem = cp.Problem(cp.Minimize(cp.sum_squares(self.u @ self.c - self.z)),
                                  [dmat @ self.c >= 0])

    def solve(self, h: np.ndarray, q: np.ndarray) -> np.ndarray:
        import cvxpy as cp

        scale = float(np.trace(h)) / h.shape[0]
        h = h / scale
        q = q / scale
        u = np.linalg.cholesky(h + 1e-12 * np.eye(h.shape[0])).T
        self.u.value = u
        self.z.value = np.linalg.solve(u.T, q)
        for solver in ("CLARABEL", "OSQP", "SCS"):
            try:
                # no warm start: the problem is shared by every fit in the process, so a
                # warm start made a model depend on the fits before it (by up to 3e-5)
                self.problem.solve(solver=solver, warm_start=False)
            except (cp.error.SolverError, ValueError):
                continue
            if self.problem.status in ("optimal", "optimal_inaccurate") and \
                    self.c.value is not None:
                return np.asarray(self.c.value, dtype=np.float64)
        raise CalibrationError("the monotone tone-curve QP (Gong et al. Eq. 9) could not be "
                               "solved by CLARABEL, OSQP or SCS")


_QP_CACHE: dict = {}


def _qp(degree: int) -> _ToneQP:
    if degree not in _QP_CACHE:
        _QP_CACHE[degree] = _ToneQP(degree)
    return _QP_CACHE[degree]


def monotone_tone_curves(x: npt.ArrayLike, y: npt.ArrayLike, *, smoothness: float = SMOOTHNESS,
                         degree: int = DEGREE, domain: npt.ArrayLike | None = None,
                         weights: npt.ArrayLike | None = None,
                         folds: npt.ArrayLike | None = None) -> MonotonePolynomial:
    """Fit per-channel monotone smooth polynomials ``y_k ≈ f_k(x_k)`` ([Gong2018] Eq. 9).

    For each channel ``k`` solves the quadratic programme of [Gong2018] §3.3, Eq. 9::

        min Σ_i w_i (f_k(x_ik) - y_ik)² + λ ∫ f_k''(x)² dx   s.t.   f_k'(x) >= 0

    with ``f_k`` a polynomial of degree 7 in the Bernstein basis on the domain
    ``[lo_k, hi_k]`` and ``f_k' >= 0`` imposed on 101 points of it.  Used for the forward
    tone curves (``x = M ρ``, ``y = P``) and for the inverse curves of §3.5
    (``x = P``, ``y = M ρ``).

    Parameters
    ----------
    x, y : array_like
        ``(n, 3)`` inputs and targets.  NaN entries (of either) are left out of their
        channel's fit.
    smoothness : float or "auto"
        λ of Eq. 9 (default 1e-5, as in [Gong2018]), for ``x`` and ``y`` on a unit scale;
        ``"auto"``: per channel the value of ``SMOOTHNESS_GRID`` with the lowest 5-fold
        cross-validated error (seeded folds), kept in ``.smoothness``/``.validation``.
    degree : int
        Polynomial degree (7 in [Gong2018]).
    domain : array_like, optional
        ``(3, 2)`` input ranges; default ``[min(0, min x_k), max x_k]``.
    weights : array_like, optional
        ``(n,)`` non-negative sample weights (default 1).
    folds : array_like, optional
        ``(n,)`` labels of the cross-validation folds for ``"auto"`` (e.g. the scene of
        each sample: leave-one-scene-out); default 5 seeded random folds.

    Returns
    -------
    MonotonePolynomial

    Raises
    ------
    CalibrationError
        Fewer than ``degree + 2`` usable samples in a channel, or a channel whose inputs do
        not vary.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise InputError(f"tone-curve data must be two (n, 3) arrays, got {x.shape}, {y.shape}")
    w = np.ones(x.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    if isinstance(smoothness, str):
        if smoothness != "auto":
            raise InputError(f"smoothness must be a number or 'auto', got {smoothness!r}")
        return _cross_validated(x, y, w, degree, domain, folds)
    domain = _fit_domain(x, y, domain)
    coefs = np.empty((3, degree + 1))
    r = _smoothness_gram(degree)
    qp = _qp(degree)
    for k in range(3):
        ok = np.isfinite(x[:, k]) & np.isfinite(y[:, k]) & (w > 0)
        lo, hi = domain[k]
        if ok.sum() < degree + 2 or not np.isfinite(hi - lo) or hi - lo <= 1e-9:
            raise CalibrationError(f"channel {k}: {int(ok.sum())} usable samples over the "
                                   f"range [{lo:.4g}, {hi:.4g}]; a tone curve needs at least "
                                   f"{degree + 2} samples with varying values")
        t = np.clip((x[ok, k] - lo) / (hi - lo), 0.0, 1.0)
        b = bernstein_basis(t, degree)
        bw = b * w[ok, None]
        # λ ∫ f''(x)² dx = λ / (hi - lo)³ ∫ f''(t)² dt
        h = b.T @ bw + smoothness / (hi - lo) ** 3 * r
        q = bw.T @ y[ok, k]
        coefs[k] = qp.solve(h, q)
    return MonotonePolynomial(coefficients=coefs, domain=domain)
