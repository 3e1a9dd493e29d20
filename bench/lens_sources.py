"""Which real stacks lensfun knows the lens of, and how far apart lensfun's calibrated
apertures are (the evidence of ``selfcal.lens.database.LOG_SIGMA_FLOOR``).

``python3 -m bench.lens_sources`` prints, per stack in ../shared/data, the camera and lens
its first frame's EXIF names, what lensfun matched (or why not) and the profile's corner
falloff; then, over every lens in lensfun's database with vignetting data, the error of
predicting a calibrated aperture's log V at the corner (r = 1) from its two neighbours
(linear in log f-number) -- an upper bound on lensfun's interpolation between apertures,
whose gaps are half as wide.  Skips with a message when ../shared/data is absent.
"""

from __future__ import annotations

import collections
import sys

import numpy as np

from bench.data import SHARED_DATA
from bench.tables import finish, start, table

#: Stacks (folders of frames) looked at, in ../shared/data.
STACKS = ("real_brackets/sony_ilce6400/scene1", "real_brackets/fujifilm_xh1/scene1",
          "piccante_canon_t2i/stack", "piccante_canon_t2i/stack_alignment", "ntu_canon_m3",
          "frobisher_canon_5d2", "panorama_sony_w180/hill")


def _first_frame(folder):
    frames = sorted(p for p in folder.iterdir()
                    if p.suffix.lower() in (".jpg", ".jpeg", ".png", ".tif", ".tiff"))
    return frames[0] if frames else None


def stacks_table() -> list[list[str]]:
    from selfcal.io.images import read_lens_info
    from selfcal.lens.database import lens_vignetting

    rows = []
    for name in STACKS:
        folder = SHARED_DATA / name
        frame = _first_frame(folder) if folder.is_dir() else None
        if frame is None:
            rows.append([name, "absent", "", "", "", ""])
            continue
        info = read_lens_info(frame)
        vignetting, match = lens_vignetting(info)
        settings = (f"{info.focal_length or '?'} mm f/{info.f_number or '?'}")
        if vignetting is None:
            outcome, corner = f"no profile: {match.reason}", ""
        else:
            outcome = (f"{match.lens} (score {match.score}, crop {match.lens_crop:.3g} -> "
                       f"{match.camera_crop:.3g})")
            corner = f"{vignetting.corner_stops()[1]:.2f}"
        rows.append([name, f"{info.make} {info.model}", str(info.lens_model or "-"),
                     settings, outcome, corner])
    return rows


def interpolation_spread() -> dict:
    import lensfunpy

    errors = []
    lenses = 0
    for lens in lensfunpy.Database().lenses:
        table = lens.calib_vignetting or []
        if not table:
            continue
        lenses += 1
        groups = collections.defaultdict(list)
        for c in table:
            k = c.terms
            groups[(c.focal, c.distance)].append(
                (c.aperture, np.log(max(1e-3, 1 + k[0] + k[1] + k[2]))))
        for points in groups.values():
            points.sort()
            for (a0, v0), (a1, v1), (a2, v2) in zip(points, points[1:], points[2:]):
                x0, x1, x2 = np.log([a0, a1, a2])
                errors.append(abs(v0 + (v2 - v0) * (x1 - x0) / (x2 - x0) - v1))
    e = np.array(errors)
    return {"lenses": lenses, "predictions": e.size, "median": float(np.median(e)),
            "p75": float(np.percentile(e, 75)), "p90": float(np.percentile(e, 90))}


def main() -> int:
    if not SHARED_DATA.is_dir():
        print(f"skipped: {SHARED_DATA} is absent (the real stacks live there)")
        return 0
    import lensfunpy

    start("lens_sources", "none")
    print(f"lensfunpy {lensfunpy.__version__}, lensfun "
          f"{'.'.join(map(str, lensfunpy.lensfun_version[:3]))}\n")
    header = ["stack", "EXIF camera", "EXIF lens", "at", "lensfun", "corner G (stops)"]
    rows = [[cell.replace("|", "/") for cell in row] for row in stacks_table()]
    print(table(header, rows))
    spread = interpolation_spread()
    print(f"\nlensfun apertures, leave-one-out (|error| of log V(1) from the two neighbours, "
          f"{spread['predictions']} predictions on {spread['lenses']} lenses): median "
          f"{spread['median']:.3f}, 75th percentile {spread['p75']:.3f}, 90th "
          f"{spread['p90']:.3f}")
    finish()
    return 0


if __name__ == "__main__":
    sys.exit(main())
