"""Loading a model file of either path.

:func:`load_model` reads the versioned envelope (:mod:`selfcal.modelfile`) and hands the
content to the model class of its ``kind``: :class:`selfcal.response.ResponseModel` (the
JPEG-only path) or :class:`selfcal.pipeline.PipelineModel` (the RAW path).  It lives above
both paths so that neither model imports the other's room, and the low-level JSON helpers
in :mod:`selfcal.modelfile` stay below them.
"""

from __future__ import annotations

from .errors import ModelFileError
from .modelfile import read_model_dict
from .pipeline.model import PipelineModel
from .response.model import ResponseModel

__all__ = ["load_model"]


def load_model(path):
    """Load a model file written by selfcal.

    Returns
    -------
    ResponseModel or PipelineModel
        ``kind == "response"``: the JPEG-only path's model; ``kind == "pipeline"``: the
        RAW path's camera pipeline (:class:`selfcal.pipeline.PipelineModel`).

    Raises
    ------
    ModelFileError
        Missing file, bad JSON, wrong format or version, or invalid content.
    """
    doc = read_model_dict(path)
    kind = doc.get("kind")
    if kind == "response":
        return ResponseModel.from_dict(doc, path=path)
    if kind == "pipeline":
        return PipelineModel.from_dict(doc, path=path)
    raise ModelFileError(f"unknown model kind {kind!r}", path)
