"""Loading a model file of either path.

:func:`load_model` reads the versioned envelope (:mod:`selfcal.io.model_file`), checks the
content of its ``kind`` (:func:`selfcal.io.model_file.check_response_content`,
:func:`~selfcal.io.model_file.check_pipeline_content`) and hands it to the model class of that
kind: :class:`selfcal.response.model.ResponseModel` (the JPEG-only path) or
:class:`selfcal.pipeline.PipelineModel` (the RAW path).  A folder of NUS in-camera model
files (Kim et al. PAMI 2012, :mod:`selfcal.pipeline.nus`) loads as a pipeline model too
(:class:`selfcal.pipeline.nus.NUSPipelineModel`, baked into dense tables).  It lives
above both paths so that neither model imports the other's room, and the low-level JSON
helpers in :mod:`selfcal.io.model_file` stay below them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..errors import ModelFileError, SelfcalError
from ..typing import PathLike
from ..io.model_file import check_pipeline_content, check_response_content, read_model_dict
from ..pipeline.model import PipelineModel
from ..pipeline.nus import is_nus_model_folder, load_nus_pipeline
from ..response.model import ResponseModel

__all__ = ["load_model"]

#: kind -> (content check, model class)
_KINDS: dict[str, tuple[Callable[..., None], type[ResponseModel] | type[PipelineModel]]] = {
    "response": (check_response_content, ResponseModel),
    "pipeline": (check_pipeline_content, PipelineModel)}


def load_model(path: PathLike) -> ResponseModel | PipelineModel:
    """Load a model file written by selfcal, or an NUS model folder.

    The envelope and every field of the content are checked before the model is built,
    so that a model that loads can be used.  A folder holding NUS in-camera model files
    (``raw2jpg_*.txt`` and ``jpg2raw_*.txt``, e.g. ``nus_model_nikon_d7000``) loads with
    the white-balance setting 14 (fluorescent, as
    :func:`selfcal.pipeline.nus.read_nus_model`); its RBF maps are baked into dense tables
    the first time each direction is used (seconds; then as fast as a fitted model).

    Returns
    -------
    ResponseModel or PipelineModel
        ``kind == "response"``: the JPEG-only path's model; ``kind == "pipeline"``: the
        RAW path's camera pipeline (:class:`selfcal.pipeline.PipelineModel`); an NUS
        folder: :class:`selfcal.pipeline.nus.NUSPipelineModel` (a PipelineModel).

    Raises
    ------
    ModelFileError
        Missing file, bad JSON, wrong format or version, or invalid content; the message
        names the file and what is wrong; a folder that is not an NUS model folder.
    InputError
        An NUS model folder with missing or malformed files.
    """
    if Path(path).is_dir():
        if not is_nus_model_folder(path):
            raise ModelFileError("is a folder, not a model file (a folder loads as a model "
                                 "only when it holds NUS model files, *_ctrlPoints.txt)",
                                 path)
        return load_nus_pipeline(path)
    doc = read_model_dict(path)
    kind = doc.get("kind")
    if not isinstance(kind, str) or kind not in _KINDS:
        shown = repr(kind) if isinstance(kind, str) and len(kind) <= 40 else "(not a name)"
        raise ModelFileError(f"unknown model kind {shown} (selfcal writes 'response' and "
                             "'pipeline')", path)
    check, cls = _KINDS[kind]
    check(doc, path)
    try:
        return cls.from_dict(doc, path=path)
    except SelfcalError:
        raise
    except (ArithmeticError, AttributeError, IndexError, KeyError, TypeError, ValueError,
            np.linalg.LinAlgError) as exc:
        # a content the checks above let through and the model's loader cannot use: the
        # checks lack a case (a bug, named as such), but the caller still gets the file
        raise ModelFileError(f"{kind} model cannot be loaded (unchecked content: "
                             f"{type(exc).__name__}: {exc})"[:300], path) from exc
