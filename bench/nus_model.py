"""NUS model folders as models (issue 18): the baked tables against the reference RBF.

``selfcal.load_model(folder)`` returns :class:`selfcal.pipeline.nus.NUSPipelineModel`:
the NUS Nikon D7000 model (Kim et al. PAMI 2012) baked into dense tables.  This prints,
for ``to_raw`` (JPEG -> raw) and ``render`` (raw -> JPEG):

- the one-off cost of the first use (per process): ``to_raw`` bakes its 49³ table;
  ``render`` evaluates the nodes of its fine grid that the frame reaches (lazily, during
  the first render of the frame; the count is printed);
- the time per megapixel of the reference (``NUSCameraModel``, the RBF per pixel,
  timed on a subsample) and of the baked model on a full 24 MP frame once its tables
  are made (the median of five runs: the machine is shared);
- the max, 99.9th percentile and RMS difference (in ``[0, 1]``: raw for to_raw,
  rendered for render) on 50,000 pixels drawn from the frame, the reference ``to_raw``
  clipped to ``[0, 1]`` as every pipeline model's output is.

The frame: ``ntu_canon_m3/ntu05.JPG`` (6000×4000, a real out-of-camera JPEG; another
camera, used as a natural distribution of codes) for ``to_raw``; for ``render``, the raw
the baked model gives for it (a 24 MP float32 linear frame).  Decoding is not timed.

    python3 -m bench.nus_model
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from .data import data_dir
from .tables import finish, start, table

import selfcal
from selfcal.io import read_image
from selfcal.pipeline.nus import read_nus_model


def _errors(a, b):
    d = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))
    return d.max(), np.percentile(d.max(axis=-1), 99.9), np.sqrt(np.mean(d ** 2))


def _timed(fn, runs: int = 5):
    """The median wall time of ``runs`` calls, and the last result."""
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main() -> None:
    start("nus_model", "none")
    folder = data_dir("nus_model_nikon_d7000")
    jpg_path = sorted(data_dir("ntu_canon_m3").glob("*.JPG"))[4]
    jpg = read_image(jpg_path)
    mp = jpg.shape[0] * jpg.shape[1] / 1e6
    rng = np.random.default_rng(0)
    flat = jpg.reshape(-1, 3)
    pick = rng.choice(flat.shape[0], 50_000, replace=False)

    cam = read_nus_model(folder, wb_code=14)
    t = time.perf_counter()
    model = selfcal.load_model(folder)
    t_load = time.perf_counter() - t

    rows = []
    # ---- to_raw
    t = time.perf_counter()
    model.to_raw(flat[:16])                       # bakes the backward table
    t_bake = time.perf_counter() - t
    t = time.perf_counter()
    ref = np.clip(cam.to_raw(flat[pick]), 0.0, 1.0)
    t_ref = (time.perf_counter() - t) / (pick.size / 1e6)
    t_ours, raw = _timed(lambda: model.to_raw(jpg))
    rows.append(["to_raw (uint8 JPEG)", f"{t_bake:.1f}", f"{t_ref:.1f}", f"{t_ours / mp:.3f}",
                 f"{t_ours:.2f}", *(f"{v:.2e}" for v in _errors(raw.reshape(-1, 3)[pick], ref))])

    # ---- render
    rflat = raw.reshape(-1, 3)
    t = time.perf_counter()
    model.render(raw)                             # evaluates the nodes the frame reaches
    t_first = time.perf_counter() - t
    nodes = model._forward.evaluated
    t = time.perf_counter()
    ref = cam.render(rflat[pick])
    t_ref = (time.perf_counter() - t) / (pick.size / 1e6)
    t_ours, out = _timed(lambda: model.render(raw))
    # its one-off cost: the first render's time beyond a later one's
    rows.append(["render (float32 raw)", f"{t_first - t_ours:.1f}", f"{t_ref:.1f}",
                 f"{t_ours / mp:.3f}", f"{t_ours:.2f}",
                 *(f"{v:.2e}" for v in _errors(out.reshape(-1, 3)[pick], ref))])

    print(f"NUS model {folder.name} (wb 14), load {t_load:.2f} s; frame {jpg_path.name} "
          f"{jpg.shape[1]}x{jpg.shape[0]} ({mp:.1f} MP); load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"render: the first render of the frame took {t_first:.1f} s and evaluated "
          f"{nodes:,} nodes of the fine grid ({model._forward.n_blocks:,} blocks of "
          f"{model._forward.nb}); times: median of 5 runs once the tables are made")
    print(table(["direction", "bake s (once)", "reference s/MP", "baked s/MP",
                 f"baked s ({mp:.0f} MP)", "max diff", "99.9 % diff", "RMS diff"], rows))


if __name__ == "__main__":
    main()
    finish()
