"""The camera simulator with ground truth, for tests, benchmarks and ``selfcal demo``.

* :mod:`selfcal.sim.synth` -- camera pipelines, scenes, sensor noise, bracketed stacks and
  RAW+JPEG pairs (re-exported here);
* :mod:`selfcal.sim.conditions` -- the named benchmark conditions (the condition matrix);
* :mod:`selfcal.sim.cards` -- simulated memory cards of many sessions (``selfcal batch``);
* :mod:`selfcal.sim.scoring` -- scores against the simulator's truth.

Nothing in the rest of the library imports this package.
"""

from __future__ import annotations

from .synth import (CHROMA_SUBSAMPLINGS, DEMO_EXPOSURE_TIMES, CameraPipeline, SensorModel,
                    SyntheticStack, ToneCurve, UnsharpMask, default_pipeline, demo_stack,
                    gamut_clip, gamut_compress, handheld, make_scene, random_color_matrix,
                    simulate_raw_jpeg_pair, simulate_stack)

__all__ = ["ToneCurve", "gamut_clip", "gamut_compress", "CameraPipeline",
           "random_color_matrix", "default_pipeline", "UnsharpMask", "CHROMA_SUBSAMPLINGS",
           "make_scene", "SensorModel", "SyntheticStack", "simulate_stack",
           "simulate_raw_jpeg_pair", "handheld", "demo_stack", "DEMO_EXPOSURE_TIMES"]
