"""The public API's outputs on the built-in inputs, frozen: a refactoring changes none.

A change that is not meant to move a result (modules moved into packages, options
objects, duplicates removed) must not change a single one.  This test computes what
``selfcal``'s public functions return on the committed fixtures and on the built-in demo
stack and compares them with ``tests/golden/public_api.npz``, written by::

    python tests/test_golden.py --write

only by a commit that changes a method on purpose and says so (its git log: issue 26's
weights, issue 35's hidden white samples and measured exposures).  Integer arrays (masks, the demo's JPEG codes) must
agree exactly; float arrays within ``RELATIVE_TOLERANCE`` of their largest magnitude: enough
for another BLAS, thread count or library release to round differently, far too little for a
changed method.  ``scripts/golden_spread.py`` measures that spread (docs/decisions.md, "The
golden test's tolerance").
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
GOLDEN = REPO / "tests" / "golden" / "public_api.npz"
FIXTURES = REPO / "fixtures"
#: Of each float array's largest magnitude (docs/decisions.md: the measured spread is
#: below 2e-13).
RELATIVE_TOLERANCE = 1e-9


def _public_outputs() -> dict[str, np.ndarray]:
    import selfcal
    from selfcal import sim

    out: dict[str, np.ndarray] = {}
    frames = sorted(str(p) for p in (FIXTURES / "stack").glob("frame_*.jpg"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = selfcal.calibrate_response(frames)
        out["response.inverse"] = np.asarray(model.inverse, dtype=np.float64)
        out["response.exposures"] = np.asarray(model.exposures, dtype=np.float64)
        out["response.linearize"] = model.linearize(_read_rgb(frames[2]))

        hdr = selfcal.merge_hdr(frames, model=model)
        out["merge.radiance"] = np.asarray(hdr.radiance)
        out["merge.unmeasured"] = np.asarray(hdr.unmeasured, dtype=np.uint8)

        demo = sim.demo_stack(seed=0)
        out["demo.frame0"] = np.asarray(demo.images[0])
        demo_model = selfcal.calibrate_response(list(demo.images), list(demo.exposure_times))
        out["demo.inverse"] = np.asarray(demo_model.inverse, dtype=np.float64)

        pair = [str(FIXTURES / "pair" / "pair.tiff"), str(FIXTURES / "pair" / "pair.jpg")]
        raw = _read_raw16(pair[0])
        rendered = _read_rgb(pair[1])
        pm = selfcal.fit_pipeline(raw.reshape(-1, 3), rendered.reshape(-1, 3) / 255.0,
                                  selfcal.PipelineOptions(n_sets=3), n_train=800, seed=0)
        out["pipeline.render"] = np.asarray(pm.render(raw), dtype=np.float64)
        out["pipeline.to_raw"] = np.asarray(pm.to_raw(rendered), dtype=np.float64)
    return out


def _read_rgb(path: str) -> np.ndarray:
    import cv2
    return cv2.cvtColor(cv2.imread(path, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def _read_raw16(path: str) -> np.ndarray:
    import tifffile
    return tifffile.imread(path).astype(np.float64) / 65535.0


def test_public_api_outputs_unchanged():
    golden = np.load(GOLDEN)
    now = _public_outputs()
    assert sorted(now) == sorted(golden.files)
    for name, value in now.items():
        expected = golden[name]
        assert value.shape == expected.shape, name
        assert value.dtype.kind == expected.dtype.kind, name
        if expected.dtype.kind in "biu":
            np.testing.assert_array_equal(value, expected, err_msg=name)
            continue
        scale = float(np.abs(expected).max())
        np.testing.assert_allclose(value.astype(np.float64), expected.astype(np.float64),
                                   rtol=0, atol=RELATIVE_TOLERANCE * scale, err_msg=name)


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        sys.exit("usage: python tests/test_golden.py --write")
    GOLDEN.parent.mkdir(exist_ok=True)
    np.savez_compressed(GOLDEN, **_public_outputs())
    print(f"wrote {GOLDEN}")
