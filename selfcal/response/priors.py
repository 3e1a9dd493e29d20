"""The priors added to the Eq. 8 normal equations, each a named term with its weight.

None of them is [Lin2011]'s (§5 solves Eq. 8 by plain least
squares and fixes the exponential ambiguity with the camera's exposure values); each
exists for one reason:

- :attr:`PriorTerms.coefficient_precision`, the *PCA-variance prior* c_n ~ N(0, λ_n / w):
  the data leave the bend of the never-observed last codes (and, with fewer than two known
  times, the exponential ambiguity) open; the curve database's variances decide it.  It is
  on whenever ``prior_weight > 0``, whatever the number of known times.  The built-in
  basis carries its PCA variances; a basis file without them (Grossberg & Nayar's
  ``invemor.txt`` stores no variances) gets λ_n estimated by
  :func:`estimated_coefficient_variance` (ours: the second moments of the coefficients
  of selfcal's documented curve family projected on that basis).
  With fewer than two different known times it is centred at :func:`ambiguity_centre`
  instead (ours): there it also chooses the exponent γ, and the basis mean
  chooses it too flat for common encodings.
- :attr:`PriorTerms.ridge`: only with ``prior_weight = 0`` (it replaces the
  PCA-variance prior, never adds to it); it keeps the coefficient block invertible.
- :class:`WhiteContinuation`, the *white-continuation prior*: beyond the brightest valid
  sample f⁻¹(1) = 1 is pure extrapolation; the straight continuation of the observed curve
  should meet g(1) = 0, which removes the almost free shift of g over the observed range.
- :class:`ExposurePrior`, for ``refine_exposures``: shutters are inaccurate, so the given
  times are a Gaussian prior on the log exposures rather than fixed values.

The censored white-threshold rows are data rows, not a prior: see :mod:`.equations`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

#: Width (normalised codes) of the stretch below the brightest valid sample whose slope the
#: white-continuation prior continues to g(1).
WHITE_CONTINUATION_WINDOW = 8.0 / 255.0


@dataclass(frozen=True, eq=False)
class WhiteContinuation:
    """The white-continuation term of one channel: J(c) = ``a · c + b0``, prior J ~ N(0, σ²).

    J = g(top) + s·(1 − top), s = (g(top) − g(top − w)) / w, is how far the straight
    continuation of the observed curve from the brightest valid sample ``top`` misses
    g(1) = 0.
    """

    channel: int
    a: np.ndarray           # (N,) coefficients of J in c_channel
    b0: float               # J at c = 0 (the basis mean)


def white_continuation_terms(values, valid, basis, N: int,
                             window: float = WHITE_CONTINUATION_WINDOW):
    """One :class:`WhiteContinuation` per channel with a valid sample (selfcal's).

    Beyond the brightest valid sample (clipping keeps the last codes unobserved) the
    normalisation f⁻¹(1) = 1 is pure extrapolation, and a basis that can bend sharply in
    the last codes makes a constant shift of g over the observed range (the scale of f⁻¹)
    almost free.  A Gaussian prior on J, how far the straight continuation of the observed
    curve misses g(1) = 0, removes that freedom.
    """
    grid = basis.intensity
    terms = []
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
        terms.append(WhiteContinuation(c, a, b0))
    return tuple(terms)


#: Curves of :mod:`.curve_family` projected on a basis without PCA variances, and their
#: seed (:func:`estimated_coefficient_variance`).
FAMILY_CURVES = 1000
FAMILY_SEED = 20110102
#: Multiplier of ``prior_weight`` for a basis whose variances are estimated
#: (:func:`estimated_coefficient_variance`, ours); 0 switches the estimate off and the
#: ridge acts instead.  Chosen on the tuning split (docs/decisions.md, "Prior scale for a
#: basis without PCA variances: ×3").
ESTIMATED_PRIOR_SCALE = 3.0
#: κ of the projection weights ``(rms f⁻¹ + κ)²``, as the built-in basis' PCA
#: (:func:`selfcal.response.basis.log_pca_basis`).
_WEIGHT_OFFSET = 0.05


#: The standard encodings whose basis coefficients, averaged, centre the PCA-variance prior
#: when fewer than two different exposure times are known (:func:`ambiguity_centre`);
#: ``"gamma p"`` is the power law ``E^(1/p)``.  Chosen on the tuning split
#: (docs/decisions.md, "The prior's centre when fewer than two times are known: sRGB and
#: Rec.709").
AMBIGUITY_CENTRE_CURVES = ("srgb", "rec709")


def _standard_inverse(name: str, grid: np.ndarray) -> np.ndarray:
    """f⁻¹ on ``grid`` of one of :data:`AMBIGUITY_CENTRE_CURVES`."""
    from .curve_family import invert_curve, rec709_oetf, srgb_oetf

    if name.startswith("gamma "):
        return np.power(grid, float(name.split()[1]))
    return invert_curve({"srgb": srgb_oetf, "rec709": rec709_oetf}[name](), grid)


@functools.lru_cache(maxsize=8)
def _centre_of(basis, N: int, names: tuple) -> np.ndarray:
    grid = basis.intensity
    coeffs = [basis.fit_inverse_response(grid, _standard_inverse(name, grid), N)
              for name in names]
    centre = np.mean(coeffs, axis=0)
    centre.setflags(write=False)
    return centre


def ambiguity_centre(basis, N: int) -> np.ndarray:
    """Centre μ of the PCA-variance prior when the exponential ambiguity is left to it (ours).

    With fewer than two different known exposure times, Eq. 8 of [Lin2011] fixes f⁻¹ only
    up to an exponent γ (§5), and the prior c_n ~ N(μ_n, λ_n / w) chooses it: the γ whose
    (f⁻¹)^γ is least costly.  Centred at the basis mean (μ = 0, the prior of every other
    solve), common encodings come out too flat (γ < 1).  Centred here instead: the
    mean of the basis coefficients of the standard encodings
    :data:`AMBIGUITY_CENTRE_CURVES` (their best ``N``-component fits), so that a curve
    shaped like them comes out with γ ≈ 1.  No DoRF data goes into it (DoRF may not be
    redistributed); the curves were chosen on the tuning split (docs/decisions.md, "The
    prior's centre when fewer than two times are known: sRGB and Rec.709").

    Parameters
    ----------
    basis : ResponseBasis
        Log-domain basis (Eq. 7).
    N : int
        Number of components used.

    Returns
    -------
    ndarray, shape (N,)
        Read-only; cached per basis and ``N``.
    """
    return _centre_of(basis, int(N), tuple(AMBIGUITY_CENTRE_CURVES))


@functools.lru_cache(maxsize=4)
def _family_curves(grid_bytes: bytes, n_curves: int, seed: int) -> np.ndarray:
    """f⁻¹ of ``n_curves`` curves of :mod:`.curve_family` on a grid (cached: ~1.5 s each)."""
    from .curve_family import generate_inverse_curves

    grid = np.frombuffer(grid_bytes, dtype=np.float64)
    _, inverse, _ = generate_inverse_curves(n_curves, intensity=grid, seed=seed)
    inverse.setflags(write=False)
    return inverse


def estimated_coefficient_variance(basis, N: int, *, n_curves: int = FAMILY_CURVES,
                                   seed: int = FAMILY_SEED) -> np.ndarray:
    """λ_n for a log-domain basis that carries no PCA variances (selfcal's estimate).

    A PCA basis file such as Grossberg & Nayar's ``invemor.txt`` (PAMI 2004) gives the
    components in order but not the variance of the curve database along each, and the
    PCA-variance prior c_n ~ N(0, λ_n / w) needs those.  Without DoRF (which may not be
    shipped), the curves at hand are selfcal's documented family
    (:mod:`.curve_family`, the curves the built-in basis was made from): each is fitted
    with the first ``N`` components by weighted log-domain least squares (weights
    ``(rms f⁻¹ + κ)²`` per intensity, as :func:`~selfcal.response.basis.log_pca_basis`),
    and λ_n is the mean square of its coefficient n.  The prior is centred at the basis
    mean (c = 0), so the second moment, not the variance about the family's mean, is what
    it needs.  On ``invemor.txt`` this replaces the ridge (``python3 -m bench.basis
    --calibrate heldout``; docs/decisions.md, "Prior scale for a basis without PCA
    variances: ×3").

    Parameters
    ----------
    basis : ResponseBasis
        Log-domain (Eq. 7; a linear one converted by ``to_log_domain``).
    N : int
        Number of components used.
    n_curves, seed : int
        How many family curves, and their seed.

    Returns
    -------
    ndarray, shape (N,)
        Positive second moments (floored at 1e-12 of the largest).
    """
    grid = np.ascontiguousarray(basis.intensity, dtype=np.float64)
    f = _family_curves(grid.tobytes(), int(n_curves), int(seed))
    eps = basis.log_floor if basis.log_floor > 0 else 1e-5
    g = np.log(np.maximum(f, eps)) - basis.mean                        # (J, K)
    w = np.sqrt(np.mean(f ** 2, axis=0)) + _WEIGHT_OFFSET               # (K,)
    H = basis.components[:N].T * w[:, None]                             # (K, N)
    coeffs = np.linalg.lstsq(H, (g * w).T, rcond=None)[0]               # (N, J)
    lam = np.mean(coeffs ** 2, axis=1)
    return np.maximum(lam, 1e-12 * max(float(lam.max()), 1e-300))


def pca_variance_precision(basis, N: int, prior_weight: float,
                           estimated_scale: float = ESTIMATED_PRIOR_SCALE):
    """Precision ``prior_weight / λ_n`` of the PCA-variance prior, or None when it is off.

    λ_n are the basis' PCA variances; for a basis without them (a file such as
    ``invemor.txt``) they are estimated by :func:`estimated_coefficient_variance` and the
    weight is multiplied by ``estimated_scale`` (``SolverOptions.estimated_prior_scale``,
    default :data:`ESTIMATED_PRIOR_SCALE`).  None when ``prior_weight`` is
    0 (or N is 0), or for such a basis when that scale is 0: the ridge then takes its
    place.
    """
    if not prior_weight > 0 or N <= 0:
        return None
    ev = getattr(basis, "explained_variance", None)
    if ev is not None and len(ev) >= N:
        return prior_weight / np.asarray(ev[:N], dtype=float)
    if not estimated_scale > 0:
        return None
    return prior_weight * estimated_scale / estimated_coefficient_variance(basis, N)


@dataclass(frozen=True, eq=False)
class ExposurePrior:
    """Gaussian prior log exposure ~ N(log given time, σ²) at the frames with a given time.

    Used with ``refine_exposures`` only: shutters are inaccurate, so the given times are
    evidence, not constraints.  Same units as the data term (noise-scaled weights).
    """

    mean: np.ndarray        # (F,) log given times (NaN where unknown)
    frames: np.ndarray      # (F,) bool: frames with a given time
    sigma: float            # std in log units

    def add_to_normal(self, Q: np.ndarray, q: np.ndarray, N: int) -> None:
        """Add the prior to the full system (exposure columns after the 3·N coefficients)."""
        kk = np.flatnonzero(self.frames)
        prior_w = 1.0 / self.sigma ** 2
        Q[3 * N + kk, 3 * N + kk] += prior_w
        q[3 * N + kk] += prior_w * self.mean[kk]

    def add_to_exposure_block(self, Q: np.ndarray, q: np.ndarray) -> None:
        """Add the prior to the exposure block alone (the exposure step of the alternation).

        The same prior as :meth:`add_to_normal`; the right-hand side is written
        ``mean / σ²`` here and ``(1 / σ²) · mean`` there, as it always was (the two can
        differ in the last bit, and the results must not change).
        """
        kk = np.flatnonzero(self.frames)
        Q[kk, kk] += 1.0 / self.sigma ** 2
        q[kk] += self.mean[kk] / self.sigma ** 2


@dataclass(frozen=True, eq=False)
class PriorTerms:
    """Every prior of the solve, with its weight (see the module docstring for why each).

    Attributes
    ----------
    coefficient_precision : ndarray (N,) or None
        PCA-variance prior c_n ~ N(0, λ_n / prior_weight), the same for every channel (λ_n
        estimated for a basis without variances, :func:`pca_variance_precision`); None
        when ``prior_weight`` is 0, and then ``ridge`` acts instead.
    ridge : float
        Ridge on the coefficients relative to the mean diagonal of their data block; only
        when ``coefficient_precision`` is None.
    white_continuation : tuple of WhiteContinuation
        The white-continuation prior, one term per channel.
    white_continuation_sigma : float
        Its std (log units).
    exposure : ExposurePrior
        The prior on the log exposures; added only when the solve refines the given times.
    coefficient_mean : ndarray (N,) or None
        Centre μ of the PCA-variance prior, the same for every channel; None: 0, the basis
        mean.  Set (to :func:`ambiguity_centre`) only when fewer than two different
        exposure times are known.
    """

    coefficient_precision: np.ndarray | None
    ridge: float
    white_continuation: tuple
    white_continuation_sigma: float
    exposure: ExposurePrior
    coefficient_mean: np.ndarray | None = None

    def add_to(self, Q: np.ndarray, q: np.ndarray, N: int, exposure_prior: bool) -> None:
        """Add the priors to the normal equations ``Q x = q`` in place."""
        self.add_coefficient_prior(Q, N)
        if self.coefficient_mean is not None and self.coefficient_precision is not None:
            q[:3 * N] += np.tile(self.coefficient_precision * self.coefficient_mean, 3)
        self.add_white_continuation(Q, q, N)
        if exposure_prior:
            self.exposure.add_to_normal(Q, q, N)

    def add_coefficient_prior(self, Q: np.ndarray, N: int) -> None:
        """The PCA-variance prior, or the ridge for a basis without variances."""
        scale = np.trace(Q[:3 * N, :3 * N]) / (3 * N) if N else 1.0
        if self.coefficient_precision is not None:
            # Gaussian prior c_n ~ N(0, λ_n) from the curve database's PCA variances: it
            # decides what the data leave open (the bend in the never-observed last codes)
            Q[:3 * N, :3 * N] += np.diag(np.tile(self.coefficient_precision, 3))
        else:
            Q[:3 * N, :3 * N] += self.ridge * scale * np.eye(3 * N)

    def add_white_continuation(self, Q: np.ndarray, q: np.ndarray, N: int) -> None:
        """The white-continuation prior J_c ~ N(0, σ²) of each channel."""
        sigma = self.white_continuation_sigma
        for term in self.white_continuation:
            c, a, b0 = term.channel, term.a, term.b0
            blk = slice(c * N, (c + 1) * N)
            Q[blk, blk] += np.outer(a, a) / sigma ** 2
            q[blk] -= a * b0 / sigma ** 2
