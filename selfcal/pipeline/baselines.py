"""Baseline pipeline models fitted from the same samples (for comparisons and benchmarks).

* :func:`independent_polynomial_model` -- "IndPoly": a 3×3 least-squares matrix and three
  independent per-channel polynomial tone curves, no gamut mapping (Chakrabarti,
  Scharstein & Zickler, *An empirical camera model for internet color vision*, BMVC 2009;
  the IndPoly baseline of [Gong2018] §4).
* :func:`least_squares_rbf_model` -- [Lin2011] §6 as
  published: per-channel response ``f⁻¹`` and a least-squares ``T`` from desaturated
  samples (HSV saturation <= β, none clipped; their §5 outlier rule), then RBF colour
  mappings ``h⁻¹`` (Eq. 10-11) and, for the forward direction, ``h``.

Both alternate least squares between the 3×3 matrix ``B = T⁻¹`` (``ρ ≈ B g(P)``) and the
per-channel curves ``g = f⁻¹`` (7th-order monotone polynomials, the QP of [Gong2018]
Eq. 9), starting from ``g(P) = P^2.2``, with ``g_k(1) = 1``.
"""

from __future__ import annotations

import numpy as np

from ..errors import CalibrationError
from ..stack.samples import hsv_saturation
from .clipped import clipped_mask
from .rbf import N_CONTROL_POINTS, rbf_inverse_colour_mapping
from .tone import SMOOTHNESS, MonotonePolynomial, monotone_tone_curves

_UNIT = np.array([[0.0, 1.0]] * 3)


def _alternating_fit(raw, rendered, iterations, smoothness):
    """ALS for ``ρ ≈ B g(P)``: returns ``B`` and ``g`` (MonotonePolynomial, g_k(1) = 1)."""
    ok = ~clipped_mask(rendered)
    if ok.sum() < 20:
        raise CalibrationError(f"only {int(ok.sum())} unclipped samples for the baseline fit")
    p, rho = rendered[ok], raw[ok]
    g_p = p ** 2.2
    g = None
    for _ in range(int(iterations)):
        bt, *_ = np.linalg.lstsq(g_p, rho, rcond=None)
        b = bt.T
        target = rho @ np.linalg.inv(b).T
        g = monotone_tone_curves(p, target, smoothness=smoothness, domain=_UNIT)
        top = np.array([g.channel(1.0, k) for k in range(3)])
        if np.any(top <= 0):
            raise CalibrationError("the alternating baseline fit diverged")
        g = MonotonePolynomial(g.coefficients / top[:, None], g.domain)
        g_p = g(p)
    bt, *_ = np.linalg.lstsq(g_p, rho, rcond=None)
    return bt.T, g


class BaselineModel:
    """A fitted baseline with the :class:`~selfcal.pipeline.PipelineModel` interface
    (``render``, ``to_raw``; evaluated directly, float64)."""

    def __init__(self, name, t, f, g, h=None, h_inv=None):
        self.name = name
        self.matrix = t                 # T: raw -> linear output space
        self.matrix_inverse = np.linalg.inv(t)
        self.tone_curves = f            # f: linear -> rendered
        self.inverse_tone_curves = g    # g = f⁻¹: rendered -> linear
        self.h = h                      # forward colour mapping (or None)
        self.h_inv = h_inv              # inverse colour mapping (or None)

    def render(self, raw) -> np.ndarray:
        x = np.asarray(raw, dtype=np.float64)
        shape = x.shape
        e = x.reshape(-1, 3) @ self.matrix.T
        if self.h is not None:
            e = self.h(e)
        return np.clip(self.tone_curves(e), 0, 1).reshape(shape)

    def to_raw(self, rendered) -> np.ndarray:
        p = np.asarray(rendered)
        p = p / 255.0 if p.dtype == np.uint8 else np.asarray(p, dtype=np.float64)
        shape = p.shape
        e = self.inverse_tone_curves(np.clip(p.reshape(-1, 3), 0, 1))
        if self.h_inv is not None:
            e = self.h_inv(e)
        return np.clip(e @ self.matrix_inverse.T, 0, 1).reshape(shape)


def _forward_curves(x, rendered, smoothness):
    return monotone_tone_curves(x, rendered, smoothness=smoothness)


def independent_polynomial_model(raw_samples, rendered_samples, *, iterations: int = 8,
                                 smoothness: float = SMOOTHNESS) -> BaselineModel:
    """IndPoly: ``P = f(T ρ)`` with a 3×3 ``T`` and per-channel polynomials (no gamut map).

    Chakrabarti, Scharstein & Zickler, BMVC 2009 (the "IndPoly" of [Gong2018] §4): the
    backward form ``ρ ≈ T⁻¹ f⁻¹(P)`` by alternating least squares on the unclipped
    samples; the forward curves ``f`` are then fitted to ``(T ρ, P)`` on all samples.

    Parameters
    ----------
    raw_samples, rendered_samples : array_like
        ``(n, 3)`` in ``[0, 1]``.
    iterations : int
    smoothness : float
        λ of the polynomial QP ([Gong2018] Eq. 9).

    Returns
    -------
    BaselineModel
    """
    raw = np.asarray(raw_samples, dtype=np.float64)
    rendered = np.asarray(rendered_samples, dtype=np.float64)
    b, g = _alternating_fit(raw, rendered, iterations, smoothness)
    t = np.linalg.inv(b)
    f = _forward_curves(raw @ t.T, rendered, smoothness)
    return BaselineModel("IndPoly", t, f, g)


def least_squares_rbf_model(raw_samples, rendered_samples, *, beta: float = 0.4,
                            iterations: int = 8, smoothness: float = SMOOTHNESS,
                            n_centres: int = N_CONTROL_POINTS, seed: int = 0) -> BaselineModel:
    """[Lin2011] §6 as published: least-squares ``T``, ``f⁻¹`` and RBF ``h⁻¹``.

    ``f⁻¹`` and ``T`` come from the desaturated samples (HSV saturation of the rendered
    colour <= ``beta`` and no channel clipped -- the outlier rule of their §5, β = 0.4 for
    cameras with strong colour mapping), by alternating least squares; then ``h⁻¹``
    (Eq. 10) maps ``f⁻¹(P)`` to ``T ρ`` with ~1,500 control points (RBFInterpolator,
    linear kernel, affine part, smoothing chosen on held-out samples), so that
    ``ρ = T⁻¹ h⁻¹(f⁻¹(P))`` (Eq. 11).  The forward direction uses the RBF ``h`` fitted
    the other way round and ``f`` fitted as a monotone polynomial: ``P = f(h(T ρ))``
    (their Eq. 9).

    Parameters
    ----------
    raw_samples, rendered_samples : array_like
        ``(n, 3)`` in ``[0, 1]``.
    beta : float
        Saturation threshold of the desaturated set.
    iterations : int
    smoothness : float
    n_centres : int
    seed : int

    Returns
    -------
    BaselineModel
    """
    raw = np.asarray(raw_samples, dtype=np.float64)
    rendered = np.asarray(rendered_samples, dtype=np.float64)
    saturation = hsv_saturation(rendered)
    desat = saturation <= beta
    if desat.sum() < 30:  # too few grey-ish samples: fall back to the least saturated
        desat = saturation <= np.sort(saturation)[min(len(rendered) - 1, 29)]
    b, g = _alternating_fit(raw[desat], rendered[desat], iterations, smoothness)
    t = np.linalg.inv(b)
    ok = ~clipped_mask(rendered)
    e = g(rendered[ok])
    te = raw[ok] @ t.T
    h_inv = rbf_inverse_colour_mapping(e, te, n_centres=n_centres, seed=seed,
                                       error_transform=lambda v: v @ b.T)
    h = rbf_inverse_colour_mapping(te, e, n_centres=n_centres, seed=seed)
    # f: linear (f⁻¹(P)) -> P, fitted on all samples
    f = _forward_curves(g(rendered), rendered, smoothness)
    return BaselineModel("LS-T + RBF (Lin et al. 2011)", t, f, g, h=h, h_inv=h_inv)
