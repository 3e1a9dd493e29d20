"""What several test modules share: the recording of the RAW-path fits and the error of a
response curve against the simulator's truth."""

from __future__ import annotations

import functools

import numpy as np
import pytest


@pytest.fixture
def fit_calls(monkeypatch):
    """Record what calibrate / calibrate_pipeline give the real fit_pipeline, which runs.

    A list of ``(raw_samples, rendered_samples, options)``, one per fit.
    """
    import selfcal.choose.paths

    calls = []
    fit = selfcal.choose.paths.fit_pipeline

    @functools.wraps(fit)   # calibrate routes its options by this signature: keep it
    def recording_fit(raw_samples, rendered_samples, **options):
        calls.append((raw_samples, rendered_samples, options))
        return fit(raw_samples, rendered_samples, **options)

    monkeypatch.setattr(selfcal.choose.paths, "fit_pipeline", recording_fit)
    return calls


def rmse_vs_truth(model, stack, codes: slice = slice(1, -1)) -> float:
    """RMSE of the model's f⁻¹ against the simulated stack's true f⁻¹ over ``codes``
    (default 1 … max code − 1: the codes that are neither black nor white)."""
    truth = stack.inverse_response()
    est = model.inverse_response(np.arange(stack.max_code + 1))
    return float(np.sqrt(np.mean((est[codes] - truth[codes]) ** 2)))
