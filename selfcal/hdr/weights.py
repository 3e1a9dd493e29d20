"""The merge's weights: Debevec & Malik's hat, inverse noise variance, per-frame tables.

The weighted mean of :func:`selfcal.hdr.merge_hdr` gives each frame ``j`` at each pixel
and channel the weight ``w_j``:

* ``"hat"``: Debevec & Malik's triangle on the normalised code, ``w(z) = 2 min(z, 1 − z)``
  (*Recovering High Dynamic Range Radiance Maps from Photographs*, SIGGRAPH 1997, §2.1);
* ``"noise"`` (the default): the inverse variance of the frame's radiance estimate
  ``f⁻¹(I)/e`` under a shot + read noise model of the sensor (Granados et al., *Optimal
  HDR reconstruction with linear digital cameras*, CVPR 2010; Hasinoff et al.,
  *Noise-optimal capture for high dynamic range photography*, CVPR 2010), the
  minimum-variance combination of the frames' estimates in Debevec & Malik's weighted mean
  (SIGGRAPH 1997, Eq. 6, on linear values).

Ours, not the papers': the code-noise term of :class:`NoiseModel` -- quantisation and JPEG
compression, carried to the linear domain through the slope of the inverse response,
which dominates in JPEGs -- and the variance taken from each frame's own measurement
rather than iterated with the merged estimate as Granados et al. do; a relative term for
errors of the response model and the exposures (:attr:`NoiseModel.relative`); fixed default
noise parameters (not estimated from the stack; docs/decisions.md, "Default weighting:
the noise model, with a 3 % relative error"); the curve's
own error per code, measured on the calibration's samples
(:mod:`selfcal.response.code_error`, the model's ``diagnostics["code_error_log"]``), where
it exceeds what the noise model explains, as a further term ``(s(z) · x)²`` of the
variance (:func:`_excess_code_error`: the noise weights trusted codes where the
curve is worse than the noise says); a weight of
zero wherever *any* channel is clipped or at its stuck ceiling, and for a channel at its
black floor (:func:`selfcal.response.stuck_codes.stuck_code_levels`), which :class:`FrameTables` takes
as per-channel limits; and :class:`FrameTables`, which tabulates weight, weighted radiance,
radiance and variance at every code once per frame, so that the merge and the deghosting
are lookups (``cv2.LUT``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..errors import InputError
from ..stack.frames import apply_lut, Lineariser
from ..io.images import import_cv2

__all__ = ["NoiseModel", "noise_variance", "weight_hat"]


def weight_hat(z: npt.ArrayLike) -> np.ndarray:
    """Debevec & Malik's hat (triangle) weighting on the normalised code ``z`` in [0, 1].

    ``w(z) = 2 min(z, 1 - z)``: 1 at mid-grey, 0 at black and white (Debevec & Malik,
    SIGGRAPH 1997, §2.1, with ``Z_min = 0``, ``Z_max = 1``).  :func:`selfcal.merge_hdr`
    sets the weight to zero at clipped codes in any case.

    Parameters
    ----------
    z : array_like
        Normalised codes ``I / max_code`` (any shape).

    Returns
    -------
    numpy.ndarray
        Weights of the same shape.
    """
    z = np.asarray(z, dtype=np.float64)
    return 2.0 * np.minimum(z, 1.0 - z).clip(0.0, None)


@dataclass(frozen=True)
class NoiseModel:
    """Noise of one linearised measurement ``x = f⁻¹(z)`` (white = 1), per channel.

    ``Var[x] = shot · x + read² + (f⁻¹'(z) · code / 255)²``

    (plus ``(relative · x)²``, see below): a Poisson (shot) term proportional to the
    signal, a signal-independent read-noise term
    (the camera noise model of Granados et al., CVPR 2010, and Hasinoff et al., CVPR 2010),
    and the noise of the code itself -- quantisation and JPEG compression, ``code`` codes
    on the 8-bit scale -- carried to the linear domain through the slope of the inverse
    response (first order error propagation).  For linear input (``linear=True``) the code
    term is only the quantisation of the data.

    The defaults are fixed, stated here and nowhere else -- ``NoiseModel()`` is the merge's
    default noise model -- and not estimated from the stack (see the module docstring for
    why).

    Attributes
    ----------
    shot : float
        Shot-noise variance per unit signal: 1 / (electrons at white), at the stack's ISO.
        Default 1e-4 (10,000 e⁻ at white).
    read : float
        Read-noise standard deviation as a fraction of white.  Default 1e-3.
    code : float
        Standard deviation of the code noise in 8-bit codes (quantisation ≈ 0.29, JPEG
        compression adds about a code).  Default 1.0.
    relative : float
        A term ``(relative · x)²`` for errors proportional to the signal: of the response
        model and of the exposures (ours).  Default 0.03, chosen on the tuning split
        (docs/decisions.md, "Default weighting: the noise model, with a 3 % relative
        error"); 0 leaves the shot, read and code terms only.
    """

    shot: float = 1e-4
    read: float = 1e-3
    code: float = 1.0
    relative: float = 0.03

    def __post_init__(self):
        for name in ("shot", "read", "code", "relative"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"NoiseModel.{name} must be a finite number >= 0, got {v!r}")


#: The merge's default noise model: ``NoiseModel()``, whose field defaults are the values
#: (a name for it, not a second set of defaults).
DEFAULT_NOISE = NoiseModel()



def noise_variance(x: np.ndarray, slope: np.ndarray, exposure: float,
                   noise: NoiseModel = NoiseModel(), *, code_std: float | None = None,
                   code_error: np.ndarray | None = None) -> np.ndarray:
    """Variance of the radiance estimate ``X = f⁻¹(z) / e`` of one frame.

    ``Var[X] = (shot · x + read² + (slope · σ_z)² + (relative · x)²) / e²`` with
    ``x = f⁻¹(z)``,
    ``slope = d f⁻¹ / dz`` and ``σ_z = noise.code / 255`` (see :class:`NoiseModel`).  The
    noise-aware weight is its inverse, ``w = 1 / Var[X]`` -- the minimum-variance
    (maximum-likelihood, for Gaussian noise) combination of the frames' estimates
    (Granados et al., CVPR 2010; Hasinoff et al., CVPR 2010).  The variance uses each
    frame's own measurement ``x`` (Granados et al. iterate with the merged estimate; the
    difference is small where the code noise dominates, as in JPEGs).

    Parameters
    ----------
    x, slope : array_like
        Linearised values and the slope of f⁻¹ at the codes (normalised code units).
    exposure : float
        Relative exposure ``e`` of the frame.
    noise : NoiseModel, optional
        Default ``NoiseModel()`` (the merge's default, with its 3 % relative term).
    code_std : float, optional
        Code noise in normalised units, overriding ``noise.code / 255``.
    code_error : array_like, optional
        The curve's measured error of log f⁻¹ at the codes (shaped like ``x``;
        :mod:`selfcal.response.code_error`): adds ``(code_error · x)²`` (ours).

    Returns
    -------
    numpy.ndarray
    """
    x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    sz = noise.code / 255.0 if code_std is None else float(code_std)
    var = (noise.shot * x + noise.read ** 2 + (np.asarray(slope) * sz) ** 2
           + (noise.relative * x) ** 2)
    if code_error is not None:
        var = var + (np.asarray(code_error) * x) ** 2
    return np.maximum(var, 1e-20) / float(exposure) ** 2


def _excess_code_error(total, profile, lin, noise: NoiseModel):
    """The part of the measured error of log f⁻¹ (:mod:`selfcal.response.code_error`) that
    the noise model does not explain: ``√max(0, s² − V_noise / x² / b²)`` per code, with
    ``V_noise`` the shot, read and code terms of :func:`noise_variance` and ``b`` the
    calibration's sample block (its samples are b×b means, whose noise variance is b²
    times smaller).  None without a profile."""
    if total is None:
        return None
    from dataclasses import replace

    x = np.maximum(lin.table, 1e-6)
    block = float((profile or {}).get("block", 1) or 1)
    v = noise_variance(x, lin.slope, 1.0, replace(noise, relative=0.0),
                       code_std=lin.code_std()) / (x * block) ** 2
    return np.sqrt(np.maximum(total ** 2 - v, 0.0))


class FrameTables:
    """Everything :func:`selfcal.merge_hdr` needs from one frame, as tables on the codes.

    ``weighted`` = w·f⁻¹/e, ``weight`` = w (zero at clipped codes), ``radiance`` = f⁻¹/e,
    ``variance`` = Var[f⁻¹/e] (noise model), each ``(K, 3)`` float32.  For linear float
    data and ``to_raw`` models the same quantities are computed on the strip.  ``lo`` and
    ``hi`` are scalars or per-channel limits: a pixel with a code at or below ``lo`` or at
    or above ``hi`` in any channel is clipped (:meth:`valid`; a stuck ceiling lowers
    ``hi``); ``floor`` (per channel, optional) zeroes the weights of a channel's codes at
    or below it, that channel only (a black floor).  With ``use_code_error`` (the LUT path)
    the curve's measured error per code (the model's ``diagnostics["code_error_log"]``)
    joins the variance of the weights and of σ (``MergeOptions.code_error``).
    """

    #: set by the merge (:mod:`selfcal.hdr.accumulate`): the code above which a pixel is
    #: bright, an unchecked frame's masked codes (None when they are not kept), and the
    #: lens's falloff as the frame saw it (:class:`.vignetting.FrameFalloff`, or None)
    bright: float
    unchecked_codes: np.ndarray | None
    falloff: object | None

    def __init__(self, lin: Lineariser, exposure: float, weighting, noise: NoiseModel,
                 lo: float, hi: float, need_variance: bool, exposure_norm: float = 1.0,
                 floor=None, use_code_error: bool = True):
        self.lin = lin
        self.e = float(exposure)
        self.e_norm = float(exposure_norm)
        self.weighting = weighting
        self.noise = noise
        # per channel: a stuck ceiling lowers hi (a pixel there is clipped, every channel);
        # a black floor raises the limit of the weights of its channel only
        self.lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), (3,)).copy()
        self.hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), (3,)).copy()
        self.wlo = self.lo if floor is None else np.maximum(self.lo, floor)
        self.lut = lin.table is not None and lin.kind != "to_raw"
        self.code_error = None
        self.unchecked = False      # merged with a time the pixels could not check
        if lin.table is None:
            return
        assert lin.max_code is not None and lin.slope is not None   # made with the table
        if use_code_error and lin.kind == "lut":
            from ..response.code_error import code_error_at

            diag = getattr(lin.model, "diagnostics", None) or {}
            self.code_error = _excess_code_error(code_error_at(diag.get("code_error_log"),
                                                               lin.max_code),
                                                 diag.get("code_error_log"), lin, noise)
        mc = lin.max_code
        z = np.arange(mc + 1) / mc
        x = lin.table
        codes = np.arange(mc + 1)[:, None]
        ok = (codes > self.wlo[None, :]) & (codes < self.hi[None, :])
        w = self._weights(np.repeat(z[:, None], 3, axis=1), x, lin.slope) * ok
        self.w_table = w.astype(np.float32)
        self.x_table = (x / self.e).astype(np.float32)
        self.a_table = (w * x / self.e).astype(np.float32)
        #: (weighted, weight) side by side: the merge's one lookup per strip
        self.aw_table = packed_table(np.stack([self.a_table, self.w_table], axis=-1))
        if need_variance:
            var = noise_variance(x, lin.slope, self.e, noise, code_std=lin.code_std(),
                                 code_error=self.code_error)
            self.v_table = var.astype(np.float32)

    def _weights(self, z, x, slope):
        if self.weighting == "hat":
            return weight_hat(z)
        if self.weighting == "noise":
            # 1 / Var[f⁻¹(I)/e], scaled by the longest exposure² (a common factor, which
            # keeps float32 sums in range)
            var = noise_variance(x, slope, self.e / self.e_norm, self.noise,
                                 code_std=self.lin.code_std(), code_error=self.code_error)
            return 1.0 / var
        w = np.asarray(self.weighting(z), dtype=np.float64)
        if w.shape != np.shape(z):
            w = np.broadcast_to(w, np.shape(z))
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError("the weighting function returned negative or non-finite weights")
        return w

    def valid(self, codes):
        """uint8 mask, 255 where every channel is unclipped."""
        cv2 = import_cv2()
        if codes.dtype == np.uint8 or codes.dtype == np.uint16:
            lo = tuple(math.floor(v) + 1 for v in self.lo)
            hi = tuple(math.ceil(v) - 1 for v in self.hi)
            return cv2.inRange(codes, lo, hi)
        lo = tuple(float(np.nextafter(np.float32(v), np.float32(np.inf))) for v in self.lo)
        hi = tuple(float(np.nextafter(np.float32(v), np.float32(-np.inf))) for v in self.hi)
        return cv2.inRange(np.asarray(codes, dtype=np.float32), lo, hi)

    def white(self, codes):
        """uint8 mask, 255 where some channel is at or above its white limit (clipped)."""
        cv2 = import_cv2()
        if codes.dtype == np.uint8 or codes.dtype == np.uint16:
            hi = tuple(math.ceil(v) - 1 for v in self.hi)
            below = cv2.inRange(codes, (0, 0, 0), hi)
        else:
            hi = tuple(float(np.nextafter(np.float32(v), np.float32(-np.inf)))
                       for v in self.hi)
            below = cv2.inRange(np.asarray(codes, dtype=np.float32), (-np.inf,) * 3, hi)
        return cv2.bitwise_not(below)

    def radiance(self, codes) -> np.ndarray:
        """f⁻¹(I)/e on a strip, float32, clipped or not."""
        if self.lut:
            return apply_lut(codes, self.x_table)
        return self.lin.values(codes) / np.float32(self.e)

    def radiance_variance(self, codes):
        """(f⁻¹(I)/e, Var[f⁻¹(I)/e]) on a strip, float32 (for deghosting)."""
        if self.lut:
            return apply_lut(codes, self.x_table), apply_lut(codes, self.v_table)
        _, _, x, v = self.evaluate(codes, need_x=True)
        return x, v

    def evaluate(self, codes, *, need_x: bool, out=None):
        """(weighted, weight, radiance or None, variance or None) on a strip.

        ``out``: optional pair of float32 buffers for the first two (table path only).
        """
        if self.lut:
            a = apply_lut(codes, self.a_table, None if out is None else out[0])
            w = apply_lut(codes, self.w_table, None if out is None else out[1])
            if need_x:
                return a, w, apply_lut(codes, self.x_table), apply_lut(codes, self.v_table)
            return a, w, None, None
        # functional path: linear float data or a to_raw model
        x = self.lin.values(codes)
        if self.lin.table is not None:           # to_raw: weights from codes
            w = apply_lut(codes, self.w_table)
            slope = None
        else:
            z = x
            slope = np.ones_like(x)
            w = self._weights(z, x, slope).astype(np.float32)
            w[~((x > self.wlo) & (x < self.hi))] = 0.0
        X = x / np.float32(self.e)
        a = w * X
        if not need_x:
            return a, w, None, None
        if self.lin.table is not None:
            assert self.lin.slope is not None       # made with the table
            slope = apply_lut(codes, self.lin.slope.astype(np.float32))
            v = noise_variance(x, slope, self.e, self.noise,
                               code_std=self.lin.code_std())
        else:
            assert slope is not None        # linear data: ones (above)
            v = noise_variance(x, slope, self.e, self.noise,
                               code_std=self.lin.code_std())
        return a, w, X, v.astype(np.float32)


def packed_table(tables: np.ndarray) -> np.ndarray:
    """A ``(K, 3, n)`` float32 table (n = 1 or 2) as one ``(K, 3)`` table of ``4 n``-byte
    values (n = 2: a float64 holding the two float32 side by side), so that one lookup
    (:func:`packed_lookup`) returns both: a lookup costs about the same for 4 or 8 bytes
    (ours)."""
    if tables.shape[-1] == 1:
        return np.ascontiguousarray(tables[..., 0], dtype=np.float32)
    return np.ascontiguousarray(tables, dtype=np.float32).view(np.float64)[..., 0]


def packed_lookup(codes: np.ndarray, table: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out[..., c] = table[codes[..., c], c]``, the table's bits copied as they are
    (``cv2.LUT`` for uint8 codes, numpy indexing otherwise); ``out.view(np.float32)``
    then holds the float32 values side by side."""
    if codes.dtype == np.uint8:
        return import_cv2().LUT(codes, table.reshape(1, 256, 3), dst=out)
    for c in range(3):
        out[..., c] = table[:, c][codes[..., c]]
    return out
