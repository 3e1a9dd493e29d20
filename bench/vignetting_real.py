"""Issue 36 on real frames: which vignetting each stack of ../shared/data gets, and the
self-calibrated falloff where the frames moved.

1. Every real bracket (memorial, piccante, frobisher, ntu, the six real_brackets scenes):
   ``calibrate_response(paths, align="homography")``, which fits a vignetting only where
   the frames moved enough to observe one; then what ``MergeOptions(vignetting="auto")``
   chooses for the stack (:func:`selfcal.hdr.vignetting.resolve_vignetting`: the model's
   own, else the lens database's profile for the EXIF lens, else none) and why.  These
   brackets were shot on a tripod: each must say "not observable".
2. The three real panoramas of ../shared/data/panorama_sony_w180 (three frames each, one
   exposure, the camera turned between shots): the self-calibrated falloff at the corner
   (stops, per channel, with the 90 % band from the fit's covariance), its centre, and the
   spread between the three (they were shot at different focal lengths, 6.2, 9.9 and
   18.6 mm, so they need not agree); lensfun holds no profile for this compact (part 1's
   table says so for whichever stack names it).  With one exposure the response is the
   prior's mean curve (the model's diagnostics say so), an error the band does not hold.

    python3 -m bench.vignetting_real [--skip-ntu]
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from .data import data_dir, real_bracket_scenes, real_stacks
from .tables import finish, start, table

PANORAMAS = ("hill", "ledge", "pier")
#: z of a two-sided 90 % band
Z90 = 1.6449


def corner(vignetting):
    """Falloff at the farthest corner in stops per channel, and the 90 % band's half-width
    there (stops), from the fit's covariance."""
    stops = vignetting.corner_stops()
    aspect = vignetting.aspect or 1.5
    h, w = 1000, int(round(1000 * aspect))
    corners = [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)]
    sig = np.max([vignetting.log_sigma_at(h, w, np.array(x, float), np.array(y, float))
                  for x, y in corners], axis=0)
    return stops, Z90 * sig / np.log(2)


def describe_stack(name, paths, times):
    import selfcal
    from selfcal.hdr.vignetting import resolve_vignetting
    from selfcal.lens import lens_vignetting
    from selfcal.io import read_image_size

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = selfcal.calibrate_response(paths, times, align="homography")
    said = model.diagnostics.get("vignetting") or {}
    motion = said.get("motion") or [0.0]
    h, w = read_image_size(paths[0])
    _, record = resolve_vignetting("auto", model, path=paths[0], shape=(h, w))
    observable = "yes" if said.get("observable") else f"no: {said.get('reason', '?')}"
    chosen = record["source"] or "none"
    detail = record["description"] or "; ".join(record["reasons"])
    own = "-"
    if model.vignetting is not None:
        stops, band = corner(model.vignetting)
        own = f"{stops[1]:.2f} ± {band[1]:.2f}"
    profile, _ = lens_vignetting(paths[0])
    lens = "-" if profile is None else f"{profile.corner_stops()[1]:.2f}"
    return [name, len(paths), f"{100 * max(motion):.2f} %", observable, chosen, own, lens,
            detail], model


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-ntu", action="store_true",
                        help="leave out ntu (17 frames of 24 MP: minutes to align)")
    args = parser.parse_args()
    start("vignetting_real", "none")
    stacks = {k: v for k, v in real_stacks().items() if not (args.skip_ntu and k == "ntu")}
    stacks.update(real_bracket_scenes())
    rows = []
    for name, (paths, times) in stacks.items():
        row, _ = describe_stack(name, paths, times)
        rows.append(row)
    print("Real brackets: calibrate_response(align=\"homography\"), then what "
          "vignetting=\"auto\" chose\n")
    print(table(["stack", "frames", "largest motion (of the diagonal)", "self-calibration "
                 "observable", "auto chose", "self-calibrated corner G (stops, ± 90 %)",
                 "lensfun corner G (stops)", "what / why"], rows))

    pano_rows, falloffs = [], []
    for scene in PANORAMAS:
        paths = sorted(data_dir("panorama_sony_w180", scene).glob("*.JPG"))
        row, model = describe_stack(f"panorama {scene}", paths, None)
        v = model.vignetting
        if v is None:
            pano_rows.append(row[:1] + [row[2], row[3], "-", "-", "-"])
            continue
        stops, band = corner(v)
        falloffs.append(stops)
        pano_rows.append([row[0], row[2], "yes",
                          " / ".join(f"{s:.2f} ± {b:.2f}" for s, b in zip(stops, band)),
                          f"({v.centre[0]:+.3f}, {v.centre[1]:+.3f})",
                          model.diagnostics["vignetting"].get("response", "?")])
    print("\nReal panoramas (one exposure each, the camera turned): the self-calibrated "
          "falloff\n")
    print(table(["panorama", "largest motion", "observable",
                 "corner falloff R / G / B (stops, ± 90 % band)", "optical centre offset "
                 "(half-diagonals)", "response"], pano_rows))
    if len(falloffs) > 1:
        f = np.array(falloffs)
        print(f"\nspread of the corner falloff between the panoramas (G): "
              f"{f[:, 1].min():.2f} … {f[:, 1].max():.2f} stops (range {np.ptp(f[:, 1]):.2f}; "
              "different focal lengths)")
    finish()


if __name__ == "__main__":
    main()
