"""Grossberg & Nayar's response-curve files: the EMoR basis and the DoRF database.

Readers for the files of Grossberg & Nayar, *What is the Space of Camera Response
Functions?* (CVPR 2003; DoRF, 201 measured response curves: ``dorfCurves.txt`` and its
MATLAB copies) and *Modeling the Space of Camera Response Functions* (PAMI 2004; the EMoR
forward basis ``emor.txt``), and the two plain types they give: :class:`ForwardBasis` and
:class:`ResponseCurveSet`.  The inverse EMoR file (``invemor.txt``) becomes a
:class:`~selfcal.response.basis.ResponseBasis`, so its reader,
:func:`~selfcal.response.basis.read_invemor`, lives with that class (and uses
:func:`emor_blocks` from here).  Every name here is also importable from
:mod:`selfcal.response.basis`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["ForwardBasis", "ResponseCurveSet", "read_emor", "read_dorf_curves",
           "read_dorf_mat"]


def check_intensity(intensity, what="intensity") -> np.ndarray:
    """Normalised intensities (or irradiances) as a flat float array, checked in [0, 1]."""
    x = np.asarray(intensity, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(x)):
        raise InputError(f"{what} values must be finite")
    if x.size and (x.min() < -1e-9 or x.max() > 1 + 1e-9):
        raise InputError(f"{what} values must lie in [0, 1] (normalised intensity)")
    return np.clip(x, 0.0, 1.0)


@dataclass(frozen=True, eq=False)
class ForwardBasis:
    """Grossberg & Nayar's EMoR forward basis: ``f(E) = f0(E) + sum_n c_n h_n(E)``.

    Attributes
    ----------
    irradiance : ndarray, shape (K,)
        The ``E`` grid.
    mean : ndarray, shape (K,)
        ``f0``.
    components : ndarray, shape (N, K)
        ``h_1 .. h_N``.
    name : str
    """

    irradiance: np.ndarray
    mean: np.ndarray
    components: np.ndarray
    name: str = ""

    @property
    def n_components(self) -> int:
        return int(self.components.shape[0])

    def response(self, coeffs, irradiance=None) -> np.ndarray:
        """``f0 + sum_n c_n h_n`` on the grid or at given irradiances (linear interpolation)."""
        c = np.asarray(coeffs, dtype=np.float64).reshape(-1)
        if c.size > self.n_components:
            raise InputError(f"{c.size} coefficients for {self.n_components} components")
        v = self.mean + c @ self.components[: c.size]
        if irradiance is None:
            return v
        return np.interp(check_intensity(irradiance, "irradiance"), self.irradiance, v)


@dataclass(frozen=True, eq=False)
class ResponseCurveSet:
    """A set of sampled response curves, as in Grossberg & Nayar's DoRF.

    Attributes
    ----------
    x : ndarray, shape (J, K)
        Abscissae of each curve: irradiance for ``kind="forward"``, intensity for
        ``kind="inverse"``.
    y : ndarray, shape (J, K)
        Brightness (forward) or irradiance (inverse) values.
    kind : {"forward", "inverse"}
    names : tuple of str
        Curve names (DoRF text file) or ``"curve 1"``... (.mat copies have none).
    graphs : tuple of str
        The DoRF "graph" line of each curve (e.g. which channel), "" when unknown.
    """

    x: np.ndarray
    y: np.ndarray
    kind: str
    names: tuple
    graphs: tuple

    def __len__(self) -> int:
        return int(self.y.shape[0])

    def inverse_curves(self, intensity=None) -> np.ndarray:
        """Inverse responses ``f^-1`` on an intensity grid, shape (J, len(intensity)).

        Forward curves are inverted by monotone interpolation (a plateau maps to its
        left end); ``f^-1(0) = 0``, ``f^-1(1) = 1``.
        """
        i = np.linspace(0.0, 1.0, 1024) if intensity is None else check_intensity(intensity)
        out = np.empty((len(self), i.size))
        for j in range(len(self)):
            x, y = self.x[j], self.y[j]
            if self.kind == "inverse":
                out[j] = np.interp(i, x, y)
            else:
                b = np.maximum.accumulate(np.clip(y, 0.0, 1.0)) + x * 1e-12
                b = (b - b[0]) / (b[-1] - b[0])
                out[j] = np.interp(i, b, x)
                out[j] = np.where(i <= 0, x[0], np.where(i >= 1, x[-1], out[j]))
        return out


_HEADER = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_]*(?:\(\s*\d+\s*\))?)\s*=\s*(.*)$")


def _read_text(path) -> str:
    try:
        return Path(path).read_text(encoding="latin-1")
    except OSError as exc:
        raise InputError(f"cannot read file ({exc.strerror or exc})", path) from None


def _parse_floats(tokens, path, lineno) -> list[float]:
    try:
        return [float(t) for t in tokens]
    except ValueError:
        raise InputError(f"line {lineno}: expected numbers, found {' '.join(tokens)[:60]!r}",
                         path) from None


def _read_named_blocks(path) -> dict[str, np.ndarray]:
    """Parse ``name =`` headers each followed by numbers (the EMoR text layout)."""
    blocks: dict[str, list[float]] = {}
    current = None
    for lineno, line in enumerate(_read_text(path).splitlines(), 1):
        if not line.strip():
            continue
        m = _HEADER.match(line)
        if m:
            current = re.sub(r"\s+", "", m.group(1))
            if current in blocks:
                raise InputError(f"line {lineno}: block {current!r} appears twice", path)
            blocks[current] = _parse_floats(m.group(2).split(), path, lineno)
            continue
        if current is None:
            raise InputError(f"line {lineno}: numbers before any 'name =' header", path)
        blocks[current].extend(_parse_floats(line.split(), path, lineno))
    return {k: np.asarray(v, dtype=np.float64) for k, v in blocks.items()}


def emor_blocks(path, grid_key, mean_key, comp_prefix):
    blocks = _read_named_blocks(path)
    for key in (grid_key, mean_key, f"{comp_prefix}(1)"):
        if key not in blocks:
            raise InputError(f"no '{key} =' block; is this an EMoR file?", path)
    comps: list[np.ndarray] = []
    while f"{comp_prefix}({len(comps) + 1})" in blocks:
        comps.append(blocks[f"{comp_prefix}({len(comps) + 1})"])
    k = blocks[grid_key].size
    if k < 2:
        raise InputError(f"block '{grid_key}' has {k} values", path)
    for key, arr in [(grid_key, blocks[grid_key]), (mean_key, blocks[mean_key])] + [
            (f"{comp_prefix}({i + 1})", c) for i, c in enumerate(comps)]:
        if arr.size != k:
            raise InputError(f"block '{key}' has {arr.size} values, expected {k}", path)
    grid = blocks[grid_key]
    if np.any(np.diff(grid) <= 0):
        raise InputError(f"block '{grid_key}' is not an increasing grid", path)
    return grid, blocks[mean_key], np.vstack(comps)


def read_emor(path) -> ForwardBasis:
    """Read Grossberg & Nayar's EMoR forward basis (emor.txt).

    The file holds blocks ``E =`` (irradiance grid), ``f0 =`` (mean response) and
    ``h(1)=`` .. ``h(25)=`` (components), each 1024 numbers, four per line (Grossberg &
    Nayar, *Modeling the Space of Camera Response Functions*, PAMI 2004).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    ForwardBasis

    Raises
    ------
    InputError
        Naming the file, when it is missing, unreadable, or lacks a block.
    """
    grid, mean, comps = emor_blocks(path, "E", "f0", "h")
    return ForwardBasis(grid, mean, comps, "EMoR (Grossberg & Nayar)")


def read_dorf_curves(path) -> ResponseCurveSet:
    """Read the DoRF text database (dorfCurves.txt) of forward response curves.

    Each curve is a block of lines: the curve's name, a "graph" line (which plot of the
    source it came from, e.g. a colour channel), ``I =``, the irradiance samples (1024
    numbers), ``B =``, the brightness samples (Grossberg & Nayar, *What is the Space of
    Camera Response Functions?*, CVPR 2003).  Numbers may run over several lines.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    ResponseCurveSet
        ``kind="forward"``, ``x`` = irradiance, ``y`` = brightness.

    Raises
    ------
    InputError
        Naming the file and line, on a malformed or empty file.
    """
    lines = [(n, ln.strip()) for n, ln in enumerate(_read_text(path).splitlines(), 1)]
    lines = [(n, ln) for n, ln in lines if ln]
    names: list[str] = []
    graphs: list[str] = []
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    pos = 0

    def numbers_after(pos, key, count=None):
        # "key =" then numbers: up to the next "B =" header (for I) or ``count`` values (B)
        n, ln = lines[pos]
        m = _HEADER.match(ln)
        if not m or re.sub(r"\s+", "", m.group(1)) != key:
            raise InputError(f"line {n}: expected '{key} =', found {ln[:40]!r}", path)
        vals = _parse_floats(m.group(2).split(), path, n)
        pos += 1
        while pos < len(lines) and (len(vals) < count if count is not None
                                    else not _HEADER.match(lines[pos][1])):
            n2, ln2 = lines[pos]
            vals.extend(_parse_floats(ln2.split(), path, n2))
            pos += 1
        return np.asarray(vals), pos

    while pos < len(lines):
        if pos + 3 >= len(lines):
            raise InputError(f"line {lines[pos][0]}: incomplete curve block at the end", path)
        names.append(lines[pos][1])
        graphs.append(lines[pos + 1][1])
        x, pos = numbers_after(pos + 2, "I")
        if pos >= len(lines):
            raise InputError(f"curve {names[-1]!r}: no 'B =' block", path)
        y, pos = numbers_after(pos, "B", count=x.size)
        if x.size < 2 or x.size != y.size:
            raise InputError(f"curve {names[-1]!r}: {x.size} irradiance and {y.size} "
                             "brightness values", path)
        if xs and x.size != xs[0].size:
            raise InputError(f"curve {names[-1]!r}: {x.size} samples, others have "
                             f"{xs[0].size}", path)
        xs.append(x)
        ys.append(y)
    if not names:
        raise InputError("no curves in the file", path)
    return ResponseCurveSet(np.vstack(xs), np.vstack(ys), "forward", tuple(names), tuple(graphs))


def read_dorf_mat(path) -> ResponseCurveSet:
    """Read a MATLAB copy of DoRF: forward (``I``, ``B``) or inverse (``invB``, ``invI``).

    ``201_CRF_data.mat`` holds ``I`` (irradiance grids) and ``B`` (201 forward curves);
    ``dorfCurvesInv.mat`` holds ``invB`` (intensity grids) and ``invI`` (201 inverse
    curves), each 201 x 1024 (Grossberg & Nayar, CVPR 2003).

    Parameters
    ----------
    path : str or os.PathLike
        Either ``.mat`` file (MATLAB 5 format, read with :func:`scipy.io.loadmat`).

    Returns
    -------
    ResponseCurveSet
        ``kind="forward"`` (x = irradiance, y = brightness) or ``kind="inverse"``
        (x = intensity, y = irradiance); names "curve 1" ... (the .mat files carry none).

    Raises
    ------
    InputError
        Naming the file, when it cannot be read or has neither variable pair.
    """
    from scipy.io import loadmat

    try:
        d = loadmat(str(path))
    except FileNotFoundError:
        raise InputError("no such file", path) from None
    except Exception as exc:  # scipy raises several types for corrupt files
        raise InputError(f"not a readable MATLAB file ({exc})", path) from None
    if "invI" in d and "invB" in d:
        x, y, kind = d["invB"], d["invI"], "inverse"
    elif "I" in d and "B" in d:
        x, y, kind = d["I"], d["B"], "forward"
    else:
        keys = sorted(k for k in d if not k.startswith("__"))
        raise InputError(f"neither (I, B) nor (invB, invI) variables; found {keys}", path)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.ndim == 1 or x.shape[0] == 1:
        x = np.broadcast_to(x.reshape(1, -1), y.shape)
    if y.ndim != 2 or x.shape != y.shape:
        raise InputError(f"curve arrays have shapes {x.shape} and {y.shape}", path)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise InputError("curve arrays contain non-finite values", path)
    names = tuple(f"curve {j + 1}" for j in range(y.shape[0]))
    return ResponseCurveSet(np.array(x), y, kind, names, ("",) * y.shape[0])
