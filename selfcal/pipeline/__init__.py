"""The RAW path: a camera pipeline fitted from corresponding raw and rendered samples.

[Gong2018]: rank-based colour matrix (§3.2, Eq. 4-8), monotone tone curves by QP (§3.3,
Eq. 9), lattice-regression gamut LUT (§3.4), backward model (§3.5); with the RBF inverse
colour mapping of [Lin2011] (§6, Eq. 9-11); clipped pixels get ``E[raw | code]`` learned
from clipped training samples (:mod:`selfcal.pipeline.clipped`).
:mod:`selfcal.pipeline.nus` reads the NUS in-camera model files ([Kim2012]) as a real
camera pipeline.  Citation keys are those of ``docs/references.md``.  Its modules:

* :mod:`selfcal.pipeline.fit` -- :func:`fit_pipeline`, from raw and rendered samples;
* :mod:`selfcal.pipeline.model` -- :class:`PipelineModel`, forward and backward;
* :mod:`selfcal.pipeline.matrix` -- the rank-based colour matrix ([Gong2018] §3.2);
* :mod:`selfcal.pipeline.tone` -- monotone 7th-order tone curves by QP ([Gong2018] §3.3);
* :mod:`selfcal.pipeline.lattice` -- the lattice-regression LUT and g ([Gong2018] §3.4);
* :mod:`selfcal.pipeline.rbf` -- the RBF inverse colour mapping h⁻¹ ([Lin2011] §6);
* :mod:`selfcal.pipeline.clipped` -- backward estimates for clipped rendered pixels;
* :mod:`selfcal.pipeline.dense` -- dense 3-D tables baked for whole images;
* :mod:`selfcal.pipeline.trust` -- how far from its training colours a model is used;
* :mod:`selfcal.pipeline.pairs` -- RAW+JPEG pairs, registered and sampled;
* :mod:`selfcal.pipeline.library` -- one model from many scenes' pairs, by leave-one-scene-out;
* :mod:`selfcal.pipeline.registration` -- where a camera's JPEG lies on its raw;
* :mod:`selfcal.pipeline.nus` -- the NUS in-camera model files ([Kim2012]);
* :mod:`selfcal.pipeline.nus_render` -- an NUS model's render table;
* :mod:`selfcal.pipeline.baselines` -- baseline pipeline models for comparisons.

Examples
--------
>>> from selfcal import sim
>>> from selfcal.pipeline import PipelineOptions, fit_pipeline
>>> pair = sim.simulate_raw_jpeg_pair(seed=0)
>>> model = fit_pipeline(pair["raw"].reshape(-1, 3), pair["rendered"].reshape(-1, 3) / 255,
...                      PipelineOptions(n_sets=2), n_train=800)
>>> rendered = model.render(pair["raw"])          # float32 HxWx3 in [0, 1]
>>> raw = model.to_raw(pair["rendered"])          # float32 linear raw
>>> raw, outside = model.to_raw(pair["rendered"], return_mask=True)  # far from training
"""

from .clipped import ClippedCorrection, clipped_pixel_correction
from .fit import PipelineOptions, fit_pipeline
from .library import LibraryFit, LibraryOptions, fit_pipeline_library
from .lattice import LatticeLUT, LatticeOptions, highlight_stretch, lattice_regression_lut
from .matrix import fibonacci_sphere, rank_based_matrix, row_scales
from .model import BackwardStages, ForwardStages, PipelineModel
from .nus import read_nus_model
from .rbf import RBFColourMapping, rbf_inverse_colour_mapping
from .tone import MonotonePolynomial, monotone_tone_curves
from .trust import TrainingColours

__all__ = [
    "fit_pipeline",
    "fit_pipeline_library",
    "LibraryOptions",
    "LibraryFit",
    "PipelineOptions",
    "PipelineModel",
    "ForwardStages",
    "BackwardStages",
    "rank_based_matrix",
    "row_scales",
    "fibonacci_sphere",
    "monotone_tone_curves",
    "MonotonePolynomial",
    "lattice_regression_lut",
    "LatticeOptions",
    "LatticeLUT",
    "highlight_stretch",
    "rbf_inverse_colour_mapping",
    "RBFColourMapping",
    "read_nus_model",
    "clipped_pixel_correction",
    "ClippedCorrection",
    "TrainingColours",
]
