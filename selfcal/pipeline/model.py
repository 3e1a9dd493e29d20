"""PipelineModel: a fitted camera pipeline, forward (raw -> rendered) and backward.

Forward ([Gong2018] Eq. 1b, §3.2-3.4)::

    P = LUT_f(g(f(M ρ)))        implemented as  y = f(M ρ),  P = y + R_f(g(y))

Backward, two variants (§3.5 of [Gong2018]; [Lin2011] Eq. 10-11)::

    "lut":  ρ = LUT_b(g(M⁻¹ f⁻¹(P)))   implemented as  ρ̂ = M⁻¹ f⁻¹(P),  ρ = ρ̂ + R_b(g(ρ̂))
    "rbf":  ρ = M⁻¹ h⁻¹(f⁻¹(P))

``R_f``, ``R_b`` are 5×5×5 lattice-regression tables of residual corrections (see
:mod:`selfcal.pipeline.lattice`).  Pixels with a clipped channel (code 0 or 255: the code
does not determine the raw) get the conditional expectation learned from the clipped
training samples, ``ρ + δ(P)`` (:mod:`selfcal.pipeline.clipped`), when the fit kept one.

Whole images go backward through a dense table baked over the linearised cube
``e = f⁻¹(P)`` (:mod:`selfcal.pipeline.dense`; 49 nodes per axis, spaced as ``u^(1/0.6)``
so they are denser near black): per pixel one exact per-channel curve and one trilinear
lookup, whichever variant is used.

The model keeps a subsample of its training colours (:mod:`selfcal.pipeline.trust`):
``render(raw, return_mask=True)`` and ``to_raw(rendered, return_mask=True)`` also return
where the input lies farther than a radius from every training colour -- where the model
is extrapolating (:meth:`PipelineModel.outside_training`).  Models saved before it was kept
load without it (the mask is then None).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..errors import InputError, ModelFileError, SelfcalError
from ..io.model_file import jsonable, save_model_dict
from ..typing import PathLike
from .clipped import CLIP_HI, CLIP_LO, ClippedCorrection, clipped_mask
from .dense import CodeTable, grid_points, trilinear_lookup
from .lattice import LatticeLUT
from .rbf import RBFColourMapping
from .tone import MonotonePolynomial
from .trust import TrainingColours

MODEL_KIND = "pipeline"
BACKWARD_VARIANTS = ("lut", "rbf")
#: Nodes per axis of the dense backward table.
BAKE_SIZE = 49
#: The dense table's nodes sit at ``t = u^(1/γ)`` of the normalised linearised range
#: (``u`` uniform): finer near black, where the inverse colour mapping bends most.
SHAPER_GAMMA = 0.6


@dataclass(frozen=True)
class ForwardStages:
    """The fitted forward stages ``P = y + R_f(g(y))``, ``y = f(M ρ)`` ([Gong2018] §3.2-3.4).

    Attributes
    ----------
    matrix : array_like
        ``(3, 3)`` colour matrix ``M``.
    tone_curves : MonotonePolynomial
        Tone curves ``f`` (Eq. 9).
    lut : LatticeLUT
        Forward gamut correction ``R_f`` (§3.4).
    """

    matrix: npt.ArrayLike
    tone_curves: MonotonePolynomial
    lut: LatticeLUT


@dataclass(frozen=True)
class BackwardStages:
    """The fitted backward stages ([Gong2018] §3.5; [Lin2011] Eq. 10-11).

    Attributes
    ----------
    inverse_tone_curves : MonotonePolynomial
        ``f⁻¹`` from rendered values to ``M ρ``.
    lut : LatticeLUT
        Backward correction ``R_b`` on ``g(M⁻¹ f⁻¹(P))`` (variant ``"lut"``).
    rbf : RBFColourMapping or None
        Inverse colour mapping ``h⁻¹`` (variant ``"rbf"``).
    clipped_corrections : dict or None
        Per variant, the :class:`~selfcal.pipeline.clipped.ClippedCorrection` of pixels
        with a clipped channel, or None.
    """

    inverse_tone_curves: MonotonePolynomial
    lut: LatticeLUT
    rbf: RBFColourMapping | None = None
    clipped_corrections: Mapping[str, ClippedCorrection | None] | None = None


def as_rgb_float(x, what: str) -> np.ndarray:
    """Validate ``(..., 3)`` input; uint8/uint16 -> [0, 1]; float kept; NaN rejected."""
    arr = np.asarray(x)
    if arr.ndim < 1 or arr.shape[-1] != 3:
        raise InputError(f"{what} must have 3 channels last (Nx3 or HxWx3), got shape "
                         f"{arr.shape}")
    if arr.dtype == np.uint8:
        return arr.astype(np.float32) / np.float32(255)
    if arr.dtype == np.uint16:
        return arr.astype(np.float32) / np.float32(65535)
    if not np.issubdtype(arr.dtype, np.floating):
        if np.issubdtype(arr.dtype, np.integer):
            raise InputError(f"{what}: integer type {arr.dtype} is ambiguous; give uint8, "
                             "uint16 or float in [0, 1]")
        raise InputError(f"{what}: unsupported dtype {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{what} holds NaN or infinite values")
    return arr


class PipelineModel:
    """A camera pipeline fitted from corresponding raw and rendered samples.

    Made by :func:`selfcal.pipeline.fit_pipeline`; loaded by :func:`selfcal.load_model`.

    Attributes
    ----------
    matrix : numpy.ndarray
        ``(3, 3)`` colour matrix ``M`` (rank-based rows, [Gong2018] §3.2, scaled so the
        brightest training sample maps to 1 per channel).
    tone_curves : MonotonePolynomial
        Forward tone curves ``f`` (Eq. 9) from ``M ρ`` to rendered values.
    forward_lut : LatticeLUT
        Forward gamut correction (§3.4) on ``g(f(M ρ))``.
    inverse_tone_curves : MonotonePolynomial
        ``f⁻¹`` (§3.5) from rendered values to ``M ρ``.
    backward_lut : LatticeLUT
        Backward correction (§3.5) on ``g(M⁻¹ f⁻¹(P))``.
    rbf : RBFColourMapping or None
        Inverse colour mapping ``h⁻¹`` ([Lin2011] Eq. 10) from ``f⁻¹(P)`` to ``M ρ``.
    backward : str
        The backward variant used by :meth:`to_raw`: ``"lut"`` or ``"rbf"``.
    diagnostics : dict
        Training and validation errors, the variant choice and both validation errors,
        the matrix search, sample counts.
    bake_size : int
        Nodes per axis of the dense backward table.
    clipped_corrections : dict
        Per backward variant, the :class:`~selfcal.pipeline.clipped.ClippedCorrection`
        applied to pixels with a clipped channel (``E[ρ | P]`` from clipped training
        samples), or None (no correction).
    training_colours : TrainingColours or None
        A subsample of the training colours (raw and rendered), for
        :meth:`outside_training`; None in models saved before it was kept.

    Parameters
    ----------
    forward_stages : ForwardStages
        ``M``, ``f`` and the forward LUT.
    backward_stages : BackwardStages
        ``f⁻¹``, the backward LUT, the RBF and the clipped-pixel corrections.
    backward, diagnostics, bake_size, training_colours
        As the attributes (keyword only).
    """

    def __init__(self, forward_stages: ForwardStages, backward_stages: BackwardStages, *,
                 backward: str = "lut", diagnostics: Mapping[str, Any] | None = None,
                 bake_size: int = BAKE_SIZE,
                 training_colours: TrainingColours | None = None) -> None:
        if not isinstance(forward_stages, ForwardStages):
            raise TypeError("forward_stages must be a ForwardStages")
        if not isinstance(backward_stages, BackwardStages):
            raise TypeError("backward_stages must be a BackwardStages")
        fwd, bwd = forward_stages, backward_stages
        matrix, rbf, clipped_corrections = fwd.matrix, bwd.rbf, bwd.clipped_corrections
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise InputError(f"the colour matrix must be a finite 3x3 array, got {m.shape}")
        if abs(np.linalg.det(m)) < 1e-12:
            raise InputError("the colour matrix is singular")
        if backward not in BACKWARD_VARIANTS:
            raise InputError(f"backward must be one of {BACKWARD_VARIANTS}, got {backward!r}")
        if backward == "rbf" and rbf is None:
            raise InputError("backward='rbf' needs an RBF colour mapping")
        self.matrix = m
        self.matrix_inverse = np.linalg.inv(m)
        self.tone_curves = fwd.tone_curves
        self.forward_lut = fwd.lut
        self.inverse_tone_curves = bwd.inverse_tone_curves
        self.backward_lut = bwd.lut
        self.rbf = rbf
        self.backward = backward
        self.diagnostics = dict(diagnostics or {})
        self.bake_size = int(bake_size)
        self.clipped_corrections: dict[str, ClippedCorrection | None] = {}
        for v, corr in dict(clipped_corrections or {}).items():
            if v not in BACKWARD_VARIANTS:
                raise InputError(f"clipped-pixel correction for an unknown variant {v!r}")
            if corr is not None and not isinstance(corr, ClippedCorrection):
                raise InputError("clipped_corrections must map variants to "
                                 "ClippedCorrection or None")
            self.clipped_corrections[v] = corr
        if training_colours is not None and not isinstance(training_colours, TrainingColours):
            raise InputError("training_colours must be a TrainingColours or None")
        self.training_colours = training_colours
        self._tables: dict = {}
        self._code_tables: dict = {}
        self._clipped_tables: dict = {}

    # ------------------------------------------------------------------ trust
    def outside_training(self, colours: npt.ArrayLike, kind: str = "raw") -> np.ndarray | None:
        """Where the model is extrapolating: colours far from every training colour.

        True where a ``(..., 3)`` raw (``kind="raw"``, the input of :meth:`render`) or
        rendered colour (``kind="rendered"``, the input of :meth:`to_raw`) lies farther
        than the trust radius from every training colour kept in the model (see
        :mod:`selfcal.pipeline.trust`: the neighbourhood of the training colours, ours).
        Across scenes the model's error is several times larger there.

        Returns
        -------
        numpy.ndarray or None
            bool, ``colours.shape[:-1]``; None when the model keeps no training colours
            (models saved before they were kept).
        """
        if self.training_colours is None:
            return None
        return self.training_colours.outside(colours, kind)

    # ------------------------------------------------------------------ forward
    def render(self, raw: npt.ArrayLike, *, return_mask: bool = False
               ) -> np.ndarray | tuple[np.ndarray, np.ndarray | None]:
        """Forward model: linear raw -> rendered, ``y = f(M ρ)``, ``P = y + R_f(g(y))``.

        [Gong2018] Eq. 1b with §3.2-3.4.

        Parameters
        ----------
        raw : array_like
            ``(N, 3)`` or ``(H, W, 3)`` linear camera RGB in ``[0, 1]`` (float, or
            uint16 read as value / 65535).
        return_mask : bool
            Also return :meth:`outside_training` of the raw (None for models without
            training colours).

        Returns
        -------
        numpy.ndarray
            float32 in ``[0, 1]``, same shape (multiply by 255 for 8-bit codes); with
            ``return_mask``, the pair ``(rendered, outside)``.
        """
        x = as_rgb_float(raw, "raw")
        shape = x.shape
        flat = x.reshape(-1, 3)
        out = np.empty(flat.shape, dtype=np.float32)
        step = 1 << 20
        for s in range(0, flat.shape[0], step):
            y = np.clip(self.tone_curves(flat[s:s + step] @ self.matrix.T), 0.0, 1.0)
            out[s:s + step] = np.clip(y + self.forward_lut.residual(y), 0.0, 1.0)
        if return_mask:
            return out.reshape(shape), self.outside_training(x, "raw")
        return out.reshape(shape)

    # ------------------------------------------------------------------ backward
    def _check_variant(self, variant):
        variant = self.backward if variant is None else variant
        if variant not in BACKWARD_VARIANTS:
            raise InputError(f"variant must be one of {BACKWARD_VARIANTS}, got {variant!r}")
        if variant == "rbf" and self.rbf is None:
            raise InputError("this model has no RBF colour mapping")
        return variant

    def backward_exact(self, e: npt.ArrayLike, variant: str | None = None) -> np.ndarray:
        """The backward model at linearised colours ``e = f⁻¹(P)``, evaluated directly.

        ``"lut"``: ``ρ̂ = M⁻¹ e``, ``ρ = ρ̂ + R_b(g(ρ̂))`` ([Gong2018] §3.5);
        ``"rbf"``: ``ρ = M⁻¹ h⁻¹(e)`` ([Lin2011] Eq. 11).  Not clipped.
        """
        variant = self._check_variant(variant)
        e = np.asarray(e, dtype=np.float64)
        if variant == "lut":
            rho = e @ self.matrix_inverse.T
            return rho + self.backward_lut.residual(rho)
        assert self.rbf is not None     # _check_variant: "rbf" needs one
        return self.rbf(e) @ self.matrix_inverse.T

    def _e_box(self):
        c = self.inverse_tone_curves
        lo = np.array([c.channel(0.0, k) for k in range(3)], dtype=np.float64)
        hi = np.array([c.channel(1.0, k) for k in range(3)], dtype=np.float64)
        hi = np.maximum(hi, lo + 1e-6)
        return lo, hi

    def _table(self, variant: str) -> np.ndarray:
        if variant not in self._tables:
            lo, hi = self._e_box()
            u = grid_points(np.zeros(3), np.ones(3), self.bake_size).reshape(-1, 3)
            nodes = lo + (hi - lo) * u ** (1.0 / SHAPER_GAMMA)
            vals = self.backward_exact(nodes, variant)
            self._tables[variant] = vals.reshape((self.bake_size,) * 3 + (3,)).astype(
                np.float32)
        return self._tables[variant]

    def bake_backward(self, variant: str | None = None) -> None:
        """Bake the dense backward table of ``variant`` now.

        :meth:`to_raw` bakes each variant's table on its first call and keeps it;
        baking it here moves that cost to a moment the caller chooses
        (:func:`selfcal.pipeline.fit_pipeline` bakes the chosen variant's, so that
        ``to_raw`` is fast from the first call).

        Parameters
        ----------
        variant : {"lut", "rbf"}, optional
            The backward variant (default: :attr:`backward`, the one chosen at fit time).

        Raises
        ------
        InputError
            For an unknown variant, or ``"rbf"`` on a model without an RBF mapping.
        """
        self._table(self._check_variant(variant))

    def _coords(self, e: np.ndarray) -> np.ndarray:
        lo, hi = self._e_box()
        t = np.clip((e - lo) / (hi - lo), 0.0, 1.0)
        return t ** SHAPER_GAMMA * (self.bake_size - 1)

    def to_raw(self, rendered: npt.ArrayLike, *, variant: str | None = None, exact: bool = False,
               return_mask: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray | None]:
        """Backward model: rendered (JPEG) -> linear raw.

        ``e = f⁻¹(P)`` per channel ([Gong2018] §3.5), then the chosen variant (see
        :meth:`backward_exact`) through the dense table baked over the linearised cube
        (trilinear), or directly when ``exact``.  Pixels with a channel within half a code
        of 0 or 255 then get the variant's clipped-pixel correction, if the fit kept one
        (:mod:`selfcal.pipeline.clipped`: ``E[ρ | P]`` learned from clipped samples,
        tabulated on the faces of the code cube).

        Parameters
        ----------
        rendered : array_like
            ``(N, 3)`` or ``(H, W, 3)``: uint8 codes, uint16, or float in ``[0, 1]``.
        variant : {"lut", "rbf"}, optional
            Override the variant chosen at fit time (:attr:`backward`).
        exact : bool
            Evaluate the model directly instead of through the baked table (slow with
            the RBF: about 10 s per million pixels).
        return_mask : bool
            Also return :meth:`outside_training` of the rendered input (None for models
            without training colours).

        Returns
        -------
        numpy.ndarray
            float32 linear raw in ``[0, 1]``, same shape; with ``return_mask``, the pair
            ``(raw, outside)``.
        """
        out = self._to_raw(rendered, variant, exact)
        if return_mask:
            return out, self.outside_training(rendered, "rendered")
        return out

    def _to_raw(self, rendered, variant, exact):
        variant = self._check_variant(variant)
        arr = np.asarray(rendered)
        if arr.dtype == np.uint8 and not exact and arr.ndim >= 1 and arr.shape[-1] == 3:
            if variant not in self._code_tables:
                e = self.inverse_tone_curves(np.arange(256)[:, None].repeat(3, 1) / 255.0)
                self._code_tables[variant] = CodeTable(self._table(variant), self._coords(e))
            out = self._code_tables[variant](arr)
            np.clip(out, 0.0, 1.0, out=out)
            self._correct_clipped(out, arr, variant)
            return out
        p = as_rgb_float(arr, "rendered")
        shape = p.shape
        flat = p.reshape(-1, 3)
        out = np.empty(flat.shape, dtype=np.float32)
        step = 1 << 20
        for s in range(0, flat.shape[0], step):
            e = self.inverse_tone_curves(np.clip(flat[s:s + step], 0.0, 1.0))
            if exact:
                out[s:s + step] = self.backward_exact(e, variant)
            else:
                out[s:s + step] = trilinear_lookup(self._table(variant), self._coords(e))
        np.clip(out, 0.0, 1.0, out=out)
        self._correct_clipped(out, flat, variant)
        return out.reshape(shape)

    def _clipped_face_table(self, variant: str) -> np.ndarray:
        """The clipped-pixel correction at every 8-bit code on the faces of the code cube.

        A clipped pixel lies on a face (a channel at 0 or 1); :meth:`to_raw` reads its
        correction from this table (8-bit input: a gather; float input: bilinear).

        ``(3, 2, 256, 256, 3)``: channel ``k`` at code 0 (index 0) or 255 (index 1), the
        other two channels (in increasing order) at every code pair.  Built once per
        variant (:meth:`~selfcal.pipeline.clipped.ClippedCorrection.face`) so that whole
        images need one gather per clipped pixel.
        """
        if variant not in self._clipped_tables:
            corr = self.clipped_corrections[variant]
            assert corr is not None     # called for variants with a correction only
            codes = np.arange(256, dtype=np.float64) / 255.0
            table = np.empty((3, 2, 256, 256, 3))
            for k in range(3):
                for side, value in enumerate((0.0, 1.0)):
                    table[k, side] = corr.face(k, value, codes)
            self._clipped_tables[variant] = table
        return self._clipped_tables[variant]

    def _correct_clipped(self, out: np.ndarray, rendered: np.ndarray, variant: str):
        """Add the clipped-pixel correction in place (``out`` and ``rendered`` flat or of
        the same shape; uint8 codes or floats in [0, 1]); clip to [0, 1]."""
        corr = self.clipped_corrections.get(variant)
        if corr is None:
            return
        o = out.reshape(-1, 3)
        r = rendered.reshape(-1, 3)
        step = 1 << 20
        for s in range(0, r.shape[0], step):
            rc = r[s:s + step]
            if rc.dtype == np.uint8:
                c = (rc - np.uint8(1)) >= 254       # codes 0 and 255 (uint8 wraps 0 to 255)
                mask = c[:, 0] | c[:, 1] | c[:, 2]
                if not mask.any():
                    continue
                px = rc[mask].astype(np.intp)
                k = np.argmax(c[mask], axis=1)        # a clipped channel of each pixel
                side = (px[np.arange(px.shape[0]), k] == 255).astype(np.intp)
                first = np.where(k == 0, px[:, 1], px[:, 0])
                second = np.where(k == 2, px[:, 1], px[:, 2])
                delta = self._clipped_face_table(variant)[k, side, first, second]
            else:
                mask = clipped_mask(rc)
                if not mask.any():
                    continue
                # bilinear on the face table (exact at 8-bit codes; the correction is
                # smooth, h >= 7 codes); a clipped channel counts as exactly 0 or 1
                p = np.clip(rc[mask].astype(np.float64), 0.0, 1.0)
                cl = (p <= CLIP_LO) | (p >= CLIP_HI)
                k = np.argmax(cl, axis=1)
                side = (p[np.arange(p.shape[0]), k] >= CLIP_HI).astype(np.intp)
                u = np.where(k == 0, p[:, 1], p[:, 0]) * 255.0
                v = np.where(k == 2, p[:, 1], p[:, 2]) * 255.0
                i = np.minimum(u.astype(np.intp), 254)
                j = np.minimum(v.astype(np.intp), 254)
                tu, tv = (u - i)[:, None], (v - j)[:, None]
                t = self._clipped_face_table(variant)
                delta = ((t[k, side, i, j] * (1 - tv) + t[k, side, i, j + 1] * tv) * (1 - tu)
                         + (t[k, side, i + 1, j] * (1 - tv) + t[k, side, i + 1, j + 1] * tv)
                         * tu)
            oc = o[s:s + step]
            oc[mask] = np.clip(oc[mask] + delta, 0.0, 1.0)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        """JSON-serialisable content (kind ``"pipeline"``) for :mod:`selfcal.io.model_file`."""
        return {
            "kind": MODEL_KIND,
            "model": "P = LUT_f(g(f(M rho))); rho = LUT_b(g(M^-1 f^-1(P))) or "
                     "M^-1 h^-1(f^-1(P))",
            "matrix": self.matrix.tolist(),
            "tone_curves": self.tone_curves.to_dict(),
            "forward_lut": self.forward_lut.to_dict(),
            "inverse_tone_curves": self.inverse_tone_curves.to_dict(),
            "backward_lut": self.backward_lut.to_dict(),
            "rbf": None if self.rbf is None else self.rbf.to_dict(),
            "backward": self.backward,
            "bake_size": self.bake_size,
            "clipped_corrections": {v: None if c is None else c.to_dict()
                                    for v, c in self.clipped_corrections.items()},
            "training_colours": (None if self.training_colours is None
                                 else self.training_colours.to_dict()),
            "diagnostics": jsonable(self.diagnostics),
        }

    @classmethod
    def from_dict(cls, d: dict, *, path: PathLike | None = None) -> "PipelineModel":
        """Rebuild a model from :meth:`to_dict` content; ModelFileError on bad content."""
        from ..io.model_file import check_pipeline_content

        if d.get("kind", MODEL_KIND) != MODEL_KIND:
            raise ModelFileError(f"not a pipeline model (kind {d.get('kind')!r})", path)
        check_pipeline_content(d, path)   # every field, before any is used
        try:
            forward = ForwardStages(
                matrix=np.asarray(d["matrix"], dtype=np.float64),
                tone_curves=MonotonePolynomial.from_dict(d["tone_curves"]),
                lut=LatticeLUT.from_dict(d["forward_lut"]))
            backward = BackwardStages(
                inverse_tone_curves=MonotonePolynomial.from_dict(d["inverse_tone_curves"]),
                lut=LatticeLUT.from_dict(d["backward_lut"]),
                rbf=None if d.get("rbf") is None else RBFColourMapping.from_dict(d["rbf"]),
                clipped_corrections={
                    v: None if c is None else ClippedCorrection.from_dict(c)
                    for v, c in (d.get("clipped_corrections") or {}).items()})
            return cls(forward, backward, backward=str(d["backward"]),
                       diagnostics=dict(d.get("diagnostics") or {}),
                       bake_size=int(d.get("bake_size", BAKE_SIZE)),
                       training_colours=None if d.get("training_colours") is None
                       else TrainingColours.from_dict(d["training_colours"]))
        except KeyError as exc:
            raise ModelFileError(f"pipeline model lacks the field {exc.args[0]!r}",
                                 path) from None
        except ModelFileError:
            raise
        except (SelfcalError, TypeError, ValueError) as exc:
            raise ModelFileError(f"pipeline model has a malformed field ({exc})",
                                 path) from None

    def save(self, path: PathLike, force: bool = False) -> Path:
        """Write the model as versioned JSON (kind ``"pipeline"``), atomically.

        Refuses to overwrite an existing file unless ``force``
        (:class:`selfcal.errors.OutputExistsError`).
        """
        return save_model_dict(path, self.to_dict(), force=force)

    def __repr__(self) -> str:
        d = self.diagnostics
        return (f"PipelineModel(backward={self.backward!r}, forward RMSE "
                f"{d.get('forward_train_rmse', float('nan')):.3g}/255)")
