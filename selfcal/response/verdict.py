"""The verdict of a response calibration: can the fit be trusted, from its own evidence.

:func:`selfcal.calibrate_response` fits Eq. 8 of Lin, Kim, Süsstrunk & Brown (ICCV 2011,
§5) to whatever frames it is given, and wrong data still give a curve: times in the wrong
order, a handheld stack without alignment, two scenes fed together, a bracket or a scene
too narrow to determine the curve.  The paper has no test for any of these; this module is
ours.  It weighs what the fit itself shows (:func:`judge_calibration`):

* **residual against noise** (:func:`residual_evidence`): the Eq. 8 residuals of the
  solve's frame pairs over their inliers, each over what a correct fit leaves at its
  codes -- one code of noise carried through the slope of g = log f⁻¹, and a 3 % relative
  model error -- and over the frames' own scatter where that is larger;
* **times** (:func:`time_order`, ``contradicting_times``): frames darker at a longer
  given time (model-free: f is increasing), and given times the pixels contradict;
* **one scene** (:func:`scene_pairs`): of two frames of one scene, either frame's samples
  are a monotone function of the other's whatever the curve and the exposures; pairs
  whose samples are not show different scenes;
* **alignment** (:func:`alignment_residuals`): the shift between neighbouring exposures
  (phase correlation of equalised thumbnails, whole frame and quarters), and how much
  compensating it lowers their residuals at the samples -- what aligned frames would give;
  motion that does not change the residuals (flat samples) is not held against the fit;
* **dynamic range** (:func:`coverage`): the exposure ratio over the stack, the usable
  frames and sample locations, the share of the code range and the stops of f⁻¹ the
  valid samples span (scene and exposures together);
* δ of Eq. 12 over the linear values it compares (``relative_delta``), evidence only: δ is
  in linear units and grows with the exposure ratio, so no threshold rests on it.

Levels: ``"ok"``; ``"doubtful"`` (usable with care; each reason is also a warning);
``"unusable"`` (the library still returns the model; the command line refuses it without
``--force``).

The thresholds (module constants) are ours, chosen on the tuning split and reported on
the held-out split (``python3 -m bench.verdict --split tuning``; docs/decisions.md, "The
verdict's thresholds").
"""

from __future__ import annotations

import math

import numpy as np

from ..exposure.times import CONTRADICTED_UNUSABLE_SHARE
from .stuck_codes import STUCK_CODES, STUCK_RATIO
from ..io.images import import_cv2
# the code noise (normalised) of a block mean the residual test assumes: one 8-bit code,
# the solver's noise weights' (defined there, once)
from .solver import CODE_NOISE
#: Relative error of each frame's linearised value a correct fit still leaves (model and
#: exposure error), as the merge's default noise model (``selfcal.hdr.weights``: 3 %).
RELATIVE_ERROR = 0.03
#: Misfit ratio (:func:`residual_evidence`; 1 = what noise explains) above which the fit
#: is doubtful, and unusable.
RESIDUAL_DOUBTFUL = 4.0
RESIDUAL_UNUSABLE = 10.0
#: Disagreement of two frames (:func:`scene_pairs`: robust scatter of one frame's samples
#: about the best monotone function of the other's, over their spread) above which the
#: two frames show different scenes.
SCENE_DISAGREEMENT = 0.7
#: Shared valid samples a frame pair needs before it is scored.
SCENE_MIN_SAMPLES = 30
#: Share of the scored frame pairs showing different scenes at or above which the
#: calibration is unusable; below it, a frame disagreeing with most of its partners makes
#: it doubtful (a stray frame).
SCENE_UNUSABLE_SHARE = 0.25
#: Motion between neighbouring frames, in sample blocks, above which a frame counts as
#: moved (handheld, bumped tripod).
MOTION_BLOCKS = 1.0
#: Drop of the neighbouring frames' residual (robust scale, in units of the noise of
#: :func:`residual_evidence`) when their measured shift is compensated, above which the
#: shift matters: the pair is misaligned.
ALIGNMENT_GAIN = 1.0
#: Phase-correlation peak below which a motion estimate carries no information.
MOTION_MIN_RESPONSE = 0.2
#: A time contradicted by at least this factor (the calibration's own reporting factor,
#: :data:`selfcal.exposure.times.CONTRADICTION_FACTOR`) makes the calibration doubtful;
#: at or above :data:`selfcal.exposure.times.CONTRADICTED_UNUSABLE_SHARE` of the known
#: times contradicted, unusable: on the synthetic tuning stacks one time off by 1.25×
#: already doubles to triples the f⁻¹ error.
CONTRADICTION_DOUBTFUL = 1.25
#: Share of the checked frame pairs darker at the longer given time (:func:`time_order`)
#: at or above which the calibration is unusable; any such pair makes it doubtful.
#: Tuning: none on good stacks, every pair with the times reversed.
REVERSED_UNUSABLE_SHARE = 0.5
#: Stops of f⁻¹ the valid samples must span (:func:`coverage`), else doubtful.  Tuning:
#: good stacks at least 7.6, a one-stop scene over two stops of exposure 3.5-3.6 (f⁻¹
#: RMSE 0.02-0.05 against the truth).
STOPS_DOUBTFUL = 5.0
#: Exposure ratio (longest / shortest used) below which the curve is undetermined, and
#: below which it is poorly determined.  Tuning: good stacks at least 25, two frames one
#: stop apart 2.0-2.1 (f⁻¹ moved by 0.04-0.11 from the whole stack's).
EXPOSURE_RATIO_UNUSABLE = 1.5
EXPOSURE_RATIO_DOUBTFUL = 3.0
#: Share of 32 code bins the valid samples of the worst channel must cover.
CODE_COVERAGE_DOUBTFUL = 0.5
#: Sample locations valid in some frame below which the calibration is unusable.
MIN_VALID_LOCATIONS = 100

LEVELS = ("ok", "doubtful", "unusable")


# --------------------------------------------------------------------------------------
# evidence
# --------------------------------------------------------------------------------------

def residual_evidence(values, valid, intensity, inverse, log_exposures, pairs, *,
                      stuck_codes: dict | None = None, code_noise: float = CODE_NOISE,
                      relative: float = RELATIVE_ERROR) -> dict:
    """The Eq. 8 residuals of the fitted model against what noise explains.

    For each frame pair (a, b) and sample valid in both, per channel, the residual of
    Eq. 8, ``r = g(I_b) − g(I_a) − (K_b − K_a)`` with ``g = log f⁻¹`` from the fitted
    table, is divided by its expected standard deviation under a correct fit,
    ``σ² = Σ_{I ∈ {I_a, I_b}} (g′(I) · code_noise)² + 2 · relative²`` (the code noise
    carried through the slope of g, first order, and a relative model error): ``z = r/σ``.
    Left out as the solve leaves them out: samples that do not move with the exposure
    (by less than :data:`selfcal.response.stuck_codes.STUCK_CODES` between frames
    :data:`selfcal.response.stuck_codes.STUCK_RATIO` apart), and codes at or below a channel's black
    floor or at or above its stuck ceiling (``stuck_codes``, from
    :func:`selfcal.response.stuck_codes.stuck_code_levels`): they are bounds, not measurements.

    The frames' own noise may exceed that model (film grain, high ISO, single-pixel
    samples of small frames): it is estimated from the spread of z between samples of
    neighbouring codes -- within each pair and channel, z sorted by the code in the darker
    frame, ``1.4826 · median |Δz| / √2`` -- which a smooth misfit of the curve does not
    raise.  The misfit ratio is the robust scale of z (1.4826 × median |z|) over
    ``max(1, that local scatter)``: about 1 for a correct fit, large when the frames do not
    follow one response at the fitted exposures.

    Returns
    -------
    dict
        ``residual_noise_ratio`` (robust scale of z), ``residual_local_scatter``,
        ``residual_misfit_ratio`` (NaN without any valid pair sample).
    """
    grid = np.asarray(intensity, dtype=float)
    g = np.log(np.maximum(np.asarray(inverse, dtype=float), 1e-6))
    dg = np.gradient(g, grid, axis=0)
    K = np.asarray(log_exposures, dtype=float)
    floor = np.asarray((stuck_codes or {}).get("floor", [0.0] * 3), dtype=float)
    ceiling = np.asarray((stuck_codes or {}).get("ceiling", [1.0] * 3), dtype=float)
    # levels past mid-grey are no floor or ceiling (exposures in the wrong order make the
    # whole range look stuck)
    floor = np.where(floor < 0.5, floor, 0.0)
    ceiling = np.where(ceiling > 0.5, ceiling, 1.0)
    measured = ((values > floor) & (values < ceiling)).all(axis=2) & valid
    abs_z, abs_dz = [], []
    for a, b in pairs:
        both = measured[a] & measured[b]
        if abs(K[b] - K[a]) >= math.log(STUCK_RATIO):
            both &= (np.abs(values[b] - values[a]) >= STUCK_CODES / 255.0).all(axis=1)
        if int(both.sum()) < 2:
            continue
        ia, ib = values[a][both], values[b][both]
        for c in range(3):
            ga, gb = np.interp(ia[:, c], grid, g[:, c]), np.interp(ib[:, c], grid, g[:, c])
            sa = np.interp(ia[:, c], grid, dg[:, c]) * code_noise
            sb = np.interp(ib[:, c], grid, dg[:, c]) * code_noise
            z = (gb - ga - (K[b] - K[a])) / np.sqrt(sa ** 2 + sb ** 2 + 2 * relative ** 2)
            abs_z.append(np.abs(z))
            abs_dz.append(np.abs(np.diff(z[np.argsort(ia[:, c], kind="stable")])))
    if not abs_z:
        return {"residual_noise_ratio": math.nan, "residual_local_scatter": math.nan,
                "residual_misfit_ratio": math.nan}
    scale = float(1.4826 * np.median(np.concatenate(abs_z)))
    local = float(1.4826 * np.median(np.concatenate(abs_dz)) / math.sqrt(2))
    return {"residual_noise_ratio": scale, "residual_local_scatter": local,
            "residual_misfit_ratio": scale / max(1.0, local)}


def _rank_correlation(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman's rank correlation (``scipy.stats.spearmanr``); NaN for constant input."""
    import warnings

    from scipy.stats import spearmanr

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")          # ConstantInputWarning: NaN says it
        return float(spearmanr(x, y).statistic)


def _monotone_residual(x: np.ndarray, y: np.ndarray) -> float:
    """Robust scale (1.4826 × median |r|) of y about its best non-decreasing fit in x."""
    from scipy.optimize import isotonic_regression

    order = np.argsort(x, kind="stable")
    fit = isotonic_regression(y[order]).x
    return float(1.4826 * np.median(np.abs(y[order] - fit)))


def scene_pairs(values, valid, *, max_rank_gap: int = 3,
                min_samples: int = SCENE_MIN_SAMPLES) -> dict:
    """How well each frame pair's samples agree with one scene seen at two exposures.

    Two frames of one scene order their unclipped samples alike whatever the response
    and the exposures (f is monotone): per channel, either frame's codes are a
    non-decreasing function of the other's, up to noise.  Frames are paired with the next
    ``max_rank_gap`` frames in brightness order; for each pair with at least
    ``min_samples`` samples valid in both and each channel, the robust scale of one
    frame's codes about their best non-decreasing fit in the other's (isotonic
    regression) over the robust spread of those codes (at least 2 codes), the smaller of
    the two ways round (the darker frame's noise, read in the brighter frame, is
    multiplied by the exposure ratio): about 0 for one scene, near 1 for two.  The pair's
    disagreement is the median over channels; Spearman's rank correlation of the grey
    levels is kept as evidence.

    Returns
    -------
    dict
        ``(a, b) -> {"disagreement": ..., "correlation": ...}``, ``a`` the darker frame.
    """
    grey = values.mean(axis=2)
    order = np.argsort(grey.mean(axis=1), kind="stable")
    out = {}

    def relative(x, y):
        spread = max(1.4826 * float(np.median(np.abs(y - np.median(y)))), 2.0 / 255.0)
        return _monotone_residual(x, y) / spread

    for i, a in enumerate(order):
        for b in order[i + 1: i + 1 + max_rank_gap]:
            both = valid[a] & valid[b]
            if int(both.sum()) < min_samples:
                continue
            va, vb = values[a, both], values[b, both]
            score = float(np.median([min(relative(va[:, c], vb[:, c]),
                                         relative(vb[:, c], va[:, c])) for c in range(3)]))
            out[(int(a), int(b))] = {
                "disagreement": score,
                "correlation": _rank_correlation(grey[a, both], grey[b, both])}
    return out


def _phase_shift(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """Translation (dx, dy) of ``b`` against ``a`` by phase correlation, and its peak.

    ``b`` at ``x + (dx, dy)`` shows what ``a`` shows at ``x``.  Both are equalised images.
    """
    cv2 = import_cv2()
    h, w = a.shape
    if h < 8 or w < 8:
        return 0.0, 0.0, 0.0
    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(a, b, window)
    return float(dx), float(dy), float(response)


def _local_shifts(a: np.ndarray, b: np.ndarray, min_response: float):
    """The shift of ``b`` against ``a`` over the whole image and over each quarter.

    Returns ``(whole, quarters)``: ``whole`` is (dx, dy), or None when the phase
    correlation found no peak of at least ``min_response``; ``quarters`` a 2×2 nested
    list of the quarters' shifts (a rotation moves them apart), each None when its peak
    is weak or it strays from the whole frame's by more than a quarter of it (at least
    2 pixels): periodic texture gives false peaks.
    """
    h, w = a.shape
    dx, dy, r = _phase_shift(a, b)
    quarters: list[list[tuple[float, float] | None]] = [[None, None], [None, None]]
    if r < min_response:
        return None, quarters
    tolerance = max(2.0, 0.25 * math.hypot(dx, dy))
    for i, y0 in enumerate((0, h - h // 2)):
        for j, x0 in enumerate((0, w - w // 2)):
            part = (slice(y0, y0 + h // 2), slice(x0, x0 + w // 2))
            qx, qy, qr = _phase_shift(np.ascontiguousarray(a[part]),
                                      np.ascontiguousarray(b[part]))
            if qr >= min_response and math.hypot(qx - dx, qy - dy) <= tolerance:
                quarters[i][j] = (qx, qy)
    return (dx, dy), quarters


def _grey_log_curve(intensity, inverse):
    """g = log f⁻¹ of the grey level (mean of the channels' f⁻¹) and its slope."""
    grid = np.asarray(intensity, dtype=float)
    g = np.log(np.maximum(np.asarray(inverse, dtype=float).mean(axis=1), 1e-6))
    return grid, g, np.gradient(g, grid)


def alignment_residuals(thumb_a, thumb_b, points, intensity, inverse, log_ratio, *,
                        code_noise: float = CODE_NOISE, relative: float = RELATIVE_ERROR,
                        min_response: float = MOTION_MIN_RESPONSE) -> dict:
    """How far two frames moved, and the Eq. 8 residuals before and after compensating it.

    The shift of the second grey thumbnail against the first is measured by phase
    correlation of the histogram-equalised thumbnails (a monotone map: two exposures of
    one scene look alike) over the whole frame and each quarter.  At the sample
    ``points`` (thumbnail coordinates ``(x, y)``) the grey Eq. 8 residual
    ``g(B) − g(A) − log_ratio`` (g = log of the channels' mean f⁻¹, over its noise as in
    :func:`residual_evidence`) is taken with the second frame read at the points
    (``before``) and at the points moved by the shift of their quarter, or of the whole
    frame (``after``, bilinear): what the aligned frames would give.  Ours; the merge's
    misalignment test (:mod:`selfcal.hdr.deghost`) asks the same of whole frames.

    Returns
    -------
    dict
        ``motion`` (largest shift found, thumbnail pixels), ``before`` and ``after``
        (robust scale of the noise-normalised residuals; NaN without motion or points).
    """
    cv2 = import_cv2()
    fa = cv2.equalizeHist(thumb_a).astype(np.float32)
    fb = cv2.equalizeHist(thumb_b).astype(np.float32)
    whole, quarters = _local_shifts(fa, fb, min_response)
    found = [whole] + [q for row in quarters for q in row]
    found = [v for v in found if v is not None]
    motion = max((math.hypot(*v) for v in found), default=0.0)
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 2)
    if motion == 0.0 or len(pts) < 10:
        return {"motion": motion, "before": math.nan, "after": math.nan}
    h, w = fa.shape
    shift = np.zeros_like(pts)
    qi = (pts[:, 1] >= h / 2).astype(int)
    qj = (pts[:, 0] >= w / 2).astype(int)
    for i in (0, 1):
        for j in (0, 1):
            shift[(qi == i) & (qj == j)] = quarters[i][j] or whole or (0.0, 0.0)
    grid, g, dg = _grey_log_curve(intensity, inverse)
    ca, cb = thumb_a.astype(np.float32) / 255.0, thumb_b.astype(np.float32) / 255.0

    def read(img, xy):
        m = xy.reshape(-1, 1, 2)
        return cv2.remap(img, m[..., 0], m[..., 1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT).ravel().astype(float)

    ia = read(ca, pts)

    def scale(ib):
        sigma = np.sqrt((np.interp(ia, grid, dg) * code_noise) ** 2
                        + (np.interp(ib, grid, dg) * code_noise) ** 2 + 2 * relative ** 2)
        z = (np.interp(ib, grid, g) - np.interp(ia, grid, g) - log_ratio) / sigma
        return float(1.4826 * np.median(np.abs(z)))

    return {"motion": motion, "before": scale(read(cb, pts)),
            "after": scale(read(cb, pts + shift))}


def coverage(values, valid, exposures, intensity, inverse) -> dict:
    """What the data span: exposure ratio, code coverage, stops of f⁻¹, valid locations.

    Code coverage is, per channel, the share of 32 equal bins over the code range that
    hold a valid sample; the stops covered are, per channel, ``log2`` of the ratio of
    the 99th to the 1st percentile of f⁻¹ over the valid samples of every frame -- the
    part of the curve the data pin down (the scene's range and the exposures' together).
    """
    exposures = np.asarray(exposures, dtype=float)
    ratio = float(np.nanmax(exposures) / np.nanmin(exposures))
    cover, stops = [], []
    for c in range(3):
        v = values[..., c][valid]
        hist = np.histogram(v, bins=32, range=(0, 1))[0] if v.size else np.zeros(32)
        cover.append(float(np.mean(hist > 0)))
        if v.size:
            lin = np.interp(np.percentile(v, [1, 99]), intensity, inverse[:, c])
            stops.append(float(np.log2(max(lin[1], 1e-9) / max(lin[0], 1e-9))))
        else:
            stops.append(0.0)
    return {"exposure_ratio": ratio, "code_coverage": cover, "stops_covered": stops,
            "valid_locations": int(valid.any(axis=0).sum())}


def time_order(values, valid, log_times, *, min_ratio: float = 1.5,
               max_rank_gap: int = 3, min_samples: int = SCENE_MIN_SAMPLES) -> dict:
    """Do the pixels brighten as the given times lengthen?  (Model-free; ours.)

    f is increasing, so of two frames of one scene whose given times differ by at least
    ``min_ratio``, the longer one's unclipped samples are brighter: the median over the
    samples valid in both of the channels' mean code difference must be positive.  Frames
    with a given time are paired with the next ``max_rank_gap`` in given-time order.

    Returns
    -------
    dict
        ``checked`` pairs, ``reversed`` pairs (darker at the longer time) and the frames of
        the reversed pairs.
    """
    known = np.flatnonzero(np.isfinite(log_times))
    order = known[np.argsort(log_times[known], kind="stable")]
    checked, bad = 0, 0
    frames: set[int] = set()
    for i, a in enumerate(order):
        for b in order[i + 1: i + 1 + max_rank_gap]:
            if log_times[b] - log_times[a] < math.log(min_ratio):
                continue
            both = valid[a] & valid[b]
            if int(both.sum()) < min_samples:
                continue
            checked += 1
            if np.median((values[b, both] - values[a, both]).mean(axis=1)) < 0:
                bad += 1
                frames.update((int(a), int(b)))
    return {"checked": checked, "reversed": bad, "frames": sorted(frames)}


def relative_delta(values, valid, intensity, inverse, log_exposures, pairs) -> float:
    """δ of Eq. 12 (all channels) over the RMS of the linear values it compares.

    δ is in linear units and grows with the exposure ratio; over the RMS of
    ``f⁻¹(I′)`` it is a relative error (evidence only).
    """
    sq = den = 0.0
    for a, b in pairs:
        both = valid[a] & valid[b]
        if not both.any():
            continue
        k = math.exp(log_exposures[b] - log_exposures[a])
        for c in range(3):
            la = np.interp(values[a][both, c], intensity, inverse[:, c])
            lb = np.interp(values[b][both, c], intensity, inverse[:, c])
            sq += float(np.sum((k * la - lb) ** 2))
            den += float(np.sum(lb ** 2))
    return math.sqrt(sq / den) if den > 0 else math.nan


# --------------------------------------------------------------------------------------
# the verdict
# --------------------------------------------------------------------------------------

def _names(sources, indices, limit: int = 4) -> str:
    import os

    names = [os.path.basename(str(sources[k])) for k in indices]
    return ", ".join(names[:limit]) + (f" and {len(names) - limit} more"
                                       if len(names) > limit else "")


def judge_calibration(samples, valid, intensity, inverse, log_exposures, pairs, *,
                      log_times=None, contradictions=(), refined: bool = False,
                      stuck_codes: dict | None = None) -> tuple[str, list, dict]:
    """The verdict on a fitted response: level, reasons and the evidence they rest on.

    Parameters
    ----------
    samples : SampleSet
        The usable frames' samples (``values``, ``sources``, ``thumbnails``, ``block``).
    valid : ndarray of bool, shape (F, n)
        Samples neither clipped nor above β (the solve's inliers).
    intensity, inverse : ndarray
        The fitted f⁻¹ table.
    log_exposures : ndarray, shape (F,)
        The fitted log exposures.
    pairs : sequence of (int, int)
        The solve's frame pairs.
    log_times : ndarray, shape (F,), optional
        Log of the given times (NaN where unknown).
    contradictions : sequence of dict
        ``contradicting_times`` of the calibration (``frame``, ``given``, ``estimated``).
    refined : bool
        The solve refined the given times (:class:`selfcal.exposure.ExposureRule`): ``contradictions`` are the
        times the pixels corrected, evidence only (correcting them is what refining is
        for; times in the wrong order are still found by :func:`time_order`).
    stuck_codes : dict, optional
        Black floors and stuck ceilings per channel
        (:func:`selfcal.response.stuck_codes.stuck_code_levels`), left out of the residual test.

    Returns
    -------
    verdict : {"ok", "doubtful", "unusable"}
    reasons : list of str
        One sentence each; empty when ok.
    evidence : dict
        The numbers the verdict rests on.
    """
    values = samples.values
    F = values.shape[0]
    log_times = (np.full(F, np.nan) if log_times is None
                 else np.asarray(log_times, dtype=float))
    ev: dict = {}
    found = _range_findings(values, valid, intensity, inverse, log_exposures, ev)
    ev.update(residual_evidence(values, valid, intensity, inverse, log_exposures, pairs,
                                stuck_codes=stuck_codes))
    ev["relative_delta"] = relative_delta(values, valid, intensity, inverse,
                                          log_exposures, pairs)
    misfit = ev["residual_misfit_ratio"]
    if misfit > RESIDUAL_UNUSABLE:
        found.append(("unusable", f"the fit leaves residuals {misfit:.1f}× what the "
                      "frames' noise explains: they do not follow one response at these "
                      "exposures"))
    elif misfit > RESIDUAL_DOUBTFUL:
        found.append(("doubtful", f"the fit leaves residuals {misfit:.1f}× what the "
                      "frames' noise explains"))
    found += _time_findings(values, valid, log_times, samples.sources, contradictions,
                            refined, ev)
    found += _scene_findings(values, valid, samples.sources, ev)
    found += _motion_findings(samples, valid, intensity, inverse, log_exposures, ev)
    # the gravest first (a stable sort keeps the order of the tests within a level)
    found.sort(key=lambda f: -LEVELS.index(f[0]))
    level = found[0][0] if found else "ok"
    return level, [r for _, r in found], ev


def _range_findings(values, valid, intensity, inverse, log_exposures, ev: dict) -> list:
    """Exposure ratio, usable frames, valid locations, code range and stops covered."""
    F = values.shape[0]
    cov = coverage(values, valid, np.exp(log_exposures), intensity, inverse)
    ev.update(cov)
    found = []
    ratio = cov["exposure_ratio"]
    if ratio < EXPOSURE_RATIO_UNUSABLE:
        found.append(("unusable", f"the exposures span only {ratio:.2f}× (under "
                      f"{EXPOSURE_RATIO_UNUSABLE:g}×): too little exposure change to "
                      "determine the curve"))
    elif ratio < EXPOSURE_RATIO_DOUBTFUL:
        found.append(("doubtful", f"the exposures span only {ratio:.2f}× "
                      f"({math.log2(ratio):.1f} stops): the curve is poorly determined"))
    if F < 3:
        found.append(("doubtful", f"only {F} usable exposures: nothing to cross-check "
                      "the fit against"))
    if cov["valid_locations"] < MIN_VALID_LOCATIONS:
        found.append(("unusable", f"only {cov['valid_locations']} valid sample locations"))
    worst = min(cov["code_coverage"])
    stops = min(cov["stops_covered"])
    if worst < CODE_COVERAGE_DOUBTFUL:
        found.append(("doubtful", f"the valid samples cover only {100 * worst:.0f}% of "
                      "the code range: the rest of the curve is extrapolated"))
    elif stops < STOPS_DOUBTFUL:
        found.append(("doubtful", f"the valid samples span only {stops:.1f} stops of the "
                      "curve (scene and exposures together): the rest is extrapolated"))
    return found


def _time_findings(values, valid, log_times, sources, contradictions, refined: bool,
                   ev: dict) -> list:
    """Times in the wrong order (pixels darker at longer times), contradicted times."""
    import os

    known = int(np.isfinite(log_times).sum())
    order = time_order(values, valid, log_times)
    ev["time_pairs_checked"] = order["checked"]
    ev["time_pairs_reversed"] = order["reversed"]
    ratios = [max(c["estimated"] / c["given"], c["given"] / c["estimated"])
              for c in contradictions]
    ev["contradicted_times"] = len(contradictions)
    ev["contradicted_share"] = len(contradictions) / known if known else 0.0
    ev["largest_contradiction"] = max(ratios, default=1.0)
    found = []
    if order["reversed"]:
        share = order["reversed"] / order["checked"]
        found.append(("unusable" if share >= REVERSED_UNUSABLE_SHARE else "doubtful",
                      f"{order['reversed']} of {order['checked']} frame pairs are darker at "
                      f"the longer given time ({_names(sources, order['frames'])}): the "
                      "times are in the wrong order or belong to other frames"))
    if refined:
        return found          # what refining corrected is evidence only
    if known >= 2 and len(contradictions) >= 2 and \
            len(contradictions) / known >= CONTRADICTED_UNUSABLE_SHARE:
        found.append(("unusable", f"{len(contradictions)} of {known} given exposure times "
                      "contradict the pixels: the times are wrong or in the wrong order"))
    else:
        big = [c for c, r in zip(contradictions, ratios) if r >= CONTRADICTION_DOUBTFUL]
        if big:
            names = ", ".join(os.path.basename(str(c["frame"])) for c in big[:4])
            found.append(("doubtful", f"{len(big)} given exposure time(s) contradict the "
                          f"pixels by {CONTRADICTION_DOUBTFUL:g}× or more ({names}), and the "
                          "fit held them: leave them to the pixels (without --hold-times, "
                          "the default)"))
    return found


def _scene_findings(values, valid, sources, ev: dict) -> list:
    """Frame pairs whose samples show two scenes; frames that disagree with most partners."""
    pairs = scene_pairs(values, valid)
    bad = [p for p, v in pairs.items() if v["disagreement"] > SCENE_DISAGREEMENT]
    ev["scene_pairs_checked"] = len(pairs)
    ev["scene_pairs_disagreeing"] = len(bad)
    ev["scene_disagreement"] = max((v["disagreement"] for v in pairs.values()),
                                   default=math.nan)
    if not bad:
        return []
    scored: dict[int, int] = {}
    against: dict[int, int] = {}
    for a, b in pairs:
        for k in (a, b):
            scored[k] = scored.get(k, 0) + 1
    for a, b in bad:
        for k in (a, b):
            against[k] = against.get(k, 0) + 1
    stray = sorted(k for k in against if against[k] > scored[k] / 2)
    share = len(bad) / len(pairs)
    ev["scene_stray_frames"] = len(stray)
    if share >= SCENE_UNUSABLE_SHARE:
        return [("unusable", f"{len(bad)} of {len(pairs)} frame pairs show different "
                 "scenes (the samples of one are no monotone function of the other's): "
                 "two scenes fed together?")]
    if stray:
        return [("doubtful", f"{_names(sources, stray)} disagree(s) with most "
                 "neighbouring exposures (the samples are no monotone function of theirs): "
                 "a frame of another scene, or one that moved?")]
    return []


def _motion_findings(samples, valid, intensity, inverse, log_exposures, ev: dict) -> list:
    thumbs = getattr(samples, "thumbnails", None) or []
    F = samples.values.shape[0]
    ev.update(motion_px=0.0, motion_blocks=0.0, misaligned_pairs=0, alignment_gain=0.0)
    if len(thumbs) != F or F < 2:
        return []
    order = np.argsort(samples.values.mean(axis=(1, 2)), kind="stable")
    to_thumb = samples.block / samples.thumbnail_pixel
    xy = (samples.locations[:, ::-1] + 0.5) * to_thumb - 0.5
    bad = []
    for a, b in zip(order[:-1], order[1:]):
        both = valid[a] & valid[b]
        res = alignment_residuals(thumbs[a], thumbs[b], xy[both], intensity, inverse,
                                  float(log_exposures[b] - log_exposures[a]))
        px = res["motion"] * samples.thumbnail_pixel
        blocks = px / max(samples.block, 1)
        gain = res["before"] - res["after"]
        ev["motion_px"] = max(ev["motion_px"], px)
        ev["motion_blocks"] = max(ev["motion_blocks"], blocks)
        if blocks > MOTION_BLOCKS and np.isfinite(gain):
            ev["alignment_gain"] = max(ev["alignment_gain"], gain)
            if gain > ALIGNMENT_GAIN:
                bad.append((a, b, px, gain))
    ev["misaligned_pairs"] = len(bad)
    if not bad:
        return []
    px = max(v[2] for v in bad)
    gain = max(v[3] for v in bad)
    return [("doubtful", f"{len(bad)} of {F - 1} pairs of neighbouring exposures are "
             f"misaligned (shifts up to {px:.1f} px; compensating them lowers the samples' "
             f"residual by up to {gain:.1f}× the noise): a handheld stack? calibrate with "
             "alignment "
             "(align='mtb' or 'homography', --align)")]


def verdict_of(diagnostics) -> tuple[str | None, list[str]]:
    """A model's verdict level and reasons, from ``diagnostics["verdict"]`` and
    ``diagnostics["verdict_reasons"]``.

    Levels are ``ok``, ``doubtful`` and ``unusable``; any other verdict string (an older
    model's ``"poorly determined: a; b"``) is ``doubtful``, its reasons the text after
    the colon.  ``(None, [])`` when there is no verdict (RAW-path models).
    """
    raw = (diagnostics or {}).get("verdict")
    reasons = [str(r) for r in (diagnostics or {}).get("verdict_reasons") or []]
    if raw is None:
        return None, reasons
    text = str(raw).strip()
    if text in LEVELS:
        return text, reasons
    if not reasons:
        detail = text.split(":", 1)[1] if ":" in text else text
        reasons = [r.strip() for r in detail.split(";") if r.strip()] or [text]
    return "doubtful", reasons
