"""The top of the curve: samples at white that JPEG moved below the clip limit (selfcal's).

[Lin2011] §5 drops samples clipped in either frame of a pair, and a sample counts as
clipped where a code of its block touches the maximum (within the clip margin,
:func:`selfcal.stack.samples.frame_masks`).  A JPEG encoder does not keep a clipped area
at the maximum code: the quantised DCT of a block holding white and its surroundings
rings, and pixels of a white area read a few codes below the limit (250 … 252).  Such a
sample passes as valid in the frame where its scene point is already beyond white, and
its pair rows of Eq. 8 put an irradiance above white at a code below it -- so the codes
≈ 245 … 254 are pulled down, and with them, through f⁻¹(1) = 1, the scale of the whole
curve.  On the simulator's truth (tuning split, ``exact/saturated``, DoRF curve 60) 761
of the 1,158 pair rows whose brighter code was ≥ 245 were off by more than 0.03 in log,
and 84 % of those had a true brighter code at or above white.  The measured ringing
reach (:mod:`.white_end`) catches damage *next to* clipped blocks, not a white area whose
own codes were moved below the limit.

The fit itself shows them: through the first fit's g (Eq. 7) and exposures, a sample of
frame a predicts its code in a brighter frame b, ``g(I_b) = g(I_a) + K_b − K_a`` (Eq. 8);
where that prediction reaches white in some channel, the sample read in b is a clipped
one (:func:`mask_hidden_white`).  It then counts as clipped in b and in every brighter
frame, and the curves are solved again (:func:`white_end_masks` runs this beside the
ringing reach, on the same fit).  The test and its threshold
(:data:`HIDDEN_WHITE_CODES`) are ours.
"""

from __future__ import annotations

import numpy as np

#: A sample counts as clipped in frame b when the fit predicts its code there (from some
#: darker partner frame, in some channel) at or above the maximum code less this many
#: codes.  Chosen on the tuning split (docs/decisions.md, "Samples the fit predicts at
#: white count as clipped: on, half a code").
HIDDEN_WHITE_CODES = 0.5
#: More than this share of the valid (frame, sample) entries predicted at white says the
#: fit is wrong, not the samples (reversed or mislabelled times): nothing is masked, and
#: the verdict judges the fit.  The tuning stacks of the response matrix reach 1.1 %.
MAX_HIDDEN_SHARE = 0.05


def hidden_white_mask(samples, valid: np.ndarray, result, grid: np.ndarray,
                      inverse: np.ndarray, codes: float = HIDDEN_WHITE_CODES) -> np.ndarray:
    """(F, n) True where a valid sample is predicted at white by a darker partner frame.

    Parameters
    ----------
    samples : SampleSet
        Block means ``values`` (F, n, 3), normalised to [0, 1], and ``max_code``.
    valid : ndarray of bool, shape (F, n)
        Samples neither clipped nor saturated (the solve's).
    result : SolveResult
        The fit: ``log_exposures`` K and the frame pairs ``pair_frames`` (a, b), b
        brighter.
    grid, inverse : ndarray
        f⁻¹ of the fit on the basis grid, (K,) and (K, 3).
    codes : float
        The prediction counts as white at or above ``max_code − codes``.

    Returns
    -------
    ndarray of bool, shape (F, n)
        Also set in every frame at least as bright as one where it is set (by K; the
        repeated shots of one exposure alike), as
        :func:`selfcal.stack.samples.frame_masks` propagates clipping; only where
        ``valid``.
    """
    g = np.log(np.maximum(np.asarray(inverse, np.float64), 1e-12)).T      # (3, K)
    K = np.asarray(result.log_exposures, np.float64)
    top = 1.0 - codes / samples.max_code
    g_top = np.array([np.interp(top, grid, g[c]) for c in range(3)])
    white = np.zeros(valid.shape, bool)
    for a, b in result.pair_frames:
        idx = np.flatnonzero(valid[a] & valid[b])
        if not idx.size:
            continue
        for c in range(3):
            predicted = np.interp(samples.values[a, idx, c], grid, g[c]) + K[b] - K[a]
            white[b, idx[predicted >= g_top[c]]] = True
    # every frame at least as bright (repeated shots alike, whatever their input order)
    white = np.array([white[K <= K[f]].any(axis=0) for f in range(K.size)])
    return white & valid


def white_end_masks(samples, masks: dict, basis, result, options) -> tuple[int, int]:
    """The white end of a first fit: the ringing reach and the hidden white samples.

    With ``options.measure_ringing``, :func:`.white_end.mask_near_clip` (the reach of
    JPEG damage next to clipped blocks); with ``options.hidden_white``, the samples
    :func:`hidden_white_mask` finds on the same fit (f⁻¹ of Eq. 7 from its coefficients,
    made non-decreasing; the ringing mask applied) count as clipped, unless they are more
    than :data:`MAX_HIDDEN_SHARE` of the valid entries.  ``masks``
    (``"clipped"``, ``"saturated"``) are replaced in the dict, as ``mask_near_clip`` does.

    Returns
    -------
    reach : int
        Blocks (0: none, or the ringing reach off).
    hidden : int
        (frame, sample) entries newly counted as clipped.  The caller solves again when
        either is non-zero.
    """
    from .white_end import mask_near_clip

    grid = basis.intensity
    inverse = basis.channel_inverses(result.coefficients, options.solver.n_components)
    reach = (mask_near_clip(samples, masks, result, grid, inverse)
             if options.measure_ringing else 0)
    hidden = 0
    if options.hidden_white:
        valid = ~(masks["clipped"] | masks["saturated"])
        white = hidden_white_mask(samples, valid, result, grid, inverse)
        hidden = int(white.sum())
        if hidden > MAX_HIDDEN_SHARE * valid.sum():
            hidden = 0
        if hidden:
            masks["clipped"] = masks["clipped"] | white
            masks["saturated"] = masks["saturated"] & ~masks["clipped"]
    return reach, hidden
