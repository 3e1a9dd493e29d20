"""A stack's frames as the merge and the alignment read them: decoding, linearising, exposures.

The rooms above -- :mod:`selfcal.stack.align`, the response path's "align, then calibrate"
(:func:`selfcal.response.calibrate.calibrate_aligned`) and the merge of :mod:`selfcal.hdr`
-- all see a bracketed stack through the pieces here:

* :class:`StackFrames`: the frames, arrays used as they are or paths decoded one at a time
  (JPEG/PNG/TIFF through :mod:`selfcal.io`, camera raw through :mod:`selfcal.io.raw`), with
  their sizes and sample types checked before any pixel work;
* :class:`Lineariser`: what a response model makes of codes, as a table of the inverse
  response ``f⁻¹`` at every code (a :class:`~selfcal.ResponseModel` of Lin, Kim, Süsstrunk
  & Brown, *Revisiting Radiometric Calibration for Color Computer Vision*, ICCV 2011, §5,
  Eq. 7) and of its slope, or the backward map ``to_raw`` of a pipeline model, or nothing
  for linear data;
* :func:`clip_limits`: which codes count as clipped (the calibration's rule,
  :func:`selfcal.stack.samples.frame_masks`);
* :func:`model_frame_index`: which of a model's frames each frame is (files by path,
  arrays by content).

The frames' exposures are not here: :mod:`selfcal.exposure` reads, resolves and records
them.  Ours, not the papers': the middle exposure as the default reference.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import import_cv2, is_path, read_image, read_image_size
from ..io.raw import is_raw_path, read_raw_linear

#: Codes (on the 8-bit scale) within this distance of 0 or of the maximum count as clipped
#: -- the same rule as the calibration's (``selfcal.stack.samples.frame_masks``).
DEFAULT_CLIP_MARGIN = 2.0

#: Rows per strip are chosen so that a strip holds about this many pixels.
STRIP_PIXELS = 1 << 20


# --------------------------------------------------------------------------------------
# frames
# --------------------------------------------------------------------------------------

def content_digest(image: np.ndarray) -> str:
    """Hash of every pixel of ``image`` (with its shape and dtype): equal for identical frames.

    Frames are judged duplicates on their full content, not on a subsample: two frames
    that are almost entirely white differ in a few dozen pixels only.  SHA-1, not for
    security (nothing here is adversarial) but for speed: with the CPU's SHA instructions
    it hashes about three times faster than BLAKE2b, and the digest reads every pixel of
    every frame (on a 1.5 MP stack it cost half as much as decoding it).
    """
    h = hashlib.sha1(usedforsecurity=False)
    h.update(f"{image.shape}{image.dtype}".encode())
    h.update(np.ascontiguousarray(image).data.cast("B"))
    return h.hexdigest()[:32]


class StackFrames:
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
        self.sources = [str(f) if is_path(f) else f"array #{k}"
                        for k, f in enumerate(self.items)]
        self.paths = [Path(f) if is_path(f) else None for f in self.items]
        self._digests: dict[int, str] = {}
        self._check()

    def digest(self, k: int) -> str:
        """:func:`content_digest` of array frame ``k`` (computed once): how a model
        calibrated on these arrays recognises them."""
        if k not in self._digests:
            self._digests[k] = content_digest(np.asarray(self.items[k]))
        return self._digests[k]

    def __len__(self):
        return len(self.items)

    def _check(self) -> None:
        shape: tuple[int, ...] | None = None
        dtype = None
        for k, item in enumerate(self.items):
            src = self.sources[k]
            if self.raw_files[k]:
                hw = _raw_size(item)
                dt = None
            elif is_path(item):
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
        assert shape is not None        # the frames are not empty (__init__)
        self.shape: tuple[int, ...] = shape

    def load(self, k, *, reduce: int = 1) -> np.ndarray:
        item = self.items[k]
        if self.raw_files[k]:
            arr = read_raw_linear(item).rgb
            if arr.shape[:2] != self.shape:
                raise InputError(f"raw decoded to {arr.shape[1]}x{arr.shape[0]}, not the "
                                 f"{self.shape[1]}x{self.shape[0]} its header gave",
                                 self.sources[k])
            return arr
        if is_path(item):
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
    return is_path(item) and is_raw_path(item)


def max_code_of(arr) -> int | None:
    if arr.dtype == np.uint8:
        return 255
    if arr.dtype == np.uint16:
        return 65535
    return None


# --------------------------------------------------------------------------------------
# linearisers: codes -> linear values per frame, and per-frame LUTs
# --------------------------------------------------------------------------------------

class Lineariser:
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
        self.table: np.ndarray | None = None    # (K, 3) f⁻¹ at every code, float64
        self.slope: np.ndarray | None = None    # (K, 3) d f⁻¹ / dz at every code
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

    def code_std(self) -> float | None:
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


def apply_lut(codes: np.ndarray, lut: np.ndarray, out: np.ndarray | None = None):
    """Per-channel table lookup: ``out[..., c] = lut[codes[..., c], c]`` as float32.

    uint8 codes go through ``cv2.LUT`` (one pass, multi-threaded); uint16 through numpy
    indexing.  ``out``, when given, is filled (a contiguous float32 buffer of the shape).
    """
    if codes.dtype == np.uint8:
        if out is None:
            return import_cv2().LUT(codes, lut.reshape(1, 256, 3))
        return import_cv2().LUT(codes, lut.reshape(1, 256, 3), dst=out)
    if out is None:
        out = np.empty(codes.shape, dtype=np.float32)
    for c in range(3):
        out[..., c] = lut[:, c][codes[..., c]]
    return out


def clip_limits(max_code, clip_margin: float, linear: bool):
    """(lo, hi): values ≤ lo or ≥ hi are clipped.

    Codes: within ``clip_margin`` (8-bit scale) of 0 or the maximum.  Linear data: 0 (black
    clip) and, for integer data, within ``clip_margin/255`` of white; float data clip at
    ``1 − 1e-4`` (white = 1).
    """
    if max_code is None:  # linear float data, white = 1
        return 0.0, 1.0 - 1e-4
    m = clip_margin * max_code / 255.0
    return (0.0 if linear else m), max_code - m


def frame_limits(max_code, clip_margin: float, linear: bool, stuck):
    """Per channel (lo, hi, floor limit or None) for :class:`selfcal.hdr.weights.FrameTables`.

    The clip limits of :func:`selfcal.stack.frames.clip_limits` (a pixel with any channel at
    or beyond them is clipped), ``hi`` lowered to the stuck ceiling of each channel, and
    the black floor of each channel, below which that channel's codes get zero weight
    (``stuck``: normalised codes, :func:`selfcal.response.stuck_codes.stuck_code_levels`; the codes
    below the floor and from the ceiling up do not move with exposure, the floor code
    itself is the first that does).  A floor zeroes its channel only: the other channels
    of a dark, coloured pixel are still measured (zeroing every channel of a pixel with one
    channel at its floor raised the odd/even median |log ratio| of ntu's night scene,
    ``python3 -m bench.hdr_oddeven``, from 0.29 to 0.54).
    """
    lo, hi = clip_limits(max_code, clip_margin, linear)
    lo = np.full(3, float(lo))
    hi = np.full(3, float(hi))
    floor = None
    if stuck is not None and max_code is not None:
        fl, ceiling = (np.asarray(v, dtype=float) * max_code for v in stuck)
        floor = np.where(fl > 0, fl - 0.5, 0.0)
        hi = np.minimum(hi, np.where(ceiling < max_code, ceiling, max_code))
    return lo, hi, floor


# --------------------------------------------------------------------------------------
# exposures and the reference frame
# --------------------------------------------------------------------------------------

def default_reference(exposures) -> int:
    """The middle frame by exposure (the lower middle for an even count)."""
    order = np.argsort(np.asarray(exposures, dtype=float), kind="stable")
    return int(order[(len(order) - 1) // 2])


def model_frame_index(model, frames: StackFrames, fresh: bool):
    """Index of each frame in the model's sources (None where it is not there): files by
    their path, arrays by their content (the model's ``diagnostics["frame_digests"]``, the
    digest of every frame it read: an array with the pixels of one of them is that frame,
    whatever its name was)."""
    n = len(frames)
    sources = list(getattr(model, "sources", []) or [])
    exposures = getattr(model, "exposures", None)
    if exposures is None or len(sources) != len(np.atleast_1d(exposures)):
        return [None] * n
    if fresh:
        return list(range(n))
    digests = list((getattr(model, "diagnostics", None) or {}).get("frame_digests") or [])
    by_digest = {d: i for i, d in enumerate(digests) if i < len(sources)}
    lookup = {}
    for i, s in enumerate(sources):
        lookup[str(Path(s))] = i
        try:
            lookup[str(Path(s).resolve())] = i
        except OSError:
            pass
    out: list[int | None] = []
    for k, p in enumerate(frames.paths):
        if p is None:
            out.append(by_digest.get(frames.digest(k)) if by_digest else None)
            continue
        out.append(lookup.get(str(p), lookup.get(str(p.resolve()))))
    return out
