"""Many sessions at once: a photo library to radiance maps, one response per camera body.

``run_batch(roots, out_dir, scheduler=None, ...)`` walks the folders, finds the bracketed
sessions by what the frames show and their EXIF (:mod:`.discover`, :mod:`.grouping`),
fits one response curve per camera body from samples pooled across its sessions
(:mod:`.pooled`, on the Eq. 7-8 solver of [Lin2011], §5), merges every session into an
HDR radiance map with a preview (:mod:`.run`), and writes a manifest and a plot per
camera (:mod:`.camera_plot`); the work runs on Dask distributed
(:mod:`.cluster`; ``pip install "selfcal[batch]"``).  Importing this package does not
import Dask.  Its modules:

* :mod:`selfcal.batch.discover` -- the bracketed sessions of a photo library: EXIF, bodies;
* :mod:`selfcal.batch.grouping` -- sessions by what the frames show;
* :mod:`selfcal.batch.thumbnails` -- the frames' thumbnails, read once and kept on disk;
* :mod:`selfcal.batch.copies` -- copies of one card in several folders, used once;
* :mod:`selfcal.batch.pooled` -- one response curve per camera body, from pooled samples;
* :mod:`selfcal.batch.run` -- the plan, the three kinds of task, the manifest, reruns;
* :mod:`selfcal.batch.cluster` -- the task graph on Dask distributed (or in process);
* :mod:`selfcal.batch.faults` -- interruption, lost workers, leftovers of killed writers;
* :mod:`selfcal.batch.camera_plot` -- per camera body, its sessions' curves over the pooled one;
* :mod:`selfcal.batch.raw_camera` -- per camera body, one RAW-path model from its RAW+JPEG
  pairs.

Examples
--------
A folder without a bracket is nothing to do: no file is written.

>>> import pathlib, tempfile
>>> from selfcal.batch import run_batch
>>> card = pathlib.Path(tempfile.mkdtemp())
>>> result = run_batch([card], card.parent / "selfcal-batch-example", scheduler="serial")
>>> result.rows, [r["session"] for r in result.failed]
([], [])
"""

from __future__ import annotations

from .cluster import BatchResult, ClusterError, ClusterOptions, require_dask, run_batch
from .discover import FrameInfo, Library, Session, discover, group_sessions, read_frame_info
from .grouping import GroupingRule, group_by_content
from .pooled import (PooledCalibration, SessionSamples, fit_shared_response,
                     pooled_calibration, session_samples, shared_model)
from .run import BatchOptions

__all__ = [
    "run_batch",
    "BatchResult",
    "BatchOptions",
    "ClusterOptions",
    "ClusterError",
    "require_dask",
    "discover",
    "group_sessions",
    "group_by_content",
    "GroupingRule",
    "read_frame_info",
    "FrameInfo",
    "Library",
    "Session",
    "session_samples",
    "fit_shared_response",
    "pooled_calibration",
    "shared_model",
    "PooledCalibration",
    "SessionSamples",
]
