"""The HDR merge: a bracketed stack's frames, weighted, into one radiance map.

The merge is the weighted mean of Debevec & Malik (*Recovering High Dynamic Range Radiance
Maps from Photographs*, SIGGRAPH 1997, §2.2, their Eq. 6), taken on linear radiance rather
than its logarithm (the form whose inverse-variance weights are noise-optimal, Granados et
al. 2010), over the frames of a bracketed stack::

    E = Σ_j w_j(I_j) · f⁻¹(I_j) / e_j  /  Σ_j w_j(I_j)

with the inverse response f⁻¹ of :func:`selfcal.calibrate_response` (Lin, Kim, Süsstrunk &
Brown, *Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011, §5) or of
any model that linearises codes (a RAW-path ``PipelineModel`` with ``to_raw``), and
``e_j`` the relative exposure of frame ``j`` (``t · ISO/100 / N²`` from EXIF, so that the
radiance of several brackets of one session comes out on one scale;
:func:`selfcal.stack.frames.resolve_exposures`).  The weights are in :mod:`.weights`, the
deghosting in :mod:`.deghost`, the alignment in :mod:`selfcal.stack.align`.

Ours, where this differs from OpenCV's ``MergeDebevec`` and most tools:

* **clipped pixels never leak in**: a frame gets weight *zero* at a pixel where *any*
  channel is clipped (a code within ``clip_margin`` of 0 or of the maximum), not merely a
  small triangle weight on the clipped channel;
* **black floors and stuck ceilings**: per channel, the codes that do not move with
  exposure -- the calibration's stuck-sample test turned into code levels,
  :func:`selfcal.response.stuck_codes.stuck_code_levels`, carried in the model's diagnostics or measured
  on the frames -- count as clipped (memorial's short frames sit at a floor of codes
  13-19; with weight there, f⁻¹(floor)/e of the shortest frames swamped the shadows);
* **clipping follows exposure**, as in the calibration (``selfcal.stack.samples.frame_masks``):
  frames are merged shortest first, and a pixel some shorter frame saw clipped at white
  gets zero weight in every longer frame where it is bright (any channel at least
  :data:`.accumulate.WHITE_FOLLOWS` of white); in a **lossy** (JPEG) frame the clipped region is
  widened by :data:`RINGING_RADIUS` pixels (``cv2.dilate``), because ringing at a
  highlight edge leaves clipped pixels a few codes below white;
* **the same frames as the calibration**: a frame the model's calibration ignored is not
  merged, with its reason in a warning -- except one it ignored as too far from the rest
  of the bracket, which is merged with its time and flagged (:attr:`HDRResult.unchecked`);
* a **misalignment test**: neighbours in exposure are compared, exposure-normalised, as
  registered and shifted by a pixel (:mod:`.deghost`); a shift lowering the residual by
  more than ``deghost.MISALIGNMENT_GAIN`` gives a warning naming ``--align``;
* pixels that **no frame measured** unclipped are filled by a documented rule and reported
  in :attr:`HDRResult.unmeasured`: per channel, from the **darkest** frame (shortest
  exposure) when the brightest frame is clipped at white there -- a highlight; its
  ``f⁻¹(I)/e`` is a lower bound -- and otherwise from the **brightest** frame -- a shadow;
  an upper bound.  Where alignment leaves that frame without data, the reference frame is
  used;
* **noise-optimal weights by default**: the inverse variance of f⁻¹(I)/e under a shot +
  read + code noise model (Granados et al. 2010; Hasinoff et al. 2010;
  :mod:`.weights`), Debevec's hat as an option;
* optional **alignment** to the reference frame (median threshold bitmaps, Ward 2003;
  ECC homography, Evangelidis & Psarakis 2008) and **deghosting** against the reference
  frame with the noise model;
* frames are **streamed**: decoded one at a time (twice with alignment) into float32
  accumulators of the frame size, in strips of rows with OpenCV lookup tables for f⁻¹
  and the weights, in parallel threads; only the reference, darkest and brightest
  frames' codes are kept (deghosting, the fill): 17 frames of 24 MP in well under 2 GB;
* **linear frames** (raws, linear TIFFs): exposures from their pixels (:mod:`selfcal.exposure.linear`).

References
----------
.. [Debevec1997] P. E. Debevec and J. Malik, "Recovering High Dynamic Range Radiance Maps
   from Photographs", SIGGRAPH 1997.
.. [Lin2011] H. Lin, S. J. Kim, S. Süsstrunk and M. S. Brown, "Revisiting Radiometric
   Calibration for Color Computer Vision", ICCV 2011.
.. [Granados2010] M. Granados, B. Ajdin, M. Wand, C. Theobalt, H.-P. Seidel and H. P. A.
   Lensch, "Optimal HDR reconstruction with linear digital cameras", CVPR 2010.
.. [Hasinoff2010] S. W. Hasinoff, F. Durand and W. T. Freeman, "Noise-optimal capture for
   high dynamic range photography", CVPR 2010.
.. [Ward2003] G. Ward, "Fast, Robust Image Registration for Compositing High Dynamic Range
   Photographs from Hand-Held Exposures", Journal of Graphics Tools 8(2), 2003.
.. [Evangelidis2008] G. D. Evangelidis and E. Z. Psarakis, "Parametric Image Alignment
   Using Enhanced Correlation Coefficient Maximization", IEEE TPAMI 30(10), 2008.
"""

from __future__ import annotations

import warnings as _pywarnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from ..errors import CalibrationError, InputError, SelfcalWarning
from ..response.calibrate import CalibrationCall, aligned_calibration, calibrate_given
from ..response.options import ResponseOptions
from ..stack.align import estimate_alignment, negligible_motion
from ..stack.frames import DEFAULT_CLIP_MARGIN, StackFrames, default_reference, model_frame_index
from ..typing import ExposureTimes, ImageInput, Progress
from .accumulate import FrameWeighing, MergeSums, accumulate_frames
from .deghost import misalignment_warning, poor_agreement
from ..exposure.linear import fit_log_sigma, measure_linear_exposures, stack_frames
from ..exposure.legacy import legacy_keywords_accepted
from ..exposure.record import BracketExposures, ExposureRule, GivenTimes, read_given_times
from ..exposure.resolve import finish_merge_exposures, linear_exposures, merge_exposures, \
    model_exposures
from .weights import DEFAULT_NOISE, NoiseModel
from .plan import frames_to_merge, looks_lossy, stuck_levels
from .sigma import SigmaSums, add_trend_term
from .vignetting import apply_vignetting, check_vignetting_option, resolve_vignetting
from ..lens.luminance import absolute_radiance

__all__ = ["HDRResult", "MergeOptions", "merge_hdr"]

#: Pixels by which a lossy (JPEG) frame's white-clipped region is widened: ringing at a
#: highlight edge leaves codes a few below white that pass the clip test (ours).  Chosen
#: on the tuning split (docs/decisions.md, "Widening a lossy frame's white clip: 5 pixels").
RINGING_RADIUS = 5


@legacy_keywords_accepted("MergeOptions")
@dataclass(frozen=True)
class MergeOptions:
    """The finer settings of :func:`merge_hdr`; the defaults suit most stacks.

    Attributes
    ----------
    reference : int, optional
        Index of the reference frame (alignment, deghosting); default the middle one by
        exposure.
    noise : NoiseModel, optional
        For ``weighting="noise"`` and deghosting.  Default :data:`.weights.DEFAULT_NOISE`.
    clip_margin : float
        Codes (8-bit scale) within this distance of 0 or the maximum count as clipped;
        also the clip margin of a calibration on the fly.  Default
        :data:`selfcal.stack.frames.DEFAULT_CLIP_MARGIN` (2, as in calibration).
    deghost_threshold, deghost_tolerance : float
        ``k`` and the relative error floor of the deghosting test (see ``deghost``).
    lossy : bool, optional
        Widen white-clipped regions by :data:`RINGING_RADIUS` px.  Default: for JPEG files
        and 8-bit arrays (maybe decoded JPEGs: pass False for lossless ones).
    stuck_codes : dict or False, optional
        ``{"floor": [R, G, B], "ceiling": [R, G, B]}``, normalised codes.  Default: the
        model's ``diagnostics["stuck_codes"]``, else measured; False: none.
    exposures : ExposureRule
        The rule for given times, EXIF and the caller's alike, linear or rendered frames,
        and for the calibration on the fly (:class:`selfcal.exposure.ExposureRule`): by
        default the exposures are measured from the pixels -- through the model's curve
        for rendered frames (:mod:`selfcal.exposure.measured`: the model's own measurement
        for the frames it was calibrated on with the same times, files by path and arrays
        by content, nothing read again; else a pre-pass), from their ratios for linear ones
        (:mod:`selfcal.exposure.linear`) -- the times setting only their scale and trend,
        and σ's exposure term becomes the measurement's, with the trend's
        (docs/decisions.md, "Given times: measured by default, one rule");
        ``ExposureRule(times="held")`` merges with the times as given.  What was used,
        frame by frame: :attr:`HDRResult.exposure_record`.
    calibrate_options : ResponseOptions, optional
        The options of :func:`selfcal.calibrate_response` when it runs on the fly (no
        model given), with the merge's ``clip_margin``; default ``ResponseOptions()``.
    sigma : bool
        Also compute the radiance's standard deviation, :attr:`HDRResult.sigma`
        (:mod:`.sigma`: noise model, exposure uncertainty and the curve's band); two more
        float32 sums the size of the radiance while merging.  Default False.
    merge_unchecked : bool
        Merge a frame the calibration ignored as ``"unchecked"`` (too far from the rest of
        the bracket, :attr:`selfcal.ResponseModel.frames_ignored`) with its time, flagged
        in :attr:`HDRResult.unchecked` (ours); False leaves it out.  Default True, chosen
        on the tuning split, see docs/decisions.md.
    code_error : bool
        Add the curve's measured error per code (:mod:`selfcal.response.code_error`, the
        model's ``diagnostics["code_error_log"]``) to the variance of the noise weights
        and of σ (ours).  Default True, chosen on the tuning split, see docs/decisions.md.
    sigma_exposure_from_fit : bool
        With measured exposures and ``sigma``: σ's exposure term is the measurement's
        (:func:`selfcal.exposure.linear.fit_log_sigma`) or, False, the fixed one of given times.
    vignetting : {"auto", "self", "lens", "none"} or selfcal.lens.Vignetting
        The lens's falloff to divide out (:mod:`.vignetting`, [Goldman2010] Eq. 1):
        ``"auto"`` (default) the model's own (self-calibrated from frames that moved, or
        attached), else the lens database's profile for the frames' EXIF, else none;
        ``"self"`` or ``"lens"`` insist on that source (InputError without it); a
        flat-field frame's path: its falloff
        (:func:`selfcal.lens.flat_field.flat_field_vignetting`, linearised by the model); a
        :class:`~selfcal.lens.Vignetting` is used as given; ``"none"``: none.  What was
        chosen, and why the others were not: ``diagnostics["vignetting"]``; with ``sigma``,
        the vignetting's uncertainty joins σ.
    luminance : {None, "exif", "model"}, LuminanceScale or ReferenceReading
        Radiance and σ in cd/m² (:func:`selfcal.lens.luminance.absolute_radiance`: the EXIF
        convention of [ISO12232], the model's stored scale, a scale, or a reading of a
        region of this merge); None (default): relative.
    """

    reference: int | None = None
    noise: NoiseModel | None = None
    clip_margin: float = DEFAULT_CLIP_MARGIN
    deghost_threshold: float = 3.0
    deghost_tolerance: float = 0.1
    lossy: bool | None = None
    stuck_codes: dict | bool | None = None
    exposures: ExposureRule = ExposureRule()
    calibrate_options: ResponseOptions | None = None
    sigma: bool = False
    merge_unchecked: bool = True
    code_error: bool = True
    sigma_exposure_from_fit: bool = True
    vignetting: object = "auto"
    luminance: object = None


@dataclass
class HDRResult:
    """The radiance map of :func:`merge_hdr` and what was trusted to make it.

    Attributes
    ----------
    radiance : numpy.ndarray
        float32 ``HxWx3`` RGB radiance, ``f⁻¹(I) / e``: 1 is the signal that reaches white
        in a frame of relative exposure 1 (1 s at ISO 100 and f/1 when the exposures come
        from EXIF).
    unmeasured : numpy.ndarray
        bool ``HxW``: pixels that no frame measured with every channel unclipped; their
        values are the fill of :func:`merge_hdr` (a bound, not a measurement).
    ghost : numpy.ndarray
        bool ``HxW``: pixels where deghosting excluded at least one frame (so the value
        comes from the reference frame and the frames that agree with it).
    exposures : numpy.ndarray
        The relative exposure ``e_j`` used for each frame.
    warnings : list of str
    sources : list of str
        The frames (file names or ``"array #k"``).
    reference : int
        Index of the reference frame (alignment and deghosting).
    transforms : list of numpy.ndarray or None
        Per frame, the 3×3 matrix mapping reference pixel coordinates to that frame's
        (identity for the reference); None without alignment.
    exposure_source : str
        Where the exposures came from, in words made from :attr:`exposure_record`
        (:meth:`selfcal.exposure.BracketExposures.describe_source`): ``"given"``,
        ``"exif"``, ``"measured+exif"``, ``"measured+given"``, ``"measured"`` (no time
        known), ``"exif+model"`` (the model's solve).
    exposure_record : BracketExposures or None
        Every frame's exposures (given, solved, measured, used, contradicted, in the
        merge's unit ``t · ISO/100 / N²`` or the caller's), and the rule that chose.
    frame_count : numpy.ndarray
        uint8 ``HxW``: number of frames that contributed to each pixel.
    diagnostics : dict
        Per-frame fraction of pixels used, fraction excluded by deghosting, the weighting,
        the model's verdict when it was calibrated on the fly, ``stuck_codes`` (floors and
        ceilings used, 8-bit scale), ``frames_ignored``, ``ringing_radius`` and
        ``neighbour_residuals`` (the misalignment test of each neighbour pair).
    model : object
        The response model used (calibrated on the fly when none was given).
    unchecked : numpy.ndarray or None
        bool ``HxW``: measured pixels where, in some channel, more than half of the weight
        is that of frames merged with an exposure time the pixels could not check
        (``diagnostics['frames_unchecked']``: a frame the calibration ignored as too far
        from the rest of the bracket); None when no frame is unchecked.
    sigma : numpy.ndarray or None
        float32 ``HxWx3``, shaped like :attr:`radiance` and in its units: the standard
        deviation of each value from the noise model, the exposures' uncertainty and the
        curve's confidence band (:mod:`selfcal.hdr.sigma`), relative to the radiance's
        scale (the scale's own σ, in log, is ``diagnostics["sigma_scale_log"]``); +inf
        where unmeasured.  None unless ``MergeOptions(sigma=True)``.
    units : {"relative", "cd/m2"}
        Of :attr:`radiance` and :attr:`sigma`: cd/m² with ``MergeOptions(luminance=...)``
        (luminance ``0.2126 R + 0.7152 G + 0.0722 B``; the scale in ``diagnostics["luminance"]``,
        its σ then in :attr:`sigma`, in quadrature).
    """

    radiance: np.ndarray
    unmeasured: np.ndarray
    ghost: np.ndarray
    exposures: np.ndarray
    warnings: list = field(default_factory=list)
    sources: list = field(default_factory=list)
    reference: int = 0
    transforms: list | None = None
    exposure_source: str = "given"
    frame_count: np.ndarray | None = None
    diagnostics: dict = field(default_factory=dict)
    model: object = field(default=None, repr=False)
    sigma: np.ndarray | None = field(default=None, repr=False)
    unchecked: np.ndarray | None = field(default=None, repr=False)
    units: str = "relative"
    exposure_record: BracketExposures | None = field(default=None, repr=False)


# --------------------------------------------------------------------------------------
# the merge
# --------------------------------------------------------------------------------------

def merge_hdr(images: Sequence[ImageInput], exposure_times: ExposureTimes | None = None,
              model: object = None, *, weighting: str | Callable = "noise",
              align: Literal[False] | str = False, deghost: bool = False,
              linear: bool = False,
              options: MergeOptions | None = None,
              progress: Progress | None = None) -> HDRResult:
    """Merge a bracketed exposure stack into a radiance map.

    The per-pixel, per-channel weighted mean of Debevec & Malik (SIGGRAPH 1997, Eq. 6,
    here on linear values rather than logarithms)::

        E = Σ_j w_j · f⁻¹(I_j) / e_j  /  Σ_j w_j

    with the inverse response f⁻¹ of a :class:`~selfcal.ResponseModel` (Lin et al., ICCV
    2011, §5; calibrated on the fly with :func:`selfcal.calibrate_response` when none is
    given) and ``e_j`` the frame's relative exposure.  By default ``w_j`` is the inverse
    variance of ``f⁻¹(I_j)/e_j`` (Granados et al., CVPR 2010; Hasinoff et al., CVPR 2010),
    the minimum-variance combination.  Ours (the module docstring says more): ``w_j = 0``
    where any channel of frame ``j`` is clipped, at a black floor or a stuck ceiling, seen
    clipped by a shorter frame, or (JPEG) near a clipped region; frames the calibration
    ignored are not merged, but one too far from the rest of the bracket is, with its
    time, flagged unchecked; misaligned neighbours give a warning naming ``--align``;
    pixels no frame measures are filled with a bound and flagged.

    Parameters
    ----------
    images : sequence
        ``HxWx3`` uint8/uint16 RGB arrays or paths (JPEG/PNG/TIFF), one scene; or, with
        ``linear=True``, linear values (float in [0, 1] with white = 1, or uint8/uint16
        codes proportional to the signal).
    exposure_times : sequence of float or None, optional
        Relative exposure per frame (seconds, or anything proportional to the exposure;
        None = unknown).  Default: EXIF ``t · ISO/100 / N²`` for paths
        (:attr:`selfcal.io.ExposureInfo.relative_exposure`), so that brackets of one
        session share a scale.  Where the model refined the exposures, or found a given
        time contradicted by the pixels (``model.diagnostics['contradicting_times']``),
        its estimates are used instead (scaled to the given units) with a warning.
    model : ResponseModel or object, optional
        Anything with ``inverse_response(codes) -> (n, 3)`` (per-channel f⁻¹, the fast LUT
        path), or with ``to_raw(rendered) -> float32`` (a pipeline model: the backward
        JPEG→raw map, applied to each strip; its noise slopes are taken on the grey axis).
        Default: calibrated on the fly from the frames -- with ``align``, from the frames
        aligned first (downscaled to a 2048-pixel long side; alignment then uses a
        gamma-2.2 stand-in response), since misaligned frames give wrong correspondences.
    weighting : {"noise", "hat"} or callable
        ``"noise"`` (default): inverse variance of ``f⁻¹(I)/e`` under
        :class:`.weights.NoiseModel`, ``w = e² / (shot·x + read² + (f⁻¹'(z)·σ_z)²)``
        (Granados et al., CVPR 2010; Hasinoff et al., CVPR 2010; see
        :func:`.weights.noise_variance`).
        ``"hat"``: Debevec & Malik's triangle on the code (:func:`.weights.weight_hat`).
        The zero weights (clipping, floors, ceilings) apply to every weighting.
        A callable ``w(z)`` of the normalised code ``z`` in [0, 1] (any shape,
        element-wise, non-negative) is used like the hat (colour-hdri style).
    align : {False, "mtb", "homography"}
        Align every frame to the reference (see :func:`selfcal.stack.align.estimate_alignment`);
        ``True`` means ``"mtb"``.  Warped frames carry no data outside their footprint,
        and a pixel interpolated from a clipped one counts as clipped.
    deghost : bool
        Per pixel, exclude frames whose luminance disagrees with the reference frame's
        beyond the noise, ``(g·Y_j − Y_ref)² > k² (g²·Var[Y_j] + Var[Y_ref])`` with
        ``k = options.deghost_threshold`` and a relative floor
        ``max(options.deghost_tolerance, s)`` (``g``, ``s``: median and spread of the
        frame's ratio to the reference), then a 5×5 median filter (:mod:`.deghost`).
        Where the reference is clipped, all frames are kept.  :attr:`HDRResult.ghost`
        marks where a frame was excluded.
    linear : bool
        Linear frames (raw files and TIFFs showing linear data are, with a warning).
    options : MergeOptions, optional
        The finer settings: reference frame, noise model, clip margin, deghosting
        thresholds, JPEG ringing, stuck codes, linear frames' exposures, the on-the-fly
        calibration's options, σ, measured exposures, unchecked frames.
    progress : callable, optional
        ``progress(stage, done, total, detail)`` with stages ``"read"``/``"solve"`` (the
        calibration), ``"exposures"`` (linear frames), ``"align"`` and ``"merge"``.

    Returns
    -------
    HDRResult

    Raises
    ------
    InputError
        Unreadable or mismatched frames (the message names the file), bad arguments.
    CalibrationError
        Exposures that cannot be determined; calibration failures.

    Examples
    --------
    >>> import selfcal
    >>> from selfcal import sim
    >>> stack = sim.demo_stack()
    >>> result = selfcal.merge_hdr(stack.images, stack.exposure_times)
    >>> result.radiance.dtype, result.radiance.shape
    (dtype('float32'), (256, 384, 3))
    """
    opts = MergeOptions() if options is None else options
    align, noise = _check_options(weighting, align, linear, model, opts)
    warnings: list[str] = []
    diagnostics: dict = {"weighting": weighting if isinstance(weighting, str)
                         else getattr(weighting, "__name__", "callable")}
    images = list(images)
    given = read_given_times(images, exposure_times)
    frames = stack_frames(images, given, model, linear, warnings, diagnostics)
    linear = frames.linear  # raw files, and TIFFs that show linear data, are linear

    fresh, transforms, ref0 = False, None, None
    if model is None and not linear:
        model, transforms, ref0 = _calibrate_on_the_fly(frames, given, align, opts,
                                                        progress, warnings, diagnostics)
        fresh = True
    record = (_linear_exposures(frames, given, opts, progress) if linear else
              merge_exposures(given, model_frame_index(model, frames, fresh),
                              model_exposures(model), opts.exposures))
    exposures = record.used
    vignetting, diagnostics["vignetting"] = resolve_vignetting(
        opts.vignetting, model, path=next((p for p in frames.paths if p), None),
        shape=frames.shape)
    ref = _reference_frame(exposures, opts.reference, len(frames))
    if transforms is not None:
        assert ref0 is not None     # an aligned calibration says its reference
        transforms = _relative_to(transforms, ref0, ref)
    elif align and len(frames) > 1:
        transforms = estimate_alignment(frames, exposures, model, method=align, reference=ref,
                                        linear=linear, clip_margin=opts.clip_margin,
                                        warnings=warnings, progress=progress)

    used, unchecked, ref, stuck, radius = _merge_plan(
        frames, model, fresh, exposures, ref, opts, linear=linear, warnings=warnings,
        diagnostics=diagnostics)
    record, line = finish_merge_exposures(
        frames, model, record, [] if linear else [k for k in used if k not in unchecked],
        opts.exposures, clip_margin=opts.clip_margin, stuck=stuck, progress=progress)
    exposures = record.used
    if line:
        warnings.append(line)
    sigma_t, trend_sigma = None, 0.0
    if record.spread is not None and opts.sigma_exposure_from_fit:
        sigma_t, trend_sigma = record.spread.log_sigma, record.spread.trend_log_sigma
    sums = MergeSums(frames.shape, exposures, ref, used, unchecked)
    if opts.sigma:
        sums.sigma = SigmaSums(frames.shape, model, exposure_log_sigma=sigma_t)
        diagnostics["sigma_curve_band"] = sums.sigma.has_band
    moved = transforms is not None and any(not negligible_motion(t, frames.shape)
                                           for t in transforms)
    sums.falloff = vignetting if moved else None
    need_x = deghost and len(used) > 1
    weighing = FrameWeighing(weighting, noise, opts.clip_margin, linear, stuck, radius, need_x,
                             opts.deghost_threshold, opts.deghost_tolerance, opts.code_error)
    accumulate_frames(sums, frames, exposures, model, transforms, weighing, progress)
    unmeasured = _finish(sums, frames, need_x, transforms is None,
                         record.used_from != "given", warnings, diagnostics)
    sigma = None if sums.sigma is None else _sigma_result(sums, diagnostics)
    if vignetting is not None:
        apply_vignetting(sums.num, sigma, vignetting, moved=moved,
                         record=diagnostics["vignetting"])
    if sigma is not None and trend_sigma > 0:
        add_trend_term(sigma, sums.num, trend_sigma)
    if opts.luminance is not None:
        sums.num, sigma, diagnostics["luminance"] = absolute_radiance(
            opts.luminance, sums.num, sigma, model=model, unmeasured=unmeasured,
            exif_exposures=record.origin == "exif", linear=linear)
    return HDRResult(radiance=sums.num, unmeasured=unmeasured, ghost=sums.ghost,
                     exposures=exposures, warnings=warnings, sources=list(frames.sources),
                     reference=ref, transforms=transforms,
                     exposure_source=record.describe_source(), exposure_record=record,
                     frame_count=sums.count, diagnostics=diagnostics, model=model,
                     sigma=sigma,
                     unchecked=sums.unchecked_pixels(unmeasured),
                     units="relative" if opts.luminance is None else "cd/m2")


def _linear_exposures(frames: StackFrames, given: GivenTimes, opts: MergeOptions,
                      progress) -> BracketExposures:
    """A linear bracket's exposures (:func:`selfcal.exposure.linear.measure_linear_exposures`):
    its ratios measured from the pixels on the times' scale, or the times held."""
    lin = measure_linear_exposures(frames, list(given.relative), hold=opts.exposures.held,
                                   clip_margin=opts.clip_margin, progress=progress)
    return linear_exposures(given, lin, opts.exposures, fit_log_sigma(lin.measured, lin.pairs))


def _sigma_result(sums: MergeSums, diagnostics: dict) -> np.ndarray:
    """:attr:`HDRResult.sigma`, with the noise scale κ it used in the diagnostics."""
    assert sums.sigma is not None   # the merge kept σ sums
    diagnostics["sigma_noise_scale"] = round(sums.sigma.kappa, 4)
    diagnostics["sigma_scale_log"] = sums.sigma.scale_log_sigma
    return sums.sigma.result()


def _reference_frame(exposures, reference, n: int) -> int:
    """The reference frame asked for, else the middle one by exposure."""
    ref = default_reference(exposures) if reference is None else int(reference)
    if not 0 <= ref < n:
        raise InputError(f"reference frame {reference} is out of range (0..{n - 1})")
    return ref


def _merge_plan(frames: StackFrames, model, fresh: bool, exposures, ref: int,
                opts: MergeOptions, *, linear: bool, warnings: list, diagnostics: dict):
    """(frames to merge, frames merged unchecked, reference, per-channel floors and
    ceilings or None, ringing radius).

    The reference moves to the middle merged frame when the calibration ignored it (an
    error when the caller chose it), or to the middle checked one when it is unchecked.
    """
    used, unchecked = frames_to_merge(frames, model, fresh, exposures, warnings, diagnostics,
                                       merge_unchecked=opts.merge_unchecked)
    if ref in unchecked:
        ref = [k for k in used if k not in unchecked][default_reference(
            exposures[[k for k in used if k not in unchecked]])]
    if ref not in used:
        ref = used[default_reference(exposures[used])] if opts.reference is None else ref
    if ref not in used:
        raise InputError(f"reference frame {ref} was ignored by the calibration: choose "
                         "another", frames.sources[ref])
    stuck = None if linear or opts.stuck_codes is False else stuck_levels(
        model, frames, exposures, used, opts.clip_margin, diagnostics, opts.stuck_codes)
    lossy = looks_lossy(frames, linear) if opts.lossy is None else opts.lossy
    radius = RINGING_RADIUS if lossy else 0
    diagnostics["ringing_radius"] = radius
    return used, unchecked, ref, stuck, radius


def _finish(sums: MergeSums, frames: StackFrames, deghosted: bool, unaligned: bool,
            exposures_from_pixels: bool, warnings: list, diagnostics: dict) -> np.ndarray:
    """The radiance from the sums, the fill, and what the merge has to say about them.

    Returns the mask of unmeasured pixels.
    """
    diagnostics.update(sums.frame_diagnostics(frames.sources, deghost=deghosted))
    poor = (poor_agreement(sums.ghost_stats, frames.sources, sums.ref) if deghosted
            else None)
    if poor:
        warnings.append(poor)
    diagnostics["neighbour_residuals"] = sums.residuals
    moved = (misalignment_warning(sums.residuals, exposures_from_pixels) if unaligned
             else None)
    if moved:
        warnings.append(moved)
    unmeasured = sums.divide_and_fill()
    n_unmeasured = int(np.count_nonzero(unmeasured))
    if n_unmeasured:
        warnings.append(f"{n_unmeasured} pixels ({100 * n_unmeasured / unmeasured.size:.2g}%) "
                        "are clipped in every frame (unmeasured; filled from the darkest "
                        "frame for highlights, the brightest for shadows)")
    return unmeasured


def _check_options(weighting, align, linear: bool, model, opts: MergeOptions):
    """``align`` as a method name or False (``True`` means ``"mtb"``), and the noise model
    (default :data:`.weights.DEFAULT_NOISE`); errors for bad options."""
    if weighting not in ("hat", "noise") and not callable(weighting):
        raise InputError(f"unknown weighting {weighting!r} (hat, noise or a function)")
    if align is True:
        align = "mtb"
    if align not in (False, None, "mtb", "homography"):
        raise InputError(f"unknown alignment {align!r} (mtb or homography)")
    if linear and model is not None:
        raise InputError("linear=True: the frames are linear already; do not pass a model")
    if not isinstance(opts.exposures, ExposureRule):
        raise InputError(f"MergeOptions(exposures=...) must be an ExposureRule, not "
                         f"{type(opts.exposures).__name__}")
    check_vignetting_option(opts.vignetting)
    return align, (DEFAULT_NOISE if opts.noise is None else opts.noise)


def _calibrate_on_the_fly(frames: StackFrames, given: GivenTimes, align, opts: MergeOptions,
                          progress, warnings: list, diagnostics: dict):
    """The frames' own response (Lin et al., ICCV 2011, §5), when no model is given.

    On the times the merge read (``given``: nothing is read twice) and by the merge's rule
    for them; with ``align``, on the frames aligned first
    (:func:`selfcal.response.calibrate.aligned_calibration`).  The calibration's warnings
    join ``warnings`` (its exposures are the merge's, said once by the merge) and its
    verdict ``diagnostics``.

    Returns
    -------
    (model, transforms or None, reference frame of the transforms or None)
    """
    if len(frames) < 2:
        raise CalibrationError("one frame and no model: give a model (a response needs "
                               "at least two frames to calibrate)")
    transforms = ref0 = None
    # one clip margin per merge: the calibration's is the merge's
    options = (opts.calibrate_options or ResponseOptions()).with_solver(
        clip_margin=opts.clip_margin)
    # its warnings are the merge's (below, in HDRResult.warnings), not warned twice
    with _pywarnings.catch_warnings():
        _pywarnings.simplefilter("ignore", SelfcalWarning)
        if align:
            # the vignetting is fitted only where the merge may use it
            call = CalibrationCall(options=replace(options, fit_vignetting=opts.vignetting
                                                   in ("auto", "self")),
                                   rule=opts.exposures, progress=progress)
            model, transforms, ref0, aligned_warnings = aligned_calibration(
                frames, given, call, method=align, reference=opts.reference,
                clip_margin=opts.clip_margin)
            warnings.extend(aligned_warnings)
            diagnostics["calibrated_on"] = model.diagnostics.get("calibrated_on")
        else:
            model = calibrate_given(frames.items, given,
                                    CalibrationCall(options=options, rule=opts.exposures,
                                                    progress=progress))
    diagnostics["model_verdict"] = model.diagnostics.get("verdict")
    warnings.extend(f"calibration: {w}" for w in model.diagnostics.get("warnings", []))
    return model, transforms, ref0


def _relative_to(transforms, ref0: int, ref: int):
    """An aligned calibration's transforms (relative to frame ``ref0``) re-expressed
    relative to ``ref``, the reference when the model's exposures moved it."""
    if ref == ref0:
        return transforms
    inv = np.linalg.inv(transforms[ref])
    transforms = [t @ inv for t in transforms]
    transforms = [t / t[2, 2] for t in transforms]
    transforms[ref] = np.eye(3)
    return transforms
