"""Which frames a merge takes and how it treats their codes (ours): frames the calibration
ignored left out or merged unchecked (:func:`frames_to_merge`), the black floors and stuck
ceilings that do not move with exposure (:func:`stuck_levels`), and whether the frames
are lossy, so that clipped regions are widened against JPEG ringing (:func:`looks_lossy`).
Used by :func:`selfcal.hdr.merge.merge_hdr`.
"""

from __future__ import annotations

import numpy as np

from ..io.images import JPEG_SUFFIXES
from ..response.options import DEFAULT_MAX_SAMPLES
from ..response.stuck_codes import stuck_code_levels
from ..stack.frames import StackFrames, model_frame_index
from ..stack.samples import collect_samples

__all__ = ["frames_to_merge", "stuck_levels", "looks_lossy"]


def frames_to_merge(frames: StackFrames, model, fresh: bool, exposures, warnings: list,
                     diagnostics: dict, *, merge_unchecked: bool = True):
    """(indices of the frames to merge, those of them merged unchecked) (ours).

    From the model's :attr:`~selfcal.ResponseModel.frames_ignored` (not its warnings): a
    frame ignored as a duplicate or clipped is not merged (a warning says why).  One
    ignored as ``"unchecked"`` (a long exposure far beyond the others, black in every
    other frame) is merged with its given or EXIF time, which the pixels could not check
    -- it alone measures the shadows it sees -- and named in a warning,
    ``diagnostics['frames_unchecked']`` and :attr:`selfcal.HDRResult.unchecked` (left out with
    ``merge_unchecked=False``).  Frames the model never saw are merged.
    """
    n = len(frames)
    by_source = {f.source: f for f in getattr(model, "frames_ignored", ()) or ()}
    if model is None or not by_source:
        return list(range(n)), []
    idx = model_frame_index(model, frames, fresh)
    msources = list(getattr(model, "sources", []) or [])
    ignored = [(k, by_source[msources[i]]) for k, i in enumerate(idx)
               if i is not None and i < len(msources) and msources[i] in by_source]
    if not ignored or len(ignored) == n:
        return list(range(n)), []
    left_out, unchecked = [], []
    for k, why in ignored:
        e = float(exposures[k])
        if merge_unchecked and why.reason == "unchecked" and np.isfinite(e) and e > 0:
            unchecked.append(k)
            warnings.append(f"{frames.sources[k]}: merged with its exposure time "
                            f"({e:g}), unchecked against the pixels: the calibration "
                            f"ignored it ({why.detail}); HDRResult.unchecked flags the "
                            "pixels that rest on it")
            continue
        left_out.append(k)
        warnings.append(f"{frames.sources[k]}: not merged: the calibration ignored it"
                        + (f" ({why.detail})" if why.detail else ""))
    if left_out:
        diagnostics["frames_ignored"] = [frames.sources[k] for k in left_out]
    if unchecked:
        diagnostics["frames_unchecked"] = [frames.sources[k] for k in unchecked]
    return [k for k in range(n) if k not in left_out], unchecked


def stuck_levels(model, frames: StackFrames, exposures, used, clip_margin: float,
                  diagnostics: dict, given=None):
    """Per channel (floor, ceiling) as normalised codes: the calibration's, else measured.

    The model's ``diagnostics['stuck_codes']`` (:func:`selfcal.response.stuck_codes.stuck_code_levels`
    over the calibration's samples) when it has them -- a floor or ceiling is a property
    of the camera (or the scan), so a model of another scene's frames carries it -- else
    the same function over samples of the frames to merge.
    """
    levels, source = given, "given"
    if levels is None:
        levels = (getattr(model, "diagnostics", None) or {}).get("stuck_codes")
        source = "model"
    if levels is None:
        items = [frames.items[k] for k in used]
        samples = collect_samples(items, sources=[frames.sources[k] for k in used],
                                  max_samples=DEFAULT_MAX_SAMPLES)
        levels = stuck_code_levels(samples.values, np.log(np.asarray(exposures)[used]),
                                   clip_margin=clip_margin)
        source = "frames"
    floor = np.asarray(levels["floor"], dtype=float)
    ceiling = np.asarray(levels["ceiling"], dtype=float)
    diagnostics["stuck_codes"] = {"floor": np.round(255 * floor, 2).tolist(),
                                  "ceiling": np.round(255 * ceiling, 2).tolist(),
                                  "scale": "8-bit codes", "from": source}
    return floor, ceiling


def looks_lossy(frames: StackFrames, linear: bool) -> bool:
    """JPEG files, or 8-bit arrays (which may be decoded JPEGs): widen clipped regions."""
    if linear:
        return False
    for item, path in zip(frames.items, frames.paths):
        if path is not None:
            if path.suffix.lower() in JPEG_SUFFIXES:
                return True
        elif np.asarray(item).dtype == np.uint8:
            return True
    return False
