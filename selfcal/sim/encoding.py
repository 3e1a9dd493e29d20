"""From a rendered frame to stored codes and files: sharpening, bit depth, JPEG, EXIF.

After the pipeline renders a frame (``P = f(Γ(M ρ))``, :mod:`selfcal.sim.camera`), the
camera may sharpen it (:class:`UnsharpMask`), quantises it to 8 or 16 bits and, for 8-bit
frames, JPEG-encodes it (OpenCV's libjpeg, the decoder :func:`selfcal.io.read_image`
uses).  :class:`FrameOutput` holds those choices for :func:`selfcal.sim.simulate_stack`.
The writers here put the nominal exposure data into PNG (``eXIf`` chunk), TIFF (IFD0
tags) and JPEG (an EXIF block) files.
"""

from __future__ import annotations

import io as _io
import struct
import zlib
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io.images import exif_rational, import_cv2
from .camera import LUMA

__all__ = ["CHROMA_SUBSAMPLINGS", "UnsharpMask", "FrameOutput"]

#: JPEG chroma subsamplings :func:`selfcal.sim.simulate_stack` can write (OpenCV's default
#: is 4:2:0).
CHROMA_SUBSAMPLINGS = ("4:2:0", "4:2:2", "4:4:4")


def _decode_jpeg(data: bytes) -> np.ndarray:
    # the same decoder and flags as selfcal.io.read_image, so files decode to `images`
    cv2 = import_cv2()
    bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8),
                       cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def jpeg_round_trip(codes: np.ndarray, quality: int,
                     chroma_subsampling: str = "4:2:0") -> tuple[np.ndarray, bytes]:
    """JPEG-encode ``codes`` with OpenCV (libjpeg) and decode them again.

    4:2:0 is OpenCV's default (``selfcal.io.encode_image``); the other subsamplings set
    ``IMWRITE_JPEG_SAMPLING_FACTOR``.
    """
    if chroma_subsampling == "4:2:0":
        from ..io.images import encode_image

        data = encode_image(codes, ".jpg", jpeg_quality=int(quality))
        return _decode_jpeg(data), data
    cv2 = import_cv2()
    factor = {"4:2:2": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422,
              "4:4:4": cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444}[chroma_subsampling]
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(codes[:, :, ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, int(quality),
                            cv2.IMWRITE_JPEG_SAMPLING_FACTOR, int(factor)])
    if not ok:
        raise InputError("OpenCV could not encode the frame as JPEG")
    data = buf.tobytes()
    return _decode_jpeg(data), data


@dataclass(frozen=True)
class UnsharpMask:
    """In-camera sharpening: an unsharp mask on the luma of the rendered image.

    ``Y = w · P`` (Rec. 709 weights) of the rendered, gamma-encoded image ``P`` in
    ``[0, 1]``; ``P' = clip(P + amount (Y - G_σ * Y), 0, 1)`` with ``G_σ`` a Gaussian
    blur -- the same detail added to R, G and B, i.e. sharpening of the luma channel
    only, as cameras do before JPEG (ours: the simulator's stand-in for them; there is
    no threshold).  It overshoots at edges, and its halos are not a per-pixel function
    of exposure: a per-pixel response model cannot explain them.

    Attributes
    ----------
    amount : float
        ``>= 0`` (0: off; 0.5-1 is a typical camera setting).
    sigma : float
        Blur radius in pixels, ``> 0``.
    """

    amount: float = 0.8
    sigma: float = 1.0

    def __post_init__(self):
        if not (np.isfinite(self.amount) and self.amount >= 0):
            raise InputError(f"sharpening amount must be >= 0, got {self.amount!r}")
        if not (np.isfinite(self.sigma) and self.sigma > 0):
            raise InputError(f"sharpening sigma must be > 0, got {self.sigma!r}")

    def apply(self, rendered: np.ndarray) -> np.ndarray:
        """Sharpen ``HxWx3`` rendered values in ``[0, 1]``; float64, clipped to ``[0, 1]``."""
        from scipy.ndimage import gaussian_filter

        p = np.asarray(rendered, dtype=np.float64)
        if p.ndim != 3 or p.shape[2] != 3:
            raise InputError(f"sharpening needs an HxWx3 image, got shape {p.shape}")
        y = p @ LUMA
        detail = self.amount * (y - gaussian_filter(y, self.sigma, mode="reflect"))
        return np.clip(p + detail[..., None], 0.0, 1.0)


@dataclass(frozen=True)
class FrameOutput:
    """How the camera stores each rendered frame (all but the JPEG quality).

    In order: in-camera ``sharpening`` of the rendered values, quantisation to
    ``bit_depth`` bits (codes ``round(P * max_code)``), then, for 8-bit frames with a JPEG
    quality, a JPEG round trip with ``chroma_subsampling``.  The default is what most
    cameras write: 8 bits, JPEG with 4:2:0 chroma, no sharpening.

    Attributes
    ----------
    bit_depth : int
        8 or 16 (16-bit frames are never JPEG-encoded).
    chroma_subsampling : str
        JPEG chroma subsampling, one of :data:`CHROMA_SUBSAMPLINGS` (default 4:2:0,
        OpenCV's default and most cameras' at everyday qualities).
    sharpening : UnsharpMask or None
        In-camera sharpening of the rendered frame before quantisation and JPEG.

    Examples
    --------
    >>> FrameOutput(bit_depth=16).max_code
    65535
    """

    bit_depth: int = 8
    chroma_subsampling: str = "4:2:0"
    sharpening: UnsharpMask | None = None

    def __post_init__(self):
        if self.bit_depth not in (8, 16):
            raise InputError(f"bit_depth must be 8 or 16, got {self.bit_depth!r}")
        if self.chroma_subsampling not in CHROMA_SUBSAMPLINGS:
            raise InputError(f"chroma_subsampling must be one of {CHROMA_SUBSAMPLINGS}, "
                             f"got {self.chroma_subsampling!r}")
        if self.sharpening is not None and not isinstance(self.sharpening, UnsharpMask):
            raise InputError("sharpening must be an UnsharpMask or None")

    @property
    def max_code(self) -> int:
        """The largest code value: 255 or 65535."""
        return 255 if self.bit_depth == 8 else 65535

    def uses_jpeg(self, jpeg_quality: int | None) -> bool:
        """Whether frames are JPEG-encoded at ``jpeg_quality`` (8-bit frames only)."""
        return jpeg_quality is not None and self.bit_depth == 8

    def store(self, rendered: np.ndarray,
              jpeg_quality: int | None) -> tuple[np.ndarray, bytes | None]:
        """Sharpen, quantise and (see :meth:`uses_jpeg`) JPEG-encode one rendered frame.

        Returns
        -------
        codes : numpy.ndarray
            uint8 or uint16 ``HxWx3``, decoded from the JPEG when there is one.
        data : bytes or None
            The JPEG file's bytes (None without JPEG).
        """
        if self.sharpening is not None:
            rendered = self.sharpening.apply(rendered)
        dtype = np.uint8 if self.bit_depth == 8 else np.uint16
        codes = np.round(rendered * self.max_code).astype(dtype)
        if not self.uses_jpeg(jpeg_quality) or jpeg_quality is None:   # (uses_jpeg says)
            return codes, None
        return jpeg_round_trip(codes, jpeg_quality, self.chroma_subsampling)


def png_with_exif(png: bytes, exif: bytes) -> bytes:
    """Insert an ``eXIf`` chunk (TIFF-structured EXIF) right after the PNG's IHDR chunk."""
    if exif.startswith(b"Exif\x00\x00"):
        exif = exif[6:]
    ihdr_len = struct.unpack(">I", png[8:12])[0]
    at = 8 + 12 + ihdr_len
    chunk = (struct.pack(">I", len(exif)) + b"eXIf" + exif
             + struct.pack(">I", zlib.crc32(b"eXIf" + exif) & 0xFFFFFFFF))
    return png[:at] + chunk + png[at:]


def tiff_with_exif_tags(image: np.ndarray, time, f_number, iso) -> bytes:
    """16/8-bit RGB TIFF with ExposureTime, FNumber, ISO in IFD0 (as TIFF/EP and DNG do)."""
    import tifffile

    tags: list[tuple[int, int, int, tuple[int, int] | int, bool]] = []
    if time is not None:
        tags.append((33434, 5, 1, exif_rational(time), False))          # ExposureTime
    if f_number is not None:
        tags.append((33437, 5, 1, exif_rational(f_number, 100), False))  # FNumber
    if iso is not None:
        tags.append((34855, 3, 1, int(round(iso)), False))         # ISOSpeedRatings
    out = _io.BytesIO()
    tifffile.imwrite(out, image, photometric="rgb", extratags=tags)
    return out.getvalue()


def jpeg_with_exif(jpeg: bytes, exif: bytes) -> bytes:
    """The JPEG file ``jpeg`` with the EXIF block ``exif`` inserted (its pixels untouched)."""
    import piexif

    out = _io.BytesIO()
    piexif.insert(exif, jpeg, out)
    return out.getvalue()
