"""Reader for the NUS in-camera imaging model files (a real camera pipeline).

Kim, Lin, Lu, Süsstrunk, Lin & Brown, *A New In-Camera Imaging Model for Color Computer
Vision and its Application* (PAMI 2012), the model of Lin et al. ICCV 2011 §6 (Eq. 9-11)::

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

import numpy as np

from ..errors import InputError

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
    """``e -> Σ_i w_i ||e - c_i|| + [1, e] A`` (Lin et al. ICCV 2011 Eq. 10; NUS file form)."""

    def __init__(self, centres, weights, affine):
        self.centres = np.asarray(centres, dtype=np.float64)
        self.weights = np.asarray(weights, dtype=np.float64)
        self.affine = np.asarray(affine, dtype=np.float64)
        self._c2 = np.sum(self.centres ** 2, axis=1)

    def __call__(self, e, chunk: int = 2048) -> np.ndarray:
        e = np.asarray(e, dtype=np.float64)
        flat = e.reshape(-1, 3)
        out = np.empty_like(flat)
        ct = self.centres.T.copy()
        for s in range(0, flat.shape[0], chunk):
            x = flat[s:s + chunk]
            d2 = np.sum(x * x, axis=1)[:, None] + self._c2[None, :] - 2.0 * (x @ ct)
            out[s:s + chunk] = (np.sqrt(np.maximum(d2, 0.0)) @ self.weights
                                + self.affine[0] + x @ self.affine[1:])
        return out.reshape(e.shape)


class NUSCameraModel:
    """A camera pipeline read from NUS model files (Kim et al. PAMI 2012; Lin et al. §6).

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


def read_nus_model(folder, direction: str = "raw2jpg", wb_code: int | None = 14):
    """Read an NUS in-camera model folder as a callable camera pipeline.

    The model of Kim et al. (PAMI 2012) / Lin et al. ICCV 2011 §6, Eq. 9-11: a 3×3
    transform per white-balance setting, an RBF gamut map (Eq. 10 form, both directions)
    and per-channel tone curves (see the module docstring for the file format).

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
