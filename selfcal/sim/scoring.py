"""Scores against the simulator's truth: how far an estimated f⁻¹ is from the true one.

- :func:`rmse`, :func:`best_scale_rmse`: distance of an estimated f⁻¹ from a known one
  (synthetic stacks, where the truth is known).

The linearisation error δ_c of [Lin2011] (§7, Eq. 12) is
:func:`selfcal.response.delta.delta_eq12` (the response path reports it); the bench's
measures on real stacks, where the truth is unknown, are in ``bench/real_stack_metrics.py``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rmse", "best_scale_rmse"]


def rmse(estimate, truth) -> float:
    """Root-mean-square difference, computed in float64.

    Parameters
    ----------
    estimate, truth : array_like
        Arrays of one shape (e.g. f⁻¹ over codes 1 … 254, or images).

    Returns
    -------
    float

    Examples
    --------
    >>> rmse([0.0, 0.5, 1.0], [0.0, 0.5, 0.0])
    0.5773502691896257
    """
    d = np.asarray(estimate, np.float64) - np.asarray(truth, np.float64)
    return float(np.sqrt(np.mean(d * d)))


def best_scale_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """RMSE after the least-squares scale s minimising ||s·estimate − truth||.

    For curves known only up to a scale (OpenCV's responses have no f⁻¹(1) = 1).

    Parameters
    ----------
    estimate, truth : ndarray
        f⁻¹ over the same codes, e.g. ``lut[1:255]``.

    Returns
    -------
    float

    Examples
    --------
    A curve scaled by a constant is at distance 0:

    >>> truth = np.linspace(0.0, 1.0, 11)
    >>> best_scale_rmse(0.5 * truth, truth)
    0.0
    """
    s = float(np.sum(estimate * truth) / max(np.sum(estimate * estimate), 1e-30))
    return float(np.sqrt(np.mean((s * estimate - truth) ** 2)))
