"""
An HDR merge and its σ map
==========================

The committed fixture stack (``fixtures/stack``: six 192 × 128 JPEGs at 1/250 … 1/8 s,
made by the simulator, with EXIF exposure times) is calibrated from its files, then merged
into a radiance map with :func:`selfcal.merge_hdr` and ``MergeOptions(sigma=True)``: beside
each value, its standard deviation from the noise model, the exposures' uncertainty and
the curve's confidence band (:mod:`selfcal.hdr.sigma`).  The command line does the same
with ``selfcal merge fixtures/stack/*.jpg -o scene.exr --sigma``.
"""

# %%
# Find the fixtures from wherever the example runs (the gallery runs it in
# ``docs/examples``), and write only into a temporary folder.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import selfcal
from selfcal.hdr import tonemap_reinhard


def repository_root(start: Path) -> Path:
    for folder in (start, *start.parents):
        if (folder / "fixtures" / "stack").is_dir():
            return folder
    raise FileNotFoundError("the fixtures/ folder of the selfcal repository")


here = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
frames = sorted((repository_root(here) / "fixtures" / "stack").glob("frame_*.jpg"))
out = Path(tempfile.mkdtemp(prefix="selfcal-merge-"))
print([f.name for f in frames])

# %%
# Calibrate from the files: the times are read from their EXIF, and the exposures used
# are measured from the pixels (the times keeping their scale and trend;
# ``ExposureRule(times="held")``, ``--hold-times``, would use the times as they are).
model = selfcal.calibrate_response(frames)
record = model.exposure_record
print("verdict:", model.diagnostics["verdict"], "| times from:", record.origin,
      "| used:", record.used_from)
print("exposures (s):", np.round(model.exposures, 5))

# %%
# Merge with that model, and ask for σ.  ``unmeasured`` marks the pixels no frame
# measured with every channel unclipped (their value is a bound, their σ is +inf).
hdr = selfcal.merge_hdr(frames, model=model, options=selfcal.MergeOptions(sigma=True))
print("radiance", hdr.radiance.shape, hdr.radiance.dtype, "| sigma", hdr.sigma.shape)
print(f"unmeasured: {hdr.unmeasured.mean():.1%} of the pixels")
# the merge takes the model's measured exposures of these files (nothing is measured
# again); its record says so frame by frame, and ``exposure_source`` in words
print("exposures:", hdr.exposure_source,
      [f.used_from for f in hdr.exposure_record.frames])
for w in hdr.warnings:
    print("warning:", w)

measured = ~hdr.unmeasured
relative = hdr.sigma / np.maximum(hdr.radiance, 1e-12)
print("median relative σ of the measured pixels (R, G, B):",
      np.round(np.median(relative[measured], axis=0), 4))

# %%
# Written as the command line writes it: an OpenEXR file with the ``R, G, B`` channels
# and a ``sigma`` layer (``sigma.R, sigma.G, sigma.B``).
from selfcal.hdr.io import write_radiance_sigma  # noqa: E402

exr, sigma_file = write_radiance_sigma(out / "scene.exr", hdr.radiance, hdr.sigma)
import OpenEXR  # noqa: E402

with OpenEXR.File(str(exr), separate_channels=True) as f:
    print(Path(str(exr)).name, "channels:", sorted(f.channels()))

# %%
# Left: the radiance map tone-mapped for display (Reinhard's global operator, as
# ``selfcal merge --preview`` does).  Middle: σ relative to the value, green channel, on a
# log scale -- low where a long exposure measured the pixel unclipped, higher in the
# highlights only short frames saw; unmeasured pixels are white.  Right: how many frames
# contributed to each pixel.
preview = tonemap_reinhard(hdr.radiance, mask=measured)
rel_g = np.where(measured, relative[..., 1], np.nan)

fig, axes = plt.subplots(1, 3, figsize=(11, 3.1), constrained_layout=True)
axes[0].imshow(preview)
axes[0].set_title("radiance (tone-mapped)")
im = axes[1].imshow(np.log10(rel_g), cmap="viridis")
axes[1].set_title("log10 σ / E (G)")
fig.colorbar(im, ax=axes[1], shrink=0.85)
im = axes[2].imshow(hdr.frame_count, cmap="magma", vmin=0, vmax=len(frames))
axes[2].set_title("frames merged per pixel")
fig.colorbar(im, ax=axes[2], shrink=0.85)
for ax in axes:
    ax.set_axis_off()
plt.show()

# %%
# Remove the temporary folder.
import shutil  # noqa: E402

shutil.rmtree(out)
