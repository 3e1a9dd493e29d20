"""The work of a batch: the plan, the three kinds of task, the manifest, rerun skipping.

Three functions do all the work and run wherever the executor puts them (a Dask worker,
or in process); they take paths and small plans, read the files themselves, and never
raise -- a failure comes back as a record naming the session and the cause:

* :func:`prepare_session` -- the session's own calibration, exactly
  ``selfcal calibrate FRAMES`` (:func:`selfcal.calibrate`), and its samples for the
  camera's pooled fit (:func:`.pooled.session_samples`);
* :func:`fit_camera` -- the camera's shared curve (:func:`.pooled.pooled_calibration`),
  written as a model file, with each pooled session's agreement;
* :func:`finish_session` -- the model the session uses (the camera's, or its own when it
  disagrees or cannot be pooled), the HDR merge and preview, exactly
  ``selfcal merge FRAMES --model MODEL --preview``, and linear frames on request; every
  output of a session is written together, or none is (:class:`selfcal.io.StagedOutputs`).

Output layout under the batch folder::

    manifest.jsonl  manifest.csv      one row per session
    cameras.jsonl   cameras.csv       one row per camera
    unassigned.csv                    files in no session, with the reason
    cameras/<camera>/model.json       the shared curve;  camera.json: its summary
    cameras/<camera>/pipeline.json    the RAW-path model (:mod:`.raw_camera`)
    sessions/<session>/radiance.exr   preview.jpg  [model.json]  [linear/*.tif]  session.json

A session is skipped on a rerun when its ``session.json`` says it finished, every output
it lists exists, and the oldest of them is newer than the newest of its frames (and of
the camera model it used); :func:`finished_row` decides.
"""

from __future__ import annotations

import csv
import io as _io
import json
import math
import os
import socket
import time
import warnings as _warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, cast

from ..errors import CalibrationError, SelfcalError, SelfcalWarning
from ..io.model_file import jsonable
from .camera_plot import camera_plot_writers, own_curve
from .grouping import DEFAULT_MAX_GAP
from .raw_camera import RAW_COLUMNS, RawLibraryOptions, raw_camera_columns
from .pooled import (POOL_SAMPLES, POOL_SESSIONS, SessionSamples, agreement_with, disagrees,
                     pooled_calibration, session_samples, shared_model)

if TYPE_CHECKING:
    from ..response.model import ResponseModel

MANIFEST = "manifest.jsonl"
MANIFEST_CSV = "manifest.csv"
CAMERAS = "cameras.jsonl"
CAMERAS_CSV = "cameras.csv"
UNASSIGNED_CSV = "unassigned.csv"
SESSION_RECORD = "session.json"
CAMERA_RECORD = "camera.json"


@dataclass(frozen=True)
class BatchOptions:
    """What every task needs to know besides its session.

    Attributes
    ----------
    linearize : bool
        Also write each frame linearised (16-bit TIFF, ``selfcal linearize``).
    pool : bool
        Fit one curve per camera (else every session is fitted alone).
    pool_sessions : int
        Sessions in a camera's pooled fit at most (spread over its sessions).
    pool_samples : int
        Sample locations per pooled session.
    force : bool
        Use a model whose verdict is ``unusable`` (as ``--force`` of the CLI).
    seed : int
    by_content : bool
        Find sessions by what the frames show, time as a hint (:mod:`.grouping`); False:
        by the time gap alone (:func:`.discover.group_sessions`).
    max_gap : float
        Seconds between frames that start a new session (the time rule, and the hint of
        the content grouping).
    luminance : {None, "exif"}
        ``"exif"``: every session's radiance in cd/m² by the EXIF convention of
        :func:`selfcal.lens.luminance.scale_from_exif` with its camera's curve
        (``MergeOptions(luminance="exif")``; the record's ``units`` and
        ``luminance_scale``); a session without EXIF exposures fails.  None: relative.
    camera_scales : dict
        Camera → :class:`selfcal.lens.LuminanceScale`: a constant measured once with a
        reference reading (``selfcal merge --reading ... --save-scale``), applied to every
        session of that camera (before ``luminance``).  A key matches a session's camera
        label (``make model #serial``) or its EXIF model, ignoring case.
    raw_library : RawLibraryOptions or None
        The RAW-path model per camera from its RAW+JPEG pairs (:mod:`.raw_camera`); None:
        none is fitted.
    """

    linearize: bool = False
    pool: bool = True
    pool_sessions: int = POOL_SESSIONS
    pool_samples: int = POOL_SAMPLES
    force: bool = False
    seed: int = 0
    by_content: bool = True
    max_gap: float = DEFAULT_MAX_GAP
    luminance: str | None = None
    camera_scales: dict = field(default_factory=dict)
    raw_library: RawLibraryOptions | None = field(default_factory=RawLibraryOptions)

    def luminance_for(self, camera_label: str) -> object:
        """The luminance option of a session of ``camera_label``: its camera's scale when
        one is given, else :attr:`luminance`."""
        label = camera_label.lower()
        for key, scale in self.camera_scales.items():
            key = key.lower()
            if label == key or label.split(" #")[0] == key or label.split(" #")[0].endswith(
                    " " + key):
                return scale
        return self.luminance


@dataclass(frozen=True)
class SessionPlan:
    """One session as the tasks get it: paths and EXIF facts, no pixels."""

    id: str
    camera: str
    camera_label: str
    frames: tuple
    raws: tuple
    exposure_times: tuple
    exposure_bias: tuple
    iso: tuple
    f_number: tuple
    lens: str
    start: str
    out_dir: str
    pool_candidate: bool = False
    alone_reason: str = ""
    grouping: tuple = ()
    grouping_unsure: bool = False

    @property
    def folder(self) -> Path:
        return Path(self.out_dir) / "sessions" / self.id

    def outputs(self, linearize: bool) -> dict:
        """The session's outputs by role (``model`` only when it is fitted alone)."""
        out: dict[str, Path | list[Path]] = {"radiance": self.folder / "radiance.exr",
                                             "preview": self.folder / "preview.jpg"}
        if linearize:
            out["linear"] = [self.folder / "linear" / (Path(f).stem + ".tif")
                             for f in self.frames]
        return out


@dataclass(frozen=True)
class CameraPlan:
    """A camera with a pooled fit: its candidate sessions and where the model goes."""

    camera: str
    label: str
    candidates: tuple
    sessions: tuple
    out_dir: str

    @property
    def folder(self) -> Path:
        return Path(self.out_dir) / "cameras" / self.camera

    @property
    def model_path(self) -> Path:
        return self.folder / "model.json"


@dataclass
class SessionPrep:
    """What :func:`prepare_session` hands on (small: a model and ~100 kB of samples)."""

    session: str
    ok: bool
    error: str = ""
    model: ResponseModel | None = None
    samples: SessionSamples | None = None
    warnings: list = field(default_factory=list)
    seconds: float = 0.0
    worker: str = ""


@dataclass
class CameraFit:
    """What :func:`fit_camera` found (or a reused fit's record)."""

    camera: str
    label: str = ""
    model_path: str = ""
    pooled: list = field(default_factory=list)
    flagged: list = field(default_factory=list)
    candidates: list = field(default_factory=list)
    agreement: dict = field(default_factory=dict)
    residual_rms_log: float | None = None
    error: str = ""
    seconds: float = 0.0
    worker: str = ""
    reused: bool = False


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _error_text(exc: BaseException) -> str:
    """One line: the library's own errors as they are, anything else with its type."""
    if isinstance(exc, SelfcalError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


# ------------------------------------------------------------------------ planning

def plan_batch(library, out_dir, options: BatchOptions):
    """Session and camera plans for a discovered library (:func:`.discover.discover`).

    A camera gets a pooled fit when pooling is on, its make and model are known and it
    has two sessions or more; its candidates are up to ``options.pool_sessions`` of them,
    spread evenly over time.  The others are fitted alone, with the reason.

    Returns
    -------
    sessions : list of SessionPlan
    cameras : dict
        Camera key → CameraPlan (only cameras with a pooled fit).
    """
    import numpy as np

    out_dir = str(Path(out_dir).resolve())
    plans, cameras = [], {}
    for camera, sessions in library.cameras.items():
        reason = ""
        if not options.pool:
            reason = "pooling is off"
        elif camera.startswith("unknown"):
            reason = "camera unknown (no make and model in EXIF)"
        elif len(sessions) < 2:
            reason = "the only session of its camera"
        candidates = set()
        if not reason:
            k = min(len(sessions), max(2, int(options.pool_sessions)))
            idx = np.unique(np.round(np.linspace(0, len(sessions) - 1, k)).astype(int))
            candidates = {sessions[i].id for i in idx}
            cameras[camera] = CameraPlan(
                camera=camera, label=sessions[0].camera_label,
                candidates=tuple(s.id for s in sessions if s.id in candidates),
                sessions=tuple(s.id for s in sessions), out_dir=out_dir)
        for s in sessions:
            f = s.frames
            plans.append(SessionPlan(
                id=s.id, camera=camera, camera_label=s.camera_label,
                frames=tuple(str(x.path) for x in f), raws=tuple(str(r) for r in s.raws),
                exposure_times=tuple(s.exposure_times),
                exposure_bias=tuple(x.exposure_bias for x in f),
                iso=tuple(x.iso for x in f), f_number=tuple(x.f_number for x in f),
                lens=f[0].lens, start=s.start, out_dir=out_dir,
                pool_candidate=s.id in candidates, alone_reason=reason,
                grouping=tuple(s.reasons), grouping_unsure=bool(s.unsure)))
    return plans, cameras


# ------------------------------------------------------------------------ task 1

def prepare_session(plan: SessionPlan, options: BatchOptions) -> SessionPrep:
    """The session's own calibration and its samples for the pool (never raises).

    The calibration is :func:`selfcal.calibrate` on the frames, as ``selfcal calibrate``
    runs it (times from EXIF; the RAW path is not taken: the batch passes the rendered
    frames only).  The samples (:func:`.pooled.session_samples`) are of the frames the
    calibration used, at the times it used.
    """
    from ..choose.paths import calibrate

    t0 = time.perf_counter()
    prep = SessionPrep(session=plan.id, ok=False, worker=_worker_name())
    try:
        with _warnings.catch_warnings(record=True) as caught:
            _warnings.simplefilter("always")
            result = calibrate(list(plan.frames), seed=options.seed)
            model = result.response
            if model is None:
                raise CalibrationError("the response path was not taken: "
                                       + "; ".join(result.reasons))
            model.fit_data = None
            prep.warnings += [str(w) for w in result.warnings]
            prep.warnings += [str(w) for w in model.diagnostics.get("warnings", [])]
            if options.pool and not plan.alone_reason:
                prep.samples = _samples_for_pool(plan, model, options)
        prep.warnings += [str(w.message) for w in caught
                          if issubclass(w.category, SelfcalWarning)]
        prep.model, prep.ok = model, True
    except Exception as exc:  # one session's failure never stops the others
        prep.error = _error_text(exc)
    prep.warnings = list(dict.fromkeys(prep.warnings))
    prep.seconds = time.perf_counter() - t0
    return prep


def _samples_for_pool(plan: SessionPlan, model, options: BatchOptions):
    """:func:`.pooled.session_samples` of the frames the model used, with its own curve."""
    used = set(model.diagnostics.get("frames_used") or model.sources)
    pick = [k for k, src in enumerate(model.sources) if src in used]
    times = [model.exposure_times[k] for k in pick]
    if len(pick) < 2 or any(t is None for t in times):
        return None
    s = session_samples([model.sources[k] for k in pick], times, session=plan.id,
                        max_samples=options.pool_samples, seed=options.seed)
    s.own_intensity, s.own_inverse = model.intensity, model.inverse
    return s


# ------------------------------------------------------------------------ task 2

def fit_camera(plan: CameraPlan, options: BatchOptions, *preps) -> CameraFit:
    """The camera's shared curve from its candidate sessions' samples (never raises).

    Writes ``cameras/<camera>/model.json`` (a response model file any selfcal command
    reads) and ``camera.json`` (this record) together.  With fewer than two agreeing
    sessions there is no model, only the record: every session is fitted alone.
    """
    from ..io.images import StagedOutputs

    t0 = time.perf_counter()
    fit = CameraFit(camera=plan.camera, label=plan.label, candidates=list(plan.candidates),
                    worker=_worker_name())
    try:
        samples = [p.samples for p in preps if p is not None and p.ok and p.samples]
        with _warnings.catch_warnings():
            _warnings.simplefilter("ignore")
            pooled = pooled_calibration(samples)
        fit.flagged, fit.pooled = list(pooled.flagged), list(pooled.pooled)
        fit.agreement = pooled.agreement
        model = None
        if pooled.fit is None:
            fit.error = (f"fewer than two of its {len(samples)} sampled sessions agree: no "
                         "shared curve")
        else:
            model = shared_model(pooled, samples, camera=plan.camera)
            fit.residual_rms_log = pooled.fit.residual_rms
            fit.model_path = str(plan.model_path)
        fit.seconds = time.perf_counter() - t0
        # the record is written without a model too: a rerun then reuses the verdict
        with StagedOutputs(force=True) as staged:
            if model is not None:
                staged.write(plan.model_path, lambda tmp: model.save(tmp, force=True))
            staged.write(plan.folder / CAMERA_RECORD,
                         lambda tmp: _write_json(tmp, jsonable(asdict(fit))))
    except Exception as exc:
        fit.error, fit.model_path = _error_text(exc), ""
    fit.seconds = time.perf_counter() - t0
    return fit


def reusable_camera_fit(plan: CameraPlan, sessions) -> CameraFit | None:
    """The camera's fit of an earlier run, when its model (or, without a model, its
    record) is newer than every frame of its candidate sessions and the candidates are
    the same; else None."""
    record = plan.folder / CAMERA_RECORD
    try:
        fit = CameraFit(**json.loads(record.read_text()))
        made = os.stat(fit.model_path or record).st_mtime
    except (OSError, ValueError, TypeError):
        return None
    if tuple(fit.candidates) != tuple(plan.candidates):
        return None
    by_id = {s.id: s for s in sessions}
    newest = max(_newest_input(by_id[c]) for c in plan.candidates)
    if not made > newest:
        return None
    fit.reused = True
    return fit


# ------------------------------------------------------------------------ task 3

def finish_session(plan: SessionPlan, options: BatchOptions, prep: SessionPrep,
                   camera: CameraFit | None = None) -> dict:
    """Merge the session with its model and write its outputs; the manifest row.

    The model: the camera's shared curve, unless the session disagrees with it (flagged
    by the pooled fit, or by :func:`.pooled.disagrees` here for a session outside the
    pool), has no samples, or has no camera fit -- then its own calibration, written to
    the session's ``model.json``.  The merge and its outputs are those of
    ``selfcal merge FRAMES --model MODEL -o radiance.exr --preview preview.jpg``, with the
    model read back from its file.  Never raises: a failure is a row with status
    ``failed`` and the error.
    """
    t0 = time.perf_counter()
    row = plan_row(plan)
    row.update(worker=_worker_name(), prepare_seconds=round(prep.seconds, 3),
               prepare_worker=prep.worker)
    if not prep.ok:
        return _failed(row, prep.error, t0, prep.warnings)
    try:
        with _warnings.catch_warnings(record=True) as caught:
            _warnings.simplefilter("always")
            choice = _choose_model(plan, prep, camera)
            row.update(choice)
            row["own_curve"] = own_curve(prep.model)
            written = _merge_and_write(plan, options, prep, row)
        row["warnings"] = list(dict.fromkeys(
            prep.warnings + row.get("warnings", []) + [str(w.message) for w in caught
                                                      if issubclass(w.category,
                                                                    SelfcalWarning)]))
    except Exception as exc:
        return _failed(row, _error_text(exc), t0, prep.warnings)
    row["outputs"] = [str(p) for p in written]
    return row


def _choose_model(plan: SessionPlan, prep: SessionPrep, camera: CameraFit | None) -> dict:
    """Which model a session uses, and why: the manifest's model fields."""
    own = prep.model
    assert own is not None      # a prepared session has its model
    out = {"verdict": own.diagnostics.get("verdict"), "pooled": False, "flagged": False,
           "agreement_shared": None, "agreement_own": None, "model_kind": "own",
           "model_reason": plan.alone_reason}
    if camera is None:
        return out
    if not camera.model_path:
        out["model_reason"] = f"no shared curve for its camera ({camera.error})"
        return out
    agree = camera.agreement.get(plan.id)
    if agree is None and prep.samples is not None:
        from ..choose.loading import load_model

        shared = cast("ResponseModel", load_model(camera.model_path))  # the camera's curve
        agree = agreement_with(prep.samples, shared.intensity, shared.inverse)
    if agree is None:
        out["model_reason"] = "no samples for the agreement test"
        return out
    agree = {k: math.nan if v is None else float(v) for k, v in agree.items()}
    out["agreement_shared"] = _round(agree["shared"])
    out["agreement_own"] = _round(agree["own"])
    out["pooled"] = plan.id in camera.pooled
    if plan.id in camera.flagged or (not out["pooled"] and disagrees(**agree)):
        out["flagged"] = True
        out["model_reason"] = (f"disagrees with its camera's shared curve (residual "
                               f"{agree['shared']:.2f} codes under it, {agree['own']:.2f} "
                               "under its own fit): fitted alone")
        return out
    out["model_kind"], out["model_reason"] = "camera", ""
    out["model"] = camera.model_path
    return out


def _merge_and_write(plan: SessionPlan, options: BatchOptions, prep: SessionPrep,
                     row: dict) -> list:
    """The merge, preview and linear frames of ``selfcal merge``/``linearize``, written
    with the session's record, all together (returns the outputs written)."""
    from ..hdr import MergeOptions, linearize_images, merge_hdr
    from ..hdr.io import write_linear, write_preview, write_radiance
    from ..io.images import StagedOutputs, read_exposure_info
    from ..choose.loading import load_model

    frames = [Path(f) for f in plan.frames]
    outputs = plan.outputs(options.linearize)
    row["model_file"] = row.pop("model", None) or str(plan.folder / "model.json")
    row["linearize"] = options.linearize
    targets = []

    def write(staged, target, writer):
        targets.append(Path(target))
        return staged.write(target, writer)

    with StagedOutputs(force=True, inputs=frames) as staged:
        if row["model_kind"] == "own":
            assert prep.model is not None   # a prepared session has its model
            _refuse_unusable(prep.model, options)
            tmp = write(staged, plan.folder / "model.json",
                        lambda t: prep.model.save(t, force=True))
            model = load_model(tmp)    # what the file holds, as `selfcal merge` reads it
        else:
            model = load_model(row["model_file"])
        t0 = time.perf_counter()
        result = merge_hdr(frames, None, model,
                           options=MergeOptions(
                               luminance=options.luminance_for(plan.camera_label)))
        write(staged, outputs["radiance"], lambda t: write_radiance(
            t, result.radiance, force=True, units=result.units))
        row["units"] = result.units
        if "luminance" in result.diagnostics:
            row["luminance_scale"] = result.diagnostics["luminance"]["scale"]
        write(staged, outputs["preview"], lambda t: write_preview(
            t, result.radiance, force=True, mask=~result.unmeasured))
        row["warnings"] = list(result.warnings)
        row["unmeasured_fraction"] = round(float(result.unmeasured.mean()), 6)
        del result
        for (src, linear), target in zip(linearize_images(frames, model) if
                                         options.linearize else (), outputs.get("linear", [])):
            info = read_exposure_info(src)
            write(staged, target, lambda t, lin=linear: write_linear(
                t, lin, force=True, exposure_time=info.exposure_time,
                f_number=info.f_number, iso=info.iso))
        row["merge_seconds"] = round(time.perf_counter() - t0, 3)
        row["status"] = "ok"
        row["seconds"] = round(row["prepare_seconds"] + row["merge_seconds"], 3)
        row["outputs"] = [str(p) for p in targets + [plan.folder / SESSION_RECORD]]
        write(staged, plan.folder / SESSION_RECORD, lambda t: _write_json(t, row))
    return staged.written


def _refuse_unusable(model, options: BatchOptions) -> None:
    """As the CLI: a model whose verdict is ``unusable`` is not used without force."""
    if model.diagnostics.get("verdict") == "unusable" and not options.force:
        reasons = "; ".join(model.diagnostics.get("verdict_reasons") or []) or "no reason"
        raise CalibrationError(f"the session's calibration is unusable: {reasons} "
                               "(--force uses it anyway)")


def _round(x):
    return None if x is None or not math.isfinite(x) else round(float(x), 4)


def _failed(row: dict, error: str, t0: float, warnings) -> dict:
    row.update(status="failed", error=error, warnings=list(dict.fromkeys(warnings)),
               seconds=round(row.get("prepare_seconds", 0.0) + time.perf_counter() - t0, 3))
    return row


def plan_row(plan: SessionPlan) -> dict:
    """The manifest fields a session's plan gives (EXIF facts, files)."""
    return {"session": plan.id, "status": "", "error": "", "camera": plan.camera,
            "camera_label": plan.camera_label, "lens": plan.lens, "start": plan.start,
            "n_frames": len(plan.frames), "frames": list(plan.frames),
            "raws": list(plan.raws), "exposure_times": list(plan.exposure_times),
            "exposure_bias": list(plan.exposure_bias), "iso": list(plan.iso),
            "f_number": list(plan.f_number), "model_kind": "", "model_file": "",
            "model_reason": "", "verdict": None, "pooled": False, "flagged": False,
            "agreement_shared": None, "agreement_own": None, "outputs": [], "warnings": [],
            "unmeasured_fraction": None, "prepare_seconds": None, "merge_seconds": None,
            "seconds": None, "worker": "", "prepare_worker": "",
            "grouping_unsure": plan.grouping_unsure, "grouping": list(plan.grouping)}


# ------------------------------------------------------------------------ rerun

def _newest_input(plan: SessionPlan) -> float:
    return max(os.stat(p).st_mtime for p in (*plan.frames, *plan.raws))


def finished_row(plan: SessionPlan, options: BatchOptions, camera_model: str = "") -> dict | None:
    """The row of an earlier run when the session need not run again, else None.

    Finished means: ``session.json`` says ``ok`` for the same frames and the same
    ``--linearize`` choice, every output it lists exists, and the oldest output is newer
    than the newest frame or raw -- and than the camera model, when it used one.
    """
    record = plan.folder / SESSION_RECORD
    try:
        row = json.loads(record.read_text())
        if row.get("status") != "ok" or tuple(row.get("frames", ())) != plan.frames:
            return None
        if bool(row.get("linearize")) != options.linearize:
            return None
        oldest = min(os.stat(p).st_mtime for p in row["outputs"])
        newest = _newest_input(plan)
        if row.get("model_kind") == "camera":
            if row.get("model_file") != camera_model:
                return None
            newest = max(newest, os.stat(camera_model).st_mtime)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return row if oldest > newest else None


# ------------------------------------------------------------------------ manifest

def _write_json(path, obj) -> Path:
    Path(path).write_text(json.dumps(jsonable(obj), indent=1, allow_nan=False, default=str))
    return Path(path)


def _cell(v):
    if isinstance(v, (list, tuple)):
        return ";".join("" if x is None else str(x) for x in v)
    return "" if v is None else v


def _csv_text(rows, columns) -> str:
    buf = _io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({k: _cell(r.get(k)) for k in columns})
    return buf.getvalue()


def camera_rows(cameras: dict, fits: dict, rows, raw_fits: dict | None = None) -> list:
    """The per-camera summary: sessions, pooled, flagged, failed, model, fit time; the
    RAW-path model and its leave-one-scene-out errors (:func:`.raw_camera.raw_camera_columns`)."""
    by_camera: dict = {}
    for r in rows:
        by_camera.setdefault(r["camera"], []).append(r)
    out, raw_fits = [], raw_fits or {}
    for cam in sorted(set(by_camera) | set(raw_fits)):    # RAW+JPEG shots only: no session
        rs = by_camera.get(cam, [])
        fit = fits.get(cam)
        out.append({
            "camera": cam,
            "camera_label": rs[0]["camera_label"] if rs else raw_fits[cam].label,
            "lenses": sorted({r["lens"] for r in rs if r["lens"]}),
            "sessions": len(rs), "ok": sum(r["status"] == "ok" for r in rs),
            "skipped": sum(r["status"] == "skipped" for r in rs),
            "failed": sum(r["status"] == "failed" for r in rs),
            "pooled_fit": cam in cameras,
            "model_file": fit.model_path if fit else "",
            "pooled_sessions": list(fit.pooled) if fit else [],
            "flagged_sessions": sorted({r["session"] for r in rs if r.get("flagged")}),
            "alone_sessions": sum(r.get("model_kind") == "own" for r in rs),
            "residual_rms_log": fit.residual_rms_log if fit else None,
            "fit_error": fit.error if fit else "",
            "fit_seconds": round(fit.seconds, 3) if fit else None,
            "fit_reused": bool(fit and fit.reused),
            **raw_camera_columns(raw_fits.get(cam))})
    return out


MANIFEST_COLUMNS = ["session", "status", "error", "camera", "camera_label", "lens", "start",
                    "n_frames", "frames", "raws", "exposure_times", "exposure_bias", "iso",
                    "f_number", "model_kind", "model_file", "model_reason", "verdict",
                    "pooled", "flagged", "agreement_shared", "agreement_own", "outputs",
                    "warnings", "unmeasured_fraction", "prepare_seconds", "merge_seconds",
                    "seconds", "worker", "grouping_unsure", "grouping"]
CAMERA_COLUMNS = ["camera", "camera_label", "lenses", "sessions", "ok", "skipped", "failed",
                  "pooled_fit", "model_file", "pooled_sessions", "flagged_sessions",
                  "alone_sessions", "residual_rms_log", "fit_error", "fit_seconds",
                  "fit_reused", *RAW_COLUMNS, "plot"]


def write_manifest(out_dir, rows, cameras, unassigned, *, inputs=()) -> list:
    """Write the manifest (JSON Lines and CSV), the camera summary, a plot per camera
    (:mod:`.camera_plot`) and the unassigned files, together
    (:class:`selfcal.io.StagedOutputs`); returns the paths written.

    JSON Lines keeps lists as lists (``pandas.read_json(path, lines=True)`` reads it);
    the CSV joins them with ``;`` for spreadsheets.
    """
    from ..io.images import StagedOutputs

    out_dir = Path(out_dir)
    rows = sorted(rows, key=lambda r: r["session"])

    def lines(items):
        return "".join(json.dumps(jsonable(r), allow_nan=False, default=str) + "\n"
                       for r in items)

    files = {
        MANIFEST: lines(rows), MANIFEST_CSV: _csv_text(rows, MANIFEST_COLUMNS),
        CAMERAS: lines(cameras), CAMERAS_CSV: _csv_text(cameras, CAMERA_COLUMNS),
        UNASSIGNED_CSV: _csv_text([{"path": str(p), "reason": why} for p, why in unassigned],
                                  ["path", "reason"]),
    }
    plots = camera_plot_writers(out_dir, cameras, rows)     # sets cameras' "plot"
    files[CAMERAS] = lines(cameras)
    files[CAMERAS_CSV] = _csv_text(cameras, CAMERA_COLUMNS)
    with StagedOutputs(force=True, inputs=inputs) as staged:
        for name, text in files.items():
            staged.write(out_dir / name, lambda t, text=text: Path(t).write_text(text))
        for path, writer in plots.items():
            staged.write(path, writer)
    return staged.written
