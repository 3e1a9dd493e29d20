"""Versioned JSON model files: the envelope and the JSON helpers both model kinds use.

Every model file is a JSON object ``{"format": "selfcal-model", "version": 1, "kind": ...}``
plus the fields of its kind.  Loading validates the envelope and the content, and raises
:class:`selfcal.errors.ModelFileError` naming the file on anything wrong.  This module
sits below both paths' models (which use it to write their files); :func:`selfcal.load_model`,
which dispatches to them, is in :mod:`selfcal.models` above them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .errors import ModelFileError
from .io import write_bytes_atomic

FORMAT = "selfcal-model"
VERSION = 1


def jsonable(obj):
    """Plain JSON types: numpy scalars and arrays converted, non-finite floats -> None."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def save_model_dict(path, content: dict, *, force: bool = False) -> Path:
    """Write ``content`` (which carries its ``kind``) in the versioned envelope, atomically."""
    doc = {"format": FORMAT, "version": VERSION, **content}
    data = json.dumps(doc, indent=1, allow_nan=False).encode()
    return write_bytes_atomic(path, data, force=force)


def read_model_dict(path) -> dict:
    """Read and check the envelope of a model file; return the parsed object."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ModelFileError("no such model file", path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ModelFileError(f"cannot be read as a model file ({exc})", path) from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"not valid JSON (line {exc.lineno}: {exc.msg})", path) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelFileError("not a selfcal model file (no 'format: selfcal-model')", path)
    version = doc.get("version")
    if not isinstance(version, int) or version > VERSION or version < 1:
        raise ModelFileError(
            f"model file version {version!r} is not supported (this selfcal reads "
            f"version {VERSION}); upgrade selfcal", path)
    return doc
