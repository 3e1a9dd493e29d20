"""The standard deviation of every merged radiance value (selfcal's own).

The merge's radiance is the weighted mean of [Debevec1997]_ Eq. 6 on linear values,
``E = Σ_j w_j X_j / Σ_j w_j`` with ``X_j = f⁻¹(I_j) / e_j``.  To first order its error has
three parts, which :class:`SigmaSums` accumulates beside the merge's own sums:

* the noise of each frame's measurement, independent between frames: the variance
  ``V_j`` of :func:`.weights.noise_variance` under the merge's noise model -- shot and
  read noise [Granados2010]_, and the code noise (quantisation, JPEG) through the slope of
  f⁻¹ -- *without* its relative term (which stands in the weights for the model and
  exposure errors counted below), and *with* the curve's measured error at the frame's
  code beyond that noise (:mod:`selfcal.response.code_error`, as the weights take it):
  frames of one pixel sit at different codes, so it is independent between them;
* each frame's exposure error, independent between frames: a log exposure off by δ_j
  (std σ_t: the measurement's posterior spread when the exposures were measured,
  :mod:`selfcal.exposure.measured`, else :data:`selfcal.response.bands.EXPOSURE_LOG_SIGMA`)
  moves ``X_j`` by ``X_j δ_j``;
* the error of the curve, the same curve for every frame: where log f⁻¹ is off by ε(I)
  (std σ_g of the model's confidence band, :mod:`selfcal.response.bands`), ``X_j`` moves
  by ``X_j ε(I_j)``; taken as fully correlated between the frames, so it adds linearly.
  The band's floor over the codes (a shift of the whole curve, where white sits) moves
  every value by one factor -- the radiance's scale, not its values relative to each
  other -- so it is taken out in quadrature and said apart (:attr:`SigmaSums.scale_log_sigma`,
  the merge's ``diagnostics["sigma_scale_log"]``; ours);
* with measured exposures, the trend the times set over the bracket, off by the slope the
  shutter's errors happen to have: :func:`add_trend_term`, after the sums.

Together::

    Var E = Σ_j w_j² (V_j + X_j² σ_t²) / (Σ_j w_j)²  +  (Σ_j w_j X_j σ_g(I_j) / Σ_j w_j)²

Each frame contributes through two tables on its codes (like the merge's own), packed
side by side in one table of float32 pairs, so that σ costs one lookup and one addition
per strip and frame (:func:`.weights.packed_table`, ours); the two sums are float32,
side by side (``H×W×3×2``, 24 bytes a pixel), and σ is written over the merge's own weight
sum Σ w once it has divided by it (:meth:`SigmaSums.finish_strip`), so the result costs no
further array.  Float16 sums relative to the merge's numerator would halve that memory but
must be renormalised with the numerator frame after frame, which costs more than the
merge's own lookups (docs/decisions.md, "σ's sums stay float32").

The noise model's constants are fixed, but cameras are not: one JPEG engine smooths its
noise away, another sharpens it.  So the independent part (noise and exposures) is scaled
by κ, measured on the stack itself (:meth:`SigmaSums.keep_sample`): on every 8th pixel of
every 8th row (at most 50,000 values a pair), for each pair of frames merged one after
the other (neighbours in exposure), ``z = (g X_a − X_b) / √(g² U_a + U_b)`` with
``g`` the pair's median ratio, where both frames measure the
pixel (``U = V`` here: the fitted ``g`` takes the pair's exposure error out of the
difference); κ = median |z| / 0.6745 (1 for a noise model that is right), clamped to [1/4, 4],
1 with fewer than :data:`MIN_NOISE_SAMPLES` values.  The merge's diagnostics hold it
(``sigma_noise_scale``).

Pixels no frame measured (the merge's fill) get σ = +inf: their values are bounds.  A model without a
band (a version 1 model file, a pipeline model, linear frames) contributes no curve term;
the merge's diagnostics say so.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..stack.frames import apply_lut
from .weights import noise_variance, packed_lookup, packed_table

__all__ = ["SigmaSums", "add_trend_term"]

#: Every SAMPLE_STRIDE-th pixel of every SAMPLE_STRIDE-th row measures κ.
SAMPLE_STRIDE = 8
#: Fewer (pixel, channel) values than this leave κ at 1.
MIN_NOISE_SAMPLES = 2000
#: At most this many |z| are kept per pair of frames.
_MAX_PER_PAIR = 50_000


def _exposure_log_sigma() -> float:
    from ..response.bands import EXPOSURE_LOG_SIGMA

    return EXPOSURE_LOG_SIGMA


class SigmaSums:
    """``Σ w² (V + X² σ_t²)`` and ``Σ w X σ_g`` per pixel and channel (``sums[..., 0]``
    and ``sums[..., 1]``; the second only with a band), and σ at the end.

    Parameters
    ----------
    shape : (H, W)
    model : object
        The merge's model; its ``inverse_log_sigma`` (if any) gives σ_g.
    exposure_log_sigma : float, optional
        σ_t; default :data:`selfcal.response.bands.EXPOSURE_LOG_SIGMA`.
    """

    def __init__(self, shape, model, exposure_log_sigma: float | None = None):
        hh, ww = shape
        self.model = model
        self.sigma_t = (_exposure_log_sigma() if exposure_log_sigma is None
                        else float(exposure_log_sigma))
        self.has_band = getattr(model, "inverse_log_sigma", None) is not None
        # [..., 0] = Σ w² (V + X² σ_t²), [..., 1] = Σ w X σ_g (only with a band): side by
        # side, so that one lookup and one addition per strip serve both
        self.terms = 2 if self.has_band else 1
        self.sums: np.ndarray | None = np.zeros((hh, ww, 3, self.terms), dtype=np.float32)
        self.sigma: np.ndarray | None = None    # σ, in the merge's weight sums once finished
        #: the last frame's sampled (X, U), NaN where unmeasured
        self.previous: tuple[np.ndarray, np.ndarray] | None = None
        self.z: list[np.ndarray] = []   # |z| of the pairs so far
        self.kappa = 1.0
        #: the band's floor (:meth:`_band_at`): σ of log of the radiance's scale
        self.scale_log_sigma = 0.0

    def _band_at(self, max_code: int) -> np.ndarray:
        """σ_g at every code (K, 3) relative to the band's floor, zero without a band.

        The band's floor over the codes below white (per channel, its smallest σ below
        95 % of white, where it falls to 0 at white by the curve's normalisation) is an
        error every code shares -- where white sits, a shift of the whole log curve -- and
        moves every radiance value by one factor: the radiance's scale, not its values
        relative to each other.  It is taken out in quadrature, and kept apart in
        :attr:`scale_log_sigma` (ours)."""
        if not self.has_band:
            return np.zeros((max_code + 1, 3))
        m = self.model
        x = np.arange(max_code + 1) / max_code
        band = np.stack([np.interp(x, m.intensity, m.inverse_log_sigma[:, c])
                         for c in range(3)], axis=-1)
        # below the last codes, where the band falls to 0 at white by definition
        body = band[1:max(2, int(0.95 * max_code))]
        floor = body.min(axis=0) if max_code > 2 else np.zeros(3)
        self.scale_log_sigma = float(floor.max())
        return np.sqrt(np.maximum(band ** 2 - floor ** 2, 0.0))

    def prepare(self, tab) -> None:
        """Give the frame's :class:`.weights.FrameTables` its two σ tables (table path)."""
        if not tab.lut:
            return
        lin = tab.lin
        x = lin.table
        noise = replace(tab.noise, relative=0.0)
        v = noise_variance(x, lin.slope, tab.e, noise, code_std=lin.code_std())
        w = tab.w_table.astype(np.float64)
        X = x / tab.e
        if tab.code_error is not None:
            v = v + (X * tab.code_error) ** 2
        u = v + (X * self.sigma_t) ** 2
        # κ's pairs fit their own exposure ratio (g), which takes the exposure error out
        # of their difference: their U leaves σ_t out too
        tab.su_table = v.astype(np.float32)
        both = [w * w * u, w * X * self._band_at(lin.max_code)][:self.terms]
        tab.sigma_table = packed_table(np.stack(both, axis=-1).astype(np.float32))

    def keep_sample(self, img, cover, tab) -> None:
        """Sample a frame (after its warp) and pair it with the previous one (see the
        module docstring: the noise scale κ)."""
        if not tab.lut:
            return
        st = SAMPLE_STRIDE
        codes = np.ascontiguousarray(img[::st, ::st])
        ok = tab.valid(codes) > 0
        if cover is not None:
            ok &= cover[::st, ::st] == 0
        X = apply_lut(codes, tab.x_table)
        U = apply_lut(codes, tab.su_table)
        X[~ok] = np.nan
        if self.previous is not None:
            self.z.append(_pair_z(self.previous, (X, U)))
        self.previous = (X, U)

    def calibrate_noise(self) -> float:
        """κ from the pairs seen (module docstring); sets and returns it."""
        z = np.concatenate(self.z) if self.z else np.zeros(0)
        self.previous, self.z = None, []
        if z.size >= MIN_NOISE_SAMPLES:
            self.kappa = float(np.clip(np.median(z) / 0.6745, 0.25, 4.0))
        return self.kappa

    def add(self, s: slice, codes, tab, valid=None, buffer=None, factors=None) -> None:
        """One strip of one frame: ``codes`` already masked as the merge masked them (table
        path: invalid pixels at the maximum code, where the weights are zero); on the
        functional path ``valid`` (uint8) says which pixels count.  ``buffer``: optional
        scratch space of 24 bytes per pixel for the lookup (default: a new array).
        ``factors``: per-pixel factors of the two terms, ``(rows, W, 3)`` each (the lens's
        falloff of a frame that moved, :class:`.vignetting.FrameFalloff`), or None."""
        assert self.sums is not None    # until result()
        sums = self.sums[s]
        if tab.lut:
            # one lookup gives both terms (float32 pairs packed in a float64 table), into
            # the merge's reused strip buffer (fresh large arrays cost page faults)
            out = self._buffer(codes.shape, tab.sigma_table.dtype, buffer)
            terms = packed_lookup(codes, tab.sigma_table, out)
            terms = terms.view(np.float32).reshape(sums.shape)
            if factors is not None:
                for t in range(self.terms):
                    np.multiply(terms[..., t], factors[t], out=terms[..., t])
            np.add(sums, terms, out=sums)
            return
        _, w, X, v = tab.evaluate(codes, need_x=True)
        # the functional path's variance carries the relative term: take it out
        v = np.maximum(v - (tab.noise.relative * np.maximum(X, 0)) ** 2, 0.0)
        keep = (valid > 0)[..., None]
        term = w * w * (v + (X * self.sigma_t) ** 2)
        if factors is not None:
            term = term * factors[0]
        sums[..., 0] += np.where(keep, term, 0.0)

    @staticmethod
    def _buffer(shape, dtype, buffer=None) -> np.ndarray:
        """A lookup buffer of ``shape`` and ``dtype``: in ``buffer`` (contiguous, large
        enough: the merge's own strip buffer), else a new one."""
        if buffer is None:
            return np.empty(shape, dtype=dtype)
        n = int(np.prod(shape))
        return buffer.reshape(-1).view(dtype)[:n].reshape(shape)

    def finish_strip(self, s: slice, den_strip) -> None:
        """σ of one strip from the sums and the merge's ``den`` (Σ w), written over
        ``den_strip`` (the merge has divided by it already; strips are disjoint: threads
        may share).  Once every strip is finished, the merge's ``den`` is σ."""
        assert self.sums is not None    # until result()
        sums = self.sums[s]
        unmeasured = ~(den_strip > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.float32(1.0) / den_strip
            scale = np.multiply(inv, inv)
            np.multiply(scale, np.float32(self.kappa ** 2), out=scale)
            v = np.multiply(sums[..., 0], scale, out=den_strip)
            if self.terms == 2:
                c = np.multiply(sums[..., 1], inv, out=inv)
                np.multiply(c, c, out=c)
                np.add(v, c, out=v)
            np.sqrt(v, out=v)
        np.copyto(v, np.inf, where=unmeasured)

    def result(self) -> np.ndarray:
        """σ (float32 ``HxWx3``, the radiance's units) after every strip is finished (the
        merge hands its ``den`` over: :attr:`sigma`); the sums are released."""
        self.sums = None
        assert self.sigma is not None   # handed over by the merge before
        return self.sigma


def add_trend_term(sigma: np.ndarray, radiance: np.ndarray, trend_log_sigma: float,
                   *, rows: int = 32) -> float:
    """Add, in place and in quadrature, the error the exposures' trend leaves (ours).

    Measured exposures keep the times' trend over the bracket (the pixels cannot see it:
    ``f⁻¹ → (f⁻¹)^γ``, ``e → e^γ`` fit them equally, [Lin2011] §4's exponential
    ambiguity), and the times' trend is off by the slope the shutter's errors happen to
    have, std ``β`` (``trend_log_sigma``, :func:`selfcal.exposure.measured._times_trend`).
    A slope error β bends the radiance about the scale's centre ``c``:
    ``log E → log E + β (log E − c)``; so ``σ² += (E β (log E − c))²``, with ``c`` the
    median log radiance of the measured values (every 8th pixel of every 8th row).
    Pixels with σ = +inf stay so.  Returns ``c``.
    """
    beta = float(trend_log_sigma)
    sample = radiance[::SAMPLE_STRIDE, ::SAMPLE_STRIDE]
    ok = np.isfinite(sigma[::SAMPLE_STRIDE, ::SAMPLE_STRIDE]) & (sample > 0)
    if beta <= 0 or not ok.any():
        return 0.0
    centre = float(np.median(np.log(sample[ok])))
    for r0 in range(0, radiance.shape[0], rows):
        e = radiance[r0:r0 + rows]
        out = sigma[r0:r0 + rows]
        # one temporary per strip, the rest in place: σ costs a pass over the map here
        bend = np.maximum(e, np.float32(1e-30), dtype=np.float32)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            np.log(bend, out=bend)
            bend -= np.float32(centre)
            bend *= e
            bend *= np.float32(beta)
            np.multiply(bend, bend, out=bend)
            np.multiply(out, out, out=out)
            out += bend
            np.sqrt(out, out=out)
    return centre


def _pair_z(a, b) -> np.ndarray:
    """|z| of two frames' sampled (X, U) where both measured (module docstring)."""
    Xa, Ua = a
    Xb, Ub = b
    both = np.flatnonzero(np.isfinite(Xa) & np.isfinite(Xb) & (Xa > 0) & (Xb > 0))
    if both.size < 10:
        return np.zeros(0)
    both = both[::max(1, both.size // _MAX_PER_PAIR)]
    xa, xb = Xa.ravel()[both], Xb.ravel()[both]
    g = np.float32(np.median(xb / xa))
    return np.abs(g * xa - xb) / np.sqrt(g * g * Ua.ravel()[both] + Ub.ravel()[both])

