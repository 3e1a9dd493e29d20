"""Loading a model file of either path.

:func:`load_model` reads the versioned envelope (:mod:`selfcal.modelfile`), checks the
content of its ``kind`` (:func:`selfcal.modelfile.check_response_content`,
:func:`~selfcal.modelfile.check_pipeline_content`) and hands it to the model class of that
kind: :class:`selfcal.response.ResponseModel` (the JPEG-only path) or
:class:`selfcal.pipeline.PipelineModel` (the RAW path).  It lives above both paths so that
neither model imports the other's room, and the low-level JSON helpers in
:mod:`selfcal.modelfile` stay below them.
"""

from __future__ import annotations

import numpy as np

from .errors import ModelFileError, SelfcalError
from .modelfile import check_pipeline_content, check_response_content, read_model_dict
from .pipeline.model import PipelineModel
from .response.model import ResponseModel

__all__ = ["load_model"]

#: kind -> (content check, model class)
_KINDS = {"response": (check_response_content, ResponseModel),
          "pipeline": (check_pipeline_content, PipelineModel)}


def load_model(path):
    """Load a model file written by selfcal.

    The envelope and every field of the content are checked before the model is built,
    so that a model that loads can be used.

    Returns
    -------
    ResponseModel or PipelineModel
        ``kind == "response"``: the JPEG-only path's model; ``kind == "pipeline"``: the
        RAW path's camera pipeline (:class:`selfcal.pipeline.PipelineModel`).

    Raises
    ------
    ModelFileError
        Missing file, bad JSON, wrong format or version, or invalid content; the message
        names the file and what is wrong.
    """
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
