"""Reading camera raw files as linear camera RGB.

The RAW calibration path (Gong et al., *Rank-based radiometric calibration* [Gong2018],
Eq. 1a: ``P = f(Γ(M ρ))``) and the exposure ratios of Lin, Kim, Süsstrunk & Brown,
*Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011 ([Lin2011],
§5: "the exposure ratio can be directly computed by dividing the raw values between two
images") both need ρ, the sensor's linear response: black level subtracted, scaled so the
white (saturation) level is 1, and nothing else -- no white balance, no colour matrix, no
tone curve.  :func:`read_raw_linear` produces exactly that through LibRaw (``rawpy``), and
also accepts 16-bit linear TIFFs (such as ``fixtures/pair/pair.tiff``) as raws.

What is read from where
-----------------------
* pixels, black and white levels, as-shot white balance: LibRaw, for every format it reads
  (the suffixes in :data:`RAW_SUFFIXES` and more);
* exposure time, f-number, ISO (:func:`read_raw_exposure_info`): from the TIFF structure
  of TIFF-based raws (DNG, CR2, NEF, NRW, ARW, SRF, SR2, PEF, SRW, 3FR, IIQ, ERF, KDC, MOS
  and 16-bit TIFFs) through ``tifffile`` -- IFD0 and the EXIF sub-IFD -- with Pillow as a
  fallback; other containers (CR3, RAF, RW2, ORF, X3F, MRW, ...) give ``None`` fields.
  The camera JPEG beside a raw usually carries the same EXIF, and
  :func:`selfcal.calibrate` reads the JPEG's first and the raw's only where the JPEG
  lacks a field.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..typing import PathLike
from .images import ExposureInfo, rational_value

__all__ = ["RAW_SUFFIXES", "RawImage", "read_raw_linear", "read_raw_exposure_info",
           "is_raw_path", "is_linear_tiff"]

#: File name suffixes (lower case, with the dot) taken for camera raw files.
RAW_SUFFIXES = frozenset(
    "." + s for s in ("dng", "cr2", "cr3", "nef", "nrw", "arw", "srf", "sr2", "raf", "orf",
                      "rw2", "pef", "srw", "x3f", "3fr", "iiq", "rwl", "erf", "kdc", "mos",
                      "mrw"))

#: TIFF suffixes: a 16-bit (or float) TIFF can stand in for a raw (see :func:`is_linear_tiff`).
TIFF_SUFFIXES = frozenset({".tif", ".tiff"})


@dataclass(frozen=True, eq=False)
class RawImage:
    """A raw frame as linear camera RGB.

    Attributes
    ----------
    rgb : numpy.ndarray
        ``HxWx3`` float32 linear camera RGB in ``[0, 1]``: ``(raw - black) / (white - black)``
        per channel, demosaiced; 0 is the black level and 1 the white (saturation) level.
        No white balance, colour conversion or tone curve is applied, so a grey object is
        usually *not* grey here (green typically dominates).
    camera_wb : tuple of float or None
        As-shot white-balance multipliers ``(R, G, B)`` normalised to ``G = 1`` (not
        applied to :attr:`rgb`); None when the file has none (TIFF input).
    exposure : ExposureInfo
        Exposure time, f-number, ISO where the file carries them (see the module notes).
    path : pathlib.Path
    black_level : tuple of float
        Black level per output channel ``(R, G, B)`` in raw units (0 for TIFF input).
    white_level : tuple of float
        White level per output channel in raw units (65535 for 16-bit TIFF input).
    source : str
        ``"libraw"`` or ``"tiff"``.
    half_size : bool
        True when read at half size (2×2 Bayer cells binned, no demosaicing).
    """

    rgb: np.ndarray
    camera_wb: tuple | None
    exposure: ExposureInfo
    path: Path
    black_level: tuple = (0.0, 0.0, 0.0)
    white_level: tuple = (1.0, 1.0, 1.0)
    source: str = "libraw"
    half_size: bool = False
    extra: dict = field(default_factory=dict, repr=False)

    @property
    def shape(self) -> tuple:
        """``(H, W, 3)`` of :attr:`rgb`."""
        return self.rgb.shape


def is_raw_path(path) -> bool:
    """True when ``path`` has a camera-raw suffix (:data:`RAW_SUFFIXES`, any case)."""
    return Path(path).suffix.lower() in RAW_SUFFIXES


def is_linear_tiff(path) -> bool:
    """True when ``path`` is a TIFF with 16-bit integer or floating-point RGB samples.

    Such a TIFF is taken as linear raw data when it sits beside a rendered image of the same
    name (``pair.tiff`` + ``pair.jpg``).  Only the header is read.  False for 8-bit TIFFs
    and for files that are not TIFFs.
    """
    path = Path(path)
    if path.suffix.lower() not in TIFF_SUFFIXES:
        return False
    import tifffile

    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            bits = int(page.bitspersample)
            kind = page.dtype.kind if page.dtype is not None else "u"
            samples = int(page.samplesperpixel)
    except Exception:  # not a TIFF / unreadable: it is not a linear TIFF
        return False
    return samples >= 3 and (bits == 16 or kind == "f")


# --------------------------------------------------------------------------------------
# EXIF of raw files
# --------------------------------------------------------------------------------------

_TAG_NAMES = {"ExposureTime": 33434, "FNumber": 33437, "ISOSpeedRatings": 34855,
              "ShutterSpeedValue": 37377}


def _first(value):
    if isinstance(value, (list, tuple)) and value and not (
            len(value) == 2 and all(isinstance(v, int) for v in value)
            and isinstance(value, tuple)):
        return value[0]
    return value


def read_raw_exposure_info(path) -> ExposureInfo:
    """Exposure time, f-number and ISO of a raw file, where its container allows.

    TIFF-structured raws (DNG, CR2, NEF, ARW, PEF, ...) are read with ``tifffile`` (IFD0 and
    the EXIF sub-IFD, as TIFF/EP and DNG place them); Pillow is tried when that fails.
    Other containers (CR3, RAF, RW2, ORF, X3F, ...) give an all-None result.  Zero values
    (as some writers store for "unknown") count as missing.  Never raises for missing
    tags or unsupported containers.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    ExposureInfo
    """
    path = Path(path)
    tags: dict = {}
    try:
        import tifffile

        with tifffile.TiffFile(path) as tif:
            page = tif.pages[0]
            exif = {}
            if "ExifTag" in page.tags:
                value = page.tags["ExifTag"].value
                exif = value if isinstance(value, dict) else {}
            for name, code in _TAG_NAMES.items():
                value = exif.get(name)
                if value is None and code in page.tags:
                    value = page.tags[code].value
                if value is not None:
                    tags[name] = value
    except Exception:
        try:
            from .images import read_exposure_info

            return read_exposure_info(path)
        except Exception:
            return ExposureInfo(None, None, None)

    def rational(name):
        value = tags.get(name)
        if value is None:
            return None
        if isinstance(value, (list, tuple)) and len(value) == 2 and not isinstance(
                value[0], (list, tuple)):
            r = rational_value(tuple(value))
        else:
            r = rational_value(_first(value))
        return r if r is not None and r > 0 else None

    time = rational("ExposureTime")
    apex_tag = tags.get("ShutterSpeedValue")
    # an ExposureTime stored as 0 means "unknown" (then a 0 APEX value means the same)
    if time is None and "ExposureTime" not in tags and apex_tag is not None:
        apex_tag = tuple(apex_tag) if isinstance(apex_tag, (list, tuple)) else apex_tag
        apex = rational_value(apex_tag)
        numerator = apex_tag[0] if isinstance(apex_tag, tuple) else apex
        if apex is not None and numerator != 0 and -30 < apex < 30:
            time = float(2.0 ** (-apex))
    fnum = rational("FNumber")
    iso = tags.get("ISOSpeedRatings")
    iso = rational_value(_first(iso)) if iso is not None else None
    return ExposureInfo(exposure_time=time, f_number=fnum,
                        iso=iso if iso is not None and iso > 0 else None)


# --------------------------------------------------------------------------------------
# pixels
# --------------------------------------------------------------------------------------

def _bin2(rgb: np.ndarray) -> np.ndarray:
    h, w = (rgb.shape[0] // 2) * 2, (rgb.shape[1] // 2) * 2
    x = rgb[:h, :w].astype(np.float32)
    return 0.25 * (x[0::2, 0::2] + x[0::2, 1::2] + x[1::2, 0::2] + x[1::2, 1::2])


def _read_linear_tiff(path: Path, half_size: bool) -> RawImage:
    import tifffile

    try:
        data = tifffile.imread(path)
    except Exception as exc:
        raise InputError(f"not a TIFF file that can be read as a linear raw ({exc})",
                         path) from None
    data = np.asarray(data)
    if data.ndim == 3 and data.shape[0] in (3, 4) and data.shape[2] not in (3, 4):
        data = np.moveaxis(data, 0, -1)  # planar
    if data.ndim != 3 or data.shape[2] < 3:
        raise InputError(f"a linear raw TIFF must be RGB, got shape {data.shape}", path)
    data = data[..., :3]
    if data.dtype == np.uint16:
        rgb = data.astype(np.float32) / np.float32(65535.0)
        white = 65535.0
    elif data.dtype.kind == "f":
        rgb = data.astype(np.float32)
        if not np.all(np.isfinite(rgb)):
            raise InputError("the linear TIFF contains NaN or infinite values", path)
        rgb = np.clip(rgb, 0.0, 1.0)
        white = 1.0
    else:
        raise InputError(
            f"a {data.dtype.itemsize * 8}-bit TIFF is not a linear raw (16-bit integer or "
            "float samples needed)", path)
    if half_size:
        rgb = _bin2(rgb)
    from .images import read_exposure_info

    try:
        exposure = read_exposure_info(path)
    except InputError:
        exposure = ExposureInfo(None, None, None)
    return RawImage(rgb=np.ascontiguousarray(rgb, dtype=np.float32), camera_wb=None,
                    exposure=exposure, path=path, black_level=(0.0,) * 3,
                    white_level=(white,) * 3, source="tiff", half_size=bool(half_size))


def _channel_levels(raw) -> tuple[np.ndarray, np.ndarray]:
    """Black and white level per output channel (R, G, B) from LibRaw's per-CFA values."""
    black4 = np.asarray(raw.black_level_per_channel, dtype=np.float64)
    white4 = raw.camera_white_level_per_channel
    if white4 is None or not np.all(np.asarray(white4) > 0):
        white4 = [raw.white_level] * 4
    white4 = np.asarray(white4, dtype=np.float64)
    desc = raw.color_desc.decode("ascii", "replace") if raw.color_desc else "RGBG"
    black = np.zeros(3)
    white = np.zeros(3)
    for c, name in enumerate("RGB"):
        idx = [i for i, ch in enumerate(desc[:4]) if ch == name] or [min(c, 3)]
        black[c] = black4[idx].mean()
        white[c] = white4[idx].mean()
    return black, white


def read_raw_linear(path: PathLike, *, half_size: bool = False) -> RawImage:
    """Read a camera raw file (or a 16-bit linear TIFF) as linear camera RGB in ``[0, 1]``.

    The sensor values ρ of Gong et al., rank-based radiometric calibration [Gong2018],
    Eq. 1a, and the RAW values whose ratios give exposure ratios in Lin et al., ICCV 2011
    [Lin2011], §5.  LibRaw (``rawpy``) decodes and demosaics with every rendering step
    off: ``gamma=(1, 1)``, ``no_auto_bright``, unit white-balance multipliers, output in
    the camera's raw colour space, 16 bits, no automatic maximum adjustment, no rotation
    (``user_flip=0``: pixels stay in sensor order, as a camera JPEG's stored pixels do
    before its EXIF orientation is applied).  The black level comes from the file (LibRaw
    subtracts its per-channel black) and ``user_sat = white - black`` makes the file's white
    level map to 1 -- verified exact to 1/65535 at the CFA sites on the real DNGs (see the
    tests).  Channels whose black or white level differ from the others are rescaled to
    that same mapping.  Demosaicing is bilinear (every output value is a linear combination
    of same-channel raw values, so linearity is exact); ``half_size`` bins 2×2 Bayer cells
    instead (no interpolation; G is the mean of the two greens), four times fewer pixels.

    A TIFF with 16-bit integer samples is read as ``value / 65535`` (float samples as they
    are, clipped to ``[0, 1]``); its EXIF tags (IFD0, TIFF/EP style) are read with Pillow.

    Parameters
    ----------
    path : str or os.PathLike
        A raw file LibRaw reads (see :data:`RAW_SUFFIXES`) or a 16-bit/float RGB TIFF.
    half_size : bool
        Read at half the sensor resolution.

    Returns
    -------
    RawImage

    Raises
    ------
    InputError
        When the file is missing, is not a raw file LibRaw can read, or is an 8-bit TIFF
        (the message names the file).

    Examples
    --------
    A raw converter's 16-bit linear TIFF (a camera raw file reads the same way):

    >>> import pathlib, tempfile
    >>> import numpy as np, tifffile
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "linear.tiff"
    >>> tifffile.imwrite(path, np.full((4, 6, 3), 32768, np.uint16))
    >>> raw = read_raw_linear(path)
    >>> raw.rgb.dtype, raw.rgb.shape, round(float(raw.rgb.max()), 3)
    (dtype('float32'), (4, 6, 3), 0.5)
    """
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", path)
    if path.is_dir():
        raise InputError("is a directory, not a raw file", path)
    if path.suffix.lower() in TIFF_SUFFIXES:
        return _read_linear_tiff(path, half_size)
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        raise InputError(f"cannot be read ({exc.strerror})", path) from None
    if not head:
        raise InputError("the file is empty", path)

    import rawpy

    try:
        with rawpy.imread(os.fspath(path)) as raw:
            black, white = _channel_levels(raw)
            span = white - black
            if not np.all(span > 0):
                raise InputError(
                    f"the raw file's white level {white.tolist()} is not above its black "
                    f"level {black.tolist()}", path)
            ref = float(span.max())
            params: dict[str, Any] = dict(
                gamma=(1, 1), no_auto_bright=True, use_camera_wb=False, use_auto_wb=False,
                user_wb=[1.0, 1.0, 1.0, 1.0], output_color=rawpy.ColorSpace.raw,
                output_bps=16, adjust_maximum_thr=0.0, user_flip=0,
                user_sat=int(round(ref)), highlight_mode=rawpy.HighlightMode.Clip,
                half_size=bool(half_size))
            if not half_size:
                params["demosaic_algorithm"] = rawpy.DemosaicAlgorithm.LINEAR
            data = raw.postprocess(**params)
            wb = raw.camera_whitebalance
            camera_wb = None
            if wb is not None and len(wb) >= 3 and wb[1] > 0 and all(
                    np.isfinite(v) for v in wb[:3]) and min(wb[:3]) > 0:
                camera_wb = (float(wb[0] / wb[1]), 1.0, float(wb[2] / wb[1]))
            extra = {"raw_type": str(raw.raw_type), "color_desc": raw.color_desc.decode(
                "ascii", "replace"), "sizes": tuple(raw.sizes)}
    except InputError:
        raise
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        detail = exc.args[0] if exc.args else ""
        if isinstance(detail, bytes):
            detail = detail.decode("utf-8", "replace")
        raise InputError(f"not a raw file LibRaw can read ({type(exc).__name__}: {detail})",
                         path) from None
    rgb = data.astype(np.float32)
    rgb *= np.float32(1.0 / 65535.0)
    if data.ndim == 2:  # monochrome sensor
        rgb = np.repeat(rgb[:, :, None], 3, axis=2)
    rgb = rgb[..., :3]
    # LibRaw scaled every channel by 1/ref (the largest span); channels with a smaller span
    # are stretched so that their own white level maps to 1 as well.
    gain = (ref / span).astype(np.float32)
    if not np.allclose(gain, 1.0):
        rgb *= gain
        np.clip(rgb, 0.0, 1.0, out=rgb)
    return RawImage(rgb=np.ascontiguousarray(rgb), camera_wb=camera_wb,
                    exposure=read_raw_exposure_info(path), path=path,
                    black_level=tuple(float(b) for b in black),
                    white_level=tuple(float(w) for w in white), source="libraw",
                    half_size=bool(half_size), extra=extra)
