"""Running a batch: the task graph on Dask distributed (or in process), and the driver.

:func:`run_batch` discovers the sessions (:mod:`.discover`), plans them (:mod:`.run`),
skips those finished by an earlier run, and submits three kinds of task to a Dask
cluster -- a :class:`distributed.LocalCluster` by default (one single-threaded worker
process per core, each with its memory limit), or the scheduler at ``scheduler``:

``prepare-<session>``
    Every session to do: its own calibration and its pool samples
    (:func:`.run.prepare_session`).  Tasks get paths; the worker reads the frames.
``camera-<camera>``
    Once the candidate sessions of a camera are prepared: the pooled fit
    (:func:`.run.fit_camera`), which depends on their ``prepare`` futures; their results
    (a model and ~100 kB of samples each) move worker to worker, never through the
    scheduler or this process.
``finish-<session>``
    The merge and outputs (:func:`.run.finish_session`), depending on the session's
    ``prepare`` future and its camera's fit.
``raw-<camera>``
    A camera with RAW+JPEG pairs in two scenes or more: its RAW-path model
    (:func:`.raw_camera.fit_raw_camera`), depending on no other task; it reads its pairs.

Priorities order the work: the pool candidates' preparation first (so that the camera
fits start early), then the camera fits, then merges before further preparation (so that
prepared sessions do not pile up in memory).  A task never raises for a bad session (it
returns the error); a task lost with its worker (killed for memory, say) fails its session
only, and the driver records why.  ``scheduler="serial"`` runs the same tasks in this
process, one after the other (the benchmark's serial loop).
"""

from __future__ import annotations

import logging
import os
import uuid
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType

from ..errors import OutputExistsError, SelfcalError
from ..typing import PathLike, Progress
from .discover import DEFAULT_MAX_GAP, discover
from .faults import Journal, interrupted_rows, sweep_partial
from .raw_camera import (fit_raw_camera, lost_raw_fit, plan_raw_cameras,
                         reusable_raw_camera_fit)
from .run import (MANIFEST, BatchOptions, camera_rows, finish_session, finished_row,
                  fit_camera, plan_batch, plan_row, prepare_session, reusable_camera_fit,
                  write_manifest)

DASK_MISSING = ('selfcal batch runs on Dask distributed, which is not installed: '
                'pip install "selfcal[batch]"')

#: How long to try reaching a scheduler given by its address (``ClusterOptions``' default).
CONNECT_TIMEOUT = "20s"
#: The Dask setting unset for the local cluster's workers (see DaskExecutor).
NO_MALLOC_TRIM = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"

#: Sessions under way at most (prepared or being prepared, not finished): bounds the
#: tasks the scheduler and the driver hold (10⁴ submitted at once starved a loaded
#: scheduler's connection to the driver in ``python3 -m bench.batch_scale``); the default
#: of ``ClusterOptions.max_in_flight``.
MAX_IN_FLIGHT = 1000

# task priorities (higher first)
_PRIORITY = {"candidate": 30, "camera": 40, "raw": 25, "finish": 20, "prepare": 10}


class ClusterError(SelfcalError):
    """Dask is missing, or the cluster cannot be reached or started (the message says
    which and what to do)."""


def require_dask() -> ModuleType:
    """The ``distributed`` module, or :class:`ClusterError` saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise ClusterError(DASK_MISSING) from None
    return distributed


# ------------------------------------------------------------------------ executors

class _Thunk:
    """A deferred call of the serial executor, with the face of a Dask future."""

    def __init__(self, fn, args):
        self.fn, self.args = fn, args
        self.status, self.value = "pending", None
        self.exc: Exception | None = None

    def run(self):
        if self.status == "pending":
            try:
                args = [a.result() if isinstance(a, _Thunk) else a for a in self.args]
                self.value, self.status = self.fn(*args), "finished"
            except Exception as exc:
                self.exc, self.status = exc, "error"
            self.fn = self.args = None
        return self

    def result(self):
        self.run()
        if self.status == "error":
            assert self.exc is not None     # the status says it was kept
            raise self.exc
        return self.value


class _SerialCompleted:
    """``as_completed`` of the serial executor: runs each call when its turn comes."""

    def __init__(self, futures):
        self.queue = deque(futures)

    def add(self, future):
        self.queue.append(future)

    def __iter__(self):
        while self.queue:
            yield self.queue.popleft().run()


class SerialExecutor:
    """The tasks in this process, in submission order (no Dask needed)."""

    name = "serial"

    def submit(self, fn, *args, key="", priority=0):
        return _Thunk(fn, args)

    def as_completed(self, futures):
        return _SerialCompleted(futures)

    def close(self):
        pass

    def worker_memory(self):
        return {}


class DaskExecutor:
    """The tasks on a Dask cluster: a given client, the scheduler at ``scheduler``, or a
    new :class:`distributed.LocalCluster` of ``workers`` single-threaded processes."""

    def __init__(self, *, scheduler=None, workers=None, memory_limit="auto",
                 processes=True, client=None, connect_timeout=CONNECT_TIMEOUT):
        distributed = require_dask()
        self._distributed = distributed
        self._own = []
        if client is not None:
            self.client = client
        elif scheduler:
            try:
                self.client = distributed.Client(scheduler, timeout=connect_timeout)
            except (OSError, TimeoutError) as exc:
                raise ClusterError(f"cannot reach the Dask scheduler at {scheduler} "
                                   f"({exc})") from None
            except (ValueError, TypeError) as exc:
                raise ClusterError(f"{scheduler!r} is not a Dask scheduler address "
                                   f"({exc}); give one like tcp://host:8786") from None
            self._own.append(self.client)
        else:
            import dask

            n = int(workers or os.cpu_count() or 1)
            # Dask's nannies export MALLOC_TRIM_THRESHOLD_=65536 to their workers, which
            # turns every large numpy allocation into an mmap/munmap round trip: the
            # calibration then spends 6-15x more system time (python3 -m bench.batch).
            before = _local_clusters(distributed)
            try:
                with dask.config.set({NO_MALLOC_TRIM: None}):
                    cluster = distributed.LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=processes,
                        memory_limit=memory_limit, dashboard_address=None,
                        silence_logs=logging.ERROR)
                self._own.append(cluster)
                self.client = distributed.Client(cluster)
                self._own.insert(0, self.client)
            except BaseException:
                # interrupted (Ctrl-C) while the cluster starts: close what started, so
                # that Dask's own clean-up at exit finds nothing half-started to trip on
                _close_quietly(self._own + list(_local_clusters(distributed) - before))
                self._own = []
                raise
        self.name = str(self.client.scheduler.address)
        self._token = uuid.uuid4().hex[:8]

    def submit(self, fn, *args, key="", priority=0):
        return self.client.submit(fn, *args, key=f"{key}-{self._token}", priority=priority,
                                  pure=False)

    def as_completed(self, futures):
        return self._distributed.as_completed(futures)

    def worker_memory(self):
        """Peak resident memory of each worker process so far (bytes; Linux ru_maxrss)."""
        def peak():
            import resource
            import sys

            rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            return rss if sys.platform == "darwin" else rss * 1024

        return self.client.run(peak)

    def close(self):
        for obj in self._own:
            obj.close()
        self._own = []


def _local_clusters(distributed) -> set:
    """The Dask clusters this process has started (Dask's own register of them)."""
    return set(getattr(distributed.SpecCluster, "_instances", ()))


def _close_quietly(objects) -> None:
    """Close clients and clusters, whatever state their start was interrupted in."""
    for obj in objects:
        try:
            obj.close()
        except Exception:       # half-started: its workers never came up
            pass


# ------------------------------------------------------------------------ the driver

@dataclass
class BatchResult:
    """What :func:`run_batch` did.

    Attributes
    ----------
    out_dir : pathlib.Path
    rows : list of dict
        One manifest row per session (``status`` ok, skipped or failed).
    cameras : list of dict
        The per-camera summary.
    unassigned : list of (pathlib.Path, str)
    files : list of pathlib.Path
        The manifest files written.
    executor : str
        ``"serial"`` or the scheduler's address.
    worker_memory : dict
        Worker → peak resident memory (bytes), for a cluster this run started.
    """

    out_dir: Path
    rows: list = field(default_factory=list)
    cameras: list = field(default_factory=list)
    unassigned: list = field(default_factory=list)
    files: list = field(default_factory=list)
    executor: str = ""
    worker_memory: dict = field(default_factory=dict)

    @property
    def failed(self) -> list:
        return [r for r in self.rows if r["status"] == "failed"]

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)


def _check_out_dir(out_dir: Path, force: bool) -> None:
    """The batch folder: missing, empty, or one a batch wrote (else refused without
    ``force``); writable."""
    from ..io.images import OutputWriteError, check_output_path

    if out_dir.exists() and not out_dir.is_dir():
        raise OutputWriteError(path=out_dir,
                               message=f"cannot be the batch folder (it is a file)")
    ours = any((out_dir / n).exists() for n in (MANIFEST, "sessions", "cameras"))
    if out_dir.is_dir() and any(out_dir.iterdir()) and not ours and not force:
        raise OutputExistsError(f"{out_dir}: exists, is not empty and holds no batch "
                                "(use --force to write into it)")
    check_output_path(out_dir / MANIFEST, force=True, create_folder=True)


@dataclass(frozen=True)
class ClusterOptions:
    """Where :func:`run_batch`'s tasks run when no scheduler address is given.

    Attributes
    ----------
    workers : int, optional
        LocalCluster workers (default: the number of cores); one thread each.
    memory_limit : str or int
        Per LocalCluster worker (Dask's ``memory_limit``: ``"auto"`` shares the machine's
        memory among the workers, ``"4GB"``, bytes, or 0 for none).
    processes : bool
        LocalCluster workers as processes (True) or threads of this process.
    client : distributed.Client, optional
        Use this client (and its cluster) instead of starting one.
    connect_timeout : str
        How long to try reaching a scheduler given by its address (Dask's ``timeout``).
    max_in_flight : int
        Sessions under way at most beyond the pool candidates (:data:`MAX_IN_FLIGHT`).
    """

    workers: int | None = None
    memory_limit: object = "auto"
    processes: bool = True
    client: object = None
    connect_timeout: str = CONNECT_TIMEOUT
    max_in_flight: int = MAX_IN_FLIGHT


def run_batch(roots: Sequence[PathLike], out_dir: PathLike, *, scheduler: str | None = None,
              cluster: ClusterOptions | None = None, options: BatchOptions | None = None,
              redo: bool = False, progress: Progress | None = None) -> BatchResult:
    """Calibrate and merge every bracketed session under ``roots``, one curve per camera.

    Parameters
    ----------
    roots : sequence of path
        Folders of frames (card dumps), walked recursively.
    out_dir : path
        The batch folder (layout in :mod:`selfcal.batch.run`); created if missing.
    scheduler : str, optional
        ``None``: a new LocalCluster (or ``cluster.client``); ``"tcp://host:port"`` or a
        scheduler file: an existing Dask scheduler; ``"serial"``: no Dask, every task in
        this process.
    cluster : ClusterOptions, optional
        The local cluster's workers and memory, or a client to use.
    options : BatchOptions, optional
        What every session does: linearised frames, pooling, ``force``, seed, how sessions
        are found (content or time gap, ``max_gap``).
    redo : bool
        Run every session again, finished or not.
    progress : callable, optional
        ``progress("sessions", done, total, session)`` after each session.

    Returns
    -------
    BatchResult
        Without rows and with no file written when no session was found.

    Raises
    ------
    ClusterError
        Dask missing (with the install command), the scheduler unreachable.
    InputError
        A root that does not exist.
    OutputExistsError, OutputWriteError
        The batch folder cannot be used.
    """
    cluster = ClusterOptions() if cluster is None else cluster
    options = BatchOptions() if options is None else options
    out_dir = Path(out_dir).resolve()
    _check_out_dir(out_dir, options.force)
    library = discover(roots, exclude=[out_dir], max_gap=options.max_gap,
                       by_content=options.by_content)
    plans, cameras = plan_batch(library, out_dir, options)
    raw = _earlier_raw_work(plans, out_dir, options, redo, library.lone_pairs)
    if not plans and not (raw[0] or raw[1]):  # nothing to do: nothing written or started
        return BatchResult(out_dir=out_dir, unassigned=library.unassigned)
    fits, rows, todo = _earlier_work(plans, cameras, options, redo)
    result = BatchResult(out_dir=out_dir, unassigned=library.unassigned)
    if progress is not None:
        progress("sessions", len(rows), len(plans), "")
    sweep_partial(out_dir)
    journal = Journal(out_dir)
    rows = _Journaled(rows, journal)
    spec = {"scheduler": scheduler, "workers": cluster.workers,
            "memory_limit": cluster.memory_limit, "processes": cluster.processes,
            "client": cluster.client, "connect_timeout": cluster.connect_timeout}
    try:
        _execute(result, spec, todo, cameras, fits, options, rows, len(plans), progress,
                 max_in_flight=cluster.max_in_flight, raw=raw)
    except KeyboardInterrupt:        # Ctrl-C, or SIGTERM as the CLI turns it
        rows += interrupted_rows(todo, rows)
        _conclude(result, list(rows), cameras, fits, plans, library, raw[1])
        journal.close(remove=True)
        raise
    journal.close()
    sweep_partial(out_dir)           # what a killed worker left half-written
    _conclude(result, list(rows), cameras, fits, plans, library, raw[1])
    journal.close(remove=True)
    return result


class _Journaled(list):
    """The rows, each also appended to the journal as it comes."""

    def __init__(self, rows, journal):
        super().__init__(rows)
        self.journal = journal

    def append(self, row):
        super().append(row)
        self.journal.add(row)


def _execute(result, cluster, todo, cameras, fits, options, rows, total, progress, *,
             max_in_flight: int = MAX_IN_FLIGHT, raw=((), {})):
    """Start the executor (when there is work), drive the tasks, close it."""
    if not todo and not raw[0]:
        return
    scheduler, client = cluster["scheduler"], cluster["client"]
    executor = (SerialExecutor() if scheduler == "serial" else DaskExecutor(**cluster))
    try:
        result.executor = executor.name
        _drive(executor, todo, cameras, fits, options, rows, total, progress,
               max_in_flight=max_in_flight, raw=raw)
        if client is None and scheduler is None:
            result.worker_memory = executor.worker_memory()
    finally:
        executor.close()


def _conclude(result, rows, cameras, fits, plans, library, raw_fits=None):
    """The sorted manifest, camera summary and unassigned list, written together."""
    result.rows = sorted(rows, key=lambda r: r["session"])
    result.cameras = camera_rows(cameras, fits, result.rows, raw_fits)
    inputs = [f for p in plans for f in p.frames]
    result.files = write_manifest(result.out_dir, result.rows, result.cameras,
                                  library.unassigned, inputs=inputs)


def _earlier_work(plans, cameras, options: BatchOptions, redo: bool):
    """Camera fits to reuse, rows of finished sessions (``skipped``), sessions to do."""
    fits, rows, todo = {}, [], []
    by_camera: dict = {}
    for p in plans:
        by_camera.setdefault(p.camera, []).append(p)
    for cam, plan in cameras.items():
        fit = None if redo else reusable_camera_fit(plan, by_camera[cam])
        if fit is not None:
            fits[cam] = fit
    for p in plans:
        refit = p.camera in cameras and p.camera not in fits
        row = None if (redo or refit) else finished_row(
            p, options, fits[p.camera].model_path if p.camera in fits else "")
        if row is None:
            todo.append(p)
        else:
            row["status"] = "skipped"
            rows.append(row)
    return fits, rows, todo


def _earlier_raw_work(plans, out_dir, options: BatchOptions, redo: bool, lone_pairs=()):
    """The RAW-path camera fits to do (:mod:`.raw_camera`) and those to reuse:
    ``(plans to do, {camera: reused fit})``."""
    raw_plans = plan_raw_cameras(plans, out_dir, options.raw_library, lone_pairs)
    reused = {} if redo else {c: f for c, p in raw_plans.items()
                              if (f := reusable_raw_camera_fit(p, options.raw_library,
                                                               options.seed)) is not None}
    return [p for c, p in raw_plans.items() if c not in reused], reused


def _drive(executor, todo, cameras, fits, options, rows, total, progress, *,
           max_in_flight: int = MAX_IN_FLIGHT, raw=((), {})):
    """Submit the tasks of the sessions to do and collect their rows as they finish.

    The pool candidates' ``prepare`` are submitted first, all of them (a camera's fit
    waits for its last candidate); beyond them, at most ``max_in_flight`` sessions
    are under way at a time (``prepare`` submitted, ``finish`` not done); each finished
    session lets the next one in, so the scheduler and this process hold a bounded
    number of tasks however large the library.  A camera's fit is submitted when the
    last of its candidates is prepared, with the ``finish`` of its sessions under way;
    a session without a fit to wait for is finished as soon as it is prepared.  The
    RAW-path fits of ``raw`` (``(plans, fits)``: :mod:`.raw_camera`) depend on no other
    task and are submitted first; their results go into its ``fits``.
    """
    by_id = {p.id: p for p in todo}
    waiting = {cam: {p.id for p in todo if p.camera == cam and p.pool_candidate}
               for cam in cameras if cam not in fits}
    tags, prep_f, camera_f, finishing = {}, {}, {}, set()
    queue = deque(sorted(todo, key=lambda p: not (p.camera in waiting
                                                  and p.pool_candidate)))

    def prepare():
        p = queue.popleft()
        kind = "candidate" if p.camera in waiting and p.pool_candidate else "prepare"
        fut = executor.submit(prepare_session, p, options, key=f"prepare-{p.id}",
                              priority=_PRIORITY[kind])
        prep_f[p.id] = fut
        tags[fut] = ("prepare", p.id)
        return fut

    raw_plans, raw_fits = {p.camera: p for p in raw[0]}, raw[1]
    raw_f = [executor.submit(fit_raw_camera, p, options.raw_library, options.seed,
                             key=f"raw-{cam}", priority=_PRIORITY["raw"])
             for cam, p in raw_plans.items()]
    tags.update({f: ("raw", cam) for f, cam in zip(raw_f, raw_plans)})
    n_candidates = sum(p.camera in waiting and p.pool_candidate for p in queue)
    first = min(len(queue), n_candidates + max_in_flight)   # every candidate at once:
    completed = executor.as_completed(raw_f + [prepare() for _ in range(first)])

    def finish(p, camera):
        finishing.add(p.id)
        fut = executor.submit(finish_session, p, options, prep_f[p.id], camera,
                              key=f"finish-{p.id}", priority=_PRIORITY["finish"])
        tags[fut] = ("finish", p.id)
        completed.add(fut)

    for fut in completed:
        kind, name = tags.pop(fut)
        if kind == "prepare":
            cam = by_id[name].camera
            if cam in waiting:
                waiting[cam].discard(name)
                if not waiting[cam]:
                    del waiting[cam]
                    camera_f[cam] = _submit_camera(executor, cam, cameras[cam], todo,
                                                   prep_f, options, tags, completed)
                    for q in todo:
                        if q.camera == cam and q.id in prep_f and q.id not in finishing:
                            finish(q, camera_f[cam])
            elif name not in finishing:
                finish(by_id[name], camera_f.get(cam, fits.get(cam)))
        elif kind == "camera":
            fits[name] = _result_or(fut, None) or fits.get(name)
        elif kind == "raw":
            raw_fits[name] = _result_or(fut, None) or lost_raw_fit(raw_plans[name], fut)
        else:
            rows.append(_result_or(fut, None) or _lost(by_id[name], fut))
            prep_f.pop(name)       # the scheduler may forget the preparation now
            if progress is not None:
                progress("sessions", len(rows), total, name)
            if queue:
                completed.add(prepare())


def _submit_camera(executor, cam, plan, todo, prep_f, options, tags, completed):
    """The camera's pooled fit, on the prepare futures of its candidates."""
    deps = [prep_f[p.id] for p in todo if p.camera == cam and p.pool_candidate
            and getattr(prep_f[p.id], "status", "finished") != "error"]
    fut = executor.submit(fit_camera, plan, options, *deps, key=f"camera-{cam}",
                          priority=_PRIORITY["camera"])
    tags[fut] = ("camera", cam)
    completed.add(fut)
    return fut


def _result_or(fut, default):
    try:
        return fut.result()
    except Exception:
        return default


def _lost(plan, fut) -> dict:
    """The row of a session whose task was lost (its worker died, say)."""
    try:
        fut.result()
        why = "no result"
    except Exception as exc:
        why = f"{type(exc).__name__}: {exc}"
    row = plan_row(plan)
    row.update(status="failed", error=f"the task failed on the cluster ({why})")
    return row
