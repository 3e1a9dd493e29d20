"""``ResponseOptions``: the finer settings of :func:`selfcal.calibrate_response`, its
sampling and its solve, which travel together through the stages of
:mod:`.calibrate` (samples, frame choice, the solve of [Lin2011] Eq. 8, δ, the verdict)
-- and the defaults they start from.

References
----------
[Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import InputError
from ..typing import PathLike
from .bands import DEFAULT_BAND_METHOD
from .basis import ResponseBasis
from .solver import SolverOptions

#: Basis functions per channel (N of Eq. 7 of [Lin2011]); chosen before the split rule
#: (docs/decisions.md, "Basis functions per channel: N = 5").
DEFAULT_N_COMPONENTS = 5
#: Sample locations drawn from a stack (block means; stratified, see collect_samples).
DEFAULT_MAX_SAMPLES = 4000
#: The values of :attr:`ResponseOptions.correspondences`.
CORRESPONDENCE_KINDS = ("blocks", "histogram", "histogram+blocks")


@dataclass(frozen=True)
class ResponseOptions(SolverOptions):
    """The finer settings of :func:`calibrate_response`: its sampling and its solve.

    Every field of :class:`selfcal.response.solver.SolverOptions` (``saturation_threshold``
    β, ``clip_margin``, ``huber_k``, the priors' weights, ``centre_ambiguity``, ...), and
    the fields of the sampling and the correspondences below.

    Attributes
    ----------
    basis : ResponseBasis or path, optional
        The response basis of Eq. 7 (a :class:`.basis.ResponseBasis`, or a file
        :func:`.basis.load_basis_file` reads: ``invemor.txt``, ``.npz``); default the
        built-in log-PCA basis.
    n_components : int
        Number of PCA basis functions per channel (N of Eq. 7); see
        :data:`DEFAULT_N_COMPONENTS`.  Capped at the basis' size.
    saturation_threshold : float
        β: samples whose HSV saturation exceeds it in either frame of a pair are rejected.
        Default 0.5 (see :data:`selfcal.response.solver.DEFAULT_SATURATION_THRESHOLD`).
    clip_margin : float
        Codes (8-bit scale) from 0 or the maximum code that count as clipped.
    max_samples : int
        Number of sample locations (block means) drawn from the stack.
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
    >>> options = ResponseOptions(saturation_threshold=0.3)
    >>> options.saturation_threshold, options.n_components, options.max_samples
    (0.3, 5, 4000)
    """

    n_components: int = DEFAULT_N_COMPONENTS
    max_samples: int = DEFAULT_MAX_SAMPLES
    basis: ResponseBasis | PathLike | None = field(default=None, repr=False, compare=False)
    correspondences: str = "blocks"
    measure_ringing: bool = True
    near_clip_blocks: int = 0
    hidden_white: bool = True
    band_method: str = DEFAULT_BAND_METHOD
    fit_vignetting: bool = True

    def __post_init__(self) -> None:
        if self.correspondences not in CORRESPONDENCE_KINDS:
            raise InputError(f"correspondences must be one of "
                             f"{', '.join(CORRESPONDENCE_KINDS)}, not {self.correspondences!r}")
        if self.band_method not in ("covariance", "bootstrap"):
            raise InputError(f"band_method must be covariance or bootstrap, not "
                             f"{self.band_method!r}")
        if int(self.near_clip_blocks) != self.near_clip_blocks or self.near_clip_blocks < 0:
            raise InputError(f"near_clip_blocks must be a whole number >= 0, not "
                             f"{self.near_clip_blocks!r}")
