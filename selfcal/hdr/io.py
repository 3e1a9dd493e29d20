"""Writing radiance maps, linearised images and tone-mapped previews, atomically.

Formats chosen by the file suffix:

* ``.exr`` -- OpenEXR, 32-bit float or 16-bit half (``half=True``), through OpenCV
  (``OPENCV_IO_ENABLE_OPENEXR=1`` is set before OpenCV is imported);
* ``.hdr`` / ``.pic`` -- Radiance RGBE (Ward, *Real Pixels*, Graphics Gems II, 1991), through
  OpenCV (8-bit mantissas with a shared exponent: about 1 % relative precision);
* ``.tif`` / ``.tiff`` -- float32 (or float16 with ``half=True``) RGB TIFF, through tifffile.

Half floats end at 65,504.  Rather than write ``inf`` there (a radiance in EXIF units,
``t·ISO/100/N²``, exceeds it for a daylight bracket: f/16, ISO 100, 1/4000 s), a half-float
output whose largest magnitude exceeds :data:`HALF_LIMIT` (2¹⁵ = 32,768) is stored divided
by a power of two, and the factor is recorded in the file -- the EXR header attribute
``selfcalRadianceScale`` (type ``double``), or the JSON of the TIFF's ImageDescription tag
(key ``selfcalRadianceScale``).  **A reader must multiply the stored values by it**
(:func:`read_radiance` does).  Files that fit are written unscaled and carry no attribute.

Every file is written to a temporary file with the same suffix in the target folder and
renamed onto the target (:func:`selfcal.io.atomic_output`); an existing file is replaced
only with ``force=True``, and an input never.
"""

from __future__ import annotations

import json
import math
import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..typing import PathLike
from ..io.images import OutputWriteError, atomic_output, exif_rational, import_cv2, write_image
from ..response.curve_family import srgb_encode
from ..lens.luminance import SRGB_CHROMATICITIES

__all__ = [
    "OutputWriteError",
    "RADIANCE_SUFFIXES",
    "HALF_LIMIT",
    "SCALE_ATTRIBUTE",
    "RadianceFile",
    "half_scale",
    "EXR_COMPRESSIONS",
    "write_radiance",
    "write_radiance_sigma",
    "units_metadata",
    "UNITS",
    "RADIANCE_EFFICACY",
    "read_radiance",
    "read_sigma",
    "write_sigma_tiff",
    "sigma_path",
    "tonemap_reinhard",
    "write_preview",
    "write_linear",
]

RADIANCE_SUFFIXES = {".exr", ".hdr", ".pic", ".tif", ".tiff"}

#: The largest magnitude a half-float output stores: 2¹⁵, about half of float16's largest
#: finite value (65,504), so rounding to half cannot overflow and a reader can still double
#: the values (an exposure adjustment) without reaching inf.
HALF_LIMIT = 2.0 ** 15

#: Name of the recorded scale: an EXR header attribute (``double``) and a key of the JSON
#: in a TIFF's ImageDescription tag.  Stored values times it are the radiance.
SCALE_ATTRIBUTE = "selfcalRadianceScale"


def _check_radiance(radiance) -> np.ndarray:
    arr = np.asarray(radiance)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"expected an HxWx3 radiance array, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        raise InputError(f"radiance must be float, got {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        raise InputError("radiance holds NaN or infinite values")
    return arr


@dataclass(frozen=True)
class RadianceFile:
    """What :func:`write_radiance` wrote: the path, and the scale a reader multiplies by.

    ``os.PathLike`` (and ``str()`` gives the path), so it can be used wherever the
    written path is wanted.

    Attributes
    ----------
    path : pathlib.Path
    scale : float
        Stored values times ``scale`` are the radiance: 1 unless a half-float output had
        to be scaled into range (then a power of two > 1, also recorded in the file as
        :data:`SCALE_ATTRIBUTE`).
    """

    path: Path
    scale: float = 1.0

    def __fspath__(self) -> str:
        return os.fspath(self.path)

    def __str__(self) -> str:
        return str(self.path)


def half_scale(radiance) -> float:
    """The power of two a half-float output of ``radiance`` is divided by (ours).

    ``2**k`` with the smallest integer ``k >= 0`` such that ``max|radiance| / 2**k <=``
    :data:`HALF_LIMIT`; 1 when the values fit as they are.  Dividing by a power of two is
    exact, so stored values times the scale equal the radiance to half precision (relative
    error ≤ 2⁻¹¹ for stored magnitudes ≥ 2⁻¹⁴; smaller ones are float16 subnormals, and
    magnitudes below ``2⁻²⁴ · scale`` are stored as 0).
    """
    arr = np.asarray(radiance)
    peak = float(np.max(np.abs(arr))) if arr.size else 0.0
    if not peak <= HALF_LIMIT:
        return float(2.0 ** math.ceil(math.log2(peak / HALF_LIMIT)))
    return 1.0


#: OpenEXR compressions (lossless ones; PIZ is the usual choice for photographs).
EXR_COMPRESSIONS = ("piz", "zip", "zips", "rle", "none")


def write_radiance(path: PathLike, radiance: np.ndarray, *, force: bool = False,
                   half: bool = False, inputs: Iterable[PathLike] = (),
                   compression: str = "piz", units: str = "relative") -> RadianceFile:
    """Write an RGB radiance map as OpenEXR, Radiance HDR or float TIFF, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The output file; its suffix chooses the format (``.exr``, ``.hdr``/``.pic``,
        ``.tif``/``.tiff``).
    radiance : numpy.ndarray
        ``HxWx3`` float RGB (channel last, as :func:`selfcal.merge_hdr` returns it).
    force : bool
        Replace an existing file.
    half : bool
        16-bit half floats (EXR ``IMWRITE_EXR_TYPE_HALF``; float16 TIFF).  Never writes
        inf: when ``max|radiance|`` exceeds :data:`HALF_LIMIT`, the values are stored
        divided by the power of two :func:`half_scale` gives, and that factor is recorded
        as :data:`SCALE_ATTRIBUTE` (EXR header attribute; TIFF ImageDescription JSON) and
        returned -- a reader must multiply the stored values by it.  Ignored for RGBE,
        which has its own 32-bit shared-exponent encoding (up to about 1.7e38).
    inputs : iterable of paths
        Files never to be written over.
    compression : {"piz", "zip", "zips", "rle", "none"}
        OpenEXR compression (all lossless).  PIZ (wavelet) is the default: on a 24 MP
        merged frame it wrote 5-10x faster than OpenCV's default ZIP at a similar size.
    units : {"relative", "cd/m2"}
        Of the values (:attr:`selfcal.hdr.HDRResult.units`).  What the files say
        (:func:`units_metadata`): an EXR always carries ``chromaticities`` (sRGB / Rec. 709
        primaries, D65: the values are scene-linear in the JPEG's output primaries) and,
        in cd/m², ``whiteLuminance`` (the cd/m² of the stored RGB (1, 1, 1)); an RGBE file
        carries ``PRIMARIES=`` and, in cd/m², ``EXPOSURE=179``; a TIFF ``selfcalUnits``
        in its ImageDescription JSON.

    Returns
    -------
    RadianceFile
        The path (``os.PathLike``) and the scale a reader multiplies the stored values by
        (1 unless a half-float output was scaled into range).

    Raises
    ------
    InputError
        Unknown suffix or compression, or a radiance array that is not finite ``HxWx3`` float.
    OutputExistsError
        The file exists and ``force`` is false, or it is one of ``inputs``.
    OutputWriteError
        The encoder or the file system failed.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in RADIANCE_SUFFIXES:
        raise InputError(f"unsupported radiance format {path.suffix!r} "
                         "(use .exr, .hdr or .tif)", path)
    if units not in UNITS:
        raise InputError(f"units must be one of {UNITS}, not {units!r}", path)
    arr = _check_radiance(radiance)
    scale = half_scale(arr) if half and suffix not in (".hdr", ".pic") else 1.0
    if suffix in (".tif", ".tiff"):
        if scale != 1.0:
            data = (arr.astype(np.float32) / np.float32(scale)).astype(np.float16)
        else:
            data = arr.astype(np.float16 if half else np.float32, copy=False)
        meta = {**({SCALE_ATTRIBUTE: scale} if scale != 1.0 else {}),
                **({UNITS_KEY: units} if units != "relative" else {})}
        _write_tiff(path, data, force=force, inputs=inputs, metadata=meta or None)
        return RadianceFile(path, scale)

    cv2 = import_cv2()
    bgr = np.ascontiguousarray(arr[:, :, ::-1], dtype=np.float32)
    if scale != 1.0:
        bgr /= np.float32(scale)
    if suffix == ".exr":
        codes = {"piz": cv2.IMWRITE_EXR_COMPRESSION_PIZ, "zip": cv2.IMWRITE_EXR_COMPRESSION_ZIP,
                 "zips": cv2.IMWRITE_EXR_COMPRESSION_ZIPS,
                 "rle": cv2.IMWRITE_EXR_COMPRESSION_RLE, "none": cv2.IMWRITE_EXR_COMPRESSION_NO}
        if compression not in codes:
            raise InputError(f"unknown EXR compression {compression!r} "
                             f"({', '.join(EXR_COMPRESSIONS)})")
        kind = cv2.IMWRITE_EXR_TYPE_HALF if half else cv2.IMWRITE_EXR_TYPE_FLOAT
        params = [cv2.IMWRITE_EXR_TYPE, kind, cv2.IMWRITE_EXR_COMPRESSION, codes[compression]]
    else:
        bgr = np.maximum(bgr, 0.0)      # RGBE has no negative values
        params = []
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        try:
            ok = cv2.imwrite(str(tmp), bgr, params)
        except cv2.error as exc:
            raise OutputWriteError(path=path,
                                   message=f"OpenCV could not write it ({exc})") from None
        if not ok:
            raise OutputWriteError(path=path,
                                   message=f"OpenCV could not write it (no {suffix} encoder?)")
        tmp = Path(tmp)
        if suffix == ".exr":
            exr = tmp.read_bytes()
            attrs = units_metadata(units, scale)
            if scale != 1.0:
                attrs[SCALE_ATTRIBUTE] = scale
            for name, value in attrs.items():
                kind = _EXR_ATTRIBUTE_TYPES[name]
                raw = struct.pack({"double": "<d", "float": "<f",
                                   "chromaticities": "<8f"}[kind],
                                  *(value if kind == "chromaticities" else [value]))
                exr = _exr_add_attribute(exr, name, kind, raw, path)
            tmp.write_bytes(exr)
        else:
            tmp.write_bytes(_rgbe_add_header(tmp.read_bytes(), units, path))
    return RadianceFile(path, scale)


#: The units a radiance file can be in (:attr:`selfcal.hdr.HDRResult.units`), and the key
#: of the TIFF ImageDescription JSON that says them.
UNITS = ("relative", "cd/m2")
UNITS_KEY = "selfcalUnits"
#: Radiance's luminous efficacy of its W/sr/m² (lm/W): luminance = 179 · (0.265 R + 0.670 G
#: + 0.065 B) of the *original* values, stored / EXPOSURE (Ward, "The RADIANCE Lighting
#: Simulation and Rendering System", SIGGRAPH 1994; Radiance's ``pvalue``/``falsecolor``).
RADIANCE_EFFICACY = 179.0
_EXR_ATTRIBUTE_TYPES = {"chromaticities": "chromaticities", "whiteLuminance": "float",
                        SCALE_ATTRIBUTE: "double"}


def units_metadata(units: str, scale: float = 1.0) -> dict:
    """The OpenEXR header attributes that say a radiance file's colours and units.

    ``chromaticities``: sRGB / Rec. 709 primaries with a D65 white
    (:data:`selfcal.lens.luminance.SRGB_CHROMATICITIES`), always -- JPEG frames are
    encoded in sRGB, so f⁻¹ gives scene-linear values in those primaries (approximate for
    raws, whose camera RGB has its own); and for ``"cd/m2"`` ``whiteLuminance``, the
    luminance of the stored RGB (1, 1, 1): ``scale`` cd/m² (the half-float scale, 1 when
    the values are stored as they are); both are standard OpenEXR attributes.
    """
    attrs: dict = {"chromaticities": SRGB_CHROMATICITIES}
    if units == "cd/m2":
        attrs["whiteLuminance"] = float(scale)
    return attrs


def _rgbe_add_header(data: bytes, units: str, path) -> bytes:
    """Radiance header lines for an RGBE file (ours, after OpenCV's ``FORMAT=`` line):
    ``PRIMARIES=`` (sRGB, D65) and, in cd/m², ``EXPOSURE=179``: the stored values are
    cd/m², so Radiance's original values (stored / EXPOSURE) are W/sr/m² with its 179 lm/W,
    and its luminance ``179 · (0.265 R + 0.670 G + 0.065 B)`` of them is ours (exactly
    for greys; Radiance's weights are for its own primaries)."""
    end = data.find(b"\n\n")
    if not data.startswith(b"#?") or end < 0:
        raise OutputWriteError(path=path,
                               message="the RGBE OpenCV wrote has no Radiance header")
    lines = ["PRIMARIES= " + " ".join(f"{v:.4f}" for v in SRGB_CHROMATICITIES)]
    if units == "cd/m2":
        lines.append(f"EXPOSURE= {RADIANCE_EFFICACY:g}")
    return data[:end + 1] + "\n".join(lines).encode("ascii") + b"\n" + data[end + 1:]


# OpenEXR file layout (openexr.com, "OpenEXR File Layout"): magic, version field, header
# attributes (name NUL, type NUL, int32 size, value) ended by a NUL byte, then the chunk
# offset table (uint64 absolute file offsets), then the chunks.  Scan lines per chunk by
# compression (NO, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A, DWAA, DWAB):
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_EXR_LINES_PER_CHUNK = (1, 1, 1, 16, 32, 16, 32, 32, 32, 256)


def _exr_header(data: bytes, path) -> tuple[dict, int]:
    """The attributes ``name -> (type, raw value)`` of a single-part EXR and the offset
    of the NUL byte that ends its header.  Ours: a reader of the layout, not of pixels."""
    if len(data) < 8 or data[:4] != _EXR_MAGIC:
        raise InputError("not an OpenEXR file", path)
    version = int.from_bytes(data[4:8], "little")
    if version & 0xFF != 2 or version & 0x1A00:       # tiled, deep or multi-part
        raise InputError("an OpenEXR layout other than single-part scan lines "
                         f"(version field {version:#x})", path)
    attrs, pos = {}, 8
    try:
        while data[pos] != 0:
            end = data.index(b"\0", pos)
            name = data[pos:end].decode("latin-1")
            tend = data.index(b"\0", end + 1)
            kind = data[end + 1:tend].decode("latin-1")
            (size,) = struct.unpack_from("<i", data, tend + 1)
            attrs[name] = (kind, data[tend + 5:tend + 5 + size])
            pos = tend + 5 + size
    except (IndexError, ValueError, struct.error):
        raise InputError("truncated OpenEXR header", path) from None
    return attrs, pos


def _exr_add_attribute(data: bytes, name: str, kind: str, value: bytes, path) -> bytes:
    """Insert a header attribute into a single-part scan-line EXR file (ours).

    The header grows by the attribute's length, so every entry of the chunk offset table
    (absolute offsets) moves by as much; the chunks themselves are copied unchanged.
    """
    try:
        attrs, end = _exr_header(data, path)
        if name in attrs:
            raise InputError(f"the OpenEXR header has a {name} attribute already", path)
        xmin, ymin, xmax, ymax = struct.unpack("<4i", attrs["dataWindow"][1])
        compression = attrs["compression"][1][0]
        lines = _EXR_LINES_PER_CHUNK[compression]
    except (InputError, KeyError, IndexError, struct.error) as exc:
        raise OutputWriteError(path=path, message=f"the EXR OpenCV wrote cannot take the "
                               f"{name} attribute ({exc})") from None
    chunks = -(-(ymax - ymin + 1) // lines)
    table = np.frombuffer(data, dtype="<u8", count=chunks, offset=end + 1)
    attr = name.encode("latin-1") + b"\0" + kind.encode("latin-1") + b"\0"
    attr += struct.pack("<i", len(value)) + value
    moved = (table + np.uint64(len(attr))).astype("<u8").tobytes()
    return data[:end] + attr + b"\0" + moved + data[end + 1 + 8 * chunks:]


def _recorded_scale(path: Path) -> float:
    """The :data:`SCALE_ATTRIBUTE` recorded in a radiance file, 1 when there is none."""
    suffix = path.suffix.lower()
    value = None
    if suffix == ".exr":
        with open(path, "rb") as fh:
            head = fh.read(1 << 16)
        attrs, _ = _exr_header(head, path)
        if SCALE_ATTRIBUTE in attrs:
            kind, raw = attrs[SCALE_ATTRIBUTE]
            value = struct.unpack("<d" if kind == "double" else "<f", raw)[0]
    elif suffix in (".tif", ".tiff"):
        import tifffile

        with tifffile.TiffFile(path) as tif:
            text = tif.pages[0].description
        try:
            meta = json.loads(text) if text else {}
        except ValueError:
            meta = {}
        if isinstance(meta, dict):
            value = meta.get(SCALE_ATTRIBUTE)
    if value is None:
        return 1.0
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"invalid {SCALE_ATTRIBUTE} {value!r}", path)
    return value


#: Name of the layer of the EXR channels that hold the radiance's σ (``sigma.R`` …), and
#: the suffix of the TIFF beside a TIFF (or RGBE) output that holds it.
SIGMA_LAYER = "sigma"


def sigma_path(path) -> Path:
    """Where :func:`write_radiance_sigma` puts σ for a non-EXR output: ``OUT.sigma.tiff``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.{SIGMA_LAYER}.tiff")


def write_radiance_sigma(path, radiance, sigma, *, force: bool = False, half: bool = False,
                         inputs=(), compression: str = "piz", units: str = "relative"):
    """Write a radiance map with its standard deviation, atomically.

    ``.exr``: one single-part scan-line file with the channels ``R, G, B`` and a
    ``sigma`` layer, ``sigma.R, sigma.G, sigma.B`` (OpenEXR's layer naming, which OpenEXR's
    own tools and OpenImageIO read, [OpenEXR]_), written with the OpenEXR Python bindings.  Other
    suffixes: the radiance as :func:`write_radiance` writes it, and σ as a float TIFF
    beside it (:func:`sigma_path`).  σ may hold +inf (pixels no frame measured,
    :attr:`selfcal.hdr.HDRResult.sigma`); a half-float output scaled into range
    (:func:`half_scale`) stores σ with the same scale.  ``units`` as in
    :func:`write_radiance` (the EXR's ``chromaticities`` and ``whiteLuminance``).

    Returns
    -------
    (RadianceFile, pathlib.Path)
        The radiance file and the file holding σ (the same path for EXR).
    """
    path = Path(path)
    arr = _check_radiance(radiance)
    sig = np.asarray(sigma)
    if sig.shape != arr.shape or np.any(np.isnan(sig)) or np.any(sig < 0):
        raise InputError(f"sigma must be shaped like the radiance {arr.shape}, >= 0, "
                         "without NaN", path)
    if path.suffix.lower() != ".exr":
        spath = sigma_path(path)
        written = write_radiance(path, arr, force=force, half=half, inputs=inputs,
                                 compression=compression, units=units)
        write_sigma_tiff(spath, sig, scale=written.scale, half=half, force=force,
                         inputs=inputs)
        return written, spath
    try:
        import OpenEXR
    except ImportError:     # pragma: no cover - a dependency
        raise InputError("writing the sigma layer of an EXR needs the OpenEXR Python "
                         "bindings (pip install OpenEXR)", path) from None
    modes = {"piz": OpenEXR.PIZ_COMPRESSION, "zip": OpenEXR.ZIP_COMPRESSION,
             "zips": OpenEXR.ZIPS_COMPRESSION, "rle": OpenEXR.RLE_COMPRESSION,
             "none": OpenEXR.NO_COMPRESSION}
    if compression not in modes:
        raise InputError(f"unknown EXR compression {compression!r} "
                         f"({', '.join(EXR_COMPRESSIONS)})")
    scale = half_scale(arr) if half else 1.0
    kind = np.float16 if half else np.float32
    channels = {}
    for name, data in (("", arr), (f"{SIGMA_LAYER}.", sig)):
        scaled = data.astype(np.float32) / np.float32(scale)
        for c, letter in enumerate("RGB"):
            channels[name + letter] = np.ascontiguousarray(scaled[..., c]).astype(kind)
    if units not in UNITS:
        raise InputError(f"units must be one of {UNITS}, not {units!r}", path)
    header = {"compression": modes[compression], "type": OpenEXR.scanlineimage,
              **units_metadata(units, scale)}
    if scale != 1.0:
        header[SCALE_ATTRIBUTE] = float(scale)
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        try:
            with OpenEXR.File(header, channels) as exr:
                exr.write(str(tmp))
        except Exception as exc:     # the bindings raise plain exceptions
            raise OutputWriteError(path=path,
                                   message=f"OpenEXR could not write it ({exc})") from None
    return RadianceFile(path, scale), path


def write_sigma_tiff(path, sigma, *, scale: float = 1.0, half: bool = False,
                     force: bool = False, inputs=()) -> Path:
    """σ as a float32 (float16 with ``half``) RGB TIFF, stored divided by ``scale`` (the
    radiance file's, recorded as :data:`SCALE_ATTRIBUTE` when not 1), atomically."""
    data = (np.asarray(sigma, dtype=np.float32) / np.float32(scale)).astype(
        np.float16 if half else np.float32)
    _write_tiff(Path(path), data, force=force, inputs=inputs,
                metadata={SCALE_ATTRIBUTE: scale} if scale != 1.0 else None)
    return Path(path)


def read_sigma(path) -> np.ndarray:
    """The σ that :func:`write_radiance_sigma` wrote for ``path``, float32 ``HxWx3``.

    EXR: the ``sigma`` layer, read with the OpenEXR bindings; other outputs: the TIFF
    beside them.  Stored values times the recorded scale.
    """
    path = Path(path)
    if path.suffix.lower() != ".exr":
        return read_radiance(sigma_path(path))
    import OpenEXR

    if not path.is_file():
        raise InputError("no such file", path)
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        chans = exr.channels()
        names = [f"{SIGMA_LAYER}.{c}" for c in "RGB"]
        if not all(n in chans for n in names):
            raise InputError("the EXR has no sigma layer", path)
        arr = np.stack([np.asarray(chans[n].pixels, dtype=np.float32) for n in names],
                       axis=-1)
        scale = float(exr.header().get(SCALE_ATTRIBUTE, 1.0))
    return arr * np.float32(scale) if scale != 1.0 else arr


def read_radiance(path: PathLike) -> np.ndarray:
    """Read an EXR, RGBE or float TIFF radiance map as float32 ``HxWx3`` RGB.

    The stored values are multiplied by the scale recorded as :data:`SCALE_ATTRIBUTE`
    (see :func:`write_radiance`), so a scaled half-float file reads back as the radiance.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        import tifffile

        arr = np.asarray(tifffile.imread(path), dtype=np.float32)
    else:
        cv2 = import_cv2()
        bgr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if bgr is None:
            raise InputError("cannot be decoded as a radiance map", path)
        arr = np.ascontiguousarray(bgr[:, :, ::-1], dtype=np.float32)
    scale = _recorded_scale(path)
    if scale != 1.0:
        arr *= np.float32(scale)
    return arr


# --------------------------------------------------------------------------------------
# tone-mapped previews
# --------------------------------------------------------------------------------------

def tonemap_reinhard(radiance: np.ndarray, *, key: float = 0.18, white: float | None = None,
                     mask: np.ndarray | None = None, rows: int = 512) -> np.ndarray:
    """Global photographic tone mapping (Reinhard et al., SIGGRAPH 2002, Eq. 1-4), to uint8.

    ``L`` is the Rec. 709 luminance; ``L̄`` its log-average over the (measured) pixels;
    ``Lm = key · L / L̄``; ``Ld = Lm (1 + Lm / Lw²) / (1 + Lm)`` with the white point
    ``Lw`` (default: the 99.5th percentile of ``Lm``, so a few specular pixels do not
    darken the image); colours keep their ratios, ``RGB_d = RGB · Ld / L``, then the sRGB
    transfer function and 8-bit codes.  Statistics come from a subsample; the mapping runs
    in strips of rows, so a 24 MP map needs little extra memory.

    Parameters
    ----------
    radiance : numpy.ndarray
        ``HxWx3`` float RGB, linear.
    key : float
        The key value ``a`` (0.18: mid-grey).
    white : float, optional
        ``Lw`` in units of the scaled luminance ``Lm``.
    mask : numpy.ndarray, optional
        bool ``HxW``: pixels to take the statistics from (e.g. ``~result.unmeasured``).
    rows : int
        Strip height.

    Returns
    -------
    numpy.ndarray
        uint8 ``HxWx3`` sRGB-encoded RGB.
    """
    arr = _check_radiance(radiance)
    h, w = arr.shape[:2]
    luma = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    step = max(1, int(math.sqrt(h * w / 250_000)))
    sub = arr[::step, ::step].astype(np.float32)
    lum = np.maximum(sub @ luma, 0.0)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)[::step, ::step]
        if m.any():
            lum = lum[m]
    lum = lum[lum > 0]
    if lum.size == 0:
        return np.zeros(arr.shape, dtype=np.uint8)
    log_avg = float(np.exp(np.mean(np.log(lum.astype(np.float64)))))
    scale = key / log_avg
    lw = float(np.percentile(lum * scale, 99.5)) if white is None else float(white)
    lw = max(lw, 1e-6)
    out = np.empty(arr.shape, dtype=np.uint8)
    for y in range(0, h, rows):
        block = np.maximum(arr[y:y + rows].astype(np.float32), 0.0)
        lum_b = block @ luma
        lm = lum_b * scale
        ld = lm * (1 + lm / (lw * lw)) / (1 + lm)
        ratio = np.divide(ld, lum_b, out=np.zeros_like(ld), where=lum_b > 0)
        out[y:y + rows] = (srgb_encode(np.clip(block * ratio[..., None], 0.0, 1.0)) * 255 + 0.5).astype(np.uint8)
    return out


def write_preview(path: PathLike, radiance: np.ndarray, *, force: bool = False,
                  inputs: Iterable[PathLike] = (), key: float = 0.18,
                  mask: np.ndarray | None = None, jpeg_quality: int = 92) -> Path:
    """Write a tone-mapped preview (JPEG or PNG) of a radiance map, atomically.

    The tone mapping is :func:`tonemap_reinhard` (Reinhard et al. 2002, global operator).

    Parameters
    ----------
    path : str or os.PathLike
        ``.jpg``/``.jpeg`` or ``.png``.
    radiance : numpy.ndarray
        ``HxWx3`` float RGB.
    force, inputs
        As in :func:`write_radiance`.
    key : float
        The key value of the tone mapping.
    mask : numpy.ndarray, optional
        Pixels for the tone-mapping statistics.
    jpeg_quality : int
    """
    path = Path(path)
    if path.suffix.lower() not in (".jpg", ".jpeg", ".png"):
        raise InputError(f"unsupported preview format {path.suffix!r} (use .jpg or .png)",
                         path)
    image = tonemap_reinhard(radiance, key=key, mask=mask)
    return write_image(path, image, force=force, inputs=inputs, jpeg_quality=jpeg_quality)


# --------------------------------------------------------------------------------------
# linear images
# --------------------------------------------------------------------------------------

def write_linear(path: PathLike, linear: np.ndarray, *, float32: bool = False,
                 force: bool = False, inputs: Iterable[PathLike] = (),
                 exposure_time: float | None = None, f_number: float | None = None,
                 iso: float | None = None) -> Path:
    """Write a linearised image as a 16-bit or float32 RGB TIFF, atomically.

    16-bit: ``round(clip(x, 0, 1) · 65535)`` (``f⁻¹(max code) = 1`` maps to 65535);
    float32: the values as they are.  Exposure time, f-number and ISO, when given, go into
    IFD0 (TIFF/EP style), where :func:`selfcal.io.read_exposure_info` finds them, so the
    files can be merged with ``merge_hdr(paths, linear=True)``.

    Parameters
    ----------
    path : str or os.PathLike
        ``.tif`` or ``.tiff``.
    linear : numpy.ndarray
        ``HxWx3`` float linear RGB.
    float32 : bool
        Write float32 instead of 16-bit integers.
    force, inputs
        As in :func:`write_radiance`.
    exposure_time, f_number, iso : float, optional
    """
    path = Path(path)
    if path.suffix.lower() not in (".tif", ".tiff"):
        raise InputError(f"linear images are written as TIFF, not {path.suffix!r}", path)
    arr = _check_radiance(linear)
    if float32:
        data = arr.astype(np.float32, copy=False)
    else:
        data = np.empty(arr.shape, dtype=np.uint16)
        rows = 512
        for y in range(0, arr.shape[0], rows):
            data[y:y + rows] = np.clip(arr[y:y + rows] * 65535.0 + 0.5, 0, 65535)
    # tifffile's extratags: (code, TIFF type, count, value, write once)
    tags: list[tuple[int, int, int, tuple[int, int] | int, bool]] = []
    if exposure_time is not None:
        tags.append((33434, 5, 1, exif_rational(exposure_time), False))
    if f_number is not None:
        tags.append((33437, 5, 1, exif_rational(f_number, 100), False))
    if iso is not None:
        tags.append((34855, 3, 1, int(round(iso)), False))
    _write_tiff(path, data, force=force, inputs=inputs, extratags=tags)
    return path


def _write_tiff(path, data, *, force, inputs, extratags=(), metadata=None):
    import tifffile

    # metadata (a dict) goes into ImageDescription as JSON, next to tifffile's "shape"
    extra: dict[str, Any] = {} if metadata is None else {"metadata": dict(metadata)}
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        try:
            tifffile.imwrite(tmp, data, photometric="rgb", extratags=list(extratags),
                             **extra)
        except OSError as exc:
            raise OutputWriteError(path=path, message=f"cannot be written ({exc})") from None
