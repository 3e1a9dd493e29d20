"""EXIF: the exposure a frame was taken with (time, f-number, ISO) and the lens it was taken
through (make, model, lens, focal length, focus distance), read with Pillow; EXIF blocks
written with piexif (the simulator's frames).  Re-exported by :mod:`selfcal.io.images`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..typing import PathLike

_EXIF_IFD = 0x8769
_TAG_EXPOSURE_TIME = 0x829A
_TAG_FNUMBER = 0x829D
_TAG_ISO = 0x8827
_TAG_SHUTTER_APEX = 0x9201


@dataclass(frozen=True)
class ExposureInfo:
    """Exposure settings read from a file's EXIF; ``None`` where the tag is absent."""

    exposure_time: float | None
    f_number: float | None
    iso: float | None

    @property
    def relative_exposure(self) -> float | None:
        """Exposure time × ISO / N², the quantity pixel values scale with (None if no time)."""
        if self.exposure_time is None:
            return None
        scale = 1.0
        if self.iso:
            scale *= self.iso / 100.0
        if self.f_number:
            scale /= self.f_number**2
        return self.exposure_time * scale


def format_exposure_time(t: float | None, *, unknown: str = "?") -> str:
    """Seconds as a photographer writes them, without the unit: ``1/250``, ``1/3.2``, ``2``.

    Times under a second are written as a reciprocal, rounded to an integer when within
    2 % of one (EXIF's 1/249.99 is 1/250); ``None`` or a non-finite time gives ``unknown``.

    >>> format_exposure_time(0.004), format_exposure_time(0.3125), format_exposure_time(2.0)
    ('1/250', '1/3.2', '2')
    >>> format_exposure_time(0.9996)
    '0.9996'

    """
    if t is None or not math.isfinite(t):
        return unknown
    if t < 1 and round(1.0 / t) > 1:      # 0.9996 s is "1", not "1/1"
        inv = 1.0 / t
        return f"1/{round(inv)}" if abs(inv - round(inv)) < 0.02 * inv else f"1/{inv:.3g}"
    return f"{t:.4g}"


def effective_exposure_times(infos: Sequence[ExposureInfo]) -> list[float | None]:
    """Exposure times scaled to the first timed frame's ISO and aperture.

    Pixel values scale with t · ISO / N², so a frame shot at another ISO or f-number is
    given the time that would have exposed it equally at the first frame's settings; the
    result stays in seconds.  ``None`` where a frame has no time.
    """
    ref = next((i for i in infos if i.exposure_time is not None), None)
    out = []
    for info in infos:
        t = info.exposure_time
        if t is not None and ref is not None:
            if info.iso and ref.iso:
                t *= info.iso / ref.iso
            if info.f_number and ref.f_number:
                t *= (ref.f_number / info.f_number) ** 2
        out.append(t)
    return out


def rational_value(value) -> float | None:
    try:
        if isinstance(value, tuple):  # (num, den) as some writers give
            num, den = value
            return float(num) / float(den) if den else None
        result = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return result if np.isfinite(result) else None


def _exif_directories(path: PathLike) -> tuple[dict, dict]:
    """IFD0 and the Exif sub-IFD (0x8769) of a file's EXIF, as dicts of tag → value.

    Raises InputError (naming the file) when it cannot be opened as an image.
    """
    from PIL import Image

    try:
        with Image.open(path) as im:
            exif = im.getexif()
            return dict(exif), dict(exif.get_ifd(_EXIF_IFD))
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except Exception as exc:
        raise InputError(f"not an image file selfcal reads ({exc})", path) from None


def read_exposure_info(path: PathLike) -> ExposureInfo:
    """Read exposure time, f-number and ISO from a file's EXIF.

    Falls back to the APEX ShutterSpeedValue (t = 2^-Tv) when ExposureTime is missing.
    Never raises for missing tags; raises InputError only when the file cannot be opened.
    """
    path = Path(path)
    exif, sub = _exif_directories(path)

    def tag(code):
        # TIFF/EP writers put the exposure tags in IFD0 rather than the EXIF sub-IFD
        value = sub.get(code)
        return exif.get(code) if value is None else value

    time = rational_value(tag(_TAG_EXPOSURE_TIME))
    if time is None or time <= 0:
        apex = rational_value(tag(_TAG_SHUTTER_APEX))
        time = float(2.0 ** (-apex)) if apex is not None else None
    fnum = rational_value(tag(_TAG_FNUMBER))
    iso = tag(_TAG_ISO)
    if isinstance(iso, tuple):
        iso = iso[0] if iso else None
    iso = rational_value(iso)
    return ExposureInfo(
        exposure_time=time if time and time > 0 else None,
        f_number=fnum if fnum and fnum > 0 else None,
        iso=iso if iso and iso > 0 else None,
    )


_TAG_MAKE, _TAG_MODEL, _TAG_LENS_MAKE, _TAG_LENS_MODEL = 0x010F, 0x0110, 0xA433, 0xA434
_TAG_FOCAL, _TAG_FOCAL_35MM, _TAG_SUBJECT_DISTANCE = 0x920A, 0xA405, 0x9206


@dataclass(frozen=True)
class LensInfo:
    """Camera and lens as a file's EXIF names them; ``None`` where a tag is absent.

    ``focus_distance`` is SubjectDistance (m); ``focal_length_35mm`` FocalLengthIn35mmFilm.
    """

    make: str | None
    model: str | None
    lens_make: str | None
    lens_model: str | None
    focal_length: float | None
    f_number: float | None
    focus_distance: float | None
    focal_length_35mm: float | None = None


def read_lens_info(path: PathLike) -> LensInfo:
    """Read camera make and model, lens make and model, focal length, f-number and focus
    distance from a file's EXIF (IFD0 and the Exif IFD 0x8769: LensMake 0xA433, LensModel
    0xA434, FocalLength 0x920A, SubjectDistance 0x9206).

    Never raises for missing tags (a lens named only in a maker note reads as None);
    raises InputError only when the file cannot be opened.
    """
    exif, sub = _exif_directories(path)

    def text(code):
        value = sub.get(code, exif.get(code))
        if isinstance(value, bytes):
            value = value.decode("utf-8", "replace")
        return (str(value).replace("\x00", " ").strip() or None) if value is not None else None

    def positive(code):
        value = rational_value(sub.get(code, exif.get(code)))
        return value if value is not None and value > 0 else None

    return LensInfo(make=text(_TAG_MAKE), model=text(_TAG_MODEL),
                    lens_make=text(_TAG_LENS_MAKE), lens_model=text(_TAG_LENS_MODEL),
                    focal_length=positive(_TAG_FOCAL), f_number=positive(_TAG_FNUMBER),
                    focus_distance=positive(_TAG_SUBJECT_DISTANCE),
                    focal_length_35mm=positive(_TAG_FOCAL_35MM))


def exif_rational(x: float, max_den: int = 1_000_000) -> tuple[int, int]:
    """``x`` as an EXIF/TIFF RATIONAL ``(numerator, denominator)``, as cameras write it.

    ``max_den`` bounds the denominator: 1,000,000 suits exposure times (1/8000 s is exact),
    100 an f-number (f/5.6 is 28/5).

    >>> exif_rational(1 / 250), exif_rational(5.6, 100)
    ((1, 250), (28, 5))
    """
    fr = Fraction(float(x)).limit_denominator(max_den)
    return fr.numerator, fr.denominator


def exif_bytes(exposure_time=None, f_number=None, iso=None, make="selfcal", model="synth", *,
               lens_make=None, lens_model=None, focal_length=None, focus_distance=None):
    """An EXIF block (bytes, piexif) with the exposure tags, the camera and, when given, the
    lens: LensMake, LensModel, FocalLength (mm), SubjectDistance (m); see
    :func:`read_lens_info`."""
    import piexif

    exif_ifd: dict[int, Any] = {}
    for tag, value in ((piexif.ExifIFD.LensMake, lens_make),
                       (piexif.ExifIFD.LensModel, lens_model)):
        if value is not None:
            exif_ifd[tag] = str(value).encode()
    for tag, value in ((piexif.ExifIFD.FocalLength, focal_length),
                       (piexif.ExifIFD.SubjectDistance, focus_distance)):
        if value is not None:
            exif_ifd[tag] = exif_rational(value, 1000)
    if exposure_time is not None:
        exif_ifd[piexif.ExifIFD.ExposureTime] = exif_rational(exposure_time)
    if f_number is not None:
        exif_ifd[piexif.ExifIFD.FNumber] = exif_rational(f_number, 100)
    if iso is not None:
        exif_ifd[piexif.ExifIFD.ISOSpeedRatings] = int(round(iso))
    zeroth = {piexif.ImageIFD.Make: make.encode(), piexif.ImageIFD.Model: model.encode()}
    return piexif.dump({"0th": zeroth, "Exif": exif_ifd})
