"""ntu's 8 s frame: merged with its EXIF time and flagged, or left out (issue 26, (c)).

The 17 ntu frames (Canon EOS M3, ISO 6400; ntu01-16 at 1/2000 … 1/100 s, ntu36 at 8 s),
decoded at 1/4 (libjpeg DCT scaling), merged by ``merge_hdr`` with the EXIF times and a
curve calibrated on the fly -- which ignores ntu36 (it shares almost no unclipped sample
with any other frame) -- once as before issue 26 (``selfcal.hdr.merge.MERGE_UNCHECKED =
False``: the frame is left out) and once as now (merged with its time, its pixels flagged
``HDRResult.unchecked``).  Printed: the share of the image unmeasured (filled with a bound)
and flagged unchecked, the merge's warnings about ntu36, and on the pixels now flagged
the ratio of the new value to the old fill (the fill is the brightest frame's
f⁻¹(I)/e at codes of 2-3, where f⁻¹ is near 0: not a useful bound), and the flagged pixels'
radiance against the checked ones' (shadows only the 8 s frame sees should be darker).

    python bench/bench_hdr_unchecked.py
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import real_stacks  # noqa: E402


def main():
    import selfcal
    from bench_hdr_oddeven import sorted_frames
    from selfcal.hdr import merge

    warnings.filterwarnings("ignore")
    t0 = time.perf_counter()
    paths, times = real_stacks()["ntu"]
    frames, paths, times = sorted_frames("ntu", paths, times, 4)
    model = selfcal.calibrate_response(frames, times)
    out = {}
    for label, on in (("before (left out)", False), ("now (merged, flagged)", True)):
        merge.MERGE_UNCHECKED = on
        try:
            out[label] = selfcal.merge_hdr(frames, times)
        finally:
            merge.MERGE_UNCHECKED = True
    h, w = frames[0].shape[:2]
    print(f"ntu, {len(frames)} frames at {w}×{h} (1/4), EXIF times; the calibration "
          f"used {len(model.diagnostics['frames_used'])} frames\n")
    for label, r in out.items():
        unchecked = 0.0 if r.unchecked is None else float(r.unchecked.mean())
        print(f"{label}: unmeasured {100 * r.unmeasured.mean():.1f}% of the pixels, "
              f"unchecked {100 * unchecked:.1f}%; frame used fractions "
              f"{[round(f, 3) for f in r.diagnostics['frame_used_fraction']][-2:]} (last two)")
        for line in r.warnings:
            if "array #16" in line and not line.startswith("calibration"):
                print(f"  warning: {line}")
    now, before = out["now (merged, flagged)"], out["before (left out)"]
    flagged = now.unchecked
    if flagged is not None and flagged.any():
        ratio = (now.radiance[flagged].astype(np.float64)
                 / before.radiance[flagged].astype(np.float64))
        ok = np.isfinite(ratio) & (ratio > 0)
        q = np.percentile(ratio[ok], [10, 50, 90])
        print(f"\non the pixels now flagged unchecked ({100 * flagged.mean():.1f}%): "
              f"new value / old fill, p10 {q[0]:.3g}, median {q[1]:.3g}, p90 {q[2]:.3g}; "
              f"of them unmeasured before: {100 * before.unmeasured[flagged].mean():.1f}%")
        checked = ~now.unmeasured & ~flagged
        qf = np.percentile(now.radiance[flagged].max(axis=1), [50, 90, 99])
        qc = np.percentile(now.radiance[checked].min(axis=1), [1, 10, 50])
        print(f"their radiance (largest channel) p50 / p90 / p99: {qf[0]:.3g} / {qf[1]:.3g} / "
              f"{qf[2]:.3g}; the checked pixels' (smallest channel) p1 / p10 / p50: "
              f"{qc[0]:.3g} / {qc[1]:.3g} / {qc[2]:.3g}")
    print(f"\nwall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
