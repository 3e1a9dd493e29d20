"""The codes that do not move with exposure: a stack's black floor and stuck ceiling per
channel, the calibration's stuck-sample test ([Lin2011] §5's clipping test, widened by
selfcal) as code levels the merge and the verdict use.  Ours, not a paper's.

References
----------
[Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

import math

import numpy as np

from ..stack.frames import DEFAULT_CLIP_MARGIN

__all__ = ["stuck_code_levels", "STUCK_RATIO", "STUCK_CODES", "STUCK_FRACTION"]


#: Two frames whose exposures differ by at least this factor, and a code that moves by less
#: than ``STUCK_CODES`` (8-bit scale) between them, does not respond to the exposure: the
#: calibration's stuck-sample test (``selfcal.response.equations._build_pairs``).
STUCK_RATIO = 1.5
STUCK_CODES = 1.0
#: ... and, for the black floor, by less than this fraction of the code itself: the toe of a
#: curve without a floor (γ ≈ 2.2: code z moves about 0.2 z for 1.5x the exposure) is not
#: a floor, however few codes it moves by (ours).
STUCK_FRACTION = 0.1


def stuck_code_levels(values, log_exposures, *, clip_margin: float = DEFAULT_CLIP_MARGIN,
                      min_count: int = 10) -> dict:
    """Per channel, the black floor and the stuck ceiling of a stack's codes.

    The calibration drops a sample pair whose code does not move between two frames whose
    exposures differ by :data:`STUCK_RATIO` or more (``_build_pairs``, selfcal's addition
    to the clipping test of Lin et al., ICCV 2011, §5).  This turns the same test into code
    levels the merge can use: for each frame ``a`` and the next frame ``b`` at least
    ``STUCK_RATIO`` brighter, the move ``I_b − I_a`` of every sample, pooled over the
    pairs and binned by the code in ``a`` (one bin per 8-bit code); walking up from the
    lowest bin, every bin whose median move is at most :data:`STUCK_CODES` and at most
    :data:`STUCK_FRACTION` of its code is at the **floor**, and the walk stops at the first
    bin that moves; walking down from the highest unclipped bin, the bins that move less
    than :data:`STUCK_CODES` are at a **ceiling**.  A black floor is the code a scanned film or a camera
    with a black pedestal writes for no light (memorial's short frames sit at codes
    12-18); codes at or below it are bounds, not measurements, like clipped codes.
    Ours, not a paper's.

    Parameters
    ----------
    values : numpy.ndarray
        ``(F, n, 3)`` codes normalised to [0, 1] (block means of sample locations, as
        :class:`selfcal.stack.samples.SampleSet` holds them, or subsampled pixels).
    log_exposures : array_like
        ``(F,)`` log exposure of each frame (NaN where unknown: such frames are skipped).
    clip_margin : float
        Codes (8-bit scale) within this distance of 0 or the maximum are clipped and not
        looked at.
    min_count : int
        Bins with fewer samples are passed over.

    Returns
    -------
    dict
        ``{"floor": [R, G, B], "ceiling": [R, G, B]}`` as normalised codes: the highest
        code that does not move up (0 when none) and the lowest code that does not move
        up (1 when none).
    """
    v = np.asarray(values, dtype=np.float64) * 255.0
    le = np.asarray(log_exposures, dtype=np.float64)
    floor = [0.0, 0.0, 0.0]
    ceiling = [1.0, 1.0, 1.0]
    known = np.flatnonzero(np.isfinite(le))
    order = known[np.argsort(le[known], kind="stable")]
    pairs = []
    for i, a in enumerate(order):
        later = [b for b in order[i + 1:] if le[b] - le[a] >= math.log(STUCK_RATIO)]
        if later:
            pairs.append((a, later[0]))
    for c in range(v.shape[2]):
        # the moves of every pair, pooled by the code in the darker frame
        codes, moves = [], []
        for a, b in pairs:
            va, vb = v[a, :, c], v[b, :, c]
            ok = (va > clip_margin) & (va < 255.0 - clip_margin)
            codes.append(np.floor(va[ok]).astype(int))
            moves.append(vb[ok] - va[ok])
        if not codes:
            continue
        code, move = np.concatenate(codes), np.concatenate(moves)
        med = {}
        for z in np.unique(code):
            m = move[code == z]
            if m.size >= min_count:
                med[int(z)] = float(np.median(m))
        zs = sorted(med)
        for z in zs:                               # up from the bottom
            if med[z] > min(STUCK_CODES, STUCK_FRACTION * z) + 1e-3:   # float block means
                break
            floor[c] = (z + 1) / 255.0
        for z in reversed(zs):                     # down from the top
            if med[z] >= STUCK_CODES or (z + 1) / 255.0 <= floor[c]:
                break
            ceiling[c] = z / 255.0
    return {"floor": floor, "ceiling": ceiling}
