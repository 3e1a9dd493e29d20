"""The merge's weighted sums, accumulated frame by frame in strips of rows.

:class:`MergeSums` holds Σ_j w_j·f⁻¹(I_j)/e_j and Σ_j w_j per pixel and channel -- the
weighted mean of [Debevec1997]_ Eq. 6, on linear values -- and divides them at the end,
filling the pixels no frame measured (:meth:`MergeSums.divide_and_fill`);
:func:`accumulate_frames` adds every frame to them, shortest exposure first, with the
weights of :mod:`.weights` and the zero weights that are ours (clipping that follows
exposure, JPEG ringing, deghosting: :mod:`selfcal.hdr.merge` says which).  Used by
:func:`selfcal.hdr.merge.merge_hdr`.

References
----------
.. [Debevec1997] See ``docs/references.md``.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..io.images import import_cv2
from ..stack.align import negligible_motion, warp_to_reference
from ..stack.frames import Lineariser, StackFrames, apply_lut, frame_limits, max_code_of
from .deghost import ghost_mask, neighbour_residual, small_log_luma
from .vignetting import FrameFalloff
from ..lens.vignetting import Vignetting
from .weights import NoiseModel, FrameTables, packed_lookup

if TYPE_CHECKING:
    from .sigma import SigmaSums

__all__ = ["MergeSums", "FrameWeighing", "accumulate_frames", "WHITE_FOLLOWS"]

#: A pixel some shorter frame saw clipped white is clipped in a longer frame where any of
#: its channels is at least this fraction of the maximum code there (ours).
WHITE_FOLLOWS = 0.5

#: Coverage mask of a warped frame: value of clipped pixels; 255 is outside the frame, and
#: interpolated values above _OUTSIDE count as outside (for the fill of unmeasured pixels).
_CLIPPED = 100
_OUTSIDE = 177
#: Pixels in a strip of the merge: a quarter of :data:`selfcal.stack.frames.STRIP_PIXELS`,
#: so that each thread's strip buffers (24 bytes a pixel for the (weighted, weight)
#: pairs) stay in the last-level cache beside the other threads'.  Chosen on CPU seconds
#: of an uncommitted harness on a machine other jobs shared, a few per cent below 1 << 20
#: and within its noise: no committed figure separates the two.
_STRIP_PIXELS = 1 << 18
#: Up to this many unchecked frames keep their codes rather than a float32 weight sum.
_UNCHECKED_CODES = 2
#: The fill gathers a strip's unmeasured pixels when they are fewer than this fraction
#: of it (fancy indexing costs more per pixel than a pass over the strip).
_GATHER_BELOW = 0.2


@dataclass(frozen=True)
class FrameWeighing:
    """How :func:`accumulate_frames` weighs each frame's pixels.

    Attributes
    ----------
    weighting : {"noise", "hat"} or callable
        As :func:`selfcal.merge_hdr`'s ``weighting``.
    noise : NoiseModel
        The noise model of the ``"noise"`` weights and of deghosting.
    clip_margin : float
        Codes (8-bit scale) within this distance of 0 or the maximum count as clipped.
    linear : bool
        Linear frames (no response to apply).
    stuck : tuple or None
        Per channel (floor, ceiling) as normalised codes, or None.
    ringing_radius : int
        Pixels by which a frame's white-clipped region is widened (0: none).
    deghost : bool
        Test every frame against the reference, per pixel.
    deghost_threshold, deghost_tolerance : float
        ``k`` and the relative error floor of the deghosting test.
    code_error : bool
        Add the curve's measured error per code to the variance of the weights and of σ
        (``MergeOptions.code_error``).
    """

    weighting: object
    noise: NoiseModel
    clip_margin: float
    linear: bool
    stuck: tuple | None
    ringing_radius: int
    deghost: bool
    deghost_threshold: float = 3.0
    deghost_tolerance: float = 0.1
    code_error: bool = True



class MergeSums:
    """A merge in progress: its float32 sums over row strips, and what each frame left.

    ``num`` = Σ_j w_j·f⁻¹(I_j)/e_j and ``den`` = Σ_j w_j per channel (Eq. 6 of Debevec &
    Malik, on linear values), ``count`` the frames each pixel got, ``ghost`` the pixels
    deghosting took a frame from, ``white`` the pixels some frame merged so far saw
    clipped at white (widened for lossy frames: ours).  ``kept`` holds the codes (and
    coverage masks) of the reference, darkest and brightest frames, for deghosting and the
    fill; ``residuals`` the misalignment test of each pair of neighbours.
    """

    #: Unchecked frames whose codes are kept (the table path) when there are at most this
    #: many; beyond, a float32 sum.  Memory only: both give the same weights.
    unchecked_codes_limit: int = _UNCHECKED_CODES

    def __init__(self, shape, exposures, ref: int, used, unchecked=()):
        hh, ww = shape
        n = len(exposures)
        self.num = np.zeros((hh, ww, 3), dtype=np.float32)
        self.den: np.ndarray | None = np.zeros((hh, ww, 3), dtype=np.float32)
        self.count = np.zeros((hh, ww), dtype=np.uint8)
        self.ghost = np.zeros((hh, ww), dtype=bool)
        self.white = np.zeros((hh, ww), dtype=np.uint8)
        self.width = ww
        self.rows = max(8, _STRIP_PIXELS // max(ww, 1))
        self.strips = [slice(y, min(y + self.rows, hh)) for y in range(0, hh, self.rows)]
        self.ref = ref
        e = np.asarray(exposures, dtype=float)
        # shortest first: a pixel clipped in a shorter frame is clipped in every longer one
        self.order = sorted(used, key=lambda k: (e[k], k))
        self.darkest = self.order[0]
        self.brightest = self.order[-1]
        self.kept: dict[int, tuple] = {}          # frame -> (codes, coverage mask or None)
        self.tables: dict[int, FrameTables] = {}
        self.used = [0.0] * n                     # pixels each frame contributed to
        self.excluded = [0.0] * n                 # pixels deghosting took from each frame
        self.ghost_stats: dict[int, dict] = {}    # frame -> agreement with the reference
        self.residuals: list[dict] = []           # neighbour pairs: misalignment test
        self.cv2 = import_cv2()
        self._local = threading.local()
        #: the radiance's σ in the making (:class:`.sigma.SigmaSums`), or None
        self.sigma: SigmaSums | None = None
        #: frames merged with a time the pixels could not check; their Σ w per pixel and
        #: channel, either as a float32 sum or (table path, at most
        #: :data:`_UNCHECKED_CODES` such frames) as each one's masked codes and tables,
        #: a quarter of the memory, looked up at the end (:meth:`keep_unchecked`); and
        #: the pixels where they carry most of the weight (only when there are some)
        self.unchecked = set(unchecked)
        self.unchecked_den: np.ndarray | None = None
        self.unchecked_codes: list[tuple] = []   # (tables, codes) in merge order
        self.unchecked_mask: np.ndarray | None = None
        #: the lens's vignetting, divided out of each frame at its own pixels (frames
        #: that moved: :class:`.vignetting.FrameFalloff`); None when there is none or it
        #: is divided out of the finished radiance (:func:`.vignetting.apply_vignetting`)
        self.falloff: Vignetting | None = None

    def keep_unchecked(self, tab: FrameTables, shape, dtype, max_code) -> None:
        """Where an unchecked frame's weights will be kept (call before its strips)."""
        if tab.lut and len(self.unchecked) <= self.unchecked_codes_limit:
            # the maximum code (zero weight) where a strip leaves it
            tab.unchecked_codes = np.full(shape, max_code, dtype=dtype)
            self.unchecked_codes.append((tab, tab.unchecked_codes))
        elif self.unchecked_den is None:
            self.unchecked_den = np.zeros(self.num.shape, dtype=np.float32)

    def _unchecked_weight(self, s: slice):
        """Σ w of the unchecked frames on strip ``s`` (float32, in merge order)."""
        if self.unchecked_den is not None:
            return self.unchecked_den[s]
        total = np.zeros(self.num[s].shape, dtype=np.float32)
        for tab, codes in self.unchecked_codes:
            np.add(total, apply_lut(codes[s], tab.w_table), out=total)
        return total

    def add_strip(self, s: slice, img, cover, off, own_white, tab: FrameTables, max_code):
        """One strip of one frame into the sums (strips are disjoint: threads may share).

        A pixel counts when every channel is inside the frame's limits, it is not clipped
        white in the frame or (``self.white``) in any shorter frame, within the widening
        of ``own_white``, and deghosting kept it.  Returns the number of pixels the frame
        contributed and that deghosting excluded.
        """
        cv2 = self.cv2
        codes = img[s]
        valid = tab.valid(codes)
        if cover is not None:
            valid[cover[s] > 0] = 0
        # clipped white in a shorter frame, or near this frame's clipped pixels: only
        # where this frame is bright as well (ringing moves clipped codes a few below
        # white; a dark pixel by a highlight, a frame's padding or a moving object is no
        # highlight)
        blocked = cv2.bitwise_or(self.white[s], own_white[s])
        if cv2.countNonZero(blocked):
            # (saturating) blocked & ~dim, then valid & ~blocked
            cv2.subtract(blocked, cv2.inRange(codes, (0, 0, 0), (tab.bright,) * 3),
                         dst=blocked)
            cv2.subtract(valid, blocked, dst=valid)
        excluded = 0
        if off is not None:
            o = off[s] > 0
            o &= valid > 0
            if o.any():
                valid[o] = 0
                self.ghost[s] |= o
                excluded = int(o.sum())
        n_valid = cv2.countNonZero(valid)
        if n_valid == 0:
            return 0, excluded
        falloff = getattr(tab, "falloff", None)    # the lens's V(H_j x) (.vignetting)
        num, den = self.num, self.den
        assert den is not None      # until divide_and_fill
        if tab.lut:
            # invalid pixels -> the maximum code in every channel, where the tables
            # hold zero weight: then plain (unmasked) sums.  Strip buffers are reused
            # (fresh large allocations cost page faults).
            rows_s = s.stop - s.start
            bufs = _thread_buffers(self._local, self.rows, self.width, img.dtype)
            if n_valid < valid.size:
                buf = bufs["codes"][:rows_s]
                if max_code == 255:
                    # codes | 255 where invalid, one pass with a 3-channel mask
                    inv = cv2.bitwise_not(valid)
                    cv2.bitwise_or(codes, cv2.merge([inv] * 3, dst=bufs["mask"][:rows_s]),
                                   dst=buf)
                else:
                    np.copyto(buf, codes)
                    cv2.bitwise_or(buf, (max_code,) * 3 + (0,), dst=buf,
                                   mask=cv2.bitwise_not(valid))
                codes = buf
            # one lookup gives (weighted, weight) side by side (weights.packed_table)
            aw = packed_lookup(codes, tab.aw_table, bufs["aw"][:rows_s])
            aw = aw.view(np.float32).reshape(aw.shape + (2,))
            a, w = aw[..., 0], aw[..., 1]
            if falloff is not None:
                v = falloff.scale_sums(s, a, w)
            np.add(num[s], a, out=num[s])
            np.add(den[s], w, out=den[s])
        else:
            a, w, _, _ = tab.evaluate(codes, need_x=False)
            if falloff is not None:
                a, w = a.astype(np.float32), w.astype(np.float32)
                v = falloff.scale_sums(s, a, w)
            cv2.add(num[s], a, dst=num[s], mask=valid)
            cv2.add(den[s], w, dst=den[s], mask=valid)
        np.add(self.count[s], valid >> 7, out=self.count[s])
        if tab.unchecked:
            kept_codes = getattr(tab, "unchecked_codes", None)
            if kept_codes is not None:
                np.copyto(kept_codes[s], codes)    # as masked for the lookup
            else:
                assert self.unchecked_den is not None   # keep_unchecked made it
                kept = w if tab.lut else np.where(valid[..., None] > 0, w, 0)
                np.add(self.unchecked_den[s], kept, out=self.unchecked_den[s])
        if self.sigma is not None:
            # (a and w are done with: σ's lookup reuses their buffer)
            self.sigma.add(s, codes, tab, valid,
                           buffer=bufs["aw"][:rows_s] if tab.lut else None,
                           factors=None if falloff is None else falloff.sigma_factors(v))
        return n_valid, excluded

    def unchecked_pixels(self, unmeasured: np.ndarray) -> np.ndarray | None:
        """Measured pixels where, in some channel, frames merged unchecked carry more than
        half of the weight (None: no such frame was merged)."""
        if self.unchecked_mask is None:
            return None
        return self.unchecked_mask & ~unmeasured

    def frame_diagnostics(self, sources, *, deghost: bool) -> dict:
        """Per frame, the fraction of pixels used (and excluded by deghosting)."""
        npix = float(self.num.shape[0] * self.num.shape[1])
        out: dict[str, object] = {"frame_used_fraction": [u / npix for u in self.used]}
        if deghost:
            out["deghost_excluded_fraction"] = [e / npix for e in self.excluded]
            out["deghost_reference_agreement"] = {
                sources[k]: st for k, st in sorted(self.ghost_stats.items())}
        return out

    def divide_and_fill(self) -> np.ndarray:
        """``num`` becomes the radiance ``num / den``; unmeasured channels are filled.

        Returns the bool mask of the pixels no frame measured (:func:`_fill_strip`).
        ``den`` is released, or becomes the radiance's σ (:meth:`.sigma.SigmaSums.finish_strip`).
        """
        hh, ww = self.num.shape[:2]
        unmeasured = np.zeros((hh, ww), dtype=bool)
        if self.sigma is not None:
            self.sigma.calibrate_noise()

        unchecked_mask = np.zeros((hh, ww), dtype=bool) if self.unchecked else None
        self.unchecked_mask = unchecked_mask
        den = self.den
        assert den is not None      # released below

        def strip(s):
            ns, ds = self.num[s], den[s]
            hole = ds <= 0
            if unchecked_mask is not None:      # (there are unchecked frames)
                unchecked_mask[s] = _any_channel(self._unchecked_weight(s) > 0.5 * ds)
            # a plain division (0/0 at the holes, overwritten by the fill below): numpy's
            # masked division is several times slower
            with np.errstate(divide="ignore", invalid="ignore"):
                np.divide(ns, ds, out=ns)
            if self.sigma is not None:
                self.sigma.finish_strip(s, ds)      # σ over den, which is done with
            hole_px = _any_channel(hole)
            if hole_px.any():
                unmeasured[s] = hole_px
                # few holes (the usual case): only those pixels, gathered, filled and put
                # back; many: the whole strip
                at = np.nonzero(hole_px) if hole_px.mean() < _GATHER_BELOW else None
                fill = _fill_strip(s, at, self.kept, self.tables, self.darkest,
                                   self.brightest, self.ref)
                if at is None:
                    np.copyto(ns, fill, where=hole)
                else:
                    values = ns[at]
                    np.copyto(values, fill[:, 0], where=hole[at])
                    ns[at] = values

        # strips are disjoint, and numpy releases the GIL
        with ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1))) as pool:
            list(pool.map(strip, self.strips))
        if self.sigma is not None:
            self.sigma.sigma = self.den
        self.den = self.unchecked_den = None
        for tab, _ in self.unchecked_codes:
            tab.unchecked_codes = None
        self.unchecked_codes = []
        return unmeasured


def accumulate_frames(sums: MergeSums, frames: StackFrames, exposures, model, transforms,
                      weighing: FrameWeighing, progress=None):
    """Every frame into ``sums``, shortest exposure first (the reference first if deghosting).

    Per frame: its tables of weights and radiance (:class:`.weights.FrameTables`), with
    the clip limits raised to the black floor and lowered to the stuck ceiling of each
    channel (``weighing.stuck``); its warp onto the reference grid with a coverage mask
    (:data:`_CLIPPED` where it was clipped, 255 outside it); its own white-clipped pixels,
    widened by ``weighing.ringing_radius`` pixels (``cv2.dilate``; JPEG ringing) -- those and every pixel a
    shorter frame saw clipped white get zero weight (ours: clipping follows exposure, as
    in the calibration's ``selfcal.stack.samples.frame_masks``); its deghosting mask against the
    reference (:func:`.deghost.ghost_mask`); the misalignment test against the previous
    frame (:func:`.deghost.neighbour_residual`); then its strips -- in parallel threads on the
    table path (OpenCV and numpy release the GIL); a model's own ``to_raw`` is called from
    this thread only.
    """
    w = weighing
    linear, weighting, noise, clip_margin = w.linear, w.weighting, w.noise, w.clip_margin
    stuck, radius, deghost = w.stuck, w.ringing_radius, w.deghost
    cv2 = sums.cv2
    ref = sums.ref
    order = sums.order
    n = len(order)
    lin = None
    # a square: OpenCV dilates with it in two 1-D passes
    kernel = np.ones((2 * radius + 1,) * 2, np.uint8) if radius > 0 else None
    loaded = {}
    if deghost:
        loaded[ref] = frames.load(ref)       # deghosting compares every frame with it
        order = [ref] + [k for k in order if k != ref]
    prev = None
    pool = ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)))
    try:
        for done, (k, img) in enumerate(_read_ahead(frames, order, loaded)):
            if lin is None:
                mc = max_code_of(img)
                lin = Lineariser(model, linear, mc)
                lo, hi, floor = frame_limits(mc, clip_margin, linear, stuck)
            elif max_code_of(img) != lin.max_code:
                raise InputError(f"sample type {img.dtype} differs from the other frames",
                                 frames.sources[k])
            tab = FrameTables(lin, exposures[k], weighting, noise, lo, hi,
                               deghost or k == ref, float(np.max(exposures[sums.order])),
                               floor=floor, use_code_error=w.code_error)
            # codes below this in every channel are not near white (see add_strip)
            tab.bright = (WHITE_FOLLOWS * lin.max_code if lin.max_code is not None
                          else WHITE_FOLLOWS)
            tab.unchecked = k in sums.unchecked
            tab.falloff = FrameFalloff.for_frame(
                sums.falloff, None if transforms is None else transforms[k], frames.shape,
                noise_weights=weighting == "noise")
            if tab.unchecked:
                sums.keep_unchecked(tab, img.shape, img.dtype, lin.max_code)
            sums.tables[k] = tab
            if sums.sigma is not None:
                sums.sigma.prepare(tab)
            cover = None
            if (transforms is not None and k != ref
                    and not negligible_motion(transforms[k], frames.shape)):
                # clipped anywhere (before warping) -> _CLIPPED; outside the frame -> 255
                bad = np.where(tab.valid(img) > 0, 0, _CLIPPED).astype(np.uint8)
                img = warp_to_reference(img, transforms[k])
                cover = warp_to_reference(bad, transforms[k], border_value=255)
                del bad
            if (k in (sums.darkest, sums.brightest)
                    or (k == ref and (deghost or transforms is not None))):
                sums.kept[k] = (img, cover)
            if sums.sigma is not None:
                sums.sigma.keep_sample(img, cover, tab)
            own_white = tab.white(img)
            if kernel is not None and cv2.countNonZero(own_white):
                # (the default border of cv2.dilate is +inf: it would widen the edges)
                own_white = cv2.dilate(own_white, kernel, borderType=cv2.BORDER_CONSTANT,
                                       borderValue=0)
            off = None
            if deghost and k != ref:
                off, stats = ghost_mask(img, cover, sums.kept[ref][0], tab, sums.tables[ref],
                                         sums.strips, w.deghost_threshold, w.deghost_tolerance)
                sums.ghost_stats[k] = stats
            small = small_log_luma(img, cover, own_white, tab)
            if prev is not None and not (deghost and (k == ref or prev[0] == ref)):
                sums.residuals.append(neighbour_residual(prev, (k, small), frames.sources))
            prev = (k, small)

            def accumulate(s, img=img, cover=cover, off=off, own_white=own_white, tab=tab):
                return sums.add_strip(s, img, cover, off, own_white, tab, lin.max_code)

            for n_valid, excluded in (pool.map if tab.lut else map)(accumulate, sums.strips):
                sums.used[k] += float(n_valid)
                sums.excluded[k] += float(excluded)
            if not (deghost and k == ref):
                # clipped here -> clipped in every longer frame (the reference, merged
                # first when deghosting, passes its clipping on to nothing)
                cv2.bitwise_or(sums.white, own_white, dst=sums.white)
            else:
                ref_white = own_white
            del img, cover, own_white
            if progress is not None:
                progress("merge", done + 1, n, frames.sources[k])
    finally:
        pool.shutdown()
    if deghost:
        cv2.bitwise_or(sums.white, ref_white, dst=sums.white)


def _read_ahead(frames: StackFrames, order, loaded: dict):
    """``(k, codes)`` for each frame of ``order``, the next one decoded while the caller
    works on this one.

    Decoders release the GIL, so one reader thread overlaps decoding with the merge
    arithmetic (ours: from files, the merge otherwise waits on every decode in turn).
    At most two frames are held beyond ``loaded``: the one yielded and the next.
    """
    def load(k):
        return loaded.pop(k) if k in loaded else frames.load(k)

    with ThreadPoolExecutor(max_workers=1) as reader:
        ahead = reader.submit(load, order[0]) if order else None
        for i, k in enumerate(order):
            assert ahead is not None        # submitted for every frame of order
            img = ahead.result()
            ahead = reader.submit(load, order[i + 1]) if i + 1 < len(order) else None
            yield k, img
            img = None  # noqa: F841 -- the caller's frame is released before the next


def _thread_buffers(local, rows: int, width: int, dtype) -> dict:
    """Per-thread strip buffers (codes, their mask, (weighted value, weight) pairs)."""
    bufs = getattr(local, "bufs", None)
    if bufs is None or bufs["codes"].dtype != dtype:
        bufs = local.bufs = {"codes": np.empty((rows, width, 3), dtype=dtype),
                             "mask": np.empty((rows, width, 3), dtype=np.uint8),
                             "aw": np.empty((rows, width, 3), dtype=np.float64)}
    return bufs


# --------------------------------------------------------------------------------------
# the fill of unmeasured pixels
# --------------------------------------------------------------------------------------

def _any_channel(mask3: np.ndarray) -> np.ndarray:
    """``mask3.any(axis=2)`` for 3 channels, without numpy's slow strided reduction."""
    return mask3[..., 0] | mask3[..., 1] | mask3[..., 2]


def _fill_strip(s, at, kept, tables, darkest, brightest, ref):
    """Values for pixels no frame measured: darkest frame for highlights, else brightest.

    ``at``: None for the whole strip ``s`` (values shaped like it), or the (rows, columns)
    of some of its pixels (values n × 1 × 3).  A pixel is a highlight when some channel of
    the brightest frame is clipped at white there (the darkest frame's codes may be JPEG
    ringing below white).  Where the chosen frame was warped and does not reach the pixel,
    the reference frame's value is used.
    """
    def pick(a):
        # a strip, or n × 1 (× 3): an image for the tables' lookups
        return a[s] if at is None else a[s][at][:, None]

    dcover, bcover = kept[darkest][1], kept[brightest][1]
    high = tables[brightest].white(pick(kept[brightest][0])) > 0
    fill = np.where(high[..., None], tables[darkest].radiance(pick(kept[darkest][0])),
                    tables[brightest].radiance(pick(kept[brightest][0])))
    outside = np.zeros(high.shape, dtype=bool)
    if dcover is not None:
        outside |= high & (pick(dcover) > _OUTSIDE)
    if bcover is not None:
        outside |= ~high & (pick(bcover) > _OUTSIDE)
    if outside.any():
        fill[outside] = tables[ref].radiance(pick(kept[ref][0]))[outside]
    return fill
