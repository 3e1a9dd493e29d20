"""Issue 5: round trips through a RAW-path model on the simulator's data.

For several simulated cameras (``selfcal.sim``: colour matrix, smooth gamut mapping,
tone curves), a PipelineModel is calibrated from one RAW+JPEG pair and applied to a
*different* scene of the same camera:

* ``to_raw(render(raw))`` against the raw (RMSE, raw normalised to [0, 1]);
* ``render(to_raw(jpeg))`` against the JPEG (RMSE on the 0–255 scale);
* and, for reference, the one-way errors ``render(raw)`` vs the camera's JPEG and
  ``to_raw(jpeg)`` vs the raw.

    python3 -m bench.roundtrip
"""

from __future__ import annotations


import numpy as np

from .tables import finish, start, table, Timer

from selfcal.sim.scoring import rmse

CAMERAS = [
    ("film curves, seed 0", None, 0),
    ("sRGB", "srgb", 1),
    ("gamma 2.2", "gamma", 2),
    ("film curves, seed 3", None, 3),
]


def main():
    start("roundtrip", "none")
    import selfcal
    from selfcal import sim

    rows = []
    for label, curve, seed in CAMERAS:
        curves = {"srgb": sim.ToneCurve.srgb(), "gamma": sim.ToneCurve.gamma(2.2),
                  None: None}[curve]
        pipe = sim.default_pipeline(gamut="smooth", curves=curves, seed=seed)
        train = sim.simulate_raw_jpeg_pair(sim.make_scene(256, 384, saturation=0.7,
                                                              seed=seed),
                                             pipe, seed=seed)
        test = sim.simulate_raw_jpeg_pair(sim.make_scene(256, 384, saturation=0.7,
                                                             seed=100 + seed),
                                            pipe, seed=100 + seed)
        with Timer() as t:
            model = selfcal.calibrate_pipeline([train["raw"]], [train["rendered"]],
                                               seed=seed)
        raw, jpeg = test["raw"], test["rendered"]
        codes = jpeg.astype(np.float64)
        rendered = model.render(raw) * 255.0
        back = model.to_raw(jpeg)
        raw_rt = model.to_raw(np.clip(np.round(rendered), 0, 255).astype(np.uint8))
        jpeg_rt = model.render(back) * 255.0
        unclipped = (raw < 0.98).all(axis=2) & (jpeg < 255).all(axis=2)
        rows.append([
            label, f"{t.seconds:.1f}",
            f"{rmse(rendered[unclipped], codes[unclipped]):.2f}",
            f"{rmse(back[unclipped], raw[unclipped]):.4f}",
            f"{rmse(raw_rt[unclipped], raw[unclipped]):.4f}",
            f"{rmse(jpeg_rt[unclipped], codes[unclipped]):.2f}",
        ])
    print("RAW-path model from one simulated RAW+JPEG pair, applied to another scene of the "
          "same camera (pixels unclipped in raw and JPEG)\n")
    print(table(["camera", "fit s", "render(raw) vs JPEG (0-255)",
                 "to_raw(JPEG) vs raw", "to_raw(render(raw)) vs raw",
                 "render(to_raw(JPEG)) vs JPEG (0-255)"], rows))


if __name__ == "__main__":
    main()
    finish()
