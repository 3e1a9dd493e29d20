"""RAW+JPEG pairs: registered, then sampled as block-mean correspondences.

The RAW calibration path ([Gong2018] §3, and the colour mapping of [Lin2011] §6) fits
``P = f(Γ(M ρ))`` to corresponding raw and rendered colours.  Each pair is first
registered (:func:`selfcal.pipeline.registration.register_raw_jpeg`: an isotropic scale and a
shift, since cameras' JPEGs are often a little cropped or scaled against what LibRaw
decodes), then sampled with block means that skip clipped blocks and high-gradient
blocks, where demosaicing, sharpening and JPEG compression make the two images differ
(:func:`pair_samples`; the same outlier reasoning as [Lin2011] §5: clipped pixels carry
no information about the curve).  Each pair also keeps small thumbnails of its raw
(:func:`selfcal.exposure.raw_ratios.split_thumbnails`), from which a bracketed
session's exposure ratios are measured (:func:`selfcal.exposure.raw_ratios.raw_exposure_ratios`).

Coordinates are those of :mod:`selfcal.pipeline.registration`: pixel centres, ``x`` to the right,
``y`` down, ``raw_xy = scale * rendered_xy + shift``.  Citation keys are those of
``docs/references.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import JPEG_SUFFIXES, import_cv2, is_path, read_image, read_image_size
from ..io.raw import read_raw_linear
from ..exposure.raw_ratios import check_linear_raw, split_thumbnails
from .registration import (Registration, as_float_rendered, inside_mask, warp_image,
                           register_raw_jpeg)

__all__ = ["PairSamples", "PairData", "BlockRejection", "pair_samples", "sample_raw_jpeg_pair",
           "collect_pair_samples", "REJECTION_REASONS"]

#: Rejection reasons of :func:`pair_samples`, in the order they are tested.
REJECTION_REASONS = ("outside", "clipped_raw", "clipped_rendered", "high_gradient")

#: Raws whose long side is shorter than this are read at full size even when half size is
#: asked for (there are few enough pixels already).
HALF_SIZE_MIN_SIDE = 2000


# --------------------------------------------------------------------------------------
# samples
# --------------------------------------------------------------------------------------

@dataclass
class PairSamples:
    """Corresponding block means of a raw and its rendering.

    Attributes
    ----------
    raw : numpy.ndarray
        ``(n, 3)`` float64 linear camera RGB in ``[0, 1]``.
    rendered : numpy.ndarray
        ``(n, 3)`` float64 rendered RGB in ``[0, 1]``.
    counts : dict
        Blocks by outcome: ``total``, one entry per :data:`REJECTION_REASONS` (first
        failing test wins), ``valid`` (passed every test) and ``used`` (after ``n_max``).
    block : int
        Block side in rendered pixels.
    positions : numpy.ndarray
        ``(n, 2)`` block centres (x, y) in rendered pixels.
    gradient_threshold : float
        The high-gradient threshold applied (after adaptation).
    groups : numpy.ndarray
        ``(n,)`` int: the pair each sample comes from (its index among the pairs joined by
        :meth:`concatenate`; 0 for one pair).  :func:`selfcal.pipeline.fit_pipeline`
        takes it as ``groups`` to choose its regulariser weights by leave-one-scene-out.
    """

    raw: np.ndarray
    rendered: np.ndarray
    counts: dict
    block: int
    positions: np.ndarray
    gradient_threshold: float = float("nan")
    groups: np.ndarray | None = None

    def __post_init__(self):
        if self.groups is None:
            self.groups = np.zeros(len(self.raw), dtype=np.intp)
        else:
            self.groups = np.asarray(self.groups, dtype=np.intp).reshape(-1)

    def __len__(self) -> int:
        return int(self.raw.shape[0])

    @staticmethod
    def concatenate(parts) -> "PairSamples":
        """Join several pairs' samples (counts are summed; block is the first part's;
        ``groups`` numbers the parts 0, 1, ...)."""
        parts = list(parts)
        if not parts:
            return PairSamples(np.zeros((0, 3)), np.zeros((0, 3)), {}, 0, np.zeros((0, 2)))
        counts: dict = {}
        for p in parts:
            for k, v in p.counts.items():
                counts[k] = counts.get(k, 0) + int(v)
        return PairSamples(np.concatenate([p.raw for p in parts]),
                           np.concatenate([p.rendered for p in parts]), counts,
                           parts[0].block, np.concatenate([p.positions for p in parts]),
                           parts[0].gradient_threshold,
                           np.concatenate([np.full(len(p), k, dtype=np.intp)
                                           for k, p in enumerate(parts)]))


def _auto_block(shape, target_blocks=40_000) -> int:
    h, w = shape[:2]
    return int(np.clip(round(math.sqrt(h * w / target_blocks)), 4, 64))


def _raw_on_rendered_grid(raw, reg: Registration, shape):
    """Resample ``raw`` (HxWxC float) onto the rendered pixel grid (area-averaged first when
    the raw is finer), plus the mask of rendered pixels that lie inside the raw."""
    cv2 = import_cv2()
    hr, wr = raw.shape[:2]
    s = reg.scale
    src = raw.astype(np.float32)
    fx = fy = 1.0
    if s > 1.25:
        nw, nh = max(1, int(round(wr / s))), max(1, int(round(hr / s)))
        src = cv2.resize(src, (nw, nh), interpolation=cv2.INTER_AREA)
        fx, fy = wr / nw, hr / nh
    # rendered x -> raw x = s x + t -> resized raw x' = (s x + t + .5) / f - .5
    m = np.array([[s / fx, 0.0, (reg.shift[0] + 0.5) / fx - 0.5],
                  [0.0, s / fy, (reg.shift[1] + 0.5) / fy - 0.5]])
    out = warp_image(src, m, shape)
    if out.ndim == 2 and src.ndim == 3:
        out = out[:, :, None]
    inside = inside_mask(m, src.shape[:2], shape)
    return out, inside


@dataclass(frozen=True)
class BlockRejection:
    """Which blocks :func:`pair_samples` rejects (see there for the tests, in order).

    Attributes
    ----------
    raw_clip : float
        A raw channel at or above this is clipped.
    rendered_low, rendered_high : float
        A rendered channel at or below ``rendered_low``, or at or above
        ``rendered_high``, is clipped.
    gradient_threshold : float
        Blocks whose mean gradient magnitude exceeds ``max(gradient_threshold, q)`` are
        rejected, ``q`` the ``min_keep_fraction`` quantile of the remaining blocks ...
    min_keep_fraction : float
        ... so a textured scene keeps its flattest blocks.
    keep_clipped : bool
        Keep blocks clipped *throughout*: every pixel clipped in the raw, or a rendered
        channel at code 0 (or 255) in every pixel.  Their means are exact (a camera
        renders the clipped raw it recorded, and its rendering is bounded by 0 and 255),
        and they are the only samples of the colours a camera renders out of gamut
        (saturated colours with a channel at 0); :func:`selfcal.pipeline.fit_pipeline`
        leaves rendered-clipped samples out of its backward fits and learns ``E[ρ | P]``
        from them.  Blocks clipped in part are rejected either way (their means mix the
        two sides of the clip).
    """

    raw_clip: float = 0.98
    rendered_low: float = 1 / 255
    rendered_high: float = 254 / 255
    gradient_threshold: float = 0.01
    min_keep_fraction: float = 0.25
    keep_clipped: bool = False


def pair_samples(raw_rgb, rendered, registration: Registration | None = None, *,
                 block: int | None = None, n_max: int | None = None, seed: int = 0,
                 rejection: BlockRejection | None = None) -> PairSamples:
    """Block-mean raw↔rendered correspondences of a registered pair, clipped and
    high-gradient blocks skipped.

    The data of the RAW path ([Gong2018] §3: raw–sRGB correspondences; [Lin2011] §6:
    sRGB–RAW control points).  The raw is resampled onto the rendered grid (area-averaged
    when finer); the rendered image is cut into ``block × block`` blocks; a block is
    rejected when (first failing test named):

    * ``outside`` -- part of it falls outside the raw;
    * ``clipped_raw`` -- a raw pixel contributing to it has a channel ``≥ raw_clip``
      (the fields named here are those of :class:`BlockRejection`);
    * ``clipped_rendered`` -- a rendered pixel has a channel ``≥ rendered_high`` or
      ``≤ rendered_low`` (clipped codes say nothing about the curve: [Lin2011] §5);
    * ``high_gradient`` -- the mean gradient magnitude of the rendered grey image
      (Gaussian σ = 1 px, per pixel, on the ``[0, 1]`` scale) exceeds the threshold:
      demosaicing, sharpening, JPEG and any misregistration differ there.  The threshold
      is ``max(gradient_threshold, q)`` with ``q`` the ``min_keep_fraction`` quantile of
      the remaining blocks, so a textured scene keeps its flattest blocks.

    Parameters
    ----------
    raw_rgb : numpy.ndarray
        ``HxWx3`` float linear camera RGB in ``[0, 1]``.
    rendered : numpy.ndarray
        ``HxWx3`` uint8 (or uint16, or float in ``[0, 1]``) rendered RGB.
    registration : Registration, optional
        From :func:`~selfcal.pipeline.registration.register_raw_jpeg`; None: the images must have
        the same size and are taken as aligned.
    block : int, optional
        Block side in rendered pixels; default adapts to the size (about 40,000 blocks,
        4 to 64 px).
    n_max : int, optional
        Keep at most this many valid blocks, drawn at random (seeded).
    seed : int
    rejection : BlockRejection, optional
        The rejection thresholds above, and whether blocks clipped throughout are kept
        (default ``BlockRejection()``).

    Returns
    -------
    PairSamples
    """
    rejection = BlockRejection() if rejection is None else rejection
    raw_clip, keep_clipped = rejection.raw_clip, rejection.keep_clipped
    rendered_low, rendered_high = rejection.rendered_low, rejection.rendered_high
    cv2 = import_cv2()
    raw = check_linear_raw(raw_rgb)
    ren_f = as_float_rendered(rendered)
    h, w = ren_f.shape[:2]
    if registration is None:
        if raw.shape[:2] != (h, w):
            raise InputError(
                f"raw {raw.shape[1]}x{raw.shape[0]} and rendered {w}x{h} differ in size: "
                "register them first (register_raw_jpeg)")
        registration = Registration.identity((h, w))
    b = int(block) if block else _auto_block((h, w))
    if b < 1:
        raise InputError(f"block must be a positive integer, got {block!r}")
    ny, nx = h // b, w // b
    counts = {"total": int(ny * nx)}
    for k in REJECTION_REASONS:
        counts[k] = 0
    if ny == 0 or nx == 0:
        counts.update(valid=0, used=0)
        return PairSamples(np.zeros((0, 3)), np.zeros((0, 3)), counts, b, np.zeros((0, 2)))

    clipped = (raw.max(axis=2) >= raw_clip).astype(np.float32)
    stacked = np.concatenate([raw.astype(np.float32), clipped[:, :, None]], axis=2)
    on_grid, inside = _raw_on_rendered_grid(stacked, registration, (h, w))
    raw_on = on_grid[..., :3]
    clip_on = on_grid[..., 3]

    grey = cv2.GaussianBlur(ren_f.mean(axis=2), (0, 0), 1.0)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
    grad = np.sqrt(gx * gx + gy * gy)

    def blocks(a):
        a = a[:ny * b, :nx * b]
        return a.reshape(ny, b, nx, b, *a.shape[2:])

    raw_mean = blocks(raw_on).mean(axis=(1, 3), dtype=np.float64).reshape(-1, 3)
    ren_blocks = blocks(ren_f)
    ren_mean = ren_blocks.mean(axis=(1, 3), dtype=np.float64).reshape(-1, 3)
    ren_max = ren_blocks.max(axis=(1, 3)).reshape(-1, 3)
    ren_min = ren_blocks.min(axis=(1, 3)).reshape(-1, 3)
    outside = ~blocks(inside).all(axis=(1, 3)).reshape(-1)
    clip_frac = blocks(clip_on).mean(axis=(1, 3), dtype=np.float64).reshape(-1)
    touched = (ren_max >= rendered_high - 1e-6) | (ren_min <= rendered_low + 1e-6)
    if keep_clipped:   # only blocks clipped in part of them are rejected
        clip_raw = (clip_frac > 1e-6) & (clip_frac < 1 - 1e-6)
        whole = (ren_min >= 254.5 / 255) | (ren_max <= 0.5 / 255)
        clip_ren = (touched & ~whole).any(axis=1)
    else:
        clip_raw = clip_frac > 1e-6
        clip_ren = touched.any(axis=1)
    g = blocks(grad).mean(axis=(1, 3), dtype=np.float64).reshape(-1)

    reason = np.zeros(ny * nx, dtype=np.int8)   # 0 = valid
    for code, mask in ((1, outside), (2, clip_raw), (3, clip_ren)):
        reason[(reason == 0) & mask] = code
    remaining = reason == 0
    thr = float(rejection.gradient_threshold)
    if remaining.any():
        thr = max(thr, float(np.quantile(g[remaining], rejection.min_keep_fraction)))
    reason[remaining & (g > thr)] = 4
    for code, name in enumerate(REJECTION_REASONS, start=1):
        counts[name] = int(np.sum(reason == code))
    valid = np.flatnonzero(reason == 0)
    counts["valid"] = int(valid.size)
    if n_max is not None and valid.size > int(n_max):
        rng = np.random.default_rng(np.random.SeedSequence(seed))
        valid = np.sort(rng.choice(valid, size=int(n_max), replace=False))
    counts["used"] = int(valid.size)
    by, bx = np.divmod(valid, nx)
    positions = np.stack([(bx + 0.5) * b - 0.5, (by + 0.5) * b - 0.5], axis=1).astype(float)
    return PairSamples(raw=np.clip(raw_mean[valid], 0.0, 1.0), rendered=ren_mean[valid],
                       counts=counts, block=b, positions=positions, gradient_threshold=thr)


# --------------------------------------------------------------------------------------
# a pair from files or arrays
# --------------------------------------------------------------------------------------

@dataclass
class PairData:
    """One RAW+rendered pair after registration and sampling.

    Attributes
    ----------
    raw_name, rendered_name : str
        File paths, or ``"array #k"``.
    registration : Registration
        In the pixel grids actually compared (see ``raw_shape`` / ``rendered_shape``).
    samples : PairSamples
    thumbnail : tuple of numpy.ndarray
        Small linear raw as ``(values, selection)`` of :func:`split_thumbnails`, for
        exposure ratios free of selection bias.
    raw_exposure : ExposureInfo or None
        EXIF of the raw file, where readable.
    camera_wb : tuple or None
    """

    raw_name: str
    rendered_name: str
    registration: Registration
    samples: PairSamples
    thumbnail: tuple
    raw_exposure: object = None
    camera_wb: tuple | None = None
    raw_shape: tuple = field(default=())


def _jpeg_reduce_for(path, raw_shape) -> int:
    """Largest libjpeg DCT reduction keeping the JPEG at least ~0.9× the raw's size."""
    if Path(path).suffix.lower() not in JPEG_SUFFIXES:
        return 1
    hj, wj = read_image_size(path)
    reduce = 1
    for r in (2, 4, 8):
        if wj / r >= 0.9 * raw_shape[1] and hj / r >= 0.9 * raw_shape[0]:
            reduce = r
    return reduce


def sample_raw_jpeg_pair(raw, rendered, *, raw_name=None, rendered_name=None,
                         half_size: bool = True, block: int | None = None,
                         n_max: int | None = None, seed: int = 0,
                         register: bool | None = None,
                         rejection: BlockRejection | None = None) -> PairData:
    """Read (when paths), register and sample one RAW+rendered pair.

    Paths are read with :func:`selfcal.io.raw.read_raw_linear` (``half_size``: 2×2 binned, no
    demosaicing, a quarter of the pixels -- for raws whose long side is at least
    :data:`HALF_SIZE_MIN_SIDE`) and :func:`selfcal.io.read_image` (a JPEG is
    decoded at a DCT-reduced size no smaller than ~0.9× the raw's), registered with
    :func:`~selfcal.pipeline.registration.register_raw_jpeg` (a mismatch raises InputError naming
    both files) and sampled with :func:`pair_samples` (``block``, ``n_max``, ``seed``,
    ``rejection`` as there).  Arrays are taken as aligned when their sizes agree (set
    ``register=True`` to register anyway).

    Returns
    -------
    PairData
    """
    raw_exposure = camera_wb = None
    if is_path(raw):
        raw_name = raw_name or str(raw)
        img = read_raw_linear(raw, half_size=half_size)
        if half_size and 2 * max(img.rgb.shape[:2]) < HALF_SIZE_MIN_SIDE:
            img = read_raw_linear(raw, half_size=False)   # small raw: keep every pixel
        raw_rgb, raw_exposure, camera_wb = img.rgb, img.exposure, img.camera_wb
        del img
    else:
        raw_rgb = check_linear_raw(raw)
        if not np.all(np.isfinite(raw_rgb)):
            raise InputError("the raw array contains NaN or infinite values", raw_name)
    if is_path(rendered):
        rendered_name = rendered_name or str(rendered)
        reduce = _jpeg_reduce_for(rendered, raw_rgb.shape)
        ren = read_image(rendered, reduce=reduce)
    else:
        ren = np.asarray(rendered)
    if register is None:
        register = is_path(raw) or is_path(rendered) or raw_rgb.shape[:2] != ren.shape[:2]
    if register:
        reg = register_raw_jpeg(raw_rgb, ren, raw_name=raw_name, rendered_name=rendered_name,
                                strict=True)
    else:
        if raw_rgb.shape[:2] != ren.shape[:2]:
            raise InputError("raw and rendered sizes differ; cannot take them as aligned",
                             rendered_name)
        reg = Registration.identity(ren.shape)
    samples = pair_samples(raw_rgb, ren, reg, block=block, n_max=n_max, seed=seed,
                           rejection=rejection)
    return PairData(raw_name=str(raw_name), rendered_name=str(rendered_name),
                    registration=reg, samples=samples,
                    thumbnail=split_thumbnails(raw_rgb), raw_exposure=raw_exposure,
                    camera_wb=camera_wb, raw_shape=tuple(raw_rgb.shape[:2]))


def collect_pair_samples(raws, rendered, *, seed: int = 0, max_samples: int | None = 20_000,
                         half_size: bool = True, block: int | None = None, progress=None,
                         names=None, rejection: BlockRejection | None = None):
    """Register and sample several RAW+rendered pairs and join their samples.

    Each pair goes through :func:`sample_raw_jpeg_pair`; ``max_samples`` is shared equally
    among the pairs (each pair's draw seeded from ``seed`` and its index).

    Parameters
    ----------
    raws, rendered : sequence
        Equal-length sequences of raw paths / ``HxWx3`` float linear arrays, and rendered
        paths / ``HxWx3`` uint8 arrays.
    seed : int
    max_samples : int or None
        Total number of samples kept (None: all valid blocks).
    half_size : bool
        Read raw files at half size.
    block : int, optional
        Block side (rendered pixels); default adaptive.
    progress : callable, optional
        ``progress("pairs", done, total, name)``.
    names : sequence of (str, str), optional
        Names of array inputs for messages (default ``"raw array #k"``, ...).
    rejection : BlockRejection, optional
        The blocks' rejection thresholds (:func:`pair_samples`).

    Returns
    -------
    samples : PairSamples
        All pairs' samples, concatenated.
    pairs : list of PairData
    """
    raws, rendered = list(raws), list(rendered)
    if len(raws) != len(rendered):
        raise InputError(f"{len(raws)} raws but {len(rendered)} rendered images: they go in "
                         "pairs")
    if not raws:
        raise InputError("no RAW+rendered pairs given")
    n = len(raws)
    per_pair = None if max_samples is None else max(1, int(math.ceil(max_samples / n)))
    seeds = np.random.SeedSequence(seed).generate_state(n)
    out = []
    for k, (r, j) in enumerate(zip(raws, rendered)):
        rname = str(r) if is_path(r) else (names[k][0] if names else f"raw array #{k}")
        jname = str(j) if is_path(j) else (names[k][1] if names else f"rendered array #{k}")
        if progress is not None:
            progress("pairs", k, n, f"{Path(rname).name} + {Path(jname).name}")
        out.append(sample_raw_jpeg_pair(r, j, raw_name=rname, rendered_name=jname,
                                        half_size=half_size, block=block, n_max=per_pair,
                                        seed=int(seeds[k]), rejection=rejection))
    if progress is not None:
        progress("pairs", n, n, "")
    return PairSamples.concatenate([p.samples for p in out]), out
