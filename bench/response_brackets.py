"""Issue 15, Build 5: one camera, several scenes -- does its response curve stay put?

A camera's response does not change with the scene it photographs.  For each camera of
../shared/data/real_brackets (Sony ILCE-6400, 3 scenes at ISO 1600; Fujifilm X-H1, 3 scenes
at ISO 400/400/800; see its SOURCE.txt), each scene is calibrated **alone**, with its EXIF
times, by

* selfcal's ``calibrate_response`` (defaults),
* OpenCV's ``CalibrateDebevec`` and ``CalibrateRobertson`` (defaults),
* colour-hdri's ``camera_response_functions_Debevec1997`` (defaults: Grossberg sampling,
  hat weights, λ = 30),

all on the same decoded frames (the 3008×2000 Sony frames reduced 2× by libjpeg's DCT
scaling, ``read_image(reduce=2)``, for Robertson's sake; the Fujifilm frames at full size).

**Spread** (the acceptance figure of issue 15: each camera's spread below OpenCV's and
colour-hdri's): per method and camera, every curve is normalised to a mean of 1 over codes
1…254 per channel, the camera's median curve is taken code by code and normalised to 1 at
its maximum, and each scene's curve is scored by its best-scale RMSE against that median
over codes 1…254 (``selfcal.sim.scoring.best_scale_rmse``), per channel.  The table gives the
mean and the largest score over the camera's scenes and channels.

**Cross-scene linearisation** (reported, not a target: the metric's minimiser is biased,
the acceptance-2 metric): ``selfcal.sim.scoring.log_linearisation_error`` of each scene's
curve on each *other* scene of its camera (mean over the pairs), next to the same score of
each scene's curve on its own scene.

Monotone: the number of (scene, channel) curves that decrease anywhere over codes 1…254.

No tuning happens here; every method runs with its defaults.

    python3 -m bench.response_brackets [--selfcal-only]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from .data import real_bracket_scenes
from .peers import colour_hdri_inverse_response, opencv_inverse_response
from .tables import finish, start, table

METHODS = ("selfcal", "OpenCV Debevec", "OpenCV Robertson", "colour-hdri Debevec")
CODES = slice(1, 255)


def colour_hdri_curve(frames, paths, times) -> np.ndarray:
    from selfcal.io import read_exposure_info

    infos = [read_exposure_info(p) for p in paths]
    return colour_hdri_inverse_response(
        frames, times, [(i.f_number or 1.0, i.iso or 100.0) for i in infos])


def curves_of_scene(paths, times, reduce: int):
    """method -> (256, 3) f⁻¹ of one scene calibrated alone; frames; seconds per method."""
    import selfcal
    from selfcal.io import read_image

    frames = [read_image(p, reduce=reduce) for p in paths]
    out, seconds = {}, {}
    t0 = time.perf_counter()
    out["selfcal"] = selfcal.calibrate_response(frames, times).inverse_response()
    seconds["selfcal"] = time.perf_counter() - t0
    if METHODS == ("selfcal",):
        return out, frames, seconds
    for method, name in (("debevec", "OpenCV Debevec"), ("robertson", "OpenCV Robertson")):
        t0 = time.perf_counter()
        out[name] = opencv_inverse_response(frames, times, method)
        seconds[name] = time.perf_counter() - t0
    t0 = time.perf_counter()
    out["colour-hdri Debevec"] = colour_hdri_curve(frames, paths, times)
    seconds["colour-hdri Debevec"] = time.perf_counter() - t0
    return out, frames, seconds


def spread(curves) -> tuple[float, float]:
    """(mean, max) best-scale RMSE of each scene's curve from the camera's median curve."""
    from selfcal.sim.scoring import best_scale_rmse

    norm = [c[CODES] / np.mean(c[CODES], axis=0, keepdims=True) for c in curves]
    median = np.median(np.stack(norm), axis=0)
    median = median / np.max(median, axis=0, keepdims=True)
    scores = [best_scale_rmse(c[:, ch], median[:, ch]) for c in norm for ch in range(3)]
    return float(np.mean(scores)), float(np.max(scores))


def non_monotone(curves) -> int:
    return sum(int(np.any(np.diff(c[CODES, ch]) < 0)) for c in curves for ch in range(3))


def cross_scene(curves, stacks) -> tuple[float, float]:
    """(own scene, mean over other scenes) log linearisation error of each scene's curve."""
    from selfcal.sim.scoring import log_linearisation_error

    own, other = [], []
    for i, curve in enumerate(curves):
        lut = np.maximum(curve, 1e-6)   # OpenCV's and colour-hdri's curves can touch 0
        for j, (frames, times) in enumerate(stacks):
            (own if i == j else other).append(log_linearisation_error(frames, times, lut))
    return float(np.mean(own)), float(np.mean(other))


def main():
    start("response_brackets", "both")
    global METHODS
    if "--selfcal-only" in sys.argv[1:]:     # the peers' figures do not change with selfcal
        METHODS = ("selfcal",)
    scenes = real_bracket_scenes()
    if not scenes:
        sys.exit("../shared/data/real_brackets is absent")
    cameras: dict[str, list] = {}
    for name, (paths, times) in scenes.items():
        cameras.setdefault(name.split("/")[0], []).append((name, paths, times))

    spread_rows, cross_rows, time_rows = [], [], []
    for camera, items in cameras.items():
        per_method = {m: [] for m in METHODS}
        stacks, secs = [], {m: 0.0 for m in METHODS}
        for name, paths, times in items:
            reduce = 2 if "sony" in camera else 1
            curves, frames, seconds = curves_of_scene(paths, times, reduce)
            for m in METHODS:
                per_method[m].append(curves[m])
                secs[m] += seconds[m] / len(items)
            stacks.append((frames, times))
            size = f"{frames[0].shape[1]}×{frames[0].shape[0]}"
            print(f"{name}: {len(paths)} frames {size}, "
                  + ", ".join(f"{m} {seconds[m]:.1f} s" for m in METHODS), file=sys.stderr)
        for m in METHODS:
            mean, worst = spread(per_method[m])
            own, other = cross_scene(per_method[m], stacks)
            spread_rows.append([camera, m, f"{mean:.4f}", f"{worst:.4f}",
                                f"{non_monotone(per_method[m])} / {3 * len(items)}"])
            cross_rows.append([camera, m, f"{own:.4f}", f"{other:.4f}"])
            time_rows.append([camera, m, f"{secs[m]:.2f}"])

    print("spread of a camera's curves across its scenes: best-scale RMSE from the camera's "
          "median curve, codes 1-254, over scenes × channels\n")
    print(table(["camera", "method", "mean", "max", "non-monotone curves"], spread_rows))
    print()
    for camera in cameras:
        rows = {r[1]: float(r[2]) for r in spread_rows if r[0] == camera}
        peers = {m: v for m, v in rows.items() if m != "selfcal"}
        if not peers:
            continue
        best = min(peers, key=peers.get)
        verdict = "met" if rows["selfcal"] < min(peers.values()) else "not met"
        print(f"{camera}: selfcal mean spread {rows['selfcal']:.4f}; best peer {best} "
              f"{peers[best]:.4f}; below every peer: {verdict}")
    print("\ncross-scene log linearisation error (reported, not a target): each scene's "
          "curve on its own scene and on the camera's other scenes (mean)\n")
    print(table(["camera", "method", "own scene", "other scenes"], cross_rows))
    print("\nseconds per scene (mean)\n")
    print(table(["camera", "method", "seconds"], time_rows))


if __name__ == "__main__":
    main()
    finish()
