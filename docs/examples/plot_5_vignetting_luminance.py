"""
Vignetting from a handheld bracket, and radiance in cd/m²
=========================================================

A lens passes less light to the corners than to the centre.  When the camera moves
between shots, the same scene point is seen at different places in the frame, and the
falloff shows: :func:`selfcal.calibrate_response` with ``align="homography"`` fits the
response, each frame's exposure and the vignetting ``V(r) = 1 + k₁r² + k₂r⁴ + k₃r⁶``
together ([Goldman2010]).  The merge then divides it out, and a luminance reading of one
region puts the whole map in cd/m².

The bracket here comes from the simulator (:func:`selfcal.sim.simulate_handheld_stack`):
five frames moved by about 12 % and turned by up to 2°, through a lens that loses about
1.5 stops at the corners, so the answer is known.
"""

# %%
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import selfcal
from selfcal import sim
from selfcal.lens import ReferenceReading

times = [1 / 200, 1 / 100, 1 / 50, 1 / 25, 1 / 12]
scene = sim.make_scene(300, 440, dynamic_range_stops=10.0, saturation=0.5, seed=4)
truth = sim.random_vignetting(4, corner_stops=(1.5, 1.5), aspect=306 / 208)
stack = sim.simulate_handheld_stack(scene, sim.default_pipeline(seed=4), times,
                                    frame_shape=(208, 306), vignetting=truth, seed=4)
print("true corner falloff (stops, R G B):", np.round(truth.corner_stops(), 2))

# %%
# Calibrate on the aligned frames: the model now holds the vignetting it saw.
model = selfcal.calibrate_response(stack.images, times, align="homography")
fitted = model.vignetting
print("fitted corner falloff (stops, R G B):", np.round(fitted.corner_stops(), 2))
print(model.diagnostics["vignetting"]["observable"], "|", fitted.description)

profile = fitted.corner_profile()
true_profile = truth.corner_profile()
fig, ax = plt.subplots(figsize=(5, 3.2))
for c, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
    band = 1.645 * profile["log_sigma"][:, c]
    ax.fill_between(profile["r"], profile["falloff"][:, c] * np.exp(-band),
                    profile["falloff"][:, c] * np.exp(band), color=colour, alpha=0.15)
    ax.plot(profile["r"], profile["falloff"][:, c], color=colour, label=f"fit {'RGB'[c]}")
    ax.plot(true_profile["r"], true_profile["falloff"][:, c], color=colour, ls=":")
ax.set_xlabel("distance from the optical centre (half-diagonals)")
ax.set_ylabel("V(r)")
ax.set_title("vignetting: fit (90 % band) and truth (dotted)")
ax.legend(fontsize=8)
fig.tight_layout()

# %%
# Merge with the model: ``vignetting="auto"`` (the default) divides the model's falloff
# out of each frame at its own pixels.  A spot meter read 250 cd/m² over a patch in the
# middle of the scene; with that reading the map and its σ come out in cd/m².
h, w = stack.images[0].shape[:2]
patch = (w // 2 - 10, h // 2 - 10, w // 2 + 10, h // 2 + 10)
reading = ReferenceReading(patch, 250.0, description="spot meter, centre patch")
hdr = selfcal.merge_hdr(stack.images, times, model, align="homography",
                        options=selfcal.MergeOptions(sigma=True, luminance=reading))
print("units:", hdr.units, "| vignetting:", hdr.diagnostics["vignetting"]["source"],
      hdr.diagnostics["vignetting"]["divided"])
luminance = hdr.radiance @ np.array([0.2126, 0.7152, 0.0722])
print(f"luminance of the patch: {np.median(luminance[patch[1]:patch[3], patch[0]:patch[2]]):.1f} cd/m²")

# %%
# The false-colour picture lighting researchers read (as Radiance's ``falsecolor``):
# luminance on a log scale with a cd/m² legend.
from selfcal.report import write_falsecolor

out = Path(tempfile.mkdtemp(prefix="selfcal-lens-")) / "luminance.png"
write_falsecolor(out, hdr.radiance, units=hdr.units, mask=hdr.unmeasured)
fig, ax = plt.subplots(figsize=(6, 3.6))
ax.imshow(plt.imread(out))
ax.set_axis_off()
fig.tight_layout()
