"""HDR radiance maps from bracketed exposure stacks, and the files they are written to.

The merge is Debevec & Malik's weighted mean (SIGGRAPH 1997, Eq. 6) on linear values,
with the inverse response of Lin et al. (ICCV 2011, §5); what selfcal adds to it is said in
each module.  Where each piece lives:

* :mod:`selfcal.hdr.merge` -- :func:`merge_hdr` and its :class:`HDRResult` (the weighted
  sums in strips, the fill of unmeasured pixels, calibration on the fly);
* :mod:`selfcal.hdr.linearize` -- :func:`linearize_images`, frames through f⁻¹ one at a
  time;
* :mod:`selfcal.hdr.weights` -- :func:`weight_hat`, :class:`NoiseModel` and
  :func:`noise_variance` (the noise-aware weights), the per-frame tables;
* :mod:`selfcal.hdr.accumulate` -- the merge's weighted sums, frame by frame in strips;
* :mod:`selfcal.hdr.sigma` -- the standard deviation of every merged radiance value;
* :mod:`selfcal.hdr.deghost` -- the per-pixel test against the reference frame;
* :mod:`selfcal.hdr.plan` -- which frames a merge takes, floors and ceilings, lossy frames;
* :mod:`selfcal.hdr.vignetting` -- the lens's falloff divided out of a merge: which one, and how;
* :mod:`selfcal.hdr.io` -- OpenEXR / Radiance HDR / float TIFF output, previews, linear
  images (:func:`write_radiance`, :func:`write_preview`, :func:`write_linear`).

Below this package, and shared with the response path: the frames, linearisers and
exposures in :mod:`selfcal.stack.frames`, the alignment in :mod:`selfcal.stack.align`; "align, then
calibrate" is :func:`selfcal.response.calibrate.calibrate_aligned`.  The exposures the merge
measures from the pixels (linear brackets, and rendered ones through the curve) are in
:mod:`selfcal.exposure`.
"""

from __future__ import annotations

from .io import (
    EXR_COMPRESSIONS,
    RADIANCE_SUFFIXES,
    OutputWriteError,
    RadianceFile,
    read_radiance,
    tonemap_reinhard,
    write_linear,
    write_preview,
    write_radiance,
)
from .linearize import linearize_images
from .merge import HDRResult, MergeOptions, merge_hdr
from .weights import NoiseModel, noise_variance, weight_hat

__all__ = [
    "HDRResult",
    "MergeOptions",
    "merge_hdr",
    "linearize_images",
    "NoiseModel",
    "noise_variance",
    "weight_hat",
    "OutputWriteError",
    "RadianceFile",
    "RADIANCE_SUFFIXES",
    "EXR_COMPRESSIONS",
    "write_radiance",
    "read_radiance",
    "tonemap_reinhard",
    "write_preview",
    "write_linear",
]
