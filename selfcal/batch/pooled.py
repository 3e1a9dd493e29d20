"""One response curve per camera body, fitted from the samples of several sessions.

Lin, Kim, Süsstrunk & Brown (*Revisiting Radiometric Calibration for Color Computer
Vision*, ICCV 2011, §5) fit the log-PCA model of Eq. 7 to the exposure equation of Eq. 8,

    g(I′) − g(I) = K′ − K,

over the sample pairs of *one* bracketed stack.  Nothing in Eq. 8 ties the samples of a
pair to one scene beyond the pair itself: rows from several stacks of one camera can sit
in one system with one g (the camera's curve) and each stack's own exposures K.  That is
the pooled fit here, built on the solver's public pieces
(:func:`selfcal.response.solver.solve_exposure_equations`) without changing them:

* **Block-diagonal samples** (ours).  The sessions' samples are laid side by side: frame
  ``j`` of session ``s`` holds its own values at the sample locations of ``s`` and is
  masked out (``clipped``) everywhere else, so no pair row ever joins two scenes.
* **Exposures per session** (ours).  Each session's log exposure times are its own
  unknowns' known values (EXIF, fixed as in ``selfcal calibrate``), shifted by a constant
  per session.  Eq. 8 sees exposure differences within a pair only, so a constant per
  session changes no row; it orders the frames session by session, so that the solver's
  pairing of each frame with its next ``max_rank_gap`` frames by exposure
  (:func:`selfcal.response.equations.frame_pairs`) pairs the frames of one session exactly
  as a single-session fit does.  With one session the pooled fit *is* the single-session
  solve (``tests/test_batch.py`` checks it).
* **Agreement** (ours): each session's samples are predicted through a curve, frame to
  frame (:func:`eq8_code_residual`); the RMS in 8-bit codes under the shared curve is
  compared with the RMS under the session's own fit.  A session whose residual under the
  shared curve exceeds :data:`DISAGREEMENT_RATIO` times its own (and its own by more than
  :data:`DISAGREEMENT_FLOOR` codes) is *flagged*: it is left out of the pool, which is
  fitted again, and fitted alone.

The memory of the block-diagonal layout grows with (frames × samples) of the whole pool,
which is why the pool is bounded (``max_sessions``, ``samples_per_session``): past a few
dozen scenes a curve gains little (``python3 -m bench.batch`` measures it).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..exposure.record import BracketExposures, FrameExposure
from ..errors import CalibrationError
from ..response.basis import ResponseBasis
from ..typing import ExposureTimes, ImageInput
from ..response.stuck_codes import stuck_code_levels
from ..stack.frames import DEFAULT_CLIP_MARGIN
from ..response.solver import DEFAULT_N_COMPONENTS
from ..response.equations import frame_pairs
from ..response.model import ResponseModel
from ..response.solver import (DEFAULT_SATURATION_THRESHOLD, SolverOptions,
                               solve_exposure_equations)
from ..stack.samples import FrameSamples, SampleSet, collect_samples, frame_masks

#: A session disagrees with the shared curve when its code residual under that curve
#: exceeds this factor times its residual under its own fit ...
DISAGREEMENT_RATIO = 1.5
#: ... and exceeds its own by more than this many 8-bit codes (JPEG noise alone gives a
#: residual near one code, which a ratio alone would over-read).
DISAGREEMENT_FLOOR = 0.75
#: Sample locations drawn from each session for the pool.
POOL_SAMPLES = 1000
#: Sessions fitted together at most (chosen evenly over the camera's sessions).
POOL_SESSIONS = 24
#: Pairs of frames compared in the agreement test (as the solver's default).
MAX_RANK_GAP = 3


@dataclass
class SessionSamples(FrameSamples):
    """A session's samples for the pooled fit: block means across its frames, with masks.

    Attributes
    ----------
    session : str
    sources : list of str
        The frames (paths), in the order of ``values``.
    log_times : numpy.ndarray
        ``(F,)`` log exposure time of each frame (seconds at the first frame's ISO and
        aperture), all known.
    values : numpy.ndarray
        ``(F, n, 3)`` float32 block means normalised to [0, 1].
    clipped, saturated : numpy.ndarray
        ``(F, n)`` masks of :func:`selfcal.stack.samples.frame_masks` (Lin et al. §5).
    max_code : int
    stuck_codes : dict
        :func:`selfcal.response.stuck_codes.stuck_code_levels` of these samples.
    own_intensity, own_inverse : numpy.ndarray or None
        The session's own fit (grid, f⁻¹ table), for the agreement test.
    """

    session: str
    sources: list
    log_times: np.ndarray
    values: np.ndarray
    clipped: np.ndarray
    saturated: np.ndarray
    max_code: int
    stuck_codes: dict
    own_intensity: np.ndarray | None = None
    own_inverse: np.ndarray | None = None


def session_samples(frames: Sequence[ImageInput], exposure_times: ExposureTimes, *,
                    session: str = "",
                    max_samples: int = POOL_SAMPLES, clip_margin: float = DEFAULT_CLIP_MARGIN,
                    saturation_threshold: float = DEFAULT_SATURATION_THRESHOLD,
                    seed: int = 0) -> SessionSamples:
    """Sample one session's frames for the pooled fit (the workers call this on paths).

    :func:`selfcal.stack.samples.collect_samples` (stratified flat blocks, as for a single
    calibration, with fewer locations) and :func:`selfcal.stack.samples.frame_masks`.

    Parameters
    ----------
    frames : sequence of path
        The frames the session's own calibration used.
    exposure_times : sequence of float
        Their exposure times (seconds), all known.
    session : str
        Its name, carried along.
    max_samples, clip_margin, saturation_threshold, seed
        As for :func:`selfcal.calibrate_response`.

    Raises
    ------
    CalibrationError
        When a time is missing: a pooled session needs its exposures.
    InputError
        Unreadable frames (named).
    """
    times = [None if t is None else float(t) for t in exposure_times]
    if len(times) != len(frames) or any(t is None or not t > 0 for t in times):
        raise CalibrationError(f"session {session}: every frame needs a known exposure "
                               "time to join a pooled fit")
    samples = collect_samples(list(frames), max_samples=max_samples,
                              clip_margin=clip_margin, seed=seed)
    masks = frame_masks(samples, clip_margin=clip_margin,
                        saturation_threshold=saturation_threshold)
    log_times = np.log(np.asarray(times, dtype=float))
    stuck = stuck_code_levels(samples.values, log_times, clip_margin=clip_margin)
    return SessionSamples(session=session, sources=[str(f) for f in frames],
                          log_times=log_times, values=samples.values.astype(np.float32),
                          clipped=masks["clipped"], saturated=masks["saturated"],
                          max_code=samples.max_code, stuck_codes=stuck)


@dataclass
class SharedFit:
    """The result of :func:`fit_shared_response`.

    Attributes
    ----------
    intensity : numpy.ndarray
        ``(K,)`` the basis grid.
    inverse : numpy.ndarray
        ``(K, 3)`` the shared f⁻¹ (non-decreasing, f⁻¹(1) = 1).
    coefficients : numpy.ndarray
        ``(3, N)`` Eq. 7 coefficients.
    basis_name : str
    residual_rms : float
        Weighted RMS of the Eq. 8 residuals of the pooled solve (log units).
    sessions : list of str
        The sessions fitted together.
    rows_used : int
    warnings : list of str
    """

    intensity: np.ndarray
    inverse: np.ndarray
    coefficients: np.ndarray
    basis_name: str
    residual_rms: float
    sessions: list
    rows_used: int
    warnings: list = field(default_factory=list)


def _pooled_sample_set(sessions):
    """The sessions' samples side by side (block diagonal), masks, and shifted log times.

    Returns ``(samples, masks, log_times, offsets)``: frame ``j`` of session ``s`` is
    valid only on the locations of ``s``; session ``s``'s log times are shifted by
    ``offsets[s]`` so that its frames follow the previous session's in exposure order.
    """
    F = sum(s.n_frames for s in sessions)
    n = sum(s.n_samples for s in sessions)
    values = np.zeros((F, n, 3))
    clipped = np.ones((F, n), dtype=bool)
    saturated = np.zeros((F, n), dtype=bool)
    log_times = np.empty(F)
    offsets = []
    f0 = n0 = 0
    top = 0.0
    for s in sessions:
        f1, n1 = f0 + s.n_frames, n0 + s.n_samples
        values[f0:f1, n0:n1] = s.values
        clipped[f0:f1, n0:n1] = s.clipped
        saturated[f0:f1, n0:n1] = s.saturated
        # a whole number of e (10 log units) past the previous session's longest exposure:
        # the shift is exact in floating point relative to the span of one session
        shift = 0.0 if f0 == 0 else math.ceil(top - float(s.log_times.min()) + 10.0)
        log_times[f0:f1] = s.log_times + shift
        offsets.append(shift)
        top = float(log_times[f0:f1].max())
        f0, n0 = f1, n1
    max_codes = {s.max_code for s in sessions}
    if len(max_codes) != 1:
        raise CalibrationError("the sessions of a pooled fit differ in bit depth "
                               f"({sorted(max_codes)}): they cannot share one curve")
    samples = SampleSet(values=values, block_max=np.zeros((F, n)), block_min=np.zeros((F, n)),
                        flatness=np.zeros(n), locations=np.zeros((n, 2), dtype=int),
                        max_code=max_codes.pop(),
                        sources=[src for s in sessions for src in s.sources], block=1,
                        frame_shape=(1, n))
    return samples, {"clipped": clipped, "saturated": saturated}, log_times, offsets


def _log_basis(basis, n_components: int):
    """The response basis in the log domain of Eq. 7 (default the built-in one), and N
    capped at its size -- as :func:`selfcal.calibrate_response` takes it."""
    from ..response.basis import builtin_basis, load_basis_file

    if basis is None:
        basis = builtin_basis()
    elif isinstance(basis, (str, os.PathLike)):
        basis = load_basis_file(basis)
    if basis.domain != "log":
        basis = basis.to_log_domain()
    return basis, int(min(n_components, basis.n_components))


def fit_shared_response(sessions: Sequence[SessionSamples], *,
                        n_components: int = DEFAULT_N_COMPONENTS,
                        basis: ResponseBasis | None = None, saturation_threshold: float =
                        DEFAULT_SATURATION_THRESHOLD, clip_margin: float = DEFAULT_CLIP_MARGIN,
                        max_rank_gap: int = MAX_RANK_GAP) -> SharedFit:
    """Fit one f⁻¹ per channel to the Eq. 8 rows of several sessions (Lin et al. §5).

    The solve is :func:`selfcal.response.solver.solve_exposure_equations` (Eq. 7-8, the
    §5 rejection of clipped and saturated samples, selfcal's priors and robust loop) on
    the block-diagonal layout described in the module docstring: one curve, each session
    with its own (known, fixed) exposures.

    Parameters
    ----------
    sessions : sequence of SessionSamples
    n_components, basis, saturation_threshold, clip_margin, max_rank_gap
        As for :func:`selfcal.calibrate_response`.

    Returns
    -------
    SharedFit

    Raises
    ------
    CalibrationError
        No sessions, or too few usable sample pairs.
    """
    sessions = list(sessions)
    if not sessions:
        raise CalibrationError("no session to fit a shared response to")
    basis, N = _log_basis(basis, n_components)
    samples, masks, log_times, _ = _pooled_sample_set(sessions)
    result = solve_exposure_equations(
        samples, basis, log_times, refine_exposures=False, masks=masks,
        options=SolverOptions(n_components=N, saturation_threshold=saturation_threshold,
                              clip_margin=clip_margin, max_rank_gap=max_rank_gap))
    inverse = basis.channel_inverses(result.coefficients, N)   # as calibrate_response
    return SharedFit(intensity=basis.intensity.copy(), inverse=inverse,
                     coefficients=result.coefficients, basis_name=basis.name,
                     residual_rms=float(result.residual_rms),
                     sessions=[s.session for s in sessions], rows_used=int(result.rows_used),
                     warnings=list(result.warnings))


def eq8_code_residual(samples: SessionSamples, intensity, inverse, *,
                      max_rank_gap: int = MAX_RANK_GAP) -> float:
    """RMS (8-bit codes) of a session's samples predicted frame to frame through a curve.

    For each pair of frames (a, b) of the session (each frame with its next
    ``max_rank_gap`` by exposure, as the solver pairs them) and each sample valid in both
    (neither clipped nor above β), the code of frame b is predicted from frame a by Eq. 8,
    ``Î_b = f(f⁻¹(I_a) · t_b / t_a)``, where that stays below white; the residual
    ``Î_b − I_b`` is taken in 8-bit codes, over the three channels.  Ours: Eq. 8's
    residual put in code units, where the noise of JPEG block means is about even
    (log-domain residuals blow up in the shadows).

    Returns
    -------
    float
        NaN when no pair has a valid sample.
    """
    intensity = np.asarray(intensity, dtype=float)
    inverse = np.asarray(inverse, dtype=float)
    valid = ~(samples.clipped | samples.saturated)
    order = np.argsort(samples.log_times, kind="stable")
    sq, count = 0.0, 0
    for a, b in frame_pairs(order, max_rank_gap):
        both = valid[a] & valid[b]
        if not both.any():
            continue
        ratio = math.exp(samples.log_times[b] - samples.log_times[a])
        for c in range(3):
            lin = np.interp(samples.values[a, both, c], intensity, inverse[:, c]) * ratio
            keep = lin < inverse[-1, c]
            if not keep.any():
                continue
            pred = np.interp(lin[keep], inverse[:, c], intensity)
            r = 255.0 * (pred - samples.values[b, both, c][keep])
            sq += float(np.sum(r * r))
            count += int(keep.sum())
    return math.sqrt(sq / count) if count else float("nan")


def disagrees(shared: float, own: float) -> bool:
    """Whether a session's code residual under the shared curve says it is another curve.

    ``shared > DISAGREEMENT_RATIO · own`` and ``shared > own + DISAGREEMENT_FLOOR``
    (:data:`DISAGREEMENT_RATIO`, :data:`DISAGREEMENT_FLOOR`); a NaN residual never
    disagrees (nothing to compare).
    """
    if shared is None or own is None or not (math.isfinite(shared) and math.isfinite(own)):
        return False
    return shared > DISAGREEMENT_RATIO * own and shared > own + DISAGREEMENT_FLOOR


@dataclass
class PooledCalibration:
    """A camera's shared curve and how each session agrees with it.

    Attributes
    ----------
    fit : SharedFit or None
        None when fewer than two sessions agree (no shared curve).
    agreement : dict
        Session → ``{"shared": rms, "own": rms}`` (8-bit codes, :func:`eq8_code_residual`),
        for every session given.
    flagged : list of str
        Sessions that disagree with the shared curve (fitted alone).
    pooled : list of str
        Sessions in the final fit.
    stuck_codes : dict or None
        Per channel floor and ceiling: the median over the pooled sessions.
    """

    fit: SharedFit | None
    agreement: dict
    flagged: list
    pooled: list
    stuck_codes: dict | None


def pooled_calibration(sessions: Sequence[SessionSamples], *,
                       rounds: int = 2) -> PooledCalibration:
    """Fit a shared curve, flag the sessions that disagree, fit again without them.

    Each round fits :func:`fit_shared_response` to the sessions still pooled and measures
    every session's :func:`eq8_code_residual` under it and under its own fit; the
    sessions that :func:`disagrees` says differ leave the pool.  With fewer than two
    sessions left there is no shared curve.  Ours: the paper fits one stack.

    Parameters
    ----------
    sessions : sequence of SessionSamples
        With ``own_intensity`` and ``own_inverse`` set.
    rounds : int
        Rounds of flagging; the pool left after the last is fitted once more.
    """
    sessions = list(sessions)
    pooled = list(sessions)
    flagged: list[str] = []
    agreement: dict = {}
    fit = None
    for _ in range(max(1, int(rounds))):
        if len(pooled) < 2:
            break
        fit = fit_shared_response(pooled)
        agreement = {s.session: session_agreement(s, fit) for s in sessions}
        out = [s for s in pooled if disagrees(**agreement[s.session])]
        if not out:
            break
        flagged += [s.session for s in out]
        pooled = [s for s in pooled if s not in out]
        fit = None
    if fit is None and len(pooled) >= 2:
        # the pool after the last round's flags: fitted once more, no more flags
        fit = fit_shared_response(pooled)
        agreement = {s.session: session_agreement(s, fit) for s in sessions}
    if fit is None:
        agreement = {s.session: {"shared": float("nan"), "own": _own_residual(s)}
                     for s in sessions}
        return PooledCalibration(fit=None, agreement=agreement, flagged=flagged,
                                 pooled=[], stuck_codes=None)
    stuck = {k: np.median([s.stuck_codes[k] for s in pooled], axis=0).tolist()
             for k in ("floor", "ceiling")}
    return PooledCalibration(fit=fit, agreement=agreement, flagged=flagged,
                             pooled=[s.session for s in pooled], stuck_codes=stuck)


def _own_residual(s: SessionSamples) -> float:
    if s.own_inverse is None:
        return float("nan")
    return eq8_code_residual(s, s.own_intensity, s.own_inverse)


def agreement_with(s: SessionSamples, intensity, inverse) -> dict:
    """``{"shared": rms, "own": rms}``: a session's :func:`eq8_code_residual` under a
    shared curve (``intensity``, ``inverse``) and under its own fit."""
    return {"shared": eq8_code_residual(s, intensity, inverse), "own": _own_residual(s)}


def session_agreement(s: SessionSamples, fit: SharedFit) -> dict:
    """:func:`agreement_with` the curve of a :class:`SharedFit`."""
    return agreement_with(s, fit.intensity, fit.inverse)


def shared_model(pooled: PooledCalibration, sessions: Sequence[SessionSamples], *,
                 camera: str = "") -> ResponseModel:
    """The shared curve as a :class:`selfcal.ResponseModel` (a model file like any other).

    Its sources are the pooled sessions' frames with their (fixed) exposure times, so
    that ``selfcal merge --model`` uses them unchanged; ``diagnostics["pooled"]`` names the
    sessions and their agreement, ``diagnostics["stuck_codes"]`` holds the median floors
    and ceilings of the pooled sessions (a property of the camera, which the merge reads).
    """
    fit = pooled.fit
    if fit is None:
        raise CalibrationError(f"camera {camera}: no shared curve (fewer than two sessions "
                               "agree)")
    used = [s for s in sessions if s.session in set(pooled.pooled)]
    sources = [src for s in used for src in s.sources]
    times = [float(math.exp(t)) for s in used for t in s.log_times]
    diagnostics = {
        "verdict": "ok",
        "verdict_reasons": [],
        "warnings": list(fit.warnings),
        "frames_used": sources,
        "residual_rms_log": fit.residual_rms,
        "stuck_codes": pooled.stuck_codes,
        "pooled": {"camera": camera, "sessions": list(pooled.pooled),
                   "flagged": list(pooled.flagged), "rows_used": fit.rows_used,
                   "agreement_codes": pooled.agreement},
    }
    return ResponseModel(intensity=fit.intensity, inverse=fit.inverse,
                         coefficients=fit.coefficients, basis_name=fit.basis_name,
                         exposures=np.asarray(times), exposure_times=times, sources=sources,
                         max_code=used[0].max_code, diagnostics=diagnostics,
                         exposure_record=BracketExposures(tuple(
                             FrameExposure(source=src, given=t, origin="exif", used=t)
                             for src, t in zip(sources, times)), rule="held", origin="exif"))
