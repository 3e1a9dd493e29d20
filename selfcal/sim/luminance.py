"""Simulated cameras whose absolute calibration is known (ours, for the luminance scale).

A simulated stack (:func:`selfcal.sim.simulate_stack`) has a true radiance
``E = M g ρ · exposure_scale`` (``g`` the white-balance gains of a camera that has them,
:meth:`selfcal.sim.CameraPipeline.colour_correct`), in units where a
frame of ``t`` seconds records ``E · t`` (1 = white).  In the EXIF units of a merge
(exposure ``e = t · S/100 / N²``, the stack's ``f_number`` N and ``iso`` S, written to the
files' EXIF) the same radiance is ``E_rel = E · 100 N² / S``.

The simulated camera is made to follow the standard output sensitivity of [ISO12232]:
a grey surface of luminance ``L`` gives the focal-plane exposure ``H = q L t / N²``
(q = 0.65), and ``H = 10/S_true`` renders at the grey code 118/255, where the camera's
true f⁻¹ reads ``x_g = Y(f⁻¹(118))``.  So ``L = C_true · Y(E_rel)`` with::

    C_true = 10 / (100 q x_g) · S / S_true

and ``S_true = S · 2^δ``: a camera whose ISO calibration is off by ``δ`` stops from the
rating it writes to EXIF (the manufacturers' spread that
:data:`selfcal.lens.luminance.EXIF_LOG_SIGMA` stands for).
"""

from __future__ import annotations

import numpy as np

from ..lens.luminance import CAMERA_Q, REC709_LUMA, SOS_EXPOSURE, SOS_GREY_CODE

__all__ = ["true_scale", "true_relative_radiance", "true_luminance"]


def true_scale(stack, iso_error_stops: float = 0.0) -> float:
    """``C_true`` (cd/m² per unit of EXIF-relative radiance) of a simulated stack's camera
    whose ISO calibration is off by ``iso_error_stops`` (see the module docstring)."""
    code = SOS_GREY_CODE * stack.max_code
    lo = int(np.floor(code))
    inv = stack.inverse_response(np.array([lo, lo + 1]))
    x_g = float((inv[0] + (code - lo) * (inv[1] - inv[0])) @ np.asarray(REC709_LUMA))
    return SOS_EXPOSURE / (100.0 * CAMERA_Q * x_g) / 2.0 ** float(iso_error_stops)


def true_relative_radiance(stack) -> np.ndarray:
    """``E_rel = M g ρ · exposure_scale · 100 N² / S`` (``g``: the camera's white-balance
    gains, when it has them, below its highlight clip): the radiance a merge of the stack's
    files (EXIF exposures) estimates, float64 ``HxWx3``."""
    pipe = stack.pipeline
    rho = stack.radiance.astype(np.float64)
    gains = getattr(pipe, "white_balance", None)
    if gains is not None:
        rho = rho * np.asarray(gains, np.float64)
    return (rho @ pipe.matrix.T) * (stack.exposure_scale * 100.0 * stack.f_number ** 2
                                    / stack.iso)


def true_luminance(stack, iso_error_stops: float = 0.0) -> np.ndarray:
    """The scene's luminance in cd/m², ``C_true · Y(E_rel)``, float64 ``HxW``."""
    return true_scale(stack, iso_error_stops) * (true_relative_radiance(stack)
                                                 @ np.asarray(REC709_LUMA))
