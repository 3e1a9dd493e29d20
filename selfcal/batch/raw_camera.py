"""Per camera body, one RAW-path model from the RAW+JPEG pairs of its sessions.

Where a camera's frames come with raws (``IMG_0001.JPG`` + ``IMG_0001.CR2``: paired by
:func:`.discover._pair_raws`), the batch fits one camera pipeline per camera key from
the pairs of many sessions (:func:`selfcal.pipeline.library.fit_pipeline_library`: the
rank-based model of [Gong2018] §3 with the RBF ``h⁻¹`` of [Lin2011] §6, the scenes as
groups, λ of the tone curves and the errors by leave-one-scene-out).  A scene is a
session of the batch (a bracket of one scene), or a single RAW+JPEG shot that is in no
session (:attr:`.discover.Library.lone_pairs`).  The camera key (:func:`.discover.camera_key`)
holds the body and the picture settings EXIF gives (CustomRendered, Contrast, Saturation,
Sharpness, EXIF 2.32): where those change, the pairs go to different models.  Picture
styles that only a maker note records (Canon Picture Style, Sony Creative Style, Fuji
film simulation, Nikon Picture Control) are *not* read: frames that differ only there
share a model.  All of this is ours.

The task (:func:`fit_raw_camera`) runs wherever the executor puts it, reads its pairs
itself, never raises, and writes together (:class:`selfcal.io.StagedOutputs`)::

    cameras/<camera>/pipeline.json     the RAW-path model (selfcal render / to-raw read it)
    cameras/<camera>/raw_camera.json   its record: scenes, λ, leave-one-scene-out errors

beside the camera's pooled response curve (``model.json``).  A rerun reuses the record
(:func:`reusable_raw_camera_fit`) when the same pairs are planned and the model is newer
than each of them.
"""

from __future__ import annotations

import json
import os
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from ..errors import CalibrationError, SelfcalError
from ..pipeline.library import LibraryOptions

RAW_MODEL = "pipeline.json"
RAW_RECORD = "raw_camera.json"
#: Scenes (sessions) in a camera's library fit at most, spread over its sessions.
RAW_SCENES = 24
#: RAW+JPEG pairs read per scene at most (spread over the bracket).
PAIRS_PER_SCENE = 2
#: The camera-row fields of the RAW-path fit (:func:`raw_camera_columns`).
RAW_COLUMNS = ["raw_model_file", "raw_scenes", "raw_smoothness", "raw_loso_forward",
               "raw_loso_backward", "raw_training_forward", "raw_training_backward",
               "raw_fit_error", "raw_fit_reused"]


@dataclass(frozen=True)
class RawLibraryOptions:
    """How the batch fits a camera's RAW+JPEG library.

    Attributes
    ----------
    fit : LibraryOptions
        The library fit's options (:func:`selfcal.pipeline.library.fit_pipeline_library`).
    max_scenes : int
        Scenes per camera at most (:data:`RAW_SCENES`), chosen evenly over time.
    pairs_per_scene : int
        Pairs read per scene at most (:data:`PAIRS_PER_SCENE`).
    half_size : bool
        Read raws at half size (:func:`selfcal.pipeline.pairs.sample_raw_jpeg_pair`).
    """

    fit: LibraryOptions = field(default_factory=LibraryOptions)
    max_scenes: int = RAW_SCENES
    pairs_per_scene: int = PAIRS_PER_SCENE
    half_size: bool = True


@dataclass(frozen=True)
class RawCameraPlan:
    """A camera with RAW+JPEG pairs in two sessions or more: its scenes and pairs."""

    camera: str
    label: str
    scenes: tuple           # ((session id, ((raw, rendered), ...)), ...)
    out_dir: str

    @property
    def folder(self) -> Path:
        return Path(self.out_dir) / "cameras" / self.camera

    @property
    def model_path(self) -> Path:
        return self.folder / RAW_MODEL

    def files(self) -> list:
        return [f for _, pairs in self.scenes for pair in pairs for f in pair]


@dataclass
class RawCameraFit:
    """What :func:`fit_raw_camera` found (or a reused fit's record)."""

    camera: str
    label: str = ""
    model_path: str = ""
    scenes: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    figures: dict = field(default_factory=dict)
    error: str = ""
    seconds: float = 0.0
    worker: str = ""
    reused: bool = False


def _error_text(exc: BaseException) -> str:
    """One line: the library's own errors as they are, anything else with its type."""
    return str(exc) if isinstance(exc, SelfcalError) else f"{type(exc).__name__}: {exc}"


def session_pairs(plan) -> tuple:
    """``((raw, rendered), ...)`` of a session plan: its frames with a raw of the same
    stem in the same folder (as discovery paired them)."""
    raws = {(Path(r).parent, Path(r).stem.lower()): str(r) for r in plan.raws}
    out = []
    for f in plan.frames:
        raw = raws.get((Path(f).parent, Path(f).stem.lower()))
        if raw is not None:
            out.append((raw, str(f)))
    return tuple(out)


def _spread(items, k: int) -> list:
    """At most ``k`` of ``items``, evenly spread, order kept."""
    if len(items) <= k:
        return list(items)
    idx = np.unique(np.round(np.linspace(0, len(items) - 1, k)).astype(int))
    return [items[i] for i in idx]


def _lone_scene(info) -> tuple:
    """A single RAW+JPEG shot as a scene: ``(start, id, label, ((raw, rendered),))``; the
    id is ``pair-<stem>-<hash of its path>`` (unique in a library)."""
    import hashlib
    from datetime import datetime, timedelta

    digest = hashlib.sha1(str(info.path).encode()).hexdigest()[:6]
    start = (datetime(1970, 1, 1) + timedelta(seconds=info.time or 0.0)).isoformat(
        timespec="milliseconds")
    return (start, f"pair-{info.path.stem.lower()}-{digest}", info.camera_label,
            ((str(info.raw), str(info.path)),))


def plan_raw_cameras(plans, out_dir, options: RawLibraryOptions | None,
                     lone_pairs=()) -> dict:
    """Camera key → :class:`RawCameraPlan` for every known camera with RAW+JPEG pairs in
    two scenes or more: its sessions with raws, and its single RAW+JPEG shots
    (``lone_pairs``, :attr:`.discover.Library.lone_pairs`), one scene each.  None when
    ``options`` is None (the RAW path is off)."""
    if options is None:
        return {}
    by_camera: dict = {}
    for p in plans:
        pairs = session_pairs(p)
        if pairs and not p.camera.startswith("unknown"):
            by_camera.setdefault(p.camera, []).append((p.start, p.id, p.camera_label, pairs))
    for info in lone_pairs:
        if not info.camera.startswith("unknown"):
            by_camera.setdefault(info.camera, []).append(_lone_scene(info))
    out = {}
    for camera, items in by_camera.items():
        if len(items) < 2:
            continue
        items = _spread(sorted(items, key=lambda x: (x[0], x[1])),
                        max(2, int(options.max_scenes)))
        scenes = tuple((sid, tuple(_spread(pairs, max(1, int(options.pairs_per_scene)))))
                       for _, sid, _, pairs in items)
        out[camera] = RawCameraPlan(camera=camera, label=items[0][2], scenes=scenes,
                                    out_dir=str(Path(out_dir).resolve()))
    return out


def raw_camera_samples(plan: RawCameraPlan, options: RawLibraryOptions, seed: int = 0
                       ) -> tuple[dict, dict]:
    """Each scene's joined pair samples, as :func:`fit_raw_camera` fits them.

    :func:`selfcal.pipeline.pairs.collect_pair_samples` of the scene's pairs (twice
    ``options.fit.scene_samples`` drawn, the library fit subsamples them).  Scenes whose
    pairs cannot be read or registered, or give fewer than 30 samples, are left out.

    Returns
    -------
    scenes : dict
        Session id → :class:`~selfcal.pipeline.pairs.PairSamples`.
    skipped : dict
        Session id → why it was left out.
    """
    from ..pipeline.pairs import collect_pair_samples

    per_scene = 2 * int(options.fit.scene_samples)
    scenes, skipped = {}, {}
    for sid, pairs in plan.scenes:
        try:
            samples, _ = collect_pair_samples([r for r, _ in pairs], [j for _, j in pairs],
                                              seed=seed, max_samples=per_scene,
                                              half_size=options.half_size)
            if len(samples) < 30:
                raise CalibrationError(f"{len(samples)} usable blocks (30 needed): too "
                                       "small, clipped or textured")
            scenes[sid] = samples
        except Exception as exc:  # one scene's failure never stops the others
            skipped[sid] = _error_text(exc)
    return scenes, skipped


def fit_raw_camera(plan: RawCameraPlan, options: RawLibraryOptions, seed: int = 0
                   ) -> RawCameraFit:
    """The camera's RAW-path model from its scenes' pairs, written with its record
    (never raises: a failure is the record's ``error``, and nothing is written).

    :func:`selfcal.pipeline.library.fit_pipeline_library` on the block-mean samples of
    each scene's pairs (:func:`selfcal.pipeline.pairs.collect_pair_samples`); the model
    goes to ``cameras/<camera>/pipeline.json`` and the record (:class:`RawCameraFit`,
    with the fit's :meth:`~selfcal.pipeline.library.LibraryFit.summary` as ``figures``)
    to ``raw_camera.json``, together.
    """
    from ..io.images import StagedOutputs
    from ..io.model_file import jsonable
    from ..pipeline.library import fit_pipeline_library

    t0 = time.perf_counter()
    fit = RawCameraFit(camera=plan.camera, label=plan.label,
                       worker=f"{socket.gethostname()}:{os.getpid()}")
    try:
        scenes, fit.skipped = raw_camera_samples(plan, options, seed)
        fit.scenes = list(scenes)
        if len(scenes) < 2:
            raise CalibrationError(f"{len(scenes)} of its {len(plan.scenes)} scenes gave samples; "
                             "a RAW-path library needs two")
        lib = fit_pipeline_library(scenes, options.fit, seed=seed)
        fit.figures = lib.summary()
        fit.model_path = str(plan.model_path)
        fit.seconds = time.perf_counter() - t0
        record = {**asdict(fit), "pairs": [[sid, [list(p) for p in pairs]]
                                           for sid, pairs in plan.scenes],
                  "settings": fit_settings(options, seed)}
        with StagedOutputs(force=True) as staged:
            staged.write(plan.model_path, lambda tmp: lib.model.save(tmp, force=True))
            staged.write(plan.folder / RAW_RECORD, lambda tmp: Path(tmp).write_text(
                json.dumps(jsonable(record), indent=1, allow_nan=False, default=str)))
    except Exception as exc:
        fit.error, fit.model_path = _error_text(exc), ""
    fit.seconds = time.perf_counter() - t0
    return fit


def fit_settings(options: RawLibraryOptions, seed: int) -> str:
    """What a fit was made with besides its pairs (the options and the seed), as text: a
    rerun with other settings fits again."""
    return f"{options!r} seed={int(seed)}"


def reusable_raw_camera_fit(plan: RawCameraPlan, options: RawLibraryOptions | None = None,
                            seed: int = 0) -> RawCameraFit | None:
    """The camera's RAW-path fit of an earlier run when its record lists the same pairs
    and settings (:func:`fit_settings`; not compared when ``options`` is None) and its
    model is newer than every one of the pairs; else None."""
    try:
        record = json.loads((plan.folder / RAW_RECORD).read_text())
        pairs = tuple((sid, tuple(tuple(p) for p in ps)) for sid, ps in record.pop("pairs"))
        settings = record.pop("settings")
        if options is not None and settings != fit_settings(options, seed):
            return None
        fit = RawCameraFit(**record)
        made = os.stat(fit.model_path).st_mtime
        newest = max(os.stat(f).st_mtime for f in plan.files())
    except (OSError, ValueError, TypeError, KeyError):
        return None
    if pairs != plan.scenes or not made > newest or fit.error:
        return None
    fit.reused = True
    return fit


def raw_camera_columns(fit: RawCameraFit | None) -> dict:
    """The camera row's RAW-path fields (:data:`RAW_COLUMNS`, and ``raw_scene_errors``
    for the JSON Lines and the plot): empty without a fit."""
    if fit is None:
        return {k: None for k in RAW_COLUMNS} | {"raw_model_file": "", "raw_fit_error": "",
                                                 "raw_fit_reused": False,
                                                 "raw_scene_errors": []}
    f = fit.figures or {}
    return {"raw_model_file": fit.model_path, "raw_scenes": list(fit.scenes),
            "raw_smoothness": f.get("smoothness"), "raw_loso_forward": f.get("loso_forward"),
            "raw_loso_backward": f.get("loso_backward"),
            "raw_training_forward": f.get("training_forward"),
            "raw_training_backward": f.get("training_backward"),
            "raw_fit_error": fit.error, "raw_fit_reused": bool(fit.reused),
            "raw_scene_errors": list(f.get("scenes", []))}


def lost_raw_fit(plan: RawCameraPlan, fut) -> RawCameraFit:
    """The record of a RAW-path fit whose task was lost (its worker died, say)."""
    try:
        fut.result()
        why = "no result"
    except Exception as exc:
        why = f"{type(exc).__name__}: {exc}"
    return RawCameraFit(camera=plan.camera, label=plan.label,
                        error=f"the task failed on the cluster ({why})")
