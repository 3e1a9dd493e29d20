"""What dividing the lens's vignetting out costs a merge with σ (issue 36).

Five 24 MP frames of ../shared/data/ntu_canon_m3 (1/2000 … 1/100 s, decoded once to RGB
arrays), one response model calibrated from them, ``selfcal.merge_hdr(...,
options=MergeOptions(sigma=True, vignetting=...))`` with:

* ``"none"``: no vignetting (the baseline);
* a lens-like falloff (1.2 stops at the corners, off-centre, with a covariance): a tripod
  stack, so it is divided out of the finished map (:func:`selfcal.hdr.vignetting.divide_out`)
  and its band joins σ;
* the same falloff on frames that moved (each frame but the reference shifted by up to
  3 % of the width, ``align="mtb"``): divided out per frame at its own pixels
  (:class:`selfcal.hdr.vignetting.FrameFalloff`), against the same aligned merge without it.

Timings alternate between the two arms of each pair, best of ``--repeats``; the ratio is
the issue's figure (target ≤ 1.2×).  The machine has two cores that other jobs may share:
the CPU seconds of the process are printed beside the wall times.

    python3 -m bench.vignetting_speed [--repeats 3]
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from .data import data_dir
from .tables import finish, start, table

SPEED_FRAMES = ["ntu03", "ntu05", "ntu09", "ntu12", "ntu16"]


def lens_like(height: int, width: int):
    """A falloff of about 1.2 stops at the corners, a little off-centre, with a band."""
    from selfcal.lens import Vignetting

    k = np.array([[-0.62, 0.10, -0.05], [-0.58, 0.08, -0.04], [-0.55, 0.07, -0.04]])
    return Vignetting(k, [0.03, -0.02], "flat", covariance=np.eye(11) * 1e-5,
                      aspect=width / height, description="bench: lens-like falloff")


def shifted(images, fraction: float = 0.03, seed: int = 0):
    """Every frame but the middle one moved by up to ``fraction`` of the width (whole
    pixels, reflected borders): a handheld bracket the MTB alignment can follow."""
    rng = np.random.default_rng(seed)
    out = []
    for k, im in enumerate(images):
        if k == len(images) // 2:
            out.append(im)
            continue
        dx, dy = (rng.uniform(-fraction, fraction, 2) * im.shape[1]).astype(int)
        out.append(np.ascontiguousarray(np.roll(im, (dy, dx), axis=(0, 1))))
    return out


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def timed(call):
    t0, c0 = time.perf_counter(), cpu_seconds()
    call()
    return time.perf_counter() - t0, cpu_seconds() - c0


def pair(run_without, run_with, repeats: int):
    """Best wall and CPU seconds of each arm, the arms alternating."""
    best = {"without": (np.inf, np.inf), "with": (np.inf, np.inf)}
    for _ in range(repeats):
        for arm, call in (("without", run_without), ("with", run_with)):
            wall, cpu = timed(call)
            best[arm] = (min(best[arm][0], wall), min(best[arm][1], cpu))
    return best


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    start("vignetting_speed", "none")

    import selfcal
    from selfcal.hdr.merge import MergeOptions
    from selfcal.io import read_exposure_info, read_image

    folder = data_dir("ntu_canon_m3")
    paths = [folder / f"{n}.JPG" for n in SPEED_FRAMES]
    model = selfcal.calibrate_response(paths)
    images = [read_image(p) for p in paths]
    times = [read_exposure_info(p).relative_exposure for p in paths]
    h, w = images[0].shape[:2]
    lens = lens_like(h, w)

    def merge(frames, vignetting, align=False):
        return lambda: selfcal.merge_hdr(frames, times, model, align=align, options=MergeOptions(
            sigma=True, vignetting=vignetting))

    tripod = pair(merge(images, "none"), merge(images, lens), args.repeats)
    moved_frames = shifted(images)
    moved = pair(merge(moved_frames, "none", "mtb"), merge(moved_frames, lens, "mtb"),
                 args.repeats)
    rows = []
    for name, best in (("tripod (divided after the merge)", tripod),
                       ("moved, aligned (divided per frame)", moved)):
        (w0, c0), (w1, c1) = best["without"], best["with"]
        rows.append([name, f"{w0:.2f}", f"{w1:.2f}", f"{w1 / w0:.2f}", f"{c0:.1f}",
                     f"{c1:.1f}", f"{c1 / c0:.2f}"])
    print(f"{len(paths)} frames of {w}x{h} ({w * h / 1e6:.0f} MP), decoded arrays, σ on, "
          f"best of {args.repeats}, arms alternating\n")
    print(table(["stack", "s without", "s with vignetting", "ratio (target ≤ 1.2)",
                 "CPU s without", "CPU s with", "CPU ratio"], rows))
    finish()


if __name__ == "__main__":
    main()
