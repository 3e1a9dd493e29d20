"""How far a fitted pipeline can be trusted: the neighbourhood of its training colours.

A camera's gamut map is only known where the calibration saw colours ([Gong2018] §3.4 fits
the 5×5×5 LUT to the training samples; what it does between and beyond them is the
regulariser's guess).  Measured across scenes (``python3 -m bench.pipeline_crossscene``), the
forward error of pixels whose raw lies inside the convex hull of the training colours but
far from every one of them is several times that of pixels near one: the hull is too
generous a test.  selfcal therefore keeps, in the model, a subsample of the training colours
(raw and rendered, the samples on the convex hull of each always included) and calls a pixel
*outside the training colours* when its distance to the nearest training colour exceeds a
radius:

* raw input (:meth:`PipelineModel.render`): distance in ``u = (ρ / s)^(1/2.2)``, ``s`` the
  largest raw value among the training samples (a gamma-like encoding, so that dark and
  bright colours count alike, as they do after the tone curve);
* rendered input (:meth:`PipelineModel.to_raw`): distance in rendered RGB ``[0, 1]``.

Whole images are tested through a table of ``TABLE_SIZE³`` cells over the encoded cube
(the test at each cell centre, a nearest-cell lookup per pixel): exact to within half a
cell diagonal, and a training colour is never outside (its cell centre lies within half
a diagonal of it, less than the radius).  The criterion, the encoding and the radius are
ours, not the papers'; the radius was chosen on the tuning scenes of the cross-scene bench.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import InputError

#: Distance (encoded units, see the module docstring) beyond which a colour is outside.
TRUST_RADIUS = 0.04
#: Training colours kept in the model (the hull vertices of each space always kept).
MAX_POINTS = 2000
#: Cells per axis of the lookup table for whole images.
TABLE_SIZE = 64
#: Exponent of the raw encoding ``u = (ρ / s)^ENCODING``.
ENCODING = 1 / 2.2
_KINDS = ("raw", "rendered")


def _hull_vertices(points: np.ndarray) -> np.ndarray:
    """Indices of the convex-hull vertices of ``points`` (none when degenerate)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return ConvexHull(points).vertices
    except (QhullError, ValueError):
        return np.zeros(0, dtype=np.intp)


class TrainingColours:
    """The training colours of a pipeline model and the test "outside them".

    Parameters
    ----------
    raw, rendered : array_like
        ``(k, 3)`` corresponding training colours (linear raw in ``[0, 1]``; rendered in
        ``[0, 1]``).
    raw_scale : float
        ``s`` of the raw encoding (the largest training raw value).
    radius : float
        Distance beyond which a colour is outside (encoded units).
    """

    def __init__(self, raw: npt.ArrayLike, rendered: npt.ArrayLike, raw_scale: float,
                 radius: float = TRUST_RADIUS) -> None:
        self.raw = np.ascontiguousarray(raw, dtype=np.float64)
        self.rendered = np.ascontiguousarray(rendered, dtype=np.float64)
        if (self.raw.ndim != 2 or self.raw.shape[1] != 3 or self.rendered.shape != self.raw.shape
                or self.raw.shape[0] < 1):
            raise InputError("training colours must be two non-empty (k, 3) arrays of the "
                             "same shape")
        if not (np.all(np.isfinite(self.raw)) and np.all(np.isfinite(self.rendered))):
            raise InputError("training colours must be finite")
        self.raw_scale = float(raw_scale)
        self.radius = float(radius)
        if not (self.raw_scale > 0 and np.isfinite(self.raw_scale)):
            raise InputError(f"raw_scale must be positive, got {raw_scale!r}")
        if not (self.radius > 0 and np.isfinite(self.radius)):
            raise InputError(f"the trust radius must be positive, got {radius!r}")
        self._tables: dict = {}

    @classmethod
    def from_samples(cls, raw: npt.ArrayLike, rendered: npt.ArrayLike, *,
                     max_points: int = MAX_POINTS,
                     radius: float = TRUST_RADIUS, seed: int = 0) -> "TrainingColours":
        """Keep at most ``max_points`` training samples: the convex-hull vertices of the raw
        and of the rendered samples, then a seeded random draw of the rest."""
        raw = np.asarray(raw, dtype=np.float64)
        rendered = np.asarray(rendered, dtype=np.float64)
        n = raw.shape[0]
        keep = np.unique(np.concatenate([_hull_vertices(raw), _hull_vertices(rendered)]))
        if keep.size > max_points:
            keep = np.sort(np.random.default_rng(seed).choice(keep, max_points, replace=False))
        rest = np.setdiff1d(np.arange(n), keep)
        extra = max(0, min(int(max_points) - keep.size, rest.size))
        if extra:
            keep = np.sort(np.concatenate([keep, np.random.default_rng(seed).choice(
                rest, extra, replace=False)]))
        scale = float(max(raw.max(), 1e-6))
        return cls(raw[keep], rendered[keep], scale, radius)

    # ------------------------------------------------------------------ encoding
    def encode(self, colours: npt.ArrayLike, kind: str) -> np.ndarray:
        """The encoded colours of ``kind`` (``"raw"``: ``(ρ / s)^(1/2.2)``; ``"rendered"``:
        as they are), float64, same shape."""
        x = np.asarray(colours, dtype=np.float64)
        if kind == "raw":
            return (np.maximum(x, 0.0) / self.raw_scale) ** ENCODING
        if kind == "rendered":
            return x
        raise InputError(f"kind must be 'raw' or 'rendered', got {kind!r}")

    def _points(self, kind):
        return self.encode(self.raw if kind == "raw" else self.rendered, kind)

    def distance(self, colours: npt.ArrayLike, kind: str = "raw") -> np.ndarray:
        """Exact distance of each ``(..., 3)`` colour to the nearest training colour."""
        from scipy.spatial import cKDTree

        u = self.encode(colours, kind)
        d, _ = cKDTree(self._points(kind)).query(u.reshape(-1, 3))
        return d.reshape(u.shape[:-1])

    def _table(self, kind):
        """Boolean ``TABLE_SIZE³`` table of cells whose centre is outside, and its upper
        bound per axis (the table spans ``[0, hi]``)."""
        if kind not in self._tables:
            from scipy.spatial import cKDTree

            hi = 1.0 + self.radius
            c = (np.arange(TABLE_SIZE) + 0.5) * (hi / TABLE_SIZE)
            grid = np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)
            d, _ = cKDTree(self._points(kind)).query(grid, distance_upper_bound=self.radius)
            self._tables[kind] = (~np.isfinite(d)).reshape((TABLE_SIZE,) * 3), hi
        return self._tables[kind]

    def outside(self, colours: npt.ArrayLike, kind: str = "raw",
                chunk: int = 1 << 20) -> np.ndarray:
        """True where a ``(..., 3)`` colour lies farther than the radius from every training
        colour (through the lookup table; see the module docstring).

        Parameters
        ----------
        colours : array_like
            Raw (``kind="raw"``) or rendered colours; uint8 rendered codes are read as
            ``code / 255``, uint16 as ``value / 65535``.
        kind : {"raw", "rendered"}

        Returns
        -------
        numpy.ndarray
            bool, ``colours.shape[:-1]``.
        """
        if kind not in _KINDS:
            raise InputError(f"kind must be 'raw' or 'rendered', got {kind!r}")
        arr = np.asarray(colours)
        if arr.ndim < 1 or arr.shape[-1] != 3:
            raise InputError(f"colours must have 3 channels last, got shape {arr.shape}")
        flat = arr.reshape(-1, 3)
        if self.radius <= 0.87 * (1.0 + self.radius) / TABLE_SIZE:  # finer than the table
            x = flat.astype(np.float64)
            if arr.dtype == np.uint8:
                x /= 255.0
            elif arr.dtype == np.uint16:
                x /= 65535.0
            return (self.distance(x, kind) > self.radius).reshape(arr.shape[:-1])
        table, hi = self._table(kind)
        out = np.empty(flat.shape[0], dtype=bool)
        for s in range(0, flat.shape[0], chunk):
            x = flat[s:s + chunk]
            if x.dtype == np.uint8:
                x = x.astype(np.float32) / np.float32(255)
            elif x.dtype == np.uint16:
                x = x.astype(np.float32) / np.float32(65535)
            u = self.encode(x, kind)
            beyond = (u > hi).any(axis=1) | ~np.isfinite(u).all(axis=1)
            idx = np.clip((np.nan_to_num(u) * (TABLE_SIZE / hi)).astype(np.intp), 0,
                          TABLE_SIZE - 1)
            out[s:s + chunk] = table[idx[:, 0], idx[:, 1], idx[:, 2]] | beyond
        return out.reshape(arr.shape[:-1])

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        return {"raw": self.raw.tolist(), "rendered": self.rendered.tolist(),
                "raw_scale": self.raw_scale, "radius": self.radius,
                "encoding": f"raw: (rho / raw_scale)^{ENCODING:.6g}; rendered: as is"}

    @classmethod
    def from_dict(cls, d: dict) -> "TrainingColours":
        return cls(d["raw"], d["rendered"], float(d["raw_scale"]), float(d["radius"]))
