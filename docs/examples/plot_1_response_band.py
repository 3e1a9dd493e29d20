"""
A response curve and its confidence band, against the truth
============================================================

The camera simulator (:mod:`selfcal.sim`) renders a bracketed JPEG stack through a known
pipeline ``P = f(Γ(M ρ))``, so the true inverse response f⁻¹ of each channel is known.
Here the stack is calibrated with :func:`selfcal.calibrate_response` (the log-PCA model of
Lin et al., ICCV 2011, §5: [Lin2011] in :doc:`/references`), and the estimate, its 90 %
confidence band (:meth:`selfcal.ResponseModel.inverse_band`) and the truth are drawn side
by side.
"""

# %%
# The stack: the one ``selfcal demo`` uses -- six JPEG frames of a 14-stop scene at
# 1/250 ... 1/8 s, 384 × 256 pixels, with ±3 % shutter jitter (the sensor's true
# exposures differ from what EXIF says).
import matplotlib.pyplot as plt
import numpy as np

import selfcal
from selfcal import sim
from selfcal.sim.scoring import rmse

stack = sim.demo_stack(seed=0)
print(len(stack.images), "frames of", stack.images[0].shape, stack.images[0].dtype)
print("nominal times (s):", np.round(stack.exposure_times, 4))

# %%
# Calibrate from the arrays and the nominal times.  (From files, pass the paths and the
# times come from their EXIF: the same rule applies to both.)  By default the exposures
# are measured from the pixels through the fitted curve, the times keeping their scale
# and trend, and the times the pixels contradict are refined in the solve.  The run says
# in one warning which frames moved, if any.
model = selfcal.calibrate_response(stack.images, stack.exposure_times)

# %%
# The verdict says whether the curve can be trusted, and why not when it cannot:
# ``ok``, ``doubtful`` (used, with its reasons as warnings) or ``unusable`` (the command
# line writes nothing and exits 4 unless ``--force``).
diag = model.diagnostics
print("verdict:", diag["verdict"], diag.get("verdict_reasons") or "")

# %%
# Every frame's exposures are in one record, :attr:`~selfcal.ResponseModel.exposure_record`:
# the given time, the solve's estimate, the exposure measured from the pixels, which of
# them is used, and whether the pixels contradict the time.
# :func:`selfcal.exposure.exposure_message` is the run's one line about them.
from selfcal.exposure import exposure_message  # noqa: E402

record = model.exposure_record
print("times from:", record.origin, "| rule:", record.rule, "| refined:", record.refined)
for frame, true in zip(record.frames, stack.true_exposures):
    print(f"{frame.source}: given {frame.given:.5f}  used {frame.used:.5f} "
          f"({frame.used_from}, {100 * frame.moved:+.1f} %)  true {true:.5f}")
print(exposure_message(record))

# %%
# ``ExposureRule(times="held")`` (``selfcal calibrate --hold-times``) uses every time
# exactly as given; ``ExposureRule(refine=True)`` (``--refine-exposures``) treats every
# time as a prior in the solve, not only those the pixels contradict.
held = selfcal.calibrate_response(stack.images, stack.exposure_times,
                                  exposures=selfcal.ExposureRule(times="held"))
print("held:", np.round(held.exposures, 5), "| used from:", held.exposure_record.used_from)

# %%
# The band and the truth at every code.  :meth:`~selfcal.ResponseModel.band_at_codes` is
# :meth:`~selfcal.ResponseModel.inverse_band` evaluated at integer codes;
# ``stack.inverse_response()`` is the simulator's true f⁻¹ (both are 1 at code 255).
codes = np.arange(256)
estimate = model.inverse_response(codes)
lower, upper = model.band_at_codes(codes, level=0.9)
truth = stack.inverse_response(codes)

inside = (truth >= lower) & (truth <= upper)
print("codes where the truth lies inside the 90 % band (R, G, B):",
      np.round(inside[1:255].mean(axis=0), 3))
print("RMSE of f⁻¹ against the truth, codes 1..254 (R, G, B):",
      [round(rmse(estimate[1:255, c], truth[1:255, c]), 4) for c in range(3)])

# %%
# Left: the curves (the band is narrow at this scale).  Right: the error against the
# truth, with the band drawn around zero -- where the dashed truth leaves the shaded band,
# the band was too optimistic.
channels = ("R", "G", "B")
colours = ("tab:red", "tab:green", "tab:blue")
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
x = codes / 255
for c, (name, colour) in enumerate(zip(channels, colours)):
    ax0.fill_between(x, lower[:, c], upper[:, c], color=colour, alpha=0.25, lw=0)
    ax0.plot(x, estimate[:, c], color=colour, lw=1.2, label=f"{name}: estimate")
    ax0.plot(x, truth[:, c], color="k", lw=0.8, ls="--")
    ax1.fill_between(x, lower[:, c] - estimate[:, c], upper[:, c] - estimate[:, c],
                     color=colour, alpha=0.2, lw=0)
    ax1.plot(x, truth[:, c] - estimate[:, c], color=colour, lw=1.0, ls="--",
             label=f"{name}: truth − estimate")
ax0.plot([], [], color="k", lw=0.8, ls="--", label="truth")
ax0.set(xlabel="normalised code I", ylabel="f⁻¹(I)", xlim=(0, 1), ylim=(0, 1.02),
        title=f"f⁻¹ with its 90 % band (verdict: {diag['verdict']})")
ax0.legend(fontsize=8)
ax1.axhline(0, color="k", lw=0.5)
ax1.set(xlabel="normalised code I", ylabel="difference in f⁻¹", xlim=(0, 1),
        title="error against the truth, band shaded")
ax1.legend(fontsize=8)
plt.show()
