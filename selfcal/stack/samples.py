"""Pixel correspondences across an exposure stack, and outlier masks with reasons.

The JPEG-only path (Lin et al., ICCV 2011, §5) needs intensity pairs (I, I') at the same
scene point in differently exposed frames.  This module reads a stack *streaming*: each
frame is decoded, reduced at once to block means on a coarse grid (``cv2.resize`` with
``INTER_AREA``), and dropped, so a stack of 24 MP frames never sits in memory as float
copies.  Block means of flat regions average JPEG and sensor noise away; blocks that are not
flat (edges, texture, demosaicing and sharpening artefacts) are avoided when the sample
locations are chosen.

Locations are chosen after the pass, from all reduced frames together: for every frame the
intensity range is cut into bins and the flattest blocks of each bin are taken, so that
every part of every frame's range is represented (stratified over intensity, preferring
flat regions).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import import_cv2
from .frames import DEFAULT_CLIP_MARGIN, content_digest

#: Reasons a sample can be rejected in a frame (or a pair), in the order they are tested.
REJECTION_REASONS = ("clipped", "saturated", "not_flat")
#: Long side (pixels) of the grey thumbnail kept of each frame: the verdict measures the
#: frames' motion against each other on it (:mod:`selfcal.response.verdict`).
THUMBNAIL_SIDE = 1024


def _grey_thumbnail(blocks: np.ndarray, max_code: int) -> np.ndarray:
    """The block means as a grey uint8 image, long side at most :data:`THUMBNAIL_SIDE`."""
    cv2 = import_cv2()
    h, w = blocks.shape[:2]
    scale = THUMBNAIL_SIDE / max(h, w)
    if scale < 1:
        blocks = cv2.resize(blocks, (max(1, round(w * scale)), max(1, round(h * scale))),
                            interpolation=cv2.INTER_AREA)
    grey = cv2.transform(blocks, np.full((1, 3), 255.0 / (3 * max_code)))
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


@dataclass
class ReducedFrame:
    """A frame reduced to block means, with what the full frame told about itself."""

    blocks: np.ndarray        # (h, w, 3) float32 block means, in codes
    block_max: np.ndarray     # (h, w) float32: highest code of any channel in the block's area
    block_min: np.ndarray     # (h, w) float32: lowest code of any channel
    max_code: int
    shape: tuple              # full frame (H, W)
    digest: str               # content hash of every decoded pixel, to find duplicate frames
    source: str               # file name or "array #k"
    thumbnail: np.ndarray | None = None   # grey uint8, long side <= THUMBNAIL_SIDE blocks
    channel_max: np.ndarray | None = None  # (h, w, 3) highest code per channel in the block
    channel_min: np.ndarray | None = None  # (h, w, 3) lowest code per channel


def _as_image_array(image, source: str) -> np.ndarray:
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise InputError(f"expected an HxWx3 RGB image, got shape {arr.shape}", source)
    if arr.dtype == np.uint8 or arr.dtype == np.uint16:
        return arr
    if np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)):
            raise InputError("the array holds NaN or infinite values", source)
        raise InputError(
            "float arrays are not camera codes; pass uint8 or uint16 images", source)
    raise InputError(f"unsupported dtype {arr.dtype} (uint8 or uint16 needed)", source)


def reduce_frame(image, *, block: int, source: str = "array",
                 digest: str | None = None, near_clip_blocks: int = 0) -> ReducedFrame:
    """Reduce one frame to ``block``×``block`` means, plus per-block extreme codes.

    With ``near_clip_blocks`` > 0 the extremes are taken over the block and its
    neighbours within that many blocks, so that a block next to a clipped one counts as
    clipped (Lin et al. §5 reject clipped pixels; keeping away from the JPEG damage around
    them is ours; off by default, ``ResponseOptions.near_clip_blocks``).

    Parameters
    ----------
    image : numpy.ndarray
        ``HxWx3`` uint8 or uint16 RGB.
    block : int
        Block edge in pixels (1 keeps every pixel).
    source : str
        Name used in error messages.
    digest : str, optional
        The frame's :func:`content_digest` when known (computed from ``image`` otherwise).
    near_clip_blocks : int
        Radius, in blocks, of the neighbourhood the extreme codes are taken over (0: the
        block alone).
    """
    cv2 = import_cv2()
    arr = _as_image_array(image, source)
    max_code = 255 if arr.dtype == np.uint8 else 65535
    h, w = arr.shape[:2]
    hb, wb = max(1, h // block), max(1, w // block)
    crop = arr[: hb * block, : wb * block]
    digest = content_digest(arr) if digest is None else digest
    if block == 1:
        blocks = crop.astype(np.float32)
        chmax = chmin = None                      # the pixels are their own extremes
        c0, c1, c2 = cv2.split(np.ascontiguousarray(crop))
        cmax = cv2.max(cv2.max(c0, c1), c2).astype(np.float32)
        cmin = cv2.min(cv2.min(c0, c1), c2).astype(np.float32)
    else:
        # INTER_AREA to a grid twice as fine, in the frame's own integer type (a float
        # copy of a 24 MP frame costs more than its decode); the 2x2 means of that grid
        # keep quarter-code precision, and its max/min catch partly clipped blocks
        fine = crop if block == 2 else cv2.resize(crop, (wb * 2, hb * 2),
                                                  interpolation=cv2.INTER_AREA)
        blocks = cv2.resize(fine.astype(np.float32), (wb, hb), interpolation=cv2.INTER_AREA)
        # OpenCV's per-channel max/min and 2x2 morphology beat numpy's strided reductions
        c0, c1, c2 = cv2.split(fine)
        kernel = np.ones((2, 2), np.uint8)
        cmax = cv2.dilate(cv2.max(cv2.max(c0, c1), c2), kernel, anchor=(0, 0))[::2, ::2]
        cmin = cv2.erode(cv2.min(cv2.min(c0, c1), c2), kernel, anchor=(0, 0))[::2, ::2]
        cmax = cmax.astype(np.float32)
        cmin = cmin.astype(np.float32)
        # per channel too, in the frame's own type (the histogram correspondences)
        fine3 = np.ascontiguousarray(fine)
        chmax = cv2.dilate(fine3, kernel, anchor=(0, 0))[::2, ::2]
        chmin = cv2.erode(fine3, kernel, anchor=(0, 0))[::2, ::2]
    if near_clip_blocks > 0:
        # JPEG ringing and chroma bleed from a clipped neighbour damage a block's codes
        near = np.ones((2 * int(near_clip_blocks) + 1,) * 2, np.uint8)
        cmax, cmin = cv2.dilate(cmax, near), cv2.erode(cmin, near)
    blocks = np.ascontiguousarray(blocks, dtype=np.float32)
    return ReducedFrame(blocks=blocks, block_max=cmax, block_min=cmin, max_code=max_code,
                        shape=(h, w), digest=digest, source=source,
                        thumbnail=_grey_thumbnail(blocks, max_code),
                        channel_max=chmax, channel_min=chmin)


class FrameSamples:
    """What every set of samples across a stack's frames has: ``values`` of shape
    ``(frames, samples, 3)``, and their counts."""

    values: np.ndarray

    @property
    def n_frames(self) -> int:
        return self.values.shape[0]

    @property
    def n_samples(self) -> int:
        return self.values.shape[1]


@dataclass
class SampleSet(FrameSamples):
    """Intensity samples at fixed locations across a stack.

    Attributes
    ----------
    values : ndarray, shape (F, n, 3)
        Block-mean codes normalised to [0, 1] (divided by ``max_code``).
    block_max, block_min : ndarray, shape (F, n)
        Extreme codes (normalised) inside each block: a block touching a clipped code is
        clipped even when its mean is not.
    flatness : ndarray, shape (n,)
        Local contrast of each block (lower is flatter), on the frame that chose it.
    locations : ndarray, shape (n, 2)
        Block row and column.
    max_code : int
    sources : list of str
    block : int
        Block edge in frame pixels.
    frame_shape : tuple
        ``(H, W)`` of the frames.
    digests : list of str
        :func:`content_digest` of each frame (every decoded pixel).
    thumbnails : list of ndarray
        Per frame, the block means as a grey uint8 image (long side at most
        :data:`THUMBNAIL_SIDE`), for the motion test of the verdict.
    thumbnail_pixel : float
        Frame pixels per thumbnail pixel.
    codes : list of ndarray or None
        Per frame, its decoded codes subsampled (:attr:`KeptData.codes_side`).
    """

    values: np.ndarray
    block_max: np.ndarray
    block_min: np.ndarray
    flatness: np.ndarray
    locations: np.ndarray
    max_code: int
    sources: list
    block: int
    frame_shape: tuple
    digests: list = field(default_factory=list)
    thumbnails: list = field(default_factory=list)
    thumbnail_pixel: float = 1.0
    codes: list | None = None
    reduced: list | None = None   # the ReducedFrames, when asked for (keep_reduced)
    clip_distance: np.ndarray | None = None   # (F, n) blocks to the nearest clipped block



def hsv_saturation(rgb: np.ndarray) -> np.ndarray:
    """HSV saturation ``(max - min) / max`` of RGB values (0 where max is 0).

    A numpy expression rather than ``skimage.color.rgb2hsv``: only S is needed, and the
    full conversion is several times slower.
    """
    cmax = rgb.max(axis=-1)
    cmin = rgb.min(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sat = np.where(cmax > 0, (cmax - cmin) / np.where(cmax > 0, cmax, 1), 0.0)
    return sat


def _local_contrast(blocks: np.ndarray) -> np.ndarray:
    """Spread of the codes over a block, its 8 neighbours *and* the three channels, over level.

    The spread is taken across channels too, so a flat but strongly coloured block ranks
    as less flat than a flat neutral one: flatness and neutrality together decide which
    blocks of an intensity bin are taken first.  That is deliberate.  Lin et al. (ICCV
    2011, §5) reject highly saturated pixels because the camera's colour processing moves
    them off the per-channel curves, and the same holds, more weakly, below β.  A per-
    channel spatial spread alone picks more coloured blocks and was less accurate
    (docs/decisions.md, "The other settings of the response solve stay at their
    defaults").
    """
    cv2 = import_cv2()
    # per-channel reductions through OpenCV: numpy's axis=2 reductions of an (h, w, 3)
    # array are strided and cost more than the rest of the sampling
    c0, c1, c2 = cv2.split(np.ascontiguousarray(blocks, dtype=np.float32))
    mean = (c0 + c1 + c2) / 3.0
    cmax = cv2.max(cv2.max(c0, c1), c2)
    cmin = cv2.min(cv2.min(c0, c1), c2)
    if blocks.shape[0] > 2:
        kernel = np.ones((3, 3), np.uint8)
        # max over channels commutes with the 3x3 max filter
        cmax = cv2.dilate(cmax, kernel)
        cmin = cv2.erode(cmin, kernel)
    return (cmax - cmin) / np.maximum(mean, 1.0)


def choose_locations(reduced: list[ReducedFrame], *, n_bins: int = 48, per_bin: int = 6,
                     max_samples: int = 6000, clip_margin: float = DEFAULT_CLIP_MARGIN,
                     seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Choose sample blocks stratified over intensity in every frame, flattest first.

    Returns
    -------
    flat_index : ndarray of int
        Indices into the flattened block grid.
    flatness : ndarray
        The local contrast of the chosen blocks (max over frames).
    """
    rng = np.random.default_rng(seed)
    max_code = reduced[0].max_code
    # flatness: the worst local contrast over frames, ignoring frames where a block is
    # clipped (clipped areas look flat but tell nothing); a running maximum, so no
    # frames-by-blocks float copy is made
    valid = []
    worst: np.ndarray | None = None
    for r in reduced:
        ok = ((r.block_max < max_code - clip_margin * max_code / 255)
              & (r.block_min > clip_margin * max_code / 255)).ravel()
        masked = np.where(ok, _local_contrast(r.blocks).ravel(), -np.inf)
        worst = masked if worst is None else np.maximum(worst, masked, out=worst)
        valid.append(ok)
    assert worst is not None        # reduced is not empty (max_code above)
    worst[~np.isfinite(worst)] = np.inf
    # a tie-breaking jitter keeps equal-contrast blocks (synthetic flat patches) spread out
    order_key = worst + rng.uniform(0, 1e-6, worst.shape)
    flattest_first = np.argsort(order_key)
    flattest_first = flattest_first[np.isfinite(worst[flattest_first])]
    chosen: set[int] = set()
    for r, ok in zip(reduced, valid):
        cand = flattest_first[ok[flattest_first]]
        if cand.size == 0:
            continue
        # the grey level of every block, then gathered: the channel mean of the block
        # means in the same float32 order as ``blocks.mean(axis=-1)``, on whole planes
        c0, c1, c2 = import_cv2().split(r.blocks)
        level = ((c0 + c1 + c2) / np.float32(3)).ravel()[cand] / max_code
        bins = np.minimum((level * n_bins).astype(np.int16), n_bins - 1)
        # a stable sort by bin keeps the flattest-first order inside each bin
        by_bin = np.argsort(bins, kind="stable")
        cand, cb = cand[by_bin], bins[by_bin]
        starts = np.searchsorted(cb, np.arange(n_bins))
        ends = np.searchsorted(cb, np.arange(n_bins), side="right")
        for s, e in zip(starts, ends):
            chosen.update(cand[s: min(e, s + per_bin)].tolist())
    idx = np.array(sorted(chosen), dtype=np.int64)
    if idx.size > max_samples:
        idx = np.sort(rng.choice(idx, size=max_samples, replace=False))
    return idx, worst[idx] if idx.size else np.zeros(0)


#: Locations taken per intensity bin and frame by :func:`collect_samples` (the flattest).
PER_BIN = 6

#: Blocks a frame is reduced to, about (:func:`working_block_size`).
TARGET_BLOCKS = 400_000


def working_block_size(shape, target_blocks: int = TARGET_BLOCKS) -> int:
    """Block edge that brings a frame of ``shape`` near ``target_blocks`` blocks (≥ 1).

    The edge is rounded down, so a frame has at least ``target_blocks`` blocks (when it
    has that many pixels) and fewer than four times as many; frames under 1.6 MP keep
    every pixel.  Rounding up instead (at most ``target_blocks``: 2×2 blocks for 1.5 MP
    frames) was faster and less accurate (docs/decisions.md, "Small frames keep every
    pixel").
    """
    h, w = shape[:2]
    return max(1, int(np.floor(np.sqrt(h * w / target_blocks))))


def _dct_factor(block: int) -> int:
    """The JPEG DCT scaling (1, 2, 4, 8) a ``block`` is read at: the largest dividing it
    that leaves at least 3 reduced pixels per block edge."""
    return max(f for f in (1, 2, 4, 8) if f == 1 or (f * 3 <= block and block % f == 0))


@dataclass(frozen=True)
class KeptData:
    """What :func:`collect_samples` keeps of the frames it reads, beyond the samples.

    Attributes
    ----------
    reduced : bool
        The reduced frames (every pixel, or block means) in the result's ``reduced``, for
        :func:`selfcal.response.histogram_samples.histogram_correspondences`.
    codes_side : int
        Every decoded frame's codes subsampled (every ``s``-th pixel of every ``s``-th
        row, no averaging: ``f⁻¹`` of a mean of codes is not the mean of ``f⁻¹``) to a
        long side of at most this many pixels, in the result's ``codes``, for the
        exposures measured after the fit (:mod:`selfcal.exposure.measured`); 0 keeps none.
    """

    reduced: bool = False
    codes_side: int = 0


def collect_samples(frames, *, sources=None, block: int | None = None,
                    per_bin: int | None = None, max_samples: int = 6000,
                    clip_margin: float = DEFAULT_CLIP_MARGIN, seed: int = 0, progress=None,
                    keep: KeptData | None = None, near_clip_blocks: int = 0) -> SampleSet:
    """Read a stack streaming and return samples at stratified flat locations.

    Parameters
    ----------
    frames : sequence
        ``HxWx3`` uint8/uint16 arrays, or paths (decoded one at a time).
    sources : sequence of str, optional
        Names for error messages (file names); defaults to ``"array #k"``.
    block : int, optional
        Block edge in pixels; by default :func:`working_block_size` (about
        :data:`TARGET_BLOCKS` blocks per frame), for JPEG files rounded up to a multiple of
        the DCT scaling they are decoded at (a 24 MP frame: 7 -> 8, read at half size).
    progress : callable, optional
        Called as ``progress(k, n, source)`` after each frame is read.
    keep : KeptData, optional
        What else to keep of the frames read (default nothing).
    near_clip_blocks : int
        A block within this many blocks of a clipped one counts as clipped
        (:func:`reduce_frame`); 0, the default, turns it off.

    Raises
    ------
    InputError
        Frames of different sizes or bit depths, unreadable files (named).
    """
    from ..io.images import JPEG_SUFFIXES, read_image, read_image_size

    n = len(frames)
    if sources is None:
        sources = [str(f) if isinstance(f, (str, os.PathLike)) else f"array #{k}"
                   for k, f in enumerate(frames)]
    keep = KeptData() if keep is None else keep
    reduced: list[ReducedFrame] = []
    codes: list[np.ndarray] = []
    for k, frame in enumerate(frames):
        src = sources[k]
        if isinstance(frame, (str, os.PathLike)):
            full_shape = read_image_size(frame)
            # JPEGs decode straight to local means (DCT scaling) when blocks are large:
            # only block means are kept, and the full decode is the cost that dominates
            scalable = Path(frame).suffix.lower() in JPEG_SUFFIXES
            if block is None:
                block = working_block_size(full_shape)
                if scalable:     # a whole number of reduced pixels per block (rounded up)
                    f = max(f for f in (1, 2, 4, 8) if f == 1 or f * 3 <= block)
                    block = f * -(-block // f)
            factor = _dct_factor(block) if scalable else 1
            image = read_image(frame) if factor == 1 else read_image(
                frame, reduce=factor)
        else:
            image = frame
            full_shape = None
            factor = 1
        arr = _as_image_array(image, src)
        digest = content_digest(arr)      # every decoded pixel, before the crop below
        if keep.codes_side:
            stride = max(1, -(-max(arr.shape[:2]) // keep.codes_side))
            codes.append(np.ascontiguousarray(arr[::stride, ::stride]))
        if full_shape is None:
            full_shape = arr.shape[:2]
        if block is None:       # an array frame first: the path frames set it above
            block = working_block_size(full_shape)
        if reduced and tuple(full_shape) != reduced[0].shape:
            raise InputError(
                f"frame size {full_shape[1]}x{full_shape[0]} differs from the first frame's "
                f"{reduced[0].shape[1]}x{reduced[0].shape[0]} ({reduced[0].source})", src)
        # reduced decodes may round their size up; crop to the common block grid
        hb, wb = full_shape[0] // block, full_shape[1] // block
        step = block // factor
        arr = arr[: hb * step, : wb * step]
        r = reduce_frame(arr, block=step, source=src, digest=digest,
                         near_clip_blocks=near_clip_blocks)
        r.shape = tuple(full_shape)
        if reduced and r.max_code != reduced[0].max_code:
            raise InputError("bit depth differs from the first frame's "
                             f"({reduced[0].source})", src)
        reduced.append(r)
        del image, arr
        if progress is not None:
            progress(k + 1, n, src)
    per_bin = PER_BIN if per_bin is None else per_bin
    idx, flatness = choose_locations(reduced, per_bin=per_bin,
                                     max_samples=max_samples, clip_margin=clip_margin,
                                     seed=seed)
    max_code = reduced[0].max_code
    thumbnail = reduced[0].thumbnail
    assert block is not None and thumbnail is not None      # reduce_frame makes one
    values = np.stack([r.blocks.reshape(-1, 3)[idx] for r in reduced]) / max_code
    bmax = np.stack([r.block_max.ravel()[idx] for r in reduced]) / max_code
    bmin = np.stack([r.block_min.ravel()[idx] for r in reduced]) / max_code
    wb = reduced[0].blocks.shape[1]
    locations = np.stack([idx // wb, idx % wb], axis=1)
    distance = np.stack([_clip_distance(r, clip_margin).ravel()[idx] for r in reduced])
    return SampleSet(values=values.astype(np.float64), block_max=bmax, block_min=bmin,
                     flatness=flatness, locations=locations, max_code=max_code,
                     sources=list(sources), block=block, frame_shape=reduced[0].shape,
                     digests=[r.digest for r in reduced],
                     thumbnails=[r.thumbnail for r in reduced],
                     thumbnail_pixel=float(reduced[0].shape[1] / thumbnail.shape[1]),
                     reduced=reduced if keep.reduced else None,
                     clip_distance=distance, codes=codes if keep.codes_side else None)


def _clip_distance(r: ReducedFrame, clip_margin: float) -> np.ndarray:
    """Blocks (Euclidean, 3x3 approximation) from each block to the nearest one touching 0
    or the top code; 255 where none is (ours: where JPEG damage next to clipping can reach,
    :mod:`selfcal.response.white_end`)."""
    cv2 = import_cv2()
    m = clip_margin * r.max_code / 255
    clipped = (r.block_max >= r.max_code - m) | (r.block_min <= m)
    if not clipped.any():
        return np.full(clipped.shape, 255, np.float32)
    d = cv2.distanceTransform((~clipped).astype(np.uint8), cv2.DIST_L2, 3)
    return np.minimum(d, 255).astype(np.float32)


def frame_masks(samples: SampleSet, *, clip_margin: float = DEFAULT_CLIP_MARGIN,
                saturation_threshold: float = 0.5, propagate: bool = True) -> dict:
    """Per-frame outlier masks of Lin et al. (ICCV 2011, §5), with their reasons.

    A sample is *clipped* in a frame when any channel of its block touches 0 or the
    maximum code (within ``clip_margin`` codes, on the 8-bit scale), and *saturated* when
    the HSV saturation of its block mean exceeds ``saturation_threshold`` (β).

    With ``propagate``, clipping also follows exposure: a scene point clipped white in a
    frame is clipped in every brighter frame, and one clipped black in every darker frame
    (frames ordered by their mean code, which rises with exposure).  JPEG ringing and
    quantisation leave saturated highlights at codes a few below the maximum in some
    frames; those would otherwise pass as valid and pair with codes they have no relation
    to.

    Returns
    -------
    dict of str -> ndarray of bool, shape (F, n)
        ``"clipped"`` and ``"saturated"`` masks (True = rejected for that reason).
    """
    margin = clip_margin / 255.0
    white = samples.block_max >= 1.0 - margin
    black = samples.block_min <= margin
    if propagate and samples.values.shape[0] > 1:
        order = np.argsort(samples.values.mean(axis=(1, 2)), kind="stable")
        white[order] = np.logical_or.accumulate(white[order], axis=0)
        black[order[::-1]] = np.logical_or.accumulate(black[order[::-1]], axis=0)
    clipped = white | black
    saturated = hsv_saturation(samples.values) > saturation_threshold
    return {"clipped": clipped, "saturated": saturated & ~clipped}
