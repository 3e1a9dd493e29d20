"""Vignetting from lensfun's lens database (through ``lensfunpy``).

The camera and lens a frame's EXIF names (:func:`selfcal.io.images.read_lens_info`) are
looked up in lensfun's database ([lensfun]); the lens's vignetting calibration is
interpolated at the frame's focal length, f-number and focus distance, and returned as a
:class:`~selfcal.lens.vignetting.Vignetting` with ``source="lens"``, beside a
:class:`LensMatch` that records what EXIF said, what was matched and how well.

Lensfun's vignetting model is ``pa`` ([lensfun], ``LF_VIGNETTING_MODEL_PA``; Pablo
d'Angelo's, the form of [Goldman2010] Eq. 4)::

    Cd = Cs · (1 + k₁ r² + k₂ r⁴ + k₃ r⁶)

Its radius is normalised so that ``r = 1`` at half the diagonal of the *calibration*
frame: lensfun's ``AddColorCallbackVignetting`` (``libs/lensfun/mod-color.cpp``, 0.3.x:
"Hugin uses two different normalized coordinate systems: for distortions it uses 1.0 =
min(half width, half height) and for vignetting it uses 1.0 = half diagonal length"), and
in lensfun's development line ``rescale_polynomial_coefficients`` divides the terms by
powers of ``real_focal / (hypot(36, 24) / calibration_crop / 2)``, the calibration sensor's
half diagonal in millimetres.  A frame from a camera of crop factor ``c`` (the lens
calibrated at crop factor ``c₀``) has a half diagonal ``c₀ / c`` times the calibration's,
so in our units (half the frame's own diagonal,
:func:`~selfcal.lens.vignetting.normalised_radius`) ``r_lensfun = s · r`` with
``s = c₀ / c``, and the coefficients become ``(k₁ s², k₂ s⁴, k₃ s⁶)``.  The frame's
aspect ratio does not enter (lensfun 0.3 normalises by the frame's own diagonal, as we do).
``tests/test_lens_sources.py`` checks the resulting map against lensfun's own
``Modifier.apply_color_modification`` on a flat image, at equal and at different crop
factors (lensfunpy 1.11.1 and 1.17.0 agree).  Lensfun puts the corner *pixel centre* at
``r = 1``, we put the frame's corner there: the radii differ by about a pixel, V by at
most 0.004 on a 600 × 400 frame, less on larger ones.

What is ours: the match policy (:func:`match_lens`), the default focus distance and the
floor on the profile's uncertainty (:data:`LOG_SIGMA_FLOOR`, ``docs/decisions.md``).

A lens profile describes the optics of a raw capture.  Many cameras correct vignetting in
their JPEGs ("peripheral illumination correction", "shading compensation"); dividing a
profile out of such a JPEG over-corrects the corners.  The profile cannot tell: compare it
with a self-calibrated or flat-field vignetting when in doubt.

References
----------
[lensfun] The lensfun library and database, https://lensfun.github.io/ (lensfunpy wraps
0.3.x); ``include/lensfun/lensfun.h.in`` (``lfLensCalibVignetting``) and
``libs/lensfun/mod-color.cpp``.
[Goldman2010] D. B. Goldman, "Vignette and exposure calibration and compensation",
IEEE TPAMI 32(12), 2010.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..io.images import LensInfo, read_lens_info
from ..typing import PathLike
from .vignetting import Vignetting

__all__ = ["LensMatch", "match_lens", "lens_vignetting", "DEFAULT_DISTANCE_M",
           "LOG_SIGMA_FLOOR", "open_database"]

#: Focus distance (m) used when EXIF gives none: lensfun's own default (its
#: ``Modifier.initialize`` takes 1000 m, focus at infinity).  Vignetting changes little
#: with distance; most profiles are measured at one or two distances only.
DEFAULT_DISTANCE_M = 1000.0
#: Standard deviation of ``log V`` at the corner (r = 1) that a lens profile does not
#: state: the spread between units of a lens and the interpolation between calibrated
#: apertures (``docs/decisions.md``, "lens profile uncertainty").
LOG_SIGMA_FLOOR = 0.03

_DATABASE = None


def open_database() -> Any:
    """Lensfun's database as lensfunpy bundles it (loaded once, then kept)."""
    global _DATABASE
    if _DATABASE is None:
        try:
            import lensfunpy
        except ImportError as exc:  # pragma: no cover - a declared dependency
            raise InputError(f"the lens database needs lensfunpy ({exc})") from None
        _DATABASE = lensfunpy.Database()
    return _DATABASE


@dataclass
class LensMatch:
    """What EXIF said, what lensfun matched, and at which settings (plain values).

    Attributes
    ----------
    exif : dict
        The fields of :class:`~selfcal.io.images.LensInfo` read from the file.
    camera : str or None
        The camera matched ("maker model"), or None.
    camera_crop : float or None
        Its crop factor (lensfun's).
    lens : str or None
        The lens matched ("maker model"), or None.
    lens_crop : float or None
        The crop factor the lens was calibrated at.
    score : int or None
        Lensfun's match score of the lens (higher is closer).
    candidates : list of str
        The best few lenses lensfun offered, with their scores.
    focal_length, f_number, distance : float or None
        The settings the vignetting was interpolated at.
    distance_source : str
        ``"given"`` (the ``distance`` argument), ``"exif"`` or ``"default"``
        (:data:`DEFAULT_DISTANCE_M`).
    extrapolated : list of str
        Settings outside the range the lens's vignetting was calibrated over.
    reason : str or None
        Why there is no vignetting (None when there is one).
    """

    exif: dict
    camera: str | None = None
    camera_crop: float | None = None
    lens: str | None = None
    lens_crop: float | None = None
    score: int | None = None
    candidates: list = field(default_factory=list)
    focal_length: float | None = None
    f_number: float | None = None
    distance: float | None = None
    distance_source: str = ""
    extrapolated: list = field(default_factory=list)
    reason: str | None = None

    def to_dict(self) -> dict:
        """A JSON-ready dict."""
        return asdict(self)


def _name(item) -> str:
    maker, model = str(item.maker or "").strip(), str(item.model or "").strip()
    return model if not maker or model.lower().startswith(maker.lower()) else f"{maker} {model}"


def match_lens(info: LensInfo, *, database: Any = None) -> tuple[LensMatch, Any, Any]:
    """Find the camera and lens of ``info`` in lensfun's database (ours: the policy).

    The camera by EXIF make and model (``Database.find_cameras``); the lens by EXIF lens
    make and model among the lenses that fit the camera (``Database.find_lenses``, lensfun's
    fuzzy scoring; the best score wins, a tie between two lenses is refused as ambiguous;
    of several entries of the best lens, calibrated on bodies of other crop factors, the
    best-scoring one with vignetting data).  The camera search
    is strict (a loose one takes a Sony DSC-W1 for a DSC-W180), retried with the make
    prefixed to the model (Canon writes "EOS 5D Mark II" as well as "Canon EOS 5D Mark
    II").  A frame whose EXIF names no lens is matched only when a single lens fits the
    camera (a fixed-lens camera).  No camera, no match: the crop factor is the camera's.

    Returns
    -------
    (LensMatch, lensfunpy.Camera or None, lensfunpy.Lens or None)
        ``LensMatch.reason`` says why when the lens is None.
    """
    db = open_database() if database is None else database
    record = LensMatch(exif=asdict(info))
    cameras = []
    if info.make and info.model:
        cameras = (db.find_cameras(info.make, info.model)
                   or db.find_cameras(info.make, f"{info.make} {info.model}"))
    camera = cameras[0] if cameras else None
    if camera is not None:
        record.camera, record.camera_crop = _name(camera), float(camera.crop_factor)
    if camera is None:
        what = " ".join(v for v in (info.make, info.model) if v) or "none named"
        record.reason = f"lensfun does not know the camera ({what})"
        return record, None, None
    if info.lens_model:
        lenses = list(db.find_lenses(camera, info.lens_make, info.lens_model))
    else:
        lenses = list(db.find_lenses(camera))
        if len(lenses) != 1:
            record.reason = (f"EXIF names no lens model (a maker note may; selfcal does not "
                             f"read maker notes) and {len(lenses)} lenses fit the "
                             f"{record.camera}")
            return record, camera, None
    lenses.sort(key=lambda lens: -int(lens.score))
    record.candidates = [f"{_name(lens)} ({int(lens.score)})" for lens in lenses[:4]]
    if not lenses:
        record.reason = (f"lensfun has no lens matching {info.lens_model!r}"
                         + (f" for the {record.camera}" if record.camera else ""))
        return record, camera, None
    if len(lenses) > 1 and int(lenses[0].score) == int(lenses[1].score) and \
            _name(lenses[0]) != _name(lenses[1]):
        record.reason = (f"lens {info.lens_model!r} is ambiguous in lensfun: "
                         + ", ".join(record.candidates[:2]))
        return record, camera, None
    # lensfun 0.3 lists one entry per calibration body: of the best-named lens, the
    # best-scoring entry that holds vignetting data (the same optics, another crop)
    same = [lens for lens in lenses if _name(lens) == _name(lenses[0])]
    lens = next((lens for lens in same if lens.calib_vignetting), lenses[0])
    record.lens, record.lens_crop = _name(lens), float(lens.crop_factor)
    record.score = int(lens.score)
    return record, camera, lens


def _calibrated_range(lens, record: LensMatch) -> None:
    table = [(c.focal, c.aperture, c.distance) for c in lens.calib_vignetting or []]
    if not table:
        return
    f, a, d = (np.array(v, float) for v in zip(*table))
    for name, value, values in (("focal length", record.focal_length, f),
                                ("f-number", record.f_number, a),
                                ("distance", record.distance, d)):
        if value is not None and not (values.min() * 0.999 <= value <= values.max() * 1.001):
            record.extrapolated.append(f"{name} {value:g} outside {values.min():g}.."
                                       f"{values.max():g}")


def lens_vignetting(source: PathLike | LensInfo, *, distance: float | None = None,
                    database: Any = None) -> tuple[Vignetting | None, LensMatch]:
    """The vignetting of the lens a frame was taken with, from lensfun's profile.

    ``V(r) = 1 + k₁r² + k₂r⁴ + k₃r⁶`` ([Goldman2010] Eq. 4, lensfun's ``pa`` model),
    interpolated by lensfun (``Lens.interpolate_vignetting``) at the frame's focal length,
    f-number and focus distance, with the radius converted from lensfun's normalisation
    (half the calibration frame's diagonal) to ours (half this frame's diagonal) by the
    ratio of crop factors (module docstring).

    Parameters
    ----------
    source : path or LensInfo
        A frame whose EXIF names camera and lens (:func:`~selfcal.io.images.read_lens_info`),
        or those fields.
    distance : float, optional
        Focus distance in metres; default EXIF's SubjectDistance, else
        :data:`DEFAULT_DISTANCE_M`.
    database : lensfunpy.Database, optional
        Default: the database lensfunpy bundles (:func:`open_database`).

    Returns
    -------
    (Vignetting or None, LensMatch)
        The vignetting (``source="lens"``, ``aspect=None``: a profile applies to any frame
        of the camera, ``log_sigma_floor`` = :data:`LOG_SIGMA_FLOOR`, no covariance) and the
        match record (also in ``Vignetting.diagnostics["lens_match"]``); None and the
        record's ``reason`` when no profile applies.  Missing EXIF or an unknown lens is
        not an error: the caller decides.

    Raises
    ------
    InputError
        When ``source`` is a file that cannot be read.
    """
    info = source if isinstance(source, LensInfo) else read_lens_info(source)
    record, camera, lens = match_lens(info, database=database)
    if lens is None:
        return None, record
    if not info.focal_length or not info.f_number:
        missing = " and ".join(n for n, v in (("focal length", info.focal_length),
                                              ("f-number", info.f_number)) if not v)
        record.reason = f"EXIF gives no {missing}: the profile cannot be interpolated"
        return None, record
    if distance is None:
        distance, record.distance_source = (
            (info.focus_distance, "exif") if info.focus_distance
            else (DEFAULT_DISTANCE_M, "default"))
    else:
        record.distance_source = "given"
    record.focal_length, record.f_number = float(info.focal_length), float(info.f_number)
    record.distance = float(distance)
    if not lens.calib_vignetting:
        record.reason = f"lensfun's profile of the {record.lens} has no vignetting data"
        return None, record
    calib = lens.interpolate_vignetting(record.focal_length, record.f_number,
                                        record.distance)
    if calib is None or "PA" not in str(calib.model).upper():
        record.reason = (f"lensfun cannot interpolate the {record.lens}'s vignetting at "
                         f"{record.focal_length:g} mm f/{record.f_number:g}")
        return None, record
    _calibrated_range(lens, record)
    s2 = (float(lens.crop_factor) / float(camera.crop_factor)) ** 2
    k = np.asarray(calib.terms[:3], np.float64) * np.array([s2, s2 ** 2, s2 ** 3])
    description = (f"lensfun: {record.lens} at {record.focal_length:g} mm "
                   f"f/{record.f_number:g} (match score {record.score})")
    vignetting = Vignetting(np.tile(k, (3, 1)), np.zeros(2), source="lens",
                            description=description, covariance=None,
                            log_sigma_floor=LOG_SIGMA_FLOOR, aspect=None,
                            diagnostics={"lens_match": record.to_dict()})
    return vignetting, record
