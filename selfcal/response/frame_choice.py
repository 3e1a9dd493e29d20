"""Which frames of a stack the response solve can use (:func:`selfcal.calibrate_response`).

Frames clipped almost everywhere and duplicates are dropped before the solve, each with
a warning (ours; [Lin2011] §5 rejects clipped *samples*, not frames).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import InputError
from .model import IgnoredFrame


def without_clipped_frames(samples, masks, sources, warnings, clip_margin,
                           ignored: list | None = None) -> list[int]:
    """Indices of the frames not clipped almost everywhere (< 1 % of samples unclipped).

    The warning of a dropped frame says whether it is white (or black) everywhere, or
    mostly white or black; ``ignored`` receives its :class:`.model.IgnoredFrame`
    (reason ``"clipped"``).
    """
    margin = clip_margin / 255.0
    keep = []
    for k in range(samples.n_frames):
        clipped = float(masks["clipped"][k].mean())
        if 1.0 - clipped >= 0.01:
            keep.append(k)
            continue
        white = float(np.mean(samples.block_max[k] >= 1.0 - margin))
        black = float(np.mean(samples.block_min[k] <= margin))
        if white >= 0.999 or black >= 0.999:
            what = "white" if white >= black else "black"
            share = 100 * max(white, black)
            detail = f"all {what} ({share:.1f}% of samples clipped {what})"
        else:
            detail = (f"clipped almost everywhere ({100 * clipped:.1f}% of samples: "
                      f"{100 * white:.1f}% white, {100 * black:.1f}% black)")
        record_ignored(sources[k], "clipped", detail, warnings, ignored)
    return keep


def without_duplicates(digests, times, sources, warnings, indices=None,
                       ignored: list | None = None) -> list[int]:
    """The frames that are not a copy of an earlier one (``indices`` of the ones kept).

    ``ignored`` receives each copy's :class:`.model.IgnoredFrame` (reason ``"duplicate"``).

    ``digests`` are :func:`selfcal.stack.frames.content_digest` of every pixel.  Identical
    pixels at different given times contradict each other: an InputError.
    """
    indices = list(range(len(digests))) if indices is None else list(indices)
    keep = list(indices)
    seen: dict[str, int] = {}
    for k, dig in enumerate(digests):
        if dig in seen:
            j = seen[dig]
            if times[j] is not None and times[k] is not None and not math.isclose(
                    times[j], times[k], rel_tol=1e-3):
                raise InputError(
                    f"identical pixels to {sources[j]} but a different exposure time "
                    f"({times[k]:g} s vs {times[j]:g} s): a duplicated file?", sources[k])
            record_ignored(sources[k], "duplicate", f"duplicate of {sources[j]}", warnings,
                           ignored)
            keep.remove(indices[k])
        else:
            seen[dig] = k
    return keep


def record_ignored(source: str, reason: str, detail: str, warnings: list,
                   ignored: list | None) -> None:
    """A frame left out of the solve: its :class:`.model.IgnoredFrame` into ``ignored``
    (the fact, which the merge reads) and ``"<source>: <detail>; ignored"`` into
    ``warnings`` (for people)."""
    warnings.append(f"{source}: {detail}; ignored")
    if ignored is not None:
        ignored.append(IgnoredFrame(source=source, reason=reason, detail=detail))


def subset(samples, keep):
    """The SampleSet of the frames ``keep`` only."""
    distance = None if samples.clip_distance is None else samples.clip_distance[keep]
    return replace(samples, values=samples.values[keep], block_max=samples.block_max[keep],
                   block_min=samples.block_min[keep], clip_distance=distance,
                   sources=[samples.sources[k] for k in keep],
                   digests=[samples.digests[k] for k in keep],
                   thumbnails=[samples.thumbnails[k] for k in keep
                               if k < len(samples.thumbnails)])
