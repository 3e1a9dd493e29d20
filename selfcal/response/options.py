"""``ResponseOptions``: the finer settings of :func:`selfcal.calibrate_response`, its
sampling and its solve, which travel together through the stages of
:mod:`.calibrate` (samples, frame choice, the solve of [Lin2011] Eq. 8, δ, the verdict)
-- and the defaults they start from.  The solve's own settings are a
:class:`.solver.SolverOptions` held in :attr:`ResponseOptions.solver` (composed, not
inherited: each field is declared in one class).

References
----------
[Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..errors import InputError
from ..typing import PathLike
from .bands import DEFAULT_BAND_METHOD
from .basis import ResponseBasis
from .solver import SolverOptions

#: Sample locations drawn from a stack (block means; stratified, see collect_samples).
DEFAULT_MAX_SAMPLES = 4000
#: The values of :attr:`ResponseOptions.correspondences`.
CORRESPONDENCE_KINDS = ("blocks", "histogram", "histogram+blocks")


def _solver_keywords_accepted(cls):
    """Let ``cls(...)`` take :class:`SolverOptions`' fields as keywords, as 1.0 did
    (``ResponseOptions(saturation_threshold=0.3)``), with a DeprecationWarning: they set
    the fields of ``solver``.  The fields stay declared in :class:`SolverOptions` only;
    ``dataclasses.replace(options, huber_k=2.0)`` works through the same door."""
    names = frozenset(f.name for f in fields(SolverOptions))
    generated = cls.__init__

    @functools.wraps(generated)
    def __init__(self, *args, **kwargs):
        flat = {k: kwargs.pop(k) for k in tuple(kwargs) if k in names}
        if flat:
            given = ", ".join(f"{k}={v!r}" for k, v in flat.items())
            warnings.warn(f"ResponseOptions({given}): the solve's settings are in "
                          f"ResponseOptions.solver; write "
                          f"ResponseOptions(solver=SolverOptions({given}))",
                          DeprecationWarning, stacklevel=2)
            solver = kwargs.get("solver", args[0] if args else SolverOptions())
            kwargs["solver"] = replace(solver, **flat)
            args = args[1:]
        generated(self, *args, **kwargs)

    cls.__init__ = __init__
    return cls


@_solver_keywords_accepted
@dataclass(frozen=True)
class ResponseOptions:
    """The finer settings of :func:`calibrate_response`: its sampling and its solve.

    The solve's settings -- the number of basis functions N, β (``saturation_threshold``),
    ``clip_margin``, ``huber_k``, the priors' weights, ``centre_ambiguity``, ... -- are
    the :class:`selfcal.response.solver.SolverOptions` in :attr:`solver`, which serves the
    sampling's masks too; the fields of the sampling and the correspondences are below.
    The keywords of 1.0, ``ResponseOptions(saturation_threshold=0.3)``, still set the
    fields of :attr:`solver`, with a DeprecationWarning; they are read as
    ``options.solver.saturation_threshold``.

    Attributes
    ----------
    solver : SolverOptions
        The settings of the solve of [Lin2011] Eq. 8 and of the samples' masks (clipped,
        β), read by every stage that needs them (samples, frame choice, solve, band,
        verdict).  ``n_components`` there is capped at the basis' size.  Default
        ``SolverOptions()``.
    basis : ResponseBasis or path, optional
        The response basis of Eq. 7 (a :class:`.basis.ResponseBasis`, or a file
        :func:`.basis.load_basis_file` reads: ``invemor.txt``, ``.npz``); default the
        built-in log-PCA basis.
    max_samples : int
        Number of sample locations (block means) drawn from the stack.  Default
        :data:`DEFAULT_MAX_SAMPLES` (4000).
    correspondences : {"blocks", "histogram", "histogram+blocks"}
        What Eq. 8 is solved on: ``"blocks"`` (default), the stratified flat block samples
        of :func:`selfcal.stack.samples.collect_samples`; ``"histogram"``, transfer
        functions matched on the histograms of every usable pixel
        (:mod:`.histogram_samples`, [Grossberg2003]), gated by a first fit on the blocks;
        ``"histogram+blocks"``, both sets of rows in one solve.  The block samples serve
        the verdict, the frame checks and the time contradictions in every case.
        Default chosen on the tuning split (docs/decisions.md, "Correspondences: block
        samples, not histograms").
    measure_ringing : bool
        Measure how far JPEG damage next to clipped areas reaches on the first fit and
        solve again without the samples within it (:mod:`.white_end`, ours); the reach is
        ``diagnostics["ringing_reach_blocks"]``.  Default True, chosen on the tuning
        split (docs/decisions.md, "The measured ringing reach next to clipped areas: on").
    near_clip_blocks : int
        A block within this many blocks of a clipped one counts as clipped
        (:func:`selfcal.stack.samples.reduce_frame`: keeps samples away from JPEG ringing at
        clipped edges, ours).  Default 0 (off), chosen on the tuning split
        (docs/decisions.md, "Blocks next to clipped ones: not widened").
    hidden_white : bool
        Count the samples the first fit predicts at white in a frame as clipped there, and
        solve again (:mod:`.hidden_white`, ours: JPEG moves clipped areas below the clip
        limit); how many is ``diagnostics["hidden_white_samples"]``.  Default True, chosen
        on the tuning split (docs/decisions.md, "Samples the fit predicts at white count
        as clipped: on, half a code").
    band_method : {"covariance", "bootstrap"}
        How the confidence band of f⁻¹ is estimated (:func:`selfcal.response.bands.curve_band`,
        ours): from the fit's covariance, or by resampling the samples.  Default
        ``"covariance"``, chosen on the tuning split (docs/decisions.md, "Curve bands: the
        covariance, σ_t = 0.02, σ_top = 0.03").
    fit_vignetting : bool
        With homography alignment (``align="homography"``, :func:`calibrate_aligned`),
        fit the lens's vignetting jointly with the response and the exposures where the
        frames moved enough to observe it (:mod:`.vignetting_fit`, [Goldman2010]); the
        model's ``vignetting`` and ``diagnostics["vignetting"]``.  Default True.

    Examples
    --------
    >>> options = ResponseOptions(solver=SolverOptions(saturation_threshold=0.3))
    >>> options.solver.saturation_threshold, options.solver.n_components, options.max_samples
    (0.3, 5, 4000)
    >>> options.with_solver(huber_k=2.0).solver.huber_k
    2.0
    """

    solver: SolverOptions = field(default_factory=SolverOptions)
    max_samples: int = DEFAULT_MAX_SAMPLES
    basis: ResponseBasis | PathLike | None = field(default=None, repr=False, compare=False)
    correspondences: str = "blocks"
    measure_ringing: bool = True
    near_clip_blocks: int = 0
    hidden_white: bool = True
    band_method: str = DEFAULT_BAND_METHOD
    fit_vignetting: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.solver, SolverOptions):
            raise InputError(f"ResponseOptions.solver must be a SolverOptions, not "
                             f"{type(self.solver).__name__}")
        if self.correspondences not in CORRESPONDENCE_KINDS:
            raise InputError(f"correspondences must be one of "
                             f"{', '.join(CORRESPONDENCE_KINDS)}, not {self.correspondences!r}")
        if self.band_method not in ("covariance", "bootstrap"):
            raise InputError(f"band_method must be covariance or bootstrap, not "
                             f"{self.band_method!r}")
        if int(self.near_clip_blocks) != self.near_clip_blocks or self.near_clip_blocks < 0:
            raise InputError(f"near_clip_blocks must be a whole number >= 0, not "
                             f"{self.near_clip_blocks!r}")

    def with_solver(self, **changes: Any) -> ResponseOptions:
        """These options with the fields ``changes`` of :attr:`solver` replaced.

        ``options.with_solver(clip_margin=4)`` is
        ``replace(options, solver=replace(options.solver, clip_margin=4))``.
        """
        return replace(self, solver=replace(self.solver, **changes))
