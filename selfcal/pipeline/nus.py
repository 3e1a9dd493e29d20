"""Reader for the NUS in-camera imaging model files (a real camera pipeline).

[Kim2012], the model of [Lin2011] §6 (Eq. 9-11)::

    forward  (raw2jpg):  P = f(h(T ρ))          T = T_s · diag(gains of a WB setting)
    backward (jpg2raw):  ρ = T⁻¹ h⁻¹(f⁻¹(P))

with ``h`` and ``h⁻¹`` radial-basis-function maps ``e' = Σ_i w_i ||e - c_i|| + [1, e] A``.

Files of a model folder (checked against the Nikon D7000 model)::

    {raw2jpg,jpg2raw}_transform.txt   count W; 3 rows of T_s; then per WB setting: its code,
                                      3 rows of T_s·diag(g), one row of the gains g
    {raw2jpg,jpg2raw}_ctrlPoints.txt  count N; N rows: control points c_i
    {raw2jpg,jpg2raw}_coefs.txt       count N+4; N rows of weights w_i, then 4 affine rows
                                      (constant, then the rows multiplying e_1, e_2, e_3)
    {raw2jpg,jpg2raw}_respFcns.txt    one header row; 256 rows × 3: f⁻¹(code) per channel
                                      (code -> linear), increasing, f⁻¹(255) = 1
    {raw2jpg,jpg2raw}_validRange.txt  lowest and highest code the model was fitted on

The raw2jpg RBF maps ``T ρ`` to gamut-mapped linear RGB; the jpg2raw RBF maps linearised
JPEG values back (its control points are the raw2jpg destination points).  The forward
tone curve is the inverse of the ``f⁻¹`` table (piecewise linear); rendering clips the
gamut-mapped values to ``[0, 1]`` first.

Nothing of the model is bundled with selfcal: the files carry no licence that allows
redistribution, so they are read from where the user keeps them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.distance import cdist

from ..errors import InputError
from ..typing import PathLike
from .model import BAKE_SIZE, BackwardStages, ForwardStages, PipelineModel, as_rgb_float
from .nus_render import (NUS_RENDER_GAMMA, NUS_RENDER_REFINE, NUS_RENDER_SIZE, RAW_CODES,
                         LazyRenderTable)

#: White-balance setting codes of the NUS models (README of the model zoo).
WB_NAMES = {3: "tungsten", 4: "flash", 9: "sunny", 10: "cloudy", 11: "shade",
            14: "fluorescent"}
_DIRECTIONS = ("raw2jpg", "jpg2raw")


def _load_counted(path: Path) -> np.ndarray:
    """A table with a count line: ``n`` then ``n`` rows of three numbers."""
    try:
        lines = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
        n = int(float(lines[0][0]))
        rows = np.array(lines[1:], dtype=np.float64)
    except (OSError, ValueError, IndexError) as exc:
        raise InputError(f"cannot be read as a NUS model table ({exc})", path) from None
    if rows.shape != (n, 3) or not np.all(np.isfinite(rows)):
        raise InputError(f"expected a count line ({n}) and {n} rows of 3 numbers, "
                         f"found {len(lines) - 1} rows", path)
    return rows


def _read_transforms(path: Path):
    try:
        lines = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
        count = int(float(lines[0][0]))
        base = np.array(lines[1:4], dtype=np.float64)
        wb = {}
        for i in range(count):
            blk = lines[4 + 5 * i: 9 + 5 * i]
            code = int(float(blk[0][0]))
            wb[code] = (np.array(blk[1:4], dtype=np.float64),
                        np.array(blk[4], dtype=np.float64))
    except (OSError, ValueError, IndexError) as exc:
        raise InputError(f"not a NUS transform file ({exc})", path) from None
    if base.shape != (3, 3) or any(m.shape != (3, 3) or g.shape != (3,)
                                   for m, g in wb.values()):
        raise InputError("not a NUS transform file (bad matrix shapes)", path)
    for code, (m, g) in wb.items():  # the file's T_s·diag(g) must match its parts
        if not np.allclose(base * g, m, atol=2e-4, rtol=1e-3):
            raise InputError(f"white-balance setting {code}: the stored transform is not the "
                             "base transform times diag(gains)", path)
    return base, wb


def _read_response(path: Path) -> np.ndarray:
    """A ``*_respFcns.txt`` table: one header row, then 256 increasing rows of 3 values."""
    try:
        table = np.loadtxt(path, skiprows=1)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read the response table ({exc})", path) from None
    if table.shape != (256, 3) or np.any(np.diff(table, axis=0) <= 0):
        raise InputError("the response table must be 256 increasing rows of 3 values", path)
    return table


class RBFMap:
    """``e -> Σ_i w_i ||e - c_i|| + [1, e] A`` ([Lin2011] Eq. 10; NUS file form)."""

    def __init__(self, centres, weights, affine):
        self.centres = np.asarray(centres, dtype=np.float64)
        self.weights = np.asarray(weights, dtype=np.float64)
        self.affine = np.asarray(affine, dtype=np.float64)

    def __call__(self, e, chunk: int = 4096) -> np.ndarray:
        e = np.asarray(e, dtype=np.float64)
        flat = e.reshape(-1, 3)
        out = np.empty_like(flat)
        for s in range(0, flat.shape[0], chunk):
            x = flat[s:s + chunk]
            # scipy's cdist: the distances in one C loop (2-3x faster than the expanded
            # |x|² + |c|² - 2 x·c, and no cancellation)
            out[s:s + chunk] = (cdist(x, self.centres) @ self.weights
                                + self.affine[0] + x @ self.affine[1:])
        return out.reshape(e.shape)


class NUSCameraModel:
    """A camera pipeline read from NUS model files ([Kim2012]; [Lin2011] §6).

    ``render(raw)`` is the forward model ``f(h(T ρ))``, ``to_raw(rendered)`` the backward
    model ``T⁻¹ h⁻¹(f⁻¹(P))``; calling the object runs the direction it was read for.

    Attributes
    ----------
    direction : str
        ``"raw2jpg"`` or ``"jpg2raw"`` (what ``__call__`` does).
    wb_code : int or None
        The white-balance setting whose transform is used (None: the base transform
        ``T_s``, for raws that are white-balanced already).
    base_transform : numpy.ndarray
        ``T_s`` (3×3).
    gains : numpy.ndarray
        White-balance gains of ``wb_code`` (ones for None).
    transform : numpy.ndarray
        ``T = T_s · diag(gains)``.
    white_balances : dict
        code -> (transform, gains) for every setting in the file.
    inverse_response : numpy.ndarray
        ``(256, 3)`` ``f⁻¹`` table (code -> linear).
    valid_range : tuple of int or None
        Codes the model was fitted on.
    """

    def __init__(self, folder, direction: str = "raw2jpg", wb_code: int | None = 14):
        folder = Path(folder)
        if direction not in _DIRECTIONS:
            raise InputError(f"direction must be 'raw2jpg' or 'jpg2raw', got {direction!r}")
        if not folder.is_dir():
            raise InputError("no such NUS model folder", folder)
        self.folder = folder
        self.direction = direction
        base, wb = _read_transforms(folder / f"{direction}_transform.txt")
        self.base_transform = base
        self.white_balances = wb
        if wb_code is None:
            self.gains = np.ones(3)
        else:
            if int(wb_code) not in wb:
                raise InputError(f"white-balance setting {wb_code} is not in the model "
                                 f"(it has {sorted(wb)})", folder)
            self.gains = wb[int(wb_code)][1].copy()
        self.wb_code = None if wb_code is None else int(wb_code)
        self.transform = base * self.gains[None, :]
        self.transform_inverse = np.linalg.inv(self.transform)
        self._maps = {}
        for d in _DIRECTIONS:
            p = folder / f"{d}_ctrlPoints.txt"
            if p.exists():
                centres = _load_counted(p)
                coefs = _load_counted(folder / f"{d}_coefs.txt")
                if coefs.shape[0] != centres.shape[0] + 4:
                    raise InputError(f"{coefs.shape[0]} coefficient rows for "
                                     f"{centres.shape[0]} control points (expected the "
                                     "weights plus 4 affine rows)", folder / f"{d}_coefs.txt")
                self._maps[d] = RBFMap(centres, coefs[:-4], coefs[-4:])
        if direction not in self._maps:
            raise InputError(f"{direction}_ctrlPoints.txt is missing", folder)
        self._responses = {}
        for d in _DIRECTIONS:
            resp = folder / f"{d}_respFcns.txt"
            if d == direction or resp.exists():
                self._responses[d] = _read_response(resp)
        self.inverse_response = self._responses[direction]
        vr = folder / f"{direction}_validRange.txt"
        self.valid_range = (tuple(int(v) for v in np.loadtxt(vr).ravel()[:2])
                            if vr.exists() else None)
        self._codes = np.arange(256, dtype=np.float64)

    # ---- tone curves -------------------------------------------------------------
    def tone(self, x) -> np.ndarray:
        """Forward tone curve ``f``: linear -> rendered in ``[0, 1]`` (the inverse of the
        raw2jpg ``f⁻¹`` table, piecewise linear)."""
        table = self._responses.get("raw2jpg", self.inverse_response)
        x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
        out = np.empty_like(x)
        for c in range(3):
            out[..., c] = np.interp(x[..., c], table[:, c], self._codes)
        return out / 255.0

    def linearise(self, p) -> np.ndarray:
        """``f⁻¹``: rendered in ``[0, 1]`` -> linear (the jpg2raw table, linearly
        interpolated)."""
        table = self._responses.get("jpg2raw", self.inverse_response)
        p = np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0) * 255.0
        out = np.empty_like(p)
        for c in range(3):
            out[..., c] = np.interp(p[..., c], self._codes, table[:, c])
        return out

    # ---- the two directions -----------------------------------------------------------
    def render(self, raw) -> np.ndarray:
        """Forward: ``P = f(clip(h(T ρ), 0, 1))``; float64 in ``[0, 1]``, same shape.

        Parameters
        ----------
        raw : array_like
            ``(..., 3)`` linear camera raw in ``[0, 1]`` (not white-balanced when
            ``wb_code`` is set: ``T`` applies the setting's gains).
        """
        raw = np.asarray(raw, dtype=np.float64)
        if raw.shape[-1:] != (3,):
            raise InputError(f"raw must have 3 channels last, got shape {raw.shape}")
        if "raw2jpg" not in self._maps:
            raise InputError("this model folder has no raw2jpg files", self.folder)
        mapped = self._maps["raw2jpg"](raw @ self.transform.T)
        return self.tone(np.clip(mapped, 0.0, 1.0))

    def to_raw(self, rendered) -> np.ndarray:
        """Backward: ``ρ = T⁻¹ h⁻¹(f⁻¹(P))``; float64, same shape (not clipped).

        Parameters
        ----------
        rendered : array_like
            ``(..., 3)`` uint8 codes or float in ``[0, 1]``.
        """
        p = np.asarray(rendered)
        p = p / 255.0 if p.dtype == np.uint8 else np.asarray(p, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise InputError(f"rendered must have 3 channels last, got shape {p.shape}")
        if "jpg2raw" not in self._maps:
            raise InputError("this model folder has no jpg2raw files", self.folder)
        return self._maps["jpg2raw"](self.linearise(p)) @ self.transform_inverse.T

    def __call__(self, x) -> np.ndarray:
        return self.render(x) if self.direction == "raw2jpg" else self.to_raw(x)

    def __repr__(self) -> str:
        wb = "base" if self.wb_code is None else f"{self.wb_code} ({WB_NAMES.get(self.wb_code)})"
        return f"NUSCameraModel({str(self.folder)!r}, {self.direction}, wb={wb})"


def read_nus_model(folder: PathLike, direction: str = "raw2jpg",
                   wb_code: int | None = 14) -> NUSCameraModel:
    """Read an NUS in-camera model folder as a callable camera pipeline.

    The model of [Kim2012] / [Lin2011] §6, Eq. 9-11: a 3×3 transform per white-balance
    setting, an RBF gamut map (Eq. 10 form, both directions) and per-channel tone curves
    (see the module docstring for the file format).

    Parameters
    ----------
    folder : str or os.PathLike
        The folder holding ``raw2jpg_*.txt`` and/or ``jpg2raw_*.txt``.
    direction : {"raw2jpg", "jpg2raw"}
        Which transform and tone tables to read, and what calling the model does
        (``raw2jpg``: raw -> rendered; ``jpg2raw``: rendered -> raw).  Both
        :meth:`NUSCameraModel.render` and :meth:`NUSCameraModel.to_raw` work whenever the
        folder has both RBF maps.
    wb_code : int or None
        White-balance setting (3 tungsten, 4 flash, 9 sunny, 10 cloudy, 11 shade, 14
        fluorescent -- the setting of the NUS D7000 sample images); None uses the base
        transform ``T_s`` for raws that are white-balanced already.  A white-balanced raw
        ``ρ_wb`` goes into a model with gains ``g`` as ``ρ_wb / g``.

    Returns
    -------
    NUSCameraModel

    Raises
    ------
    InputError
        Missing folder or files, malformed tables, unknown white-balance code.
    """
    return NUSCameraModel(folder, direction=direction, wb_code=wb_code)


# ---- an NUS model folder as a selfcal pipeline model ------------------------------------

_CHUNK = 1 << 15


class _NUSInverseTone:
    """The NUS ``f⁻¹`` in the form :class:`~selfcal.pipeline.PipelineModel` calls its
    inverse tone curves: ``curves(p)`` for ``(..., 3)`` and ``curves.channel(v, k)``."""

    def __init__(self, camera: NUSCameraModel):
        self._camera = camera

    def __call__(self, p) -> np.ndarray:
        return self._camera.linearise(p)

    def channel(self, value: float, k: int) -> float:
        return float(self._camera.linearise(np.full(3, float(value)))[k])


class NUSPipelineModel(PipelineModel):
    """An NUS model folder used as a :class:`~selfcal.pipeline.PipelineModel`.

    The reference model is :class:`NUSCameraModel` ([Kim2012]; [Lin2011]
    §6, Eq. 9-11): an RBF with thousands of centres per pixel (tens of µs each).  Here
    it is baked, once per loaded model and direction, into dense tables evaluated as a
    fitted pipeline model's (:mod:`selfcal.pipeline.dense`):

    - ``to_raw``: the pipeline model's own backward path, with ``M = T`` (the transform of
      the white-balance setting), ``f⁻¹`` the NUS response table and ``h⁻¹`` the jpg2raw
      RBF: ``ρ = T⁻¹ h⁻¹(f⁻¹(P))`` baked over the linearised cube (``bake_size`` nodes per
      axis, the ``u^(1/0.6)`` shaper), 8-bit input through the per-code table.  Output
      clipped to ``[0, 1]`` like every pipeline model's.
    - ``render``: ``h(T ρ)`` (the raw2jpg RBF) on a fine grid over the raw cube
      ``[0, 1]³`` (``(render_size - 1) · render_refine + 1`` nodes per axis at
      ``ρ = u^(1/0.45)``: 241 by default; ours), evaluated lazily where images reach
      (:class:`LazyRenderTable`: the first image pays for the nodes it needs),
      tetrahedral interpolation, then the clip and the tone curve ``f`` per channel
      (tabulated at every 1/65535).
      The raw is read at 16-bit precision (float input is rounded to ``1/65535``, below
      any raw file's step) to find its grid coordinate by a table look-up.

    The RBF's kernel ``||e - c_i||`` has a kink at each of its thousands of centres, so
    linear interpolation converges only to first order: the render grid is fine and
    hence lazy (docs/decisions.md, "NUS model render grid: 241 nodes per axis, spaced as
    ρ^0.45"; ``python3 -m bench.nus_model`` measures it).  The first render of a frame
    spanning many colours costs a few seconds of RBF evaluation (about 20 µs per node; a 24 MP frame needs
    50,000-200,000 nodes), kept for the next frames; an image of random colours over the
    whole cube would need millions.  The render table grows as it renders: not for
    several threads at once (one model per thread).

    Not saved as a selfcal model file (:meth:`save` refuses): the folder is the model.

    Parameters
    ----------
    camera : NUSCameraModel
        The folder read with both RBF maps.
    bake_size : int
        Nodes per axis of the backward table.
    render_size : int
        Nodes per axis of the coarse forward grid (its cells are the lazy blocks).
    render_refine : int
        Each coarse cell split into ``render_refine³`` cells.
    """

    def __init__(self, camera: NUSCameraModel, *, bake_size: int = BAKE_SIZE,
                 render_size: int = NUS_RENDER_SIZE,
                 render_refine: int = NUS_RENDER_REFINE):
        for d in _DIRECTIONS:
            if d not in camera._maps:
                raise InputError(f"{d}_ctrlPoints.txt is missing: a model used for both "
                                 "to-raw and render needs both RBF maps", camera.folder)
        self.camera = camera
        self.render_size = int(render_size)
        self.render_refine = int(render_refine)
        self._forward: LazyRenderTable | None = None
        self._tone_table: np.ndarray | None = None
        wb = "base" if camera.wb_code is None else f"{camera.wb_code} " \
            f"({WB_NAMES.get(camera.wb_code, '?')})"
        # the NUS model renders and inverts with its own tables (the methods below): its
        # stages stand in for fitted ones (f⁻¹ and h⁻¹ of its own kinds, no tone curves
        # or LUTs), which the type checker rightly says they are not
        inverse, rbf = _NUSInverseTone(camera), camera._maps["jpg2raw"]
        forward = ForwardStages(camera.transform, None, None)  # type: ignore[arg-type]
        backward_stages = BackwardStages(inverse, None, rbf)  # type: ignore[arg-type]
        super().__init__(forward, backward_stages,
                         backward="rbf",
                         diagnostics={"source": "NUS model folder", "folder": str(camera.folder),
                                      "white_balance": wb, "valid_range": camera.valid_range},
                         bake_size=bake_size)

    def _check_variant(self, variant):
        if variant not in (None, "rbf"):
            raise InputError(f"an NUS model has only the RBF backward mapping, not {variant!r}")
        return "rbf"

    def backward_exact(self, e, variant: str | None = None) -> np.ndarray:
        """``T⁻¹ h⁻¹(e)`` at linearised colours ``e`` (the NUS jpg2raw RBF, unclipped)."""
        self._check_variant(variant)
        return self.camera._maps["jpg2raw"](np.asarray(e, dtype=np.float64)) \
            @ self.camera.transform_inverse.T

    def _forward_table(self) -> LazyRenderTable:
        if self._forward is None:
            cam = self.camera
            raw2jpg, transform = cam._maps["raw2jpg"], cam.transform

            def evaluate(rho):
                return raw2jpg(rho @ transform.T)

            # the table holds h in 16-bit steps plus half a step plus 65536 c: after a clip
            # and a truncation, channel c's index into the tone table (passes saved)
            self._forward = LazyRenderTable(evaluate, self.render_size - 1,
                                             self.render_refine, NUS_RENDER_GAMMA,
                                             scale=RAW_CODES - 1,
                                             shift=0.5 + RAW_CODES * np.arange(4))
            codes = np.arange(RAW_CODES, dtype=np.float64) / (RAW_CODES - 1)
            # f at every 1/65535 of the gamut-mapped value, channel after channel (and a
            # fourth, unused: the table's rows have four columns, contiguous passes are
            # 1.5-2x faster than over three of four)
            tone = np.zeros((4, RAW_CODES), dtype=np.float32)
            tone[:3] = cam.tone(np.repeat(codes[:, None], 3, axis=1)).T
            self._tone_table = tone.ravel()
        return self._forward

    def render_exact(self, raw) -> np.ndarray:
        """``f(clip(h(T ρ), 0, 1))`` evaluated directly (the reference,
        :meth:`NUSCameraModel.render`; about 20 µs per pixel); float64, same shape."""
        return self.camera.render(as_rgb_float(raw, "raw"))

    def render(self, raw, *, return_mask: bool = False):
        """Forward: raw -> rendered, ``f(clip(h(T ρ), 0, 1))`` through the render table.

        ``h(T ρ)`` is interpolated in the lazily evaluated fine table (see the class
        docstring); the clip and the tone curve ``f`` are then applied per channel (``f``
        tabulated at every ``1/65535``).

        Parameters
        ----------
        raw : array_like
            ``(N, 3)`` or ``(H, W, 3)`` linear camera raw in ``[0, 1]`` (float, or uint16
            read as value / 65535), not white-balanced (``T`` applies the setting's gains).
        return_mask : bool
            Also return the outside-training mask (None: an NUS folder keeps no training
            colours).

        Returns
        -------
        numpy.ndarray
            float32 in ``[0, 1]``, same shape.
        """
        x = np.asarray(raw)
        if x.dtype != np.uint16 or x.ndim < 1 or x.shape[-1] != 3:
            x = as_rgb_float(x, "raw")          # uint16 is used as the 16-bit code
        table = self._forward_table()
        tone = self._tone_table
        assert tone is not None     # made with the table
        shape = x.shape
        flat = x.reshape(-1, 3)
        out = np.empty(flat.shape, dtype=np.float32)
        top = np.float32(RAW_CODES - 1)
        lo = tuple(0.5 + RAW_CODES * c for c in range(4))
        hi = tuple(v + RAW_CODES - 1 for v in lo)
        for s in range(0, flat.shape[0], _CHUNK):
            chunk = flat[s:s + _CHUNK]
            n = chunk.shape[0]
            if flat.dtype == np.uint16:
                q = chunk.astype(np.intp)
            else:   # OpenCV (one channel): rounded to int32, then clipped to the codes
                # (OpenCV's type stubs omit its scalar operands)
                q = cv2.multiply(chunk.reshape(1, 3 * n), float(top),  # type: ignore[call-overload]
                                 dtype=cv2.CV_32S)
                cv2.max(q, 0, dst=q)                # type: ignore[call-overload]
                cv2.min(q, RAW_CODES - 1, dst=q)    # type: ignore[call-overload]
                q = q.reshape(n, 3).astype(np.intp)
            mapped = table(q)                      # (n, 4): 65535 h + 0.5 + 65536 c
            # clipped per column with OpenCV (10x numpy's clip with array bounds)
            img = mapped.reshape(1, n, 4)
            cv2.min(cv2.max(img, lo, dst=img), hi, dst=img)  # type: ignore[call-overload]
            tone.take(mapped[:, :3].astype(np.intp), out=out[s:s + _CHUNK])
        result = out.reshape(shape)
        return (result, None) if return_mask else result

    def to_dict(self) -> dict:
        raise InputError("an NUS model folder is used from its folder; it is not saved as a "
                         "selfcal model file", self.camera.folder)

    def __repr__(self) -> str:
        return f"NUSPipelineModel({self.camera!r})"


def is_nus_model_folder(path) -> bool:
    """True when ``path`` is a folder holding NUS model files (``*_ctrlPoints.txt``)."""
    p = Path(path)
    return p.is_dir() and any((p / f"{d}_ctrlPoints.txt").is_file() for d in _DIRECTIONS)


def load_nus_pipeline(folder, wb_code: int | None = 14, *, bake_size: int = BAKE_SIZE,
                      render_size: int = NUS_RENDER_SIZE,
                      render_refine: int = NUS_RENDER_REFINE) -> NUSPipelineModel:
    """An NUS model folder as a pipeline model (:class:`NUSPipelineModel`).

    What :func:`selfcal.load_model` returns for such a folder: ``to_raw`` and ``render``
    as a fitted :class:`~selfcal.pipeline.PipelineModel`'s, through dense tables baked
    from the folder's RBF maps ([Kim2012]).

    Parameters
    ----------
    folder : str or os.PathLike
        Holding both the raw2jpg and jpg2raw files.
    wb_code : int or None
        White-balance setting (see :func:`read_nus_model`; default 14, fluorescent, the
        setting of the NUS D7000 sample images).
    bake_size : int
        Nodes per axis of the backward table.
    render_size, render_refine : int
        The render grid: coarse nodes per axis, and the split of each coarse cell.

    Returns
    -------
    NUSPipelineModel
        The same object for the same folder (unchanged files) and settings within a
        process, so that its baked tables are made once.

    Raises
    ------
    InputError
        Missing or malformed files, one direction missing, unknown white balance.
    """
    camera = NUSCameraModel(folder, direction="jpg2raw", wb_code=wb_code)
    # one baked model per folder state in a process: loading it again costs no new bake
    stamp = tuple(sorted((f.name, f.stat().st_mtime_ns, f.stat().st_size)
                         for f in Path(folder).glob("*.txt")))
    key = (str(Path(folder).resolve()), camera.wb_code, int(bake_size), int(render_size),
           int(render_refine), stamp)
    if key not in _LOADED:
        _LOADED.clear()
        _LOADED[key] = NUSPipelineModel(camera, bake_size=bake_size, render_size=render_size,
                                        render_refine=render_refine)
    return _LOADED[key]


_LOADED: dict = {}
