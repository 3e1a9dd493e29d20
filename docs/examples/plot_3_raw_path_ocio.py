"""
The RAW path both ways, and its OpenColorIO config
==================================================

A RAW+JPEG pair gives the RAW-path model: the rank-based colour matrix, monotone tone
curves and lattice gamut LUT of [Gong2018] with the RBF inverse colour mapping of
[Lin2011] §6 (keys of :doc:`/references`).  Here it is fitted to the committed fixture
pair (``fixtures/pair``: a 16-bit linear TIFF standing in for the raw, and the JPEG the
simulated camera rendered from it), used both ways -- raw → JPEG
(:meth:`~selfcal.PipelineModel.render`) and JPEG → raw
(:meth:`~selfcal.PipelineModel.to_raw`) -- then exported as an OpenColorIO v2 config and
applied with OpenColorIO's own Python bindings (``PyOpenColorIO``).

The command line::

    selfcal calibrate fixtures/pair/pair.tiff fixtures/pair/pair.jpg -o camera.json
    selfcal export camera.json --ocio camera_ocio/
"""

# %%
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import PyOpenColorIO as OCIO

import selfcal
from selfcal.export.ocio import ocio_colour_space_names, write_ocio_config
from selfcal.io import read_image


def repository_root(start: Path) -> Path:
    for folder in (start, *start.parents):
        if (folder / "fixtures" / "pair").is_dir():
            return folder
    raise FileNotFoundError("the fixtures/ folder of the selfcal repository")


here = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
pair = repository_root(here) / "fixtures" / "pair"
out = Path(tempfile.mkdtemp(prefix="selfcal-raw-path-"))

# %%
# Fit.  :func:`selfcal.calibrate` would choose this path itself for a raw and a JPEG of
# the same stem; :func:`selfcal.calibrate_pipeline` takes it directly.
model = selfcal.calibrate_pipeline(pair / "pair.tiff", pair / "pair.jpg")
d = model.diagnostics
print("backward variant:", model.backward, "| samples:", d["samples"])

raw = selfcal.read_raw_linear(pair / "pair.tiff").rgb     # float32 linear camera RGB
jpeg = read_image(pair / "pair.jpg")                         # uint8 RGB
print("raw", raw.shape, raw.dtype, "| JPEG", jpeg.shape, jpeg.dtype)

# %%
# Both ways.  ``return_mask=True`` also marks the pixels far from every training colour
# (there the model extrapolates; ``selfcal to-raw`` and ``selfcal render`` warn when
# more than 1 % of a file's pixels are).  Even on its own training scene the share is not
# zero: the fit samples block means away from edges and clipped blocks, and about half
# of the pixels at edges or with a clipped channel lie outside.
rendered, outside_r = model.render(raw, return_mask=True)
back, outside_b = model.to_raw(jpeg, return_mask=True)
render_err = np.abs(rendered * 255 - jpeg.astype(np.float32))
raw_err = np.abs(back - raw)
print(f"render: median |error| {np.median(render_err):.2f} codes; "
      f"outside training {outside_r.mean():.1%}")
print(f"to_raw: median |error| {np.median(raw_err):.4f} of raw white; "
      f"outside training {outside_b.mean():.1%}")

# %%
# The OpenColorIO config: ``config.ocio`` and two CLF files (shaper + 3D LUT each way),
# with the colour spaces ``<camera> JPEG`` and ``<camera> scene-linear``.
config_path = write_ocio_config(model, out / "camera_ocio", camera="fixture")
print(sorted(p.name for p in config_path.parent.iterdir()))
names = ocio_colour_space_names("fixture")
config = OCIO.Config.CreateFromFile(str(config_path))
config.validate()                                           # raises if anything is wrong
print("colour spaces:", [cs.getName() for cs in config.getColorSpaces()])

processor = config.getProcessor(names["jpeg"], names["linear"]).getDefaultCPUProcessor()
via_ocio = np.ascontiguousarray(jpeg, dtype=np.float32) / 255
processor.applyRGB(via_ocio)                                # in place, HxWx3 float32
model_raw = model.to_raw(jpeg)
print(f"OpenColorIO against the model's to_raw: max |difference| "
      f"{np.abs(via_ocio - model_raw).max():.4f}")

# %%
# The JPEG, the render's error against it, the error of JPEG → raw against the raw, and
# (right) OpenColorIO's JPEG → scene-linear against the model's, per channel.
fig, axes = plt.subplots(1, 4, figsize=(13, 3.2), constrained_layout=True)
axes[0].imshow(jpeg)
axes[0].set_title("the camera's JPEG")
im = axes[1].imshow(render_err.max(axis=-1), cmap="magma", vmin=0, vmax=8)
axes[1].set_title("render: |error| (codes)")
fig.colorbar(im, ax=axes[1], shrink=0.8)
im = axes[2].imshow(raw_err.max(axis=-1), cmap="magma", vmin=0, vmax=0.02)
axes[2].set_title("to_raw: |error| (raw white = 1)")
fig.colorbar(im, ax=axes[2], shrink=0.8)
for ax in axes[:3]:
    ax.set_axis_off()
step = 5
for c, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
    axes[3].plot(model_raw[::step, ::step, c].ravel(),
                 (via_ocio - model_raw)[::step, ::step, c].ravel(),
                 ".", ms=2, color=colour, alpha=0.5)
axes[3].axhline(0, color="k", lw=0.6)
axes[3].set(xlabel="model.to_raw (linear raw)", ylabel="PyOpenColorIO − model",
            title="JPEG → linear: OCIO vs model")
plt.show()

# %%
# Remove the temporary folder.
import shutil  # noqa: E402

shutil.rmtree(out)
