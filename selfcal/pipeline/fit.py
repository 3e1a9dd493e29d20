"""``fit_pipeline``: a camera pipeline from corresponding raw and rendered samples.

[Gong2018] §3.2-3.5, with the RBF inverse colour mapping of [Lin2011] §6.
"""

from __future__ import annotations

import time
from dataclasses import dataclass


import numpy as np
import numpy.typing as npt

from ..errors import CalibrationError, InputError
from ..stack.samples import hsv_saturation
from ..typing import Progress
from .clipped import CLIP_HI, CLIP_LO, clipped_mask, clipped_pixel_correction
from .lattice import LUT_SMOOTHNESS, LatticeLUT, lattice_regression_lut
from .matrix import rank_based_matrix, row_scales
from .model import BAKE_SIZE, BACKWARD_VARIANTS, BackwardStages, ForwardStages, PipelineModel
from .rbf import N_CONTROL_POINTS, RBFColourMapping, rbf_inverse_colour_mapping
from .tone import SMOOTHNESS, MonotonePolynomial, monotone_tone_curves
from .trust import TrainingColours

#: Default β of the neutral weighting of the forward tone-curve samples (None: equal
#: weights, [Gong2018]'s Eq. 9; see fit_pipeline).
NEUTRAL_WEIGHTING = None
#: Fewest samples fit_pipeline accepts.
MIN_SAMPLES = 30


def _check_samples(raw, rendered):
    def arr(x, what):
        a = np.asarray(x)
        if a.dtype == np.uint8:
            a = a.astype(np.float64) / 255.0
        elif a.dtype == np.uint16:
            a = a.astype(np.float64) / 65535.0
        elif np.issubdtype(a.dtype, np.number) and not np.issubdtype(a.dtype, np.complexfloating):
            a = a.astype(np.float64)
        else:
            raise InputError(f"{what} must be a numeric (n, 3) array, got dtype {a.dtype}")
        if a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"{what} must have shape (n, 3) (one RGB sample per row), got "
                             f"{a.shape}")
        bad = ~np.all(np.isfinite(a), axis=1)
        if bad.any():
            raise InputError(f"{what} holds NaN or infinite values in {int(bad.sum())} of "
                             f"{a.shape[0]} rows (first at row {int(np.argmax(bad))})")
        return a

    raw = arr(raw, "raw_samples")
    rendered = arr(rendered, "rendered_samples")
    if raw.shape[0] != rendered.shape[0]:
        raise InputError(f"raw_samples has {raw.shape[0]} rows but rendered_samples has "
                         f"{rendered.shape[0]}; they must correspond row by row")
    if raw.shape[0] < MIN_SAMPLES:
        raise CalibrationError(f"{raw.shape[0]} samples are too few to fit a camera pipeline; "
                               f"give at least {MIN_SAMPLES} (the paper's one-shot setting "
                               "uses 140)")
    if rendered.max() > 1.5:
        raise InputError(f"rendered_samples must be in [0, 1] (codes / 255), but the largest "
                         f"is {rendered.max():g}; divide 8-bit codes by 255")
    if raw.max() > 1.5 or raw.min() < -0.5:
        raise InputError(f"raw_samples must be linear raw normalised to [0, 1] by the black "
                         f"and white levels, but they span [{raw.min():g}, {raw.max():g}]")
    if rendered.min() < -0.5:
        raise InputError(f"rendered_samples must be in [0, 1], the smallest is "
                         f"{rendered.min():g}")
    return np.clip(raw, 0.0, 1.0), np.clip(rendered, 0.0, 1.0)


def _rmse(a, b) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


def _forward_fit(unit, raw, rendered, smoothness, lut_smoothness, tone_weights=None):
    """Scale rows, fit tone curves (Eq. 9) and the forward LUT (§3.4); training errors."""
    m = row_scales(unit, raw)[:, None] * unit
    if np.linalg.cond(m) > 1e6:
        raise CalibrationError("the rank-based colour matrix is (nearly) singular")
    x = raw @ m.T
    curves = monotone_tone_curves(x, rendered, smoothness=smoothness, weights=tone_weights)
    y = np.clip(curves(x), 0.0, 1.0)
    lut = lattice_regression_lut(y, rendered, smoothness=lut_smoothness)
    pred = np.clip(y + lut.residual(y), 0.0, 1.0)
    return m, curves, lut, _rmse(pred, rendered), _rmse(y, rendered)


def _backward_fit(raw, rendered, m, m_inv, smoothness, lut_smoothness, n_centres, seed,
                  want_rbf, groups=None):
    """f⁻¹ (§3.5, Eq. 9 reversed), the backward LUT (§3.5) and h⁻¹ ([Lin2011] Eq. 10).

    Rendered samples clipped in a channel are left out of that channel's ``f⁻¹`` and, if
    clipped in any channel, out of the LUT and the RBF.  Returns the parts and the
    leave-one-out (held-out) raw RMSE of both variants.
    """
    target = raw @ m.T
    # rendered values within half a code of 0 or 255 do not determine the raw ([Lin2011]
    # §5): out of the backward fits, they train the clipped-pixel correction
    clipped = (rendered <= CLIP_LO) | (rendered >= CLIP_HI)
    inv = monotone_tone_curves(np.where(clipped, np.nan, rendered), target,
                               smoothness=smoothness, domain=np.array([[0.0, 1.0]] * 3),
                               folds=groups if smoothness == "auto" else None)
    # A top code stands for every raw from the clipping threshold up.  When no training
    # sample reaches it, the curve's value there is an extrapolation, and cameras clip
    # JPEG white where the sensor saturates: the white M ρ_w (ρ_w ∝ M⁻¹ 1, its largest raw
    # channel at saturation, 1) is the prior for the top code, over its last half code.
    # Where training samples do reach the top code, they speak instead (through the
    # clipped-pixel correction): JPEG ringing, for one, puts bright unclipped pixels there.
    r_white = m_inv @ np.ones(3)
    if np.all(r_white > 0):
        e_white = np.full(3, 1.0 / r_white.max())
        beyond = ((e_white > np.nanmax(np.where(clipped, np.nan, target), axis=0))
                  & ~(rendered >= CLIP_HI).any(axis=0))
        if beyond.any():
            inv.top = np.where(beyond, e_white, 0.0)  # 0: below the curve, polynomial kept
    ok = ~clipped.any(axis=1)
    if ok.sum() < 10:
        raise CalibrationError(f"only {int(ok.sum())} samples are unclipped in every "
                               "rendered channel; the backward model needs at least 10")
    e = inv(rendered[ok])
    rho_hat = e @ m_inv.T
    hi = np.maximum(raw[ok].max(axis=0), 1e-3)
    g_ok = None if groups is None else groups[ok]
    blut = lattice_regression_lut(rho_hat, raw[ok], lo=np.zeros(3), hi=hi,
                                  smoothness=lut_smoothness, groups=g_ok)
    held_out = {}
    if blut.validation:
        held_out["lut"] = blut.validation[blut.smoothness]
    rbf = None
    if want_rbf:
        rbf = rbf_inverse_colour_mapping(e, target[ok], n_centres=n_centres,
                                         smoothing="auto",
                                         error_transform=lambda v: v @ m_inv.T, seed=seed,
                                         groups=g_ok)
        held_out["rbf"] = rbf.validation[rbf.smoothing]
    return inv, blut, rbf, held_out


def _clipped_corrections(raw, rendered, inv, m_inv, blut, rbf, held_out):
    """The clipped-pixel correction per backward variant (:mod:`selfcal.pipeline.clipped`).

    The residuals ``ρ_i - ρ_b(P_i)`` of the clipped training samples under each variant
    (``ρ_b`` the backward model of [Gong2018] §3.5 / [Lin2011] Eq. 11, clipped to
    ``[0, 1]`` as :meth:`PipelineModel.to_raw` does) train a kernel-regression estimate of
    ``E[ρ | P]`` at clipped codes.  Returns the corrections, their leave-one-out scores,
    and each variant's held-out RMSE over *all* training samples (the unclipped ones'
    leave-one-out error from ``held_out`` pooled with the clipped ones' -- with the
    correction, or without one when none is kept).
    """
    clipped = clipped_mask(rendered)
    n_c, n_ok = int(clipped.sum()), int((~clipped).sum())
    corrections, scores, pooled = {}, {}, {}
    e_c = inv(rendered[clipped])
    for variant in ("lut",) + (("rbf",) if rbf is not None else ()):
        if variant == "lut":
            rho = e_c @ m_inv.T
            base = rho + blut.residual(rho)
        else:
            base = rbf(e_c) @ m_inv.T
        resid = raw[clipped] - np.clip(base, 0.0, 1.0)
        corr, sc = clipped_pixel_correction(rendered[clipped], resid)
        corrections[variant] = corr
        scores[variant] = sc
        if variant not in held_out:
            continue
        err_ok = held_out[variant]
        if n_c:
            err_c = min(sc.values()) if sc else float(np.sqrt(np.mean(resid ** 2)))
            pooled[variant] = float(np.sqrt((n_ok * err_ok ** 2 + n_c * err_c ** 2)
                                            / (n_ok + n_c)))
        else:
            pooled[variant] = err_ok
    return corrections, scores, pooled


@dataclass(frozen=True)
class PipelineOptions:
    """The knobs of :func:`fit_pipeline`: the matrix search, the regulariser weights, the
    backward variant and its table.

    Attributes
    ----------
    n_sets, set_size : int
        Random sets for the matrix search and their size (25 and 200 in [Gong2018]).  With
        ``n <= set_size`` the sets are random subsets of 80 % of the samples.
    matrix_method : {"fast", "literal"}
        The half-space search (see :func:`~selfcal.pipeline.matrix.rank_based_matrix`).
    smoothness : float
        λ of Eq. 9 for the forward tone curves ``f`` (1e-5 as in [Gong2018]).
    lut_smoothness : float or "auto"
        Relative graph-Laplacian weight of the lattice regressions; ``"auto"`` uses 3e-3
        during the matrix-set search, then the leave-one-out choice for each LUT.
    inverse_smoothness : float or "auto"
        λ for the inverse curves ``f⁻¹`` (§3.5); ``"auto"`` picks it per channel by 5-fold
        cross-validation from 1e-6 ... 0.1 (the backward error is dominated by the sparse,
        steep highlight end of ``f⁻¹``, where a fixed small λ overfits small sample sets).
    backward : {"auto", "lut", "rbf"}
        The backward variant (``"lut"`` skips the RBF fit).
    n_centres : int
        RBF control points.
    bake_size : int
        Nodes per axis of the dense backward table used by :meth:`PipelineModel.to_raw`.
    neutral_weighting : float or None
        β of the weights ``exp(-(s / β)²)`` of the forward tone-curve samples, ``s`` the
        HSV saturation of the rendered colour (ours; [Lin2011] §5 recover the response
        from desaturated pixels, which the gamut map leaves alone, so the curves describe
        the camera's tone rather than a scene's mix of gamut-mapped colours and the LUT
        takes the gamut map); None (the default): equal weights, Eq. 9 of [Gong2018];
        chosen on the tuning scenes (docs/decisions.md, "The RAW-path fit: β, LUT weight,
        γ of g, trust radius").

    Raises
    ------
    InputError
        An unknown ``backward`` or ``matrix_method``, ``n_sets < 1`` or ``set_size < 3``.

    Examples
    --------
    >>> PipelineOptions(n_sets=5, backward="lut").n_sets
    5
    """

    n_sets: int = 25
    set_size: int = 200
    matrix_method: str = "fast"
    smoothness: float = SMOOTHNESS
    lut_smoothness: float | str = "auto"
    inverse_smoothness: float | str = "auto"
    backward: str = "auto"
    n_centres: int = N_CONTROL_POINTS
    bake_size: int = BAKE_SIZE
    neutral_weighting: float | None = NEUTRAL_WEIGHTING

    def __post_init__(self):
        if self.backward not in ("auto",) + BACKWARD_VARIANTS:
            raise InputError(f"backward must be 'auto', 'lut' or 'rbf', got {self.backward!r}")
        if int(self.n_sets) < 1 or int(self.set_size) < 3:
            raise InputError("n_sets must be >= 1 and set_size >= 3")
        if self.matrix_method not in ("fast", "literal"):
            raise InputError("matrix_method must be 'fast' or 'literal', got "
                             f"{self.matrix_method!r}")


def _check_groups(groups, n):
    """``groups`` as integer labels ``0 … k-1`` (None when absent or a single group)."""
    if groups is None:
        return None
    labels = np.asarray(groups)
    if labels.ndim != 1 or labels.shape[0] != n:
        raise InputError(f"groups must hold one label per sample ({n}), got shape "
                         f"{labels.shape}")
    codes = np.unique(labels, return_inverse=True)[1].reshape(-1)
    return codes if codes.max() >= 1 else None


def _training_samples(raw_samples, rendered_samples, n_train, subset_seed, groups=None):
    """The checked samples the fit uses: all, or a seeded subset of ``n_train`` of them.

    Refuses samples that cannot determine the pipeline: fewer than :data:`MIN_SAMPLES`, raw
    samples without colour variety (the matrix of [Gong2018] §3.2 is not determined), a
    rendered channel that barely varies (its tone curve, §3.3, is not).  Returns ``(raw,
    rendered, n_given, groups)``: float64 in ``[0, 1]``, the number of samples given, and
    the group labels of the samples kept (None: one group).
    """
    raw, rendered = _check_samples(raw_samples, rendered_samples)
    n_given = raw.shape[0]
    groups = _check_groups(groups, n_given)
    if n_train is not None:
        n_train = int(n_train)
        if n_train < 1:
            raise InputError(f"n_train must be positive, got {n_train}")
        if n_train < n_given:
            pick = np.sort(np.random.default_rng(subset_seed).choice(n_given, n_train,
                                                                     replace=False))
            raw, rendered = raw[pick], rendered[pick]
            groups = None if groups is None else _check_groups(groups[pick], n_train)
    n = raw.shape[0]
    if n < MIN_SAMPLES:
        raise CalibrationError(f"{n} samples are too few to fit a camera pipeline; give at "
                               f"least {MIN_SAMPLES} (the paper's one-shot setting uses 140)")
    spread = np.linalg.svd(raw - raw.mean(axis=0), compute_uv=False)
    if spread[0] < 1e-6 or spread[2] < 1e-4 * spread[0]:
        raise CalibrationError("the raw samples have no colour variety (they lie on a line "
                               "or plane in RGB, e.g. greys only); the colour matrix is not "
                               "determined -- sample coloured as well as grey surfaces")
    if np.ptp(rendered, axis=0).min() < 2.0 / 255:
        raise CalibrationError("the rendered samples barely vary in some channel; the tone "
                               "curves are not determined")
    return raw, rendered, n_given, groups


def _neutral_weights(rendered, beta):
    """Weights ``exp(-(s / β)²)`` of the forward tone-curve samples, ``s`` the HSV
    saturation of the rendered colour (None: equal weights)."""
    if beta is None:
        return None
    beta = float(beta)
    if not beta > 0:
        raise InputError(f"neutral_weighting must be positive, got {beta!r}")
    return np.exp(-(hsv_saturation(rendered) / beta) ** 2)


@dataclass
class _ForwardFit:
    """Steps 1-3 of :func:`fit_pipeline`: the chosen matrix set and its forward pipeline."""

    matrix: np.ndarray
    curves: MonotonePolynomial  # the tone curves f (Eq. 9)
    lut: LatticeLUT          # the forward gamut correction (§3.4)
    rmse: float              # training RMSE of the whole forward pipeline, [0, 1] scale
    rmse_without_lut: float
    chosen_set: int
    info: list               # rank_based_matrix's per-row constraint counts
    set_errors: list         # training RMSE (0-255) per set, None for a failed set
    failures: list
    set_size: int


def _search_matrix_sets(raw, rendered, *, n_sets, set_size, matrix_method, smoothness,
                        search_lut, rng, progress, tone_weights=None) -> _ForwardFit:
    """Steps 1-3: the colour matrix of the best of ``n_sets`` random sample sets.

    For each set, :func:`~selfcal.pipeline.matrix.rank_based_matrix` on the set (Gong et
    al. §3.2, Eq. 4-8), then the whole forward fit on all samples (:func:`_forward_fit`:
    tone curves, Eq. 9; forward LUT, §3.4, at the fixed weight ``search_lut``); the set
    with the lowest training error is kept ("best luck", §3.2).
    """
    n = raw.shape[0]
    size = int(set_size) if n > int(set_size) else max(3, int(round(0.8 * n)))
    best = None
    set_errors: list[float | None] = []
    failures: list = []
    for s in range(int(n_sets)):
        idx = rng.choice(n, size, replace=False)
        try:
            unit, info = rank_based_matrix(raw[idx], rendered[idx], method=matrix_method,
                                           return_info=True)
            m, curves, flut, err, err_nolut = _forward_fit(unit, raw, rendered, smoothness,
                                                           search_lut, tone_weights)
        except CalibrationError as exc:
            set_errors.append(None)
            failures.append(str(exc))
        else:
            set_errors.append(err * 255)
            if best is None or err < best[0]:
                best = (err, s, m, curves, flut, err_nolut, info)
        if progress is not None:
            progress("matrix", s + 1, int(n_sets),
                     "" if set_errors[-1] is None else f"training RMSE {set_errors[-1]:.2f}")
    if best is None:
        raise CalibrationError("no random sample set gave a usable colour matrix: "
                               + (failures[0] if failures else ""))
    err, chosen, m, curves, flut, err_nolut, info = best
    return _ForwardFit(matrix=m, curves=curves, lut=flut, rmse=err,
                       rmse_without_lut=err_nolut, chosen_set=chosen, info=info,
                       set_errors=set_errors, failures=failures, set_size=size)


def _refit_forward_lut(raw, rendered, fwd: _ForwardFit, groups=None):
    """The forward LUT again, its weight now chosen by leave-one-out, or leave-one-group-out
    with ``groups`` (the search used a fixed one); updates ``fwd.lut`` and ``fwd.rmse``."""
    m = fwd.matrix
    y = np.clip(fwd.curves(raw @ m.T), 0.0, 1.0)
    fwd.lut = lattice_regression_lut(y, rendered, smoothness="auto", groups=groups)
    fwd.rmse = _rmse(np.clip(y + fwd.lut.residual(y), 0.0, 1.0), rendered)


@dataclass
class _BackwardFit:
    """Steps 4-5 of :func:`fit_pipeline`: both backward variants and the one chosen."""

    inverse_curves: MonotonePolynomial  # f⁻¹
    lut: LatticeLUT          # the backward LUT (§3.5)
    rbf: RBFColourMapping | None  # h⁻¹ ([Lin2011] Eq. 10)
    held_out_unclipped: dict
    corrections: dict
    correction_scores: dict
    held_out: dict           # pooled over all samples, per variant
    variant: str


def _fit_backward(raw, rendered, m, m_inv, options: PipelineOptions, *, rbf_seed, progress,
                  groups=None) -> _BackwardFit:
    """Steps 4-5: ``f⁻¹``, backward LUT, RBF ``h⁻¹``, clipped-pixel corrections; the variant.

    With ``backward="auto"`` the variant with the lower held-out error over all training
    samples (:func:`_clipped_corrections`) is used.
    """
    if progress is not None:
        progress("backward", 0, 1, "inverse tone curves, LUT, RBF")
    backward = options.backward
    inv, blut, rbf, held_out = _backward_fit(raw, rendered, m, m_inv,
                                             options.inverse_smoothness,
                                             options.lut_smoothness, options.n_centres,
                                             rbf_seed, backward != "lut", groups)
    corrections, correction_scores, pooled = _clipped_corrections(
        raw, rendered, inv, m_inv, blut, rbf, held_out)
    if backward == "auto":
        chosen_variant = min(pooled, key=pooled.get) if pooled else "rbf"
    else:
        chosen_variant = backward
    if progress is not None:
        progress("backward", 1, 1, f"variant {chosen_variant}")
    return _BackwardFit(inverse_curves=inv, lut=blut, rbf=rbf, held_out_unclipped=held_out,
                        corrections=corrections, correction_scores=correction_scores,
                        held_out=pooled, variant=chosen_variant)


def _backward_training_rmse(raw, rendered, m_inv, bwd: _BackwardFit) -> dict:
    """Raw RMSE of each backward variant on the unclipped training samples (no correction)."""
    ok = ~clipped_mask(rendered)
    e_t = bwd.inverse_curves(rendered[ok])
    rho_hat = e_t @ m_inv.T
    train_err = {"lut": _rmse(np.clip(rho_hat + bwd.lut.residual(rho_hat), 0, 1), raw[ok])}
    if bwd.rbf is not None:
        train_err["rbf"] = _rmse(np.clip(bwd.rbf(e_t) @ m_inv.T, 0, 1), raw[ok])
    return train_err


def _diagnostics(raw, rendered, m_inv, fwd: _ForwardFit, bwd: _BackwardFit,
                 options: PipelineOptions, *, n_given, seed, seconds, groups=None) -> dict:
    """:attr:`PipelineModel.diagnostics`: sample counts, training and held-out errors, the
    regulariser weights chosen, the matrix search, timings."""
    clipped = clipped_mask(rendered)
    corrections, rbf, blut, flut = bwd.corrections, bwd.rbf, bwd.lut, fwd.lut
    clipped_info = {
        v: {"samples": int(clipped.sum()),
            "kept": corrections.get(v) is not None,
            "bandwidth": None if corrections.get(v) is None else corrections[v].bandwidth,
            "prior_weight": (None if corrections.get(v) is None
                             else corrections[v].prior_weight),
            "validation_rmse": bwd.correction_scores.get(v, {})}
        for v in corrections}
    return {
        "method": "rank-based (Gong et al. §3.2-3.5) + RBF h^-1 (Lin et al. ICCV 2011 §6)",
        "samples": {"given": n_given, "used": raw.shape[0],
                    "clipped_rendered": int(clipped.sum())},
        "seed": int(seed),
        "forward_train_rmse": fwd.rmse * 255,
        "forward_train_rmse_without_lut": fwd.rmse_without_lut * 255,
        "backward": bwd.variant,
        "backward_selection": options.backward,
        "backward_validation_rmse": bwd.held_out,
        "backward_validation_rmse_unclipped": bwd.held_out_unclipped,
        "clipped_correction": clipped_info,
        "backward_train_rmse": _backward_training_rmse(raw, rendered, m_inv, bwd),
        "validation": ("leave-one-out in closed form (lattice: hat-matrix diagonal; RBF: "
                       "Rippa 1999)" if groups is None else
                       f"leave-one-scene-out over {int(groups.max()) + 1} groups (lattice, "
                       "inverse tone curves, RBF: Dubrule 1983 block form)"),
        "groups": None if groups is None else np.bincount(groups).tolist(),
        "neutral_weighting": options.neutral_weighting,
        "forward_lut_smoothness": flut.smoothness,
        "forward_lut_validation_rmse": {k: v * 255 for k, v in flut.validation.items()},
        "inverse_tone_smoothness": getattr(bwd.inverse_curves, "smoothness",
                                           options.inverse_smoothness),
        "backward_lut_smoothness": blut.smoothness,
        "backward_lut_validation_rmse": blut.validation,
        "rbf_smoothing": None if rbf is None else rbf.smoothing,
        "rbf_smoothing_validation": {} if rbf is None else rbf.validation,
        "matrix_search": {
            "method": options.matrix_method, "n_sets": int(options.n_sets),
            "set_size": fwd.set_size,
            "chosen_set": int(fwd.chosen_set), "set_train_rmse": fwd.set_errors,
            "satisfied": [i["satisfied"] for i in fwd.info],
            "constraints": [i["constraints"] for i in fwd.info],
            "failed_sets": len(fwd.failures),
        },
        "seconds": seconds,
    }


def fit_pipeline(raw_samples: npt.ArrayLike, rendered_samples: npt.ArrayLike,
                 options: PipelineOptions | None = None, *, n_train: int | None = None,
                 seed: int = 0, groups: npt.ArrayLike | None = None,
                 progress: Progress | None = None) -> PipelineModel:
    """Fit a camera pipeline, raw -> rendered and back, from corresponding samples.

    The rank-based radiometric calibration of [Gong2018] with the RBF inverse
    colour mapping of [Lin2011]:

    1. Colour matrix ``M`` (§3.2, Eq. 4-8): for each of ``n_sets`` random sets of
       ``set_size`` samples, rows from rank-order half-space constraints
       (:func:`~selfcal.pipeline.matrix.rank_based_matrix`), scaled so the brightest
       training sample maps to 1 per channel
       (:func:`~selfcal.pipeline.matrix.row_scales`); the set whose full forward pipeline
       (steps 2-3) has the lowest training error is kept ("best luck", §3.2).
    2. Tone curves ``f`` (§3.3, Eq. 9): monotone smooth 7th-order polynomials by QP.
    3. Forward gamut correction (§3.4): 5×5×5 lattice regression on ``g(f(M ρ))``.
    4. Backward (§3.5): ``f⁻¹`` by the same QP (λ by cross-validation), then both (a) the
       backward 5×5×5 lattice LUT on ``g(M⁻¹ f⁻¹(P))`` and (b) the RBF ``h⁻¹`` of Lin et
       al. Eq. 10-11 (``E = M⁻¹ h⁻¹(f⁻¹(P))``, up to 1,500 control points).  With
       ``backward="auto"`` the variant with the lower held-out error over all training
       samples is used; both errors are in :attr:`PipelineModel.diagnostics`
       (``backward_validation_rmse``; ``..._unclipped`` for the unclipped samples alone).
    5. Clipped pixels (a channel at 0 or 255; the code does not determine the raw): for a
       channel with no training sample at 255 whose ``f⁻¹`` stays below the white
       ``M ρ_w`` (``ρ_w ∝ M⁻¹ 1`` with its largest raw channel at saturation), the top
       code's last half code runs up to that white (:attr:`MonotonePolynomial.top`): the
       prior that JPEG white is where the sensor saturates.  Otherwise the
       conditional expectation ``E[ρ | P]`` learned from the clipped training samples, as
       a kernel-regression correction of the backward model chosen by leave-one-out
       (:func:`~selfcal.pipeline.clipped.clipped_pixel_correction`; none without clipped
       training samples, or when it does not predict held-out ones better).

    Every fit keeps a subsample of its training colours
    (:class:`~selfcal.pipeline.trust.TrainingColours`) for
    :meth:`PipelineModel.outside_training`.

    Held-out errors are leave-one-out errors in closed form (both the lattice regression
    and the RBF are linear smoothers; the inverse curves' λ uses 5-fold cross-validation):
    they choose the regulariser weights of the two LUTs and the RBF smoothing, and compare
    the backward variants -- every sample serves for fitting and for validation, which
    matters in the 140-sample one-shot setting.
    Rendered samples clipped at 0 or 255 are left out of the backward fits (they do not
    determine the raw) and train only the clipped-pixel correction (step 5); raw samples
    need no such care (the camera rendered the clipped raw it recorded).

    Parameters
    ----------
    raw_samples : array_like
        ``(n, 3)`` linear camera RGB in ``[0, 1]`` (black subtracted, divided by the white
        level; white-balanced or not -- the matrix absorbs the white balance).
    rendered_samples : array_like
        ``(n, 3)`` rendered RGB in ``[0, 1]`` (JPEG codes / 255; uint8 is accepted too).
    options : PipelineOptions, optional
        The matrix search, the regulariser weights, the backward variant and its table
        (default ``PipelineOptions()``).
    n_train : int, optional
        Use a seeded random subset of this many samples (default: all).
    seed : int
        Seeds every random choice (subset, matrix sets, RBF control points).
    groups : array_like, optional
        ``(n,)`` labels of the pair (scene) each sample comes from.  With two or more
        groups every ``"auto"`` regulariser weight (forward and backward LUT, inverse
        tone curves, RBF smoothing) is chosen by leave-one-scene-out instead of
        leave-one-sample-out: the weight that predicts a scene the fit did not see, which
        is what a model calibrated on some pictures is used for.  The backward variant
        is then chosen by the same held-out errors.
    progress : callable, optional
        ``progress(stage, done, total, detail)``; stages ``"matrix"`` and ``"backward"``.

    Returns
    -------
    PipelineModel

    Raises
    ------
    InputError
        Wrong shapes, NaN or infinite values, values far outside ``[0, 1]``, bad options.
    TypeError
        ``options`` that is not a :class:`PipelineOptions`.
    CalibrationError
        Fewer than 30 samples, samples without colour variety (the matrix is not
        determined), or a fit that cannot be solved.

    Examples
    --------
    >>> from selfcal import sim
    >>> from selfcal.pipeline import PipelineOptions, fit_pipeline
    >>> pair = sim.simulate_raw_jpeg_pair(seed=0)
    >>> raw = pair["raw"].reshape(-1, 3); jpg = pair["rendered"].reshape(-1, 3) / 255
    >>> model = fit_pipeline(raw, jpg, PipelineOptions(n_sets=2), n_train=800)
    >>> model.diagnostics["forward_train_rmse"] < 4       # 0-255 scale
    True
    """
    t_start = time.perf_counter()
    options = PipelineOptions() if options is None else options
    if not isinstance(options, PipelineOptions):
        raise TypeError(f"options must be a PipelineOptions, got {type(options).__name__}")
    seeds = np.random.SeedSequence(seed).spawn(3)   # subset, matrix sets, RBF centres
    raw, rendered, n_given, groups = _training_samples(raw_samples, rendered_samples,
                                                       n_train, seeds[0], groups)

    t0 = time.perf_counter()
    fwd = _fit_forward(raw, rendered, groups, options, rng=np.random.default_rng(seeds[1]),
                       progress=progress)
    m, m_inv = fwd.matrix, np.linalg.inv(fwd.matrix)
    t_forward = time.perf_counter() - t0

    t0 = time.perf_counter()
    bwd = _fit_backward(raw, rendered, m, m_inv, options,
                        rbf_seed=int(seeds[2].generate_state(1)[0]), progress=progress,
                        groups=groups)
    t_backward = time.perf_counter() - t0

    diagnostics = _diagnostics(raw, rendered, m_inv, fwd, bwd, options, n_given=n_given,
                               seed=seed, seconds={"forward": t_forward, "backward": t_backward},
                               groups=groups)
    model = _baked_model(fwd, bwd, diagnostics, options.bake_size, TrainingColours.from_samples(
        raw, rendered, seed=int(seeds[0].generate_state(1)[0])))
    diagnostics["seconds"]["total"] = time.perf_counter() - t_start
    return model


def _fit_forward(raw, rendered, groups, options: PipelineOptions, *, rng, progress):
    """Steps 1-3 of :func:`fit_pipeline`: the colour matrix of the best random set, its
    tone curves and forward lattice LUT (the LUT's weight then chosen by held-out error
    when ``lut_smoothness="auto"``)."""
    lut_smoothness = options.lut_smoothness
    search_lut = LUT_SMOOTHNESS if lut_smoothness == "auto" else float(lut_smoothness)
    fwd = _search_matrix_sets(raw, rendered, n_sets=options.n_sets, set_size=options.set_size,
                              matrix_method=options.matrix_method,
                              smoothness=options.smoothness, search_lut=search_lut, rng=rng,
                              progress=progress,
                              tone_weights=_neutral_weights(rendered,
                                                            options.neutral_weighting))
    if lut_smoothness == "auto":
        _refit_forward_lut(raw, rendered, fwd, groups)
    return fwd


def _baked_model(fwd, bwd, diagnostics, bake_size, training_colours) -> PipelineModel:
    """The :class:`PipelineModel` of the fitted pieces, its backward table baked now (so
    that ``to_raw`` is fast from the first call)."""
    model = PipelineModel(ForwardStages(matrix=fwd.matrix, tone_curves=fwd.curves,
                                        lut=fwd.lut),
                          BackwardStages(inverse_tone_curves=bwd.inverse_curves, lut=bwd.lut,
                                         rbf=bwd.rbf, clipped_corrections=bwd.corrections),
                          backward=bwd.variant, diagnostics=diagnostics,
                          bake_size=bake_size, training_colours=training_colours)
    t0 = time.perf_counter()
    model.bake_backward(bwd.variant)
    diagnostics["seconds"]["bake"] = time.perf_counter() - t0
    return model
