"""
A photo library on a Dask cluster: one curve per camera
=======================================================

:func:`selfcal.batch.run_batch` (``selfcal batch``) finds the bracketed sessions of a
photo library, fits one response curve per camera body from samples pooled across its
sessions, merges every session into an EXR with a preview, and draws a plot per camera.
Here it runs on a simulated memory card (:mod:`selfcal.sim.cards`: two bodies with
known responses, three five-frame sessions each, 192 × 128 frames) on a real
Dask ``LocalCluster`` of two single-threaded workers.

The command line does the same with::

    selfcal batch card/ -o batch/ --workers 2
"""

# %%
# Write the card into a temporary folder.  Each body's frames are numbered and filed as a
# camera does (``DCIM/100SIMCM/IMG_0001.JPG`` ...), with the EXIF a camera writes.
import json
import tempfile
from pathlib import Path

import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np

import selfcal
from selfcal.batch import ClusterOptions, run_batch
from selfcal.sim.cards import Shots, write_library

tmp = Path(tempfile.mkdtemp(prefix="selfcal-batch-"))
library = write_library(tmp / "card", sessions_per_body=3, shots=Shots(height=128, width=192))
print(len(library.sessions), "sessions;", sum(len(s.frames) for s in library.sessions),
      "frames, e.g.", library.sessions[0].frames[0].relative_to(tmp))

# %%
# Run the batch on a LocalCluster that :func:`~selfcal.batch.run_batch` starts and stops
# itself: two workers, one thread each.  Here they are threads of this process
# (``processes=False``), so that the example also runs as a plain script; the default
# (and ``selfcal batch``) starts worker processes, which in a script of your own needs
# the ``if __name__ == "__main__":`` guard of Python's multiprocessing.
# ``scheduler="tcp://host:8786"`` (or a scheduler file) would use a running cluster
# instead, ``scheduler="serial"`` no Dask at all, and ``ClusterOptions(client=...)`` an
# existing ``distributed.Client``.
result = run_batch([tmp / "card"], tmp / "batch",
                   cluster=ClusterOptions(workers=2, processes=False))
print("scheduler:", result.executor.split("://")[0])
print("sessions ok:", result.count("ok"), "| failed:", len(result.failed))
print("written:", sorted(p.name for p in result.out_dir.iterdir()))

# %%
# One manifest row per session (``manifest.jsonl``, ``manifest.csv``), one summary row
# per camera (``cameras.jsonl``, ``cameras.csv``).
for row in result.rows[:2]:
    print({k: row[k] for k in ("session", "status", "verdict", "pooled", "flagged",
                                "model_kind")})
for cam in result.cameras:
    print(cam["camera_label"], "| pooled sessions:", len(cam["pooled_sessions"]),
          "| flagged:", cam["flagged_sessions"])
manifest = [json.loads(line) for line in
            (result.out_dir / "manifest.jsonl").read_text().splitlines()]
assert len(manifest) == len(result.rows)

# %%
# The simulator knows each body's true response: how far are the pooled curve (the
# camera's ``model.json``) and each session's own curve (kept in its manifest row, the
# mean of R, G, B at 33 codes) from it?
bodies = {f"{s.body.make} {s.body.model} #{s.body.serial}": s.body for s in library.sessions}
grid = np.linspace(0.0, 1.0, 33)
for cam in result.cameras:
    truth = bodies[cam["camera_label"]].inverse_response().mean(axis=1)
    truth = np.interp(grid, np.arange(256) / 255, truth)
    pooled = selfcal.load_model(cam["model_file"]).inverse_response(grid * 255).mean(axis=1)
    own = [np.asarray(r["own_curve"]) for r in result.rows if r["camera"] == cam["camera"]]
    print(f"{cam['camera_label']}: RMSE of f⁻¹ against the truth: pooled "
          f"{np.sqrt(np.mean((pooled - truth) ** 2)):.4f}, sessions' own "
          + ", ".join(f"{np.sqrt(np.mean((o - truth) ** 2)):.4f}" for o in own))

# %%
# The batch's plot of each camera (``camera-<camera>.png`` beside ``cameras.csv``):
# every session's own curve in the colour of its verdict (dashed when the pooled fit
# flagged it as disagreeing), under the camera's pooled curve in black.
fig, axes = plt.subplots(1, len(result.cameras), figsize=(12, 4.6), constrained_layout=True)
for ax, cam in zip(np.atleast_1d(axes), result.cameras):
    ax.imshow(mpimg.imread(cam["plot"]))
    ax.set_title(Path(cam["plot"]).name, fontsize=9)
    ax.set_axis_off()
plt.show()

# %%
# Remove the temporary folder.
import shutil  # noqa: E402

shutil.rmtree(tmp)
