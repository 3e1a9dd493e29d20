"""The methods selfcal is compared with, called as their authors ship them.

* OpenCV: ``CalibrateDebevec`` / ``CalibrateRobertson`` (:func:`opencv_inverse_response`);
* colour-hdri: ``camera_response_functions_Debevec1997`` and its ``ImageStack``
  (:func:`colour_hdri_stack`, :func:`colour_hdri_inverse_response`; the ``bench`` extra);
* Mitsunaga & Nayar 1999 (:func:`mitsunaga_nayar_inverse_response`), implemented here
  from the paper (below);
* ffmpeg's ``lut1d``/``lut3d`` filters, an implementation of the LUT formats independent
  of selfcal: the tests' helper ``tests/ffmpeg_lut.py``, re-exported here (the tests never
  import from ``bench``, so the helper lives beside them).

Mitsunaga & Nayar 1999 [Mitsunaga1999]
--------------------------------------

T. Mitsunaga and S. K. Nayar, *Radiometric Self Calibration*, CVPR 1999, §3-4 (the method
behind pfstools' ``pfshdrcalibrate --calibration mitsunaga``), implemented from the paper
for the benches only (not part of the library):

* the inverse response is a polynomial of the normalised measurement,
  ``I = f(M) = Σ_{n=0}^{N} c_n M^n`` (Eq. 2), normalised (the paper: ``f(1) = 1``; ours:
  at the brightest code used, see :func:`_solve_coefficients`);
* for consecutive exposures q, q+1 with ratio ``R_q = e_q / e_{q+1}`` every pixel p gives
  ``f(M_{p,q}) − R_q f(M_{p,q+1}) = 0``; the error ``ε = Σ_q Σ_p [...]²`` is linear in the
  coefficients (Eq. 4-5), solved by least squares with the normalisation substituted;
* the ratios are then re-estimated, ``R_q = mean_p f(M_{p,q}) / f(M_{p,q+1})`` (Eq. 6),
  starting from the given (nominal) times, and the two steps alternate until f changes
  by less than 1e-5 anywhere (at most 50 rounds); the product of the ratios is held at
  the given times' (ours: without it the alternation slides to f ≡ 1, all ratios 1);
* the order N is the one of smallest error, searched over 1 … :data:`MAX_ORDER` (§4).

Our choices where the paper leaves them open: a fixed random set of pixels
(:data:`PIXELS`, seeded, the same locations in every frame), per channel, a pixel used in a
pair when its codes lie in 3 … 251 in both frames (away from clipping and the black floor);
the error that picks N is measured on the other half of the pixels, relative to the mean
square of f (:func:`_error`).  The result is f⁻¹ on codes 0 … 255, clipped below at 0; it
is not forced to be monotone (the bench counts the non-monotone channels).
"""

from __future__ import annotations

import numpy as np

from tests.ffmpeg_lut import (apply_cube_ffmpeg, apply_filters_ffmpeg,  # noqa: F401
                              apply_shaper_ffmpeg, ffmpeg_binaries)


def opencv_inverse_response(images_rgb, times, method: str) -> np.ndarray:
    """OpenCV's CalibrateDebevec / CalibrateRobertson response as f⁻¹, (256, 3) RGB."""
    import cv2

    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images_rgb]
    t = np.asarray(times, dtype=np.float32)
    if method == "debevec":
        cal = cv2.createCalibrateDebevec()
    elif method == "robertson":
        cal = cv2.createCalibrateRobertson()
    else:
        raise ValueError(method)
    resp = cal.process(bgr, t).reshape(256, 3)[:, ::-1]
    return resp.astype(np.float64)


def colour_hdri_stack(images, times, meta=None):
    """A colour-hdri ``ImageStack`` of 8-bit RGB frames, shortest exposure first.

    ``meta``: per frame ``(f-number, ISO)``; default f/8, ISO 100 for every frame (only the
    times then set the exposures, as for our simulated stacks).
    """
    from colour_hdri import ImageStack
    from colour_hdri.utilities import Image, Metadata

    stack = ImageStack()
    for k in np.argsort(np.asarray(times, float), kind="stable"):
        n, iso = meta[k] if meta is not None else (8.0, 100.0)
        im = Image()
        im.data = np.asarray(images[k]).astype(np.float64) / 255.0
        im.metadata = Metadata(f_number=n, exposure_time=float(times[k]), iso=iso)
        stack.append(im)
    return stack


def colour_hdri_inverse_response(images, times, meta=None) -> np.ndarray:
    """colour-hdri's Debevec 1997 curves (its defaults: Grossberg sampling, hat weights)
    as f⁻¹, (256, 3), max 1."""
    from colour_hdri import camera_response_functions_Debevec1997

    return np.asarray(camera_response_functions_Debevec1997(
        colour_hdri_stack(images, times, meta)), dtype=np.float64)


def colour_hdri_merge(images, times, meta=None, crfs=None):
    """colour-hdri's merge (``image_stack_to_HDRI``) with its Debevec 1997 curves from the
    same frames unless ``crfs`` is given; BLAS limited to one thread."""
    from colour_hdri import camera_response_functions_Debevec1997, image_stack_to_HDRI
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        if crfs is None:
            crfs = camera_response_functions_Debevec1997(colour_hdri_stack(images, times, meta))
        # image_stack_to_HDRI sets each frame's data to None as it goes: a fresh stack
        return image_stack_to_HDRI(colour_hdri_stack(images, times, meta),
                                   camera_response_functions=crfs)


def opencv_merge(images, times, calibrate_from=None):
    """OpenCV's ``MergeDebevec`` of ``images`` with ``CalibrateDebevec``'s response from
    ``calibrate_from`` (default the same frames and times), RGB."""
    import cv2

    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images]
    t = np.asarray(times, np.float32)
    if calibrate_from is None:
        response = cv2.createCalibrateDebevec().process(bgr, t)
    else:
        src, src_t = calibrate_from
        response = cv2.createCalibrateDebevec().process(
            [np.ascontiguousarray(im[:, :, ::-1]) for im in src], np.asarray(src_t, np.float32))
    return cv2.createMergeDebevec().process(bgr, t, response)[:, :, ::-1]


# --------------------------------------------------------------------------------------
# Mitsunaga & Nayar 1999
# --------------------------------------------------------------------------------------

#: Pixels sampled from the stack (the same locations in every frame).
PIXELS = 5000
#: Highest polynomial order tried.
MAX_ORDER = 6
#: Rounds of the alternation at most.
ROUNDS = 50
#: Codes (8-bit) a pixel must lie within, in both frames of a pair, to be used.
LOW, HIGH = 3, 251


def _pair_data(codes, order):
    """Per consecutive pair (q, q+1) in exposure order: (M_q, M_q+1) of usable pixels."""
    pairs = []
    for q in range(len(order) - 1):
        a, b = codes[order[q]], codes[order[q + 1]]
        ok = (a >= LOW) & (a <= HIGH) & (b >= LOW) & (b <= HIGH)
        pairs.append((a[ok] / 255.0, b[ok] / 255.0))
    return pairs


def _solve_coefficients(pairs, ratios, n):
    """Least squares of Eq. 4-5 with ``f(m) = 1`` at ``m = HIGH / 255`` substituted for
    ``c_N``: the N+1 coefficients.

    The paper normalises at M = 1; with no pixel there (clipping), a high order then
    shrinks f over the whole observed range, which shrinks the absolute error with it
    (ours: normalised at the brightest code used, f⁻¹(255) = 1 set afterwards).
    """
    m = HIGH / 255.0
    mp = m ** np.arange(n + 1)
    rows, rhs = [], []
    for (ma, mb), r in zip(pairs, ratios):
        if ma.size == 0:
            continue
        d = ma[:, None] ** np.arange(n + 1) - r * mb[:, None] ** np.arange(n + 1)  # (P, N+1)
        rows.append(d[:, :n] - d[:, n:n + 1] * (mp[:n] / mp[n]))
        rhs.append(-d[:, n] / mp[n])
    A, y = np.concatenate(rows), np.concatenate(rhs)
    c = np.linalg.lstsq(A.T @ A, A.T @ y, rcond=None)[0]     # normal equations: N small
    return np.append(c, (1.0 - c @ mp[:n]) / mp[n])


def _poly(c, m):
    return np.polynomial.polynomial.polyval(m, c)


def _update_ratios(pairs, c, ratios, span):
    """Eq. 6: the mean over pixels of f(M_q) / f(M_{q+1}) (kept where undefined), then
    raised to the power that keeps the product of the ratios at the given times' ``span``.

    The power is ours: f and the ratios are otherwise free along the exponential
    ambiguity, and the alternation slides to f ≡ 1 with every ratio 1 (a zero error);
    the given times fix the total exposure span, as two known times fix γ for selfcal.
    """
    out = list(ratios)
    for k, (ma, mb) in enumerate(pairs):
        fa, fb = _poly(c, ma), _poly(c, mb)
        ok = (fb > 1e-6) & (fa > 0)
        if ok.sum() >= 10:
            out[k] = float(np.mean(fa[ok] / fb[ok]))
    logs = np.log(np.clip(out, 1e-6, 1 - 1e-6))
    return list(np.exp(logs * (span / logs.sum())))


def _fit(pairs, ratios, n, rounds=None, tol=1e-5):
    """Alternate coefficients and ratios (§4) from the given ratios."""
    grid = np.linspace(0, 1, 256)
    span = float(np.sum(np.log(ratios)))
    c = _solve_coefficients(pairs, ratios, n)
    for _ in range(ROUNDS if rounds is None else rounds):
        ratios = _update_ratios(pairs, c, ratios, span)
        new = _solve_coefficients(pairs, ratios, n)
        done = np.max(np.abs(_poly(new, grid) - _poly(c, grid))) < tol
        c = new
        if done:
            break
    return c, ratios


def _error(pairs, ratios, c):
    """Mean squared residual of ``f(M_q) − R_q f(M_{q+1})`` over the mean square of f there.

    Relative (ours): the absolute error falls as a higher order shrinks f over the data
    and lets it rise only past the last codes observed, so it would always pick the
    highest order.
    """
    res, size = [], []
    for (ma, mb), r in zip(pairs, ratios):
        if ma.size:
            fa, fb = _poly(c, ma), r * _poly(c, mb)
            res.append(fa - fb)
            size.append(0.5 * (fa * fa + fb * fb))
    if not res:
        return np.inf
    return float(np.mean(np.concatenate(res) ** 2) / max(np.mean(np.concatenate(size)), 1e-12))


def mitsunaga_nayar_inverse_response(images, times, *, seed: int = 0) -> np.ndarray:
    """[Mitsunaga1999] per channel: f⁻¹ at codes 0 … 255, shape (256, 3), f⁻¹(255) = 1.

    Parameters
    ----------
    images : sequence of (H, W, 3) uint8
    times : sequence of float
        Exposure times (their ratios start the re-estimation).
    """
    times = np.asarray(times, dtype=float)
    order = np.argsort(times, kind="stable")
    h, w = np.asarray(images[0]).shape[:2]
    rng = np.random.default_rng(seed)
    idx = rng.choice(h * w, size=min(PIXELS, h * w), replace=False)
    half = np.zeros(idx.size, bool)
    half[rng.permutation(idx.size)[: idx.size // 2]] = True
    ratios0 = [times[order[q]] / times[order[q + 1]] for q in range(len(order) - 1)]
    codes_all = [np.asarray(im).reshape(-1, 3)[idx].astype(float) for im in images]
    grid = np.arange(256) / 255.0
    out = np.empty((256, 3))
    for ch in range(3):
        codes = [c[:, ch] for c in codes_all]
        fit_pairs = _pair_data([c[half] for c in codes], order)
        test_pairs = _pair_data([c[~half] for c in codes], order)
        best = None
        for n in range(1, MAX_ORDER + 1):
            c, ratios = _fit(fit_pairs, ratios0, n)
            err = _error(test_pairs, ratios, c)
            if best is None or err < best[0]:
                best = (err, n)
        c, _ = _fit(_pair_data(codes, order), ratios0, best[1])
        f = _poly(c, grid)
        out[:, ch] = np.maximum(f / (f[-1] if f[-1] > 0 else 1.0), 0.0)
    return out
