"""``python bench/bench_export_cube.py --tune``: candidate render shapers and 3D node
values at 33³, on the tuning image alone.  ``--where``: where the shipped table's
pixels beyond 0.005 lie, on every bench image.

The NUS Nikon D7000 model (white balance 14) and the tuning image
``sony_ilce6400/scene1/DSC04141.JPG`` of ``bench_export_shaper`` (its ``prepare``: the
render of the raw selfcal's ``to_raw`` gives for the JPEG, in-range pixels, within 0.005).
Tables are applied by selfcal's own interpolation (:func:`selfcal.export.shaper.
apply_shaper_lut`, tetrahedral, equal to OpenColorIO's to 1e-6; trilinear here for the
interpolation rows).  Candidates (ours unless a source is named):

- ``log2``: the shipped shaper, ``log2(1 + x/ε_c)`` with the knee where the model's tone
  curve reaches a share of its output (``f_c(ε_c M_cc) = q``), q swept;
- ``log2`` with one channel's knee moved (the others at the shipped q);
- ``power``: density ``(x + ε_c)^-β`` instead of the log's ``1/(x + ε_c)``: for a tone
  curve ``e^γ`` the L∞-optimal knots of piecewise-linear interpolation have density
  ``|f''|^(1/2) ∝ e^(γ/2 - 1)`` (de Boor, *A Practical Guide to Splines*, ch. III), and
  the D7000's curves have ``γ ≈ 0.55-0.6`` between codes 64 and 192, so ``β ≈ 0.7``;
- ``neutral log2``: one knee for all channels, on the model's neutral axis
  ``ρ = t · M⁻¹ 1``, so that neutrals run along the cube's diagonal (the edge every
  tetrahedron shares); the shaper reaches 1 on the channel with the smallest ``M⁻¹ 1``;
- ``tone curve``: the model's own tone curve as the shaper, ``s_c(x) = f_c(x / n_c)`` on
  the neutral scaling ``n = M⁻¹ 1`` (its linear toe kept as it is), continued beyond
  neutral white at its end slope (density ``f'``);
- ``tone curvature``: density ``|d²f_c(x / n_c)/dx²|^α`` on the neutral scaling ``n =
  M⁻¹ 1`` (``f`` Gaussian-smoothed, σ = 1/256, as the D7000's is piecewise linear), plus
  a floor of 0.05 of its mean (zero curvature beyond white would leave no nodes there);
- ``de Boor``: one step of de Boor's knot placement with the model's own measured error:
  the 33³ table's largest-channel error against ``render_exact`` at two random points per
  cell, its RMS per slab of each axis, knots moved to equidistribute
  ``RMS^(1/2) / width`` per slab;
- node values by least squares (lattice regression, [GarciaGupta2009]'s fit of a
  lattice to samples, here the model's): on the same log2 shaper,
  (a) fitted to a cheap in-cell model (the raw2jpg RBF ``h`` interpolated trilinearly in
  raw between the nodes, exact for an affine ``h``, then the tone curve), 4³ samples per
  cell over the whole cube (seconds); (b) fitted to ``render_exact`` at k³ points per cell
  in the cells the tuning image reaches only: an upper bound for any node values on this
  shaper, since it uses the image (a whole-cube fit at 3³ per cell needs 885,000 RBF
  evaluations);
- the shipped tables read with trilinear instead of tetrahedral interpolation.

The failing pixels of the shipped table are then described (output channel, level).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.ndimage import gaussian_filter1d
from scipy.sparse.linalg import cg, lsqr

from common import data_dir, table

import selfcal
from bench_export_shaper import bench_images, prepare, score
from selfcal.export.shaper import (DEFAULT_SHAPER_SIZE, ShaperLUT, _normalise, _tetrahedra,
                                   _tone, apply_shaper_lut, render_knees)

SIZE = 33
X = np.linspace(0.0, 1.0, DEFAULT_SHAPER_SIZE)
CORNERS = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])


def knees_at(model, q: float) -> np.ndarray:
    import selfcal.export.shaper as export_shaper

    kept = export_shaper.KNEE_OUTPUT
    try:
        export_shaper.KNEE_OUTPUT = q
        return render_knees(model)
    finally:
        export_shaper.KNEE_OUTPUT = kept


def log2_shaper(eps) -> np.ndarray:
    return _normalise(np.log2(1.0 + X[:, None] / eps) / np.log2(1.0 + 1.0 / eps))


def power_shaper(eps, beta: float) -> np.ndarray:
    return _normalise((X[:, None] + eps) ** (1.0 - beta) - eps ** (1.0 - beta))


def neutral_log2_shaper(model, q: float) -> np.ndarray:
    neutral = np.linalg.solve(np.asarray(model.matrix, dtype=np.float64), np.ones(3))
    e = np.linspace(0.0, 1.0, 65537)
    f = _tone(model, np.repeat(e[:, None], 3, axis=1))
    eps = np.mean([e[np.argmax(f[:, c] >= f[0, c] + q * (f[-1, c] - f[0, c]))]
                   for c in range(3)])
    s = np.log2(1.0 + X[:, None] / (neutral * eps))
    return 0.999 * s / s.max() + 0.001 * X[:, None]


def tone_shaper(model) -> np.ndarray:
    e = X[:, None] / np.linalg.solve(np.asarray(model.matrix, dtype=np.float64), np.ones(3))
    end = _tone(model, np.array([[1.0] * 3, [1.0 - 1.0 / 256] * 3]))
    slope = (end[0] - end[1]) * 256
    return _normalise(_tone(model, np.clip(e, 0.0, 1.0)) + slope * np.maximum(e - 1.0, 0.0))


def curvature_shaper(model, alpha: float) -> np.ndarray:
    neutral = np.linalg.solve(np.asarray(model.matrix, dtype=np.float64), np.ones(3))
    e = np.linspace(0.0, 1.0, 65537)
    f = gaussian_filter1d(_tone(model, np.repeat(e[:, None], 3, axis=1)), 256, axis=0)
    d2 = np.abs(np.gradient(np.gradient(f, e, axis=0), e, axis=0))
    s = np.empty((X.size, 3))
    for c in range(3):
        w = np.interp(np.clip(X / neutral[c], 0, 1), e, d2[:, c]) ** alpha
        w = w * (X <= neutral[c])
        w = w / w.mean() + 0.05
        s[:, c] = np.concatenate([[0.0], np.cumsum((w[1:] + w[:-1]) / 2)])
    return _normalise(s)


def node_raw(shaper: np.ndarray) -> np.ndarray:
    """``(SIZE, 3)``: the raw of the 3D nodes per axis (the shaper's preimages)."""
    u = np.linspace(0.0, 1.0, SIZE)
    return np.stack([np.interp(u, shaper[:, c], X) for c in range(3)], axis=1)


def inner_outer(model):
    """The NUS render split as ``f(clip(h(T ρ)))``: (h∘T, f∘clip)."""
    cam = model.camera
    rbf, transform = cam._maps["raw2jpg"], cam.transform
    return (lambda rho: rbf(rho @ transform.T)), (lambda e: cam.tone(np.clip(e, 0.0, 1.0)))


def sampled(model, shaper: np.ndarray):
    """The table at the nodes (what ``shaper_lut`` writes), and ``h`` at the nodes."""
    pre = node_raw(shaper)
    grid = np.stack(np.meshgrid(*pre.T, indexing="ij"), axis=-1).reshape(-1, 3)
    inner, outer = inner_outer(model)
    h = inner(grid)
    return ShaperLUT("render", shaper, outer(h).reshape((SIZE,) * 3 + (3,)), ""), pre, h


def apply_chunked(lut: ShaperLUT, x: np.ndarray, trilinear: bool = False) -> np.ndarray:
    flat = x.reshape(-1, 3)
    out = np.empty_like(flat)
    for s in range(0, flat.shape[0], 1 << 20):
        chunk = flat[s:s + (1 << 20)]
        out[s:s + chunk.shape[0]] = (apply_trilinear(lut, chunk) if trilinear
                                     else apply_shaper_lut(lut, chunk))
    return out.reshape(x.shape)


def apply_trilinear(lut: ShaperLUT, x: np.ndarray) -> np.ndarray:
    u = np.stack([np.interp(x[:, c], X, lut.shaper[:, c]) for c in range(3)], axis=1)
    p = u * (SIZE - 1)
    base = np.minimum(np.floor(p), SIZE - 2).astype(np.int64)
    frac = p - base
    out = np.zeros_like(x)
    for corner in CORNERS:
        w = np.prod(np.where(corner == 1, frac, 1.0 - frac), axis=1)
        i = base + corner
        out += w[:, None] * lut.table[i[:, 0], i[:, 1], i[:, 2]]
    return out


def deboor_step(model, lut: ShaperLUT, pre: np.ndarray, seed: int = 7) -> np.ndarray:
    """One knot move per axis from the table's measured error (see the docstring)."""
    m = SIZE - 1
    cells = np.stack(np.meshgrid(*[np.arange(m)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = np.repeat(cells, 2, axis=0)
    u = (cells + np.random.default_rng(seed).random(cells.shape)) / m
    rho = np.stack([np.interp(u[:, c], lut.shaper[:, c], X) for c in range(3)], axis=1)
    err = np.abs(apply_shaper_lut(lut, rho) - model.render_exact(rho)).max(axis=1)
    new = np.empty_like(lut.shaper)
    for c in range(3):
        rms = np.sqrt(np.bincount(cells[:, c], err ** 2, m) / np.bincount(cells[:, c], None, m))
        # density RMS^(1/2) / width over a slab of that width: its share is RMS^(1/2)
        cum = np.concatenate([[0.0], np.cumsum(np.sqrt(rms))])
        knots = np.interp(np.linspace(0.0, 1.0, SIZE), cum / cum[-1], pre[:, c])
        new[:, c] = np.interp(X, knots, np.linspace(0.0, 1.0, SIZE))
    return new


def _element(k: int):
    """Tetrahedral weights of k³ points per cell, and the cell's 8×8 Gram matrix."""
    fr = (np.arange(k) + 0.5) / k
    q = np.stack(np.meshgrid(fr, fr, fr, indexing="ij"), -1).reshape(-1, 3)
    idx, w = _tetrahedra(q, 2)                       # corners as 4 a + 2 b + c
    gram = np.zeros((8, 8))
    for j in range(4):
        for jj in range(4):
            np.add.at(gram, (idx[:, j], idx[:, jj]), w[:, j] * w[:, jj])
    return fr, idx, w, gram


def fit_cheap(model, lut: ShaperLUT, pre: np.ndarray, h: np.ndarray, k: int = 4):
    """Node values by least squares to the in-cell model over the whole cube (a)."""
    m, n = SIZE - 1, SIZE
    fr, idx, w, gram = _element(k)
    weights = []
    for c in range(3):                   # trilinear in raw between the nodes, per axis
        rho = np.interp(((np.arange(m)[:, None] + fr) / m).ravel(), lut.shaper[:, c], X)
        cell = np.repeat(np.arange(m), k)
        t = (rho - pre[cell, c]) / (pre[cell + 1, c] - pre[cell, c])
        wc = np.zeros((rho.size, n))
        wc[np.arange(rho.size), cell], wc[np.arange(rho.size), cell + 1] = 1 - t, t
        weights.append(wc)
    hh = np.einsum("ai,ijkd->ajkd", weights[0], h.reshape(n, n, n, 3))
    hh = np.einsum("bj,ajkd->abkd", weights[1], hh)
    hh = np.einsum("ck,abkd->abcd", weights[2], hh)
    target = inner_outer(model)[1](hh).reshape(m, k, m, k, m, k, 3)
    rhs = np.zeros((n, n, n, 3))
    qi = np.stack(np.meshgrid(*[np.arange(k)] * 3, indexing="ij"), -1).reshape(-1, 3)
    for s, (a, b, c) in enumerate(qi):
        block = target[:, a, :, b, :, c, :]
        for j in range(4):
            o = CORNERS[idx[s, j]]
            rhs[o[0]:o[0] + m, o[1]:o[1] + m, o[2]:o[2] + m] += w[s, j] * block
    cells = np.stack(np.meshgrid(*[np.arange(m)] * 3, indexing="ij"), -1).reshape(-1, 3)
    base = (cells[:, 0] * n + cells[:, 1]) * n + cells[:, 2]
    off = CORNERS @ np.array([n * n, n, 1])
    rows, cols = np.nonzero(gram)
    k_mat = sp.csr_matrix((np.repeat(gram[rows, cols], base.size),
                           (np.concatenate([base + off[r] for r in rows]),
                            np.concatenate([base + off[c] for c in cols]))),
                          shape=(n ** 3, n ** 3))
    pre_cond = sp.diags(1.0 / k_mat.diagonal())
    start = lut.table.reshape(-1, 3)
    out = np.stack([cg(k_mat, rhs.reshape(-1, 3)[:, c], x0=start[:, c], M=pre_cond,
                       rtol=1e-10, maxiter=500)[0] for c in range(3)], axis=1)
    return ShaperLUT("render", lut.shaper, np.clip(out, 0, 1).reshape(lut.table.shape), "")


def fit_on_image_cells(model, lut: ShaperLUT, x: np.ndarray, k: int):
    """Node values by least squares to ``render_exact`` in the image's cells (b)."""
    u = np.stack([np.interp(x[:, c], X, lut.shaper[:, c]) for c in range(3)], axis=1)
    cell = np.minimum(np.floor(u * (SIZE - 1)), SIZE - 2).astype(np.int64)
    cells = np.unique(cell, axis=0)
    fr = (np.arange(k) + 0.5) / k
    q = np.stack(np.meshgrid(fr, fr, fr, indexing="ij"), -1).reshape(-1, 3)
    us = ((cells[:, None, :] + q[None]) / (SIZE - 1)).reshape(-1, 3)
    rho = np.stack([np.interp(us[:, c], lut.shaper[:, c], X) for c in range(3)], axis=1)
    target = model.render_exact(rho)
    idx, w = _tetrahedra(us, SIZE)
    a = sp.csr_matrix((w.ravel(), (np.repeat(np.arange(us.shape[0]), 4), idx.ravel())),
                      shape=(us.shape[0], SIZE ** 3))
    used = np.unique(idx)
    a = a[:, used]
    flat = lut.table.reshape(-1, 3).copy()
    for c in range(3):
        flat[used, c] += lsqr(a, target[:, c] - a @ flat[used, c], atol=1e-12, btol=1e-12,
                              iter_lim=2000)[0]
    fitted = np.clip(flat, 0, 1).reshape(lut.table.shape)
    return ShaperLUT("render", lut.shaper, fitted, ""), cells.shape[0], rho.shape[0]


def failing(out: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> str:
    """Which output channel is worst on the pixels beyond 0.005, and their levels."""
    err = np.abs(out - ref)[mask]
    bad = err.max(axis=1) > 0.005
    share = np.bincount(err[bad].argmax(axis=1), minlength=3) / max(bad.sum(), 1)
    level = np.percentile(ref[mask][bad].max(axis=1), [10, 50, 90])
    return (f"{bad.sum()} of {mask.sum()} in-range pixels beyond 0.005; worst channel "
            f"r/g/b {100 * share[0]:.0f}/{100 * share[1]:.0f}/{100 * share[2]:.0f} %; "
            f"their brightest output channel at the 10/50/90th percentile "
            + " / ".join(f"{v:.2f}" for v in level))


def failing_row(out: np.ndarray, ref: np.ndarray, mask: np.ndarray) -> list:
    """:func:`failing` as table cells."""
    err = np.abs(out - ref)[mask]
    bad = err.max(axis=1) > 0.005
    share = np.bincount(err[bad].argmax(axis=1), minlength=3) / max(bad.sum(), 1)
    level = np.percentile(ref[mask][bad].max(axis=1), [10, 50, 90])
    return [f"{100 * np.mean(~bad):.2f}", f"{bad.sum()}",
            "/".join(f"{100 * v:.0f}" for v in share), " / ".join(f"{v:.2f}" for v in level)]


def main_where() -> None:
    """``--where``: the pixels beyond 0.005 of the shipped render table at 33³ on every
    bench image (a description, not a choice: nothing is chosen from it)."""
    from selfcal.export.shaper import shaper_lut

    model = selfcal.load_model(data_dir("nus_model_nikon_d7000"))
    lut = shaper_lut(model, "render", size=SIZE)
    rows = []
    for fr in prepare(model, bench_images()):
        out = apply_chunked(lut, fr["raw16"] / 65535.0)
        rows.append([fr["split"], fr["label"],
                     *failing_row(out, fr["render"], fr["mask"]["render"])])
    print("render 33³ (the shipped shaper), in-range pixels beyond 0.005: how many, which "
          "output channel is worst on them, and their brightest output channel")
    print(table(["split", "image", "% within", "pixels beyond", "worst channel r/g/b %",
                 "brightest channel p10 / p50 / p90"], rows))


def main_tune() -> None:
    import time

    import selfcal.export.shaper as export_shaper

    model = selfcal.load_model(data_dir("nus_model_nikon_d7000"))
    fr = prepare(model, bench_images()[:1])[0]
    mask, ref = fr["mask"]["render"], fr["render"]
    x = fr["raw16"] / 65535.0
    chosen = export_shaper.KNEE_OUTPUT
    rows = []

    def row(name, lut, build, trilinear=False, note=""):
        rows.append([name, *score(apply_chunked(lut, x, trilinear), ref, mask),
                     f"{build:.1f}", note])

    def timed(fn, *args):
        t0 = time.perf_counter()
        return fn(*args), time.perf_counter() - t0

    for q in (0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5):
        eps = knees_at(model, q)
        (lut, pre, h), build = timed(sampled, model, log2_shaper(eps))
        row(f"log2, knee q={q:g}" + (" (shipped)" if q == chosen else ""), lut, build,
            note="knees at raw " + " ".join(f"{e:.4f}" for e in eps))
        if q == chosen:
            shipped, shipped_pre, shipped_h = lut, pre, h
    eps = knees_at(model, chosen)
    for c, channel in enumerate("rgb"):   # one channel's knee moved, the others kept
        for q in (0.2, 0.3):
            one = eps.copy()
            one[c] = knees_at(model, q)[c]
            lut, build = timed(lambda: sampled(model, log2_shaper(one))[0])
            row(f"log2, knee q={chosen:g}, {channel} at q={q:g}", lut, build)
    for beta in (0.9, 0.8, 0.7):
        lut, build = timed(lambda: sampled(model, power_shaper(eps, beta))[0])
        row(f"power, beta={beta:g}, knee q={chosen:g}", lut, build)
    for q in (0.25, 0.3):
        lut, build = timed(lambda: sampled(model, neutral_log2_shaper(model, q))[0])
        row(f"neutral log2, knee q={q:g}", lut, build)
    lut, build = timed(lambda: sampled(model, tone_shaper(model))[0])
    row("tone curve f_c (neutral scaling)", lut, build)
    for alpha in (1 / 2, 1 / 3):
        lut, build = timed(lambda: sampled(model, curvature_shaper(model, alpha))[0])
        row(f"tone curvature, alpha={alpha:.2f}", lut, build)
    new, build = timed(deboor_step, model, shipped, shipped_pre)
    lut, more = timed(lambda: sampled(model, new)[0])
    row("de Boor step from the shipped shaper", lut, build + more)
    lut, build = timed(fit_cheap, model, shipped, shipped_pre, shipped_h)
    row("shipped shaper, nodes fitted to the in-cell model (a)", lut, build)
    for k in (3, 5):
        (lut, cells, evals), build = timed(fit_on_image_cells, model, shipped,
                                           x[mask].reshape(-1, 3), k)
        row(f"shipped shaper, nodes fitted in the image's cells, {k}³ (b)", lut, build,
            note=f"{cells} cells, {evals} RBF evaluations; uses the image")
    row("shipped tables, trilinear", shipped, 0.0, trilinear=True)
    print(f"render 33³ on the tuning image {fr['label']} (in-range pixels), applied by "
          "selfcal's own interpolation (tetrahedral unless said)")
    print(table(["candidate", "% within", "p99", "worst", "build s", "note"], rows))
    print()
    print("shipped table: " + failing(apply_chunked(shipped, x), ref, mask))
