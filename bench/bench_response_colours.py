"""Issue 3: do neutral and coloured pixels ask for the same per-channel curve on memorial and piccante?

The acceptance-2 metric (``bench.real_stack_metrics.log_linearisation_error``) scores the residual
r = log f⁻¹(I′) − log f⁻¹(I) − log(t′/t) of every adjacent exposure pair, over pixels with
all channels in [25, 235] in both frames.  If one per-channel curve could hold for all
pixels, r would centre on 0 at every code whatever the pixel's colour.  This script
prints the mean r, for selfcal's curve and OpenCV Robertson's, at one channel and range of
the darker frame's codes, split by HSV saturation (the larger of the pair's; Lin et al.
§5 rejects above β = 0.5): where the bands' means differ by the same amount for both
curves, no per-channel curve can zero both.

A second table tests whether the window [25, 235] causes the split on memorial (by
selecting pixels whose bright channel has negative noise): the saturated pixels of the
first table, split by the brighter frame's largest code.

    python bench/bench_response_colours.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import opencv_inverse_response, read_real_stacks, table  # noqa: E402

from selfcal.stack.samples import hsv_saturation  # noqa: E402

LO, HI = 25, 235
# stack -> (channel, darker frame's codes [lo, hi]): where the first table looks
CELLS = {"memorial": (2, 25, 63), "piccante": (0, 91, 235)}
BANDS = [("< 0.3", 0.0, 0.3), ("0.3 – 0.5", 0.3, 0.5), ("≥ 0.5", 0.5, 1.01)]
LARGEST = [("< 150", 0, 150), ("150 – 219", 150, 220), ("220 – 235", 220, 236)]


def pair_pixels(images, times, lut_by_curve, channel):
    """Per adjacent pair (sorted by time), over the metric's pixels: the darker frame's code
    of the channel, the pair's saturation, the brighter frame's largest code and r per
    curve (concatenated over pairs)."""
    order = np.argsort(times)
    out = {"code": [], "sat": [], "largest": [], **{k: [] for k in lut_by_curve}}
    for a, b in zip(order[:-1], order[1:]):
        ia, ib = images[a], images[b]
        ok = ((ia >= LO) & (ia <= HI)).all(axis=2) & ((ib >= LO) & (ib <= HI)).all(axis=2)
        ca, cb = ia[..., channel][ok], ib[..., channel][ok]
        out["code"].append(ca)
        out["sat"].append(np.maximum(hsv_saturation(ia[ok] / 255.0),
                                     hsv_saturation(ib[ok] / 255.0)))
        out["largest"].append(ib[ok].max(axis=1))
        for key, lut in lut_by_curve.items():
            log_lut = np.log(np.maximum(lut[:, channel], 1e-12))
            out[key].append(log_lut[cb] - log_lut[ca] - np.log(times[b] / times[a]))
    return {k: np.concatenate(v) for k, v in out.items()}


def main():
    import selfcal

    stacks = read_real_stacks(CELLS)
    band_rows, largest_rows = [], []
    for name, (channel, lo, hi) in CELLS.items():
        images, times = stacks[name]
        luts = {"selfcal": selfcal.calibrate_response(images, times).inverse_response(),
                "robertson": opencv_inverse_response(images, times, "robertson")}
        px = pair_pixels(images, times, luts, channel)
        cell = (px["code"] >= lo) & (px["code"] <= hi)
        for label, s0, s1 in BANDS:
            sel = cell & (px["sat"] >= s0) & (px["sat"] < s1)
            band_rows.append([name, "RGB"[channel], f"{lo}–{hi}", label, f"{sel.sum()}",
                              f"{px['selfcal'][sel].mean():+.3f}",
                              f"{px['robertson'][sel].mean():+.3f}"])
        if name == "memorial":
            for label, l0, l1 in LARGEST:
                sel = cell & (px["sat"] >= 0.5) & (px["largest"] >= l0) & (px["largest"] < l1)
                largest_rows.append([name, label, f"{sel.sum()}",
                                     f"{px['selfcal'][sel].mean():+.3f}",
                                     f"{px['robertson'][sel].mean():+.3f}"])
    print("Mean of log f⁻¹(I') − log f⁻¹(I) − log(t'/t) over adjacent pairs and the metric's "
          "pixels, at one channel and range of the darker frame's codes, by HSV saturation\n")
    print(table(["stack", "channel", "codes", "saturation", "pixel pairs", "selfcal",
                 "OpenCV Robertson"], band_rows))
    print("\nmemorial, saturation ≥ 0.5, the same blue codes, by the brighter frame's "
          "largest code\n")
    print(table(["stack", "largest code", "pixel pairs", "selfcal", "OpenCV Robertson"],
                largest_rows))


if __name__ == "__main__":
    main()
