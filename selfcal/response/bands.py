"""Confidence bands on the fitted inverse response f⁻¹ (selfcal's own).

The solve of Lin et al. [Lin2011] (§5, Eq. 7–8) gives one curve per channel; nothing in
the paper says how far to trust it.  This module measures the spread of the curve the same
data could have given, per channel and per point of the basis grid, as the standard
deviation σ_g of g = log f⁻¹ (Eq. 7's domain).  The band at a level is then
``f⁻¹ · exp(±z σ_g)`` with ``z`` the normal quantile (:func:`band_from_sigma`); at
I = 1 σ_g is 0 (f⁻¹(1) = 1 is the normalisation of Eq. 7).

Two estimates (the covariance is the default, chosen on the tuning split:
docs/decisions.md, "Curve bands: the covariance, σ_t = 0.02, σ_top = 0.03"):

``"bootstrap"``
    A one-step bootstrap [Efron1993]_ over sample locations: the weighted normal
    equations of the final robust fit are re-formed with each location's rows counted by a multinomial
    draw (a location enters up to 3·(F−1) correlated rows — channels and frame pairs —
    so locations, not rows, are the independent units), and solved again, curves and
    exposures jointly, with the given log times as a prior whose mean is drawn from
    N(log t, σ_t²) in every replicate: the exposure uncertainty (shutters are
    inaccurate) is folded into the curve.  The IRLS weights and the monotone
    constraint are held at the fit's (one step: no re-iteration), which keeps it cheap.
    The means of the coefficient and white-continuation priors are drawn from the priors
    too (:func:`_perturb_prior_means`).
``"covariance"`` (the default)
    The inverse of the same normal matrix (data, priors, exposure prior of variance σ_t²
    on the held log times), marginalised to the coefficients: the robust fit's
    covariance, which treats every row as independent.

To both, an extrapolation term is added in quadrature (:func:`_top_sigma`): the shift of the
curve below the brightest valid sample, which the data do not see.

With fewer than two different known times, a third term (:func:`ambiguity_sigma`, issue 35):
Eq. 8 then fixes f⁻¹ only up to the exponential ambiguity of [Lin2011] §5 (f⁻¹ → (f⁻¹)^γ,
exposures → exposures^γ) and the prior chooses γ (:func:`.priors.ambiguity_centre`).  Neither
estimate above sees how wrong that choice can be -- the prior's precision pins γ to a
percent or so, while camera curves stray from the prior's centre by far more -- so the band
would describe the scatter around the prior's choice, not the ambiguity.  The term is the
log-domain effect of γ, |log f⁻¹| · σ_γ, with σ_γ = σ₀ √(1 + E) (:func:`ambiguity_gamma_sigma`):
E is how far the fitted curve lies from the prior's centre in the prior's own standard
deviations, and σ₀ (:data:`AMBIGUITY_LOG_GAMMA_SIGMA`) is measured on the tuning split.

The threshold rows of the solve (:class:`.equations.ThresholdRows`) are left out of both:
they are few and move the curve, not its spread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import norm

from ..errors import InputError
from .solver import CODE_NOISE, SolverOptions
from .equations import NormalEquations, build_pair_rows
from .priors import ExposurePrior, PriorTerms, pca_variance_precision, white_continuation_terms

#: Band estimate used at calibration (chosen on the tuning split, see the module docstring).
DEFAULT_BAND_METHOD = "covariance"
#: Bootstrap replicates (each one a build of the normal equations).
DEFAULT_REPLICATES = 64
#: Std of a given time's log (shutter inaccuracy), chosen on the tuning split (see
#: the module docstring).
EXPOSURE_LOG_SIGMA = 0.02
#: Std of the shift of log f⁻¹ below the brightest valid sample (:func:`_top_sigma`),
#: chosen on the tuning split.
TOP_LOG_SIGMA = 0.03
#: σ₀ of :func:`ambiguity_gamma_sigma` (σ_γ, the std of log γ -- the exponent by which the
#: fitted f⁻¹ misses the true one -- is σ₀ √(1 + E)), chosen on the tuning split: the
#: smallest of the candidates whose 90 % band covers the true curve on ≥ 90 % of the (code,
#: channel, stack) there, with one known time and with none (``python3 -m
#: bench.response_unknown --split tuning --step 5 --known one,none --band --gamma-sigma S``;
#: docs/decisions.md, "The band with fewer than two known times: σ_γ = 0.10 √(1 + E)").
AMBIGUITY_LOG_GAMMA_SIGMA = 0.10
#: The most σ_γ can be: the largest |log γ| on the tuning split (≈ 1.0, a DoRF curve the
#: prior missed by γ ≈ 2.7) over the 90 % quantile 1.645.  Without it a curve unlike any
#: camera's (E in the hundreds) got a band a hundred times f⁻¹ wide, far beyond any γ seen.
AMBIGUITY_LOG_GAMMA_SIGMA_MAX = 0.6
#: Floor of f⁻¹ before the log in :func:`ambiguity_sigma` (the basis' log floor).
_LOG_FLOOR = 1e-5
#: Precision of a log exposure held as the additive gauge (no time given).
_GAUGE_PRECISION = 1e10
#: The body of the curve, for the verdict and ``selfcal show``: normalised codes 0.1 … 0.9.
BODY = (0.1, 0.9)
#: A 90 % band wider than this (relative half-width, max over the body and channels) makes
#: the verdict doubtful; chosen on the tuning split (``python3 -m bench.uncertainty
#: --split tuning``; docs/decisions.md, "Curve bands: the covariance, σ_t = 0.02,
#: σ_top = 0.03").
BAND_TOO_WIDE = 0.25


@dataclass(frozen=True)
class BandSettings:
    """How :func:`curve_band` estimates the band."""

    method: str = DEFAULT_BAND_METHOD
    replicates: int = DEFAULT_REPLICATES
    exposure_log_sigma: float = EXPOSURE_LOG_SIGMA
    seed: int = 0
    top_log_sigma: float | None = None      # None: TOP_LOG_SIGMA (read at call time)


def _top_sigma(values, valid, grid, sigma) -> np.ndarray:
    """The extrapolation term of σ_g on the grid, per channel (ours).

    Between the brightest valid sample ``top`` of a channel and I = 1 the curve is never
    observed, yet f⁻¹(1) = 1 anchors the whole curve there: how far the observed part sits
    from the anchor (a shift of g, i.e. the scale of f⁻¹) is set by the priors and the
    threshold rows, not by the samples, and neither the bootstrap nor the fit's
    covariance sees how wrong those can be.  This term is σ_top below ``top`` and falls
    linearly to 0 at I = 1; σ_top (:data:`TOP_LOG_SIGMA`) is measured on the tuning split.
    """
    out = np.zeros((grid.size, 3))
    for c in range(3):
        vals = values[..., c][valid]
        top = float(min(vals.max(), grid[-2])) if vals.size else 0.0
        out[:, c] = sigma * np.clip((1.0 - grid) / max(1.0 - top, 1e-6), 0.0, 1.0)
    return out


def curve_band(samples, masks, basis, coefficients, log_exposures, known, *,
               options: SolverOptions, settings: BandSettings = BandSettings()) -> np.ndarray:
    """σ_g = std of log f⁻¹ on the basis grid, per channel, from a fitted solve.

    Parameters
    ----------
    samples : SampleSet
        The samples the solve was fitted to (usable frames only).
    masks : dict
        Their ``"clipped"`` and ``"saturated"`` masks.
    basis : ResponseBasis
        The log-domain basis of the fit.
    coefficients : ndarray, shape (3, N)
        The fitted Eq. 7 coefficients.
    log_exposures : ndarray, shape (F,)
        The fitted log exposures.
    known : ndarray of bool, shape (F,)
        Frames with a given time (their log exposure gets the prior of σ_t); the others
        are free, except one held as the additive gauge when no time is given.
    options : SolverOptions
        The settings the solve was fitted with (the calibration's ``options.solver``, its
        ``n_components`` capped at the basis' size): the band re-forms that solve's
        normal equations -- pairs (``max_rank_gap``), Huber weights (``huber_k``), priors
        (``prior_weight``, ``estimated_prior_scale``, ``ridge``,
        ``white_continuation_sigma``) -- so that it is the spread of the curve that was
        fitted.  (β and the clip margin reach it through ``masks``.)
    settings : BandSettings

    Returns
    -------
    ndarray, shape (K, 3)
        σ_g on ``basis.intensity``; 0 at I = 1.
    """
    if settings.method not in ("bootstrap", "covariance"):
        raise InputError(f"unknown band method {settings.method!r} (bootstrap or covariance)")
    N = int(options.n_components)
    values = samples.values
    F = values.shape[0]
    valid = ~(masks["clipped"] | masks["saturated"])
    K = np.asarray(log_exposures, dtype=float)
    order = np.lexsort((values.mean(axis=(1, 2)), K))
    rows = build_pair_rows(values, valid, order, K, basis, N, options.max_rank_gap)
    normal = NormalEquations(rows.dH, rows.rhs, rows.pa, rows.pb, F, N)
    x = np.concatenate([np.asarray(coefficients, float).ravel(), K])
    w = _row_weights(normal, rows, basis, coefficients, x, options.huber_k)
    priors = PriorTerms(
        coefficient_precision=pca_variance_precision(basis, N, options.prior_weight,
                                                     options.estimated_prior_scale),
        ridge=options.ridge,
        white_continuation=white_continuation_terms(values, valid, basis, N),
        white_continuation_sigma=options.white_continuation_sigma,
        exposure=ExposurePrior(mean=K, frames=np.zeros(F, bool), sigma=1.0))
    precision = _exposure_precision(np.asarray(known, bool), K, settings.exposure_log_sigma)
    H = basis.components[:N].T                                  # (K grid, N)
    top = _top_sigma(values, valid, basis.intensity, TOP_LOG_SIGMA if
                     settings.top_log_sigma is None else settings.top_log_sigma)
    return np.sqrt(_statistical_sigma(normal, rows, w, priors, precision, K, H, N,
                                      values.shape[1], settings) ** 2 + top ** 2)


def _statistical_sigma(normal, rows, w, priors, precision, K, H, N, n_locations, settings):
    """σ_g from the data, the priors and the exposures: the bootstrap or the covariance."""
    if settings.method == "covariance":
        Q, q = normal(w)
        priors.add_to(Q, q, N, exposure_prior=False)
        Q[3 * N:, 3 * N:] += np.diag(precision)
        cov = np.linalg.pinv(0.5 * (Q + Q.T), hermitian=True)
        var = np.stack([np.einsum("kn,nm,km->k", H, cov[c * N:(c + 1) * N, c * N:(c + 1) * N],
                                  H) for c in range(3)], axis=-1)
        return np.sqrt(np.maximum(var, 0.0))
    return _bootstrap_sigma(normal, rows, w, priors, precision, K, H, N, n_locations,
                            settings)


def _row_weights(normal, rows, basis, coefficients, x, huber_k: float) -> np.ndarray:
    """The robust fit's row weights at its solution: slope noise and Huber (as the solver,
    with its ``huber_k``)."""
    N = coefficients.shape[1]
    grid = basis.intensity
    g_grid = basis.mean[None, :] + coefficients @ basis.components[:N]
    dg = np.gradient(g_grid, grid, axis=1)
    m = rows.pa.size
    var = np.empty(3 * m)
    for c in range(3):          # np.interp: the solver's interpolation matrices, applied
        sa = np.interp(rows.Ia[:, c], grid, dg[c])
        sb = np.interp(rows.Ib[:, c], grid, dg[c])
        var[c * m:(c + 1) * m] = CODE_NOISE ** 2 * (sa ** 2 + sb ** 2)
    var = np.maximum(var, 0.05 * np.median(var))
    u = normal.residual(x) / np.sqrt(var)
    scale = max(1.4826 * np.median(np.abs(u)) + 1e-12, 1e-3)
    robust = np.minimum(1.0, huber_k * scale / np.maximum(np.abs(u), 1e-12))
    return robust / (var * scale ** 2)


def _exposure_precision(known, K, sigma) -> np.ndarray:
    """Prior precision of each log exposure: 1/σ_t² where a time was given, the gauge's
    huge where none was (the frame nearest 0, as the solver holds), 0 elsewhere."""
    precision = np.where(known, 1.0 / max(sigma, 1e-6) ** 2, 0.0)
    if not known.any():
        precision[int(np.argmin(np.abs(K)))] = _GAUGE_PRECISION
    return precision


def _bootstrap_sigma(normal, rows, w, priors, precision, K, H, N, n_locations,
                     settings) -> np.ndarray:
    """σ_g from the one-step bootstrap over sample locations (see the module docstring)."""
    rng = np.random.default_rng([int(settings.seed), 26])
    loc = np.concatenate([p[2] for p in rows.pairs])            # location of each row
    B = max(int(settings.replicates), 2)
    sigma_t = np.sqrt(np.divide(1.0, precision, out=np.zeros_like(precision),
                                where=precision > 0))
    g = np.empty((B, H.shape[0], 3))
    for b in range(B):
        counts = rng.multinomial(n_locations, np.full(n_locations, 1.0 / n_locations))
        Q, q = normal(w * np.tile(counts[loc], 3))
        priors.add_to(Q, q, N, exposure_prior=False)
        _perturb_prior_means(q, priors, N, rng)
        mean = K + sigma_t * rng.standard_normal(K.size)
        Q[3 * N:, 3 * N:] += np.diag(precision)
        q[3 * N:] += precision * mean
        Q = 0.5 * (Q + Q.T)
        try:
            z = np.linalg.solve(Q, q)
        except np.linalg.LinAlgError:
            z = np.linalg.lstsq(Q, q, rcond=None)[0]
        g[b] = (H @ z[:3 * N].reshape(3, N).T)
    return g.std(axis=0, ddof=1)


def _perturb_prior_means(q, priors, N, rng) -> None:
    """Draw the means of the coefficient and white-continuation priors from the priors
    themselves (randomise-then-optimise: for a linear Gaussian model, perturbing the data
    and the prior means together samples the posterior; the bootstrap alone leaves out
    what the priors are unsure of, e.g. the scale of f⁻¹ beyond the brightest sample)."""
    if priors.coefficient_precision is not None:
        q[:3 * N] += (np.sqrt(np.tile(priors.coefficient_precision, 3))
                      * rng.standard_normal(3 * N))
    sigma = priors.white_continuation_sigma
    for term in priors.white_continuation:
        q[term.channel * N:(term.channel + 1) * N] += term.a * rng.standard_normal() / sigma


def ambiguity_sigma(inverse, sigma_gamma: float) -> np.ndarray:
    """σ of log f⁻¹ that the exponential ambiguity leaves (ours; issue 35).

    With fewer than two different known exposure times, Eq. 8 of [Lin2011] is blind to
    f⁻¹ → (f⁻¹)^γ with every exposure raised to γ (§5), and the prior chooses γ.  Then
    log f⁻¹ → γ · log f⁻¹: a relative error ε = log γ of γ moves log f⁻¹ by
    ε · log f⁻¹ to first order, so a spread σ_γ of log γ gives ``|log f⁻¹(I)| · σ_γ`` at
    each I -- 0 at I = 1 (f⁻¹(1) = 1, the normalisation of Eq. 7 and of the scores), and
    largest in the shadows.

    Parameters
    ----------
    inverse : ndarray, shape (K, 3)
        The fitted f⁻¹ on its grid (floored at 1e-5 before the log, as the basis' own
        floor, so the term stays finite at I = 0).
    sigma_gamma : float
        σ_γ, the std of log γ (:func:`ambiguity_gamma_sigma`).

    Returns
    -------
    ndarray, shape (K, 3)
    """
    logs = np.log(np.maximum(np.asarray(inverse, dtype=float), _LOG_FLOOR))
    return float(sigma_gamma) * np.abs(logs)


def ambiguity_gamma_sigma(basis, coefficients, n_components: int,
                          sigma0: float = AMBIGUITY_LOG_GAMMA_SIGMA) -> tuple[float, float]:
    """σ_γ, the std of log γ the prior's choice of γ leaves: σ₀ √(1 + E) (ours; issue 35).

    The data cannot narrow γ (for power-law-like curves it is not in the data at all:
    docs/decisions.md, "γ with unknown times is not read from the noise"); how far the
    prior's choice can be off is a matter of the curves cameras have.  It is small for a
    camera whose curve is shaped like the prior's centre (:func:`.priors.ambiguity_centre`:
    the least-costly γ is then about right) and grows with how unlike it the curve is.  E
    measures that: the squared distance of the fitted coefficients from the centre in the
    PCA variances of the basis (``Σ_n (c_n − μ_n)² / λ_n``, the prior's own energy at unit
    weight, mean over the channels; λ estimated for a basis without variances, as
    :func:`.priors.pca_variance_precision`).  On the tuning split the curves the prior
    misses by γ ≈ 2 lie at E ≈ 6 … 17, the encodings it matches at E < 4.  σ₀
    (:data:`AMBIGUITY_LOG_GAMMA_SIGMA`) is the one constant tuned there; σ_γ is capped at
    :data:`AMBIGUITY_LOG_GAMMA_SIGMA_MAX`, the largest γ error seen there
    (:func:`gamma_sigma_of_energy`).

    Parameters
    ----------
    basis : ResponseBasis
    coefficients : ndarray, shape (3, N)
        The fitted Eq. 7 coefficients.
    n_components : int
    sigma0 : float, optional
        σ₀; default :data:`AMBIGUITY_LOG_GAMMA_SIGMA`.

    Returns
    -------
    sigma_gamma : float
        At most :data:`AMBIGUITY_LOG_GAMMA_SIGMA_MAX`.
    energy : float
        E.
    """
    from .priors import ambiguity_centre, estimated_coefficient_variance

    N = int(n_components)
    ev = getattr(basis, "explained_variance", None)
    lam = (np.asarray(ev[:N], dtype=float) if ev is not None and len(ev) >= N
           else estimated_coefficient_variance(basis, N))
    c = np.asarray(coefficients, dtype=float)[:, :N]
    energy = float(np.mean(np.sum((c - ambiguity_centre(basis, N)) ** 2 / lam, axis=1)))
    return gamma_sigma_of_energy(energy, sigma0), energy


def gamma_sigma_of_energy(energy: float, sigma0: float = AMBIGUITY_LOG_GAMMA_SIGMA) -> float:
    """σ_γ = min(σ₀ √(1 + E), :data:`AMBIGUITY_LOG_GAMMA_SIGMA_MAX`) (ours; issue 35).

    ``sigma0`` default :data:`AMBIGUITY_LOG_GAMMA_SIGMA`; the
    candidates it was chosen among are given here by ``bench.response_unknown
    --gamma-sigma``, from the E of each calibration's evidence.
    """
    return min(float(sigma0) * float(np.sqrt(1.0 + float(energy))),
               AMBIGUITY_LOG_GAMMA_SIGMA_MAX)


def band_from_sigma(inverse, log_sigma, level: float = 0.9):
    """``(lower, upper)`` of the two-sided band at ``level`` around ``inverse``.

    ``inverse · exp(∓z σ_g)``, z the standard normal quantile of (1 + level)/2: the band of
    g = log f⁻¹ is Gaussian (ours).
    """
    level = float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), not {level}")
    z = norm.ppf(0.5 + level / 2.0)
    s = np.asarray(log_sigma, dtype=float)
    inv = np.asarray(inverse, dtype=float)
    return inv * np.exp(-z * s), inv * np.exp(z * s)


def widest_band(intensity, inverse, log_sigma, level: float = 0.9, body=BODY) -> dict:
    """The widest relative half-width of the band over the body of the curve.

    Returns ``{"width": (upper − lower) / (2 f⁻¹), "channel": 0…2, "intensity": I}`` at the
    widest point of ``body`` (normalised codes), over the channels.
    """
    lower, upper = band_from_sigma(inverse, log_sigma, level)
    inside = (np.asarray(intensity) >= body[0]) & (np.asarray(intensity) <= body[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(inverse > 0, (upper - lower) / (2.0 * inverse), 0.0)
    rel = np.where(inside[:, None], rel, -np.inf)
    k, c = np.unravel_index(int(np.argmax(rel)), rel.shape)
    return {"width": float(rel[k, c]), "channel": int(c), "intensity": float(intensity[k])}


def band_reason(intensity, inverse, log_sigma, max_code: int):
    """A verdict reason when the 90 % band over the body is wider than
    :data:`BAND_TOO_WIDE`, with its number; else None."""
    wide = widest_band(intensity, inverse, log_sigma)
    if wide["width"] <= BAND_TOO_WIDE:
        return None, wide
    code = round(wide["intensity"] * max_code)
    return (f"the 90 % confidence band of f⁻¹ is ±{100 * wide['width']:.1f} % at code "
            f"{code} of the {'RGB'[wide['channel']]} channel (more than "
            f"±{100 * BAND_TOO_WIDE:.0f} % over the body of the curve): the stack does not "
            "pin the curve down there"), wide


def band_for_fit(samples, masks, basis, result, log_times, fit, warnings, *,
                 options: SolverOptions, seed: int = 0,
                 method: str = DEFAULT_BAND_METHOD) -> np.ndarray:
    """:func:`curve_band` of a :class:`.solver.SolveResult`, judged (:func:`judge_band`):
    the hook of the calibration.  Returns σ_g, (K, 3).

    ``options`` are the solver options the result was fitted with (see
    :func:`curve_band`; ``options.n_components`` the fit's N).

    When the solve left the exponential ambiguity to the prior
    (``result.ambiguity_prior``: fewer than two different known times),
    :func:`ambiguity_sigma` of the fitted curve is added in quadrature *after* the band is
    judged: the verdict's band reason says what the stack does not pin down, and the
    ambiguity has its own warning (:func:`.solver._ambiguity_warnings`), which a band
    reason on every such calibration would only repeat.  σ_γ and E
    (:func:`ambiguity_gamma_sigma`) join the verdict's evidence as
    ``ambiguity_gamma_sigma`` and ``ambiguity_energy``.
    """
    known = np.isfinite(np.asarray(log_times, dtype=float))
    log_sigma = curve_band(samples, masks, basis, result.coefficients, result.log_exposures,
                           known, options=options,
                           settings=BandSettings(method=method, seed=seed))
    judge_band(fit, log_sigma, samples.max_code, warnings)
    if getattr(result, "ambiguity_prior", False):
        sigma_gamma, energy = ambiguity_gamma_sigma(basis, result.coefficients,
                                                    options.n_components)
        fit["evidence"]["ambiguity_gamma_sigma"] = sigma_gamma
        fit["evidence"]["ambiguity_energy"] = energy
        log_sigma = np.sqrt(log_sigma ** 2 + ambiguity_sigma(fit["inverse"], sigma_gamma) ** 2)
    return log_sigma


def judge_band(fit: dict, log_sigma, max_code: int, warnings: list) -> None:
    """Add the band's verdict reason (:func:`band_reason`) to a judged fit, in place.

    An ``"ok"`` verdict becomes ``"doubtful"``; the evidence gets ``band_width_90`` (the
    widest relative half-width over the body) and where it is.
    """
    reason, wide = band_reason(fit["grid"], fit["inverse"], log_sigma, max_code)
    fit["evidence"]["band_width_90"] = {"width": round(wide["width"], 5),
                                        "channel": "RGB"[wide["channel"]],
                                        "code": int(round(wide["intensity"] * max_code))}
    if reason is None:
        return
    fit["reasons"].append(reason)
    warnings.append(reason)
    if fit["verdict"] == "ok":
        fit["verdict"] = "doubtful"
