"""Backward estimates for clipped rendered pixels: a conditional expectation from samples.

A rendered value at 0 or 255 does not determine the raw: every raw beyond the clipping
threshold renders to the same code.  [Lin2011] (§5) therefore reject clipped pixels as
outliers of the fit, and [Gong2018] §3.5 fit the backward model ``f⁻¹`` and ``LUT_b`` (or
[Lin2011]'s ``h⁻¹``, Eq. 10-11) on samples that the code determines.  Applied to a clipped
pixel, that model returns its value at the clipping threshold, ``ρ(P)`` on the face of the
code cube -- the smallest raw the code allows, not the expected one.

Under squared error the best estimate of a clipped pixel's raw is the conditional
expectation ``E[ρ | P]``.  Clipped *training* samples (their raw is known) sample it
directly: selfcal fits the backward model on the unclipped samples as before and then
learns an additive correction for clipped pixels,

    ρ(P) = ρ_b(P) + δ(P),     δ(P) = Σ_i K(P, P_i) r_i / (κ + Σ_i K(P, P_i)),

a Nadaraya-Watson kernel regression (Gaussian kernel ``K`` of bandwidth ``h`` in rendered
RGB) of the residuals ``r_i = ρ_i - ρ_b(P_i)`` of the clipped training samples, shrunk
toward no correction by a prior weight ``κ`` (``κ`` pseudo-samples of residual 0).  Far
from every clipped training sample ``δ -> 0``: the fitted model is left as it is (with no
clipped training samples there is no correction at all).  ``h`` and ``κ`` are chosen by
leave-one-out error over the clipped training samples, and "no correction" competes:
the correction is kept only if it predicts held-out clipped samples better.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import cast

import numpy as np
import numpy.typing as npt

from ..errors import InputError

#: Rendered values within half a code of 0 or 255 are clipped (they do not determine the
#: raw; [Lin2011] §5 reject them as outliers).
CLIP_LO, CLIP_HI = 0.5 / 255, 254.5 / 255
#: Kernel bandwidths (rendered RGB in [0, 1]) tried by the leave-one-out choice; ``inf``
#: is a constant correction (the mean residual, shrunk).
BANDWIDTHS = (0.03, 0.06, 0.12, 0.25, 0.5, np.inf)
#: Prior weights κ (pseudo-samples of zero correction) tried by the leave-one-out choice.
PRIOR_WEIGHTS = (0.25, 1.0, 4.0)
#: Fewest clipped training samples for which a correction is tried.
MIN_CLIPPED = 3


def clipped_mask(rendered) -> np.ndarray:
    """``True`` where a rendered pixel (``(..., 3)`` in ``[0, 1]``) has a clipped channel."""
    p = np.asarray(rendered)
    # an array for (N, 3) and (H, W, 3) input (a single (3,) colour gives a numpy bool)
    return cast(np.ndarray, ((p <= CLIP_LO) | (p >= CLIP_HI)).any(axis=-1))


def _kernel(a: np.ndarray, b: np.ndarray, h: float) -> np.ndarray:
    if np.isinf(h):
        return np.ones((a.shape[0], b.shape[0]))
    from scipy.spatial.distance import cdist

    return np.exp(-0.5 * cdist(a, b, "sqeuclidean") / (h * h))


class ClippedCorrection:
    """Kernel-regression correction of the backward model at clipped pixels.

    ``δ(P) = Σ_i K(P, P_i) r_i / (κ + Σ_i K(P, P_i))`` (see the module docstring): the
    conditional expectation of the raw given a clipped code, learned from clipped
    training samples, relative to the backward model of [Gong2018] §3.5 / [Lin2011]
    Eq. 11 fitted on the unclipped ones.

    Attributes
    ----------
    points : numpy.ndarray
        ``(n, 3)`` rendered values ``P_i`` of the clipped training samples, in ``[0, 1]``.
    residuals : numpy.ndarray
        ``(n, 3)`` raw residuals ``ρ_i - ρ_b(P_i)``.
    bandwidth : float
        Gaussian kernel bandwidth ``h`` (``inf``: a constant, shrunk mean).
    prior_weight : float
        ``κ``.
    validation : dict
        Leave-one-out RMSE per ``"h,κ"`` tried and for ``"none"`` (no correction).
    """

    def __init__(self, points: npt.ArrayLike, residuals: npt.ArrayLike, bandwidth: float,
                 prior_weight: float, validation: Mapping[str, float] | None = None) -> None:
        self.points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        self.residuals = np.ascontiguousarray(residuals, dtype=np.float64).reshape(-1, 3)
        self.bandwidth = float(bandwidth)
        self.prior_weight = float(prior_weight)
        self.validation = dict(validation or {})
        if self.points.shape != self.residuals.shape or self.points.shape[0] < 1:
            raise InputError("a clipped-pixel correction needs matching (n, 3) points and "
                             "residuals")
        if not (np.all(np.isfinite(self.points)) and np.all(np.isfinite(self.residuals))):
            raise InputError("a clipped-pixel correction needs finite points and residuals")
        if not (self.bandwidth > 0 and self.prior_weight > 0):
            raise InputError("the bandwidth and prior weight of a clipped-pixel correction "
                             "must be positive")

    def __call__(self, rendered, chunk: int = 1 << 16) -> np.ndarray:
        """``δ`` at ``(N, 3)`` rendered values in ``[0, 1]`` (float64)."""
        p = np.asarray(rendered, dtype=np.float64).reshape(-1, 3)
        out = np.empty_like(p)
        for s in range(0, p.shape[0], chunk):
            k = _kernel(p[s:s + chunk], self.points, self.bandwidth)
            out[s:s + chunk] = (k @ self.residuals) / (self.prior_weight
                                                       + k.sum(axis=1))[:, None]
        return out

    def face(self, channel: int, value: float, grid: npt.ArrayLike) -> np.ndarray:
        """``δ`` on a face of the rendered cube: channel ``channel`` at ``value``, the
        other two (in increasing order) at every pair of ``grid`` values.

        The Gaussian kernel factorises over the channels, so the face costs four
        ``(G × n) @ (n × G)`` products instead of ``G² n`` kernel evaluations.

        Returns
        -------
        numpy.ndarray
            ``(G, G, 3)`` float64.
        """
        g = np.asarray(grid, dtype=np.float64).reshape(-1)
        others = [c for c in range(3) if c != channel]
        n = self.points.shape[0]
        if np.isinf(self.bandwidth):
            d = self.residuals.sum(axis=0) / (self.prior_weight + n)
            return np.broadcast_to(d, (g.size, g.size, 3)).copy()
        s = -0.5 / self.bandwidth ** 2
        w = np.exp(s * (value - self.points[:, channel]) ** 2)
        ga = np.exp(s * (g[:, None] - self.points[None, :, others[0]]) ** 2)
        gb = np.exp(s * (g[:, None] - self.points[None, :, others[1]]) ** 2)
        den = self.prior_weight + ga @ (w[:, None] * gb.T)
        out = np.empty((g.size, g.size, 3))
        for c in range(3):
            out[..., c] = ga @ ((w * self.residuals[:, c])[:, None] * gb.T) / den
        return out

    def to_dict(self) -> dict:
        return {"points": self.points.tolist(), "residuals": self.residuals.tolist(),
                "bandwidth": "inf" if np.isinf(self.bandwidth) else self.bandwidth,
                "prior_weight": self.prior_weight,
                "validation": {str(k): float(v) for k, v in self.validation.items()}}

    @classmethod
    def from_dict(cls, d: dict) -> "ClippedCorrection":
        return cls(d["points"], d["residuals"], float(d["bandwidth"]),
                   float(d["prior_weight"]), d.get("validation") or {})


def clipped_pixel_correction(rendered: npt.ArrayLike, residuals: npt.ArrayLike, *,
                             bandwidths: Sequence[float] = BANDWIDTHS,
                             prior_weights: Sequence[float] = PRIOR_WEIGHTS
                             ) -> tuple[ClippedCorrection | None, dict]:
    """Learn ``E[ρ | P]`` at clipped codes from clipped training samples (leave-one-out).

    For the backward model ([Gong2018] §3.5; [Lin2011] Eq. 10-11), fitted on
    the samples whose code determines the raw, this fits the Nadaraya-Watson correction
    of :class:`ClippedCorrection` to the residuals of the clipped samples and picks the
    bandwidth ``h`` and prior weight ``κ`` with the lowest leave-one-out RMSE (each
    sample predicted from the others: the kernel matrix with a zero diagonal).

    Parameters
    ----------
    rendered : array_like
        ``(n, 3)`` rendered values (in ``[0, 1]``) of the clipped training samples.
    residuals : array_like
        ``(n, 3)`` their raw minus the backward model's estimate.
    bandwidths, prior_weights : sequence of float
        The candidates.

    Returns
    -------
    (ClippedCorrection or None, dict)
        The correction, or None when there are fewer than :data:`MIN_CLIPPED` samples or
        when no candidate beats "no correction" on held-out samples; and the
        leave-one-out scores (``"none"``: RMSE of the residuals themselves).
    """
    p = np.asarray(rendered, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(residuals, dtype=np.float64).reshape(-1, 3)
    if p.shape != r.shape:
        raise InputError(f"rendered and residuals must both be (n, 3), got {p.shape}, "
                         f"{r.shape}")
    keep = np.all(np.isfinite(p), axis=1) & np.all(np.isfinite(r), axis=1)
    p, r = p[keep], r[keep]
    if p.shape[0] < MIN_CLIPPED:
        return None, {}
    scores = {"none": float(np.sqrt(np.mean(r ** 2)))}
    best, best_score = None, scores["none"]
    for h in bandwidths:
        k = _kernel(p, p, float(h))
        np.fill_diagonal(k, 0.0)
        ks = k.sum(axis=1)
        kr = k @ r
        for kappa in prior_weights:
            loo = r - kr / (float(kappa) + ks)[:, None]
            score = float(np.sqrt(np.mean(loo ** 2)))
            scores[f"{float(h):g},{float(kappa):g}"] = score
            if score < best_score:
                best, best_score = (float(h), float(kappa)), score
    if best is None:
        return None, scores
    return ClippedCorrection(p, r, best[0], best[1], validation=scores), scores
