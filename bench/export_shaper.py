"""Shaper LUTs, CLF files and an OpenColorIO config of real models, applied by
OpenColorIO (the reference implementation) and ffmpeg.  Run as
``python3 -m bench.export_cube`` (this module holds its default mode).

The camera: the NUS Nikon D7000 model folder (``selfcal.load_model(folder)``, white
balance 14).  The images: real out-of-camera JPEGs of other cameras, used as a natural
spread of colours -- the tuning image ``sony_ilce6400/scene1/DSC04141.JPG`` (the one the
shaper choices were tried on) and, held out, the middle frame of each other scene of
``real_brackets`` (Sony scenes 2-3, Fujifilm scenes 1-3).  ``to-raw`` is applied to the
JPEG; ``render`` to the raw selfcal's ``to_raw`` gives for it (16-bit), each against
selfcal's own ``to_raw`` / ``render`` of the same model.  "In range": pixels whose codes
(``to-raw``: the JPEG's; ``render``: the rendering's) all lie in the model's fitted range
(5-252).  A pixel is "within" when its largest channel difference is at most 0.005 (0.5 %
of full scale).

1. Per 3D size (17, 33, 65) and direction, the shaper LUT
   (:func:`selfcal.export.shaper.shaper_lut`) written as CLF
   (:func:`selfcal.export.clf.write_clf`) and applied by OpenColorIO's CPU processor
   (``FileTransform``); the Resolve ``.cube`` of the same tables applied by OpenColorIO
   (tetrahedral) must give the same values (largest difference printed).
2. The same tables through ffmpeg: ``lut1d`` (the shaper) then ``lut3d`` (tetrahedral),
   16-bit frames (:func:`selfcal.export.shaper.write_ffmpeg_cubes`).
3. Response models (JPEG-only path) calibrated from two real stacks: the 1D ``.cube``, the
   CLF and the OCIO config applied by OpenColorIO to every code and to a frame of the
   stack, against ``ResponseModel.linearize``.
4. The OCIO config of the NUS model (33³ and its default 65³): ``Config.validate()``,
   ``ociocheck``, and
   the round trip JPEG -> scene-linear -> JPEG through it, against the model's own round
   trip ``render(to_raw(P))``.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from .data import data_dir
from .tables import table

import selfcal
from .peers import apply_shaper_ffmpeg, ffmpeg_binaries
from selfcal.export import write_cube
from selfcal.export.clf import write_clf, write_model_clf
from selfcal.export.ocio import ocio_colour_space_names, write_ocio_config
from selfcal.export.shaper import shaper_lut, write_ffmpeg_cubes, write_shaper_cube
from selfcal.io import read_image

SIZES = (17, 33, 65)
TOL = 0.005
TUNING = ("sony_ilce6400", "scene1", "DSC04141.JPG")


def bench_images() -> list:
    """``(split, label, path)``: the tuning image, then the middle frame of every other
    scene of real_brackets."""
    root = data_dir("real_brackets")
    out = [("tuning", "sony scene1 " + TUNING[2], root.joinpath(*TUNING))]
    for cam in sorted(p for p in root.iterdir() if p.is_dir()):
        for scene in sorted(p for p in cam.iterdir() if p.is_dir()):
            if (cam.name, scene.name) == TUNING[:2]:
                continue
            frames = sorted(f for f in scene.iterdir() if f.suffix.lower() == ".jpg")
            mid = frames[len(frames) // 2]
            out.append(("held-out", f"{cam.name.split('_')[0]} {scene.name} {mid.name}", mid))
    return out


def ocio_apply(processor, x: np.ndarray) -> np.ndarray:
    img = np.ascontiguousarray(np.asarray(x, dtype=np.float32))
    processor.applyRGB(img)
    return img.astype(np.float64)


def file_processor(ocio, path: Path, tetrahedral: bool = False):
    ft = ocio.FileTransform(src=str(path))
    if tetrahedral:
        ft.setInterpolation(ocio.INTERP_TETRAHEDRAL)
    return ocio.Config.CreateRaw().getProcessor(ft).getDefaultCPUProcessor()


def score(out: np.ndarray, ours: np.ndarray, mask: np.ndarray) -> list:
    err = np.abs(out - ours).max(axis=-1)[mask]
    return [f"{100 * np.mean(err <= TOL):.2f}", f"{np.percentile(err, 99):.4f}",
            f"{err.max():.4f}"]


def prepare(model, images) -> list:
    """Per image: the JPEG, selfcal's raw for it (16-bit), selfcal's to_raw and render,
    and the in-range masks."""
    lo, hi = model.camera.valid_range or (0, 255)
    out = []
    for split, label, path in images:
        jpg = read_image(path)
        ours_raw = model.to_raw(jpg).astype(np.float64)
        raw16 = np.round(np.clip(ours_raw, 0.0, 1.0) * 65535).astype(np.uint16)
        ours_render = model.render(raw16).astype(np.float64)
        codes_out = np.round(ours_render * 255)
        out.append({"split": split, "label": label, "jpg": jpg, "raw16": raw16,
                    "to-raw": ours_raw, "render": ours_render,
                    "mask": {"to-raw": ((jpg >= lo) & (jpg <= hi)).all(axis=2),
                             "render": ((codes_out >= lo) & (codes_out <= hi)).all(axis=2)}})
    return out


def shaper_tables(ocio, model, frames, tmp: Path, exe) -> tuple:
    """Sections 1 and 2: rows per size, direction and image; the cube-vs-CLF check."""
    rows, ff_rows, same, kinds = [], [], [], {}
    for size in SIZES:
        for direction in ("render", "to-raw"):
            t0 = time.perf_counter()
            lut = shaper_lut(model, direction, size=size)
            build = time.perf_counter() - t0
            kinds[direction] = lut.kind
            stem = f"{direction}{size}"
            clf = write_clf(lut, tmp / f"{stem}.clf", direction, name=stem)
            cube = write_shaper_cube(lut, tmp / f"{stem}.cube")
            p1, p3 = write_ffmpeg_cubes(lut, tmp / f"{stem}.shaper.cube",
                                        tmp / f"{stem}.3d.cube")
            proc = file_processor(ocio, clf)
            for k, fr in enumerate(frames):
                x = fr["jpg"] / 255.0 if direction == "to-raw" else fr["raw16"] / 65535.0
                out = ocio_apply(proc, x)
                mask = fr["mask"][direction]
                rows.append([f"{direction} {size}³", fr["split"], fr["label"],
                             f"{100 * mask.mean():.1f}", *score(out, fr[direction], mask)])
                if k == 0:
                    by_cube = ocio_apply(file_processor(ocio, cube, True), x)
                    same.append([f"{direction} {size}³", f"{np.abs(by_cube - out).max():.2e}",
                                 f"{build:.1f}"])
                if exe is not None:
                    frame16 = (fr["jpg"].astype(np.uint16) * 257 if direction == "to-raw"
                               else fr["raw16"])
                    got = apply_shaper_ffmpeg(exe, p1, p3, frame16)
                    ff_rows.append([f"{direction} {size}³", fr["split"], fr["label"],
                                    *score(got, fr[direction], mask)])
    return rows, ff_rows, same, kinds


def response_rows(ocio, tmp: Path) -> list:
    """Section 3: response models through OpenColorIO against linearize."""
    stacks = [("piccante canon t2i", data_dir("piccante_canon_t2i", "stack")),
              ("fujifilm scene3", data_dir("real_brackets", "fujifilm_xh1", "scene3"))]
    rows = []
    codes8 = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    for name, folder in stacks:
        frames = sorted(f for f in folder.iterdir() if f.suffix.lower() in (".jpg", ".jpeg"))
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = selfcal.calibrate_response(frames)
        frame = read_image(frames[len(frames) // 2])
        stem = name.replace(" ", "_")
        cube = write_cube(model, tmp / f"{stem}.cube")
        clf = write_model_clf(model, tmp / f"{stem}.clf")
        cfg_path = write_ocio_config(model, tmp / f"{stem}_ocio", camera=stem)
        cfg = ocio.Config.CreateFromFile(str(cfg_path))
        names = ocio_colour_space_names(stem)
        procs = {".cube (1D)": file_processor(ocio, cube), ".clf": file_processor(ocio, clf),
                 "OCIO config": cfg.getProcessor(names["jpeg"], names["linear"])
                 .getDefaultCPUProcessor()}
        want_codes = model.linearize(codes8).astype(np.float64)
        want_frame = model.linearize(frame).astype(np.float64)
        for label, proc in procs.items():
            e_codes = np.abs(ocio_apply(proc, codes8 / 255.0) - want_codes).max()
            e_frame = np.abs(ocio_apply(proc, frame / 255.0) - want_frame).max()
            rows.append([name, label, f"{e_codes:.1e}", f"{e_frame:.1e}"])
    return rows


def config_rows(ocio, model, frames, tmp: Path, size: int) -> tuple:
    """Section 4: the NUS model's OCIO config: validation and the round trip."""
    tmp.mkdir(exist_ok=True)
    cfg_path = write_ocio_config(model, tmp / "nus_ocio", camera="nikon_d7000", size=size)
    ocio.ClearAllCaches()
    cfg = ocio.Config.CreateFromFile(str(cfg_path))
    try:
        cfg.validate()
        valid = "passed"
    except Exception as exc:     # OCIO raises its own Exception type
        valid = f"failed: {exc}"
    check = subprocess.run(["ociocheck", "--iconfig", str(cfg_path)], capture_output=True,
                           text=True)
    warnings_line = [ln for ln in check.stdout.splitlines() if "Warnings" in ln]
    checked = (f"ociocheck exit {check.returncode}; "
               + (warnings_line[0] if warnings_line else "no warnings line"))
    names = ocio_colour_space_names("nikon_d7000")
    to_lin = cfg.getProcessor(names["jpeg"], names["linear"]).getDefaultCPUProcessor()
    from_lin = cfg.getProcessor(names["linear"], names["jpeg"]).getDefaultCPUProcessor()
    rows = []
    for fr in frames:
        p = fr["jpg"] / 255.0
        back = ocio_apply(from_lin, ocio_apply(to_lin, p))
        own = model.render(np.round(np.clip(fr["to-raw"], 0, 1) * 65535).astype(np.uint16))
        mask = fr["mask"]["to-raw"]
        rows.append([fr["split"], fr["label"], *score(back, p, mask)[:1],
                     *score(back, p, mask)[2:], *score(own, p, mask)[:1],
                     *score(back, own, mask)[:1]])
    return valid, checked, rows


def main_shaper() -> None:
    import PyOpenColorIO as ocio

    folder = data_dir("nus_model_nikon_d7000")
    model = selfcal.load_model(folder)
    images = bench_images()
    exes = ffmpeg_binaries()
    exe = exes[0] if exes else None
    t0 = time.perf_counter()
    frames = prepare(model, images)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rows, ff_rows, same, kinds = shaper_tables(ocio, model, frames, tmp, exe)
        resp = response_rows(ocio, tmp)
        configs = {size: config_rows(ocio, model, frames, tmp / str(size), size)
                   for size in (33, 65)}
    ff_version = subprocess.run([exe, "-version"], capture_output=True, text=True).stdout \
        .split("\n", 1)[0].split(" Copyright")[0] if exe else "none"
    print(f"NUS model {folder.name} (wb 14); OpenColorIO {ocio.__version__}; ffmpeg: "
          f"{ff_version}; {len(frames)} images; load average {os.getloadavg()[0]:.1f}; "
          f"{time.perf_counter() - t0:.0f} s")
    for d, k in kinds.items():
        print(f"{d}: {k}")
    print()
    print(f"1. Shaper LUTs (CLF: Range, LUT1D 4081, LUT3D tetrahedral) applied by "
          f"OpenColorIO, against selfcal's own render / to_raw; in-range pixels: % within "
          f"{TOL}, 99th percentile and worst largest-channel difference")
    print(table(["LUT", "split", "image", "% pixels in range", "% within", "p99", "worst"],
                rows))
    print()
    print("The Resolve .cube (shaper + 3D in one file) applied by OpenColorIO (tetrahedral) "
          "against the CLF, tuning image; and the time to build the tables")
    print(table(["LUT", "largest difference, cube vs CLF", "build s"], same))
    print()
    print("2. ffmpeg: lut1d (the shaper) then lut3d (tetrahedral), 16-bit frames, "
          "against selfcal's own render / to_raw; in-range pixels")
    print(table(["LUT", "split", "image", "% within", "p99", "worst"], ff_rows))
    print()
    print("3. Response models (JPEG-only path) through OpenColorIO against "
          "ResponseModel.linearize: largest difference over every 8-bit code and over a "
          "frame of the stack")
    print(table(["stack", "export", "every code", "a frame"], resp))
    print()
    print("4. OCIO config of the NUS model: validation, and the round trip JPEG -> "
          "scene-linear -> JPEG through it on the JPEG's in-range pixels: % within 0.005 of "
          "the JPEG (and worst), the model's own render(to_raw(P)) likewise, and % of the "
          "config's round trip within 0.005 of the model's")
    trip = []
    for size, (valid, checked, rows) in configs.items():
        print(f"   {size}³ LUTs: Config.validate() {valid}; {checked}")
        trip += [[f"{size}³", *r] for r in rows]
    print(table(["config", "split", "image", "% within (OCIO round trip)", "worst (OCIO)",
                 "% within (model's own)", "% OCIO within 0.005 of the model's"], trip))

