"""Whether a bracket of 16-bit (or float) TIFFs is linear data rather than rendered frames.

A raw converter's linear TIFFs look like rendered 16-bit frames; :func:`linear_evidence`
says, in words, why a bracket is linear (a TIFF tag, or pixel ratios that do not change
with brightness and follow the exposure times), or returns None.  The test is ours; the
exponential ambiguity it guards against is [Lin2011]_ §5.

References
----------
.. [Lin2011] See ``docs/references.md``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import read_image
from ..io.raw import TIFF_SUFFIXES, is_linear_tiff
from .raw_ratios import split_thumbnails

__all__ = ["linear_evidence", "PHOTOMETRIC_LINEAR_RAW", "LINEAR_RATIO_SPREAD",
           "LINEAR_EXPONENT_TOLERANCE", "LINEAR_MIN_EXPOSURE_RATIO"]

#: TIFF PhotometricInterpretation of linear raw data (DNG's LinearRaw).
PHOTOMETRIC_LINEAR_RAW = 34892
#: A bracket is linear when the pixel ratio between two frames is the same at every
#: brightness: the medians of log(ratio) over the four quartiles of the darker frame's
#: values differ by at most this share of the median log ratio (a rendered curve's toe and
#: shoulder change the ratio with brightness: 15-20 % on the simulator's default camera) ...
LINEAR_RATIO_SPREAD = 0.05
#: ... and, where exposure times are known, the ratios follow them to the power
#: 1 ± LINEAR_EXPONENT_TOLERANCE (a rendered curve's log-log slope is 0.4-0.7).
LINEAR_EXPONENT_TOLERANCE = 0.15
#: Frame pairs whose exposures (or median values) differ by less than this factor say
#: little about linearity.
LINEAR_MIN_EXPOSURE_RATIO = 1.5


#: (values, selection) half-frame thumbnails of a frame's grey
_Thumbnails = tuple[np.ndarray, np.ndarray]


def _grey_thumbnails(path: str | os.PathLike[str], side: int = 256) -> _Thumbnails:
    """The frame's mean of the channels on [0, 1] as two half-frame thumbnails of about
    ``side`` pixels a side, (values, selection) of :func:`selfcal.exposure.raw_ratios.split_thumbnails`
    (NaN where a clipped value went in)."""
    img = read_image(path)
    white = 65535.0 if img.dtype == np.uint16 else 255.0 if img.dtype == np.uint8 else 1.0
    values, selection = split_thumbnails(img.astype(np.float32) / np.float32(white),
                                         max_side=side)
    return values.mean(axis=2), selection.mean(axis=2)


def _photometric_linear_raw(path) -> bool:
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            return int(tif.pages[0].photometric) == PHOTOMETRIC_LINEAR_RAW
    except Exception:  # an unreadable TIFF is not said to be linear
        return False


def _ratio_profile(a: _Thumbnails, b: _Thumbnails) -> tuple[float, float] | None:
    """log(b / a) over pixels well exposed in both, and the spread of its values over the
    quartiles of ``a`` relative to it; None with too few pixels.

    ``a`` and ``b`` are (values, selection) half-frame thumbnails: pixels are chosen and
    put in quartiles by the selection half and measured (log of the ratio of sums) on the
    other, so that the noise does not bend the profile at its ends.
    """
    (av, asel), (bv, bsel) = a, b
    ok = ((asel > 0.01) & (bsel > 0.01) & (asel < 0.9) & (bsel < 0.9)
          & np.isfinite(av) & np.isfinite(bv) & (av > 0) & (bv > 0))
    if ok.sum() < 64:
        return None
    av, bv, asel = av[ok], bv[ok], asel[ok]
    edges = np.quantile(asel, [0.0, 0.25, 0.5, 0.75, 1.0])
    levels = [float(np.log(bv[m].sum() / av[m].sum()))
              for lo, hi in zip(edges[:-1], edges[1:])
              if (m := (asel >= lo) & (asel <= hi)).any()]
    level = float(np.log(bv.sum() / av.sum()))
    if abs(level) < math.log(LINEAR_MIN_EXPOSURE_RATIO):
        return None
    return level, (max(levels) - min(levels)) / abs(level)


def linear_evidence(frames, exposures) -> str | None:
    """Why a bracket of 16-bit (or float) TIFFs is linear data, or None if it is not.

    A raw converter's linear TIFFs (``dcraw -4 -T``, ``selfcal linearize``) look like
    rendered 16-bit frames, but their response is the identity: calibrated as rendered
    frames without exposure times, the exponential ambiguity (Lin et al. 2011, §5) is
    resolved by the basis prior, which bends the curve (f⁻¹ at 1/8 of full scale 0.07
    instead of 0.125) and gets the exposure ratios wrong.  They are linear when a tag says
    so (PhotometricInterpretation LinearRaw, as in DNG), or when the pixel ratio between
    frames is the same at every brightness (:data:`LINEAR_RATIO_SPREAD`) and, where
    exposures are known, equals the exposure ratio (to the power 1 ±
    :data:`LINEAR_EXPONENT_TOLERANCE`).  This test is ours.  Without times, a rendered
    curve that is a pure power law passes it too: such frames are indistinguishable from
    linear data up to that ambiguity, and giving their times decides.

    Parameters
    ----------
    frames : sequence of path
    exposures : sequence of float or None
        Exposure per frame (EXIF time × ISO / N², or given), None where unknown.

    Returns
    -------
    str or None
        The evidence, in words, when every frame is a 16-bit or float TIFF and the
        bracket is linear; None otherwise.
    """
    frames = [Path(p) for p in frames]
    if len(frames) < 2 or not all(p.suffix.lower() in TIFF_SUFFIXES and is_linear_tiff(p)
                                  for p in frames):
        return None
    if all(_photometric_linear_raw(p) for p in frames):
        return "their TIFF tags say linear raw data (PhotometricInterpretation LinearRaw)"
    try:
        greys = [_grey_thumbnails(p) for p in frames]
    except InputError:      # e.g. float TIFFs: said where the frames are read for the work
        return None
    if any(g[0].shape != greys[0][0].shape for g in greys):
        return None
    known = [(float(e), g) for e, g in zip(exposures, greys) if e is not None]
    timed = len({round(math.log(t), 2) for t, _ in known}) >= 2
    pairs: list[tuple[_Thumbnails, _Thumbnails, float | None]]
    if timed:
        ordered = sorted(known, key=lambda x: x[0])
        pairs = [(a, b, math.log(tb / ta)) for (ta, a), (tb, b) in zip(ordered, ordered[1:])
                 if tb >= ta * LINEAR_MIN_EXPOSURE_RATIO]
    else:
        by_level = sorted(greys, key=lambda g: float(np.median(np.nan_to_num(g[1], nan=1.0))))
        pairs = [(a, b, None) for a, b in zip(by_level, by_level[1:])]
    profiles = [(prof, log_t) for a, b, log_t in pairs
                if (prof := _ratio_profile(a, b)) is not None]
    if not profiles or max(spread for (_, spread), _ in profiles) > LINEAR_RATIO_SPREAD:
        return None
    spread = max(spread for (_, spread), _ in profiles)
    same = (f"the pixel ratios between frames are the same at every brightness (within "
            f"{100 * spread:.0f}%)")
    if not timed:
        return same + " and no exposure times are known to check them against"
    power = float(np.median([level / log_t for (level, _), log_t in profiles
                             if log_t is not None]))     # all of them: the frames are timed
    if abs(power - 1.0) > LINEAR_EXPONENT_TOLERANCE:
        return None
    return same + f" and follow the exposure times (to the power {power:.2f})"
