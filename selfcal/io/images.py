"""Reading and writing images, and atomic output files; EXIF (:mod:`.exif`) re-exported.

Arrays are RGB (not OpenCV's BGR), channel last.  Decoding goes through OpenCV, which is the
fastest decoder available here; file structure is checked first so that a truncated JPEG is
an error instead of a silently grey-padded image.
"""

from __future__ import annotations

import contextlib
import io as _io
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TypeGuard, TypeVar

import numpy as np

from ..errors import InputError, OutputExistsError, SelfcalError
from ..typing import PathLike
from .exif import (ExposureInfo, LensInfo, effective_exposure_times, exif_bytes,  # noqa: F401
                   exif_rational, format_exposure_time, rational_value, read_exposure_info,
                   read_lens_info)

_T = TypeVar("_T")

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
JPEG_SUFFIXES = {".jpg", ".jpeg"}


def import_cv2():
    """OpenCV, with OpenEXR enabled and its own log lines silenced.

    The library never prints: OpenCV would otherwise log libtiff warnings (e.g. for
    exposure tags in a TIFF's IFD0) to stderr; errors still come back as failed reads.
    """
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    import cv2

    try:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    except AttributeError:  # builds without the logging module
        pass
    return cv2


def is_path(x: object) -> TypeGuard[PathLike]:
    """True for what names a file (``str`` or ``os.PathLike``), False for an array."""
    return isinstance(x, (str, os.PathLike))


# --------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------

def _check_structure(path: Path, data: bytes) -> None:
    """Raise InputError when the bytes are plainly not a complete image file."""
    if len(data) == 0:
        raise InputError("the file is empty", path)
    if data[:2] == b"\xff\xd8":
        # A complete JPEG ends with the EOI marker; cameras may pad after it, some (the
        # Sony ILCE-6400) with tens of kilobytes of zeros.
        if b"\xff\xd9" not in data.rstrip(b"\x00")[-4096:]:
            raise InputError("truncated JPEG (no end-of-image marker)", path)
    elif data[:8] == b"\x89PNG\r\n\x1a\n":
        if b"IEND" not in data[-64:]:
            raise InputError("truncated PNG (no IEND chunk)", path)
    elif data[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        pass
    else:
        raise InputError("not an image file selfcal reads (JPEG, PNG or TIFF)", path)


def read_image(path: PathLike, *, reduce: int = 1) -> np.ndarray:
    """Read an image file as an RGB array, channel last.

    Parameters
    ----------
    path : str or os.PathLike
        A JPEG, PNG or TIFF file, 8 or 16 bits per channel.
    reduce : {1, 2, 4, 8}
        For JPEG files, decode at 1/reduce of the size with libjpeg's DCT scaling (each
        output pixel is a local mean of reduce×reduce pixels), several times faster than
        a full decode; ignored for other formats.

    Returns
    -------
    numpy.ndarray
        ``HxWx3`` array of dtype ``uint8`` or ``uint16`` (16-bit files keep their depth).
        Grey images are repeated over three channels; an alpha channel is dropped.

    Raises
    ------
    InputError
        When the file is missing, empty, truncated, or not a decodable image.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except IsADirectoryError:
        raise InputError("is a directory, not an image", path) from None
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror})", path) from None
    _check_structure(path, data)
    cv2 = import_cv2()
    buf = np.frombuffer(data, dtype=np.uint8)
    flags = cv2.IMREAD_UNCHANGED
    if reduce > 1 and data[:2] == b"\xff\xd8":
        flags = {2: cv2.IMREAD_REDUCED_COLOR_2, 4: cv2.IMREAD_REDUCED_COLOR_4,
                 8: cv2.IMREAD_REDUCED_COLOR_8}[reduce]
    image = cv2.imdecode(buf, flags | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None:
        raise InputError("the image data cannot be decoded (corrupt file?)", path)
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(f"unsupported sample type {image.dtype} (8 or 16-bit needed)", path)
    if image.ndim == 2:
        image = np.repeat(image[:, :, None], 3, axis=2)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    elif image.shape[2] == 3:
        # in place: a second full-size frame would cost as much memory as the decode
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB, dst=image)
    else:
        raise InputError(f"unsupported channel count {image.shape[2]}", path)
    return image


def read_image_size(path: PathLike) -> tuple[int, int]:
    """Return ``(height, width)`` of an image file from its header, without decoding it."""
    from PIL import Image

    path = Path(path)
    try:
        with Image.open(path) as im:
            width, height = im.size
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except IsADirectoryError:
        raise InputError("is a directory, not an image", path) from None
    except Exception as exc:  # Pillow raises several types for bad headers
        try:       # the cause in words when it is plain: empty, truncated, not an image
            _check_structure(path, path.read_bytes())
        except InputError as plain:
            raise plain from None
        except OSError:
            pass
        raise InputError(f"not an image file selfcal reads ({exc})", path) from None
    return height, width


# --------------------------------------------------------------------------------------
# writing (atomic, never over an existing file unless asked)
# --------------------------------------------------------------------------------------

class OutputWriteError(SelfcalError, OSError):
    """An output file cannot be written (its folder is missing, not a folder, read-only,
    or the disk refused); the message names the output asked for, never a temporary file.

    ``path`` (the output) and ``reason`` (what is wrong) are fields, as
    :class:`~selfcal.errors.InputError`'s: the message is ``"{path}: {reason}"``.
    """

    def __init__(self, message: str, path: object = None) -> None:
        self.path = None if path is None else str(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


def _reason(exc: OSError) -> str:
    """The cause of an OS error in words, without the file name it carries."""
    return (exc.strerror or str(exc) or type(exc).__name__).rstrip(".").lower()


def _names_a_temporary(exc: BaseException, folder: Path
                       ) -> TypeGuard[InputError | OutputWriteError]:
    """Whether ``exc`` is an error about a hidden temporary file of ``folder`` (its ``path``
    field, :func:`_temporary_beside`'s ``.name.xxxx.ext``): the output asked for should be
    named instead."""
    if not isinstance(exc, (InputError, OutputWriteError)) or not exc.path:
        return False
    p = Path(exc.path)
    return p.parent == folder and p.name.startswith(".")


def first_blocker(folder: Path):
    """Walk up from ``folder`` to the first path that exists: ``(existing, missing)``,
    where ``missing`` are the folders below it to be created (deepest last)."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return folder, missing[::-1]


def check_output_path(path: PathLike, *, force: bool = False, inputs: Iterable[PathLike] = (),
                      create_folder: bool = False) -> None:
    """Check before any work that ``path`` can be written; raise what writing it would.

    The checks: not one of ``inputs``; not a directory; not an existing file unless
    ``force``; its folder exists (or, with ``create_folder``, can be created: the nearest
    existing ancestor is a folder) and a file can really be created in it (a temporary
    file is made and removed: permissions alone do not tell for root or read-only
    mounts).  Nothing is left behind.

    Raises
    ------
    OutputExistsError
        ``path`` is an input, or exists and ``force`` is false.
    OutputWriteError
        ``path`` is a directory, its folder is missing or is a file, or cannot be written.
    """
    path = Path(path)
    resolved = path.resolve()
    for inp in inputs:
        if Path(inp).resolve() == resolved:
            raise OutputExistsError(f"{path}: refusing to write over an input file")
    if path.is_dir():
        raise OutputWriteError(path=path, message="cannot be written (it is a directory)")
    if path.exists() and not force:
        raise OutputExistsError(f"{path}: exists already (use --force to overwrite)")
    folder = path.parent
    existing, missing = first_blocker(folder)
    if not existing.is_dir():
        raise OutputWriteError(path=path,
                               message=f"cannot be written ({existing} is a file, not a "
                               "folder)")
    if missing and not create_folder:
        raise OutputWriteError(path=path,
                               message=f"cannot be written (the folder {missing[0]} does "
                               "not exist)")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".selfcal-check.", dir=existing)
    except OSError as exc:
        raise OutputWriteError(path=path, message=f"cannot be written (the folder {existing}: "
                               f"{_reason(exc)})") from None
    os.close(fd)
    os.unlink(tmp)


def _temporary_beside(path: Path) -> Path:
    """An empty hidden temporary file in the output's folder (so the final rename is
    atomic), with the permissions an ordinary new file gets (mkstemp makes 0600)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp",
                                   dir=path.parent)
    except OSError as exc:
        raise OutputWriteError(path=path,
                               message=f"cannot be written (the folder {path.parent}: "
                               f"{_reason(exc)})") from None
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return Path(tmp)


@contextlib.contextmanager
def atomic_output(path: PathLike, *, force: bool = False,
                  inputs: Iterable[PathLike] = ()) -> Iterator[Path]:
    """Context manager giving a temporary path that is renamed onto ``path`` on success.

    The temporary file sits in the same folder (a rename, never a copy); on any failure it
    is removed and errors name ``path``, not the temporary file.  Missing folders are
    created.

    Parameters
    ----------
    path : str or os.PathLike
        The final output file.
    force : bool
        Allow replacing an existing file.  Never allows replacing one of ``inputs``.
    inputs : iterable of paths
        Input files of the current job; writing over one of them is always refused.

    Raises
    ------
    OutputExistsError
        When ``path`` exists and ``force`` is false, or when it is one of the inputs.
    OutputWriteError
        When the folder cannot be created or written, or the rename fails (the message
        names ``path`` and the cause).
    """
    path = Path(path)
    resolved = path.resolve()
    for inp in inputs:
        if Path(inp).resolve() == resolved:
            raise OutputExistsError(f"{path}: refusing to write over an input file")
    if path.exists() and not force:
        raise OutputExistsError(f"{path}: exists already (use --force to overwrite)")
    existing, _ = first_blocker(path.parent)
    if not existing.is_dir():
        raise OutputWriteError(path=path,
                               message=f"cannot be written ({existing} is a file, not a "
                               "folder)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputWriteError(path=path,
                               message=f"cannot be written (the folder {path.parent}: "
                               f"{_reason(exc)})") from None
    tmp = _temporary_beside(path)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if _names_a_temporary(exc, path.parent):
            # a writer's own error about the temporary file: the same error, named right
            raise type(exc)(message=exc.reason, path=path) from None
        if isinstance(exc, OSError) and not isinstance(exc, SelfcalError):
            raise OutputWriteError(path=path,
                                   message=f"cannot be written ({_reason(exc)})") from None
        raise


class StagedOutputs:
    """Several output files written so that they all appear at the end, or none does.

    Each output is written to a temporary file beside it (:meth:`write`); :meth:`commit`
    renames them all onto their targets, and :meth:`discard` (or leaving the ``with``
    block by an exception) removes the temporary files and the folders this object
    created.  If a rename fails in :meth:`commit`, the outputs already renamed that did
    not exist before are removed again.  Errors name the output, not the temporary file.

    Parameters
    ----------
    force : bool
        Allow replacing existing files.
    inputs : iterable of paths
        Never written over.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> with StagedOutputs(force=False) as out:
    ...     _ = out.write(folder / "model.json", lambda tmp: pathlib.Path(tmp).write_text("{}"))
    ...     _ = out.write(folder / "notes.txt", lambda tmp: pathlib.Path(tmp).write_text("ok"))
    >>> sorted(p.name for p in folder.iterdir())
    ['model.json', 'notes.txt']
    """

    def __init__(self, *, force: bool = False, inputs: Iterable[PathLike] = ()) -> None:
        self.force = force
        self.inputs = [Path(p) for p in inputs]
        self._staged: list[tuple[Path, Path]] = []
        self._created_dirs: list[Path] = []
        self.written: list[Path] = []

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if kind is None:
            self.commit()
        else:
            self.discard()
        return False

    def _stage(self, target: Path) -> Path:
        check_output_path(target, force=self.force, inputs=self.inputs, create_folder=True)
        _, missing = first_blocker(target.parent)
        try:
            for folder in missing:
                folder.mkdir()
                self._created_dirs.append(folder)
        except OSError as exc:
            raise OutputWriteError(path=target, message=f"cannot be written (the folder "
                                   f"{target.parent}: {_reason(exc)})") from None
        tmp = _temporary_beside(target)
        self._staged.append((tmp, target))
        return tmp

    def write(self, target: PathLike, writer: Callable[[Path], _T]) -> _T:
        """Call ``writer(tmp)`` to write ``target``'s content to a temporary file (the
        writer must be allowed to replace ``tmp``, e.g. ``force=True``); returns what the
        writer returns."""
        target = Path(target)
        tmp = self._stage(target)
        try:
            return writer(tmp)
        except SelfcalError as exc:
            if _names_a_temporary(exc, tmp.parent):
                raise type(exc)(message=exc.reason, path=target) from None
            raise
        except OSError as exc:
            raise OutputWriteError(path=target,
                                   message=f"cannot be written ({_reason(exc)})") from None

    def commit(self) -> list[Path]:
        """Rename every staged file onto its target; returns the targets."""
        done: list[tuple[Path, bool]] = []
        try:
            for tmp, target in self._staged:
                if target.exists() and not self.force:
                    raise OutputExistsError(
                        f"{target}: exists already (use --force to overwrite)")
                existed = target.exists()
                try:
                    os.replace(tmp, target)
                except OSError as exc:
                    raise OutputWriteError(path=target, message=f"cannot be written "
                                           f"({_reason(exc)})") from None
                done.append((target, existed))
        except BaseException:
            for target, existed in done:
                if not existed:
                    with contextlib.suppress(OSError):
                        os.unlink(target)
            self._staged = [(t, g) for t, g in self._staged
                            if g not in {d for d, _ in done}]
            self.discard()
            raise
        self.written = [target for _, target in self._staged]
        self._staged = []
        self._created_dirs = []
        return self.written

    def discard(self) -> None:
        """Remove every staged file and the (now empty) folders created for them."""
        for tmp, _ in self._staged:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        self._staged = []
        for folder in reversed(self._created_dirs):
            with contextlib.suppress(OSError):
                folder.rmdir()
        self._created_dirs = []


def write_bytes_atomic(path: PathLike, data: bytes, *, force: bool = False,
                       inputs: Iterable[PathLike] = ()) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_output`)."""
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        Path(tmp).write_bytes(data)
    return Path(path)


def encode_image(image: np.ndarray, suffix: str, *, jpeg_quality: int = 95,
                 exposure_time: float | None = None, f_number: float | None = None,
                 iso: float | None = None) -> bytes:
    """Encode an RGB array (uint8, uint16 or float32) into the bytes of a ``suffix`` file.

    JPEG and PNG take uint8 (PNG and TIFF also uint16); TIFF also takes float32.  When any
    of ``exposure_time``, ``f_number``, ``iso`` is given, a JPEG gets an EXIF block with them.
    """
    cv2 = import_cv2()
    suffix = suffix.lower()
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"expected an HxWx3 RGB array, got shape {image.shape}")
    bgr = np.ascontiguousarray(image[:, :, ::-1])
    if suffix in JPEG_SUFFIXES:
        if image.dtype != np.uint8:
            raise InputError("JPEG output needs uint8 data")
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        data = buf.tobytes()
        if any(v is not None for v in (exposure_time, f_number, iso)):
            import piexif

            out = _io.BytesIO()
            piexif.insert(exif_bytes(exposure_time, f_number, iso), data, out)
            data = out.getvalue()
    elif suffix == ".png":
        if image.dtype not in (np.uint8, np.uint16):
            raise InputError("PNG output needs uint8 or uint16 data")
        ok, buf = cv2.imencode(".png", bgr)
        data = buf.tobytes()
    elif suffix in (".tif", ".tiff"):
        import tifffile

        if image.dtype not in (np.uint8, np.uint16, np.float32):
            raise InputError("TIFF output needs uint8, uint16 or float32 data")
        out = _io.BytesIO()
        tifffile.imwrite(out, image, photometric="rgb")
        data = out.getvalue()
        ok = True
    else:
        raise InputError(f"unsupported output format {suffix!r}")
    if not ok:
        raise InputError(f"OpenCV could not encode the image as {suffix}")
    return data


def write_image(path: PathLike, image: np.ndarray, *, force: bool = False,
                inputs: Iterable[PathLike] = (), jpeg_quality: int = 95,
                exposure_time: float | None = None, f_number: float | None = None,
                iso: float | None = None) -> Path:
    """Encode ``image`` by the suffix of ``path`` and write it atomically.

    See :func:`encode_image` for the formats, ``jpeg_quality`` and the EXIF fields
    (``exposure_time``, ``f_number``, ``iso``).
    """
    path = Path(path)
    data = encode_image(image, path.suffix, jpeg_quality=jpeg_quality,
                        exposure_time=exposure_time, f_number=f_number, iso=iso)
    return write_bytes_atomic(path, data, force=force, inputs=inputs)
