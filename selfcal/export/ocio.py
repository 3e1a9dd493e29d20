"""A calibration as an OpenColorIO v2 configuration: ``config.ocio`` plus its LUT files.

VFX and grading applications (Nuke, Resolve, Blender, Houdini) load colour transforms
through OpenColorIO [OCIO2]; a config names colour spaces and how each converts to the
config's reference space.  :func:`write_ocio_config` writes a folder:

``config.ocio``
    ``ocio_profile_version: 2.1``, ``search_path: .`` (the LUTs beside it), and the
    colour spaces (ours: their names, families and descriptions):

    - ``<camera> scene-linear``: the reference space (no transform), ``encoding:
      scene-linear``.  For a RAW-path model: the camera's raw primaries, normalised
      (black 0, white 1), not white-balanced -- what ``selfcal to-raw`` gives.  For a
      response model: linear in the JPEG's own primaries (the camera's output space,
      normally sRGB), ``f⁻¹`` per channel with ``f⁻¹(1) = 1`` [Lin2011] -- what
      ``selfcal linearize`` gives.
    - ``<camera> JPEG``: the camera's rendered encoding, ``encoding: sdr-video``;
      ``to_scene_reference`` / ``from_scene_reference`` are ``FileTransform``\\ s of the
      CLF files (:mod:`selfcal.export.clf`): RAW path, ``jpeg_to_linear.clf`` (to-raw)
      and ``linear_to_jpeg.clf`` (render, the model's forward pipeline); response model,
      ``jpeg_to_linear.clf`` (linearize) and its inverse (OpenColorIO inverts a 1D LUT).
    - ``Non-Color`` (``isdata: true``, the ``data`` role).

    Roles: ``scene_linear``, ``reference``, ``rendering`` ->
    scene-linear; ``default``, ``color_picking``, ``matte_paint``, ``texture_paint`` ->
    JPEG; ``data`` -> Non-Color.  One display ``sRGB`` with the view ``Camera JPEG``
    (the camera's own rendering is display-ready sRGB-encoded).  A file rule sends every
    file to ``default``.
``jpeg_to_linear.clf``, ``linear_to_jpeg.clf`` (RAW path) or ``jpeg_to_linear.clf``
(response model)

The folder is written all or nothing: into a hidden temporary folder beside it, renamed
into place when complete (with ``force``, an existing folder is swapped out and removed
only after the new one is in place).  OpenColorIO is not needed to write it; the tests
load it with OpenColorIO's Python bindings and run ``Config.validate()``.

References
----------
.. [OCIO2] OpenColorIO v2 documentation, "Config syntax" (ocio_profile_version 2,
   ColorSpace to_scene_reference / from_scene_reference, FileTransform, roles, file_rules,
   displays) and ``Config.validate()``, https://opencolorio.readthedocs.io
.. [Lin2011] H. Lin, S. J. Kim, S. Süsstrunk and M. S. Brown, "Revisiting Radiometric
   Calibration for Color Computer Vision", ICCV 2011.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InputError, OutputExistsError
from .cube import check_export, cube_table
from .clf import write_clf
from .shaper import DEFAULT_SHAPER_SIZE, ShaperLUT, shaper_lut
from ..io.images import OutputWriteError, first_blocker

if TYPE_CHECKING:
    import numpy as np

__all__ = ["write_ocio_config", "check_ocio_folder", "ocio_colour_space_names", "CONFIG_NAME"]

CONFIG_NAME = "config.ocio"
TO_LINEAR = "jpeg_to_linear.clf"
#: LUT3D nodes per axis of a RAW-path config unless asked otherwise.
OCIO_3D_SIZE = 65
FROM_LINEAR = "linear_to_jpeg.clf"


def _safe_name(text: str) -> str:
    keep = "".join(ch if ch.isalnum() or ch in " -_.()" else "_" for ch in str(text))
    return " ".join(keep.split())[:60] or "camera"


def ocio_colour_space_names(camera: str) -> dict:
    """The colour-space names a config for ``camera`` uses: ``{"jpeg", "linear", "data"}``."""
    cam = _safe_name(camera)
    return {"jpeg": f"{cam} JPEG", "linear": f"{cam} scene-linear", "data": "Non-Color"}


def _yaml_text(text: str) -> str:
    """A double-quoted YAML scalar."""
    return '"' + str(text).replace("\\", "\\\\").replace('"', "'").replace("\n", " ") + '"'


def _config_text(names: dict, camera: str, kind: str, linear_desc: str) -> str:
    jpeg, linear, data = names["jpeg"], names["linear"], names["data"]
    if kind == "pipeline":
        to_ref = f"!<FileTransform> {{src: {TO_LINEAR}}}"
        from_ref = f"!<FileTransform> {{src: {FROM_LINEAR}}}"
        jpeg_desc = (f"{camera}: the camera's rendered JPEG encoding (code/255). To "
                     "scene-linear through the model's to-raw, from it through the model's "
                     "render (selfcal RAW-path model, shaper + 3D LUT)")
    else:
        to_ref = f"!<FileTransform> {{src: {TO_LINEAR}}}"
        from_ref = f"!<FileTransform> {{src: {TO_LINEAR}, direction: inverse}}"
        jpeg_desc = (f"{camera}: the camera's JPEG encoding (code/max_code). To scene-linear "
                     "through the inverse response f^-1 (selfcal response model, 1D LUT), "
                     "from it through the LUT's inverse")
    lines = [
        "ocio_profile_version: 2.1",
        "",
        f"name: {_yaml_text('selfcal ' + camera)}",
        "description: " + _yaml_text(f"Written by selfcal: the colour spaces of {camera}"),
        "search_path: .",
        "strictparsing: true",
        "luma: [0.2126, 0.7152, 0.0722]",
        "",
        "roles:",
        f"  color_picking: {_yaml_text(jpeg)}",
        f"  data: {_yaml_text(data)}",
        f"  default: {_yaml_text(jpeg)}",
        f"  matte_paint: {_yaml_text(jpeg)}",
        f"  reference: {_yaml_text(linear)}",
        f"  rendering: {_yaml_text(linear)}",
        f"  scene_linear: {_yaml_text(linear)}",
        f"  texture_paint: {_yaml_text(jpeg)}",
        "",
        "file_rules:",
        "  - !<Rule> {name: Default, colorspace: default}",
        "",
        "displays:",
        "  sRGB:",
        f"    - !<View> {{name: Camera JPEG, colorspace: {_yaml_text(jpeg)}}}",
        "",
        "active_displays: [sRGB]",
        "active_views: [Camera JPEG]",
        "",
        "colorspaces:",
        "  - !<ColorSpace>",
        f"    name: {_yaml_text(linear)}",
        "    family: Camera",
        "    encoding: scene-linear",
        "    bitdepth: 32f",
        f"    description: {_yaml_text(linear_desc)}",
        "    isdata: false",
        "",
        "  - !<ColorSpace>",
        f"    name: {_yaml_text(jpeg)}",
        "    family: Camera",
        "    encoding: sdr-video",
        "    bitdepth: 8ui",
        f"    description: {_yaml_text(jpeg_desc)}",
        "    isdata: false",
        f"    to_scene_reference: {to_ref}",
        f"    from_scene_reference: {from_ref}",
        "",
        "  - !<ColorSpace>",
        f"    name: {_yaml_text(data)}",
        "    family: Utility",
        "    encoding: data",
        "    description: \"Non-colour data: no conversion\"",
        "    isdata: true",
        ""]
    return "\n".join(lines)


def check_ocio_folder(folder, force: bool = False, inputs=()) -> None:
    """Refuse, before any work, a config folder that could not be written: one holding an
    input or being one, a file, an existing folder without ``force``, a missing parent,
    an unwritable parent (OutputExistsError / OutputWriteError naming the folder)."""
    folder = Path(folder)
    resolved = folder.resolve()
    for inp in inputs:
        p = Path(inp).resolve()
        if p == resolved or resolved in p.parents:
            raise OutputExistsError(f"{folder}: refusing to write over an input")
    if folder.exists() and not folder.is_dir():
        raise OutputWriteError(path=folder,
                               message="cannot be written (it is a file, not a folder)")
    if folder.exists() and not force:
        raise OutputExistsError(f"{folder}: exists already (use --force to replace it)")
    existing, missing = first_blocker(folder.parent)
    if not existing.is_dir():
        raise OutputWriteError(path=folder,
                               message=f"cannot be written ({existing} is a file, not a "
                               "folder)")
    if missing:
        raise OutputWriteError(path=folder,
                               message=f"cannot be written (the folder {missing[0]} does "
                               "not exist)")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise OutputWriteError(path=folder,
                               message=f"cannot be written (the folder {existing} is not "
                               "writable)")


def _swap_in(tmp: Path, folder: Path) -> None:
    """Rename ``tmp`` onto ``folder``; an existing ``folder`` is moved aside first and
    removed once the new one is in place (restored if the rename fails)."""
    old = None
    if folder.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{folder.name}.old.", dir=folder.parent))
        old.rmdir()
        os.rename(folder, old)
    try:
        os.rename(tmp, folder)
    except OSError:
        if old is not None:
            os.rename(old, folder)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def write_ocio_config(model, folder, *, camera: str = "camera", size: int | None = None,
                      shaper_size: int = DEFAULT_SHAPER_SIZE, force: bool = False,
                      inputs=()) -> Path:
    """Write ``model`` as an OpenColorIO v2 config folder (see the module docstring).

    Parameters
    ----------
    model : ResponseModel or PipelineModel
        A response model (JPEG-only path) or a RAW-path model / NUS model folder.
    folder : str or os.PathLike
        The folder to create (its parent must exist).
    camera : str
        The name the colour spaces carry (e.g. the model file's stem).
    size : int, optional
        RAW path: LUT3D nodes per axis (default :data:`OCIO_3D_SIZE`, 65: the config
        chains both directions, and in a round trip JPEG -> linear -> JPEG the render's
        steep toe multiplies the to-raw table's error in the darks; at 33³ a dark frame's
        round trip was within 0.005 of the model's own on 62 % of its pixels, at 65³ on
        all of them, ``python3 -m bench.export_cube``); response model: LUT1D length
        (default ``max_code + 1``).
    shaper_size : int
        RAW path: the shaper's LUT1D length.
    force : bool
        Replace an existing folder.
    inputs : iterable of paths
        Never written over (nor a folder holding one).

    Returns
    -------
    pathlib.Path
        The path of ``config.ocio``.

    Raises
    ------
    InputError
        A model that cannot be exported, or a bad size.
    OutputExistsError, OutputWriteError
        The folder exists (without ``force``), holds an input, or cannot be written.
    """
    folder = Path(folder)
    kind = "pipeline" if hasattr(model, "to_raw") and hasattr(model, "render") else "response"
    if size is None and kind == "pipeline":
        size = OCIO_3D_SIZE
    direction, size = check_export(model, "to-raw" if kind == "pipeline" else "linearize",
                                   size)
    check_ocio_folder(folder, force, inputs)
    names = ocio_colour_space_names(camera)
    luts: dict[str, tuple[str, np.ndarray | ShaperLUT]]
    if kind == "pipeline":
        luts = {TO_LINEAR: ("to-raw", shaper_lut(model, "to-raw", size=size,
                                                 shaper_size=shaper_size)),
                FROM_LINEAR: ("render", shaper_lut(model, "render", size=size,
                                                   shaper_size=shaper_size))}
        linear_desc = (f"{camera}: scene-linear camera raw, the camera's own (raw) primaries,"
                       " not white-balanced, normalised (black level 0, white level 1); "
                       "selfcal RAW-path model")
    elif direction == "linearize":
        luts = {TO_LINEAR: ("linearize", cube_table(model, "linearize", size=size)[0])}
        linear_desc = (f"{camera}: scene-linear in the JPEG's own primaries (the camera's "
                       "output colour space, normally sRGB): the inverse response f^-1 per "
                       "channel, f^-1(1) = 1; selfcal response model")
    else:   # pragma: no cover
        raise InputError(f"cannot write an OCIO config for direction {direction!r}")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
    except OSError as exc:
        raise OutputWriteError(path=folder,
                               message=f"cannot be written ({exc.strerror or exc})") \
            from None
    try:
        for fname, (d, content) in luts.items():
            write_clf(content, tmp / fname, d, name=f"{camera} {d}")
        (tmp / CONFIG_NAME).write_text(_config_text(names, _safe_name(camera), kind,
                                                    linear_desc),
                                       encoding="utf-8", newline="\n")
        os.chmod(tmp, 0o777 & ~_umask())
        _swap_in(tmp, folder)
    except OSError as exc:
        raise OutputWriteError(path=folder,
                               message=f"cannot be written ({exc.strerror or exc})") \
            from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return folder / CONFIG_NAME


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
