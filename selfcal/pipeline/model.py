"""PipelineModel: a fitted camera pipeline, forward (raw -> rendered) and backward.

Forward (Gong et al., *Rank-based radiometric calibration*, Eq. 1b, §3.2-3.4)::

    P = LUT_f(g(f(M ρ)))        implemented as  y = f(M ρ),  P = y + R_f(g(y))

Backward, two variants (§3.5 of Gong et al.; Lin et al. ICCV 2011 Eq. 10-11)::

    "lut":  ρ = LUT_b(g(M⁻¹ f⁻¹(P)))   implemented as  ρ̂ = M⁻¹ f⁻¹(P),  ρ = ρ̂ + R_b(g(ρ̂))
    "rbf":  ρ = M⁻¹ h⁻¹(f⁻¹(P))

``R_f``, ``R_b`` are 5×5×5 lattice-regression tables of residual corrections (see
:mod:`selfcal.pipeline.lattice`).  Whole images go backward through a dense table baked
over the linearised cube ``e = f⁻¹(P)`` (:mod:`selfcal.pipeline.dense`; 49 nodes per axis,
spaced as ``u^(1/0.6)`` so they are denser near black): per pixel one exact per-channel
curve and one trilinear lookup, whichever variant is used.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError, ModelFileError, SelfcalError
from ..modelfile import jsonable
from .dense import CodeTable, grid_points, trilinear_lookup
from .lattice import LatticeLUT
from .rbf import RBFColourMapping
from .tone import MonotonePolynomial

MODEL_KIND = "pipeline"
BACKWARD_VARIANTS = ("lut", "rbf")
#: Nodes per axis of the dense backward table.
BAKE_SIZE = 49
#: The dense table's nodes sit at ``t = u^(1/γ)`` of the normalised linearised range
#: (``u`` uniform): finer near black, where the inverse colour mapping bends most.
SHAPER_GAMMA = 0.6


def _as_rgb_float(x, what: str) -> np.ndarray:
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
        ``(3, 3)`` colour matrix ``M`` (rank-based rows, Gong et al. §3.2, scaled so the
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
        Inverse colour mapping ``h⁻¹`` (Lin et al. Eq. 10) from ``f⁻¹(P)`` to ``M ρ``.
    backward : str
        The backward variant used by :meth:`to_raw`: ``"lut"`` or ``"rbf"``.
    diagnostics : dict
        Training and validation errors, the variant choice and both validation errors,
        the matrix search, sample counts.
    bake_size : int
        Nodes per axis of the dense backward table.
    """

    def __init__(self, matrix, tone_curves: MonotonePolynomial, forward_lut: LatticeLUT,
                 inverse_tone_curves: MonotonePolynomial, backward_lut: LatticeLUT,
                 rbf: RBFColourMapping | None, backward: str = "lut", diagnostics=None,
                 bake_size: int = BAKE_SIZE):
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
        self.tone_curves = tone_curves
        self.forward_lut = forward_lut
        self.inverse_tone_curves = inverse_tone_curves
        self.backward_lut = backward_lut
        self.rbf = rbf
        self.backward = backward
        self.diagnostics = dict(diagnostics or {})
        self.bake_size = int(bake_size)
        self._tables: dict = {}
        self._code_tables: dict = {}

    # ------------------------------------------------------------------ forward
    def render(self, raw) -> np.ndarray:
        """Forward model: linear raw -> rendered, ``y = f(M ρ)``, ``P = y + R_f(g(y))``.

        Gong et al., rank-based radiometric calibration, Eq. 1b with §3.2-3.4.

        Parameters
        ----------
        raw : array_like
            ``(N, 3)`` or ``(H, W, 3)`` linear camera RGB in ``[0, 1]`` (float, or
            uint16 read as value / 65535).

        Returns
        -------
        numpy.ndarray
            float32 in ``[0, 1]``, same shape (multiply by 255 for 8-bit codes).
        """
        x = _as_rgb_float(raw, "raw")
        shape = x.shape
        flat = x.reshape(-1, 3)
        out = np.empty(flat.shape, dtype=np.float32)
        step = 1 << 20
        for s in range(0, flat.shape[0], step):
            y = np.clip(self.tone_curves(flat[s:s + step] @ self.matrix.T), 0.0, 1.0)
            out[s:s + step] = np.clip(y + self.forward_lut.residual(y), 0.0, 1.0)
        return out.reshape(shape)

    # ------------------------------------------------------------------ backward
    def _check_variant(self, variant):
        variant = self.backward if variant is None else variant
        if variant not in BACKWARD_VARIANTS:
            raise InputError(f"variant must be one of {BACKWARD_VARIANTS}, got {variant!r}")
        if variant == "rbf" and self.rbf is None:
            raise InputError("this model has no RBF colour mapping")
        return variant

    def backward_exact(self, e, variant: str | None = None) -> np.ndarray:
        """The backward model at linearised colours ``e = f⁻¹(P)``, evaluated directly.

        ``"lut"``: ``ρ̂ = M⁻¹ e``, ``ρ = ρ̂ + R_b(g(ρ̂))`` (Gong et al. §3.5);
        ``"rbf"``: ``ρ = M⁻¹ h⁻¹(e)`` (Lin et al. Eq. 11).  Not clipped.
        """
        variant = self._check_variant(variant)
        e = np.asarray(e, dtype=np.float64)
        if variant == "lut":
            rho = e @ self.matrix_inverse.T
            return rho + self.backward_lut.residual(rho)
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

    def _coords(self, e: np.ndarray) -> np.ndarray:
        lo, hi = self._e_box()
        t = np.clip((e - lo) / (hi - lo), 0.0, 1.0)
        return t ** SHAPER_GAMMA * (self.bake_size - 1)

    def to_raw(self, rendered, *, variant: str | None = None,
               exact: bool = False) -> np.ndarray:
        """Backward model: rendered (JPEG) -> linear raw.

        ``e = f⁻¹(P)`` per channel (Gong et al. §3.5), then the chosen variant (see
        :meth:`backward_exact`) through the dense table baked over the linearised cube
        (trilinear), or directly when ``exact``.

        Parameters
        ----------
        rendered : array_like
            ``(N, 3)`` or ``(H, W, 3)``: uint8 codes, uint16, or float in ``[0, 1]``.
        variant : {"lut", "rbf"}, optional
            Override the variant chosen at fit time (:attr:`backward`).
        exact : bool
            Evaluate the model directly instead of through the baked table (slow with
            the RBF: about 10 s per million pixels).

        Returns
        -------
        numpy.ndarray
            float32 linear raw in ``[0, 1]``, same shape.
        """
        variant = self._check_variant(variant)
        arr = np.asarray(rendered)
        if arr.dtype == np.uint8 and not exact and arr.ndim >= 1 and arr.shape[-1] == 3:
            if variant not in self._code_tables:
                e = self.inverse_tone_curves(np.arange(256)[:, None].repeat(3, 1) / 255.0)
                self._code_tables[variant] = CodeTable(self._table(variant), self._coords(e))
            out = self._code_tables[variant](arr)
            np.clip(out, 0.0, 1.0, out=out)
            return out
        p = _as_rgb_float(arr, "rendered")
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
        return out.reshape(shape)

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        """JSON-serialisable content (kind ``"pipeline"``) for :mod:`selfcal.modelfile`."""
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
            "diagnostics": jsonable(self.diagnostics),
        }

    @classmethod
    def from_dict(cls, d: dict, *, path=None) -> "PipelineModel":
        """Rebuild a model from :meth:`to_dict` content; ModelFileError on bad content."""
        if d.get("kind", MODEL_KIND) != MODEL_KIND:
            raise ModelFileError(f"not a pipeline model (kind {d.get('kind')!r})", path)
        try:
            return cls(matrix=np.asarray(d["matrix"], dtype=np.float64),
                       tone_curves=MonotonePolynomial.from_dict(d["tone_curves"]),
                       forward_lut=LatticeLUT.from_dict(d["forward_lut"]),
                       inverse_tone_curves=MonotonePolynomial.from_dict(
                           d["inverse_tone_curves"]),
                       backward_lut=LatticeLUT.from_dict(d["backward_lut"]),
                       rbf=None if d.get("rbf") is None else RBFColourMapping.from_dict(
                           d["rbf"]),
                       backward=str(d["backward"]),
                       diagnostics=dict(d.get("diagnostics") or {}),
                       bake_size=int(d.get("bake_size", BAKE_SIZE)))
        except KeyError as exc:
            raise ModelFileError(f"pipeline model lacks the field {exc.args[0]!r}",
                                 path) from None
        except ModelFileError:
            raise
        except (SelfcalError, TypeError, ValueError) as exc:
            raise ModelFileError(f"pipeline model has a malformed field ({exc})",
                                 path) from None

    def save(self, path, force: bool = False):
        """Write the model as versioned JSON (kind ``"pipeline"``), atomically.

        Refuses to overwrite an existing file unless ``force``
        (:class:`selfcal.errors.OutputExistsError`).
        """
        from ..modelfile import save_model_dict

        return save_model_dict(path, self.to_dict(), force=force)

    def __repr__(self) -> str:
        d = self.diagnostics
        return (f"PipelineModel(backward={self.backward!r}, forward RMSE "
                f"{d.get('forward_train_rmse', float('nan')):.3g}/255)")
