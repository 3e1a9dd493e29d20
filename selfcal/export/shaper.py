"""A camera pipeline as a shaper LUT: a 1D table per channel, then a 3D table.

A 3D table sampled on a uniform grid of its input is coarse where the model is steep
(:mod:`selfcal.export`: the ``render`` direction's tone curve takes the darkest 1/32 of
linear raw to half the output range).  The colour industry's answer is a *shaper*: a
per-channel 1D table ``s`` applied first, so that the 3D table ``T`` is sampled on a
uniform grid of ``u = s(x)``, which puts its nodes where the model bends::

    out = T(s_r(r), s_g(g), s_b(b))

Both tables are written to one file (:func:`write_shaper_cube`: the DaVinci Resolve
``.cube`` layout ``[RESOLVE]``, ``LUT_1D_SIZE`` / ``LUT_1D_INPUT_RANGE`` /
``LUT_3D_SIZE`` / ``LUT_3D_INPUT_RANGE``, the 1D rows then the 3D rows, red fastest;
or the Common LUT Format, :mod:`selfcal.export.clf`).

The shaper is chosen from the model (ours):

``render`` (linear raw -> rendered)
    ``s_c(x) = log2(1 + x / ε_c) / log2(1 + 1 / ε_c)``: a log2 curve whose knee ``ε_c``
    is where the model's own tone curve ``f`` reaches a quarter of its output
    (``f_c(ε_c M_cc) = 1/4``, with ``M`` the model's colour matrix: ``M_cc`` scales raw
    channel ``c`` into the tone curve's input).  Below the knee nodes are spaced
    linearly, above it logarithmically: dense in the toe, where the tone curve rises
    fastest, without leaving the mid-tones (where the gamut map bends) too coarse.
``to-raw`` (rendered -> linear raw)
    ``s_c(P) = e_c(P)^0.6`` with ``e_c`` the model's inverse response ``f⁻¹``
    [Lin2011] [Gong2018] normalised to ``[0, 1]``, and 0.6 the spacing the model's own
    dense backward table uses (:data:`selfcal.pipeline.model.SHAPER_GAMMA`, nodes at
    ``e = u^(1/0.6)``): the 3D table then holds only the colour part of the model
    (``M⁻¹ h⁻¹(e)``, or ``M⁻¹ e`` plus the lattice correction), on the grid the model
    itself was baked on, while the steep climb of ``f⁻¹`` over the last codes stays in
    the 1D table.  (The power 0.6 against 1: docs/decisions.md, "The render shaper's
    knee: output 1/4".)

Either shaper is blended with the identity (``0.999 s + 0.001 x``) so that it is strictly
increasing (a flat stretch would merge inputs the model tells apart).  The shaper is a
piecewise-linear table (``shaper_size`` nodes, uniform on ``[0, 1]``), and the 3D nodes
sit at the exact preimages of the uniform ``u`` grid through that table, so a reader
interpolating both tables linearly reproduces the model at every 3D node.  Node values
are the model's ``render`` (its reference evaluation ``render_exact`` where it has one)
or ``to_raw``.

References
----------
.. [RESOLVE] P. Chamberlain (Blackmagic Design), "LUT documentation (to create from another
   program)", DaVinci Resolve forum, 2015: the .cube layout with LUT_1D_INPUT_RANGE /
   LUT_3D_INPUT_RANGE and a 1D table before a 3D one.
.. [Lin2011] H. Lin, S. J. Kim, S. Süsstrunk and M. S. Brown, "Revisiting Radiometric
   Calibration for Color Computer Vision", ICCV 2011.
.. [Gong2018] H. Gong et al., "Rank-based radiometric calibration", BMVC 2018: the
   RAW-path pipeline model of :mod:`selfcal.pipeline` (colour matrix, tone curves ``f`` and
   ``f⁻¹``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.images import atomic_output, check_output_path
from .cube import cube_title
from ..pipeline.model import SHAPER_GAMMA

__all__ = ["ShaperLUT", "SHAPER_DIRECTIONS", "DEFAULT_SHAPER_SIZE", "shaper_curve",
           "shaper_lut", "write_shaper_cube", "write_ffmpeg_cubes", "apply_shaper_lut"]

SHAPER_DIRECTIONS = ("to-raw", "render")
#: Nodes of the 1D shaper unless asked otherwise: 16 per 8-bit code, and one on each code.
DEFAULT_SHAPER_SIZE = 255 * 16 + 1
#: The tone-curve output at which the render shaper's log2 knee sits (ours; chosen on the
#: tuning image, docs/decisions.md, "The render shaper's knee: output 1/4").
KNEE_OUTPUT = 0.25
#: Weight of the identity blended into a shaper so that it is strictly increasing.
IDENTITY_BLEND = 1e-3
#: Sizes the Resolve .cube layout allows (1D, 3D).
SHAPER_LIMITS = {1: (2, 65536), 3: (2, 256)}


@dataclass
class ShaperLUT:
    """A 1D shaper and the 3D table that follows it.

    Attributes
    ----------
    direction : str
        ``"to-raw"`` or ``"render"``.
    shaper : numpy.ndarray
        ``(n1, 3)`` float64: the shaper per channel at ``linspace(0, 1, n1)``, from 0 to
        1, strictly increasing.
    table : numpy.ndarray
        ``(n, n, n, 3)`` float64 indexed ``[r, g, b]``: the model at the shaper's
        preimages of ``linspace(0, 1, n)`` per axis.
    kind : str
        How the shaper was chosen (said in the files).
    """

    direction: str
    shaper: np.ndarray
    table: np.ndarray
    kind: str

    @property
    def size(self) -> int:
        return int(self.table.shape[0])

    def rows_red_fastest(self) -> np.ndarray:
        """The 3D table as ``(n³, 3)`` rows, red index varying fastest (``.cube``)."""
        return np.transpose(self.table, (2, 1, 0, 3)).reshape(-1, 3)

    def rows_blue_fastest(self) -> np.ndarray:
        """The 3D table as ``(n³, 3)`` rows, blue index varying fastest (CLF ``LUT3D``)."""
        return self.table.reshape(-1, 3)


def _is_nus(model) -> bool:
    return hasattr(model, "camera") and hasattr(model, "render_exact")


def _tone(model, x: np.ndarray) -> np.ndarray:
    """The model's forward tone curve ``f`` per channel at ``(..., 3)`` input."""
    if _is_nus(model):
        return np.asarray(model.camera.tone(x), dtype=np.float64)
    return np.asarray(model.tone_curves(x), dtype=np.float64)


def _inverse_tone(model, p: np.ndarray) -> np.ndarray:
    """The model's inverse tone curve ``f⁻¹`` per channel at ``(..., 3)`` input."""
    return np.asarray(model.inverse_tone_curves(p), dtype=np.float64)


def _normalise(s: np.ndarray) -> np.ndarray:
    """Per column: from 0 to 1, blended with the identity (strictly increasing)."""
    s = s - s[:1]
    span = s[-1:]
    if np.any(~np.isfinite(s)) or np.any(span <= 0):
        raise InputError("the model's curve does not rise over [0, 1]: no shaper can be "
                         "made from it")
    s = np.maximum.accumulate(s / span, axis=0)
    x = np.linspace(0.0, 1.0, s.shape[0])[:, None]
    return (1.0 - IDENTITY_BLEND) * s + IDENTITY_BLEND * x


def render_knees(model) -> np.ndarray:
    """``ε_c``: the raw at which the model's tone curve reaches :data:`KNEE_OUTPUT`
    (``f_c(ε_c M_cc) = 1/4``), clipped to ``[1e-4, 0.5]`` (ours)."""
    lin = np.linspace(0.0, 1.0, 65537)
    tone = _tone(model, np.repeat(lin[:, None], 3, axis=1))
    knees = np.empty(3)
    diag = np.abs(np.diag(np.asarray(model.matrix, dtype=np.float64)))
    for c in range(3):
        reach = np.flatnonzero(tone[:, c] >= tone[0, c] + KNEE_OUTPUT
                               * (tone[-1, c] - tone[0, c]))
        at = lin[reach[0]] if reach.size else 0.05
        knees[c] = at / max(diag[c], 1e-6)
    return np.clip(knees, 1e-4, 0.5)


def shaper_curve(model, direction: str, size: int = DEFAULT_SHAPER_SIZE):
    """The shaper the model gets (see the module docstring).

    Returns
    -------
    shaper : numpy.ndarray
        ``(size, 3)`` at ``linspace(0, 1, size)``, strictly increasing from 0 to 1.
    kind : str
        A one-line description, written into the files.
    """
    x = np.linspace(0.0, 1.0, int(size))
    if direction == "render":
        eps = render_knees(model)
        s = np.log2(1.0 + x[:, None] / eps[None, :]) / np.log2(1.0 + 1.0 / eps[None, :])
        kind = ("log2 shaper, knees at raw " + " ".join(f"{e:.5f}" for e in eps)
                + f" (the model's tone curve at {KNEE_OUTPUT:g} of its output)")
        return _normalise(s), kind
    if direction == "to-raw":
        e = _normalise(_inverse_tone(model, np.repeat(x[:, None], 3, axis=1)))
        return (_normalise(e ** SHAPER_GAMMA),
                f"shaper: the model's inverse response f^-1, normalised, to the power "
                f"{SHAPER_GAMMA:g}")
    raise InputError(f"a shaper LUT is made for 'to-raw' or 'render', not {direction!r}")


def check_shaper_sizes(size, shaper_size) -> tuple[int, int]:
    """``(size, shaper_size)`` as ints, or InputError naming the bad one."""
    for value, dims in ((size, 3), (shaper_size, 1)):
        lo, hi = SHAPER_LIMITS[dims]
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) \
                or not lo <= value <= hi:
            raise InputError(f"LUT_{dims}D_SIZE must be a whole number from {lo} to {hi}, "
                             f"not {value!r}")
    return int(size), int(shaper_size)


def shaper_lut(model, direction: str, *, size: int = 33,
               shaper_size: int = DEFAULT_SHAPER_SIZE) -> ShaperLUT:
    """The shaper and 3D table of a pipeline model (see the module docstring).

    Parameters
    ----------
    model : PipelineModel
        A fitted RAW-path model or an NUS model folder (:func:`selfcal.load_model`).
    direction : {"to-raw", "render"}
        ``to-raw``: rendered ``code/255`` -> linear camera raw in ``[0, 1]``;
        ``render``: linear camera raw in ``[0, 1]`` (black 0, white 1) -> rendered
        ``code/255``.
    size : int
        Nodes per axis of the 3D table (2-256).
    shaper_size : int
        Nodes of the 1D shaper (2-65536).

    Returns
    -------
    ShaperLUT
    """
    if direction not in SHAPER_DIRECTIONS:
        raise InputError(f"a shaper LUT is made for 'to-raw' or 'render', not {direction!r}")
    if not (hasattr(model, "to_raw") and hasattr(model, "render")):
        raise InputError(f"a shaper LUT needs a RAW-path (pipeline) model, not a "
                         f"{type(model).__name__}")
    size, shaper_size = check_shaper_sizes(size, shaper_size)
    shaper, kind = shaper_curve(model, direction, shaper_size)
    x = np.linspace(0.0, 1.0, shaper_size)
    u = np.linspace(0.0, 1.0, size)
    pre = np.stack([np.interp(u, shaper[:, c], x) for c in range(3)], axis=1)
    r, g, b = np.meshgrid(pre[:, 0], pre[:, 1], pre[:, 2], indexing="ij")
    nodes = np.stack([r, g, b], axis=-1).reshape(-1, 3)
    if direction == "to-raw":
        values = model.to_raw(nodes)
    else:   # an NUS folder's render is itself a table: its nodes from the RBF
        values = getattr(model, "render_exact", model.render)(nodes)
    table = np.asarray(values, dtype=np.float64).reshape(size, size, size, 3)
    return ShaperLUT(direction, shaper, table, kind)


def _tetrahedra(u: np.ndarray, n: int):
    """For ``(N, 3)`` points ``u`` in ``[0, 1]``: the four nodes (flat ``[r, g, b]``
    indices) of the tetrahedron holding each, and its barycentric weights -- the split of
    each cell along its main diagonal that OpenColorIO's and ffmpeg's tetrahedral
    interpolation use."""
    p = u * (n - 1)
    base = np.minimum(np.floor(p), n - 2).astype(np.int64)
    frac = p - base
    order = np.argsort(-frac, axis=1, kind="stable")
    f = np.take_along_axis(frac, order, axis=1)
    stride = np.array([n * n, n, 1])
    i0 = base @ stride
    steps = stride[order]
    i1 = i0 + steps[:, 0]
    i2 = i1 + steps[:, 1]
    idx = np.stack([i0, i1, i2, i2 + steps[:, 2]], axis=1)
    w = np.stack([1 - f[:, 0], f[:, 0] - f[:, 1], f[:, 1] - f[:, 2], f[:, 2]], axis=1)
    return idx, w


def apply_shaper_lut(lut: ShaperLUT, x) -> np.ndarray:
    """``lut`` applied to ``(..., 3)`` values in ``[0, 1]``: the shaper by linear
    interpolation, then the 3D table by tetrahedral interpolation (ours; a reference for
    tests, what OpenColorIO and ffmpeg do with the files)."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    shape = x.shape
    x = x.reshape(-1, 3)
    grid = np.linspace(0.0, 1.0, lut.shaper.shape[0])
    u = np.stack([np.interp(x[:, c], grid, lut.shaper[:, c]) for c in range(3)], axis=1)
    idx, w = _tetrahedra(u, lut.size)
    flat = lut.table.reshape(-1, 3)
    out = np.einsum("nk,nkc->nc", w, flat[idx])
    return out.reshape(shape)


#: What each direction's input and output are, for the files' comments.
MEANING = {"to-raw": "rendered code/255 -> linear camera raw in [0, 1]",
           "render": "linear camera raw in [0, 1] (black 0, white 1) -> rendered code/255",
           "linearize": "code/max_code -> linear (f^-1 per channel)"}


def write_shaper_cube(lut: ShaperLUT, path, *, title: str | None = None,
                      force: bool = False, inputs=()) -> Path:
    """Write ``lut`` as one ``.cube`` file holding the shaper and the 3D table.

    The layout is DaVinci Resolve's [RESOLVE] (read by Resolve and by OpenColorIO's
    ``resolve_cube`` format): ``LUT_1D_SIZE`` and ``LUT_1D_INPUT_RANGE 0 1`` (the
    shaper's input), ``LUT_3D_SIZE`` and ``LUT_3D_INPUT_RANGE 0 1`` (the shaper's
    output), then the 1D rows, then the 3D rows with the red index varying fastest; the
    1D table is applied first.  The Adobe keywords ``DOMAIN_MIN`` / ``DOMAIN_MAX`` and
    ``TITLE`` are not part of this layout (OpenColorIO refuses them in a file with a
    shaper): the title is a comment line.  Written atomically, never over an existing
    file unless ``force`` nor over one of ``inputs``.

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    check_output_path(path, force=force, inputs=inputs)
    head = [f"# selfcal {lut.direction}: {MEANING[lut.direction]}",
            f"# {lut.kind}",
            "# DaVinci Resolve .cube with a shaper: the 1D table, then the 3D table "
            "(red varies fastest)",
            f"# {cube_title(title or f'selfcal {lut.direction}')}",
            f"LUT_1D_SIZE {lut.shaper.shape[0]}",
            "LUT_1D_INPUT_RANGE 0.0 1.0",
            f"LUT_3D_SIZE {lut.size}",
            "LUT_3D_INPUT_RANGE 0.0 1.0"]
    with atomic_output(path, force=force, inputs=inputs) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write("\n".join(head) + "\n")
            np.savetxt(fh, lut.shaper, fmt="%.8f")
            np.savetxt(fh, lut.rows_red_fastest(), fmt="%.7f")
    return path


def write_ffmpeg_cubes(lut: ShaperLUT, path_1d, path_3d, *, force: bool = False) -> tuple:
    """Write ``lut`` as two ``.cube`` files for ffmpeg's ``lut1d`` then ``lut3d`` filters.

    ffmpeg reads one table per file (its ``lut3d`` refuses a file that also holds a 1D
    table), so the shaper goes to ``path_1d`` (``LUT_1D_SIZE``, ``LUT_1D_INPUT_RANGE 0 1``)
    and the 3D table to ``path_3d`` (``LUT_3D_SIZE``, red fastest, Adobe Cube 1.0); the
    chain is ``-vf lut1d=file=<path_1d>,lut3d=file=<path_3d>``.  Both written atomically.

    Returns
    -------
    (pathlib.Path, pathlib.Path)
    """
    path_1d, path_3d = Path(path_1d), Path(path_3d)
    for p in (path_1d, path_3d):
        check_output_path(p, force=force)
    parts = ((path_1d, [f"# selfcal {lut.direction} shaper: {lut.kind}",
                        f"LUT_1D_SIZE {lut.shaper.shape[0]}", "LUT_1D_INPUT_RANGE 0.0 1.0"],
              lut.shaper, "%.8f"),
             (path_3d, [f"# selfcal {lut.direction} 3D table, after {path_1d.name}",
                        f"LUT_3D_SIZE {lut.size}", "DOMAIN_MIN 0.0 0.0 0.0",
                        "DOMAIN_MAX 1.0 1.0 1.0"], lut.rows_red_fastest(), "%.7f"))
    for path, head, rows, fmt in parts:
        with atomic_output(path, force=force) as tmp:
            with open(tmp, "w", encoding="ascii", newline="\n") as fh:
                fh.write("\n".join(head) + "\n")
                np.savetxt(fh, rows, fmt=fmt)
    return path_1d, path_3d
