"""Thumbnails of a library's frames: read once with their EXIF, in parallel, and kept on
disk until the session search asks for them.

:func:`read_frames` opens each file once for its EXIF and a small grey
:func:`thumbnail` (JPEG DCT scaling, box means); :class:`ThumbnailSpool` keeps the
thumbnails in a temporary file so that discovery holds none of them in memory, and the
search (:func:`.grouping.group_by_content`) reads each back when it places its frame and
drops it when the frame's session closes.  All of this is ours.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: Thumbnail width in pixels (height keeps the aspect ratio).
THUMB_WIDTH = 64


def thumbnail(path, width: int = THUMB_WIDTH):
    """A small grey thumbnail of a rendered frame (uint8 codes), or None.

    Decoded at reduced size where the format allows (JPEG DCT scaling), averaged over
    boxes.  Returns None when the pixels cannot be read (a truncated file, say): the
    grouping then falls back on time, and the session's own work reports the file.
    """
    from PIL import Image

    try:
        with Image.open(path) as im:
            return _thumbnail_of(im, width)
    except Exception:  # noqa: BLE001 -- any unreadable frame: no thumbnail
        return None


def _thumbnail_of(im, width: int = THUMB_WIDTH):
    """:func:`thumbnail` of an open Pillow image (None when its pixels cannot be read)."""
    from PIL import Image

    try:
        w, h = im.size
        tw = max(1, min(int(width), w))
        th = max(1, round(tw * h / w))
        im.draft("RGB", (2 * tw, 2 * th))
        grey = im.convert("L") if im.mode in ("RGB", "L") else im.convert("RGB").convert("L")
        return np.asarray(grey.resize((tw, th), Image.Resampling.BOX), dtype=np.uint8)
    except Exception:  # noqa: BLE001 -- truncated or corrupt pixels: no thumbnail
        return None


def _read_one(pair, reader, thumbnails=True):
    """EXIF and thumbnail of one frame from one opening of the file (``reader`` is
    :func:`.discover.read_frame`)."""
    from ..errors import InputError

    try:
        info, thumb = reader(*pair, also=_thumbnail_of if thumbnails else None)
    except InputError as exc:
        return exc, None
    return info, (thumb if info.exposure_time is not None else None)


def _read_chunk(pairs, reader, thumbnails):
    return [_read_one(p, reader, thumbnails) for p in pairs]


#: Frames from which :func:`read_frames` reads in worker processes rather than threads.
PROCESS_THRESHOLD = 2000


class ThumbnailSpool:
    """Thumbnails kept in an anonymous temporary file as they are read, read back one at a
    time: discovery holds no more thumbnails than the grouping's open sessions do (ours;
    at 10⁵ frames the thumbnails alone are about 270 MB).

    :meth:`add` stores one and returns its key (None stays None); ``spool[key]`` reads it
    back.  Use it as a context manager (the file goes with it).
    """

    def __init__(self):
        import tempfile

        self._file = tempfile.TemporaryFile()
        self._where: list[tuple[int, tuple[int, ...]]] = []

    def add(self, thumb) -> int | None:
        if thumb is None:
            return None
        a = np.ascontiguousarray(thumb, dtype=np.uint8)
        self._file.seek(0, 2)
        self._where.append((self._file.tell(), a.shape))
        self._file.write(a.tobytes())
        return len(self._where) - 1

    def __getitem__(self, key):
        if key is None:
            return None
        offset, shape = self._where[key]
        self._file.seek(offset)
        data = self._file.read(int(np.prod(shape)))
        return np.frombuffer(data, np.uint8).reshape(shape)

    def close(self) -> None:
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def read_frames(pairs, reader, *, workers: int | None = None, thumbnails: bool = True,
                keep=None):
    """EXIF and thumbnail of each ``(rendered, raw)`` pair, each file read once, in
    parallel: threads for a few files, processes (``spawn``-safe, chunks of 500) from
    :data:`PROCESS_THRESHOLD` on -- Pillow's EXIF parsing holds the GIL.

    ``reader`` is :func:`.discover.read_frame` (passed in: this module does not import
    the discovery).  Returns a list of ``(FrameInfo or InputError, thumbnail or None)``
    in input order; with ``keep`` (e.g. :meth:`ThumbnailSpool.add`), each thumbnail is
    passed to it as soon as its chunk is read and the list holds what it returned.
    """
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor
    from functools import partial

    def kept(read):
        return read if keep is None else (read[0], keep(read[1]))

    pairs = list(pairs)
    n = int(workers or min(8, os.cpu_count() or 1))
    if n <= 1 or len(pairs) < 8:
        return [kept(_read_one(p, reader, thumbnails)) for p in pairs]
    if len(pairs) < PROCESS_THRESHOLD:
        with ThreadPoolExecutor(max_workers=n) as pool:
            return [kept(x) for x in pool.map(
                partial(_read_one, reader=reader, thumbnails=thumbnails), pairs)]
    chunks = [pairs[i:i + 500] for i in range(0, len(pairs), 500)]
    spawn = multiprocessing.get_context("spawn")     # no fork of a threaded process
    with ProcessPoolExecutor(max_workers=n, mp_context=spawn) as processes:
        done = processes.map(partial(_read_chunk, reader=reader, thumbnails=thumbnails), chunks)
        return [kept(x) for chunk in done for x in chunk]
