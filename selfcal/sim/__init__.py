"""The camera simulator with ground truth, for tests, benchmarks and ``selfcal demo``.

The simulated camera follows the pipeline model of [Gong2018], Eq. 1a::

    P = f(Γ(M ρ))

where ρ is the linear camera raw (scene radiance × exposure, with shot and read noise
and black/white clipping), ``M`` a 3×3 colour matrix, ``Γ`` a gamut mapping and ``f``
three per-channel tone curves.  The modules follow a frame through the camera:

* :mod:`selfcal.sim.scenes` -- synthetic scenes (linear radiance, :func:`make_scene`);
* :mod:`selfcal.sim.sensor` -- exposure, shot and read noise (:class:`SensorModel`);
* :mod:`selfcal.sim.camera` -- ``M``, ``Γ`` and the pipeline (:class:`CameraPipeline`);
* :mod:`selfcal.sim.tone` -- the tone curves ``f`` (:class:`ToneCurve`);
* :mod:`selfcal.sim.encoding` -- sharpening, bit depth, JPEG, EXIF (:class:`FrameOutput`);
* :mod:`selfcal.sim.stacks` -- bracketed stacks and RAW+JPEG pairs with their truth
  (:func:`simulate_stack`, :func:`demo_stack`);
* :mod:`selfcal.sim.conditions` -- the named benchmark conditions (the condition matrix);
* :mod:`selfcal.sim.lens` -- lens falloff and handheld stacks through it, with the truth
  (:func:`random_vignetting`, :func:`simulate_handheld_stack`);
* :mod:`selfcal.sim.exact` -- benchmark cells where the per-channel response model is exact;
* :mod:`selfcal.sim.cards` -- simulated memory cards of many sessions (``selfcal batch``);
* :mod:`selfcal.sim.mixed_cards` -- cards as photographers fill them: bursts, manual
  brackets, scenes mixed;
* :mod:`selfcal.sim.hard_cards` -- harder cards: slow manual, long tripod and handheld
  phone brackets, neighbouring scenes a minute apart, copies of a card;
* :mod:`selfcal.sim.raw_cards` -- a card of RAW+JPEG brackets of many scenes (DNG + JPEG);
* :mod:`selfcal.sim.scoring` -- scores against the simulator's truth;
* :mod:`selfcal.sim.luminance` -- the absolute calibration of a simulated camera (cd/m²).

The names below are re-exported here.  Nothing in the rest of the library imports this
package.

Examples
--------
>>> from selfcal import sim
>>> stack = sim.demo_stack()
>>> len(stack.images), stack.images[0].dtype
(6, dtype('uint8'))
>>> truth = stack.inverse_response()        # (256, 3) true f^-1 per channel
"""

from __future__ import annotations

from .camera import (CameraPipeline, default_pipeline, gamut_clip, gamut_compress,
                     random_color_matrix)
from .encoding import CHROMA_SUBSAMPLINGS, FrameOutput, UnsharpMask
from .lens import random_vignetting, simulate_handheld_stack, vignetting_rms
from .scenes import make_scene
from .sensor import SensorModel
from .stacks import (DEMO_EXPOSURE_TIMES, SyntheticStack, demo_stack, handheld,
                     simulate_raw_jpeg_pair, simulate_stack)
from .tone import ToneCurve

__all__ = ["ToneCurve", "gamut_clip", "gamut_compress", "CameraPipeline",
           "random_color_matrix", "default_pipeline", "UnsharpMask", "CHROMA_SUBSAMPLINGS",
           "FrameOutput", "make_scene", "SensorModel", "SyntheticStack", "simulate_stack",
           "simulate_raw_jpeg_pair", "handheld", "demo_stack", "DEMO_EXPOSURE_TIMES",
           "random_vignetting", "simulate_handheld_stack", "vignetting_rms"]
