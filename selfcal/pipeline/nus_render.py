"""The render table of an NUS model: ``h(T ρ)`` on a fine grid, evaluated where images reach.

The forward stage of :class:`selfcal.pipeline.nus.NUSPipelineModel`.  The raw2jpg RBF of
an NUS model folder ([Kim2012]) costs tens of µs per pixel; :class:`LazyRenderTable` keeps
it on a fine grid over the raw cube whose blocks are evaluated the first time a pixel falls
in them, and interpolates tetrahedrally ([Kasson1995]).  Reading the model files and the
model itself are in :mod:`selfcal.pipeline.nus`.  Citation keys are those of
``docs/references.md``.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["LazyRenderTable", "NUS_RENDER_SIZE", "NUS_RENDER_REFINE", "NUS_RENDER_GAMMA",
           "RAW_CODES"]

#: Nodes per axis of the coarse forward (render) grid of an NUS model: its cells are the
#: blocks of the lazily evaluated render table.
NUS_RENDER_SIZE = 49
#: Each coarse cell is split into ``NUS_RENDER_REFINE³`` cells (a 241-node grid per axis
#: at the defaults); only the cells an image reaches are evaluated.
NUS_RENDER_REFINE = 5
#: The render grid's nodes sit at raw ``ρ = u^(1/γ)`` (``u`` uniform): cells grow with
#: ``ρ^(1-γ)`` as the tone curve's slope falls (for a ``1/2.2`` tone curve the output error
#: of first-order interpolation is then even over the cube; ours, ``python3 -m
#: bench.nus_model``; docs/decisions.md, "NUS model render grid: 241 nodes per axis,
#: spaced as ρ^0.45").
NUS_RENDER_GAMMA = 0.45
#: 16-bit raw codes: the render reads the raw at this precision.
RAW_CODES = 65536
_BITS = 10          # the low bits of a packed index: the cell's offset in its block
_W = np.float32(65536.0)


class LazyRenderTable:
    """``h(T ρ)`` on a fine grid over the raw cube, evaluated only where images reach (ours).

    The raw2jpg RBF ``Σ wᵢ ||e - cᵢ|| + [1, e] A`` ([Kim2012]) is a sum of
    cones: it has a kink at each of its thousands of centres, so trilinear interpolation
    converges only to first order in the cell size and a table within 1e-3 of it needs
    about 241 nodes per axis (14 M nodes; 5 minutes of RBF evaluation).  A natural image
    reaches a small part of that cube (a 24 MP frame: 50,000-200,000 nodes), so the grid
    is kept in blocks, one per coarse cell (``coarse_cells³`` of them, ``refine + 1`` nodes
    per axis each, faces shared by duplication), allocated when a pixel first falls in
    the coarse cell, and a node is evaluated when a pixel first falls in one of the
    cells it is a corner of.

    Per pixel: the raw read at 16-bit precision, the grid coordinate from per-code tables
    (one packed integer per channel: coarse cell and offset in the block), one gather of
    the block's first node, then tetrahedral interpolation in the shaper's coordinate
    ``u = ρ^γ``: four 16-byte gathers of corner rows (``h`` padded to four float32) and
    three OpenCV ``blendLinear`` passes (1.2x faster than trilinear here, and as close
    to the RBF: max 7.2e-4 against 8.2e-4 on the bench frame).  A cell's eight corners
    are evaluated together.

    Parameters
    ----------
    evaluate : callable
        ``(n, 3)`` raw -> ``(n, 3)`` ``h(T ρ)`` (float64).
    coarse_cells, refine : int
        Cells per axis of the coarse grid, and the split of each.
    gamma : float
        The shaper: nodes at ``ρ = u^(1/γ)``.
    scale : float
    shift : float or array_like of 4
        The table holds ``scale · h + shift`` per column (the render's tone-table index,
        saving passes per pixel; interpolation commutes with it).
    """

    def __init__(self, evaluate, coarse_cells: int, refine: int, gamma: float,
                 scale: float = 1.0, shift=0.0):
        self._evaluate = evaluate
        self.scale = float(scale)
        self.shift = np.broadcast_to(np.asarray(shift, dtype=np.float64), (4,))
        self.c = c = int(coarse_cells)
        self.r = r = int(refine)
        self.b = b = r + 1                       # nodes per axis of a block
        self.nb = b ** 3
        if b * b * (r - 1) + b * (r - 1) + (r - 1) >= 1 << _BITS or c ** 3 << _BITS >= 2 ** 31:
            raise InputError(f"render grid of {c} coarse cells split {r} ways per axis: too "
                             "fine for the table's packed indices (at most 127 cells split "
                             "9 ways; 48 split 5 by default)")
        self.gamma = float(gamma)
        self.block_of = np.full(c ** 3, -1, dtype=np.intp)   # first node of its block
        self.coarse_of = np.empty(0, dtype=np.int64)
        self.values = np.zeros((0, 4), dtype=np.float32)
        self.known = np.zeros(0, dtype=bool)    # node evaluated
        self.ready = np.zeros(0, dtype=bool)    # cell (at its first corner) has all 8
        self.n_blocks = 0
        self.evaluated = 0
        self.offsets = [0, 1, b, b + 1, b * b, b * b + 1, b * b + b, b * b + b + 1]
        u = np.arange(RAW_CODES, dtype=np.float64) / (RAW_CODES - 1)
        u = u ** self.gamma * (c * r)
        i = np.minimum(np.floor(u).astype(np.int64), c * r - 1)
        self.t = (u - i).astype(np.float32)
        # per tetrahedron case (bits: t_r >= t_g, t_g >= t_b, t_r >= t_b), the node offsets
        # of the axes with the largest and the second-largest t (cases 1 and 6 cannot occur)
        r_, g_, b_ = b * b, b, 1
        self.first = np.array([b_, b_, g_, g_, b_, r_, r_, r_], dtype=np.intp)
        self.second = np.array([g_, r_, b_, r_, r_, b_, g_, g_], dtype=np.intp)
        coarse, sub = np.divmod(i, r)
        # per channel: (coarse-cell contribution << _BITS) + offset in the block
        self.packed = [(((coarse * c * c) << _BITS) + sub * b * b).astype(np.int32),
                       (((coarse * c) << _BITS) + sub * b).astype(np.int32),
                       ((coarse << _BITS) + sub).astype(np.int32)]

    def _grow(self, blocks: int):
        cap = self.values.shape[0] // self.nb
        if blocks <= cap:
            return
        cap = max(blocks, 2 * cap, 64)
        for name in ("values", "known", "ready"):
            old = getattr(self, name)
            new = np.zeros((cap * self.nb,) + old.shape[1:], dtype=old.dtype)
            new[:old.shape[0]] = old
            setattr(self, name, new)
        coarse_of = np.empty(cap, dtype=np.int64)
        coarse_of[:self.n_blocks] = self.coarse_of[:self.n_blocks]
        self.coarse_of = coarse_of

    def _add_blocks(self, coarse: np.ndarray):
        coarse = np.unique(coarse)
        n0, n = self.n_blocks, coarse.size
        self._grow(n0 + n)
        self.coarse_of[n0:n0 + n] = coarse
        self.block_of[coarse] = np.arange(n0, n0 + n, dtype=np.intp) * self.nb
        self.n_blocks = n0 + n

    def _fill(self, cells: np.ndarray):
        """Evaluate the missing corners of ``cells`` (first-corner node indices)."""
        cells = np.unique(cells)
        nodes = np.unique((cells[:, None] + np.array(self.offsets)).ravel())
        nodes = nodes[~self.known[nodes]]
        if nodes.size:
            b, c, r = self.b, self.c, self.r
            blk, loc = np.divmod(nodes, self.nb)
            co = self.coarse_of[blk]
            fine = np.stack([co // (c * c) * r + loc // (b * b),
                             (co // c) % c * r + (loc // b) % b,
                             co % c * r + loc % b], axis=1)
            rho = (fine / (c * r)) ** (1.0 / self.gamma)
            self.values[nodes] = self.shift
            self.values[nodes, :3] += self._evaluate(rho) * self.scale
            self.known[nodes] = True
            self.evaluated += nodes.size
        self.ready[cells] = True

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """``scale · h + shift`` at ``(n, 3)`` 16-bit raw codes ``q`` (intp); ``(n, 4)``
        float32, the fourth column unused."""
        key = self.packed[0].take(q[:, 0])
        key += self.packed[1].take(q[:, 1])
        key += self.packed[2].take(q[:, 2])
        coarse = key >> _BITS
        base = self.block_of.take(coarse)
        if (base < 0).any():
            self._add_blocks(coarse[base < 0])
            base = self.block_of.take(coarse)
        base += key & ((1 << _BITS) - 1)
        ready = self.ready.take(base)
        if not ready.all():
            self._fill(base[~ready])
        rows = self.values.view(np.complex128).ravel()   # one 16-byte row per node
        n = q.shape[0]
        # OpenCV images of four channels: 256 pixels a row when n allows, else one row
        shape = (n // 256, 256, 4) if n % 256 == 0 else (1, n, 4)
        bufs = [np.empty((n, 4), dtype=np.float32) for _ in range(4)]

        def take(index, k):     # rows[index] into buffer k, as an OpenCV image
            rows.take(index, out=bufs[k].view(np.complex128).reshape(n))
            return bufs[k].reshape(shape)

        # tetrahedral interpolation ([Kasson1995]): the cell's tetrahedron
        # from the order of (t_r, t_g, t_b); corners base, +first axis, +second axis, +all
        t = [self.t.take(q[:, k]) for k in range(3)]
        rg, gb, rb = t[0] >= t[1], t[1] >= t[2], t[0] >= t[2]
        case = rg.view(np.int8) * np.int8(4)
        case += gb.view(np.int8) * np.int8(2)
        case += rb.view(np.int8)
        hi = np.maximum(np.maximum(t[0], t[1]), t[2])
        lo = np.minimum(np.minimum(t[0], t[1]), t[2])
        mid = t[0] + t[1] + t[2] - hi - lo
        c0 = take(base, 0)
        index = base + self.first.take(case)
        c1 = take(index, 1)
        index += self.second.take(case)
        c2 = take(index, 2)
        c3 = take(base + self.offsets[7], 3)
        # cv2.blendLinear: (w0 a + w1 b) / (w0 + w1 + 1e-5) in one pass (3x numpy's three);
        # weights scaled by 2^16 so that the 1e-5 costs < 1e-9; accumulated weights chain
        # the four corners: ((w0 c0 + w1 c1) / (w0 + w1)), then c2, then c3
        two = shape[:2]
        w = [(1.0 - hi) * _W, (hi - mid) * _W, (mid - lo) * _W, lo * _W]
        acc = w[0] + w[1]
        cv2.blendLinear(c0, c1, w[0].reshape(two), w[1].reshape(two), dst=c0)
        cv2.blendLinear(c0, c2, acc.reshape(two), w[2].reshape(two), dst=c0)
        acc += w[2]
        cv2.blendLinear(c0, c3, acc.reshape(two), w[3].reshape(two), dst=c0)
        return bufs[0]
