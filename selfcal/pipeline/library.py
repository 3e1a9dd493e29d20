"""One RAW-path model from many scenes' RAW+JPEG pairs, judged by leave-one-scene-out.

A camera that saves RAW+JPEG leaves hundreds of pairs on a card.  One pair fits the
pipeline of [Gong2018] §3 (with the RBF ``h⁻¹`` of [Lin2011] §6) well on its own scene and
worse on others (its colours cover a part of the gamut; its curves are pinned where that
scene had samples).  :func:`fit_pipeline_library` fits one model to the pairs of many
scenes and measures it the way it is used: on scenes it was not fitted on.

What is the papers' and what is ours:

* the model and its fit are :func:`selfcal.pipeline.fit_pipeline` ([Gong2018] §3.2-3.5,
  [Lin2011] Eq. 10-11), with the scenes as ``groups`` (its LUT weights, inverse-curve λ
  and RBF smoothing chosen by leave-one-scene-out);
* ours: the samples of every scene are subsampled to the same number (scenes weigh
  equally, however many pairs or valid blocks each has, and memory is bounded);
* ours: λ of Eq. 9 of [Gong2018] (the forward tone curves' smoothness, the one weight
  ``fit_pipeline`` does not choose itself) is chosen from a small grid
  (:data:`SMOOTHNESS_GRID`, tuned on simulated cards: ``docs/decisions.md``, "RAW+JPEG
  libraries") by the mean leave-one-scene-out forward error;
* ours: the leave-one-scene-out forward (0-255) and backward (raw) errors of each scene,
  and the training-scene errors of the final model, are kept as data
  (:class:`LibraryFit`).  With more scenes than ``max_folds`` the scenes are dealt into
  ``max_folds`` folds (scene ``k`` to fold ``k mod max_folds``): leave-one-fold-out, each
  scene still scored by a model that did not see it.

Citation keys are those of ``docs/references.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from ..errors import CalibrationError, InputError
from ..typing import Progress
from .fit import PipelineOptions, fit_pipeline
from .model import PipelineModel
from .pairs import PairSamples

__all__ = ["LibraryOptions", "LibraryFit", "SceneErrors", "fit_pipeline_library",
           "SMOOTHNESS_GRID", "pair_sample_errors"]

#: λ of the forward tone curves ([Gong2018] Eq. 9) tried by leave-one-scene-out (tuned on
#: simulated cards, seeds < 1000: docs/decisions.md, "RAW+JPEG libraries").
SMOOTHNESS_GRID = (1e-5, 1e-3)
#: Samples drawn from each scene (all pairs of the scene together).
SCENE_SAMPLES = 2000
#: Folds of the leave-one-scene-out at most (more scenes share folds).
MAX_FOLDS = 10


@dataclass(frozen=True)
class LibraryOptions:
    """The knobs of :func:`fit_pipeline_library`.

    Attributes
    ----------
    smoothness_grid : tuple of float
        λ candidates of the forward tone curves ([Gong2018] Eq. 9), chosen by the mean
        leave-one-scene-out forward error (ties: the first).
    scene_samples : int
        Samples drawn from each scene (seeded); fewer when a scene has fewer.
    max_folds : int
        Folds of the leave-one-scene-out at most (see the module notes).
    pipeline : PipelineOptions
        The options of every :func:`~selfcal.pipeline.fit_pipeline` call, ``smoothness``
        excepted (the grid sets it).  Default: 8 matrix sets and the LUT backward model
        (ours, for speed: the RBF fit takes ~10 s per fit against ~1 s for the LUT, and
        the fold fits multiply it; ``backward="auto"`` lets the final fit choose by
        leave-one-scene-out, and the fold fits then use it too, so the reported backward
        errors describe the model written).

    Raises
    ------
    InputError
        An empty grid, a non-positive λ, ``scene_samples < 30`` or ``max_folds < 2``.
    """

    smoothness_grid: tuple = SMOOTHNESS_GRID
    scene_samples: int = SCENE_SAMPLES
    max_folds: int = MAX_FOLDS
    pipeline: PipelineOptions = field(
        default_factory=lambda: PipelineOptions(n_sets=8, backward="lut"))

    def __post_init__(self):
        grid = tuple(float(v) for v in self.smoothness_grid)
        if not grid or min(grid) <= 0:
            raise InputError(f"smoothness_grid must hold positive values, got {grid}")
        if int(self.scene_samples) < 30 or int(self.max_folds) < 2:
            raise InputError("scene_samples must be >= 30 and max_folds >= 2")
        if not isinstance(self.pipeline, PipelineOptions):
            raise InputError("pipeline must be a PipelineOptions")


@dataclass(frozen=True)
class SceneErrors:
    """One scene's errors (RMSE over its samples).

    Attributes
    ----------
    scene : str
    samples : int
        Samples of the scene used.
    loso_forward, training_forward : float
        Raw -> rendered, 0-255 codes: by the model fitted without the scene's fold, and by
        the final model (fitted on it).
    loso_backward, training_backward : float
        Rendered -> raw, raw in ``[0, 1]``, the same two ways.
    """

    scene: str
    samples: int
    loso_forward: float
    loso_backward: float
    training_forward: float
    training_backward: float


@dataclass
class LibraryFit:
    """What :func:`fit_pipeline_library` found.

    Attributes
    ----------
    model : PipelineModel
        Fitted on every scene with the chosen λ.
    smoothness : float
        The chosen λ.
    candidates : dict
        λ → mean leave-one-scene-out forward error (0-255).
    scenes : list of SceneErrors
    folds : int
    loso_forward, loso_backward, training_forward, training_backward : float
        Means over the scenes (each scene weighs the same).
    fold_of : dict
        Scene → its fold.
    fold_models : dict
        Fold → the model fitted without it at the chosen λ (with ``keep_fold_models``;
        else empty): to score held-out scenes on more than their samples.
    """

    model: PipelineModel
    smoothness: float
    candidates: dict
    scenes: list
    folds: int
    loso_forward: float = float("nan")
    loso_backward: float = float("nan")
    training_forward: float = float("nan")
    training_backward: float = float("nan")
    fold_of: dict = field(default_factory=dict)
    fold_models: dict = field(default_factory=dict)

    def __post_init__(self):
        for name in ("loso_forward", "loso_backward", "training_forward",
                     "training_backward"):
            setattr(self, name, float(np.mean([getattr(s, name) for s in self.scenes])))

    def summary(self) -> dict:
        """The figures as plain data (no model): for a manifest or a record."""
        return {"smoothness": self.smoothness,
                "candidates": {repr(k): v for k, v in self.candidates.items()},
                "folds": self.folds, "loso_forward": self.loso_forward,
                "loso_backward": self.loso_backward,
                "training_forward": self.training_forward,
                "training_backward": self.training_backward,
                "scenes": [asdict(s) for s in self.scenes]}


def pair_sample_errors(model, samples: PairSamples) -> tuple[float, float]:
    """Forward RMSE (0-255) and backward RMSE (raw) of ``model`` on block-mean samples.

    Forward: ``model.render(raw)`` against the rendered block means ([Gong2018] §4's
    error, on the 0-255 scale).  Backward: ``model.to_raw(rendered)`` against the raw
    block means, over samples with no rendered channel within half a code of 0 or 255
    (a clipped code does not determine its raw, [Lin2011] §5).
    """
    fwd = np.asarray(model.render(samples.raw), dtype=np.float64).reshape(-1, 3)
    f_err = float(np.sqrt(np.mean((fwd - samples.rendered) ** 2))) * 255.0
    codes = samples.rendered
    ok = ~((codes <= 0.5 / 255) | (codes >= 254.5 / 255)).any(axis=1)
    if not ok.any():
        return f_err, float("nan")
    back = np.asarray(model.to_raw(codes[ok]), dtype=np.float64).reshape(-1, 3)
    return f_err, float(np.sqrt(np.mean((back - samples.raw[ok]) ** 2)))


def _subsample(samples: PairSamples, n: int, seed) -> PairSamples:
    """At most ``n`` of ``samples``, drawn without replacement (seeded), order kept."""
    if len(samples) <= n:
        return samples
    pick = np.sort(np.random.default_rng(seed).choice(len(samples), n, replace=False))
    return PairSamples(samples.raw[pick], samples.rendered[pick], dict(samples.counts),
                       samples.block, samples.positions[pick], samples.gradient_threshold)


def _fit(parts: list, smoothness: float, options: LibraryOptions, seed: int):
    """``fit_pipeline`` on the joined scenes ``parts`` (each its own group)."""
    joined = PairSamples.concatenate(parts)
    return fit_pipeline(joined.raw, joined.rendered,
                        replace(options.pipeline, smoothness=float(smoothness)), seed=seed,
                        groups=joined.groups if len(parts) > 1 else None)


def fit_pipeline_library(scenes: Mapping[str, PairSamples] | Sequence[PairSamples],
                         options: LibraryOptions | None = None, *, seed: int = 0,
                         keep_fold_models: bool = False,
                         progress: Progress | None = None) -> LibraryFit:
    """Fit one RAW-path model to many scenes' pairs; λ and errors by leave-one-scene-out.

    :func:`selfcal.pipeline.fit_pipeline` ([Gong2018] §3.2-3.5 with [Lin2011] Eq. 10-11)
    on every scene's samples, the scenes as groups; what is ours is said in the module
    notes: equal samples per scene, λ of [Gong2018] Eq. 9 chosen from
    ``options.smoothness_grid`` by the mean leave-one-scene-out forward error, and each
    scene's leave-one-scene-out and training errors (:func:`pair_sample_errors`).

    Parameters
    ----------
    scenes : mapping of str to PairSamples, or sequence of PairSamples
        Each scene's block-mean samples (all its pairs joined:
        :func:`selfcal.pipeline.pairs.collect_pair_samples`); a sequence is named
        ``scene 0``, ``scene 1``, ...
    options : LibraryOptions, optional
    seed : int
        Seeds the subsampling and every fit (the same input gives the same model).
    keep_fold_models : bool
        Keep the fold models of the chosen λ (:attr:`LibraryFit.fold_models`).
    progress : callable, optional
        ``progress("library", done, total, detail)`` after each fit.

    Returns
    -------
    LibraryFit

    Raises
    ------
    InputError
        Fewer than two scenes.
    CalibrationError
        A scene with fewer than 30 samples, or a fit that cannot be solved.

    Examples
    --------
    >>> from selfcal import sim
    >>> from selfcal.pipeline.pairs import collect_pair_samples
    >>> cam = sim.default_pipeline(seed=1)
    >>> pairs = [sim.simulate_raw_jpeg_pair(seed=s, pipeline=cam) for s in range(3)]
    >>> scenes = [collect_pair_samples([p["raw"]], [p["rendered"]])[0] for p in pairs]
    >>> fit = fit_pipeline_library(scenes, LibraryOptions(smoothness_grid=(1e-5,), scene_samples=300))
    >>> fit.loso_forward < 6 and fit.folds == 3
    True
    """
    options = LibraryOptions() if options is None else options
    named = (dict(scenes) if isinstance(scenes, Mapping)
             else {f"scene {k}": s for k, s in enumerate(scenes)})
    if len(named) < 2:
        raise InputError(f"a library fit needs the pairs of two scenes or more, got "
                         f"{len(named)}")
    seeds = np.random.SeedSequence(seed).generate_state(len(named))
    names = list(named)
    parts = []
    for k, name in enumerate(names):
        if len(named[name]) < 30:
            raise CalibrationError(f"scene {name!r} has {len(named[name])} samples; a "
                                   "library fit needs 30 or more per scene")
        parts.append(_subsample(named[name], int(options.scene_samples), int(seeds[k])))
    n_folds = min(len(parts), int(options.max_folds))
    fold_of = np.arange(len(parts)) % n_folds
    grid = tuple(float(v) for v in options.smoothness_grid)
    total, done = len(grid) * n_folds + 1, 0
    held: dict = {}           # λ -> per scene (forward, backward)
    fold_models: dict = {}    # (λ, fold) -> model, with keep_fold_models
    for lam in grid:
        errs: list = [None] * len(parts)
        for f in range(n_folds):
            model = _fit([p for p, g in zip(parts, fold_of) if g != f], lam, options, seed)
            for k in np.flatnonzero(fold_of == f).tolist():
                errs[k] = pair_sample_errors(model, parts[k])
            if keep_fold_models:
                fold_models[(lam, f)] = model
            done += 1
            if progress is not None:
                progress("library", done, total, f"λ={lam:g}, fold {f + 1}/{n_folds}")
        held[lam] = errs
    candidates = {lam: float(np.mean([e[0] for e in held[lam]])) for lam in grid}
    best = min(grid, key=lambda lam: (candidates[lam], grid.index(lam)))
    model = _fit(parts, best, options, seed)
    if progress is not None:
        progress("library", total, total, f"final fit, λ={best:g}")
    rows = []
    for k, name in enumerate(names):
        train = pair_sample_errors(model, parts[k])
        rows.append(SceneErrors(scene=name, samples=len(parts[k]),
                                loso_forward=held[best][k][0],
                                loso_backward=held[best][k][1],
                                training_forward=train[0], training_backward=train[1]))
    model.diagnostics["library"] = {"smoothness": best, "folds": n_folds,
                                    "scenes": names,
                                    "candidates": [[lam, candidates[lam]] for lam in grid]}
    return LibraryFit(model=model, smoothness=best, candidates=candidates, scenes=rows,
                      folds=n_folds, fold_of=dict(zip(names, fold_of.tolist())),
                      fold_models={f: m for (lam, f), m in fold_models.items()
                                   if lam == best})
