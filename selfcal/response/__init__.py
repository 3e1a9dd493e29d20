"""The JPEG-only path: a camera's response from an exposure stack ([Lin2011] §5).

:func:`selfcal.calibrate_response` (:mod:`.calibrate`) takes its finer settings as a
:class:`ResponseOptions`; the solve of Eq. 8 alone (:mod:`.solver`) as a
:class:`SolverOptions`.  Its modules:

* :mod:`selfcal.response.calibrate` -- :func:`calibrate_response`, frames to a model;
* :mod:`selfcal.response.options` -- :class:`ResponseOptions`, its finer settings and their
  defaults;
* :mod:`selfcal.response.model` -- :class:`ResponseModel` and its model file;
* :mod:`selfcal.response.basis` -- the log-domain PCA basis of Eq. 7 (built in, or a file);
* :mod:`selfcal.response.basis_files` -- Grossberg & Nayar's EMoR and DoRF files;
* :mod:`selfcal.response.curve_family` -- the response-curve family the built-in basis is
  computed from;
* :mod:`selfcal.response.equations` -- the rows of Eq. 8 and the censored threshold rows;
* :mod:`selfcal.response.priors` -- the priors added to Eq. 8's normal equations;
* :mod:`selfcal.response.solver` -- the joint solve for coefficients and log exposures;
* :mod:`selfcal.response.frame_choice` -- which frames the solve can use;
* :mod:`selfcal.response.histogram_samples` -- correspondences by histogram matching;
* :mod:`selfcal.response.white_end` -- how far JPEG damage next to clipping reaches;
* :mod:`selfcal.response.hidden_white` -- samples at white that JPEG moved below the clip
  limit;
* :mod:`selfcal.response.code_error` -- the curve's error per code, on its own samples;
* :mod:`selfcal.response.vignetting_fit` -- the lens falloff from frames that moved, fitted
  jointly with the response ([Goldman2010]);
* :mod:`selfcal.response.bands` -- the confidence band of f⁻¹;
* :mod:`selfcal.response.delta` -- δ of Eq. 12;
* :mod:`selfcal.response.verdict` -- whether the fit can be trusted, from its evidence;
* :mod:`selfcal.response.solved_times` -- the given times in the solve: Eq. 8's log times,
  refined exposures anchored, the times they corrected;
* :mod:`selfcal.response.stuck_codes` -- the black floor and stuck ceiling of a stack's codes;
* :mod:`selfcal.response.diagnostics` -- what the fit says about itself, in the model.
"""

from .options import ResponseOptions
from .solver import SolverOptions

__all__ = ["ResponseOptions", "SolverOptions"]
