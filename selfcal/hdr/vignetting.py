"""The lens's falloff divided out of a merge: which vignetting, and how it enters the sums.

A frame ``j`` records ``I_j(p) = f(e_j · V(p) · L(p))`` at its own pixel ``p``
([Goldman2010], Eq. 1), so its radiance estimate at a reference pixel ``x`` seen at
``p = H_j x`` is ``X_j / V(H_j x)``.  Under the merge's noise weights (the inverse variance
of that estimate) the weight becomes ``w_j · V(H_j x)²``.  Writing ``V(H_j x) = ρ_j V(x)``,
the weighted mean is ``Σ w_j ρ_j X_j / Σ w_j ρ_j²`` divided by ``V(x)``: each frame that
moved carries its ratio ``ρ_j`` into the sums (``a_j · ρ_j``, ``w_j · ρ_j²``; the hat and
callable weightings leave ``w_j`` alone: ``a_j / ρ_j``), σ's two sums scale by the same
powers (:class:`FrameFalloff`), and the finished radiance and σ are divided by ``V(x)``
(:func:`apply_vignetting`).  Where no frame moved every ``ρ_j`` is 1 and the division
alone is exact.  The vignetting's own uncertainty
(:meth:`selfcal.lens.Vignetting.log_sigma_map`) joins σ in quadrature, taken at the
reference pixel (ours).

Which vignetting (:func:`resolve_vignetting`): the ``MergeOptions.vignetting`` choice,
``"auto"`` by default -- the model's own (self-calibrated from frames that moved, or one
attached from a flat field or a lens profile), else the lens database's profile for the
frames' EXIF, else none -- and what was chosen and why goes to the merge's diagnostics.

References
----------
[Goldman2010] See ``docs/references.md``.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import import_cv2
from ..lens.database import lens_vignetting
from ..lens.vignetting import Vignetting

#: A frame whose falloff ratio to the reference's stays within this of 1 everywhere is
#: summed as it is (0.1 %, far under the vignetting's own uncertainty).
NEGLIGIBLE_RATIO = 1e-3

__all__ = ["VIGNETTING_CHOICES", "resolve_vignetting", "FrameFalloff", "apply_vignetting",
           "SmoothField"]

#: The string choices of ``MergeOptions.vignetting`` (a :class:`Vignetting` is also taken).
VIGNETTING_CHOICES = ("auto", "self", "lens", "none")


def check_vignetting_option(option) -> None:
    """InputError unless ``option`` is one of :data:`VIGNETTING_CHOICES`, a Vignetting, a
    flat-field frame's path or None."""
    if option is None or isinstance(option, (Vignetting, os.PathLike)):
        return
    if isinstance(option, str) and (option in VIGNETTING_CHOICES or Path(option).suffix):
        return
    raise InputError(f"vignetting must be one of {', '.join(VIGNETTING_CHOICES)}, a "
                     f"selfcal.lens.Vignetting or a flat-field frame's path, not {option!r}")


def resolve_vignetting(option, model, *, path, shape) -> tuple[Vignetting | None, dict]:
    """The vignetting a merge (or a linearisation) divides out, and a record of the choice.

    Parameters
    ----------
    option : {"auto", "self", "lens", "none"}, Vignetting, path or None
        ``"self"``: the model's (an error when it has none); ``"lens"``: the lens
        database's profile for ``path``'s EXIF (an error when none matches); ``"auto"``:
        the model's, else the lens database's, else none; a :class:`Vignetting`: that
        one; a path: a flat-field frame's (:func:`selfcal.lens.flat_field.flat_field_vignetting`,
        linearised by the model); None or ``"none"``: none.
    model : object
        The model (its ``vignetting``, ``diagnostics["vignetting"]``, ``linearize``), or
        None for linear frames.
    path : path or None
        A frame whose EXIF names the lens (None: the frames are arrays).
    shape : (H, W)
        The frames' size (the vignetting must have been made for their aspect).

    Returns
    -------
    (Vignetting or None, dict)
        The record: ``source`` (``"self"``, ``"lens"``, ``"flat"`` or None), ``chosen_by``
        (the option), ``description``, and ``reasons``: one sentence for each source
        passed over.
    """
    check_vignetting_option(option)
    chosen_by = (option if isinstance(option, str) and option in VIGNETTING_CHOICES
                 else "none" if option is None else
                 "given" if isinstance(option, Vignetting) else "flat")
    record: dict = {"chosen_by": chosen_by, "source": None, "description": "", "reasons": []}
    if chosen_by == "none":
        return None, record
    if chosen_by == "given":
        return _chosen(option, record, shape)
    if chosen_by == "flat":
        return _chosen(_flat_field(option, model), record, shape)
    own = getattr(model, "vignetting", None)
    if own is not None and option in ("auto", "self"):
        return _chosen(own, record, shape)
    if option in ("auto", "self"):
        record["reasons"].append(_why_no_self(model))
        if option == "self":
            raise InputError(f"no self-calibrated vignetting: {record['reasons'][-1]}")
    lens, why = _lens_profile(path)
    if lens is not None:
        return _chosen(lens, record, shape)
    record["reasons"].append(why)
    if option == "lens":
        raise InputError(f"no lens profile: {why}", None if path is None else str(path))
    return None, record


def _chosen(vignetting: Vignetting, record: dict, shape):
    vignetting.check_size(*shape)
    record.update(source=vignetting.source, description=vignetting.description)
    return vignetting, record


def _flat_field(path, model) -> Vignetting:
    from ..lens.flat_field import flat_field_vignetting

    linearize = getattr(model, "linearize", None)
    return flat_field_vignetting(path, linearize=linearize)


def _why_no_self(model) -> str:
    """The model's own account of why it holds no vignetting."""
    diag = getattr(model, "diagnostics", None) or {}
    said = diag.get("vignetting") if isinstance(diag, dict) else None
    if isinstance(said, dict) and said.get("reason"):
        return f"self-calibration: {said['reason']}"
    return ("self-calibration: the model was not calibrated on aligned frames that moved "
            "(align=\"homography\")")


def _lens_profile(path) -> tuple[Vignetting | None, str]:
    """The lens database's vignetting for ``path``'s EXIF, or None and why not."""
    if path is None:
        return None, "lens database: the frames are arrays (no EXIF names a lens)"
    try:
        vignetting, match = lens_vignetting(path)
    except InputError as exc:     # a raw file Pillow cannot open: no lens named, no error
        return None, f"lens database: the EXIF of {Path(path).name} cannot be read ({exc})"
    if vignetting is None:
        return None, f"lens database: {match.reason}"
    return vignetting, ""


class SmoothField:
    """A smooth per-channel field on a frame's pixel grid (the falloff, its σ), evaluated
    exactly on a coarse grid of every ``step``-th pixel and interpolated bilinearly to
    each strip of rows (ours: the falloff is a low-order polynomial, so the interpolation
    error is ``k₁·(step / half diagonal)² / 4``; docs/decisions.md says why 8 pixels).

    The coarse rows run on past the frame's last row (the function is a polynomial,
    defined there), so every row sits a multiple of ``1/step`` into its interval and a
    strip is one call of OpenCV's ``remap``, whose linear weights (multiples of 1/32) are
    then exact: ``step`` is a power of two.

    Parameters
    ----------
    function : callable
        ``function(xs, ys) -> (…, 3)`` at pixel coordinates.
    shape : (H, W)
    step : int, optional
        Default 8 pixels, less on frames whose half-diagonal is under 512 pixels (at most
        1/64 of it, rounded down to a power of two).
    """

    def __init__(self, function, shape, *, step: int | None = None):
        hh, ww = shape
        if step is None:    # 8 px on large frames; at most 1/64 of the half-diagonal
            step = 1 << int(np.log2(np.clip(0.5 * np.hypot(hh, ww) / 64, 1, 8)))
        if step & (step - 1) or not 1 <= step <= 32:
            raise ValueError(f"step {step} is not a power of two from 1 to 32")
        self.step = int(step)
        self.rows = np.arange(0, hh - 1 + step, step, dtype=np.float64)
        cols = np.arange(0, ww - 1 + step, step, dtype=np.float64)
        grid = np.asarray(function(cols[None, :], self.rows[:, None]), np.float32)
        # along x to every column once: (coarse rows, W, 3)
        n = len(self.rows)
        map_x = np.repeat((np.arange(ww, dtype=np.float32) / np.float32(step))[None, :], n,
                          axis=0)
        map_y = np.repeat(np.arange(n, dtype=np.float32)[:, None], ww, axis=1)
        cv2 = import_cv2()
        self.across = cv2.remap(grid, map_x, map_y, cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE).reshape(n, ww, -1)

    def strip(self, s: slice) -> np.ndarray:
        """The field on rows ``s``: float32 (rows, W, 3)."""
        cv2 = import_cv2()
        first = s.start // self.step
        last = min(-(-(s.stop - 1) // self.step), len(self.rows) - 1)
        map_x, map_y = _strip_maps(s.stop - s.start, s.start - first * self.step,
                                   self.step, self.across.shape[1])
        block = self.across[first:last + 1]
        if block.shape[0] == 1:         # one coarse row (a one-row frame): no interval
            return np.repeat(block, s.stop - s.start, axis=0)
        return cv2.remap(block, map_x, map_y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)


@functools.lru_cache(maxsize=4)
def _strip_maps(rows: int, offset: int, step: int, width: int):
    """``remap``'s maps for ``rows`` rows starting ``offset`` pixels into a coarse
    interval of ``step`` (the same for every full strip of a merge: cached)."""
    fy = (offset + np.arange(rows, dtype=np.float32)) / np.float32(step)
    map_y = np.repeat(fy[:, None], width, axis=1)
    map_x = np.repeat(np.arange(width, dtype=np.float32)[None, :], rows, axis=0)
    return map_x, map_y


def _through(transform, xs, ys):
    """Pixel coordinates ``xs``, ``ys`` mapped by a 3×3 homography (None: as they are)."""
    if transform is None:
        return xs, ys
    t = transform
    d = t[2, 0] * xs + t[2, 1] * ys + t[2, 2]
    return (t[0, 0] * xs + t[0, 1] * ys + t[0, 2]) / d, (t[1, 0] * xs + t[1, 1] * ys + t[1, 2]) / d


class FrameFalloff:
    """``ρ_j = V(H_j x) / V(x)`` of one frame on the reference grid, strip by strip, and
    the powers by which it scales the frame's terms of the merge's sums.

    A frame's estimate is ``X_j / V(H_j x) = X_j / (ρ_j V(x))`` with the weight
    ``w_j ρ_j² V(x)²``, so ``E = Σ w_j ρ_j X_j / Σ w_j ρ_j²`` divided by ``V(x)``: the
    frames carry ``ρ_j`` while they are summed, and the finished map is divided by
    ``V(x)`` as on a tripod (:func:`apply_vignetting`); a frame that sees the falloff
    where the reference does (``|ρ_j − 1|`` under :data:`NEGLIGIBLE_RATIO` everywhere,
    the reference itself) costs nothing (:meth:`for_frame` gives None).

    Parameters
    ----------
    vignetting : Vignetting
    transform : numpy.ndarray or None
        3×3 reference → frame pixel coordinates (None: the identity).
    shape : (H, W)
        The frames' size.
    noise_weights : bool
        The merge's weights are inverse variances (``"noise"``): ``w·V²``; else ``w``.
    """

    def __init__(self, vignetting: Vignetting, transform, shape, *, noise_weights: bool):
        hh, ww = shape
        transform = None if transform is None else np.asarray(transform, np.float64)

        def ratio(xs, ys):
            seen = np.maximum(vignetting.at(hh, ww, *_through(transform, xs, ys)), 1e-3)
            return seen / np.maximum(vignetting.at(hh, ww, xs, ys), 1e-3)

        self.field = SmoothField(ratio, shape)
        self.power = 2 if noise_weights else 0

    @classmethod
    def for_frame(cls, vignetting: Vignetting | None, transform, shape, *,
                  noise_weights: bool) -> "FrameFalloff | None":
        """The frame's falloff ratio, or None when there is no vignetting or the ratio is
        negligible (the frame did not move, or moved along the falloff's level lines)."""
        if vignetting is None or transform is None:
            return None
        made = cls(vignetting, transform, shape, noise_weights=noise_weights)
        if np.max(np.abs(made.field.across - 1.0)) < NEGLIGIBLE_RATIO:
            return None
        return made

    def strip(self, s: slice) -> np.ndarray:
        """``ρ_j`` at the reference pixels of rows ``s``: float32 (rows, W, 3)."""
        return self.field.strip(s)

    def scale_sums(self, s: slice, a: np.ndarray, w: np.ndarray) -> tuple:
        """``a``, ``w`` (the frame's weighted values and weights on strip ``s``) scaled in
        place (``a·ρ^(p−1)``, ``w·ρ^p``); returns ``(ρ, ρ²)`` (``ρ²`` None unless
        p = 2) for σ's sums (:meth:`sigma_factors`)."""
        v = self.strip(s)
        if self.power == 2:
            np.multiply(a, v, out=a)
            v2 = np.multiply(v, v)
            np.multiply(w, v2, out=w)
            return v, v2
        np.divide(a, v, out=a)
        return v, None

    def sigma_factors(self, scaled) -> tuple[np.ndarray, np.ndarray]:
        """Factors of σ's two sums, ``Σ w²(V + X²σ_t²)`` and ``Σ w X σ_g``: ``ρ^(2p−2)``
        and ``ρ^(p−1)``, from what :meth:`scale_sums` returned."""
        v, v2 = scaled
        if self.power == 2:
            return v2, v
        return 1.0 / (v * v), 1.0 / v


def apply_vignetting(radiance: np.ndarray, sigma: np.ndarray | None, vignetting: Vignetting,
                     *, moved: bool, record: dict, rows: int = 256) -> None:
    """The lens's falloff out of a finished merge, in place, strip by strip: the radiance
    and σ divided by ``V(x)`` (exact when no frame moved; frames that moved carried their
    ratio ``V(H_j x)/V(x)`` into the sums, :class:`FrameFalloff`), and its uncertainty
    ``E · σ_logV(x)`` added to σ in quadrature; ``record`` (the merge's
    ``diagnostics["vignetting"]``) says how."""
    hh, ww = radiance.shape[:2]
    falloff = SmoothField(
        lambda xs, ys: np.maximum(vignetting.at(hh, ww, xs, ys), 1e-3), (hh, ww))
    band = None if sigma is None else SmoothField(
        lambda xs, ys: vignetting.log_sigma_at(hh, ww, xs, ys), (hh, ww))
    for y in range(0, hh, rows):
        s = slice(y, min(y + rows, hh))
        v = falloff.strip(s)
        np.divide(radiance[s], v, out=radiance[s])
        if sigma is not None:
            np.divide(sigma[s], v, out=sigma[s])
        if band is not None:
            assert sigma is not None
            term = band.strip(s)
            np.multiply(term, radiance[s], out=term)
            np.multiply(term, term, out=term)
            sig = sigma[s]
            np.multiply(sig, sig, out=sig)
            np.add(sig, term, out=sig)
            np.sqrt(sig, out=sig)
    record["divided"] = "per frame" if moved else "after the merge"
    if band is not None:
        record["log_sigma_median"] = float(np.median(band.across))
