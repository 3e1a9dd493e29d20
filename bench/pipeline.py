"""Issue 4 (RAW path): the fitted camera pipeline against baselines, stability and speed.

Data
  (a) selfcal.sim RAW+JPEG pairs (smooth gamut mapping, JPEG q95), seeds 0-2;
  (b) the real Nikon D7000 in-camera model of NUS (../shared/data/nus_model_nikon_d7000,
      read by selfcal.pipeline.nus, white-balance setting 14) applied to the real raws in
      ../shared/data/raw: each DNG is read as linear camera RGB (raw_image_visible, black
      and white levels, 2×2 superpixels; the 4128-wide Blackmagic frame is averaged 2× more),
      white-balanced with its as-shot multipliers (clipped at 1) and divided by the model's
      WB gains, so that the model's T = T_s·diag(gains) sees a white-balanced raw
      (README "white-balance them to suit the model's matrix").  The rendering is quantised
      to 8 bits (the main tables) and also JPEG q95-compressed (one extra table).

Training: 1,500 random pixels, and 140 (Gong et al. §7 one-shot setting), the same samples
for every method.  Test: every pixel.  Forward RMSE on the 0-255 scale against the
camera's continuous rendering; backward RMSE of the raw (normalised to [0, 1]) from the
8-bit (or JPEG) rendering, over all pixels and over the pixels with no channel at 0 or 255
(a clipped code does not determine its raw).

Methods: selfcal (rank-based matrix, tone curves, 5³ LUTs; backward by held-out choice
between the §3.5 LUT and the RBF h⁻¹ -- both also shown), IndPoly (3×3 least-squares
matrix + per-channel polynomials; Chakrabarti et al. 2009), LS-T + RBF (Lin et al. ICCV
2011 §6 as published), and for (b) the NUS model's own published jpg2raw direction as a
reference (it was fitted on many more samples of the real camera).

    python3 -m bench.pipeline                 # accuracy, stability (5 repeats), speed
    python3 -m bench.pipeline --repeats 50    # the paper's 50-repeat stability protocol
    python3 -m bench.pipeline --only stability --repeats 50   # that table alone (~45 min)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from .tables import finish, start, table, Timer
from .data import camera_name, data_dir

from selfcal.sim.scoring import rmse

WB_CODE = 14          # the NUS D7000 model's fluorescent setting (its sample images' one)
TRAIN_SIZES = (1500, 140)


# --------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------

def read_raw_superpixels(path: Path, extra: int = 1):
    """Linear camera RGB from a Bayer raw: 2×2 superpixels (R, mean G, B), then ``extra``×
    block averaging; normalised by the black and white levels; and the as-shot WB."""
    import rawpy

    with rawpy.imread(str(path)) as r:
        raw = r.raw_image_visible.astype(np.float64)
        cols = r.raw_colors_visible.copy()
        black = np.asarray(r.black_level_per_channel, dtype=np.float64)
        white = float(r.white_level)
        wb = np.asarray(r.camera_whitebalance[:3], dtype=np.float64)
    step = 2 * extra
    h, w = (raw.shape[0] // step) * step, (raw.shape[1] // step) * step
    raw, cols = raw[:h, :w], cols[:h, :w]
    norm = np.clip((raw - black[cols]) / (white - black[cols]), 0.0, 1.0)
    out = np.zeros((h // 2, w // 2, 3))
    cnt = np.zeros((h // 2, w // 2, 3))
    for dy in (0, 1):
        for dx in (0, 1):
            c = cols[dy::2, dx::2]
            c = np.where(c == 3, 1, c)
            v = norm[dy::2, dx::2]
            for k in range(3):
                sel = c == k
                out[..., k][sel] += v[sel]
                cnt[..., k][sel] += 1
    out /= np.maximum(cnt, 1)
    if extra > 1:
        hh, ww = out.shape[0] // extra, out.shape[1] // extra
        out = out[:hh * extra, :ww * extra].reshape(hh, extra, ww, extra, 3).mean(axis=(1, 3))
    return out, wb / wb[1]


def jpeg(codes: np.ndarray, quality: int = 95) -> np.ndarray:
    import cv2

    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(codes[..., ::-1]),
                            [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1].copy()


def synthetic_datasets():
    from selfcal import sim

    out = []
    for seed in (0, 1, 2):
        p = sim.simulate_raw_jpeg_pair(seed=seed)
        out.append({"name": f"synth seed {seed}", "group": "a",
                    "raw": p["raw"].astype(np.float64),
                    "truth": p["pipeline"].render(p["raw"]), "rendered": p["rendered"]})
    return out


def nus_datasets(cam):
    out = []
    for fname, extra in (("colorchart_canon550d.dng", 1), ("blackmagic_cinema.dng", 2)):
        rho, wb = read_raw_superpixels(data_dir("raw", fname), extra)
        raw = np.clip(rho * wb, 0.0, 1.0) / cam.gains       # white-balanced, then / gains
        with Timer() as t:
            truth = cam.render(raw)
        codes = np.round(truth * 255).astype(np.uint8)
        name = f"D7000 model on {fname.split('_')[0]}"
        ds = {"name": name, "group": "b", "raw": raw, "truth": truth, "rendered": codes,
              "render_seconds": t.seconds}
        out.append(ds)
        out.append({**ds, "name": name + " (JPEG q95)", "group": "b-jpeg",
                    "rendered": jpeg(codes)})
    return out


# --------------------------------------------------------------------------------------
# evaluation
# --------------------------------------------------------------------------------------

def scores(model, ds, variant=None):
    raw = ds["raw"].reshape(-1, 3)
    rendered = ds["rendered"].reshape(-1, 3)
    ok = ~((rendered == 0) | (rendered == 255)).any(axis=1)
    fwd = rmse(model.render(raw), ds["truth"].reshape(-1, 3)) * 255
    back = (model.to_raw(rendered) if variant is None
            else model.to_raw(rendered, variant=variant)).reshape(-1, 3)
    return fwd, rmse(back, raw), rmse(back[ok], raw[ok])


def train_samples(ds, n, seed):
    raw = ds["raw"].reshape(-1, 3)
    rendered = ds["rendered"].reshape(-1, 3) / 255.0
    idx = np.random.default_rng(seed).choice(raw.shape[0], n, replace=False)
    return raw[idx], rendered[idx]


def fit_all(ds, n, seed, with_ls=True):
    from selfcal.pipeline import fit_pipeline
    from selfcal.pipeline.baselines import (independent_polynomial_model,
                                            least_squares_rbf_model)

    raw, rendered = train_samples(ds, n, seed)
    out = {}
    with Timer() as t:
        out["selfcal"] = fit_pipeline(raw, rendered, seed=seed)
    out["fit_seconds"] = t.seconds
    out["IndPoly"] = independent_polynomial_model(raw, rendered)
    if with_ls:
        out["LS-T+RBF"] = least_squares_rbf_model(raw, rendered, seed=seed)
    return out


def accuracy_tables(datasets, nus_cam):
    fwd_rows, back_rows, clip_rows, target_rows = [], [], [], []
    for ds in datasets:
        sizes = TRAIN_SIZES if ds["group"] != "b-jpeg" else (1500,)
        for n in sizes:
            fits = fit_all(ds, n, seed=0)
            sc = fits["selfcal"]
            s_auto = scores(sc, ds)
            s_lut = scores(sc, ds, "lut")
            s_rbf = scores(sc, ds, "rbf")
            s_ip = scores(fits["IndPoly"], ds)
            s_ls = scores(fits["LS-T+RBF"], ds)
            ref_all = ref_ok = None
            if ds["group"].startswith("b"):
                rendered = ds["rendered"].reshape(-1, 3)
                ok = ~((rendered == 0) | (rendered == 255)).any(axis=1)
                if "nus_back" not in ds:
                    ds["nus_back"] = np.clip(nus_cam.to_raw(rendered), 0, 1)
                ref_all = rmse(ds["nus_back"], ds["raw"].reshape(-1, 3))
                ref_ok = rmse(ds["nus_back"][ok], ds["raw"].reshape(-1, 3)[ok])
            name = ds["name"]
            fwd_rows.append([name, n, f"{s_auto[0]:.2f}", f"{s_ip[0]:.2f}", f"{s_ls[0]:.2f}",
                             f"{sc.diagnostics['forward_train_rmse']:.2f}"])
            for rows, k, ref in ((back_rows, 1, ref_all), (clip_rows, 2, ref_ok)):
                rows.append([name, n, f"{s_auto[k]:.4f} ({sc.backward})", f"{s_lut[k]:.4f}",
                             f"{s_rbf[k]:.4f}", f"{s_ip[k]:.4f}", f"{s_ls[k]:.4f}",
                             f"{s_auto[k] / s_ip[k]:.2f}",
                             "-" if ref is None else f"{ref:.4f}"])
            if ds["group"] == "b":
                target_rows.append([
                    name, n, f"{s_auto[0]:.2f}", "yes" if s_auto[0] <= 2.5 else "NO",
                    f"{s_auto[1]:.4f}", "yes" if s_auto[1] <= 0.01 else "NO",
                    f"{s_auto[1] / s_ip[1]:.2f} / {s_auto[2] / s_ip[2]:.2f}",
                    "yes" if s_auto[1] <= 0.7 * s_ip[1] else
                    ("unclipped only" if s_auto[2] <= 0.7 * s_ip[2] else "NO")])
            print(f"  {name}, {n} samples: fitted in {fits['fit_seconds']:.1f} s",
                  file=sys.stderr)
    print("\n### Forward (raw -> rendered) RMSE, 0-255, all pixels\n")
    print(table(["data", "train", "selfcal", "IndPoly", "LS-T+RBF",
                 "selfcal train RMSE"], fwd_rows))
    hdr = ["data", "train", "selfcal (chosen)", "selfcal LUT", "selfcal RBF", "IndPoly",
           "LS-T+RBF", "selfcal/IndPoly", "NUS own jpg2raw"]
    print("\n### Backward (rendered -> raw) RMSE, raw in [0, 1], all pixels\n")
    print(table(hdr, back_rows))
    print("\n### Backward RMSE, pixels with no channel at 0 or 255\n")
    print(table(hdr, clip_rows))
    print("\n### Targets on (b) (8-bit rendering): forward <= 2.5, backward <= 0.01, "
          "selfcal backward <= 0.7 x IndPoly\n")
    print(table(["data", "train", "forward", "<= 2.5", "backward", "<= 0.01",
                 "ratio all / unclipped", "<= 0.7"], target_rows))


def stability_table(datasets, repeats):
    rows = []
    for ds in datasets:
        if ds["group"] == "b-jpeg":
            continue
        res = {"selfcal": [], "IndPoly": []}
        for r in range(repeats):
            fits = fit_all(ds, 1500, seed=1000 + r, with_ls=False)
            for k in res:
                res[k].append(scores(fits[k], ds)[:2])
        a = {k: np.array(v) for k, v in res.items()}
        rows.append([ds["name"], repeats,
                     f"{a['selfcal'][:, 0].mean():.2f} ± {a['selfcal'][:, 0].std():.2f}",
                     f"{a['selfcal'][:, 1].mean():.4f} ± {a['selfcal'][:, 1].std():.4f}",
                     f"{a['IndPoly'][:, 0].mean():.2f} ± {a['IndPoly'][:, 0].std():.2f}",
                     f"{a['IndPoly'][:, 1].mean():.4f} ± {a['IndPoly'][:, 1].std():.4f}"])
        print(f"  stability: {ds['name']} done", file=sys.stderr)
    print(f"\n### Stability: {repeats} random training sets of 1,500 samples "
          "(mean ± std; Gong et al. §5 use 50)\n")
    print(table(["data", "repeats", "selfcal forward", "selfcal backward", "IndPoly forward",
                 "IndPoly backward"], rows))


def speed_table(ds_real, literal: bool):
    from selfcal.pipeline import fit_pipeline
    from selfcal.pipeline.matrix import rank_based_row

    rows = []
    raw_all = ds_real["raw"].reshape(-1, 3)
    ren_all = ds_real["rendered"].reshape(-1, 3) / 255.0
    for n in (1500, 20_000):
        idx = np.random.default_rng(7).choice(raw_all.shape[0], n, replace=False)
        with Timer() as t:
            model = fit_pipeline(raw_all[idx], ren_all[idx], seed=0)
        sec = model.diagnostics["seconds"]
        rows.append([f"fit_pipeline, {n} samples (25 sets)", f"{t.seconds:.1f} s",
                     f"matrix+forward {sec['forward']:.1f} s, backward {sec['backward']:.1f} s,"
                     f" bake {sec['bake']:.1f} s", "<= 20 s: " +
                     ("yes" if t.seconds <= 20 else "NO")])
    # fast vs literal half-space search, one set of 200 samples, three rows
    idx = np.random.default_rng(8).choice(raw_all.shape[0], 200, replace=False)
    if literal:
        tf = tl = 0.0
        counts = []
        for k in range(3):
            with Timer() as t:
                f = rank_based_row(raw_all[idx], ren_all[idx], k, method="fast")
            tf += t.seconds
            with Timer() as t:
                lit = rank_based_row(raw_all[idx], ren_all[idx], k, method="literal")
            tl += t.seconds
            counts.append(f"{f['satisfied']}/{lit['satisfied']} of {f['constraints']}")
        rows.append(["matrix search, 200 samples x 3 rows: fast / literal",
                     f"{tf:.3f} s / {tl:.2f} s",
                     "satisfied fast/literal: " + ", ".join(counts),
                     f"ratio {tl / tf:.0f}x (>= 20x: {'yes' if tl / tf >= 20 else 'NO'})"])
    # 24 MP to_raw through the baked table vs direct RBF evaluation
    codes = ds_real["rendered"]
    reps = (int(np.ceil(4000 / codes.shape[0])), int(np.ceil(6000 / codes.shape[1])), 1)
    big = np.ascontiguousarray(np.tile(codes, reps)[:4000, :6000])
    model.to_raw(big[:8, :8], variant="rbf")   # build the 8-bit code table once
    with Timer() as t:
        model.to_raw(big, variant="rbf")
    sub = codes.reshape(-1, 3)[:100_000]
    with Timer() as td:
        model.to_raw(sub, variant="rbf", exact=True)
    direct = td.seconds * big.shape[0] * big.shape[1] / sub.shape[0]
    rows.append(["to_raw, 6000x4000 uint8 (RBF variant, baked 49³)", f"{t.seconds:.2f} s",
                 f"direct RBF, extrapolated from 100k px: {direct:.0f} s",
                 f"<= 3 s: {'yes' if t.seconds <= 3 else 'NO'}; {direct / t.seconds:.0f}x "
                 "faster than direct"])
    bigraw = np.tile(ds_real["raw"].astype(np.float32), reps)[:4000, :6000]
    with Timer() as t:
        model.render(bigraw)
    rows.append(["render, 6000x4000 float32", f"{t.seconds:.2f} s", "exact (no baking)", ""])
    print("\n### Speed (2 shared cores; ratios carry over, seconds do not)\n")
    print(table(["what", "time", "detail", "target"], rows))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5,
                    help="random training sets for the stability table (paper: 50)")
    ap.add_argument("--no-literal", action="store_true",
                    help="skip the (slow) literal 100,000-direction search timing")
    ap.add_argument("--only", choices=("accuracy", "stability", "speed"), action="append",
                    help="run only these parts (repeatable; default: all three)")
    args = ap.parse_args(argv)
    start("pipeline", "none")
    parts = set(args.only or ("accuracy", "stability", "speed"))

    from selfcal.pipeline.nus import read_nus_model

    cam = read_nus_model(data_dir("nus_model_nikon_d7000"), wb_code=WB_CODE)
    data_dir("raw")
    t0 = time.perf_counter()
    datasets = synthetic_datasets() + nus_datasets(cam)
    print(f"## selfcal pipeline benchmark ({camera_name(cam)}; rendering the real raws took "
          f"{sum(d.get('render_seconds', 0) for d in datasets if d['group'] == 'b'):.0f} s)")
    if "accuracy" in parts:
        accuracy_tables(datasets, cam)
    if "stability" in parts:
        stability_table(datasets, args.repeats)
    if "speed" in parts:
        speed_table(next(d for d in datasets if d["group"] == "b"), not args.no_literal)
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
    finish()
