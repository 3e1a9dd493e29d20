"""Calibrations as Academy/ASC Common LUT Format files (``.clf``).

The format is the Common LUT Format version 3 [CLF3] (Academy S-2014-006, also SMPTE
ST 2136-1): an XML ``ProcessList`` of process nodes applied in order.  selfcal writes
three kinds of node, all with ``inBitDepth="32f" outBitDepth="32f"`` (values are
normalised, no bit-depth scaling):

``<Range>``
    with ``minInValue``/``maxInValue``/``minOutValue``/``maxOutValue`` 0 and 1: clamps
    the input to ``[0, 1]`` (the range the models take; [CLF3] §"Range": with all four
    values and the default ``style="Clamp"`` it clamps and scales by 1).
``<LUT1D interpolation="linear">``
    an ``<Array dim="N 3">``: one column per channel, nodes uniform on ``[0, 1]``.
``<LUT3D interpolation="tetrahedral">``
    an ``<Array dim="n n n 3">``: rows with the **blue** index varying fastest, then
    green, then red ([CLF3] §"LUT3D"; the reverse of a ``.cube`` file's order).

What each direction writes:

``linearize`` (a :class:`~selfcal.response.ResponseModel`)
    Range, LUT1D: the twin of the 1D ``.cube`` of :func:`selfcal.export.write_cube`
    (``code/max_code`` -> ``f⁻¹`` per channel [Lin2011], nodes on the codes).
``to-raw`` / ``render`` (a pipeline model)
    Range, LUT1D (the shaper), LUT3D: the tables of :func:`selfcal.export.shaper.shaper_lut`.

Ours: the writer (XML by hand, ~60 lines, so that no XML or colour library is a
dependency) and the choice of nodes; the format is the spec's.  OpenColorIO reads these
files with its own CLF parser (``FileTransform``); the tests apply them with it.

References
----------
.. [CLF3] Academy of Motion Picture Arts and Sciences / ASC, "Common LUT Format (CLF):
   A Common File Format for Look-Up Tables", Academy S-2014-006, version 3 (2020).
.. [Lin2011] H. Lin, S. J. Kim, S. Süsstrunk and M. S. Brown, "Revisiting Radiometric
   Calibration for Color Computer Vision", ICCV 2011.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from ..errors import InputError
from .cube import check_export, cube_table
from .shaper import (DEFAULT_SHAPER_SIZE, MEANING, ShaperLUT, shaper_lut)
from ..io.images import atomic_output, check_output_path

__all__ = ["write_clf", "clf_text", "write_model_clf"]


def _array(values: np.ndarray, fmt: str) -> str:
    return "\n".join(" ".join(fmt % v for v in row) for row in values)


def _range_node() -> str:
    return ('  <Range inBitDepth="32f" outBitDepth="32f">\n'
            "    <Description>clamp to [0, 1], the range the model takes</Description>\n"
            "    <minInValue>0</minInValue>\n    <maxInValue>1</maxInValue>\n"
            "    <minOutValue>0</minOutValue>\n    <maxOutValue>1</maxOutValue>\n"
            "  </Range>")


def _lut1d_node(values: np.ndarray, what: str) -> str:
    return (f'  <LUT1D inBitDepth="32f" outBitDepth="32f" interpolation="linear">\n'
            f"    <Description>{escape(what)}</Description>\n"
            f'    <Array dim="{values.shape[0]} 3">\n{_array(values, "%.8f")}\n'
            "    </Array>\n  </LUT1D>")


def _lut3d_node(lut: ShaperLUT) -> str:
    n = lut.size
    return (f'  <LUT3D inBitDepth="32f" outBitDepth="32f" interpolation="tetrahedral">\n'
            f"    <Description>the model on the shaper's grid</Description>\n"
            f'    <Array dim="{n} {n} {n} 3">\n{_array(lut.rows_blue_fastest(), "%.7f")}\n'
            "    </Array>\n  </LUT3D>")


def clf_text(content, direction: str, *, name: str, description: str = "") -> str:
    """The text of a CLF file.

    Parameters
    ----------
    content : numpy.ndarray or ShaperLUT
        ``(N, 3)`` 1D table (``direction="linearize"``) or a :class:`ShaperLUT`.
    direction : {"linearize", "to-raw", "render"}
    name : str
        The ``ProcessList``'s ``name`` (and, made safe, its ``id``).
    description : str
        One more ``<Description>`` line (e.g. the model file).
    """
    ident = "selfcal-" + "".join(ch if ch.isalnum() or ch in "-_." else "-"
                                 for ch in f"{direction}-{name}")[:120]
    inp, _, out = MEANING[direction].partition(" -> ")
    nodes = [_range_node()]
    if isinstance(content, ShaperLUT):
        nodes += [_lut1d_node(content.shaper, content.kind), _lut3d_node(content)]
    else:
        nodes.append(_lut1d_node(np.asarray(content, dtype=np.float64),
                                 "f^-1 per channel, nodes uniform in code/max_code"))
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<ProcessList compCLFversion="3" id={quoteattr(ident)} name={quoteattr(name)}>',
             f"  <Description>selfcal {direction}: {escape(MEANING[direction])}</Description>"]
    if description:
        lines.append(f"  <Description>{escape(description)}</Description>")
    lines += [f"  <InputDescriptor>{escape(inp)}</InputDescriptor>",
              f"  <OutputDescriptor>{escape(out)}</OutputDescriptor>", *nodes,
              "</ProcessList>", ""]
    return "\n".join(lines)


def write_clf(content, path, direction: str, *, name: str, description: str = "",
              force: bool = False, inputs=()) -> Path:
    """Write :func:`clf_text` to ``path`` atomically (never over an existing file unless
    ``force``, never over one of ``inputs``)."""
    path = Path(path)
    check_output_path(path, force=force, inputs=inputs)
    text = clf_text(content, direction, name=name, description=description)
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        Path(tmp).write_text(text, encoding="utf-8", newline="\n")
    return path


def write_model_clf(model, path, *, direction: str | None = None, size: int | None = None,
                    shaper_size: int = DEFAULT_SHAPER_SIZE, name: str | None = None,
                    force: bool = False, inputs=()) -> Path:
    """Write ``model`` as a CLF file [CLF3] (see the module docstring).

    Parameters
    ----------
    model : ResponseModel or PipelineModel
        A response model writes ``linearize`` (Range, LUT1D); a pipeline model (or an
        NUS model folder) ``to-raw`` (the default) or ``render`` (Range, LUT1D shaper,
        LUT3D).
    path : str or os.PathLike
    direction : {"linearize", "to-raw", "render"}, optional
    size : int, optional
        LUT1D length of a ``linearize`` file (default ``max_code + 1``, at most 4096);
        LUT3D nodes per axis otherwise (default 33).
    shaper_size : int
        LUT1D length of the shaper (pipeline models).
    name : str, optional
        The ProcessList name (default ``selfcal <direction>``).

    Raises
    ------
    InputError
        A direction the model cannot export or a size outside the allowed range.
    OutputExistsError, OutputWriteError
        The output exists (without ``force``), is an input, or cannot be written.
    """
    path = Path(path)
    direction, size = check_export(model, direction, size)
    check_output_path(path, force=force, inputs=inputs)
    name = name or f"selfcal {direction}"
    content: np.ndarray | ShaperLUT
    if direction == "linearize":
        rows, _, _ = cube_table(model, direction, size=size)
        content = rows
    elif direction in ("to-raw", "render"):
        content = shaper_lut(model, direction, size=size, shaper_size=shaper_size)
    else:   # pragma: no cover - check_export allows no other
        raise InputError(f"unknown direction {direction!r}")
    return write_clf(content, path, direction, name=name, force=force, inputs=inputs)
