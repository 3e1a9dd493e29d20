"""selfcal: radiometric self-calibration of cameras.

Two calibration paths, after the two papers this package implements:

* the JPEG-only path: per-channel camera response functions from a bracketed exposure
  stack with the log-domain PCA model of Lin, Kim, Süsstrunk & Brown, *Revisiting
  Radiometric Calibration for Color Computer Vision*, ICCV 2011 (§5, Eq. 7-8);
* the RAW path: the rank-based radiometric calibration pipeline (colour matrix, monotone
  tone curves, lattice-regression gamut LUT) with the RBF inverse colour mapping of Lin et
  al. (§6, Eq. 9-11).

Its packages, from the ground floor up (a module imports only from its own floor and the
floors below):

* :mod:`selfcal.errors` -- the exceptions and the warning the library raises;
* :mod:`selfcal.version` -- the version, read from the installed package's metadata;
* :mod:`selfcal.typing` -- the type aliases of the public signatures;
* :mod:`selfcal.io` -- image files and EXIF, linear raws, model files; atomic writes;
* :mod:`selfcal.stack` -- a bracket before any model: frames, alignment, correspondences;
* :mod:`selfcal.exposure` -- a bracket's exposures: given, EXIF, raw ratios, measured, the plan;
* :mod:`selfcal.lens` -- the lens and the scale: vignetting, lens profiles, flat fields, cd/m²;
* :mod:`selfcal.response` -- the JPEG-only path: the response from an exposure stack;
* :mod:`selfcal.pipeline` -- the RAW path: a camera pipeline from RAW+JPEG pairs;
* :mod:`selfcal.hdr` -- HDR radiance maps, their σ, and the files they are written to;
* :mod:`selfcal.export` -- calibrations as LUTs and OpenColorIO configs;
* :mod:`selfcal.choose` -- which path the inputs allow; loading a model file;
* :mod:`selfcal.report` -- plots and the text a person reads about a model;
* :mod:`selfcal.batch` -- photo libraries: sessions, one curve per camera, Dask;
* :mod:`selfcal.sim` -- the camera simulator with ground truth (tests, benchmarks, demo).
"""

from __future__ import annotations

from . import errors
from .version import __version__
from .errors import (
    CalibrationError,
    InputError,
    ModelFileError,
    OutputExistsError,
    SelfcalError,
    SelfcalWarning,
)

from .choose.loading import load_model
from .response.calibrate import calibrate_response
from .response.options import ResponseOptions
from .exposure.record import ExposureRule
from .response.model import ResponseModel
from .pipeline import PipelineModel, PipelineOptions, fit_pipeline
from .choose.paths import CalibrationResult, calibrate, calibrate_pipeline  # path choice; RAW path
from .io.raw import RawImage, read_raw_linear  # linear camera raw (rawpy/LibRaw)
from .hdr import MergeOptions, merge_hdr  # HDR radiance maps (selfcal.hdr)


__all__ = [
    "calibrate",
    "calibrate_pipeline",
    "CalibrationResult",
    "read_raw_linear",
    "RawImage",
    "calibrate_response",
    "ResponseOptions",
    "ExposureRule",
    "load_model",
    "ResponseModel",
    "fit_pipeline",
    "PipelineOptions",
    "PipelineModel",
    "merge_hdr",
    "MergeOptions",
    "errors",
    "CalibrationError",
    "InputError",
    "ModelFileError",
    "OutputExistsError",
    "SelfcalError",
    "SelfcalWarning",
    "__version__",
]
