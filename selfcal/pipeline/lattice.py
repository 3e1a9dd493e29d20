"""Lattice-regression look-up tables and the highlight-stretching function g.

[Gong2018] §3.4-3.5: a 5×5×5 LUT with trilinear interpolation, fitted by lattice
regression ([GarciaGupta2009]; keys of ``docs/references.md``): the node values ``b`` minimise

    || W b - y ||²  +  α bᵀ L b

where ``W`` holds the trilinear interpolation weights of every sample (8 non-zeros per
row, a sparse matrix) and ``L`` is the graph Laplacian of the lattice (6-neighbour grid),
``bᵀ L b = Σ_edges (b_i - b_j)²``.  The LUT is applied to ``g(x)``, a fixed function that
stretches highlights ([Gong2018] Fig. 3) so that more of the uniform lattice lies where
gamut mapping acts.

selfcal fits the lattice to the *residual* ``y - base(x)`` of a known base map (the
identity of what came before, e.g. ``f(Mρ)`` in the forward pipeline), so the table only
has to hold the correction; the graph Laplacian then pulls empty lattice regions toward a
constant correction (no correction when there is no data) instead of toward a constant
colour, and the curvature of the base map costs no lattice resolution.

Also ours, not [Gong2018]'s: beside the 5×5×5 nodes, :func:`lattice_regression_lut` fits an
unpenalised linear term ``(t - 1/2) A`` with ``t = (x - lo) / (hi - lo)`` and a 3×3 matrix
``A`` (option ``affine``, on by default and used by :func:`selfcal.pipeline.fit_pipeline`
for both the forward and the backward LUT).  The reason, as the code states it: the graph
Laplacian penalises every difference between neighbouring nodes, so it would shrink even a
purely linear correction towards a constant; with ``A`` outside the penalty the Laplacian
only shapes the non-linear rest (and empty lattice regions continue the linear
correction rather than a constant one).  (The history records no measurement behind it; the term
came with the first version of the RAW path.)  Each LUT therefore has
125 × 3 + 3 × 3 = 384 parameters, not the 125 × 3 of [Gong2018] §3.6 (whose count, 408 in
all, is 9 for ``M``, 8 × 3 for ``f`` and 125 × 3 for the LUT); the fitted pipeline has two
LUTs (forward and backward) and, unless ``backward="lut"``, the RBF ``h⁻¹`` besides.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import scipy.sparse as sp
from scipy.sparse.linalg import splu, spsolve

from ..errors import CalibrationError, InputError

#: Lattice size per axis ([Gong2018] §3.4: 5×5×5).
LATTICE_SIZE = 5
#: Steepness γ of the highlight stretch g (see :func:`highlight_stretch`).
STRETCH_GAMMA = 1.5
#: Default relative weight of the graph-Laplacian regulariser (see lattice_regression_lut).
LUT_SMOOTHNESS = 3e-3


def highlight_stretch(x: npt.ArrayLike, gamma: float = STRETCH_GAMMA) -> np.ndarray:
    """The highlight-stretching function ``g`` of [Gong2018] §3.4 (their Fig. 3).

    ``g(x) = (exp(γ x) - 1) / (exp(γ) - 1)`` on ``[0, 1]`` (inputs are clipped): increasing,
    convex, ``g(0) = 0``, ``g(1) = 1``; its slope is ``γ / (e^γ - 1) ≈ 0.43`` at 0 and
    ``γ e^γ / (e^γ - 1) ≈ 1.93`` at 1 for γ = 1.5, so a uniform 5-node lattice on ``g(x)``
    has about 4.5× finer cells in ``x`` near white than near black.

    Parameters
    ----------
    x : array_like
    gamma : float
        ``>= 0``; 0 is the identity (no stretch).

    Returns
    -------
    numpy.ndarray
    """
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    if gamma == 0:
        return x
    return np.expm1(gamma * x) / np.expm1(gamma)


def highlight_stretch_inverse(y, gamma: float = STRETCH_GAMMA) -> np.ndarray:
    """Inverse of :func:`highlight_stretch`: ``log(1 + y (e^γ - 1)) / γ``."""
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    if gamma == 0:
        return y
    return np.log1p(y * np.expm1(gamma)) / gamma


def trilinear_weights(u: np.ndarray, size: int) -> sp.csr_matrix:
    """Sparse trilinear interpolation weights of points ``u ∈ [0, 1]³`` on a ``size³`` lattice.

    Row ``i`` holds the 8 weights of point ``i`` on the nodes of its lattice cell (node
    index ``(i0 * size + i1) * size + i2``); ``W @ values`` interpolates node values.
    """
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0) * (size - 1)
    i = np.minimum(np.floor(u).astype(np.int64), size - 2)
    t = u - i
    n = u.shape[0]
    rows = np.repeat(np.arange(n), 8)
    cols = np.empty((n, 8), dtype=np.int64)
    vals = np.empty((n, 8))
    k = 0
    for a in (0, 1):
        wa = t[:, 0] if a else 1.0 - t[:, 0]
        for b in (0, 1):
            wb = t[:, 1] if b else 1.0 - t[:, 1]
            for c in (0, 1):
                wc = t[:, 2] if c else 1.0 - t[:, 2]
                cols[:, k] = ((i[:, 0] + a) * size + i[:, 1] + b) * size + i[:, 2] + c
                vals[:, k] = wa * wb * wc
                k += 1
    return sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(n, size ** 3))


def lattice_laplacian(size: int) -> sp.csr_matrix:
    """Graph Laplacian ``L`` of the ``size³`` lattice, 6-neighbour edges.

    ``bᵀ L b = Σ_edges (b_i - b_j)²``.
    """
    idx = np.arange(size ** 3).reshape(size, size, size)
    edges = []
    for axis in range(3):
        a = np.take(idx, np.arange(size - 1), axis=axis).ravel()
        b = np.take(idx, np.arange(1, size), axis=axis).ravel()
        edges.append(np.stack([a, b], axis=1))
    e = np.concatenate(edges)
    m = e.shape[0]
    inc = sp.csr_matrix((np.concatenate([np.ones(m), -np.ones(m)]),
                         (np.concatenate([np.arange(m)] * 2), e.T.ravel())),
                        shape=(m, size ** 3))
    return (inc.T @ inc).tocsr()


@dataclass
class LatticeLUT:
    """A lattice-regression LUT applied after normalisation and the highlight stretch.

    ``LUT(x) = base(x) + R(g(t)) + (t - 1/2) A`` with ``t = (x - lo) / (hi - lo)``, where
    ``R`` interpolates the residual node values trilinearly ([Gong2018] §3.4-3.5; the base
    is supplied by the caller) and ``A`` is the unpenalised linear term, ours (zero when
    fitted with ``affine=False``).

    Attributes
    ----------
    nodes : numpy.ndarray
        ``(size, size, size, 3)`` residual node values.
    lo, hi : numpy.ndarray
        ``(3,)`` input range mapped to ``[0, 1]`` before ``g``.
    gamma : float
        γ of :func:`highlight_stretch`.
    smoothness : float
        Relative graph-Laplacian weight it was fitted with.
    validation : dict
        Leave-one-out RMSE per weight tried (``smoothness="auto"``).
    linear : numpy.ndarray
        ``(3, 3)`` matrix ``A`` of the linear term (not in [Gong2018]; see the module
        docstring).
    """

    nodes: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    gamma: float = STRETCH_GAMMA
    smoothness: float = LUT_SMOOTHNESS
    validation: dict = field(default_factory=dict)
    linear: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))

    def __post_init__(self):
        self.nodes = np.asarray(self.nodes, dtype=np.float64)
        self.lo = np.asarray(self.lo, dtype=np.float64).reshape(3)
        self.hi = np.asarray(self.hi, dtype=np.float64).reshape(3)
        self.linear = np.asarray(self.linear, dtype=np.float64).reshape(3, 3)
        s = self.nodes.shape
        if len(s) != 4 or s[0] != s[1] or s[1] != s[2] or s[3] != 3 or s[0] < 2:
            raise InputError(f"LUT nodes must have shape (n, n, n, 3), got {s}")
        if not (np.all(np.isfinite(self.nodes)) and np.all(self.hi > self.lo)):
            raise InputError("LUT nodes must be finite and its range non-empty")

    @property
    def size(self) -> int:
        return self.nodes.shape[0]

    def coordinates(self, x: npt.ArrayLike) -> np.ndarray:
        """``g((x - lo) / (hi - lo))`` in ``[0, 1]³`` (the lattice coordinates)."""
        x = np.asarray(x, dtype=np.float64)
        return highlight_stretch((x - self.lo) / (self.hi - self.lo), self.gamma)

    def affine_features(self, x: npt.ArrayLike) -> np.ndarray:
        """``t - 1/2`` with ``t = (x - lo) / (hi - lo)`` clipped to [0, 1] (the linear term's
        inputs)."""
        x = np.asarray(x, dtype=np.float64)
        return np.clip((x - self.lo) / (self.hi - self.lo), 0.0, 1.0) - 0.5

    def residual(self, x: npt.ArrayLike) -> np.ndarray:
        """The correction ``R(g(t)) + (t - 1/2) A`` at ``(..., 3)`` inputs (float64)."""
        from .dense import trilinear_lookup

        x = np.asarray(x, dtype=np.float64)
        shape = x.shape
        flat = x.reshape(-1, 3)
        u = self.coordinates(flat) * (self.size - 1)
        out = trilinear_lookup(self.nodes, u, dtype=np.float64)
        if np.any(self.linear):
            out += self.affine_features(flat) @ self.linear
        return out.reshape(shape)

    def to_dict(self) -> dict:
        return {"size": self.size, "gamma": self.gamma, "lo": self.lo.tolist(),
                "hi": self.hi.tolist(), "smoothness": self.smoothness,
                "linear": self.linear.tolist(),
                "validation": {str(k): v for k, v in self.validation.items()},
                "nodes": self.nodes.reshape(-1, 3).tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "LatticeLUT":
        n = int(d["size"])
        return cls(nodes=np.asarray(d["nodes"], dtype=np.float64).reshape(n, n, n, 3),
                   lo=d["lo"], hi=d["hi"], gamma=float(d["gamma"]),
                   smoothness=float(d.get("smoothness", LUT_SMOOTHNESS)),
                   linear=np.asarray(d.get("linear", np.zeros((3, 3))), dtype=np.float64),
                   validation={float(k): float(v)
                               for k, v in (d.get("validation") or {}).items()})


def _leave_group_out(z, res, labels, a, rhs) -> float:
    """RMSE of each group's residuals predicted from the others' fit (normal equations
    ``a`` and right-hand side ``rhs`` of all samples; a group's rows are taken out)."""
    sq = 0.0
    for g in np.unique(labels):
        rows = labels == g
        zg = z[rows]
        try:
            r = splu((a - (zg.T @ zg)).tocsc()).solve(np.asarray(rhs - zg.T @ res[rows]))
        except RuntimeError:          # singular without the group: no prediction
            return float("inf")
        sq += float(np.sum((zg @ r - res[rows]) ** 2))
    return float(np.sqrt(sq / res.size))


#: Relative regulariser weights tried by ``smoothness="auto"``.
SMOOTHNESS_GRID = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 1e-1)


@dataclass(frozen=True)
class LatticeOptions:
    """The form of a lattice-regression LUT and the weights its ``"auto"`` choice tries.

    Attributes
    ----------
    size : int
        Lattice nodes per axis (5 in [Gong2018]).
    gamma : float
        γ of the highlight stretch :func:`highlight_stretch`.
    affine : bool
        Also fit the unpenalised linear term ``(t - 1/2) A`` (3×3 ``A``, ours, not
        [Gong2018]'s: see the module docstring), kept in ``LatticeLUT.linear``; False fits
        the 125 × 3 node values of [Gong2018] alone.
    smoothness_grid : sequence of float
        Candidates for ``smoothness="auto"``.
    """

    size: int = LATTICE_SIZE
    gamma: float = STRETCH_GAMMA
    affine: bool = True
    smoothness_grid: tuple = SMOOTHNESS_GRID


def lattice_regression_lut(x: npt.ArrayLike, y: npt.ArrayLike,
                           options: LatticeOptions | None = None, *,
                           base: npt.ArrayLike | None = None, lo: npt.ArrayLike | None = None,
                           hi: npt.ArrayLike | None = None,
                           smoothness: float | str = LUT_SMOOTHNESS,
                           groups: npt.ArrayLike | None = None) -> LatticeLUT:
    """Fit a ``size³`` lattice-regression LUT ``y ≈ base + R(g(x))`` ([Gong2018] §3.4-3.5).

    Lattice regression ([GarciaGupta2009]): the node values minimise
    ``||W r - (y - base)||² + α rᵀ L r`` with trilinear weights ``W`` (sparse) and the
    lattice graph Laplacian ``L``; the 125×125 normal equations are assembled sparse and
    solved by a sparse direct solver (SuperLU).  ``α = smoothness · trace(WᵀW) / size³``
    (the regulariser's weight relative to the average data weight per node).

    With ``smoothness="auto"`` the weight is the value of ``smoothness_grid`` with the
    lowest leave-one-out error, in closed form for this linear smoother: the held-out
    residual of sample ``i`` is ``e_i / (1 - h_ii)`` with ``h_ii = w_iᵀ A⁻¹ w_i``,
    ``A = WᵀW + α L``.  With ``groups`` (two or more distinct labels, e.g. the scene each
    sample comes from) the error is leave-one-group-out instead: each group's samples
    predicted by the LUT fitted to the others (ours: samples of one scene are neighbours
    of one another, so leave-one-out rewards a LUT that follows a scene's own colours and
    says nothing of colours the scene lacks).  The scores are kept in
    ``LatticeLUT.validation``.

    Parameters
    ----------
    x : array_like
        ``(n, 3)`` inputs (e.g. ``f(M ρ)`` forward, ``M⁻¹ f⁻¹(P)`` backward).
    y : array_like
        ``(n, 3)`` targets (``P`` forward, ``ρ`` backward).
    base : array_like, optional
        ``(n, 3)`` base map at the samples (default ``x``: the LUT corrects the identity).
    options : LatticeOptions, optional
        Lattice size, highlight stretch γ, the affine term, the candidates of ``"auto"``
        (default ``LatticeOptions()``).
    lo, hi : array_like, optional
        ``(3,)`` input range normalised to ``[0, 1]`` before ``g`` (default ``[0, 1]``).
    smoothness : float or "auto"
        Relative weight of the graph-Laplacian regulariser.
    groups : array_like, optional
        ``(n,)`` labels; with ``smoothness="auto"`` and two or more distinct labels the
        weight is chosen by leave-one-group-out.

    Returns
    -------
    LatticeLUT

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> x = rng.uniform(0, 1, (2000, 3))
    >>> y = x + 0.05 * np.sin(3 * x[:, [1, 2, 0]])
    >>> lut = lattice_regression_lut(x, y, smoothness=1e-3)
    >>> float(np.sqrt(np.mean((x + lut.residual(x) - y) ** 2))) < 0.003
    True
    """
    options = LatticeOptions() if options is None else options
    size, gamma, affine = options.size, options.gamma, options.affine
    smoothness_grid = options.smoothness_grid
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or y.shape != x.shape:
        raise InputError(f"LUT data must be two (n, 3) arrays, got {x.shape}, {y.shape}")
    base = x if base is None else np.asarray(base, dtype=np.float64)
    lo = np.zeros(3) if lo is None else np.asarray(lo, dtype=np.float64)
    hi = np.ones(3) if hi is None else np.asarray(hi, dtype=np.float64)
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(y), axis=1) & \
        np.all(np.isfinite(base), axis=1)
    if ok.sum() < 8:
        raise CalibrationError(f"a lattice LUT needs at least 8 samples, got {int(ok.sum())}")
    lut = LatticeLUT(nodes=np.zeros((size, size, size, 3)), lo=lo, hi=hi, gamma=gamma)
    w = trilinear_weights(lut.coordinates(x[ok]), size)
    nodes = size ** 3
    per_node = (w.T @ w).diagonal().sum() / nodes
    lap = lattice_laplacian(size)
    if affine:  # an unpenalised linear term: the Laplacian only shapes the non-linear rest
        z = sp.hstack([w, sp.csr_matrix(lut.affine_features(x[ok]))]).tocsr()
        lap = sp.block_diag([lap, sp.csr_matrix((3, 3))])
    else:
        z = w
    ztz = (z.T @ z).tocsc()
    ridge = 1e-9 * per_node * sp.identity(z.shape[1], format="csc")
    res = y[ok] - base[ok]
    rhs = np.asarray(z.T @ res)

    def system(s):
        return (ztz + float(s) * per_node * lap + ridge).tocsc()

    labels = None if groups is None else np.asarray(groups).reshape(-1)
    if labels is not None and labels.shape[0] != x.shape[0]:
        raise InputError(f"groups has {labels.shape[0]} labels for {x.shape[0]} samples")
    if smoothness == "auto" and labels is not None and np.unique(labels[ok]).size >= 2:
        scores = {float(s): _leave_group_out(z, res, labels[ok], system(s), rhs)
                  for s in smoothness_grid}
        smoothness = min(scores, key=scores.__getitem__)
        lut.validation = scores
    elif smoothness == "auto":
        scores = {}
        for s in smoothness_grid:
            # sparse LU (no BLAS threads: a 128×128 inverse must not wait on a thread pool)
            a_inv = splu(system(s)).solve(np.eye(z.shape[1]))
            fitted = z @ (a_inv @ rhs)
            h = np.asarray(z.multiply(np.asarray(z @ a_inv)).sum(axis=1)).ravel()
            loo = (res - fitted) / np.maximum(1.0 - h, 1e-6)[:, None]
            scores[float(s)] = float(np.sqrt(np.mean(loo ** 2)))
        smoothness = min(scores, key=scores.__getitem__)
        lut.validation = scores
    r = np.asarray(spsolve(system(smoothness), rhs)).reshape(-1, 3)
    if not np.all(np.isfinite(r)):
        raise CalibrationError("the lattice regression is singular")
    lut.nodes = r[:nodes].reshape(size, size, size, 3)
    lut.linear = r[nodes:] if affine else np.zeros((3, 3))
    lut.smoothness = float(smoothness)
    return lut
