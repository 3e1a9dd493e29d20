"""What several test modules share: the recording of the RAW-path fits and the error of a
response curve against the simulator's truth."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture
def fit_calls(monkeypatch):
    """Record what calibrate / calibrate_pipeline give the real fit_pipeline, which runs.

    A list of ``(raw_samples, rendered_samples, options)``, one per fit; ``options`` holds
    the keyword arguments (``groups`` only when it is given) and, spread in, the fields of
    the ``PipelineOptions`` given that differ from their defaults (the knobs a caller set).
    """
    import selfcal.choose.paths

    calls = []
    fit = selfcal.choose.paths.fit_pipeline

    @functools.wraps(fit)
    def recording_fit(raw_samples, rendered_samples, options=None, **keywords):
        knobs = {} if options is None else {
            f.name: getattr(options, f.name) for f in dataclasses.fields(options)
            if getattr(options, f.name) != f.default}
        given = {k: v for k, v in keywords.items() if not (k == "groups" and v is None)}
        calls.append((raw_samples, rendered_samples, {**knobs, **given}))
        return fit(raw_samples, rendered_samples, options, **keywords)

    monkeypatch.setattr(selfcal.choose.paths, "fit_pipeline", recording_fit)
    return calls


def rmse_vs_truth(model, stack, codes: slice = slice(1, -1)) -> float:
    """RMSE of the model's f⁻¹ against the simulated stack's true f⁻¹ over ``codes``
    (default 1 … max code − 1: the codes that are neither black nor white)."""
    truth = stack.inverse_response()
    est = model.inverse_response(np.arange(stack.max_code + 1))
    return float(np.sqrt(np.mean((est[codes] - truth[codes]) ** 2)))


def dim_training_pixels():
    """A simulated RAW+JPEG pair and 1,200 of its pixels that are dim and weakly coloured:
    ``(raw, jpg, pick)`` with ``raw`` float64 and ``jpg`` uint8 codes, both ``(n, 3)``.
    A model fitted to them has bright saturated colours outside its training colours."""
    from selfcal import sim

    p = sim.simulate_raw_jpeg_pair(
        sim.make_scene(96, 144, dynamic_range_stops=8.0, saturation=0.6, seed=3), seed=3)
    raw = p["raw"].reshape(-1, 3).astype(np.float64)
    jpg = p["rendered"].reshape(-1, 3)
    sat = (raw.max(1) - raw.min(1)) / np.maximum(raw.max(1), 1e-6)
    pick = np.flatnonzero((raw.max(1) < 0.35) & (raw.max(1) > 0.01) & (sat < 0.6))
    return raw, jpg, np.random.default_rng(0).choice(pick, 1200, replace=False)


FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


@pytest.fixture(scope="session")
def pair_model_file(tmp_path_factory):
    """The RAW-path model file ``selfcal calibrate`` writes for the fixture RAW+JPEG pair
    (16-bit linear TIFF + JPEG); one calibration for every test module that reads it."""
    from selfcal_cli.main import main

    out = tmp_path_factory.mktemp("pair_model") / "camera.json"
    assert main(["calibrate", str(FIXTURES / "pair" / "pair.tiff"),
                 str(FIXTURES / "pair" / "pair.jpg"), "-o", str(out)]) == 0
    return out


@pytest.fixture(scope="session")
def pair_pixels_model():
    """A RAW-path model fitted to 600 pixels of the fixture pair (backward: lattice LUT; the
    RBF variant goes through the same dense table), for the export tests."""
    from selfcal.io import read_image
    from selfcal.pipeline import PipelineOptions, fit_pipeline

    raw = read_image(FIXTURES / "pair" / "pair.tiff").reshape(-1, 3) / 65535.0
    jpg = read_image(FIXTURES / "pair" / "pair.jpg").reshape(-1, 3)
    idx = np.random.default_rng(0).choice(raw.shape[0], 600, replace=False)
    return fit_pipeline(raw[idx], jpg[idx] / 255.0, PipelineOptions(n_sets=2, backward="lut"),
                        n_train=600, seed=0)
