"""HDR radiance maps from exposure stacks: weighted merge, clipping, deghosting, alignment.

The merge is the weighted mean of Debevec & Malik (*Recovering High Dynamic Range Radiance
Maps from Photographs*, SIGGRAPH 1997, §2.2, their Eq. 6), taken on linear radiance rather
than its logarithm (the form whose inverse-variance weights are noise-optimal, Granados et
al. 2010), over the frames of a bracketed stack::

    E = Σ_j w_j(I_j) · f⁻¹(I_j) / e_j  /  Σ_j w_j(I_j)

with the inverse response f⁻¹ of :func:`selfcal.calibrate_response` (Lin, Kim, Süsstrunk &
Brown, *Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011, §5) or of
any model that linearises codes (a future RAW-path ``PipelineModel`` with ``to_raw``), and
``e_j`` the relative exposure of frame ``j`` (``t · ISO/100 / N²`` from EXIF, so that the
radiance of several brackets of one session comes out on one scale).

Where this differs from OpenCV's ``MergeDebevec`` and most tools:

* **clipped pixels never leak in**: a frame gets weight *zero* at a pixel where *any*
  channel is clipped (a code within ``clip_margin`` of 0 or of the maximum), not merely a
  small triangle weight on the clipped channel;
* pixels that **no frame measured** unclipped are filled by a documented rule (the darkest
  frame for highlights, the brightest for shadows) and reported in
  :attr:`HDRResult.unmeasured`;
* a **noise-aware** weighting (inverse variance of f⁻¹(I)/e under a shot + read + code
  noise model, after Granados et al. 2010 and Hasinoff et al. 2010) besides Debevec's hat;
* optional **alignment** to the reference frame (median threshold bitmaps, Ward 2003;
  ECC homography, Evangelidis & Psarakis 2008) and **deghosting** against the reference
  frame with the noise model;
* frames are **streamed**: paths are decoded one at a time, and only float32 accumulators
  (numerator and denominator per channel) of the frame size are held, so 17 frames of
  24 MP merge in well under 2 GB.

References
----------
.. [Debevec1997] P. E. Debevec and J. Malik, "Recovering High Dynamic Range Radiance Maps
   from Photographs", SIGGRAPH 1997.
.. [Lin2011] H. Lin, S. J. Kim, S. Süsstrunk and M. S. Brown, "Revisiting Radiometric
   Calibration for Color Computer Vision", ICCV 2011.
.. [Granados2010] M. Granados, B. Ajdin, M. Wand, C. Theobalt, H.-P. Seidel and H. P. A.
   Lensch, "Optimal HDR reconstruction with linear digital cameras", CVPR 2010.
.. [Hasinoff2010] S. W. Hasinoff, F. Durand and W. T. Freeman, "Noise-optimal capture for
   high dynamic range photography", CVPR 2010.
.. [Ward2003] G. Ward, "Fast, Robust Image Registration for Compositing High Dynamic Range
   Photographs from Hand-Held Exposures", Journal of Graphics Tools 8(2), 2003.
.. [Evangelidis2008] G. D. Evangelidis and E. Z. Psarakis, "Parametric Image Alignment
   Using Enhanced Correlation Coefficient Maximization", IEEE TPAMI 30(10), 2008.
.. [Rublee2011] E. Rublee, V. Rabaud, K. Konolige and G. Bradski, "ORB: an efficient
   alternative to SIFT or SURF", ICCV 2011.
"""

from __future__ import annotations

import math
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import CalibrationError, InputError

__all__ = [
    "HDRResult",
    "NoiseModel",
    "merge_hdr",
    "weight_hat",
    "noise_variance",
    "estimate_alignment",
    "warp_to_reference",
    "linearize_images",
]

#: Codes (on the 8-bit scale) within this distance of 0 or of the maximum count as clipped
#: -- the same rule as the calibration's (``selfcal.samples.frame_masks``).
DEFAULT_CLIP_MARGIN = 2.0
#: Coverage mask of a warped frame: value of clipped pixels; 255 is outside the frame, and
#: interpolated values above _OUTSIDE count as outside (for the fill of unmeasured pixels).
_CLIPPED = 100
_OUTSIDE = 177
#: Rows per strip are chosen so that a strip holds about this many pixels.
_STRIP_PIXELS = 1 << 20


def _cv2():
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
    import cv2

    return cv2


def _is_path(x) -> bool:
    return isinstance(x, (str, os.PathLike))


# --------------------------------------------------------------------------------------
# weighting functions and the noise model
# --------------------------------------------------------------------------------------

def weight_hat(z):
    """Debevec & Malik's hat (triangle) weighting on the normalised code ``z`` in [0, 1].

    ``w(z) = 2 min(z, 1 - z)``: 1 at mid-grey, 0 at black and white (Debevec & Malik,
    SIGGRAPH 1997, §2.1, with ``Z_min = 0``, ``Z_max = 1``).  :func:`merge_hdr` sets the
    weight to zero at clipped codes in any case.

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

    a Poisson (shot) term proportional to the signal, a signal-independent read-noise term
    (the camera noise model of Granados et al., CVPR 2010, and Hasinoff et al., CVPR 2010),
    and the noise of the code itself -- quantisation and JPEG compression, ``code`` codes
    on the 8-bit scale -- carried to the linear domain through the slope of the inverse
    response (first order error propagation).  For linear input (``linear=True``) the code
    term is only the quantisation of the data.

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
    """

    shot: float = 1e-4
    read: float = 1e-3
    code: float = 1.0

    def __post_init__(self):
        for name in ("shot", "read", "code"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"NoiseModel.{name} must be a finite number >= 0, got {v!r}")


def noise_variance(x, slope, exposure: float, noise: NoiseModel = NoiseModel(), *,
                   code_std: float | None = None):
    """Variance of the radiance estimate ``X = f⁻¹(z) / e`` of one frame.

    ``Var[X] = (shot · x + read² + (slope · σ_z)²) / e²`` with ``x = f⁻¹(z)``,
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
    noise : NoiseModel
    code_std : float, optional
        Code noise in normalised units, overriding ``noise.code / 255``.

    Returns
    -------
    numpy.ndarray
    """
    x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    sz = noise.code / 255.0 if code_std is None else float(code_std)
    var = noise.shot * x + noise.read ** 2 + (np.asarray(slope) * sz) ** 2
    return np.maximum(var, 1e-20) / float(exposure) ** 2


# --------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------

@dataclass
class HDRResult:
    """The radiance map of :func:`merge_hdr` and what was trusted to make it.

    Attributes
    ----------
    radiance : numpy.ndarray
        float32 ``HxWx3`` RGB radiance, ``f⁻¹(I) / e``: 1 is the signal that reaches white
        in a frame of relative exposure 1 (1 s at ISO 100 and f/1 when the exposures come
        from EXIF).
    unmeasured : numpy.ndarray
        bool ``HxW``: pixels that no frame measured with every channel unclipped; their
        values are the fill of :func:`merge_hdr` (a bound, not a measurement).
    ghost : numpy.ndarray
        bool ``HxW``: pixels where deghosting excluded at least one frame (so the value
        comes from the reference frame and the frames that agree with it).
    exposures : numpy.ndarray
        The relative exposure ``e_j`` used for each frame.
    warnings : list of str
    sources : list of str
        The frames (file names or ``"array #k"``).
    reference : int
        Index of the reference frame (alignment and deghosting).
    transforms : list of numpy.ndarray or None
        Per frame, the 3×3 matrix mapping reference pixel coordinates to that frame's
        (identity for the reference); None without alignment.
    exposure_source : str
        ``"given"``, ``"exif"``, ``"model"`` or ``"exif+model"``.
    frame_count : numpy.ndarray
        uint8 ``HxW``: number of frames that contributed to each pixel.
    diagnostics : dict
        Per-frame fraction of pixels used, fraction excluded by deghosting, the weighting,
        and the model's verdict when it was calibrated on the fly.
    model : object
        The response model used (calibrated on the fly when none was given).
    """

    radiance: np.ndarray
    unmeasured: np.ndarray
    ghost: np.ndarray
    exposures: np.ndarray
    warnings: list = field(default_factory=list)
    sources: list = field(default_factory=list)
    reference: int = 0
    transforms: list | None = None
    exposure_source: str = "given"
    frame_count: np.ndarray | None = None
    diagnostics: dict = field(default_factory=dict)
    model: object = field(default=None, repr=False)


# --------------------------------------------------------------------------------------
# frames
# --------------------------------------------------------------------------------------

class _Frames:
    """The stack's frames: arrays (used as they are) or paths (decoded when needed)."""

    def __init__(self, images, linear: bool):
        self.items = list(images)
        if not self.items:
            raise InputError("no frames given")
        self.raw_files = [_is_raw_file(f) for f in self.items]
        if any(self.raw_files):
            if not all(self.raw_files):
                raise InputError("raw files and rendered images cannot be merged together: "
                                 "merge the raws alone (linear), or the JPEGs alone")
            # raw files are linear camera RGB: merged directly, no response needed
            linear = True
        self.linear = linear
        self.sources = [str(f) if _is_path(f) else f"array #{k}"
                        for k, f in enumerate(self.items)]
        self.paths = [Path(f) if _is_path(f) else None for f in self.items]
        self._check()

    def __len__(self):
        return len(self.items)

    def _check(self):
        from .io import read_image_size

        shape = dtype = None
        for k, item in enumerate(self.items):
            src = self.sources[k]
            if self.raw_files[k]:
                hw = _raw_size(item)
                dt = None
            elif _is_path(item):
                hw = read_image_size(item)
                dt = None
            else:
                arr = np.asarray(item)
                if arr.ndim != 3 or arr.shape[2] != 3:
                    raise InputError(f"expected an HxWx3 RGB image, got shape {arr.shape}", src)
                hw = arr.shape[:2]
                dt = arr.dtype
                if np.issubdtype(dt, np.floating):
                    if not self.linear:
                        raise InputError(
                            "float arrays are not camera codes: pass uint8/uint16 images, or "
                            "linear=True for linear raw values", src)
                    if not np.all(np.isfinite(arr)):
                        raise InputError("the array holds NaN or infinite values", src)
                elif dt not in (np.uint8, np.uint16):
                    raise InputError(f"unsupported dtype {dt} (uint8, uint16, or float "
                                     "with linear=True)", src)
            if shape is None:
                shape, first = tuple(hw), src
            elif tuple(hw) != shape:
                raise InputError(f"frame size {hw[1]}x{hw[0]} differs from {first} "
                                 f"({shape[1]}x{shape[0]})", src)
            if dt is not None:
                if dtype is None:
                    dtype, dfirst = dt, src
                elif dt != dtype:
                    raise InputError(f"sample type {dt} differs from {dfirst} ({dtype})", src)
        self.shape = shape

    def load(self, k, *, reduce: int = 1) -> np.ndarray:
        item = self.items[k]
        if self.raw_files[k]:
            from .raw import read_raw_linear

            arr = read_raw_linear(item).rgb
            if arr.shape[:2] != self.shape:
                raise InputError(f"raw decoded to {arr.shape[1]}x{arr.shape[0]}, not the "
                                 f"{self.shape[1]}x{self.shape[0]} its header gave",
                                 self.sources[k])
            return arr
        if _is_path(item):
            from .io import read_image

            arr = read_image(item, reduce=reduce)
            if arr.shape[:2] != self.shape and reduce == 1:
                raise InputError("frame size changed while reading", self.sources[k])
            return arr
        return np.asarray(item)


def _raw_size(path) -> tuple:
    """(height, width) LibRaw will output for a raw file, from its header."""
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            return (int(raw.sizes.height), int(raw.sizes.width))
    except Exception as exc:  # LibRaw raises several types
        raise InputError(f"not a raw file LibRaw can read ({exc})", path) from None


def _is_raw_file(item) -> bool:
    from .raw import RAW_SUFFIXES

    return _is_path(item) and Path(item).suffix.lower().lstrip(".") in {
        x.lstrip(".") for x in RAW_SUFFIXES}


def _max_code(arr) -> int | None:
    if arr.dtype == np.uint8:
        return 255
    if arr.dtype == np.uint16:
        return 65535
    return None


# --------------------------------------------------------------------------------------
# linearisers: codes -> linear values per frame, and per-frame LUTs
# --------------------------------------------------------------------------------------

class _Lineariser:
    """What a model (or linear data) makes of codes.

    kinds: ``"lut"`` (per-channel inverse response tables; ResponseModel or anything with
    ``inverse_response(codes)``), ``"to_raw"`` (a model with ``to_raw(rendered)``; its
    per-channel slopes are taken along the grey axis), ``"linear"`` (linear data).
    """

    def __init__(self, model, linear: bool, max_code: int | None):
        self.max_code = max_code
        if linear:
            self.kind = "linear"
        elif hasattr(model, "inverse_response"):
            self.kind = "lut"
        elif hasattr(model, "to_raw"):
            self.kind = "to_raw"
        else:
            raise InputError("the model must have inverse_response(codes) (a ResponseModel) "
                             "or to_raw(rendered) (a pipeline model)")
        self.model = model
        self.table = None       # (K, 3) f⁻¹ at every code, float64
        self.slope = None       # (K, 3) d f⁻¹ / dz at every code
        if max_code is None:
            return
        codes = np.arange(max_code + 1)
        if self.kind == "linear":
            table = np.repeat((codes / max_code)[:, None], 3, axis=1)
        elif self.kind == "lut":
            mc = getattr(model, "max_code", max_code) or max_code
            table = np.asarray(model.inverse_response(codes * (mc / max_code)), dtype=np.float64)
            if table.shape != (max_code + 1, 3) or not np.all(np.isfinite(table)):
                raise InputError("the model's inverse response is not a finite (K, 3) table")
        else:
            dtype = np.uint8 if max_code == 255 else np.uint16
            ramp = np.repeat(codes.astype(dtype)[:, None, None], 3, axis=2)
            table = np.asarray(model.to_raw(ramp), dtype=np.float64).reshape(-1, 3)
        self.table = table
        z = codes / max_code
        self.slope = np.abs(np.gradient(table, z, axis=0))

    def code_std(self, noise: NoiseModel) -> float | None:
        """Code noise in normalised units (None: the noise model's JPEG-like default)."""
        if self.kind == "linear":
            q = 1.0 / self.max_code if self.max_code else 0.0
            return q / math.sqrt(12.0)
        return None

    def values(self, strip: np.ndarray) -> np.ndarray:
        """Linear values of a strip, float32 (for kinds without a LUT path)."""
        if self.kind == "to_raw":
            return np.asarray(self.model.to_raw(strip), dtype=np.float32)
        if self.max_code is not None:
            return strip.astype(np.float32) * np.float32(1.0 / self.max_code)
        return np.asarray(strip, dtype=np.float32)


def _apply_lut(codes: np.ndarray, lut: np.ndarray, out: np.ndarray | None = None):
    """Per-channel table lookup: ``out[..., c] = lut[codes[..., c], c]`` as float32.

    uint8 codes go through ``cv2.LUT`` (one pass, multi-threaded); uint16 through numpy
    indexing.  ``out``, when given, is filled (a contiguous float32 buffer of the shape).
    """
    if codes.dtype == np.uint8:
        if out is None:
            return _cv2().LUT(codes, lut.reshape(1, 256, 3))
        return _cv2().LUT(codes, lut.reshape(1, 256, 3), dst=out)
    if out is None:
        out = np.empty(codes.shape, dtype=np.float32)
    for c in range(3):
        out[..., c] = lut[:, c][codes[..., c]]
    return out


class _FrameTables:
    """Everything :func:`merge_hdr` needs from one frame, as tables on the codes.

    ``weighted`` = w·f⁻¹/e, ``weight`` = w (zero at clipped codes), ``radiance`` = f⁻¹/e,
    ``variance`` = Var[f⁻¹/e] (noise model), each ``(K, 3)`` float32.  For linear float
    data and ``to_raw`` models the same quantities are computed on the strip.
    """

    def __init__(self, lin: _Lineariser, exposure: float, weighting, noise: NoiseModel,
                 lo: float, hi: float, need_variance: bool, exposure_norm: float = 1.0):
        self.lin = lin
        self.e = float(exposure)
        self.e_norm = float(exposure_norm)
        self.weighting = weighting
        self.noise = noise
        self.lo, self.hi = lo, hi
        self.lut = lin.table is not None and lin.kind != "to_raw"
        if lin.table is None:
            return
        mc = lin.max_code
        z = np.arange(mc + 1) / mc
        x = lin.table
        ok = ((np.arange(mc + 1) > lo) & (np.arange(mc + 1) < hi))[:, None]
        w = self._weights(np.repeat(z[:, None], 3, axis=1), x, lin.slope) * ok
        self.w_table = w.astype(np.float32)
        self.x_table = (x / self.e).astype(np.float32)
        self.a_table = (w * x / self.e).astype(np.float32)
        if need_variance:
            var = noise_variance(x, lin.slope, self.e, noise, code_std=lin.code_std(noise))
            self.v_table = var.astype(np.float32)

    def _weights(self, z, x, slope):
        if self.weighting == "hat":
            return weight_hat(z)
        if self.weighting == "noise":
            # 1 / Var[f⁻¹(I)/e], scaled by the longest exposure² (a common factor, which
            # keeps float32 sums in range)
            var = noise_variance(x, slope, self.e / self.e_norm, self.noise,
                                 code_std=self.lin.code_std(self.noise))
            return 1.0 / var
        w = np.asarray(self.weighting(z), dtype=np.float64)
        if w.shape != np.shape(z):
            w = np.broadcast_to(w, np.shape(z))
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise InputError("the weighting function returned negative or non-finite weights")
        return w

    def valid(self, codes):
        """uint8 mask, 255 where every channel is unclipped."""
        cv2 = _cv2()
        if codes.dtype == np.uint8 or codes.dtype == np.uint16:
            lo = math.floor(self.lo) + 1
            hi = math.ceil(self.hi) - 1
            return cv2.inRange(codes, (lo, lo, lo), (hi, hi, hi))
        lo = float(np.nextafter(np.float32(self.lo), np.float32(np.inf)))
        hi = float(np.nextafter(np.float32(self.hi), np.float32(-np.inf)))
        return cv2.inRange(np.asarray(codes, dtype=np.float32), (lo,) * 3, (hi,) * 3)

    def radiance(self, codes) -> np.ndarray:
        """f⁻¹(I)/e on a strip, float32, clipped or not."""
        if self.lut:
            return _apply_lut(codes, self.x_table)
        return self.lin.values(codes) / np.float32(self.e)

    def radiance_variance(self, codes):
        """(f⁻¹(I)/e, Var[f⁻¹(I)/e]) on a strip, float32 (for deghosting)."""
        if self.lut:
            return _apply_lut(codes, self.x_table), _apply_lut(codes, self.v_table)
        _, _, x, v = self.evaluate(codes, need_x=True)
        return x, v

    def evaluate(self, codes, *, need_x: bool, out=None):
        """(weighted, weight, radiance or None, variance or None) on a strip.

        ``out``: optional pair of float32 buffers for the first two (table path only).
        """
        if self.lut:
            a = _apply_lut(codes, self.a_table, None if out is None else out[0])
            w = _apply_lut(codes, self.w_table, None if out is None else out[1])
            if need_x:
                return a, w, _apply_lut(codes, self.x_table), _apply_lut(codes, self.v_table)
            return a, w, None, None
        # functional path: linear float data or a to_raw model
        x = self.lin.values(codes)
        if self.lin.table is not None:           # to_raw: weights from codes
            w = _apply_lut(codes, self.w_table)
            slope = None
        else:
            z = x
            slope = np.ones_like(x)
            w = self._weights(z, x, slope).astype(np.float32)
            w[~((x > self.lo) & (x < self.hi))] = 0.0
        X = x / np.float32(self.e)
        a = w * X
        if not need_x:
            return a, w, None, None
        if self.lin.table is not None:
            slope = _apply_lut(codes, self.lin.slope.astype(np.float32))
            v = noise_variance(x, slope, self.e, self.noise,
                               code_std=self.lin.code_std(self.noise))
        else:
            v = noise_variance(x, slope, self.e, self.noise,
                               code_std=self.lin.code_std(self.noise))
        return a, w, X, v.astype(np.float32)


# --------------------------------------------------------------------------------------
# exposures
# --------------------------------------------------------------------------------------

def _given_exposures(frames: _Frames, exposure_times):
    """The caller's times (checked) or EXIF ``t · ISO/100 / N²``; None where unknown."""
    n = len(frames)
    given = [None] * n
    source = "given"
    if exposure_times is not None:
        times = list(exposure_times)
        if len(times) != n:
            raise InputError(f"{len(times)} exposure times given for {n} frames")
        for k, t in enumerate(times):
            if t is None:
                continue
            try:
                tf = float(t)
            except (TypeError, ValueError):
                raise InputError(f"exposure time {t!r} is not a number",
                                 frames.sources[k]) from None
            if not math.isfinite(tf) or tf <= 0:
                raise InputError(f"exposure time {t!r} must be a positive number",
                                 frames.sources[k])
            given[k] = tf
    elif any(p is not None for p in frames.paths):
        from .io import read_exposure_info

        source = "exif"
        for k, p in enumerate(frames.paths):
            if p is not None and frames.raw_files[k]:
                from .raw import read_raw_exposure_info

                given[k] = read_raw_exposure_info(p).relative_exposure
            elif p is not None:
                given[k] = read_exposure_info(p).relative_exposure
    return given, source


def _name_arrays(text: str, sources) -> str:
    """Replace ``array #k`` in a message by the k-th frame's name."""
    for k in range(len(sources) - 1, -1, -1):
        text = text.replace(f"array #{k}", str(sources[k]))
    return text


def _aligned_working_frames(frames: _Frames, transforms, max_side: int = 2048) -> list:
    """The frames warped onto the reference, downscaled to ``max_side`` (for calibration).

    Calibration samples block means on a coarse grid, so a reduced copy loses little, and
    17 frames of 24 MP then take about 80 MB instead of 1.2 GB.
    """
    cv2 = _cv2()
    full_h, full_w = frames.shape
    s0 = min(1.0, max_side / max(full_h, full_w))
    size = (max(8, round(full_w * s0)), max(8, round(full_h * s0)))
    sx, sy = size[0] / full_w, size[1] / full_h
    reduce = _working_reduce(frames, max_side)
    out = []
    for k in range(len(frames)):
        img = frames.load(k, reduce=reduce)
        if (img.shape[1], img.shape[0]) != size:
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        t = _rescale_homography(transforms[k], sx, sy)
        if not _negligible(t, img.shape[:2]):
            img = warp_to_reference(img, t)
        out.append(img)
    return out


def _model_frame_index(model, frames: _Frames, fresh: bool):
    """Index of each frame in the model's sources (None where it is not there)."""
    n = len(frames)
    sources = list(getattr(model, "sources", []) or [])
    exposures = getattr(model, "exposures", None)
    if exposures is None or len(sources) != len(np.atleast_1d(exposures)):
        return [None] * n
    if fresh:
        return list(range(n))
    lookup = {}
    for i, s in enumerate(sources):
        if s.startswith("array #"):
            continue
        lookup[str(Path(s))] = i
        try:
            lookup[str(Path(s).resolve())] = i
        except OSError:
            pass
    out = []
    for p in frames.paths:
        if p is None:
            out.append(None)
            continue
        out.append(lookup.get(str(p), lookup.get(str(p.resolve()))))
    return out


def _resolve_exposures(frames: _Frames, exposure_times, model, fresh: bool, warnings):
    """Relative exposure e_j of each frame, and where it came from.

    Given times (the caller's) or EXIF ``t · ISO/100 / N²`` set the scale; the model's
    estimates replace them where it refined them or found them contradicted by the pixels
    (scaled to the given/EXIF units by the median ratio over the frames it did not
    contradict), and fill frames whose time is unknown.
    """
    n = len(frames)
    given, source = _given_exposures(frames, exposure_times)

    # the model's estimates, in its own units
    idx = _model_frame_index(model, frames, fresh) if model is not None else [None] * n
    est = [None] * n
    contradicted = set()
    refined = False
    if any(i is not None for i in idx):
        mexp = np.asarray(model.exposures, dtype=float)
        diag = getattr(model, "diagnostics", {}) or {}
        refined = bool(diag.get("refine_exposures", False))
        contra = {str(c.get("frame")): c.get("estimated")
                  for c in diag.get("contradicting_times", []) or []}
        msources = list(model.sources)
        for k, i in enumerate(idx):
            if i is None or not math.isfinite(mexp[i]) or mexp[i] <= 0:
                continue
            est[k] = float(mexp[i])
            c = contra.get(msources[i])
            if c is not None and math.isfinite(float(c)) and float(c) > 0:
                est[k] = float(c)
                contradicted.add(k)

    use_model = set(contradicted)
    if refined:
        use_model |= {k for k in range(n) if est[k] is not None}
    use_model |= {k for k in range(n) if given[k] is None and est[k] is not None}
    missing = [frames.sources[k] for k in range(n) if given[k] is None and est[k] is None]
    if missing:
        raise CalibrationError(
            f"{missing[0]}: no exposure time (give exposure_times, or a model calibrated on "
            "these frames)" + (f"; {len(missing) - 1} more frames lack one"
                               if len(missing) > 1 else ""))
    if not use_model:
        return np.array(given, dtype=float), source

    # scale the model's estimates to the given/EXIF units
    anchor = [k for k in range(n) if given[k] is not None and est[k] is not None
              and k not in contradicted]
    if not anchor:
        anchor = [k for k in range(n) if given[k] is not None and est[k] is not None]
    if anchor:
        factor = math.exp(float(np.median([math.log(given[k] / est[k]) for k in anchor])))
    else:
        factor = 1.0
        warnings.append("no exposure times known: the radiance is on a relative scale "
                        "(the model's estimated exposures)")
    out = np.array(given, dtype=object)
    changed = []
    for k in sorted(use_model):
        new = est[k] * factor
        if given[k] is not None:
            dev = abs(math.log(new / given[k]))
            if dev > math.log(1.01):
                changed.append((dev, k, given[k], new))
        out[k] = new
    label = {"given": "given times", "exif": "EXIF exposures"}[source]
    if contradicted:
        names = ", ".join(Path(frames.sources[k]).name for k in sorted(contradicted))
        warnings.append(f"the model found the {label} of {names} contradicted by the pixels: "
                        "using the model's estimated exposures for them")
    elif changed:
        dev, k, g, new = max(changed)
        warnings.append(f"using the model's refined exposures instead of the {label} "
                        f"(largest difference {100 * (math.exp(dev) - 1):.1f}% at "
                        f"{Path(frames.sources[k]).name})")
    if any(g is None for g in given) and anchor:
        unknown = [Path(frames.sources[k]).name for k in range(n) if given[k] is None]
        warnings.append(f"no exposure time for {', '.join(unknown)}: using the model's "
                        "estimates")
    return np.array(out, dtype=float), (source + "+model" if anchor else "model")


# --------------------------------------------------------------------------------------
# alignment
# --------------------------------------------------------------------------------------

def _to_grey8(image: np.ndarray) -> np.ndarray:
    """8-bit grey image for median threshold bitmaps (codes, not linear values)."""
    cv2 = _cv2()
    if image.dtype == np.uint16:
        image = (image >> 8).astype(np.uint8)
    elif image.dtype != np.uint8:
        image = (np.clip(image, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def _mtb_shift(ref_grey: np.ndarray, grey: np.ndarray, max_bits: int | None = None,
               exclude_range: int = 4) -> tuple[int, int]:
    """Translation of ``grey`` relative to ``ref_grey`` by median threshold bitmaps.

    Ward, *Fast, Robust Image Registration for Compositing High Dynamic Range Photographs
    from Hand-Held Exposures*, JGT 2003, through ``cv2.AlignMTB.calculateShift``.  Returns
    ``(dx, dy)``: shifting ``grey`` by it aligns it to ``ref_grey``.  The pyramid has
    ``max_bits`` levels (shifts up to about ``2**max_bits`` pixels); by default as many as
    keep the coarsest level at least 8 pixels high, at most 6.

    Both images are histogram-equalised first (a monotone map: the median threshold bitmap
    is unchanged, but the exclusion band around the median then holds a fixed share of the
    pixels, so very dark frames do not leave an empty bitmap), and the shift found is kept
    only when its bitmap disagreement is lower than at zero shift -- OpenCV returns the
    largest shift when the bitmaps carry no information, and MTB is fragile on very noisy
    frames (then use the homography).
    """
    cv2 = _cv2()
    if max_bits is None:
        max_bits = int(np.clip(math.floor(math.log2(min(ref_grey.shape) / 8)), 1, 6))
    mtb = cv2.createAlignMTB(max_bits, exclude_range, False)
    a, b = cv2.equalizeHist(ref_grey), cv2.equalizeHist(grey)
    dx, dy = (int(v) for v in mtb.calculateShift(a, b))
    if (dx, dy) == (0, 0):
        return 0, 0
    tb0, eb0 = mtb.computeBitmaps(a)
    tb1, eb1 = mtb.computeBitmaps(b)

    def disagreement(sx, sy):
        t1 = _shift_integer(tb1, -sx, -sy, 0)
        e1 = _shift_integer(eb1, -sx, -sy, 0)
        both = cv2.bitwise_and(eb0, e1)
        n = cv2.countNonZero(both)
        if n < 0.01 * both.size:
            return 1.0
        return cv2.countNonZero(cv2.bitwise_and(cv2.bitwise_xor(tb0, t1), both)) / n

    if disagreement(dx, dy) < disagreement(0, 0):
        return dx, dy
    return 0, 0


def _translation(dx: float, dy: float) -> np.ndarray:
    """3×3 map from reference to frame coordinates for a frame shifted by (−dx, −dy)."""
    return np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]])


def _scale_matrix(sx: float, sy: float | None = None) -> np.ndarray:
    """Pixel-centre map from a grid to one scaled by ``(sx, sy)`` (``u' = (u + ½) s − ½``)."""
    sy = sx if sy is None else sy
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


def _rescale_homography(h: np.ndarray, sx: float, sy: float | None = None) -> np.ndarray:
    """A homography between grids scaled by ``(sx, sy)`` relative to the grid of ``h``."""
    m = _scale_matrix(sx, sy)
    out = m @ h @ np.linalg.inv(m)
    return out / out[2, 2]


def _log_clamped(image, lin: _Lineariser, exposure: float, lo: float, hi: float):
    """log radiance (grey) of a small image, and its unclipped range (log)."""
    cv2 = _cv2()
    # the unclipped range, conservatively: every channel unclipped at both ends
    lo_x, hi_x = 1e-4, 1.0
    if lin.table is not None and lin.kind != "linear":
        lo_x = float(np.max(lin.table[int(lo) + 1]))
        hi_x = float(np.min(lin.table[int(math.ceil(hi)) - 1]))
    if lin.table is not None and lin.kind == "lut":
        x = _apply_lut(image, lin.table.astype(np.float32))
    else:
        x = lin.values(image)
    grey = cv2.cvtColor(np.ascontiguousarray(x, dtype=np.float32), cv2.COLOR_RGB2GRAY)
    lo_x = max(lo_x, 1e-6)
    g = np.log(np.maximum(grey, lo_x) / exposure)
    return g.astype(np.float32), math.log(lo_x / exposure), math.log(hi_x / exposure)


def _ecc_homography(template, image, init: np.ndarray, levels: int = 3) -> tuple:
    """ECC homography (Evangelidis & Psarakis, TPAMI 2008), coarse to fine.

    ``template`` and ``image`` are float32 grey images of one size; returns the 3×3 map
    from template to image coordinates and the final correlation coefficient.
    """
    cv2 = _cv2()
    pyr_t, pyr_i = [template], [image]
    for _ in range(levels - 1):
        if min(pyr_t[-1].shape) < 64:
            break
        pyr_t.append(cv2.resize(pyr_t[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
        pyr_i.append(cv2.resize(pyr_i[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
    depth = len(pyr_t) - 1
    h = _rescale_homography(init, 0.5 ** depth)
    cc = 0.0
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-6)
    for level in range(depth, -1, -1):
        warp = h.astype(np.float32)
        cc, warp = cv2.findTransformECC(pyr_t[level], pyr_i[level], warp,
                                        cv2.MOTION_HOMOGRAPHY, criteria, None, 5)
        h = warp.astype(np.float64)
        h /= h[2, 2]
        if level:
            h = _rescale_homography(h, 2.0)
    return h, float(cc)


def _orb_homography(template, image) -> np.ndarray | None:
    """ORB features (Rublee et al., ICCV 2011) + RANSAC homography, template → image."""
    cv2 = _cv2()

    def to8(g):
        lo, hi = np.percentile(g, [1, 99])
        return np.clip((g - lo) / max(hi - lo, 1e-6) * 255, 0, 255).astype(np.uint8)

    orb = cv2.ORB_create(4000)
    k1, d1 = orb.detectAndCompute(to8(template), None)
    k2, d2 = orb.detectAndCompute(to8(image), None)
    if d1 is None or d2 is None or len(k1) < 8 or len(k2) < 8:
        return None
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    if len(matches) < 8:
        return None
    src = np.float32([k1[m.queryIdx].pt for m in matches])
    dst = np.float32([k2[m.trainIdx].pt for m in matches])
    h, inliers = cv2.findHomography(src, dst, cv2.RANSAC, 2.0)
    if h is None or inliers is None or int(inliers.sum()) < 8:
        return None
    return h / h[2, 2]


def _negligible(h: np.ndarray, shape, limit: float = 0.25) -> bool:
    """No corner moves by more than ``limit`` pixels: resampling would blur more than help."""
    hh, ww = shape
    corners = np.array([[0, 0, 1], [ww - 1, 0, 1], [0, hh - 1, 1], [ww - 1, hh - 1, 1]], float)
    moved = corners @ np.asarray(h, dtype=float).T
    moved = moved[:, :2] / moved[:, 2:]
    return bool(np.all(np.hypot(*(moved - corners[:, :2]).T) <= limit))


def _plausible(h: np.ndarray, shape, limit: float = 0.1) -> bool:
    """Corners move by less than ``limit`` of the image diagonal."""
    hh, ww = shape
    corners = np.array([[0, 0, 1], [ww - 1, 0, 1], [0, hh - 1, 1], [ww - 1, hh - 1, 1]], float)
    moved = corners @ h.T
    if np.any(np.abs(moved[:, 2]) < 1e-9):
        return False
    moved = moved[:, :2] / moved[:, 2:]
    return bool(np.all(np.hypot(*(moved - corners[:, :2]).T) < limit * math.hypot(hh, ww)))


def _working_reduce(frames: _Frames, size: int) -> int:
    """JPEG DCT-scaling factor that keeps the long side at least ``size``."""
    long_side = max(frames.shape)
    r = 1
    while r < 8 and long_side / (2 * r) >= size:
        r *= 2
    return r


def estimate_alignment(images, exposures=None, model=None, *, method: str = "mtb",
                       reference: int | None = None, linear: bool = False,
                       clip_margin: float = DEFAULT_CLIP_MARGIN, working_size: int = 1024,
                       warnings: list | None = None, progress=None) -> list:
    """Transforms that align each frame of a stack to the reference frame.

    ``"mtb"``: translation by median threshold bitmaps (Ward, JGT 2003, via
    ``cv2.AlignMTB``), exposure-invariant and robust, on the full-resolution grey codes.
    ``"homography"``: an MTB translation refined to a homography by ECC maximisation
    (Evangelidis & Psarakis, TPAMI 2008, ``cv2.findTransformECC`` with
    ``MOTION_HOMOGRAPHY``, coarse to fine), both on downscaled images (long side
    ``working_size``; JPEGs decoded with DCT scaling), ECC on grey *linearised* images
    ``log(f⁻¹(I)/e)`` clamped to the radiance range both frames measure unclipped, so the
    two frames look alike whatever their exposures; when ECC fails, ORB features + RANSAC
    (``cv2.findHomography``), and when that fails too, the translation (with a warning).

    Parameters
    ----------
    images : sequence
        Frames (arrays or paths; paths are decoded one at a time).
    exposures : sequence of float, optional
        Relative exposures (needed for ``"homography"``; also chooses the default
        reference, the middle exposure).
    model : ResponseModel or object with ``inverse_response``/``to_raw``, optional
        The inverse response for ``"homography"`` (default: an sRGB-like gamma 2.2).
    method : {"mtb", "homography"}
    reference : int, optional
        Index of the reference frame; default the middle one by exposure.
    linear : bool
        The frames are linear values.
    clip_margin : float
        Codes (8-bit scale) within this distance of 0 or the maximum count as clipped.
    working_size : int
        Long side of the images the homography is estimated on.
    warnings : list, optional
        Receives warnings (strings).
    progress : callable, optional
        ``progress("align", done, total, source)``.

    Returns
    -------
    list of numpy.ndarray
        Per frame, the 3×3 map from reference pixel coordinates to the frame's (use
        :func:`warp_to_reference`).
    """
    frames = images if isinstance(images, _Frames) else _Frames(images, linear)
    n = len(frames)
    if method is True:
        method = "mtb"
    if method not in ("mtb", "homography"):
        raise InputError(f"unknown alignment method {method!r} (mtb or homography)")
    if exposures is None:
        exposures = np.ones(n)
        if method == "homography":
            raise InputError("homography alignment needs the frames' exposures")
    exposures = np.asarray(exposures, dtype=float)
    ref = _default_reference(exposures) if reference is None else int(reference)
    warnings = [] if warnings is None else warnings
    transforms = [np.eye(3) for _ in range(n)]
    order = [ref] + [k for k in range(n) if k != ref]

    if method == "mtb":
        # integer translation by MTB at full resolution
        ref_grey = None
        for done, k in enumerate(order):
            img = frames.load(k)
            grey = _to_grey8(img)
            del img
            if k == ref:
                ref_grey = grey
            else:
                transforms[k] = _translation(*_mtb_shift(ref_grey, grey))
            if progress is not None:
                progress("align", done + 1, n, frames.sources[k])
        return transforms

    # homography: MTB translation, then ECC, on downscaled (linearised) images
    cv2 = _cv2()
    if model is None:
        model = _GammaModel()
    full_h, full_w = frames.shape
    s0 = min(1.0, working_size / max(full_h, full_w))
    size = (max(8, round(full_w * s0)), max(8, round(full_h * s0)))      # (w, h)
    scale = (size[0] / full_w, size[1] / full_h)
    reduce = _working_reduce(frames, working_size)
    lin = None
    ref_data = None
    for done, k in enumerate(order):
        img = frames.load(k, reduce=reduce)
        if (img.shape[1], img.shape[0]) != size:
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        if lin is None:
            lin = _Lineariser(model, linear, _max_code(img))
        lo, hi = _clip_limits(lin.max_code, clip_margin, linear)
        g, glo, ghi = _log_clamped(img, lin, exposures[k], lo, hi)
        grey = _to_grey8(img)
        del img
        if k == ref:
            ref_data = (g, glo, ghi, grey)
        else:
            t, tlo, thi, ref_grey = ref_data
            init = _translation(*_mtb_shift(ref_grey, grey))
            transforms[k] = _rescale_homography(init, 1.0 / scale[0], 1.0 / scale[1])
            a, b = max(glo, tlo), min(ghi, thi)
            h = None
            if a < b:
                tc = np.clip(t, a, b)
                ic = np.clip(g, a, b)
                try:
                    h, cc = _ecc_homography(tc, ic, init)
                    if cc < 0.5 or not _plausible(h, tc.shape):
                        h = None
                except cv2.error:
                    h = None
                if h is None:
                    h = _orb_homography(tc, ic)
                    if h is not None and not _plausible(h, tc.shape):
                        h = None
            if h is None:
                warnings.append(f"{Path(frames.sources[k]).name}: homography alignment failed"
                                + ("" if a < b else " (no radiance range shared with the "
                                   "reference)") + "; kept the MTB translation")
            else:
                transforms[k] = _rescale_homography(h, 1.0 / scale[0], 1.0 / scale[1])
        if progress is not None:
            progress("align", done + 1, n, frames.sources[k])
    return transforms


def calibrate_aligned(images, exposure_times=None, *, method="mtb", reference=None,
                      clip_margin: float = DEFAULT_CLIP_MARGIN, warnings: list | None = None,
                      progress=None, max_side: int = 2048, **options):
    """Align a handheld stack to its reference frame, then calibrate its response.

    Misaligned frames give wrong correspondences, and the solve of Lin et al. (ICCV 2011,
    Eq. 8) then reads them as contradicted exposure times; so the frames are aligned first
    (:func:`estimate_alignment`; with unknown times, after a provisional calibration that
    supplies the exposures the homography needs) and the response is calibrated on the
    aligned frames, downscaled to ``max_side`` (:func:`_aligned_working_frames`: the
    calibration uses block means only).

    Parameters
    ----------
    images : sequence
        Frames (arrays or paths).
    exposure_times : sequence of float or None, optional
        As for :func:`selfcal.calibrate_response`.
    method : {"mtb", "homography"}
        Alignment (see :func:`estimate_alignment`).
    reference : int, optional
        Reference frame; default the middle exposure.
    options
        Passed on to :func:`selfcal.calibrate_response`.

    Returns
    -------
    model : ResponseModel
        Its ``sources`` are the original frames'; ``diagnostics["calibrated_on"]`` says
        what it was calibrated on, ``diagnostics["alignment"]`` holds the transforms.
    transforms : list of numpy.ndarray
        Per frame, the 3×3 map from reference to frame pixel coordinates.
    reference : int
    """
    from .response.calibrate import calibrate_response, resolve_exposure_times

    frames = images if isinstance(images, _Frames) else _Frames(images, False)
    n = len(frames)
    warnings = [] if warnings is None else warnings
    given, _ = _given_exposures(frames, exposure_times)
    provisional = None
    if any(g is None for g in given):
        provisional = calibrate_response(frames.items, exposure_times, progress=progress,
                                         **options)
        given = list(_resolve_exposures(frames, exposure_times, provisional, True, [])[0])
    ref = _default_reference(given) if reference is None else int(reference)
    if not 0 <= ref < n:
        raise InputError(f"reference frame {reference} is out of range (0..{n - 1})")
    transforms = estimate_alignment(frames, given, provisional, method=method, reference=ref,
                                    clip_margin=clip_margin, warnings=warnings,
                                    progress=progress)
    small = _aligned_working_frames(frames, transforms, max_side=max_side)
    # the solve gets the frames' own times (seconds, None where unknown), as unaligned
    times, time_source = resolve_exposure_times(frames.items, exposure_times,
                                                list(frames.sources))
    options.setdefault("clip_margin", clip_margin)
    model = calibrate_response(small, times, progress=progress, **options)
    model.diagnostics["exposure_source"] = time_source
    model.sources = list(frames.sources)
    diag = model.diagnostics
    diag["warnings"] = [_name_arrays(w, frames.sources) for w in diag.get("warnings", [])]
    diag["frames_used"] = [_name_arrays(f, frames.sources)
                           for f in diag.get("frames_used", [])]
    diag["per_pair_rms_log"] = {_name_arrays(k, frames.sources): v
                                for k, v in diag.get("per_pair_rms_log", {}).items()}
    for c in diag.get("contradicting_times", []) or []:
        c["frame"] = _name_arrays(str(c.get("frame")), frames.sources)
    model.diagnostics["calibrated_on"] = (f"frames aligned ({method}), long side "
                                          f"{max(small[0].shape[:2])} px")
    model.diagnostics["alignment"] = {
        "method": method, "reference": frames.sources[ref],
        "transforms": [np.round(t, 6).tolist() for t in transforms]}
    return model, transforms, ref


class _GammaModel:
    """Stand-in inverse response f⁻¹(z) = z^2.2 when no model is at hand."""

    max_code = 255

    def inverse_response(self, codes):
        z = np.clip(np.asarray(codes, dtype=float) / self.max_code, 0, 1)
        return np.repeat((z ** 2.2)[:, None], 3, axis=1)


def warp_to_reference(image: np.ndarray, transform: np.ndarray, *, border_value=0,
                      interpolation: str = "linear") -> np.ndarray:
    """Resample a frame onto the reference frame's pixel grid.

    Parameters
    ----------
    image : numpy.ndarray
        ``HxW`` or ``HxWxC`` frame.
    transform : numpy.ndarray
        3×3 map from reference to frame coordinates (:func:`estimate_alignment`).
    border_value : scalar
        Value outside the frame.
    interpolation : {"linear", "nearest"}

    Returns
    -------
    numpy.ndarray
        Same shape and dtype.
    """
    cv2 = _cv2()
    h = np.asarray(transform, dtype=np.float64)
    hh, ww = image.shape[:2]
    flags = (cv2.INTER_LINEAR if interpolation == "linear" else cv2.INTER_NEAREST) \
        | cv2.WARP_INVERSE_MAP
    bv = (border_value,) * 4
    if np.allclose(h[2], [0, 0, 1]):
        if np.allclose(h[:2, :2], np.eye(2)) and np.allclose(h[:2, 2], np.round(h[:2, 2])):
            return _shift_integer(image, int(round(h[0, 2])), int(round(h[1, 2])), border_value)
        return cv2.warpAffine(image, h[:2], (ww, hh), flags=flags,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=bv)
    return cv2.warpPerspective(image, h, (ww, hh), flags=flags,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=bv)


def _shift_integer(image, tx: int, ty: int, border_value) -> np.ndarray:
    """out(x, y) = image(x + tx, y + ty), constant outside."""
    out = np.full_like(image, border_value)
    hh, ww = image.shape[:2]
    ys, yd = (slice(ty, hh), slice(0, hh - ty)) if ty >= 0 else (slice(0, hh + ty),
                                                                  slice(-ty, hh))
    xs, xd = (slice(tx, ww), slice(0, ww - tx)) if tx >= 0 else (slice(0, ww + tx),
                                                                  slice(-tx, ww))
    if abs(tx) < ww and abs(ty) < hh:
        out[yd, xd] = image[ys, xs]
    return out


def _default_reference(exposures) -> int:
    """The middle frame by exposure (the lower middle for an even count)."""
    order = np.argsort(np.asarray(exposures, dtype=float), kind="stable")
    return int(order[(len(order) - 1) // 2])


def _clip_limits(max_code, clip_margin: float, linear: bool):
    """(lo, hi): values ≤ lo or ≥ hi are clipped.

    Codes: within ``clip_margin`` (8-bit scale) of 0 or the maximum.  Linear data: 0 (black
    clip) and, for integer data, within ``clip_margin/255`` of white; float data clip at
    ``1 − 1e-4`` (white = 1).
    """
    if max_code is None:  # linear float data, white = 1
        return 0.0, 1.0 - 1e-4
    m = clip_margin * max_code / 255.0
    return (0.0 if linear else m), max_code - m


# --------------------------------------------------------------------------------------
# the merge
# --------------------------------------------------------------------------------------

def merge_hdr(images, exposure_times=None, model=None, *, weighting="hat",
              align=False, deghost: bool = False, reference: int | None = None,
              linear: bool = False, noise: NoiseModel | None = None,
              clip_margin: float = DEFAULT_CLIP_MARGIN, deghost_threshold: float = 3.0,
              deghost_tolerance: float = 0.1, calibrate_options: dict | None = None,
              progress=None) -> HDRResult:
    """Merge a bracketed exposure stack into a radiance map.

    The per-pixel, per-channel weighted mean of Debevec & Malik (SIGGRAPH 1997, Eq. 6,
    here on linear values rather than logarithms)::

        E = Σ_j w_j · f⁻¹(I_j) / e_j  /  Σ_j w_j

    with the inverse response f⁻¹ of a :class:`~selfcal.ResponseModel` (Lin et al., ICCV
    2011, §5; calibrated on the fly with :func:`selfcal.calibrate_response` when none is
    given) and ``e_j`` the frame's relative exposure.  ``w_j`` is **zero** wherever any
    channel of frame ``j`` is clipped (a code within ``clip_margin`` of 0 or of the
    maximum), so clipped values never leak in.

    Pixels no frame measures unclipped (clipped in every frame) are filled per channel
    from one frame and flagged in :attr:`HDRResult.unmeasured`: from the **darkest** frame
    (shortest exposure) when some channel is clipped at white there -- a highlight; its
    ``f⁻¹(I)/e`` is a lower bound -- and otherwise from the **brightest** frame -- a
    shadow; an upper bound.  Where alignment leaves that frame without data, the reference
    frame is used.

    Frames are streamed: paths are decoded one at a time (twice with alignment: once to
    estimate it, once to merge) into float32 accumulators (numerator and denominator per
    channel), processed in strips of rows with OpenCV lookup tables (``cv2.LUT``) for f⁻¹
    and the weights.  Only the reference frame's codes (for deghosting) and those of the
    darkest and brightest frames (for the fill) are kept, as codes.

    Parameters
    ----------
    images : sequence
        ``HxWx3`` uint8/uint16 RGB arrays or paths (JPEG/PNG/TIFF), one scene; or, with
        ``linear=True``, linear values (float in [0, 1] with white = 1, or uint8/uint16
        codes proportional to the signal).
    exposure_times : sequence of float or None, optional
        Relative exposure per frame (seconds, or anything proportional to the exposure;
        None = unknown).  Default: EXIF ``t · ISO/100 / N²`` for paths
        (:attr:`selfcal.io.ExposureInfo.relative_exposure`), so that brackets of one
        session share a scale.  Where the model refined the exposures, or found a given
        time contradicted by the pixels (``model.diagnostics['contradicting_times']``),
        its estimates are used instead (scaled to the given units) with a warning.
    model : ResponseModel or object, optional
        Anything with ``inverse_response(codes) -> (n, 3)`` (per-channel f⁻¹, the fast LUT
        path), or with ``to_raw(rendered) -> float32`` (a pipeline model: the backward
        JPEG→raw map, applied to each strip; its noise slopes are taken on the grey axis).
        Default: calibrated on the fly from the frames -- with ``align``, from the frames
        aligned first (downscaled to a 2048-pixel long side; alignment then uses a
        gamma-2.2 stand-in response), since misaligned frames give wrong correspondences.
    weighting : {"hat", "noise"} or callable
        ``"hat"``: Debevec & Malik's triangle on the code (:func:`weight_hat`).
        ``"noise"``: inverse variance of ``f⁻¹(I)/e`` under :class:`NoiseModel`,
        ``w = e² / (shot·x + read² + (f⁻¹'(z)·σ_z)²)`` (Granados et al., CVPR 2010;
        Hasinoff et al., CVPR 2010; see :func:`noise_variance`).
        A callable ``w(z)`` of the normalised code ``z`` in [0, 1] (any shape,
        element-wise, non-negative) is used like the hat (colour-hdri style).
    align : {False, "mtb", "homography"}
        Align every frame to the reference (see :func:`estimate_alignment`); ``True``
        means ``"mtb"``.  Warped frames carry no data outside their footprint, and a
        pixel interpolated from a clipped one counts as clipped.
    deghost : bool
        Per pixel, exclude frames whose radiance estimate disagrees with the reference
        frame's beyond the noise: on luminance ``Y``,
        ``(g·Y_j − Y_ref)² > k² (g²·Var[Y_j] + Var[Y_ref])`` with
        ``k = deghost_threshold``, the variances of :func:`noise_variance` plus a relative
        floor ``(max(deghost_tolerance, s) · Y)²`` for calibration and exposure errors,
        where ``g`` and ``s`` are the median and robust spread of the frame's ratio to the
        reference over the pixels both measure; then a 5×5 median filter (ghosts are
        regions).  Where the reference frame is clipped, the weighted mean of all frames
        is kept.  :attr:`HDRResult.ghost` marks the pixels where a frame was excluded.
        Moving objects that change only hue, not luminance, are not detected.
    reference : int, optional
        Index of the reference frame; default the middle one by exposure.
    linear : bool
        The frames are linear already (no model; a given model is an error).
    noise : NoiseModel, optional
        For ``weighting="noise"`` and deghosting.  Default :class:`NoiseModel()`.
    clip_margin : float
        Codes (8-bit scale) within this distance of 0 or the maximum count as clipped
        (default 2, as in calibration).
    deghost_threshold, deghost_tolerance : float
        ``k`` and the relative error floor of the deghosting test.
    calibrate_options : dict, optional
        Keyword arguments for :func:`selfcal.calibrate_response` when it runs on the fly.
    progress : callable, optional
        ``progress(stage, done, total, detail)`` with stages ``"read"``/``"solve"`` (the
        calibration), ``"align"`` and ``"merge"``.

    Returns
    -------
    HDRResult

    Raises
    ------
    InputError
        Unreadable or mismatched frames (the message names the file), bad arguments.
    CalibrationError
        Exposures that cannot be determined; calibration failures.

    References
    ----------
    Debevec & Malik, SIGGRAPH 1997; Lin et al., ICCV 2011; Granados et al., CVPR 2010;
    Hasinoff et al., CVPR 2010; Ward, JGT 2003; Evangelidis & Psarakis, TPAMI 2008.

    Examples
    --------
    >>> import selfcal
    >>> from selfcal import synth
    >>> stack = synth.demo_stack()
    >>> result = selfcal.merge_hdr(stack.images, stack.exposure_times)
    >>> result.radiance.dtype, result.radiance.shape
    (dtype('float32'), (256, 384, 3))
    """
    if weighting not in ("hat", "noise") and not callable(weighting):
        raise InputError(f"unknown weighting {weighting!r} (hat, noise or a function)")
    if align is True:
        align = "mtb"
    if align not in (False, None, "mtb", "homography"):
        raise InputError(f"unknown alignment {align!r} (mtb or homography)")
    noise = NoiseModel() if noise is None else noise
    if linear and model is not None:
        raise InputError("linear=True: the frames are linear already; do not pass a model")
    frames = _Frames(images, linear)
    linear = frames.linear  # raw files are linear
    n = len(frames)
    warnings: list[str] = []
    diagnostics: dict = {"weighting": weighting if isinstance(weighting, str)
                         else getattr(weighting, "__name__", "callable")}

    fresh = False
    transforms = None
    if model is None and not linear:
        if n < 2:
            raise CalibrationError("one frame and no model: give a model (a response needs "
                                   "at least two frames to calibrate)")
        from .response.calibrate import calibrate_response

        options = dict(calibrate_options or {})
        if align:
            model, transforms, ref0 = calibrate_aligned(
                frames, exposure_times, method=align, reference=reference,
                clip_margin=clip_margin, warnings=warnings, progress=progress, **options)
            diagnostics["calibrated_on"] = model.diagnostics.get("calibrated_on")
        else:
            model = calibrate_response(frames.items, exposure_times, progress=progress,
                                       **options)
        fresh = True
        diag = getattr(model, "diagnostics", {})
        diagnostics["model_verdict"] = diag.get("verdict")
        for w in diag.get("warnings", []):
            if "contradict" not in w:       # reported below, with what is done about it
                warnings.append(f"calibration: {_name_arrays(w, frames.sources)}")
        for c in diag.get("contradicting_times", []) or []:
            c["frame"] = _name_arrays(str(c.get("frame")), frames.sources)

    exposures, exposure_source = _resolve_exposures(frames, exposure_times, model, fresh,
                                                    warnings)
    ref = _default_reference(exposures) if reference is None else int(reference)
    if not 0 <= ref < n:
        raise InputError(f"reference frame {reference} is out of range (0..{n - 1})")

    if align and n > 1 and transforms is None:
        transforms = estimate_alignment(frames, exposures, model, method=align, reference=ref,
                                        linear=linear, clip_margin=clip_margin,
                                        warnings=warnings, progress=progress)
    elif transforms is not None and ref != ref0:
        # the reference moved (the model's exposures reordered the frames): re-express
        inv = np.linalg.inv(transforms[ref])
        transforms = [t @ inv for t in transforms]
        transforms = [t / t[2, 2] for t in transforms]
        transforms[ref] = np.eye(3)

    hh, ww = frames.shape
    num = np.zeros((hh, ww, 3), dtype=np.float32)
    den = np.zeros((hh, ww, 3), dtype=np.float32)
    count = np.zeros((hh, ww), dtype=np.uint8)
    ghost = np.zeros((hh, ww), dtype=bool)
    rows = max(8, _STRIP_PIXELS // max(ww, 1))
    strips = [slice(y, min(y + rows, hh)) for y in range(0, hh, rows)]

    darkest = int(np.argmin(exposures))
    brightest = int(np.argmax(exposures))
    kept: dict[int, tuple] = {}          # frame -> (codes, coverage mask or None)
    order = [ref] + [k for k in range(n) if k != ref]
    lin = None
    tables: dict[int, _FrameTables] = {}
    need_x = deghost and n > 1
    used_fraction = [0.0] * n
    excluded_fraction = [0.0] * n
    ghost_stats: dict[int, dict] = {}
    cv2 = _cv2()
    local = threading.local()
    pool = ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)))

    try:
        for done, k in enumerate(order):
            img = frames.load(k)
            if lin is None:
                mc = _max_code(img)
                lin = _Lineariser(model, linear, mc)
                lo, hi = _clip_limits(mc, clip_margin, linear)
            elif _max_code(img) != lin.max_code:
                raise InputError(f"sample type {img.dtype} differs from the other frames",
                                 frames.sources[k])
            tab = _FrameTables(lin, exposures[k], weighting, noise, lo, hi, need_x or k == ref,
                               float(np.max(exposures)))
            tables[k] = tab
            cover = None
            if transforms is not None and k != ref and not _negligible(transforms[k], (hh, ww)):
                # clipped anywhere (before warping) -> _CLIPPED; outside the frame -> 255
                bad = np.where(tab.valid(img) > 0, 0, _CLIPPED).astype(np.uint8)
                img = warp_to_reference(img, transforms[k])
                cover = warp_to_reference(bad, transforms[k], border_value=255)
                del bad
            if k in (darkest, brightest) or (k == ref and (need_x or transforms is not None)):
                kept[k] = (img, cover)
            off = None
            if need_x and k != ref:
                off, stats = _ghost_mask(img, cover, kept[ref][0], tab, tables[ref], strips,
                                         deghost_threshold, deghost_tolerance)
                ghost_stats[k] = stats
            def accumulate(s, img=img, cover=cover, off=off, tab=tab, k=k):
                """One strip of one frame into the accumulators (strips are disjoint)."""
                codes = img[s]
                valid = tab.valid(codes)
                if cover is not None:
                    valid[cover[s] > 0] = 0
                excluded = 0
                if off is not None:
                    o = off[s] > 0
                    o &= valid > 0
                    if o.any():
                        valid[o] = 0
                        ghost[s] |= o
                        excluded = int(o.sum())
                n_valid = cv2.countNonZero(valid)
                if n_valid == 0:
                    return 0, excluded
                if tab.lut:
                    # invalid pixels -> the maximum code in every channel, where the tables
                    # hold zero weight: then plain (unmasked) sums.  Strip buffers are reused
                    # (fresh large allocations cost page faults).
                    rows_s = s.stop - s.start
                    bufs = _thread_buffers(local, rows, ww, img.dtype)
                    if n_valid < valid.size:
                        buf = bufs["codes"][:rows_s]
                        np.copyto(buf, codes)
                        cv2.bitwise_or(buf, (lin.max_code,) * 3 + (0,), dst=buf,
                                       mask=cv2.bitwise_not(valid))
                        codes = buf
                    a, w, _, _ = tab.evaluate(codes, need_x=False,
                                              out=(bufs["a"][:rows_s], bufs["w"][:rows_s]))
                    np.add(num[s], a, out=num[s])
                    np.add(den[s], w, out=den[s])
                else:
                    a, w, _, _ = tab.evaluate(codes, need_x=False)
                    cv2.add(num[s], a, dst=num[s], mask=valid)
                    cv2.add(den[s], w, dst=den[s], mask=valid)
                np.add(count[s], valid >> 7, out=count[s])
                return n_valid, excluded

            # strips in parallel threads (OpenCV and numpy release the GIL) on the table path;
            # a model's own to_raw is called from this thread only
            for n_valid, excluded in (pool.map if tab.lut else map)(accumulate, strips):
                used_fraction[k] += float(n_valid)
                excluded_fraction[k] += float(excluded)
            del img, cover
            if progress is not None:
                progress("merge", done + 1, n, frames.sources[k])
    finally:
        pool.shutdown()

    npix = float(hh * ww)
    diagnostics["frame_used_fraction"] = [u / npix for u in used_fraction]
    if need_x:
        diagnostics["deghost_excluded_fraction"] = [e / npix for e in excluded_fraction]
        diagnostics["deghost_reference_agreement"] = {
            frames.sources[k]: st for k, st in sorted(ghost_stats.items())}
        poor = [(st["spread"], k) for k, st in ghost_stats.items()
                if st["samples"] >= 100 and st["spread"] > 0.25]
        if poor:
            spread, k = max(poor)
            warnings.append(
                f"deghosting: {len(poor)} frame(s) disagree with the reference frame "
                f"{Path(frames.sources[ref]).name} by {100 * spread:.0f}% (typical, at "
                f"{Path(frames.sources[k]).name}) even where nothing moves: the response "
                "model or the exposures fit poorly, so deghosting was made cautious")

    # radiance = num / den; unmeasured channels filled from the darkest / brightest frame
    unmeasured = np.zeros((hh, ww), dtype=bool)
    for s in strips:
        ns, ds = num[s], den[s]
        hole = ds <= 0
        np.divide(ns, ds, out=ns, where=~hole)
        hole_px = _any_channel(hole)
        if hole_px.any():
            unmeasured[s] = hole_px
            fill = _fill_strip(s, kept, tables, darkest, brightest, ref, hi)
            np.copyto(ns, fill, where=hole)
    del den
    n_unmeasured = int(np.count_nonzero(unmeasured))
    if n_unmeasured:
        warnings.append(f"{n_unmeasured} pixels ({100 * n_unmeasured / npix:.2g}%) are clipped "
                        "in every frame (unmeasured; filled from the darkest frame for "
                        "highlights, the brightest for shadows)")
    return HDRResult(radiance=num, unmeasured=unmeasured, ghost=ghost, exposures=exposures,
                     warnings=warnings, sources=list(frames.sources), reference=ref,
                     transforms=transforms, exposure_source=exposure_source,
                     frame_count=count, diagnostics=diagnostics, model=model)


_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)


def _thread_buffers(local, rows: int, width: int, dtype) -> dict:
    """Per-thread strip buffers (codes, weighted values, weights)."""
    bufs = getattr(local, "bufs", None)
    if bufs is None or bufs["codes"].dtype != dtype:
        bufs = local.bufs = {"codes": np.empty((rows, width, 3), dtype=dtype),
                             "a": np.empty((rows, width, 3), dtype=np.float32),
                             "w": np.empty((rows, width, 3), dtype=np.float32)}
    return bufs


def _luma(x, w=_LUMA):
    return w[0] * x[..., 0] + w[1] * x[..., 1] + w[2] * x[..., 2]


def _disagree(x, v, xr, vr, k: float, tol: float, gain: float = 1.0) -> np.ndarray:
    """Pixels where two radiance estimates differ beyond the noise (deghosting test).

    Compared on luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` -- gamut mapping and
    JPEG chroma subsampling disturb the channels of saturated colours but not their
    luminance much -- with ``Var[Y] = Σ_c w_c² Var[X_c] + (tol · Y)²``:
    ``(g·Y − Y_ref)² > k² (g²·Var[Y] + Var[Y_ref])``, ``g`` the correction of the frame's
    typical ratio to the reference (see :func:`_ghost_mask`).
    """
    y, yr = _luma(x) * np.float32(gain), _luma(xr)
    g2 = np.float32(gain * gain)
    var = (g2 * _luma(v, _LUMA * _LUMA) + _luma(vr, _LUMA * _LUMA)
           + np.float32(tol * tol) * (y * y + yr * yr))
    return (y - yr) ** 2 > np.float32(k * k) * var


def _ratio_statistics(img, cover, ref_img, tab, ref_tab, strips, step: int = 4):
    """Median and robust spread (1.4826 MAD) of log(Y / Y_ref) over pixels both measure.

    On a subsample (every ``step``-th row and column).  The median is the frame's exposure
    mismatch with the reference; the spread is how well the response model and noise
    explain the pair (a static scene and a good model give a few per cent).
    """
    logs = []
    for s in strips:
        first = s.start + (-s.start) % step
        sub = (slice(first, s.stop, step), slice(None, None, step))
        codes = np.ascontiguousarray(img[sub])
        rcodes = np.ascontiguousarray(ref_img[sub])
        if codes.size == 0:
            continue
        both = (tab.valid(codes) > 0) & (ref_tab.valid(rcodes) > 0)
        if cover is not None:
            both &= cover[sub] == 0
        if not both.any():
            continue
        y = _luma(tab.radiance(codes))[both]
        yr = _luma(ref_tab.radiance(rcodes))[both]
        ok = (y > 0) & (yr > 0)
        logs.append(np.log(y[ok]) - np.log(yr[ok]))
    r = np.concatenate(logs) if logs else np.zeros(0)
    if r.size < 100:
        return 0.0, 0.0, int(r.size)
    med = float(np.median(r))
    return med, 1.4826 * float(np.median(np.abs(r - med))), int(r.size)


def _any_channel(mask3: np.ndarray) -> np.ndarray:
    """``mask3.any(axis=2)`` for 3 channels, without numpy's slow strided reduction."""
    return mask3[..., 0] | mask3[..., 1] | mask3[..., 2]


def _ghost_mask(img, cover, ref_img, tab, ref_tab, strips, k: float, tol: float):
    """uint8 mask (255) of the pixels where a frame disagrees with the reference frame.

    First the frame's typical ratio to the reference ``g`` and the spread ``s`` of
    ``log(Y/Y_ref)`` (:func:`_ratio_statistics`): the test of :func:`_disagree` is made
    after dividing out ``g`` (an exposure error is not a ghost) with the relative floor
    ``max(tol, s)`` (a poorly fitting response makes deghosting cautious rather than
    wild).  Then a 5×5 median filter: a ghost is a region, while isolated pixels and thin
    lines along edges (JPEG ringing, chroma subsampling, residual misalignment) are noise
    the model does not describe.

    Returns
    -------
    (numpy.ndarray, dict)
        The mask, and ``{"log_ratio": median, "spread": s, "samples": n}``.
    """
    cv2 = _cv2()
    med, spread, count = _ratio_statistics(img, cover, ref_img, tab, ref_tab, strips)
    gain = math.exp(-med)
    floor = max(tol, spread)
    off = np.zeros(img.shape[:2], dtype=np.uint8)
    for s in strips:
        codes, rcodes = img[s], ref_img[s]
        both = (tab.valid(codes) > 0) & (ref_tab.valid(rcodes) > 0)
        if cover is not None:
            both &= cover[s] == 0
        x, v = tab.radiance_variance(codes)
        xr, vr = ref_tab.radiance_variance(rcodes)
        off[s] = (_disagree(x, v, xr, vr, k, floor, gain) & both).view(np.uint8) * np.uint8(255)
    return cv2.medianBlur(off, 5), {"log_ratio": med, "spread": spread, "samples": count}


def _fill_strip(s, kept, tables, darkest, brightest, ref, hi):
    """Values for pixels no frame measured: darkest frame for highlights, else brightest.

    A pixel is a highlight when some channel of the darkest frame is clipped at white
    there.  Where the chosen frame was warped and does not reach the pixel, the reference
    frame's value is used.
    """
    dcodes, dcover = kept[darkest]
    bcodes, bcover = kept[brightest]
    high = _any_channel(dcodes[s] >= hi)
    fill = np.where(high[..., None], tables[darkest].radiance(dcodes[s]),
                    tables[brightest].radiance(bcodes[s]))
    outside = np.zeros(high.shape, dtype=bool)
    if dcover is not None:
        outside |= high & (dcover[s] > _OUTSIDE)
    if bcover is not None:
        outside |= ~high & (bcover[s] > _OUTSIDE)
    if outside.any():
        fill[outside] = tables[ref].radiance(kept[ref][0][s])[outside]
    return fill


# --------------------------------------------------------------------------------------
# linearised frames
# --------------------------------------------------------------------------------------

def linearize_images(images, model, *, progress=None):
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
    progress : callable, optional
        ``progress("linearize", done, total, source)``.

    Yields
    ------
    (str, numpy.ndarray)
        The source (path or ``"array #k"``) and its float32 ``HxWx3`` linear image.
    """
    items = list(images)
    sources = [str(f) if _is_path(f) else f"array #{k}" for k, f in enumerate(items)]
    from .io import read_image

    for k, item in enumerate(items):
        img = read_image(item) if _is_path(item) else np.asarray(item)
        if img.ndim != 3 or img.shape[2] != 3:
            raise InputError(f"expected an HxWx3 RGB image, got shape {img.shape}", sources[k])
        if img.dtype not in (np.uint8, np.uint16):
            raise InputError(f"unsupported dtype {img.dtype} (uint8 or uint16 codes)",
                             sources[k])
        lin = _Lineariser(model, False, _max_code(img))
        if lin.kind == "lut":
            out = np.empty(img.shape, dtype=np.float32)
            table = lin.table.astype(np.float32)
            rows = max(8, _STRIP_PIXELS // img.shape[1])
            for y in range(0, img.shape[0], rows):
                out[y:y + rows] = _apply_lut(img[y:y + rows], table)
        else:
            out = lin.values(img)
        del img
        if progress is not None:
            progress("linearize", k + 1, len(items), sources[k])
        yield sources[k], out
