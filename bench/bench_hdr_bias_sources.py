"""The merge's bias on real stacks: near white, or elsewhere?  selfcal's merge varied.

The odd/even protocol of ``bench_hdr_oddeven.py`` (frames in exposure order, one curve
from all frames, the odd and the even frames merged separately, median |log(E_odd/E_even)
− s| on 8×8 block means and per pixel, on the pixels both halves measure), with selfcal's
merge changed one thing at a time:

* ``default``: ``merge_hdr`` as it is; ``before``: without the code-error term of issue 26
  (``selfcal.hdr.weights.USE_CODE_ERROR = False``); ``hat``: ``weighting="hat"``;
* ``before, codes > T cut``: the weights of ``before`` set to zero at normalised codes
  above T (0.9, 0.8) -- if the noise weights' trust in the brightest codes were the bias,
  this would remove it;
* ``refined exposures``: the curve calibrated with ``refine_exposures=True`` and both
  halves merged with its per-frame exposures (scaled to the EXIF units by their median
  ratio) instead of the EXIF times, default and ``before`` weights; the first columns
  print how far the pixels put each frame from its EXIF time.

    python bench/bench_hdr_bias_sources.py [--only memorial --only fujifilm_xh1/scene1 ...]

Default stacks: the tuning stacks (memorial, fujifilm_xh1/scene1, sony_ilce6400/scene1)
and fujifilm_xh1/scene2, the held-out stack where the gap to the hat is largest.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import table  # noqa: E402

DEFAULT = ("memorial", "fujifilm_xh1/scene1", "sony_ilce6400/scene1", "fujifilm_xh1/scene2")
CUTS = (0.9, 0.8)


def _cut_above(top):
    """Patch the weights of selfcal.hdr.weights._FrameTables to zero above ``top``;
    returns the undo."""
    from selfcal.hdr import weights

    orig = weights._FrameTables._weights

    def patched(self, z, x, slope):
        return orig(self, z, x, slope) * (np.asarray(z) <= top)

    weights._FrameTables._weights = patched
    return lambda: setattr(weights._FrameTables, "_weights", orig)


def run(name, paths, times):
    import selfcal
    from bench_hdr_oddeven import TUNING, agreement, block_agreement, measured, sorted_frames
    from selfcal.hdr import weights

    frames, paths, times = sorted_frames(name, paths, times, 1)
    n = len(frames)
    halves = (tuple(range(1, n, 2)), tuple(range(0, n, 2)))
    mask = measured([frames[k] for k in halves[0]]) & measured([frames[k] for k in halves[1]])
    t = np.asarray(times, float)

    def score(model, tt, weighting="noise", before=False, cut=None):
        undo = _cut_above(cut) if cut is not None else None
        weights.USE_CODE_ERROR = not before
        try:
            maps = [selfcal.merge_hdr([frames[k] for k in h], [tt[k] for k in h], model,
                                      weighting=weighting).radiance for h in halves]
        finally:
            weights.USE_CODE_ERROR = True
            if undo is not None:
                undo()
        return block_agreement(*maps, mask, 8)[0], agreement(*maps, mask)[0]

    model = selfcal.calibrate_response(frames, times)
    out = {"name": name, "split": "tuning" if name in TUNING else "held out"}
    out["default"] = score(model, t)
    out["before"] = score(model, t, before=True)
    out["hat"] = score(model, t, weighting="hat")
    for c in CUTS:
        out[f"before, codes > {c} cut"] = score(model, t, before=True, cut=c)
    refined = selfcal.calibrate_response(frames, times, refine_exposures=True)
    e = np.asarray(refined.exposures, float)
    ok = np.isfinite(e) & (e > 0)
    tt = np.where(ok, e * np.exp(np.median(np.log(t[ok] / e[ok]))), t)
    dev = np.abs(np.log(tt / t))
    out["exif off"] = (float(np.median(dev)), float(np.max(dev)))
    out["refined exposures"] = score(refined, tt)
    out["refined exposures, before"] = score(refined, tt, before=True)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")
    from bench_hdr_oddeven import stack_list
    from threadpoolctl import threadpool_limits

    stacks = stack_list()
    names = args.only or list(DEFAULT)
    cols = (["default", "before", "hat"] + [f"before, codes > {c} cut" for c in CUTS]
            + ["refined exposures", "refined exposures, before"])
    t0 = time.perf_counter()
    rows = []
    with threadpool_limits(limits=1, user_api="blas"):
        for name in names:
            r = run(name, *stacks[name])
            rows.append([name, r["split"], f"{r['exif off'][0]:.3f} / {r['exif off'][1]:.3f}"]
                        + [f"{r[c][0]:.4f} / {r[c][1]:.4f}" for c in cols])
            print(f"[{name}: {time.perf_counter() - t0:.0f} s]", file=sys.stderr, flush=True)
    print("selfcal's merge varied: odd/even median |log ratio| after one global scale, "
          "8×8 block means / per pixel (JPEGs at 1/1); |log(refined exposure / EXIF time)| "
          "median / max over the frames:\n")
    print(table(["stack", "split", "EXIF off (median / max)"] + cols, rows))
    print(f"\nwall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
