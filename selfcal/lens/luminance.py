"""The absolute scale: selfcal's relative radiance in candelas per square metre.

A merged radiance map (:func:`selfcal.merge_hdr`) is relative: 1 is the signal that
reaches white (f⁻¹ = 1) in a frame of relative exposure ``e = t · S/100 / N²`` (EXIF time
``t``, ISO ``S``, f-number ``N``).  A :class:`LuminanceScale` is the factor ``C`` that
turns it into luminance, ``L = C · Y(E)`` in cd/m², with the standard deviation of
``log C``.  It comes from one of two places.

**The EXIF convention** (:func:`scale_from_exif`).  The standard output sensitivity of
[ISO12232] (SOS, the rating most cameras report since CIPA DC-004, 2004): a camera set to
ISO ``S`` renders the focal-plane exposure ``H = 10/S`` lux·s at the 18 % grey output of
its sRGB file, the code ``118/255`` (sRGB's encoding of 0.18, 0.461).  The focal-plane
exposure of a scene luminance ``L`` is [ISO12232] (Eq. for the camera exposure)::

    H = q · L · t / N²,   q = 0.65

(``q = (π/4) · T · v · cos⁴θ`` with lens transmittance T = 0.9, vignetting factor
v = 0.98 and θ = 10° off axis).  In a frame of exposure ``e``, the grey code reads
``f⁻¹(118)`` on selfcal's normalised curve, i.e. a relative radiance
``E_g = f⁻¹(118)/e = f⁻¹(118) · 100 N² / (t S)``, and the luminance that gave it is
``L_g = 10 N² / (q t S)``.  The ratio does not depend on ``t``, ``N`` or ``S``::

    C = L_g / E_g = 10 / (100 · q · Y(f⁻¹(118))) = 0.1538 / Y(f⁻¹(118))   cd/m²

with ``Y(f⁻¹(118))`` the Rec. 709 luminance of the model's own inverse response at the
grey code (its three channels; a grey renders at one code in each).  Using the model's
own ``f⁻¹`` there, not the sRGB curve's 0.18, takes the camera's tone curve and JPEG
headroom out of the derivation: ``C · f⁻¹(118) / e`` is the convention's grey whatever
the curve.  (An sRGB curve gives ``C = 0.855``.)  For linear frames, which have no
rendered grey, the saturation-based speed of [ISO12232] is used instead: the exposure
``H = 78/S`` reaches white, so ``C = 78 / (100 q) = 1.2``.

Its uncertainty is the camera's, not the pixels': the SOS convention admits the 18 % grey
at ±1/3 stop of its nominal place (ISO 12232:2006; CIPA DC-004), cameras use the
recommended exposure index (REI) the maker chooses, lenses transmit 80–95 % of the light
(q assumes 90 %), and the image centre sees neither the cos⁴ nor the vignetting that q
includes (there q ≈ 0.71, +0.13 stop).  We state a log-σ of :data:`EXIF_LOG_SIGMA`,
1/3 stop, for all of this (ours: an estimate from those tolerances, not a measurement).

The reflected-light meter constant of [ISO2720], ``K = 12.5`` cd·s/m² (``N²/t = L S/K``),
puts the metered average at ``H = q K / S = 8.1/S``, 0.3 stop below the SOS grey; it
says which luminance a meter calls "correctly exposed", not which code the camera writes,
so it is not the default (:data:`ISO2720_K` is here for comparison).

**A reference reading** (:func:`scale_from_reference`): a spot meter's luminance ``L_ref``
of a region of the scene, or a grey card of reflectance ρ under an illuminance ``E_v``
(lux), ``L_ref = ρ E_v / π`` (a Lambertian surface).  ``C = L_ref / Y(median E)`` over
the region, per channel medians; its log-σ combines the meter's stated accuracy, the
median's standard error from the region's spread and, for a textured region, the
difference between the mean a meter integrates and the median (ours).

**Luminance of the radiance.**  JPEG frames are encoded in sRGB, so f⁻¹ gives
scene-linear values in sRGB's (Rec. 709) primaries with a D65 white; their luminance is
``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (:data:`REC709_LUMA`; IEC 61966-2-1, ITU-R
BT.709).  For raws this is approximate: camera RGB has its own primaries.

References
----------
[ISO12232] ISO 12232:2019, Photography -- Digital still cameras -- Determination of
exposure index, ISO speed ratings, standard output sensitivity, and recommended exposure
index.
[ISO2720] ISO 2720:1974, General purpose photographic exposure meters (photoelectric
type) -- Guide to product specification.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..errors import InputError

__all__ = ["LuminanceScale", "ReferenceReading", "REC709_LUMA", "SRGB_CHROMATICITIES",
           "SOS_GREY_CODE", "CAMERA_Q", "EXIF_LOG_SIGMA", "DEFAULT_METER_ACCURACY",
           "luminance_of", "grey_inverse", "scale_from_exif", "scale_from_reference",
           "card_luminance", "parse_reference", "absolute_radiance"]

#: Rec. 709 / sRGB luminance weights of R, G, B (ITU-R BT.709; IEC 61966-2-1).
REC709_LUMA = (0.2126, 0.7152, 0.0722)
#: The primaries and white point of sRGB / Rec. 709 (CIE 1931 xy): red, green, blue, D65,
#: in the order of OpenEXR's ``chromaticities`` attribute.
SRGB_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: The 18 % grey output of [ISO12232]'s standard output sensitivity, as a fraction of
#: the largest code: 118/255 (sRGB's encoding of 0.18).
SOS_GREY_CODE = 118 / 255
#: Focal-plane exposure times S at the SOS grey (lux·s): H = 10/S.
SOS_EXPOSURE = 10.0
#: Focal-plane exposure times S at saturation, the saturation-based speed (lux·s): 78/S.
SATURATION_EXPOSURE = 78.0
#: [ISO12232]'s ``q`` of ``H = q L t / N²``.
CAMERA_Q = 0.65
#: [ISO2720]'s reflected-light meter constant K (cd·s/m²), for comparison.
ISO2720_K = 12.5
#: Std of log C from EXIF alone: 1/3 stop (see the module docstring; ours).
EXIF_LOG_SIGMA = math.log(2.0) / 3.0
#: Std of log C for linear frames (saturation-based speed; the raw white is not the
#: ISO saturation, so 1/2 stop; ours).
EXIF_LINEAR_LOG_SIGMA = math.log(2.0) / 2.0
#: Default relative accuracy of a luminance or illuminance meter (one σ, 3 %).
DEFAULT_METER_ACCURACY = 0.03
#: Std of log C added when a scale measured on one merge is applied to another merge of
#: the same camera (a model's stored scale): the repeatability of the EXIF exposure's
#: level (shutter and aperture), the value of selfcal.response.bands.EXPOSURE_LOG_SIGMA.
TRANSFER_LOG_SIGMA = 0.02

SOURCES = ("exif-convention", "reference")


@dataclass(frozen=True)
class LuminanceScale:
    """cd/m² per unit of selfcal's relative radiance, and how well it is known.

    Attributes
    ----------
    scale : float
        ``C``: luminance ``L = C · Y(E)`` (cd/m²) of a relative radiance ``E``.
    log_sigma : float
        Standard deviation of ``log C``.
    source : {"exif-convention", "reference"}
    description : str
        The convention, or the reading (region, value, meter accuracy), for people.
    """

    scale: float
    log_sigma: float
    source: str
    description: str = ""

    def __post_init__(self):
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise InputError(f"a luminance scale must be positive and finite, not {self.scale!r}")
        if not (math.isfinite(self.log_sigma) and self.log_sigma >= 0):
            raise InputError(f"a luminance scale's log-sigma must be >= 0, not "
                             f"{self.log_sigma!r}")
        if self.source not in SOURCES:
            raise InputError(f"luminance scale source {self.source!r} is not one of {SOURCES}")

    def to_dict(self) -> dict:
        """A JSON-ready dict (model files, format version 4)."""
        return {"scale": float(self.scale), "log_sigma": float(self.log_sigma),
                "source": self.source, "description": self.description}

    @classmethod
    def from_dict(cls, d: dict) -> "LuminanceScale":
        """Inverse of :meth:`to_dict`."""
        return cls(scale=float(d["scale"]), log_sigma=float(d["log_sigma"]),
                   source=str(d["source"]), description=str(d.get("description", "")))


@dataclass(frozen=True)
class ReferenceReading:
    """A luminance measured in the scene, over a region of the merged map.

    Attributes
    ----------
    region : tuple of int
        ``(x0, y0, x1, y1)`` in pixels of the merged map, ``x1``, ``y1`` exclusive.
    luminance : float
        cd/m² (a spot meter's reading, or :func:`card_luminance`).
    accuracy : float
        The meter's relative accuracy (one σ), default :data:`DEFAULT_METER_ACCURACY`.
    description : str
        What was measured, for people.
    """

    region: tuple
    luminance: float
    accuracy: float = DEFAULT_METER_ACCURACY
    description: str = ""

    def __post_init__(self):
        _check_region(self.region)
        if not (math.isfinite(self.luminance) and self.luminance > 0):
            raise InputError(f"a reference luminance must be positive, not {self.luminance!r}")
        if not (math.isfinite(self.accuracy) and 0 <= self.accuracy < 1):
            raise InputError(f"a meter accuracy must be in [0, 1), not {self.accuracy!r}")


def _check_region(region) -> None:
    if len(region) != 4 or not all(isinstance(v, (int, np.integer)) for v in region):
        raise InputError(f"a region is four integers x0,y0,x1,y1, not {region!r}")
    x0, y0, x1, y1 = region
    if not (0 <= x0 < x1 and 0 <= y0 < y1):
        raise InputError(f"region {x0},{y0},{x1},{y1}: needs 0 <= x0 < x1 and 0 <= y0 < y1")


def luminance_of(rgb) -> np.ndarray:
    """Rec. 709 luminance ``0.2126 R + 0.7152 G + 0.0722 B`` of ``(…, 3)`` linear RGB."""
    return np.asarray(rgb, dtype=np.float64) @ np.asarray(REC709_LUMA)


def card_luminance(reflectance: float, illuminance: float) -> float:
    """Luminance of a Lambertian card: ``L = ρ E_v / π`` (cd/m² from lux)."""
    if not (0 < reflectance <= 1):
        raise InputError(f"a card's reflectance is in (0, 1], not {reflectance!r}")
    if not (math.isfinite(illuminance) and illuminance > 0):
        raise InputError(f"an illuminance must be positive (lux), not {illuminance!r}")
    return reflectance * illuminance / math.pi


def grey_inverse(model) -> float:
    """``Y(f⁻¹)`` at the SOS grey code (118/255 of the largest code) of a response model
    (anything with ``inverse_response(codes) -> (n, 3)`` and ``max_code``)."""
    if not callable(getattr(model, "inverse_response", None)):
        raise InputError("the EXIF luminance convention needs a response model's f⁻¹ at "
                         "the grey code (this model has no inverse_response): give a "
                         "reference reading instead")
    max_code = int(getattr(model, "max_code", 255))
    code = SOS_GREY_CODE * max_code
    lo = int(math.floor(code))
    vals = np.asarray(model.inverse_response(np.array([lo, min(lo + 1, max_code)])), float)
    value = float(luminance_of(vals[0] + (code - lo) * (vals[1] - vals[0])))
    if not value > 0:
        raise InputError("the response model's f⁻¹ is zero at the grey code 118/255: no "
                         "EXIF luminance scale")
    return value


def scale_from_exif(model: object = None, *, log_sigma: float | None = None) -> LuminanceScale:
    """The luminance scale of the SOS convention of [ISO12232] (see the module docstring).

    ``C = SOS_EXPOSURE / (100 · q · Y(f⁻¹(118)))`` with the model's own inverse response
    at the grey code; for ``model=None`` (linear frames) the saturation-based speed,
    ``C = 78 / (100 q)``.  Valid only for radiance whose exposures are EXIF's
    ``t · S/100 / N²`` (:attr:`selfcal.io.ExposureInfo.relative_exposure`).

    Parameters
    ----------
    model : object, optional
        A response model (``inverse_response``, ``max_code``); None for linear frames.
    log_sigma : float, optional
        Default :data:`EXIF_LOG_SIGMA` (1/3 stop), :data:`EXIF_LINEAR_LOG_SIGMA` without
        a model.
    """
    if model is None:
        c = SATURATION_EXPOSURE / (100.0 * CAMERA_Q)
        sig = EXIF_LINEAR_LOG_SIGMA if log_sigma is None else log_sigma
        text = ("ISO 12232 saturation-based speed (linear frames): H = 78/S lux·s at white, "
                f"H = q·L·t/N² with q = {CAMERA_Q}")
    else:
        g = grey_inverse(model)
        c = SOS_EXPOSURE / (100.0 * CAMERA_Q * g)
        sig = EXIF_LOG_SIGMA if log_sigma is None else log_sigma
        text = ("ISO 12232 standard output sensitivity: H = 10/S lux·s at the grey code "
                f"118/255 (model's f⁻¹ there: {g:.4g}), H = q·L·t/N² with q = {CAMERA_Q}; "
                f"EXIF exposures; ±{sig / math.log(2):.2g} stop (1σ)")
    return LuminanceScale(scale=float(c), log_sigma=float(sig), source="exif-convention",
                          description=text)


def scale_from_reference(radiance: np.ndarray, reading: ReferenceReading, *,
                         unmeasured: np.ndarray | None = None) -> LuminanceScale:
    """The luminance scale from a reference reading of a region of a merged map (ours).

    ``C = L_ref / Y(m)`` with ``m`` the per-channel median of the radiance over the
    region's measured pixels.  ``log C``'s variance is the sum of the meter's
    ``accuracy²``, the median's squared standard error ``(1.2533 · s)² / n`` (``s``:
    1.4826 × the median absolute deviation of ``log Y`` over the region, ``n`` pixels;
    pixels taken as independent), and ``log(mean Y / Y(m))²`` -- a meter integrates the
    mean over its spot, we take the median, and the two part where the region is
    textured.

    Raises
    ------
    InputError
        A region outside the map, or with fewer than 16 measured pixels of positive
        luminance.
    """
    arr = np.asarray(radiance)
    h, w = arr.shape[:2]
    x0, y0, x1, y1 = reading.region
    where = f"reference region {x0},{y0},{x1},{y1}"
    if x1 > w or y1 > h:
        raise InputError(f"{where} lies outside the {w}x{h} radiance map")
    block = arr[y0:y1, x0:x1].reshape(-1, 3).astype(np.float64)
    ok = np.ones(len(block), bool)
    if unmeasured is not None:
        ok &= ~np.asarray(unmeasured)[y0:y1, x0:x1].reshape(-1)
    ys = luminance_of(block)
    ok &= np.isfinite(ys) & (ys > 0)
    if ok.sum() < 16:
        raise InputError(f"{where}: {int(ok.sum())} measured pixels of positive "
                         "luminance (at least 16 needed)")
    block, ys = block[ok], ys[ok]
    y_med = float(luminance_of(np.median(block, axis=0)))
    if not y_med > 0:
        raise InputError(f"{where}: its median luminance is not positive")
    logs = np.log(ys)
    spread = 1.4826 * float(np.median(np.abs(logs - np.median(logs))))
    se = 1.2533 * spread / math.sqrt(len(ys))
    texture = math.log(float(np.mean(ys)) / y_med)
    sig = math.sqrt(reading.accuracy ** 2 + se ** 2 + texture ** 2)
    text = (f"{reading.description or f'{reading.luminance:g} cd/m2'} over pixels "
            f"{x0},{y0},{x1},{y1} (median of {len(ys)} measured pixels; meter "
            f"±{100 * reading.accuracy:g} %, region spread {100 * spread:.2g} %)")
    return LuminanceScale(scale=reading.luminance / y_med, log_sigma=sig, source="reference",
                          description=text)


_NUMBER = r"([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)"
_REGION = r"(\d+),(\d+),(\d+),(\d+)"
_SPOT = re.compile(_REGION + r"=" + _NUMBER + r"\s*(cd/m2|cd/m²|nits?)?$", re.I)
_CARD = re.compile(r"card:" + _NUMBER + r"(%?)@" + _NUMBER + r"\s*lux:" + _REGION + r"$",
                   re.I)


def parse_reference(text: str, accuracy: float = DEFAULT_METER_ACCURACY) -> ReferenceReading:
    """A reference reading from text: ``"x0,y0,x1,y1=120cd/m2"`` (a spot meter; the unit
    ``cd/m2``, ``nit`` or none) or ``"card:0.18@500lux:x0,y0,x1,y1"`` (a grey card of
    reflectance 0.18 -- or ``18%`` -- under 500 lux, :func:`card_luminance`).

    >>> parse_reference("10,20,30,40=120cd/m2").luminance
    120.0
    >>> round(parse_reference("card:18%@500lux:0,0,8,8").luminance, 3)
    28.648

    Raises
    ------
    InputError
        Text of neither form, a reversed region, a non-positive value.
    """
    s = str(text).strip().replace(" ", "")
    m = _SPOT.match(s)
    if m:
        region = tuple(int(v) for v in m.group(1, 2, 3, 4))
        value = float(m.group(5))
        return ReferenceReading(region, value, accuracy, f"spot meter {value:g} cd/m2")
    m = _CARD.match(s)
    if m:
        rho = float(m.group(1)) / (100.0 if m.group(2) else 1.0)
        lux = float(m.group(3))
        region = tuple(int(v) for v in m.group(4, 5, 6, 7))
        value = card_luminance(rho, lux)
        return ReferenceReading(region, value, accuracy,
                                f"grey card rho = {rho:g} under {lux:g} lux "
                                f"(L = rho·E/pi = {value:.4g} cd/m2)")
    raise InputError(f"reference {text!r}: expected 'x0,y0,x1,y1=L' (L in cd/m2) or "
                     "'card:RHO@Elux:x0,y0,x1,y1' (e.g. card:0.18@500lux:10,10,60,60)")


def absolute_radiance(how, radiance, sigma, *, model=None, unmeasured=None,
                      exif_exposures: bool = True, linear: bool = False):
    """A merge's radiance and σ in cd/m² (the hook of :func:`selfcal.merge_hdr`, ours).

    ``how`` is ``"exif"`` (:func:`scale_from_exif` with the merge's model), ``"model"``
    (the model's stored :attr:`luminance`), a :class:`ReferenceReading` (measured on this
    radiance) or a :class:`LuminanceScale`.  Radiance and σ are multiplied by ``C``, and
    σ gains the scale's uncertainty in quadrature::

        σ_abs² = (C σ)² + (C E · s)²,   s² = log_sigma² (+ TRANSFER_LOG_SIGMA² for a scale
                                                           measured on another merge)

    The merge's own scale error (``diagnostics["sigma_scale_log"]``, a shift of the whole
    curve) is *not* added: a reference on this merge measures it away, and the EXIF
    scale, taken at the same model's grey code, moves against it.

    Radiance and σ are scaled in place when they are float32 (the merge's own arrays).

    Returns
    -------
    (radiance, sigma or None, summary dict for ``diagnostics["luminance"]``)
    """
    transfer = 0.0
    if isinstance(how, ReferenceReading):
        scale = scale_from_reference(radiance, how, unmeasured=unmeasured)
    elif isinstance(how, LuminanceScale):
        scale = how
        transfer = TRANSFER_LOG_SIGMA if how.source == "reference" else 0.0
    elif how == "exif":
        if not exif_exposures:
            raise InputError("luminance from EXIF needs the exposures from EXIF (time, "
                             "f-number, ISO), not given times: leave the times out, or "
                             "give a reference reading")
        scale = scale_from_exif(None if linear else model)
    elif how == "model":
        stored = getattr(model, "luminance", None)
        if not isinstance(stored, LuminanceScale):
            raise InputError("the response model holds no luminance scale (measure one "
                             "with a reference reading)")
        scale = stored
        transfer = TRANSFER_LOG_SIGMA if stored.source == "reference" else 0.0
    else:
        raise InputError(f"luminance must be None, 'exif', 'model', a ReferenceReading or "
                         f"a LuminanceScale, not {how!r}")
    total = math.hypot(scale.log_sigma, transfer)
    c = np.float32(scale.scale)
    out = np.asarray(radiance, np.float32)
    out *= c
    if sigma is not None:
        sig = np.asarray(sigma, np.float32)
        sig *= c
        extra = np.abs(out) * np.float32(total)
        np.hypot(sig, extra, out=sig)             # +inf stays +inf
        sigma = sig
    summary = {**scale.to_dict(), "transfer_log_sigma": transfer,
               "total_log_sigma": total, "units": "cd/m2"}
    return out, sigma, summary
