"""The merge's bias on real stacks: the curve or the weights?  Each merge with each curve.

The odd/even protocol of ``bench_hdr_oddeven.py`` (frames in exposure order, one curve
calibrated from all frames, the odd and the even frames merged separately, agreement of
the two maps after one global scale on the pixels both halves measure -- the same
``measured`` mask, ``agreement`` and ``block_agreement`` functions), with the curves and
the merges crossed:

* curves: selfcal's ``calibrate_response`` (defaults) and colour-hdri's
  ``camera_response_functions_Debevec1997`` (its defaults), both as f⁻¹ on the 256 codes
  (colour-hdri's made non-decreasing and clipped at 0 for selfcal, which needs a monotone
  table; f⁻¹(255) = 1 for both -- a common scale does not change the score);
* merges: selfcal's ``merge_hdr`` (defaults; a ``ResponseModel`` holding colour-hdri's
  table carries no stuck codes and no frames-used list, so those come from the frames)
  and colour-hdri's ``image_stack_to_HDRI`` (its defaults, with the given
  ``camera_response_functions``).

Reading the table: when swapping the curve moves a merge's score to the other tool's, the
gap is the curve's; when swapping the merge does, it is the weights'.  Scores: median
|log(E_odd/E_even) − s| on 8×8 block means (bias) and per pixel.

    python bench/bench_hdr_attribution.py [--only fujifilm_xh1/scene2 ...] [--reduce 1]

Default stacks: the ones where selfcal's default stayed above the peers after averaging
(Fujifilm X-H1 scenes 2 and 3, Sony ILCE-6400 scene 3; held out) and the tuning scenes of
those cameras.
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

DEFAULT = ("fujifilm_xh1/scene1", "fujifilm_xh1/scene2", "fujifilm_xh1/scene3",
           "sony_ilce6400/scene1", "sony_ilce6400/scene3")


def _selfcal_model(inverse, sources):
    from selfcal.response.model import ResponseModel

    inv = np.maximum.accumulate(np.clip(np.asarray(inverse, float), 0.0, None), axis=0)
    inv = inv / inv[-1]
    return ResponseModel(intensity=np.arange(256) / 255.0, inverse=inv,
                         coefficients=np.zeros((3, 1)), basis_name="table",
                         exposures=np.full(len(sources), np.nan),
                         exposure_times=[None] * len(sources), sources=list(sources))


def run(name, paths, times, reduce):
    import selfcal
    from bench_hdr_oddeven import (BLOCK, TUNING, agreement, block_agreement, exposure_meta,
                                   measured)
    from colour_hdri import (Image, ImageStack, Metadata,
                             camera_response_functions_Debevec1997, image_stack_to_HDRI)
    from selfcal.io import read_image

    order = np.argsort(np.asarray(times, float), kind="stable")
    paths = [paths[k] for k in order]
    times = [float(times[k]) for k in order]
    frames = [read_image(p, reduce=reduce) for p in paths]
    meta = exposure_meta(paths)
    n = len(frames)
    halves = (tuple(range(1, n, 2)), tuple(range(0, n, 2)))
    mask = measured([frames[k] for k in halves[0]]) & measured([frames[k] for k in halves[1]])

    def stack(indices):
        s = ImageStack()
        for k in indices:
            f, iso = meta[k]
            s.append(Image(data=frames[k] / 255.0,
                           metadata=Metadata(f_number=f, exposure_time=times[k], iso=iso)))
        return s

    model = selfcal.calibrate_response(frames, times)
    curves = {"selfcal": model.inverse_response(),
              "colour-hdri": np.asarray(camera_response_functions_Debevec1997(
                  stack(range(n))), float)}
    curves["colour-hdri"] = curves["colour-hdri"] / curves["colour-hdri"][-1]
    out = {"name": name, "split": "tuning" if name in TUNING else "held out"}
    for curve_name, inv in curves.items():
        m = model if curve_name == "selfcal" else _selfcal_model(inv, model.sources)
        maps = [selfcal.merge_hdr([frames[k] for k in h], [times[k] for k in h], m).radiance
                for h in halves]
        out[("selfcal", curve_name)] = (block_agreement(*maps, mask, BLOCK)[0],
                                        agreement(*maps, mask)[0])
        maps = [image_stack_to_HDRI(stack(h), camera_response_functions=inv) for h in halves]
        out[("colour-hdri", curve_name)] = (block_agreement(*maps, mask, BLOCK)[0],
                                            agreement(*maps, mask)[0])
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append")
    parser.add_argument("--reduce", type=int, default=1)
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")
    from bench_hdr_oddeven import stack_list
    from threadpoolctl import threadpool_limits

    stacks = stack_list()
    names = args.only or list(DEFAULT)
    t0 = time.perf_counter()
    rows = []
    combos = [("selfcal", "selfcal"), ("selfcal", "colour-hdri"),
              ("colour-hdri", "colour-hdri"), ("colour-hdri", "selfcal")]
    with threadpool_limits(limits=1, user_api="blas"):
        for name in names:
            r = run(name, *stacks[name], args.reduce)
            rows.append([name, r["split"]] + [f"{r[c][0]:.4f} / {r[c][1]:.4f}"
                                              for c in combos])
            print(f"[{name}: {time.perf_counter() - t0:.0f} s]", file=sys.stderr, flush=True)
    print("Odd/even median |log ratio| after one global scale, 8×8 block means / per pixel "
          f"(JPEGs decoded at 1/{args.reduce}):\n")
    print(table(["stack", "split"] + [f"{m} merge, {c} curve" for m, c in combos], rows))
    print(f"\nwall {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
