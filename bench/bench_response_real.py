"""Issue 3, acceptance 2: scale-free linearisation error on real stacks, against OpenCV.

For memorial, piccante, frobisher and ntu (../shared/data), with the nominal times:
RMS over adjacent exposure pairs and pixels with all channels in [25, 235] of
log f⁻¹(I′) − log f⁻¹(I) − log(t′/t), for selfcal's curve and for OpenCV's
CalibrateDebevec and CalibrateRobertson curves, all calibrated and scored on the same
arrays.  The 6000×4000 ntu frames are reduced 4× (INTER_AREA) first, so that Robertson,
which iterates over every pixel, runs in reasonable time and memory.

The "per-code floor" column is the lowest value any per-channel curve can reach on the
metric: a free log f⁻¹ value per code, least squares over the metric's own pixel pairs
(``common.per_code_floor``).  It is not a calibration, only a scale for the others.

    python bench/bench_response_real.py
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import (Timer, log_linearisation_error, opencv_inverse_response,  # noqa: E402
                    per_code_floor, real_stacks, table)


def load(paths, reduce: int):
    import cv2

    from selfcal.io import read_image

    images = []
    for p in paths:
        im = read_image(p)
        if reduce > 1:
            im = cv2.resize(im, (im.shape[1] // reduce, im.shape[0] // reduce),
                            interpolation=cv2.INTER_AREA)
        images.append(im)
    return images


def main():
    import selfcal

    rows = []
    for name, (paths, times) in real_stacks().items():
        images = load(paths, 4 if name == "ntu" else 1)
        errs, secs = {}, {}
        with Timer() as t:
            model = selfcal.calibrate_response(images, times)
        secs["selfcal"] = t.seconds
        errs["selfcal"] = log_linearisation_error(images, times, model.inverse_response())
        for method in ("debevec", "robertson"):
            with Timer() as t:
                resp = opencv_inverse_response(images, times, method)
            secs[method] = t.seconds
            errs[method] = log_linearisation_error(images, times, resp)
        floor = log_linearisation_error(images, times, per_code_floor(images, times))
        best = min(errs["debevec"], errs["robertson"])
        rows.append([name, f"{len(images)}", f"{images[0].shape[1]}x{images[0].shape[0]}",
                     f"{errs['selfcal']:.4f}", f"{errs['debevec']:.4f}",
                     f"{errs['robertson']:.4f}", f"{floor:.4f}",
                     f"{errs['selfcal'] / best:.3f}",
                     "yes" if errs["selfcal"] < best else "NO",
                     model.diagnostics["verdict"].split(":")[0]])
    print("Scale-free linearisation error (RMS of log f⁻¹(I') − log f⁻¹(I) − log(t'/t), "
          "adjacent pairs, all channels in [25, 235]); lower is better\n")
    print(table(["stack", "frames", "size", "selfcal", "OpenCV Debevec", "OpenCV Robertson",
                 "per-code floor", "selfcal / best OpenCV", "selfcal lowest", "selfcal verdict"], rows))


if __name__ == "__main__":
    main()
