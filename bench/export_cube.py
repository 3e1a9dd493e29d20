"""LUT exports of the NUS model folder, applied by OpenColorIO and ffmpeg.

``python3 -m bench.export_cube``: shaper LUTs (1D shaper + 3D table; CLF and
Resolve ``.cube``), the ffmpeg ``lut1d`` + ``lut3d`` chain, response-model LUTs and the
OpenColorIO config -- see ``bench.export_shaper``.

``python3 -m bench.export_cube --no-shaper``: what follows, the 3D-only cubes.

``.cube`` exports of the NUS model folder applied by ffmpeg's ``lut3d`` (issue 18).

Issue 18 asks that a 3D ``.cube`` applied by ffmpeg's ``lut3d`` filter to a real frame
equal selfcal's own ``to_raw`` / ``render`` within 0.5 % (33³) on the pixels inside the
cube's range.  This writes the NUS Nikon D7000 model (``selfcal.load_model(folder)``,
white balance 14) as ``to-raw`` and ``render`` cubes of 33³ and 65³ nodes
(:func:`selfcal.export.write_cube`; ``to-raw`` as written by default, following the model
for its fitted codes 5-252 and continuing the chords outside them, and with every node
at the model's value, ``code_range=None``), applies them with ffmpeg (the imageio-ffmpeg binary,
and a system ``ffmpeg`` when one is on PATH) to lossless 16-bit frames (``rgb48le`` raw
video in and out), trilinear and tetrahedral, and prints per direction, size and
interpolation the share of pixels within 0.005 (0.5 % of full scale; largest channel
difference) and the worst difference, over

- all pixels;
- the model's range: ``to-raw``, pixels with every code inside the model's fitted range
  (``jpg2raw_validRange.txt``: codes 5-252); ``render``, pixels whose rendering has every
  code inside it;
- no end cell: pixels in no grid cell touching the cube's faces (``to-raw``: every code
  within ``[255/(n-1), 255 - 255/(n-1)]``; ``render``: every raw channel at least
  ``1/(n-1)``, the first cell where the tone curve is steepest).

The frame: ``real_brackets/sony_ilce6400/scene1/DSC04141.JPG`` (3008×2000, a real
out-of-camera JPEG, daylight; another camera, used as a natural spread of colours) for
``to-raw``; for ``render``, the raw selfcal's ``to_raw`` gives for it, read by ffmpeg as
16-bit codes and by selfcal as the same codes.

Why the rest cannot reach 0.5 % (printed as evidence): the cube's nodes are uniform in its
input and ffmpeg reads no shaper.  On grey pixels, tetrahedral interpolation runs along
the cube's diagonal, between two diagonal nodes: it is one-dimensional linear
interpolation of the model's grey response.  The second table prints, per grid cell of
that grey axis, the worst difference of that interpolation (the cube's nodes hold the
model) and the least any straight line can reach over the cell's codes (a minimax fit by
linear programming: a lower bound for any table of that size, whatever its node values).
ffmpeg's ``DOMAIN_MIN`` / ``DOMAIN_MAX`` cannot narrow the range instead (see
:mod:`selfcal.export`): the third table applies a cube whose nodes are the identity on a
``[0.1, 0.9]`` domain and prints what ffmpeg returns.

    python3 -m bench.export_cube
"""

from __future__ import annotations

import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

from .data import data_dir
from .tables import finish, start, table

import selfcal
from .peers import apply_cube_ffmpeg, ffmpeg_binaries
from selfcal.export import cube_table, write_cube
from selfcal.io import read_image

SIZES = (33, 65)
INTERPS = ("trilinear", "tetrahedral")
TOL = 0.005


def ffmpeg_version(exe: str) -> str:
    out = subprocess.run([exe, "-version"], capture_output=True, text=True).stdout
    return out.split("\n", 1)[0].split(" Copyright")[0]


def _score(err: np.ndarray, mask: np.ndarray) -> list[str]:
    if not mask.any():
        return ["-", "-"]
    e = err[mask]
    return [f"{100 * np.mean(e <= TOL):.2f}", f"{e.max():.4f}"]


def _minimax_line(x: np.ndarray, y: np.ndarray) -> float:
    """The least max |y - (a + b x)| over straight lines (linear programming)."""
    n = x.size
    # variables a, b, e; minimise e subject to ±(y - a - b x) <= e
    a_ub = np.block([[-np.ones((n, 1)), -x[:, None], -np.ones((n, 1))],
                     [np.ones((n, 1)), x[:, None], -np.ones((n, 1))]])
    b_ub = np.concatenate([-y, y])
    res = linprog([0, 0, 1], A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 3,
                  method="highs")
    return float(res.x[2])


def _diagonal(rows: np.ndarray, size: int) -> np.ndarray:
    """The table's nodes on the grey diagonal (r = g = b), in order."""
    k = np.arange(size)
    return rows[k * (1 + size + size * size)]


def _cells(x: np.ndarray, size: int) -> np.ndarray:
    return np.minimum(np.floor(x * (size - 1)), size - 2).astype(int)


def grey_axis_evidence(model, valid) -> list[list[str]]:
    """Per size and table: along the grey axis, the nodes' linear interpolation against
    the model, and the least any straight line reaches per cell."""
    rows = []
    codes = np.arange(256)
    inside = (codes >= valid[0]) & (codes <= valid[1])
    to_raw = model.to_raw(np.repeat(codes.astype(np.uint8)[:, None], 3, axis=1))
    to_raw = to_raw.astype(np.float64)
    raw_axis = np.arange(0, 65536, 16) / 65535.0                  # 4096 grey raw levels
    render = model.render(np.repeat(raw_axis[:, None], 3, axis=1)).astype(np.float64)
    for size in SIZES:
        nodes = np.linspace(0.0, 1.0, size)
        for label, code_range in ((f"codes {valid[0]}-{valid[1]}", tuple(valid)),
                                  ("none", None)):
            diag = _diagonal(cube_table(model, "to-raw", size=size,
                                        code_range=code_range)[0], size)
            lerp = np.stack([np.interp(codes / 255.0, nodes, diag[:, c]) for c in range(3)],
                            axis=1)
            err = np.abs(lerp - to_raw).max(axis=1)
            worst = int(codes[inside][np.argmax(err[inside])])
            cell = _cells(np.array([worst / 255.0]), size)[0]
            in_cell = inside & (_cells(codes / 255.0, size) == cell)
            least = max(_minimax_line(codes[in_cell] / 255.0, to_raw[in_cell, c])
                        for c in range(3))
            rows.append([f"to-raw {size}³, range {label}", f"codes {valid[0]}-{valid[1]}",
                         f"{255 * cell / (size - 1):.1f}-{255 * (cell + 1) / (size - 1):.1f}",
                         f"code {worst}", f"{err[inside].max():.4f}",
                         f"{abs(least):.4f}", "-"])
        diag = _diagonal(cube_table(model, "render", size=size)[0], size)
        lerp = np.stack([np.interp(raw_axis, nodes, diag[:, c]) for c in range(3)], axis=1)
        err = np.abs(lerp - render).max(axis=1)
        worst = int(np.argmax(err))
        cell_of = _cells(raw_axis, size)
        least = np.array([max(_minimax_line(raw_axis[cell_of == c], render[cell_of == c, k])
                              for k in range(3)) for c in range(size - 1)])
        beyond = np.flatnonzero(least > TOL)
        rows.append([f"render {size}³", "raw 0-1",
                     f"{cell_of[worst] / (size - 1):.4f}-{(cell_of[worst] + 1) / (size - 1):.4f}",
                     f"raw {raw_axis[worst]:.4f}", f"{err.max():.4f}",
                     f"{least[cell_of[worst]]:.4f}",
                     f"{beyond.size} (raw < {(beyond.max() + 1) / (size - 1):.3f})"
                     if beyond.size else "0"])
    return rows


def domain_check(exe: str, folder: Path) -> list[list[str]]:
    """A cube whose nodes are the identity on [lo, hi]: what ffmpeg returns."""
    lo, hi, n = 0.1, 0.9, 5
    x = np.linspace(0.0, 1.0, n)
    b, g, r = np.meshgrid(x, x, x, indexing="ij")
    vals = lo + np.stack([r, g, b], axis=-1).reshape(-1, 3) * (hi - lo)
    path = folder / "domain.cube"
    with open(path, "w", encoding="ascii") as fh:
        fh.write(f"LUT_3D_SIZE {n}\nDOMAIN_MIN {lo} {lo} {lo}\nDOMAIN_MAX {hi} {hi} {hi}\n")
        np.savetxt(fh, vals, fmt="%.7f")
    probe = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    frame = np.round(np.repeat(probe[None, :, None], 3, axis=2) * 65535).astype(np.uint16)
    out = apply_cube_ffmpeg(exe, path, frame, "trilinear")[0, :, 0]
    return [[f"{p:.1f}", f"{p:.3f}", f"{lo + p * (hi - lo):.3f}", f"{o:.3f}"]
            for p, o in zip(probe, out)]


def main_no_shaper() -> None:
    """The 3D-only cubes of issue 18 applied by ffmpeg's lut3d (``--no-shaper``)."""
    folder = data_dir("nus_model_nikon_d7000")
    jpg_path = data_dir("real_brackets", "sony_ilce6400", "scene1") / "DSC04141.JPG"
    exes = ffmpeg_binaries()
    if not exes:
        raise SystemExit("no ffmpeg: pip install imageio-ffmpeg, or install ffmpeg")
    model = selfcal.load_model(folder)
    valid = model.camera.valid_range or (0, 255)
    jpg = read_image(jpg_path)
    ours_raw = model.to_raw(jpg).astype(np.float64)
    raw16 = np.round(np.clip(ours_raw, 0.0, 1.0) * 65535).astype(np.uint16)
    ours_render = model.render(raw16).astype(np.float64)
    codes_out = np.round(ours_render * 255)
    in_model = {"to-raw": ((jpg >= valid[0]) & (jpg <= valid[1])).all(axis=2),
                "render": ((codes_out >= valid[0]) & (codes_out <= valid[1])).all(axis=2)}

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for exe in exes:
            for direction, code_range in (("to-raw", "model"), ("to-raw", None),
                                          ("render", "model")):
                for size in SIZES:
                    cube = write_cube(model, tmp / f"{direction}{size}.cube",
                                      direction=direction, size=size, force=True,
                                      code_range=code_range)
                    label = f"{direction} {size}³" + (
                        "" if direction == "render" else
                        f", range {valid[0]}-{valid[1]}" if code_range else ", range none")
                    if direction == "to-raw":
                        frame16, ours = jpg.astype(np.uint16) * 257, ours_raw
                        step = 255.0 / (size - 1)
                        no_end = ((jpg >= step) & (jpg <= 255 - step)).all(axis=2)
                    else:
                        frame16, ours = raw16, ours_render
                        no_end = (raw16 >= 65535.0 / (size - 1)).all(axis=2)
                    for interp in INTERPS:
                        out = apply_cube_ffmpeg(exe, cube, frame16, interp)
                        err = np.abs(out - ours).max(axis=2)
                        everything = np.ones(err.shape, dtype=bool)
                        rows.append([f"{label} {interp}"
                                     + ("" if len(exes) == 1 else f" ({Path(exe).name})"),
                                     *_score(err, everything),
                                     f"{100 * in_model[direction].mean():.1f}",
                                     *_score(err, in_model[direction]),
                                     f"{100 * no_end.mean():.1f}", *_score(err, no_end)])
        domain_rows = domain_check(exes[0], tmp)

    print(f"NUS model {folder.name} (wb 14) exported by selfcal.export.write_cube; frame "
          f"{jpg_path.name} {jpg.shape[1]}x{jpg.shape[0]}; model range codes "
          f"{valid[0]}-{valid[1]}; ffmpeg: "
          + "; ".join(ffmpeg_version(e) for e in exes)
          + f"; load average {os.getloadavg()[0]:.1f}")
    print()
    print(f"ffmpeg lut3d against selfcal's own to_raw / render: % of pixels within {TOL} "
          "(largest channel) and the worst difference")
    print(table(["cube", "% within (all)", "worst (all)", "% of pixels in model range",
                 "% within (model range)", "worst (model range)", "% of pixels, no end cell",
                 "% within (no end cell)", "worst (no end cell)"], rows))
    print()
    print("Grey axis (what tetrahedral interpolation does on grey pixels): the worst cell, "
          "linear interpolation between the cube's nodes vs the least a straight line can "
          "reach over the cell (any node values)")
    print(table(["cube", "over", "worst cell", "at", "nodes' interpolation",
                 "least any line (that cell)", f"cells where no line is within {TOL}"],
                grey_axis_evidence(model, valid)))
    print()
    print("ffmpeg and DOMAIN lines: a cube whose nodes are the identity on [0.1, 0.9] "
          "(DOMAIN_MIN 0.1, DOMAIN_MAX 0.9), applied by ffmpeg")
    print(table(["input", "identity (domain read)", "domain ignored", "ffmpeg"],
                domain_rows))


if __name__ == "__main__":
    import sys

    start("export_cube", "none")
    if "--no-shaper" in sys.argv[1:]:
        main_no_shaper()
    else:
        from .export_shaper import main_shaper

        main_shaper()
    finish()
