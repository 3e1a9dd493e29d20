"""Rank-based colour matrix: rows of M from half-space (rank order) constraints.

[Gong2018] §3.2, Eq. 4-8.  For an output channel ``k`` and two samples ``a, b`` with
rendered values ``P_k^a > P_k^b`` the rank order is assumed to survive colour correction,
``M_k ρ^a > M_k ρ^b``, i.e. ``M_k · d > 0`` for the difference vector ``d = ρ^a - ρ^b`` (Eq.
4-5): a half-space constraint on the row ``M_k``.  The row is the unit direction that
satisfies the most constraints (Eq. 6 with noise); its length is not determined by rank and
is fixed later (see :func:`row_scales`).

Two searches are implemented:

``method="literal"``
    As published: 100,000 quasi-uniform directions on the unit sphere (a Fibonacci
    lattice: every direction lies within about 0.45° of one, finer than [Gong2018]'s
    1.15°), the satisfied
    constraints counted for all of them by one (chunked) matrix product, the best count
    kept, the median of tied directions taken.

``method="fast"``
    A branch-and-bound over a cube-map quadtree of spherical cells.  A cell with centre
    ``u`` and angular radius ``r`` (the largest angle from ``u`` to a corner; cells are
    gnomonic squares, whose angular distance to the centre is quasi-convex, so the corners
    bound it) satisfies at most ``#{j : u·d̂_j > -sin r}`` constraints at any of its points
    (upper bound) and exactly ``#{j : u·d̂_j > 0}`` at its centre.  Cells whose upper bound
    is below the best count seen are pruned, the others split into four, down to a radius
    of 0.02° (the literal probes are ~0.6° apart); a cell that no constraint boundary
    crosses (``|u·d̂_j| >= sin r`` for all ``j``) has a constant count and is not split, and
    constraints decided alike for every live cell are counted once and dropped.  Pruning
    never discards a region that could beat the best count, so the search is exact up to
    the 0.02° leaf size: it reaches the literal search's count (whose probes all lie in
    some cell) or a higher one, evaluating 2-3 % as many directions against a shrinking
    constraint set.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from ..errors import CalibrationError, InputError

#: Number of directions of the published search ([Gong2018] §3.2).
LITERAL_DIRECTIONS = 100_000
#: Cells of the fast search are split down to this angular radius (degrees).
FAST_MIN_RADIUS_DEG = 0.02
_CHUNK = 1 << 22  # elements per block of the (directions x constraints) product


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` quasi-uniform unit vectors on the sphere (Fibonacci / golden-angle lattice).

    The directions probed by the literal search of [Gong2018] §3.2 ("100,000 unit length
    vectors uniformly distributed on the surface of the unit sphere").

    Parameters
    ----------
    n : int
        Number of points, ``>= 1``.

    Returns
    -------
    numpy.ndarray
        ``(n, 3)`` float64 unit vectors.
    """
    n = int(n)
    if n < 1:
        raise InputError(f"the number of sphere points must be >= 1, got {n}")
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def rank_constraints(raw: np.ndarray, rendered: np.ndarray, channel: int) -> np.ndarray:
    """Unit difference vectors ``d̂`` of all sample pairs, oriented by rendered rank.

    [Gong2018] Eq. 4-5: for every pair ``(a, b)`` with ``P_k^a != P_k^b`` the vector ``d =
    sign(P_k^a - P_k^b) (ρ^a - ρ^b)`` must satisfy ``M_k · d > 0``.  Pairs with equal
    rendered values (ties, e.g. both clipped at 255) or (nearly) equal raws carry no order
    and are dropped.

    Parameters
    ----------
    raw : numpy.ndarray
        ``(n, 3)`` linear raws ρ.
    rendered : numpy.ndarray
        ``(n, 3)`` rendered values P.
    channel : int
        Output channel ``k`` (0, 1, 2).

    Returns
    -------
    numpy.ndarray
        ``(m, 3)`` float64 unit vectors, ``m <= n (n - 1) / 2``.
    """
    raw = np.asarray(raw, dtype=np.float64)
    p = np.asarray(rendered, dtype=np.float64)[:, channel]
    a, b = np.triu_indices(raw.shape[0], k=1)
    s = np.sign(p[a] - p[b])
    d = (raw[a] - raw[b]) * s[:, None]
    norm = np.linalg.norm(d, axis=1)
    keep = (s != 0) & (norm > 1e-9)
    return d[keep] / norm[keep, None]


def count_satisfied(directions: np.ndarray, constraints: np.ndarray) -> np.ndarray:
    """Number of half-space constraints ``u · d̂ > 0`` satisfied by each direction ``u``.

    The counting step of [Gong2018] §3.2, as one matrix product (in blocks).

    Parameters
    ----------
    directions : numpy.ndarray
        ``(q, 3)`` candidate rows.
    constraints : numpy.ndarray
        ``(m, 3)`` difference vectors (from :func:`rank_constraints`).

    Returns
    -------
    numpy.ndarray
        ``(q,)`` int64 counts.
    """
    u = np.asarray(directions, dtype=np.float64)
    d = np.asarray(constraints, dtype=np.float64)
    out = np.empty(u.shape[0], dtype=np.int64)
    step = max(1, _CHUNK // max(1, d.shape[0]))
    dt = d.T.copy()
    for s in range(0, u.shape[0], step):
        out[s:s + step] = np.count_nonzero(u[s:s + step] @ dt > 0.0, axis=1)
    return out


def _dot3(u: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """``u @ dt`` for ``(q, 3) @ (3, m)`` without BLAS (whose threads only add overhead at
    inner dimension 3 and compete with other work)."""
    p = u[:, 0:1] * dt[0]
    p += u[:, 1:2] * dt[1]
    p += u[:, 2:3] * dt[2]
    return p


def _median_direction(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Component-wise (weighted) median of unit vectors, renormalised."""
    if points.shape[0] == 1:
        return points[0].copy()
    if weights is None:
        med = np.median(points, axis=0)
    else:
        med = np.empty(3)
        for c in range(3):
            order = np.argsort(points[:, c], kind="stable")
            cw = np.cumsum(weights[order])
            med[c] = points[order[np.searchsorted(cw, 0.5 * cw[-1])], c]
    n = np.linalg.norm(med)
    if n < 1e-12:  # ties all round the sphere: no preferred direction
        return points[0].copy()
    return med / n


def _resolve_ties(ties: np.ndarray, weights, constraints: np.ndarray, best: int) -> np.ndarray:
    """Median of the tied directions ([Gong2018] §3.2); if the median falls outside the
    tie set (ties in separate regions), the tied direction nearest to it."""
    u = _median_direction(ties, weights)
    if count_satisfied(u[None], constraints)[0] >= best:
        return u
    return ties[int(np.argmax(ties @ u))].copy()


def _literal_row(constraints: np.ndarray, n_directions: int):
    dirs = fibonacci_sphere(n_directions)
    counts = count_satisfied(dirs, constraints)
    best = int(counts.max())
    row = _resolve_ties(dirs[counts == best], None, constraints, best)
    return row, best, n_directions


# ---- the fast search: branch and bound on a cube-map quadtree --------------------------

_FACES = np.array([  # (normal, first tangent, second tangent) per cube face
    [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
    [[-1, 0, 0], [0, 0, 1], [0, 1, 0]],
    [[0, 1, 0], [0, 0, 1], [1, 0, 0]],
    [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
    [[0, 0, 1], [1, 0, 0], [0, 1, 0]],
    [[0, 0, -1], [0, 1, 0], [1, 0, 0]],
], dtype=np.float64)


def _cube_dirs(face: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    f = _FACES[face]
    v = f[:, 0] + a[:, None] * f[:, 1] + b[:, None] * f[:, 2]
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _cells(face, a, b, half):
    """Centre directions and angular radii of square cells on the cube faces."""
    centre = _cube_dirs(face, a, b)
    cosmin = np.ones(face.size)
    for sa in (-1.0, 1.0):
        for sb in (-1.0, 1.0):
            corner = _cube_dirs(face, a + sa * half, b + sb * half)
            cosmin = np.minimum(cosmin, np.sum(centre * corner, axis=1))
    radius = np.arccos(np.clip(cosmin, -1.0, 1.0)) * 1.000001 + 1e-12
    return centre, radius


def _fast_row(constraints: np.ndarray, min_radius_deg: float = FAST_MIN_RADIUS_DEG,
              grid: int = 4):
    g = np.arange(grid)
    half0 = 1.0 / grid
    ga, gb = np.meshgrid(-1.0 + half0 * (2 * g + 1), -1.0 + half0 * (2 * g + 1),
                         indexing="ij")
    face = np.repeat(np.arange(6), grid * grid)
    a = np.tile(ga.ravel(), 6)
    b = np.tile(gb.ravel(), 6)
    half = np.full(face.size, half0)
    min_radius = math.radians(min_radius_deg)

    dt = constraints.T.copy()   # the constraints still undecided for the live cells
    base = 0                    # constraints satisfied by every live cell (dropped from dt)
    best, best_u = -1, None
    final_u, final_w, final_lb = [], [], []  # cells that are not split further
    evaluated = 0
    while face.size:
        u, r = _cells(face, a, b, half)
        prod = _dot3(u, dt)
        sr = np.sin(r)[:, None]
        lb = base + np.count_nonzero(prod > 0.0, axis=1)
        ub = base + np.count_nonzero(prod > -sr, axis=1)
        crossed = np.abs(prod) < sr
        uncertain = np.count_nonzero(crossed, axis=1)
        evaluated += face.size
        top = int(lb.max())
        if top > best:
            best, best_u = top, u[lb == top]
        elif top == best:
            best_u = np.concatenate([best_u, u[lb == top]])
        alive = ub >= best
        split = alive & (uncertain > 0) & (r > min_radius)
        stop = alive & ~split
        final_u.append(u[stop])
        final_w.append(r[stop] ** 2)
        final_lb.append(lb[stop])
        if not split.any():
            break
        # constraints decided (same sign over the whole cap) for every cell to be split
        # stay decided for their children: count them once and drop them
        ps, ss = prod[split], sr[split]
        sat_all = np.all(ps >= ss, axis=0)
        undecided = np.any(crossed[split], axis=0) | ~(sat_all | np.all(ps <= -ss, axis=0))
        base += int(np.count_nonzero(sat_all & ~undecided))
        dt = dt[:, undecided]
        face, a, b, half = face[split], a[split], b[split], half[split] / 2.0
        # four children per split cell
        face = np.repeat(face, 4)
        a = np.repeat(a, 4) + np.tile([-1.0, -1.0, 1.0, 1.0], a.size) * np.repeat(half, 4)
        b = np.repeat(b, 4) + np.tile([-1.0, 1.0, -1.0, 1.0], b.size) * np.repeat(half, 4)
        half = np.repeat(half, 4)
    us = np.concatenate(final_u)
    ws = np.concatenate(final_w)
    lbs = np.concatenate(final_lb)
    tie = lbs == best
    if tie.any():
        row = _resolve_ties(us[tie], ws[tie], constraints, best)
    else:  # the best centres were split and no leaf centre hit the best count again
        assert best_u is not None       # set on the first pass (any count beats -1)
        row = _resolve_ties(best_u, None, constraints, best)
    return row, best, evaluated


def rank_based_row(raw: np.ndarray, rendered: np.ndarray, channel: int, *,
                   method: str = "fast", n_directions: int = LITERAL_DIRECTIONS) -> dict:
    """One unit row ``M_k`` of the colour matrix from rank-order constraints.

    [Gong2018] §3.2, Eq. 4-8 (see the module docstring for the two searches).

    Parameters
    ----------
    raw, rendered : numpy.ndarray
        ``(n, 3)`` samples (typically 200, [Gong2018] §3.2).
    channel : int
    method : {"fast", "literal"}
    n_directions : int
        Directions of the literal search.

    Returns
    -------
    dict
        ``row`` (unit 3-vector), ``satisfied`` (constraints it satisfies), ``best``
        (largest count found), ``constraints`` (their number), ``evaluated`` (directions
        whose counts were computed).
    """
    d = rank_constraints(raw, rendered, channel)
    if d.shape[0] < 3:
        raise CalibrationError(
            f"channel {channel}: only {d.shape[0]} ordered sample pairs; the rendered "
            "values barely vary -- give samples that cover dark to bright colours")
    if method == "literal":
        row, best, evaluated = _literal_row(d, n_directions)
    elif method == "fast":
        row, best, evaluated = _fast_row(d)
    else:
        raise InputError(f"method must be 'fast' or 'literal', got {method!r}")
    satisfied = int(count_satisfied(row[None], d)[0])
    return {"row": row, "satisfied": satisfied, "best": int(best),
            "constraints": int(d.shape[0]), "evaluated": int(evaluated)}


def rank_based_matrix(raw: npt.ArrayLike, rendered: npt.ArrayLike, *, method: str = "fast",
                      n_directions: int = LITERAL_DIRECTIONS, return_info: bool = False
                      ) -> np.ndarray | tuple[np.ndarray, list[dict]]:
    """The colour correction matrix ``M`` up to row scales, from rank order.

    [Gong2018] §3.2, Eq. 4-8: each row ``M_k`` is the unit direction satisfying the most
    half-space constraints ``M_k · (ρ^a - ρ^b) > 0`` over the sample pairs with ``P_k^a >
    P_k^b``; the median of tied directions is taken. Rows are returned with unit length;
    :func:`row_scales` fixes their lengths.

    Parameters
    ----------
    raw : array_like
        ``(n, 3)`` linear camera RGB ρ ([Gong2018] uses ``n = 200`` random samples).
    rendered : array_like
        ``(n, 3)`` rendered RGB P in ``[0, 1]``.
    method : {"fast", "literal"}
        ``"literal"``: 100,000 Fibonacci-sphere directions counted by a matrix product (the
        published search); ``"fast"``: exact branch-and-bound on a cube-map quadtree,
        reaching the literal count or a higher one at a fraction of the cost.
    n_directions : int
        Directions of the literal search.
    return_info : bool
        Also return per-row search information.

    Returns
    -------
    numpy.ndarray or (numpy.ndarray, list of dict)
        ``(3, 3)`` matrix with unit rows; with ``return_info`` also the dicts of
        :func:`rank_based_row` (``satisfied``, ``best``, ``constraints``, ``evaluated``).

    Raises
    ------
    CalibrationError
        When a channel has too few ordered pairs.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> raw = rng.uniform(0, 1, (200, 3))
    >>> m_true = np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]])
    >>> m = rank_based_matrix(raw, np.clip(raw @ m_true.T, 0, 1) ** 0.45)
    >>> bool(np.all(np.sum(m * m_true / np.linalg.norm(m_true, axis=1, keepdims=True),
    ...                    axis=1) > 0.999))
    True
    """
    raw = np.asarray(raw, dtype=np.float64)
    rendered = np.asarray(rendered, dtype=np.float64)
    rows, info = [], []
    for k in range(3):
        r = rank_based_row(raw, rendered, k, method=method, n_directions=n_directions)
        rows.append(r.pop("row"))
        info.append(r)
    m = np.stack(rows)
    return (m, info) if return_info else m


def row_scales(unit_matrix: np.ndarray, raw: np.ndarray) -> np.ndarray:
    """Row lengths of ``M``: the brightest training sample maps to 1 in every channel.

    Rank order determines each row of ``M`` only up to a positive factor ([Gong2018]
    §3.2, Eq. 6: ``α M_k`` satisfies the same constraints).  selfcal fixes it so that
    ``max_i M_k ρ_i = 1`` over the training raws: the colour-corrected values then span
    about ``[0, 1]`` like the rendered values, and the tone curve of Eq. 9 maps the
    brightest training colour of each channel to its rendered value.

    Parameters
    ----------
    unit_matrix : numpy.ndarray
        ``(3, 3)`` rows of unit length (from :func:`rank_based_matrix`).
    raw : numpy.ndarray
        ``(n, 3)`` training raws.

    Returns
    -------
    numpy.ndarray
        ``(3,)`` positive scales ``s_k``; ``M = diag(s) @ unit_matrix``.

    Raises
    ------
    CalibrationError
        When a row makes every training sample non-positive.
    """
    top = np.max(np.asarray(raw, dtype=np.float64) @ unit_matrix.T, axis=0)
    if np.any(top <= 1e-9):
        k = int(np.argmin(top))
        raise CalibrationError(f"colour matrix row {k} maps every sample to a value <= 0; "
                               "the samples do not constrain the matrix")
    return 1.0 / top
