"""Linearised frames: each frame through the model's inverse response, one at a time.

:func:`linearize_images` is what ``selfcal linearize`` and ``selfcal batch --linearize``
write: ``f⁻¹(I)`` per channel ([Lin2011] §5), or a RAW-path model's ``to_raw``; the frames'
exposures are not divided out (the merge, :mod:`selfcal.hdr.merge`, does that); the lens's
vignetting is, when there is one (:mod:`.vignetting`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from ..errors import InputError
from ..io.images import is_path, read_image
from ..stack.frames import STRIP_PIXELS, Lineariser, apply_lut, max_code_of
from ..typing import ImageInput, Progress
from .vignetting import apply_vignetting, resolve_vignetting

__all__ = ["linearize_images"]


def linearize_images(images: Sequence[ImageInput], model: object, *,
                     vignetting: object = "auto", records: list | None = None,
                     progress: Progress | None = None) -> Iterator[tuple[str, np.ndarray]]:
    """Linearise frames one at a time: ``f⁻¹(I)`` per channel (Lin et al., ICCV 2011, §5).

    A generator, so a long list of large frames never sits in memory at once.  Values are
    linear camera signal with ``f⁻¹(max code) = 1`` (not divided by the exposure), as
    :meth:`selfcal.ResponseModel.linearize` gives them; for a model with ``to_raw`` (the
    RAW path's backward model) that is used instead.

    Parameters
    ----------
    images : sequence
        uint8/uint16 RGB arrays or paths.
    model : ResponseModel or object with ``to_raw``
    vignetting : {"auto", "self", "lens", "none"}, Vignetting or path
        The lens's falloff divided out of each image
        (:func:`selfcal.hdr.vignetting.resolve_vignetting`: ``"auto"``, the default, is
        the model's, else the lens database's profile for the file's EXIF, else none).
    records : list, optional
        Receives, per image, the record of the vignetting chosen
        (:func:`~selfcal.hdr.vignetting.resolve_vignetting`) with its ``frame``.
    progress : callable, optional
        ``progress("linearize", done, total, source)``.

    Yields
    ------
    (str, numpy.ndarray)
        The source (path or ``"array #k"``) and its float32 ``HxWx3`` linear image.
    """
    items = list(images)
    sources = [str(f) if is_path(f) else f"array #{k}" for k, f in enumerate(items)]
    for k, item in enumerate(items):
        img = read_image(item) if is_path(item) else np.asarray(item)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InputError(f"expected an HxWx3 RGB image, got shape {img.shape}", sources[k])
        if img.dtype not in (np.uint8, np.uint16):
            raise InputError(f"unsupported dtype {img.dtype} (uint8 or uint16 codes)",
                             sources[k])
        lin = Lineariser(model, False, max_code_of(img))
        if lin.kind == "lut":
            out = np.empty(img.shape, dtype=np.float32)
            assert lin.table is not None    # made for the frame's max code
            table = lin.table.astype(np.float32)
            rows = max(8, STRIP_PIXELS // img.shape[1])
            for y in range(0, img.shape[0], rows):
                out[y:y + rows] = apply_lut(img[y:y + rows], table)
        else:
            out = lin.values(img)
        falloff, record = resolve_vignetting(vignetting, model, path=item if is_path(item)
                                             else None, shape=out.shape[:2])
        if falloff is not None:
            apply_vignetting(out, None, falloff, moved=False, record=record)
        if records is not None:
            records.append({**record, "frame": sources[k]})
        del img
        if progress is not None:
            progress("linearize", k + 1, len(items), sources[k])
        yield sources[k], out
