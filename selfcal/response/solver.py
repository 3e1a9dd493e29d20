"""Joint solve for log-domain PCA response coefficients and log exposures (Eq. 8).

Implements [Lin2011] (Lin, Kim, Süsstrunk & Brown, *Revisiting Radiometric Calibration
for Color Computer Vision*, ICCV 2011), §5, with additions of selfcal's own.  The response
of each channel is modelled in the log domain with a PCA basis (Eq. 7),

    g(I) = log f⁻¹(I) = g₀(I) + Σₙ hₙ(I) cₙ,

and every pair of samples (I, I′) of one scene point in two frames gives (Eq. 8)

    g(I′) − g(I) = K′ − K,          K = log(exposure).

The equations are linear in the coefficients and the log exposures together, so the whole
problem is a weighted linear least-squares fit, iterated for robust weights.

[Lin2011]'s parts (§5):

- Eq. 7, the log-domain PCA model: the basis is read at the sample codes (:mod:`.basis`).
- Eq. 8, one row per sample pair and channel (:func:`.equations.build_pair_rows`).
- Unknown exposure ratios K′ solved jointly with g (as in [Kim2008]); the
  solution is then known only up to an exponential γ (f⁻¹ → (f⁻¹)^γ), which the paper
  fixes with exposure values from the camera — here any two known times fix it.
- Outlier rejection: a sample is dropped from a pair when any channel is clipped in either
  frame, or when its HSV saturation exceeds β in either frame (masks from
  :func:`selfcal.stack.samples.frame_masks`, counts in :func:`.equations.rejection_counts`).

selfcal's own (one line each on why):

- PCA-variance prior on the coefficients (:mod:`.priors`): the data leave the bend of the
  never-observed last codes open, and with fewer than two known times the exponential
  ambiguity too; the curve database decides (with fewer than two known times the prior
  is centred at standard encodings, ``SolverOptions.centre_ambiguity``).  On in every
  solve with the built-in basis
  (it carries PCA variances), not only with < 2 known times.  A basis without variances
  (``invemor.txt``) gets them estimated from the curve family projected on it
  (:func:`.priors.estimated_coefficient_variance`, ours); the ridge acts only when the
  prior is off (``prior_weight = 0``, or ``estimated_prior_scale = 0``).
- White-continuation prior (:mod:`.priors`): beyond the brightest valid sample f⁻¹(1) = 1
  is extrapolation, and the observed curve's straight continuation should meet it.
- Censored white-threshold rows (:class:`.equations.ThresholdRows`): where each channel
  starts to clip at the top code ties the scale of f⁻¹ to the data.
- Exposure prior for ``refine_exposures``: shutters are inaccurate, so given times are
  evidence rather than constraints.
- Stuck samples (:func:`.equations._build_pairs`): a code that does not move with the
  exposure is clipped, whatever its value (black pedestals, scanned film).
- Slope-based noise weights (:func:`_noise_variance`): residuals in code units, so that the
  data term cannot shrink the exponential ambiguity towards γ → 0.
- Huber loss by IRLS (:func:`_robust_fit`): what survives the paper's rejection still
  holds misaligned, moving or JPEG-damaged samples; they are down-weighted, not dropped.
- Block alternation between curves and exposures (:func:`_block_step`): a joint step can
  slide g and K together along the exponential ambiguity, which the data barely oppose.
- Initial exposures from the mean curve (:func:`_initial_log_exposures`): they order the
  frames for the pairs and start the alternation.
- Theil–Sen rescale (:func:`_theil_sen_rescale`): with refined exposures, γ and the offset
  are taken from the given times, so that one lying EXIF time cannot tilt the rest.
- Monotone f⁻¹ (:func:`_monotone_qp`): linear inequalities, a small QP handed to Clarabel
  only when the unconstrained fit violates them.

Normalisation: every basis function and the mean vanish at I = 1, so f⁻¹(1) = 1 holds by
construction and the additive gauge of Eq. 8 is fixed.  With fewer than two known times
the result says in its warnings that the ambiguity was resolved by the prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError
from ..stack.frames import DEFAULT_CLIP_MARGIN
from ..stack.samples import SampleSet, frame_masks
from .equations import (
    ThresholdRows,
    interpolation_matrix,
    NormalEquations,
    white_thresholds,
    build_pair_rows,
    rejection_counts,
)
from . import priors as _priors
from .priors import (
    ExposurePrior,
    PriorTerms,
    ambiguity_centre,
    pca_variance_precision,
    white_continuation_terms,
)

#: Default HSV saturation threshold β.  Lin et al. (§7) use 0.4 for cameras with strong
#: colour mapping and above 0.7 for most others; 0.5 drops the colours gamut mapping is
#: most likely to have moved while keeping enough samples in ordinary scenes.
DEFAULT_SATURATION_THRESHOLD = 0.5

#: Basis functions per channel (N of Eq. 7 of [Lin2011]); chosen before the split rule
#: (docs/decisions.md, "Basis functions per channel: N = 5").
DEFAULT_N_COMPONENTS = 5

#: Std of code noise (normalised units) assumed for block means when weighting Eq. 8:
#: one 8-bit code.  The one definition: the band (:mod:`.bands`) and the verdict's residual
#: test (:mod:`.verdict`) take it from here.
CODE_NOISE = 1.0 / 255.0
#: IRLS iterations at most when some exposures are estimated (run to convergence).
MAX_ITERATIONS_ESTIMATED = 60


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


@dataclass(frozen=True, eq=False)
class MonotoneConstraint:
    """f⁻¹ non-decreasing on the basis grid: ``DH · c_c ≥ eps − Dg0`` for every channel.

    Monotone over the whole grid: the dark end below the first code has no data, and an
    unconstrained fit there can shoot up.  Every 4th grid point (and the last) carries a
    constraint, a quarter of the QP's size; the table is made non-decreasing between them
    afterwards.  Without the constraint the rows are empty.
    """

    DH: np.ndarray          # (P, N) differences of the components between grid points
    Dg0: np.ndarray         # (P,) differences of the mean

    @classmethod
    def on_grid(cls, basis, N: int, enabled: bool) -> MonotoneConstraint:
        grid = basis.intensity
        mono_idx = np.unique(np.append(np.arange(0, len(grid), 4), len(grid) - 1))
        D = np.diff(np.eye(len(mono_idx)), axis=0)
        if not enabled:
            D = D[:0]
        return cls(DH=D @ basis.components[:N].T[mono_idx], Dg0=D @ basis.mean[mono_idx])


@dataclass(frozen=True, eq=False)
class SolveSettings:
    """What every weighted solve of the loop adds to the data: priors and the constraint."""

    N: int                          # basis functions per channel (Eq. 7)
    priors: PriorTerms
    monotone: MonotoneConstraint


@dataclass(frozen=True, eq=False)
class _Exposures:
    """The log exposures' starting point: what is given, what is held, what is refined."""

    log_times: np.ndarray           # (F,) given log times; the gauge frame's 0 if none given
    known: np.ndarray               # (F,) bool: a time was given
    fixed: np.ndarray               # (F,) bool: held at ``log_times`` in the joint solve
    refine: bool                    # given times are a prior, not fixed
    initial: np.ndarray             # (F,) first estimates (:func:`_initial_log_exposures`)

    @property
    def alternate(self) -> bool:
        """Solve by block alternation (see :func:`_block_step`) rather than jointly."""
        return bool((self.refine or self.known.sum() < 2) and not self.fixed.all())


@dataclass(frozen=True)
class SolverOptions:
    """The finer settings of the Eq. 8 solve (:func:`solve_exposure_equations`).

    Attributes
    ----------
    n_components : int
        Number of basis functions N per channel in Eq. 7.  Default
        :data:`DEFAULT_N_COMPONENTS` (5); :func:`selfcal.calibrate_response` caps it at
        the basis' size.
    saturation_threshold : float
        β of §5: samples whose HSV saturation exceeds it are dropped.
    clip_margin : float
        Codes (8-bit scale) from 0 or the maximum that count as clipped.
    exposure_prior_sigma : float
        Std (log units) of the prior on the given times when they are refined.
    max_rank_gap : int
        Each frame is paired with the next ``max_rank_gap`` frames in exposure order.
    huber_k : float
        Huber threshold in robust standard deviations (IRLS).
    max_iterations : int, optional
        IRLS iterations at most.  Default: 8 (stopping when no coefficient moves by 1e-5)
        when every exposure is held; when some are estimated, to convergence (1e-8, at
        most 60): the exposures then move slowly between iterations, and a loop stopped
        early leaves a model that depends on its starting guess (ours).
    ridge : float
        Weight of the ridge on the coefficients, relative to the mean data weight; used
        only when the PCA-variance prior is off (``prior_weight = 0``, or a basis without
        variances with ``estimated_prior_scale = 0``).
    white_continuation_sigma : float
        Std (log units) of the white-continuation prior: the observed curve continues
        straight from the brightest valid sample to g(1) = 0.
    prior_weight : float
        Scale of the PCA-variance prior c_n ~ N(0, λ_n / prior_weight) from the basis' PCA
        variances λ_n (estimated for a basis without them, and then weighted by
        ``estimated_prior_scale``), on in every solve whatever the number of known
        times.  The data term counts every pair equation as independent, but one sample
        location enters up to 3·(F−1) correlated equations (channels, pairs) and JPEG
        errors are spatially correlated, so the prior is weighted up by about that factor
        (ours; docs/decisions.md, "The other settings of the response solve stay at their
        defaults").
    monotone : bool
        Constrain f⁻¹ to be non-decreasing (a QP when the plain fit is not).
    white_threshold : bool
        Add the censored white-threshold rows (:class:`.equations.ThresholdRows`: where
        each channel starts to clip at the top code), which tie the scale of f⁻¹ to the
        data.
    estimated_prior_scale : float
        Multiplier of ``prior_weight`` for a basis whose PCA variances are estimated
        (:func:`.priors.estimated_coefficient_variance`, ours); 0 switches that prior off
        (the ridge acts instead).  Default :data:`.priors.ESTIMATED_PRIOR_SCALE`, chosen
        on the tuning split (docs/decisions.md, "Prior scale for a basis without PCA
        variances: ×3").
    centre_ambiguity : bool
        With fewer than two different known times, centre the PCA-variance prior at
        :func:`.priors.ambiguity_centre` (standard encodings) instead of the basis mean,
        and start the exposures from that centre's curve (ours).  Default True, chosen on
        the tuning split (docs/decisions.md, "The prior's centre when fewer than two times
        are known: sRGB and Rec.709").
    """

    n_components: int = DEFAULT_N_COMPONENTS
    saturation_threshold: float = DEFAULT_SATURATION_THRESHOLD
    clip_margin: float = DEFAULT_CLIP_MARGIN
    exposure_prior_sigma: float = 0.05
    max_rank_gap: int = 3
    huber_k: float = 1.345
    max_iterations: int | None = None
    ridge: float = 1e-4
    white_continuation_sigma: float = 0.03
    prior_weight: float = 100.0
    monotone: bool = True
    white_threshold: bool = True
    estimated_prior_scale: float = _priors.ESTIMATED_PRIOR_SCALE
    centre_ambiguity: bool = True


def solve_exposure_equations(samples: SampleSet, basis, log_times: np.ndarray, *,
                             refine_exposures: bool = False, masks: dict | None = None,
                             options: SolverOptions | None = None,
                             sample_weights: np.ndarray | None = None) -> SolveResult:
    """Solve Eq. 8 of [Lin2011] for three channels' coefficients and exposures.

    Parameters
    ----------
    samples : SampleSet
        Block-mean intensities across the stack (normalised to [0, 1]).
    basis : ResponseBasis
        A log-domain basis (``basis.domain == "log"``), Eq. 7.
    log_times : ndarray, shape (F,)
        Log of the given exposure of each frame, NaN where unknown.
    refine_exposures : bool
        Treat given times as a prior (std ``options.exposure_prior_sigma`` in log units)
        and re-estimate them; otherwise they are fixed.
    masks : dict, optional
        ``"clipped"`` and ``"saturated"`` masks of :func:`selfcal.stack.samples.frame_masks`
        (computed with ``options``' clip margin and β when not given).
    options : SolverOptions, optional
        The finer settings; default ``SolverOptions()``.
    sample_weights : ndarray (n, 3), optional
        Weight of each sample's row per channel (histogram correspondences,
        :mod:`.histogram_samples`); rows of weight 0 are left out of the fit and of the
        robust scale.

    Returns
    -------
    SolveResult
    """
    options = SolverOptions() if options is None else options
    if basis.domain != "log":
        raise CalibrationError(
            f"basis {basis.name!r} is a {basis.domain}-domain basis; Eq. 8 needs a "
            "log-domain basis (convert it with ResponseBasis.to_log_domain)")
    values = samples.values
    F, n, _ = values.shape
    N = int(options.n_components)
    if masks is None:
        masks = frame_masks(samples, clip_margin=options.clip_margin,
                            saturation_threshold=options.saturation_threshold)
    clipped, saturated = masks["clipped"], masks["saturated"]
    valid = ~(clipped | saturated)
    log_times = np.asarray(log_times, dtype=float)
    warnings, ambiguity_prior = _ambiguity_warnings(np.isfinite(log_times), log_times,
                                                    centred=options.centre_ambiguity)
    precision = pca_variance_precision(basis, N, options.prior_weight,
                                       options.estimated_prior_scale)
    centre = (ambiguity_centre(basis, N) if ambiguity_prior and precision is not None
              and options.centre_ambiguity else None)
    exposures = _exposure_setup(log_times, refine_exposures, values, valid, basis,
                                None if centre is None else basis.model_values(centre))

    # frames by exposure; shots of one exposure by brightness, not by their place in the
    # input (the pairs, and so the model, must not depend on the order of the frames)
    order = np.lexsort((values.mean(axis=(1, 2)), exposures.initial))
    rows = build_pair_rows(values, valid, order, exposures.initial, basis, N,
                           options.max_rank_gap, sample_weights)
    rejections = rejection_counts(clipped, saturated, order, options.max_rank_gap, rows.stuck)
    thresholds = (white_thresholds(values, valid, order, options.max_rank_gap,
                                    samples.max_code, options.clip_margin / 255.0)
                  if options.white_threshold else [])
    threshold_rows = (ThresholdRows(thresholds, F, samples.max_code, basis, N)
                      if thresholds else None)
    # the threshold rows (if any) are set at the start of every IRLS iteration
    normal = NormalEquations(rows.dH, rows.rhs, rows.pa, rows.pb, F, N)

    priors = PriorTerms(
        coefficient_precision=precision, coefficient_mean=centre, ridge=options.ridge,
        white_continuation=white_continuation_terms(values, valid, basis, N),
        white_continuation_sigma=options.white_continuation_sigma,
        exposure=ExposurePrior(mean=exposures.log_times, frames=exposures.known,
                               sigma=options.exposure_prior_sigma))
    settings = SolveSettings(N=N, priors=priors,
                             monotone=MonotoneConstraint.on_grid(basis, N, options.monotone))
    max_iterations, tolerance = options.max_iterations, 1e-5
    if max_iterations is None:
        max_iterations, tolerance = ((8, 1e-5) if exposures.fixed.all() else
                                     (MAX_ITERATIONS_ESTIMATED, 1e-8))
    fit = _robust_fit(normal, threshold_rows, rows, basis, settings, exposures,
                      options.huber_k, max_iterations, tolerance)
    coeffs, K = fit.coefficients, fit.log_exposures
    if refine_exposures and exposures.known.sum() >= 2:
        rescaled = _theil_sen_rescale(K, exposures.log_times, exposures.known)
        if rescaled is not None:
            # refit the curves with the rescaled exposures held
            K = rescaled
            x, _ = _weighted_solve(normal(fit.weights), settings, np.ones(F, bool), K, False)
            coeffs = x[:3 * N].reshape(3, N)

    resid = normal.residual(np.concatenate([coeffs.ravel(), K]))
    w = fit.robust / fit.variance * fit.row_weight
    residual_rms = float(np.sqrt(np.average(resid ** 2, weights=w)))
    return SolveResult(coefficients=coeffs, log_exposures=K, exposure_fixed=exposures.fixed,
                       pair_frames=np.array([(a, bb) for a, bb, _ in rows.pairs]),
                       residual_rms=residual_rms, per_pair_rms=_per_pair_rms(resid, rows),
                       rejections=rejections, rows_used=int(3 * rows.m),
                       rows_downweighted=int(np.sum((fit.robust < 0.5)
                                                    & (fit.row_weight > 0))),
                       monotone_constrained=fit.monotone_constrained, warnings=warnings,
                       ambiguity_prior=ambiguity_prior)


def _ambiguity_warnings(known: np.ndarray, log_times: np.ndarray, *, centred: bool = True):
    """The warning that the exponential ambiguity (§5) was left to the prior, if it was.

    Returns
    -------
    warnings : list of str
    ambiguity_prior : bool
        True when fewer than two *different* exposure times are known (two shots at one
        known time fix no exposure ratio).
    """
    warnings: list[str] = []
    ambiguity_prior = False
    if np.unique(log_times[known]).size < 2:
        ambiguity_prior = True
        warnings.append(
            "fewer than two different exposure times are known: the exponential "
            "ambiguity of the response (Lin et al. §5) was resolved by a prior towards "
            + (f"standard encodings ({', '.join(_priors.AMBIGUITY_CENTRE_CURVES)})"
               if centred
               else "the basis mean response")
            + ", a guess that can leave f⁻¹ raised to a wrong power; "
            "exposures are relative"
            + (" to the frame(s) with a known time" if known.any() else "")
            + "; two different known exposure times fix it")
    return warnings, ambiguity_prior


def _exposure_setup(log_times, refine: bool, values, valid, basis,
                    start_curve=None) -> _Exposures:
    """Which log exposures are held, with first estimates, and the additive gauge of K.

    ``start_curve`` (g on the basis grid) replaces the basis mean in the first estimates.

    Given times are held unless ``refine``.  When nothing else fixes the additive gauge of
    K (Eq. 8 sees differences only), one frame is held: the first with a known time, else
    the frame whose initial estimate is nearest 0, at log exposure 0.
    """
    known = np.isfinite(log_times)
    fixed = known.copy() if not refine else np.zeros(log_times.size, bool)
    init = _initial_log_exposures(values, valid, basis, log_times, start_curve)
    if not fixed.any() and not (refine and known.any()):
        # fix the additive gauge of K: the first known frame, else the frame chosen above
        gauge = int(np.flatnonzero(known)[0]) if known.any() else int(np.argmin(np.abs(init)))
        fixed[gauge] = True
        if not known.any():
            log_times = log_times.copy()
            log_times[gauge] = 0.0
    return _Exposures(log_times=log_times, known=known, fixed=fixed, refine=refine,
                      initial=init)


def _initial_log_exposures(values, valid, basis, log_times, start_curve=None):
    """Exposure guesses from the mean response where times are unknown (median ratios).

    selfcal's: with the basis mean g₀ (or ``start_curve``) for g, Eq. 8 gives K_j − K_k as
    the median of g₀(I_j) − g₀(I_k) over the samples valid in both frames; unknown frames
    are chained to the known frame sharing most samples with them.
    """
    F = values.shape[0]
    g0 = np.interp(values, basis.intensity,
                   basis.mean if start_curve is None else start_curve)  # (F, n, 3)
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
            shared = [(k, valid[j] & valid[k]) for k in known]
            most = max((int(both.sum()) for _, both in shared), default=0)
            if most < 5:
                continue
            # every known frame sharing the most samples, averaged: frames clipped alike
            # share equally many, and the first of them by index would make the guess
            # depend on the order of the frames
            est[j] = np.mean([est[k] + np.median(g0[j][both] - g0[k][both])
                              for k, both in shared if both.sum() == most])
            progressed = True
        if not progressed:
            break
    if np.any(np.isnan(est)):
        raise CalibrationError(
            "some frames share no usable (unclipped, unsaturated) samples with any other "
            "frame, so their exposures cannot be estimated")
    return est


@dataclass(frozen=True, eq=False)
class _Fit:
    """Where the robust loop stopped, with the weights of its last iteration."""

    coefficients: np.ndarray        # (3, N)
    log_exposures: np.ndarray       # (F,)
    robust: np.ndarray              # Huber weights of every row (pair rows, threshold rows)
    variance: np.ndarray            # noise variance of every row (log units)
    weights: np.ndarray             # the last solve's row weights
    monotone_constrained: bool
    row_weight: np.ndarray          # given weight of every row


def _robust_fit(normal, thresholds, rows, basis, settings, exposures, huber_k,
                max_iterations, tolerance) -> _Fit:
    """Iteratively reweighted least squares with a Huber loss (selfcal's, not §5's).

    Every iteration reads the current curve's slope for the noise weights, moves the
    censored threshold rows to the current crossing, solves (jointly, or by block
    alternation), and sets the Huber weights of the residuals in robust standard
    deviations; it stops when no coefficient moves by ``tolerance``.
    """
    N, m = settings.N, rows.m
    nt = thresholds.size if thresholds is not None else 0
    grid, g0_grid = basis.intensity, basis.mean
    H_grid = basis.components[:N].T  # (K, N)
    alternate = exposures.alternate
    coeffs = np.zeros((3, N))
    noise_scale = 1.0
    K = exposures.initial.copy()
    K[exposures.fixed] = exposures.log_times[exposures.fixed]
    robust = np.ones(3 * m + nt)
    row_weight = np.ones(3 * m + nt)
    if rows.weight is not None:
        row_weight[:3 * m] = rows.weight
    monotone_constrained = False
    interp_a = [interpolation_matrix(grid, rows.Ia[:, c]) for c in range(3)]
    interp_b = [interpolation_matrix(grid, rows.Ib[:, c]) for c in range(3)]
    for it in range(max_iterations):
        g_grid = g0_grid[None, :] + coeffs @ H_grid.T          # (3, K)
        dg_grid = np.gradient(g_grid, grid, axis=1)
        if nt:
            thresholds.censor(g_grid, grid, K)
            normal.A_thr, normal.b_thr = thresholds.rows()
        var = _noise_variance(dg_grid, interp_a, interp_b, m, thresholds, grid)
        # the data term is a likelihood only with the noise at its measured level
        w = row_weight * robust / (var * noise_scale ** 2)
        if nt:
            w[3 * m:] *= thresholds.active
        if alternate:
            x, constrained = _block_step(normal(w), settings, K, exposures)
        else:
            x, constrained = _weighted_solve(normal(w), settings, exposures.fixed,
                                             exposures.log_times, exposures.refine)
        monotone_constrained |= constrained
        new_coeffs = x[:3 * N].reshape(3, N)
        K = x[3 * N:]
        new_robust, noise_scale = _huber_weights(normal.residual(x), var, huber_k,
                                                 row_weight > 0)
        change = np.max(np.abs(new_coeffs - coeffs))
        coeffs = new_coeffs
        robust = new_robust
        if it > 0 and change < tolerance:
            break
    return _Fit(coefficients=coeffs, log_exposures=K, robust=robust, variance=var,
                weights=w, monotone_constrained=monotone_constrained, row_weight=row_weight)


def _noise_variance(dg_grid, interp_a, interp_b, m, thresholds, grid):
    """Variance of every row from code noise through the slope of the current g (selfcal's).

    A pair row's error is g(I′ + e′) − g(I + e) for code noise e, e′ of std
    :data:`CODE_NOISE`: variance σ²·(g′(I)² + g′(I′)²).  Threshold rows carry θ's
    uncertainty through g′(θ).  Residuals are thus in code units (errors-in-variables):
    scaling g and K together by γ scales the variance by γ², so the data term cannot
    shrink the exponential ambiguity towards γ → 0; the floor (5 % of the median) is
    relative for the same reason.
    """
    nt = thresholds.size if thresholds is not None else 0
    var = np.empty(3 * m + nt)
    for c in range(3):
        slope_a = interp_a[c] @ dg_grid[c]
        slope_b = interp_b[c] @ dg_grid[c]
        var[c * m:(c + 1) * m] = (CODE_NOISE ** 2) * (slope_a ** 2 + slope_b ** 2)
    if nt:
        var[3 * m:] = thresholds.variance(dg_grid, grid)
    var[:3 * m] = np.maximum(var[:3 * m], 0.05 * np.median(var[:3 * m]))
    return var


def _huber_weights(resid, var, huber_k, used=None):
    """Huber IRLS weights min(1, k·s / |u|) of residuals u in noise units, and the scale s.

    s is the robust (MAD) standard deviation of u over the ``used`` rows (default all); it
    also scales the noise of the next iteration (floored at 1e-3).
    """
    u = resid / np.sqrt(var)
    scale = 1.4826 * np.median(np.abs(u if used is None else u[used])) + 1e-12
    robust = np.minimum(1.0, huber_k * scale / np.maximum(np.abs(u), 1e-12))
    return robust, max(scale, 1e-3)


def _block_step(normal_eq, settings, K, exposures):
    """One block coordinate step: the curves with the exposures held, then the exposures.

    selfcal's.  A joint step could rescale g and K together along the exponential
    ambiguity, which the (slope-weighted) data barely oppose; alternating leaves the scale
    where the times (or the mean curve) put it.
    """
    F, N = K.size, settings.N
    x, constrained = _weighted_solve(normal_eq, settings, np.ones(F, bool), K, False)
    prior = settings.priors.exposure if exposures.refine else None
    x[3 * N:] = _exposure_step(normal_eq, x, N, exposures.fixed, K, prior)
    return x, constrained


def _exposure_step(normal_eq, x, N, fixed, K, exposure_prior):
    """Log exposures minimising the weighted Eq. 8 residuals with the curves held.

    ``exposure_prior`` (an :class:`.priors.ExposurePrior`, or None) is added when refining.
    """
    Qfull, qfull = normal_eq
    Q = Qfull[3 * N:, 3 * N:].copy()
    q = qfull[3 * N:] - Qfull[3 * N:, :3 * N] @ x[:3 * N]
    if exposure_prior is not None:
        exposure_prior.add_to_exposure_block(Q, q)
    out = K.copy()
    free = ~fixed
    if free.any():
        qf = q[free] - Q[np.ix_(free, fixed)] @ K[fixed]
        out[free] = np.linalg.lstsq(Q[np.ix_(free, free)], qf, rcond=None)[0]
    return out


def _weighted_solve(normal_eq, settings: SolveSettings, fixed, held, refine: bool):
    """Minimise Σ w r² + priors, with the exposures in ``fixed`` held at ``held``.

    ``normal_eq`` is ``(AᵀWA, AᵀWb)`` of the Eq. 8 system (see
    :class:`.equations.NormalEquations`); the priors of ``settings`` are added (the
    exposure prior only when ``refine``), and the monotone QP replaces the plain solution
    when that is not monotone.

    Returns
    -------
    x : ndarray
        Coefficients (3·N) then log exposures (F).
    constrained : bool
        The monotone QP was needed.
    """
    N = settings.N
    Q, q = normal_eq[0].copy(), normal_eq[1].copy()
    settings.priors.add_to(Q, q, N, exposure_prior=refine)
    free = np.concatenate([np.ones(3 * N, bool), ~fixed])
    xf = np.where(fixed, held, 0.0)
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
    mono = settings.monotone
    eps = 1e-7
    slopes = [mono.Dg0 + mono.DH @ x[c * N:(c + 1) * N] for c in range(3)]
    constrained = bool(mono.DH.shape[0] and min(s.min() for s in slopes) < eps)
    if constrained:
        x[free] = _monotone_qp(Qf, qf, mono, N, eps)
    return x, constrained


def _monotone_qp(Qf, qf, mono: MonotoneConstraint, N: int, eps: float):
    """min zᵀQf z − 2 qfᵀz subject to f⁻¹ non-decreasing on the grid (Clarabel).

    ``Qf = LLᵀ`` (Cholesky, a trace-relative 1e-12 added), and ‖Lᵀz‖² − 2 qfᵀz has the
    same minimiser as the weighted least squares.  The problem goes to Clarabel directly,
    in the conic form cvxpy made of it (ours: cvxpy rebuilt that form in every call, which
    cost several times the solve): variables ``[t, z]``, objective ``tᵀt − 2 qfᵀz``, the
    zero cone ``Lᵀz − t = 0``, then the non-negative cone ``DH z_c − (eps − Dg0) ≥ 0``
    channel by channel; the same matrices with the same sparsity, so the same iterates and
    solution as the cvxpy model ``sum_squares(L.T @ z) − 2 qf @ z`` it replaces.  Where
    Clarabel reports a numerical failure, cvxpy's OSQP solves it as before.
    """
    import clarabel
    import scipy.sparse as sp

    n, p = len(qf), mono.DH.shape[0]
    L = np.linalg.cholesky(Qf + 1e-12 * np.eye(n) * np.trace(Qf) / n)
    A = np.zeros((n + 3 * p, 2 * n))
    A[:n, :n] = -np.eye(n)
    A[:n, n:] = L.T
    for c in range(3):
        A[n + c * p:n + (c + 1) * p, n + c * N:n + (c + 1) * N] = -mono.DH
    b = np.concatenate([np.zeros(n), np.tile(mono.Dg0 - eps, 3)])
    P = sp.csc_matrix((np.full(n, 2.0), (np.arange(n), np.arange(n))), shape=(2 * n, 2 * n))
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    status = "NumericalError"
    try:
        solution = clarabel.DefaultSolver(
            P, np.concatenate([np.zeros(n), -2 * qf]), sp.csc_matrix(A), b,
            [clarabel.ZeroConeT(n), clarabel.NonnegativeConeT(3 * p)], settings).solve()
        status = str(solution.status)
    except Exception:  # pragma: no cover - the fallback below
        pass
    if status in ("Solved", "AlmostSolved", "MaxIterations", "MaxTime"):
        return np.array(solution.x[n:])
    if "Infeasible" not in status:  # pragma: no cover - fall back to the other solver
        import cvxpy as cp

        zv = cp.Variable(n)
        prob = cp.Problem(cp.Minimize(cp.sum_squares(L.T @ zv) - 2 * qf @ zv),
                          [mono.DH @ zv[c * N:(c + 1) * N] >= eps - mono.Dg0
                           for c in range(3)])
        prob.solve(solver=cp.OSQP, eps_abs=1e-9, eps_rel=1e-9, max_iter=200000)
        status = prob.status
        if zv.value is not None:
            return zv.value
    raise CalibrationError("the monotone response fit did not converge "
                           f"(solver status {status})")


def _theil_sen_rescale(K, log_times, known):
    """Refined log exposures mapped onto the given times' scale, or None (selfcal's).

    The data fix exposure *ratios* only up to the exponential ambiguity (γ), which the
    alternation drifts along slowly; the given times fix it: γ and the offset α come from
    a Theil–Sen fit K ≈ γ·log t + α at the frames with a given time, and (K − α) / γ keeps
    each frame's deviation from its time (the shutter errors).  Theil–Sen, so that one
    lying EXIF time cannot tilt the scale of all the others.  None when γ ≤ 0.
    """
    from scipy.stats import theilslopes

    L = log_times[known]
    gamma, alpha = theilslopes(K[known], L)[:2]
    if gamma > 0:
        return (K - alpha) / gamma
    return None


def _per_pair_rms(resid, rows) -> dict:
    """RMS of the pair rows' residuals (log units, all channels) per frame pair (a, b)."""
    per_pair = {}
    r3 = resid[:3 * rows.m].reshape(3, rows.m)
    for k, (a, bb, _) in enumerate(rows.pairs):
        sel = rows.pair_id == k
        per_pair[(int(a), int(bb))] = float(np.sqrt(np.mean(r3[:, sel] ** 2)))
    return per_pair
