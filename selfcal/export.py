"""Calibrations other tools can read: ``.cube`` look-up tables (1D and 3D).

The file format is the *Cube LUT Specification* version 1.0 (Adobe, 2013), the format
DaVinci Resolve, ffmpeg (``lut1d`` / ``lut3d`` filters) and OpenColorIO (``FileTransform``)
read::

    # comments
    TITLE "text"
    LUT_1D_SIZE N   or   LUT_3D_SIZE N
    DOMAIN_MIN rmin gmin bmin
    DOMAIN_MAX rmax gmax bmax
    r g b           N (1D) or N³ (3D) rows of output values; in a 3D table the red
    ...             input index varies fastest, then green, then blue

What each direction writes (``direction``):

``"linearize"`` (a :class:`~selfcal.response.ResponseModel`)
    a 1D table, one column per channel: input ``code / max_code`` in ``[0, 1]``, output
    the linearised value ``f⁻¹`` (Lin et al. ICCV 2011 §5; ``f⁻¹(1) = 1``) -- what
    :meth:`~selfcal.response.ResponseModel.linearize` gives.  With the default size
    (``max_code + 1`` for 8-bit models) the nodes sit exactly on the codes.
``"to-raw"`` (a pipeline model)
    a 3D table: input the rendered (JPEG) value ``code / 255`` in ``[0, 1]``, output the
    linear camera raw in ``[0, 1]`` of :meth:`~selfcal.pipeline.PipelineModel.to_raw`.
``"render"`` (a pipeline model)
    a 3D table: input the linear camera raw **normalised to [0, 1]** (black level
    subtracted, divided by the white level: what ``selfcal render`` reads from a raw file
    and what :meth:`~selfcal.pipeline.PipelineModel.render` takes), output the rendered
    value in ``[0, 1]`` (× 255 for codes).

Both 3D directions write ``DOMAIN_MIN 0 0 0`` and ``DOMAIN_MAX 1 1 1`` (the values the
models take; the lines are the spec's defaults, written so that no reader has to assume
them).  A 3D table is sampled on a uniform grid of its input, so the ``render`` table is
coarse where the tone curve is steep (the darkest few grid cells of linear raw: a 33³
table is off by up to a few per cent of full scale below raw ≈ 0.1); a shaper LUT would
fix that, but neither the 3D-only ``.cube`` files ffmpeg reads nor this module write one.

Ours: the choice of what each direction's input and output mean.  The writer is ours too
(~30 lines): colour-science's ``write_LUT`` writes the same table order but omits the
DOMAIN lines for the default domain and writes in place (not atomically), and
colour-science is not a dependency of selfcal; the tests read the files back with
colour-science's ``read_LUT`` and apply the 3D tables with ffmpeg's ``lut3d``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError
from .io import atomic_output, check_output_path

__all__ = ["DIRECTIONS", "DEFAULT_3D_SIZE", "cube_table", "write_cube", "read_cube_header"]

DIRECTIONS = ("linearize", "to-raw", "render")
#: Nodes per axis of a 3D table unless asked otherwise (33 and 65 are the usual sizes).
DEFAULT_3D_SIZE = 33
#: Sizes the Cube LUT Specification 1.0 allows.
SIZE_LIMITS = {1: (2, 65536), 3: (2, 256)}


def _kind(model) -> str:
    """``"response"`` (has ``linearize``) or ``"pipeline"`` (has ``to_raw`` and ``render``)."""
    if hasattr(model, "to_raw") and hasattr(model, "render"):
        return "pipeline"
    if hasattr(model, "linearize"):
        return "response"
    raise InputError(f"cannot export a {type(model).__name__}: not a selfcal model")


def default_direction(model) -> str:
    """``"linearize"`` for a response model, ``"to-raw"`` for a pipeline model."""
    return "linearize" if _kind(model) == "response" else "to-raw"


def default_size(model, direction: str) -> int:
    """Default table size: ``max_code + 1`` for 1D (at most 4096), 33 for 3D."""
    if direction == "linearize":
        return int(min(int(getattr(model, "max_code", 255)) + 1, 4096))
    return DEFAULT_3D_SIZE


def check_export(model, direction: str | None, size: int | None) -> tuple[str, int]:
    """The direction and size an export will use, or InputError saying what is wrong.

    A response model exports only ``"linearize"``; a pipeline model only ``"to-raw"`` and
    ``"render"``.  Sizes: 2 to 65536 (1D), 2 to 256 (3D), as the Cube LUT Specification
    allows.
    """
    kind = _kind(model)
    if direction is None:
        direction = default_direction(model)
    if direction not in DIRECTIONS:
        raise InputError(f"direction must be one of {', '.join(DIRECTIONS)}, not "
                         f"{direction!r}")
    if kind == "response" and direction != "linearize":
        raise InputError(f"a response model (JPEG-only path) exports only 'linearize', not "
                         f"{direction!r}: {direction} needs a RAW-path (pipeline) model")
    if kind == "pipeline" and direction == "linearize":
        raise InputError("a pipeline model (RAW path) exports 'to-raw' or 'render', not "
                         "'linearize' (a 1D table needs a response model)")
    if size is None:
        size = default_size(model, direction)
    dims = 1 if direction == "linearize" else 3
    lo, hi = SIZE_LIMITS[dims]
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not lo <= size <= hi:
        raise InputError(f"LUT_{dims}D_SIZE must be a whole number from {lo} to {hi}, not "
                         f"{size!r}")
    return direction, int(size)


def cube_table(model, direction: str | None = None, *, size: int | None = None):
    """The rows of the ``.cube`` table of ``model`` (see the module docstring).

    Returns
    -------
    rows : numpy.ndarray
        float64 ``(size, 3)`` (1D) or ``(size³, 3)`` (3D, red varying fastest).
    direction : str
    size : int
    """
    direction, size = check_export(model, direction, size)
    x = np.linspace(0.0, 1.0, size)
    if direction == "linearize":
        rows = model.linearize(np.repeat(x[:, None], 3, axis=1))
        return np.asarray(rows, dtype=np.float64), direction, size
    # index [b, g, r] so that a C-order flattening varies red fastest
    b, g, r = np.meshgrid(x, x, x, indexing="ij")
    nodes = np.stack([r, g, b], axis=-1).reshape(-1, 3)
    if direction == "to-raw":
        rows = model.to_raw(nodes)
    else:
        rows = model.render(nodes)
    return np.asarray(rows, dtype=np.float64), direction, size


def _title(text: str) -> str:
    return " ".join(str(text).replace('"', "'").split())[:200]


def write_cube(model, path, *, direction: str | None = None, size: int | None = None,
               title: str | None = None, force: bool = False, inputs=()) -> Path:
    """Write ``model`` as a ``.cube`` look-up table (Adobe Cube LUT Specification 1.0).

    Parameters
    ----------
    model : ResponseModel or PipelineModel
        A response model gives a 1D table (``direction="linearize"``); a pipeline model
        (including an NUS model folder loaded by :func:`selfcal.load_model`) a 3D table
        (``"to-raw"``: JPEG -> raw, the default; ``"render"``: raw -> JPEG).
    path : str or os.PathLike
        The ``.cube`` file; written atomically, never over an existing file unless
        ``force`` nor over one of ``inputs``.
    direction : {"linearize", "to-raw", "render"}, optional
        Default: ``"linearize"`` for a response model, ``"to-raw"`` for a pipeline model.
    size : int, optional
        ``LUT_1D_SIZE`` (default ``max_code + 1``, at most 4096) or ``LUT_3D_SIZE``
        (default 33; 65 for a finer table).
    title : str, optional
        The ``TITLE`` line (default names the direction).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    InputError
        A direction the model cannot export, or a size outside the spec's range.
    OutputExistsError, OutputWriteError
        The output exists (without ``force``), is an input, or cannot be written.
    """
    path = Path(path)
    direction, size = check_export(model, direction, size)
    check_output_path(path, force=force, inputs=inputs)
    rows, direction, size = cube_table(model, direction, size=size)
    dims = 1 if direction == "linearize" else 3
    what = {"linearize": "code/max_code -> linear (f^-1 per channel)",
            "to-raw": "rendered code/255 -> linear camera raw in [0, 1]",
            "render": "linear camera raw in [0, 1] (black 0, white 1) -> rendered "
                      "code/255"}[direction]
    head = [f"# selfcal {direction}: {what}",
            "# Adobe Cube LUT Specification 1.0" + ("" if dims == 1 else
                                                    "; red varies fastest"),
            f'TITLE "{_title(title or f"selfcal {direction}")}"',
            f"LUT_{dims}D_SIZE {size}",
            "DOMAIN_MIN 0.0 0.0 0.0",
            "DOMAIN_MAX 1.0 1.0 1.0"]
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write("\n".join(head) + "\n")
            np.savetxt(fh, rows, fmt="%.7f")
    return path


def read_cube_header(path) -> dict:
    """The keyword lines of a ``.cube`` file (``TITLE``, ``LUT_3D_SIZE``, ...) as strings.

    A small reader for checks and tests; it does not read the table.
    """
    out = {}
    for line in Path(path).read_text(encoding="ascii").splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        if not key[:1].isalpha():
            break
        out[key] = value.strip()
    return out
