"""Issue 16: the RAW-path model on scenes it was not fitted on (cross-scene protocol).

Every scene is a linear raw rendered by the real Nikon D7000 in-camera model of NUS
(../shared/data/nus_model_nikon_d7000, white-balance setting 14, read by
selfcal.pipeline.nus; the raw white-balanced, then divided by the model's WB gains, as in
bench.pipeline), quantised to 8 bits and JPEG q95-compressed:

  chart, blackmagic   the two real raws of ../shared/data/raw (2x2 superpixels, then 2x /
                      4x block means: about 130k pixels each);
  sim-*               selfcal.sim.make_scene (a chart, texture, neutral ramp, hue x chroma
                      and hue x luminance ramps; saturation 0.6 / 0.9) and
                      selfcal.sim.conditions.natural_scene (sky and sun, foliage with
                      flowers, a ColorChecker, skin spheres, a shadow ramp; palette
                      colourful / saturated), through selfcal.sim.SensorModel;
  ssf-*               physically made raws: smooth reflectances (sums of one to three
                      Gaussians; for ssf-D65-cc the 24 BabelColor ColorChecker spectra and 56
                      such) under CIE D65 or A (colour.SDS_ILLUMINANTS), integrated against
                      the measured Nikon D7000 sensitivities of ../shared/data/camera_ssf,
                      80 patches under light falling off 4 stops, shot and read noise,
                      white-balanced on the illuminant's white.

Protocol: calibrate on scene A's pair the way selfcal.calibrate_pipeline does
(selfcal.pipeline.pairs.collect_pair_samples block means, then selfcal.pipeline.fit_pipeline), test
on every pixel of scene B.  Forward RMSE (raw -> rendered, 0-255) against the camera's
continuous rendering; backward RMSE (JPEG -> raw, raw in [0, 1]) over pixels with no JPEG
channel at 0 or 255 (a clipped code does not determine its raw).  Pixels are reported
(a) inside the convex hull of A's raw colours (scipy ConvexHull vertices of every pixel,
then Delaunay.find_simplex), (b) all, and (c) those the model itself trusts
(PipelineModel.outside_training is False: within the trust radius of a training colour).

Split: TUNING scenes (sim-ramps, sim-outdoor, ssf-D65) choose every parameter: the tone-curve
neutral weighting β (fit_pipeline's neutral_weighting), the forward LUT weight, γ of the
highlight stretch g before it (Gong et al. Fig. 3; 0: none), and the trust radius of
selfcal.pipeline.trust; HELD_OUT scenes (chart, blackmagic, sim-ramps-sat, sim-outdoor-sat,
ssf-A, ssf-D65-cc) are what the acceptance lines report (30 ordered pairs), the part swap
(which of M, f, the LUT and g carries the error) and the one / two / three training scenes.

    python3 -m bench.pipeline_crossscene                  # every table
    python3 -m bench.pipeline_crossscene --only tuning    # the tuning table alone
    python3 -m bench.pipeline_crossscene --only heldout --only swap --only multi
    python3 -m bench.pipeline_crossscene --only same      # same-scene regression
    python3 -m bench.pipeline_crossscene --only diagnose  # tuning pairs: where the
                                                               # forward error sits

The same-scene table repeats bench.pipeline's protocol on the two real raws (8-bit
rendering, random training pixels) and compares with the figures recorded before issue 16
(acceptance: no more than 10 % worse).

Rendered scenes are kept in --cache (default $TMPDIR/selfcal-crossscene-cache; computed
from ../shared/data, so never inside the repository); rendering one takes 1-3 minutes.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .pipeline import jpeg, read_raw_superpixels
from .data import camera_name, data_dir
from .tables import finish, start, table

WB_CODE = 14
SCENES = ("chart", "blackmagic", "sim-ramps", "sim-ramps-sat", "sim-outdoor",
          "sim-outdoor-sat", "ssf-D65", "ssf-A", "ssf-D65-cc")
TUNING = ("sim-ramps", "sim-outdoor", "ssf-D65")
HELD_OUT = ("chart", "blackmagic", "sim-ramps-sat", "sim-outdoor-sat", "ssf-A", "ssf-D65-cc")
SIZE = (300, 450)
SSF_CAMERA = ("Nikon", "D7000", "spectroscope", "Nikon_D7000_ssf.csv")
#: β candidates of fit_pipeline(neutral_weighting=...) tried on the tuning pairs.
BETAS = (None, 0.3, 0.15)
#: forward LUT weights tried on the tuning pairs ("auto": leave-one-out, the default).
LUT_WEIGHTS = ("auto", 1e-3, 1e-2)
#: γ of the highlight stretch g before the forward LUT (1.5: Gong et al. Fig. 3; 0: none).
STRETCHES = (1.5, 0.0)


# --------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------

def ssf_table():
    """(wavelengths in nm, (n, 3) sensitivities) of the measured D7000."""
    path = data_dir("camera_ssf", *SSF_CAMERA)
    rows = [ln.split(",") for ln in path.read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    t = np.array(rows, dtype=np.float64)
    keep = t[:, 0] <= 700
    return t[keep, 0], t[keep, 1:4]


def gaussian_reflectances(n, wl, rng):
    """Smooth reflectances: a level in 0.03-0.5 plus one to three Gaussian bumps or dips
    (centres 380-720 nm, σ 15-90 nm), clipped to [0.02, 0.95]."""
    out = np.empty((n, wl.size))
    for i in range(n):
        r = np.full(wl.size, rng.uniform(0.03, 0.5))
        for _ in range(rng.integers(1, 4)):
            mu, sig = rng.uniform(380, 720), rng.uniform(15, 90)
            r += rng.uniform(-0.5, 0.8) * np.exp(-0.5 * ((wl - mu) / sig) ** 2)
        out[i] = np.clip(r, 0.02, 0.95)
    return out


def ssf_scene(illuminant, reflectances, seed, gains, size=SIZE):
    """80 patches (8 x 10) of smooth reflectances under a CIE illuminant, seen by the
    measured D7000 sensitivities; light falls off 4 stops across the frame, with soft
    shading; a perfect white in full light at 0.45 of raw white; white-balanced on the
    illuminant's white, then divided by the camera model's WB gains."""
    import colour

    from selfcal.sim import SensorModel
    from selfcal.sim.scenes import unit_noise

    wl, ssf = ssf_table()
    sd = colour.SDS_ILLUMINANTS[illuminant]
    ill = np.interp(wl, sd.wavelengths, sd.values)
    rng = np.random.default_rng(seed)
    if reflectances == "gaussians":
        refl = gaussian_reflectances(80, wl, rng)
    else:
        sds = colour.SDS_COLOURCHECKERS["BabelColor Average"].values()
        cc = np.array([np.interp(wl, s.wavelengths, s.values) for s in sds])
        refl = np.concatenate([cc, gaussian_reflectances(56, wl, rng)])
    rng.shuffle(refl)
    cam = (refl * ill) @ ssf
    white = ill @ ssf
    h, w = size
    ys = np.linspace(0, h, 9).round().astype(int)
    xs = np.linspace(0, w, 11).round().astype(int)
    idx = np.zeros((h, w), dtype=int)
    for r in range(8):
        for c in range(10):
            idx[ys[r]:ys[r + 1], xs[c]:xs[c + 1]] = r * 10 + c
    yy, xx = np.mgrid[0:h, 0:w] / np.array([h, w], dtype=float)[:, None, None]
    light = np.exp2(-4.0 * (0.6 * xx + 0.4 * yy) + 0.5 * unit_noise(rng, (h, w), 20.0))
    radiance = cam[idx] * light[..., None] / white.max()
    raw = SensorModel(full_well_electrons=20000, read_noise=5e-4).expose(
        radiance, 0.45, np.random.default_rng(seed + 1)).astype(np.float64)
    return np.clip(raw * (white.max() / white), 0.0, 1.0) / gains


def synth_scene(kind, seed, gains, size=SIZE):
    """make_scene (kind "ramps-<saturation>") or natural_scene (kind "outdoor-<palette>")
    as white-balanced camera RGB, exposed by SensorModel, divided by the WB gains."""
    from selfcal import sim
    from selfcal.sim import conditions

    h, w = size
    if kind.startswith("ramps"):
        scene = sim.make_scene(h, w, dynamic_range_stops=8.0,
                                 saturation=float(kind.split("-")[1]), seed=seed)
        exposure = 0.6
    else:
        scene = conditions.natural_scene(h, w, palette=kind.split("-")[1], seed=seed)
        exposure = 0.35
    raw = sim.SensorModel().expose(scene, exposure, np.random.default_rng(seed + 7))
    return raw.astype(np.float64) / gains


def real_scene(fname, extra, gains):
    rho, wb = read_raw_superpixels(data_dir("raw", fname), extra)
    return np.clip(rho * wb, 0.0, 1.0) / gains


def scene_raw(name, cam):
    g = cam.gains
    makers = {
        "chart": lambda: real_scene("colorchart_canon550d.dng", 2, g),
        "blackmagic": lambda: real_scene("blackmagic_cinema.dng", 4, g),
        "sim-ramps": lambda: synth_scene("ramps-0.6", 0, g),
        "sim-ramps-sat": lambda: synth_scene("ramps-0.9", 1, g),
        "sim-outdoor": lambda: synth_scene("outdoor-colourful", 2, g),
        "sim-outdoor-sat": lambda: synth_scene("outdoor-saturated", 3, g),
        "ssf-D65": lambda: ssf_scene("D65", "gaussians", 10, g),
        "ssf-A": lambda: ssf_scene("A", "gaussians", 11, g),
        "ssf-D65-cc": lambda: ssf_scene("D65", "colorchecker", 12, g),
    }
    return makers[name]()


def load_scene(name, cam, cache: Path):
    """The scene's raw, the camera's continuous rendering and the JPEG (cached)."""
    cache.mkdir(parents=True, exist_ok=True)
    f = cache / f"{name}.npz"
    if not f.exists():
        raw = scene_raw(name, cam)
        truth = cam.render(raw)
        rendered = jpeg(np.round(truth * 255).astype(np.uint8), 95)
        np.savez(f, raw=raw, truth=truth, rendered=rendered)
    d = np.load(f)
    return {"name": name, "raw": d["raw"].reshape(-1, 3), "truth": d["truth"].reshape(-1, 3),
            "rendered": d["rendered"].reshape(-1, 3), "image_raw": d["raw"],
            "image_rendered": d["rendered"]}


# --------------------------------------------------------------------------------------
# fitting and scoring
# --------------------------------------------------------------------------------------

def training_samples(scenes, names, seed=0):
    """What calibrate_pipeline fits: block means of the pairs, joined (and their groups)."""
    from selfcal.pipeline.pairs import collect_pair_samples

    return collect_pair_samples([scenes[n]["image_raw"] for n in names],
                                [scenes[n]["image_rendered"] for n in names], seed=seed)[0]


def fit_selfcal(samples, **options):
    from selfcal.pipeline import PipelineOptions, fit_pipeline

    return fit_pipeline(samples.raw, samples.rendered, PipelineOptions(**options), seed=0,
                        groups=samples.groups)


def fit_baselines(samples):
    from selfcal.pipeline.baselines import (independent_polynomial_model,
                                            least_squares_rbf_model)

    return {"IndPoly": independent_polynomial_model(samples.raw, samples.rendered),
            "LS-T+RBF": least_squares_rbf_model(samples.raw, samples.rendered, seed=0)}


class Hull:
    """Convex hull of a set of raw colours (Delaunay of its vertices)."""

    def __init__(self, raw):
        from scipy.spatial import ConvexHull, Delaunay

        self.tri = Delaunay(raw[ConvexHull(raw).vertices])

    def inside(self, raw):
        return self.tri.find_simplex(raw) >= 0


def rmse(a, b, mask=None):
    if mask is not None:
        a, b = a[mask], b[mask]
    return float(np.sqrt(np.mean((a - b) ** 2))) if a.size else float("nan")


def score(model, test, inside, variant=None):
    """Forward (0-255) in hull / all / trusted, backward (unclipped codes) in hull / all,
    and the share of the test pixels the model trusts."""
    raw, truth, codes = test["raw"], test["truth"], test["rendered"]
    fwd = np.asarray(model.render(raw)).reshape(-1, 3)
    back = (model.to_raw(codes) if variant is None
            else model.to_raw(codes, variant=variant))
    back = np.asarray(back).reshape(-1, 3)
    ok = ~((codes == 0) | (codes == 255)).any(axis=1)
    trusted = None
    if hasattr(model, "outside_training") and model.training_colours is not None:
        trusted = ~model.outside_training(raw, "raw")
    return {"in": float(inside.mean()),
            "fwd_in": rmse(fwd, truth, inside) * 255, "fwd_all": rmse(fwd, truth) * 255,
            "fwd_trusted": (float("nan") if trusted is None
                            else rmse(fwd, truth, trusted) * 255),
            "trusted": float("nan") if trusted is None else float(trusted.mean()),
            "bwd_in": rmse(back, raw, inside & ok), "bwd_all": rmse(back, raw, ok)}


def f2(v):
    return "-" if not np.isfinite(v) else f"{v:.2f}"


def f4(v):
    return "-" if not np.isfinite(v) else f"{v:.4f}"


def with_forward_lut(model, weight, samples, stretch):
    """A copy of ``model`` whose forward LUT is refitted at a weight ("auto": leave-one-out)
    and highlight stretch γ on the same ``f(M ρ)`` of the training samples (what
    fit_pipeline does with them, but for the matrix search, which keeps its set)."""
    import copy

    from selfcal.pipeline.lattice import LatticeOptions, lattice_regression_lut

    y = np.clip(model.tone_curves(samples.raw @ model.matrix.T), 0.0, 1.0)
    out = copy.copy(model)
    out.forward_lut = lattice_regression_lut(y, samples.rendered,
                                             LatticeOptions(gamma=stretch), smoothness=weight)
    return out


def gmean(values):
    v = np.asarray([x for x in values if np.isfinite(x)])
    return float(np.exp(np.mean(np.log(v)))) if v.size else float("nan")


# --------------------------------------------------------------------------------------
# tables
# --------------------------------------------------------------------------------------

def tuning_tables(scenes, hulls):
    """Tuning pairs only: β of the neutral weighting x forward LUT weight; trust radius."""
    from selfcal.pipeline.trust import TrainingColours

    res, models = {}, {}
    for a in TUNING:
        s = training_samples(scenes, [a])
        for beta in BETAS:
            t0 = time.perf_counter()
            base = fit_selfcal(s, backward="lut", neutral_weighting=beta)
            print(f"  tuning fit {a}, β={beta}: {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr)
            for wt in LUT_WEIGHTS:
                for g in STRETCHES:
                    m = (base if (wt, g) == ("auto", 1.5)
                         else with_forward_lut(base, wt, s, g))
                    models[(a, beta, wt, g)] = m
                    for b in TUNING:
                        res[(a, b, beta, wt, g)] = score(m, scenes[b],
                                                         hulls[a].inside(scenes[b]["raw"]))
    configs = [(beta, wt, g) for beta in BETAS for wt in LUT_WEIGHTS for g in STRETCHES]
    pairs = [(a, b) for a in TUNING for b in TUNING]
    default = (None, "auto", 1.5)
    cross = {c: gmean(res[(a, b) + c]["fwd_in"] for a, b in pairs if a != b) for c in configs}
    same = {c: gmean(res[(a, a) + c]["fwd_in"] for a in TUNING) for c in configs}
    worst = {c: max(res[p + c]["fwd_in"] / res[p + default]["fwd_in"] for p in pairs)
             for c in configs}
    rows = [[f"β={c[0]}, LUT {c[1]}, γ={c[2]:g}"]
            + [f2(res[p + c]["fwd_in"]) for p in pairs]
            + [f2(cross[c]), f2(same[c]), f2(worst[c])] for c in configs]
    chosen = min(configs, key=lambda c: (round(worst[c], 3), cross[c]))
    print("\n### Tuning pairs: forward RMSE in hull (0-255) per β (tone-curve neutral "
          "weighting), forward LUT weight and γ of its highlight stretch g\n")
    short = {"sim-ramps": "ramps", "sim-outdoor": "outdoor", "ssf-D65": "ssf"}
    print(table(["configuration"]
                + [f"{short.get(a, a)}→{short.get(b, b)} "
                   f"({res[(a, b) + default]['in']:.2f})" for a, b in pairs]
                + ["gmean cross", "gmean same", "worst ratio to default"], rows))
    print(f"\n(in brackets: the share of test pixels in the training scene's hull)  chosen "
          f"on the tuning pairs (the lowest worst ratio to the old default β=None, LUT auto, "
          f"γ=1.5 over every tuning pair, same-scene ones included; ties: the lower cross-"
          f"scene geometric mean): β={chosen[0]}, LUT {chosen[1]}, γ={chosen[2]:g}")
    rows = []
    for radius in (0.02, 0.04, 0.06, 0.08):
        cells = []
        for a in TUNING:
            m = models[(a,) + chosen]
            tc = m.training_colours
            tcr = TrainingColours(tc.raw, tc.rendered, tc.raw_scale, radius)
            for b in TUNING:
                if a == b:
                    continue
                test = scenes[b]
                trusted = ~tcr.outside(test["raw"], "raw")
                fwd = m.render(test["raw"])
                cells.append((rmse(fwd, test["truth"], trusted) * 255, trusted.mean()))
        rows.append([radius, f2(max(c[0] for c in cells)), f2(gmean(c[0] for c in cells)),
                     f"{min(c[1] for c in cells):.2f}", f"{np.mean([c[1] for c in cells]):.2f}"])
    print("\n### Tuning pairs (cross-scene): the trust radius (forward RMSE of the pixels "
          "the model trusts, and their share); selfcal keeps the largest radius whose "
          "geometric mean is <= 2.5\n")
    print(table(["radius", "worst pair", "geometric mean", "least share", "mean share"],
                rows))
    return chosen


def heldout_fits(scenes):
    fits = {}
    for a in HELD_OUT:
        s = training_samples(scenes, [a])
        t0 = time.perf_counter()
        fits[a] = {"selfcal": fit_selfcal(s), "samples": s, **fit_baselines(s),
                   "β=0.3": fit_selfcal(s, neutral_weighting=0.3, backward="lut")}
        print(f"  held-out fit {a} ({len(s)} samples): {time.perf_counter() - t0:.0f} s",
              file=sys.stderr)
    return fits


def heldout_tables(scenes, hulls, fits, cam):
    """The cross-scene table on held-out pairs, the same-scene table, acceptance lines."""
    rows, same_rows, verdict, means = [], [], [], {k: [] for k in range(5)}
    floor = {}
    for b in HELD_OUT:   # the camera's own inverse (NUS jpg2raw) from the JPEG: a floor
        floor[b] = np.clip(cam.to_raw(scenes[b]["rendered"]), 0.0, 1.0).reshape(-1, 3)
    for a in HELD_OUT:
        for b in HELD_OUT:
            inside = hulls[a].inside(scenes[b]["raw"])
            codes = scenes[b]["rendered"]
            ok = ~((codes == 0) | (codes == 255)).any(axis=1)
            nus = rmse(floor[b], scenes[b]["raw"], inside & ok)
            r = {k: score(fits[a][k], scenes[b], inside)
                 for k in ("selfcal", "IndPoly", "LS-T+RBF", "β=0.3")}
            lut = score(fits[a]["selfcal"], scenes[b], inside, "lut")
            rbf = score(fits[a]["selfcal"], scenes[b], inside, "rbf")
            s, ip, ls = r["selfcal"], r["IndPoly"], r["LS-T+RBF"]
            row = [f"{a} → {b}", f"{s['in']:.2f}",
                   f"{f2(s['fwd_in'])} / {f2(r['β=0.3']['fwd_in'])} / "
                   f"{f2(ip['fwd_in'])} / {f2(ls['fwd_in'])}",
                   f2(s["fwd_in"] / ip["fwd_in"]),
                   f"{f2(s['fwd_all'])} / {f2(ip['fwd_all'])}",
                   f"{s['trusted']:.2f}: {f2(s['fwd_trusted'])}",
                   f"{f4(s['bwd_in'])} ({fits[a]['selfcal'].backward}) / {f4(lut['bwd_in'])}"
                   f" / {f4(rbf['bwd_in'])}",
                   f"{f4(ip['bwd_in'])} / {f4(ls['bwd_in'])} / {f4(nus)}",
                   f2(s["bwd_in"] / ip["bwd_in"]), f"{f4(s['bwd_all'])} / {f4(ip['bwd_all'])}"]
            if a == b:
                same_rows.append([a, f2(s["fwd_all"]), f2(ip["fwd_all"]), f2(ls["fwd_all"]),
                                  f4(s["bwd_all"]), f4(ip["bwd_all"]), f4(ls["bwd_all"]),
                                  f"{s['trusted']:.2f}"])
                continue
            rows.append(row)
            verdict.append((s["fwd_in"] <= 2.5, s["fwd_in"] <= 0.5 * ip["fwd_in"],
                            s["bwd_in"] <= 0.008, s["bwd_in"] <= 0.5 * ip["bwd_in"],
                            s["fwd_trusted"] <= 2.5, nus <= 0.5 * ip["bwd_in"]))
            for k, v in enumerate((s["fwd_in"], r["β=0.3"]["fwd_in"], ip["fwd_in"],
                                   ls["fwd_in"], s["fwd_trusted"])):
                means[k].append(v)
    hdr = ["train → test", "in hull",
           "fwd in hull selfcal / selfcal β=0.3 / IndPoly / LS-T+RBF",
           "fwd ratio", "fwd all selfcal / IndPoly", "trusted: fwd",
           "bwd in hull selfcal (chosen) / LUT / RBF",
           "bwd in hull IndPoly / LS-T+RBF / camera's own inverse",
           "bwd ratio", "bwd all selfcal / IndPoly"]
    print("\n### Held-out pairs: cross-scene RMSE (forward 0-255; backward raw [0, 1], "
          "unclipped codes)\n")
    print(table(hdr, rows))
    print("\ngeometric means over the held-out pairs, forward in hull: selfcal "
          + " / ".join(f2(gmean(means[k])) for k in range(4))
          + " (selfcal / selfcal β=0.3 / IndPoly / LS-T+RBF); selfcal on the pixels it "
          f"trusts: {f2(gmean(means[4]))}")
    print("\n### Held-out scenes: same scene (every pixel; backward unclipped codes)\n")
    print(table(["scene", "fwd selfcal", "fwd IndPoly", "fwd LS-T+RBF", "bwd selfcal",
                 "bwd IndPoly", "bwd LS-T+RBF", "trusted share"], same_rows))
    v = np.array(verdict)
    n = len(verdict)
    print(f"\nacceptance on {n} held-out pairs: forward in hull <= 2.5: {v[:, 0].sum()}/{n};"
          f" <= 0.5 x IndPoly: {v[:, 1].sum()}/{n}; backward in hull <= 0.008: "
          f"{v[:, 2].sum()}/{n}; <= 0.5 x IndPoly: {v[:, 3].sum()}/{n}.  Forward on the "
          f"pixels the model trusts <= 2.5: {v[:, 4].sum()}/{n}; the camera's own inverse "
          f"is <= 0.5 x IndPoly's backward on {v[:, 5].sum()}/{n}")


class Forward:
    """``P = y + R(g(y))``, ``y = f(M ρ)`` from given parts (a part swapped for the truth)."""

    def __init__(self, m, f, lut=None):
        self.m, self.f, self.lut = np.asarray(m), f, lut

    def render(self, raw):
        y = np.clip(self.f(np.asarray(raw) @ self.m.T), 0.0, 1.0)
        return y if self.lut is None else np.clip(y + self.lut.residual(y), 0.0, 1.0)


SWAP_TRAIN = ("chart", "blackmagic", "ssf-A", "sim-ramps-sat")


def swap_table(scenes, hulls, fits, cam):
    """Which part carries the cross-scene error: each swapped for the camera's truth."""
    from selfcal.pipeline.lattice import LatticeOptions, lattice_regression_lut
    from selfcal.pipeline.tone import monotone_tone_curves

    weighting = fits[SWAP_TRAIN[0]]["selfcal"].diagnostics.get("neutral_weighting")
    rows = []
    test_samples = {}
    for a in SWAP_TRAIN:
        model, s = fits[a]["selfcal"], fits[a]["samples"]
        t = cam.transform
        x = s.raw @ t.T
        w = None if weighting is None else np.exp(-(_saturation(s.rendered) / weighting) ** 2)
        f_t = monotone_tone_curves(x, s.rendered, weights=w)
        y_t = np.clip(f_t(x), 0, 1)
        y_tt = np.clip(cam.tone(x), 0, 1)
        y = np.clip(model.tone_curves(s.raw @ model.matrix.T), 0, 1)
        parts = {
            "fitted": model,
            "M=T": Forward(t, f_t, lattice_regression_lut(y_t, s.rendered, smoothness="auto")),
            "M=T, f=true": Forward(t, cam.tone, lattice_regression_lut(y_tt, s.rendered,
                                                                       smoothness="auto")),
            "no LUT": Forward(model.matrix, model.tone_curves),
            "g=identity": Forward(model.matrix, model.tone_curves, lattice_regression_lut(
                y, s.rendered, LatticeOptions(gamma=0.0), smoothness="auto")),
        }
        for b in SWAP_TRAIN:
            if b == a:
                continue
            test = scenes[b]
            inside = hulls[a].inside(test["raw"])
            if b not in test_samples:
                test_samples[b] = training_samples(scenes, [b])
            tb = test_samples[b]
            yb = np.clip(model.tone_curves(tb.raw @ model.matrix.T), 0, 1)
            parts["LUT fitted on test scene"] = Forward(
                model.matrix, model.tone_curves,
                lattice_regression_lut(yb, tb.rendered, smoothness="auto"))
            cells = [f"{a} → {b}", f"{inside.mean():.2f}"]
            for p in parts.values():
                cells.append(f2(rmse(np.asarray(p.render(test["raw"])).reshape(-1, 3),
                                     test["truth"], inside) * 255))
            nogamut = cam.tone(np.clip(test["raw"] @ t.T, 0, 1))
            cells.append(f2(rmse(nogamut, test["truth"], inside) * 255))
            trusted = ~model.outside_training(test["raw"], "raw")
            fwd = model.render(test["raw"])
            cells.append(f"{f2(rmse(fwd, test['truth'], inside & trusted) * 255)} / "
                         f"{f2(rmse(fwd, test['truth'], inside & ~trusted) * 255)} "
                         f"({(inside & ~trusted).mean() / max(inside.mean(), 1e-9):.2f})")
            rows.append(cells)
    print("\n### Swap each part for the truth (forward RMSE in hull, 0-255; held-out "
          "pairs).  M=T: the camera's 3x3 transform, tone curves and LUT refitted;\n"
          "M=T, f=true: also the camera's tone curves, LUT refitted; no LUT: fitted M and f "
          "alone; g=identity: LUT without the highlight stretch; LUT fitted on test\n"
          "scene: the fitted M and f with the LUT fitted to the test scene's samples "
          "(an oracle).  'truth, no gamut map' is f(clip(T ρ)) against the camera: what "
          "the gamut map does.\nLast column: the fitted model on in-hull pixels near / far "
          "from its training colours (the share of in-hull pixels that are far)\n")
    print(table(["train → test", "in hull"] + list(parts) + ["truth, no gamut map",
                                                             "fitted: near / far (far share)"],
                rows))


def _saturation(rgb):
    from selfcal.stack.samples import hsv_saturation

    return hsv_saturation(rgb)


def multi_table(scenes, hulls, fits):
    """What a second and a third training scene buy (held-out scenes; each test scene is
    predicted from the next one, two and three held-out scenes in a fixed cyclic order)."""
    from selfcal.pipeline.baselines import independent_polynomial_model

    cache = {}

    def fitted(names, loso=True):
        key = (tuple(names), loso)
        if key not in cache:
            s = training_samples(scenes, list(names))
            if not loso:
                s.groups = None
            t0 = time.perf_counter()
            cache[key] = (fit_selfcal(s), independent_polynomial_model(s.raw, s.rendered))
            print(f"  multi fit {' + '.join(names)} ({len(s)} samples, "
                  f"{'LOSO' if loso else 'LOO'}): {time.perf_counter() - t0:.0f} s",
                  file=sys.stderr)
        return cache[key]

    rows, summary = [], {k: [] for k in ("1", "2", "3", "3 LOO", "ip1", "ip3", "b1", "b3")}
    n = len(HELD_OUT)
    for i, b in enumerate(HELD_OUT):
        train = [HELD_OUT[(i + k) % n] for k in (1, 2, 3)]
        test = scenes[b]
        base = hulls[train[0]].inside(test["raw"])
        union = Hull(np.concatenate([scenes[t]["raw"] for t in train])).inside(test["raw"])
        res = {"1": (fits[train[0]]["selfcal"], fits[train[0]]["IndPoly"])}
        res["2"] = fitted(train[:2])
        res["3"] = fitted(train)
        res["3 LOO"] = (fitted(train, loso=False)[0], None)
        sc = {k: score(m, test, base) for k, (m, _) in res.items()}
        ip = {k: score(res[k][1], test, base) for k in ("1", "3")}
        for k in ("1", "2", "3", "3 LOO"):
            summary[k].append(sc[k]["fwd_in"])
        summary["ip1"].append(ip["1"]["fwd_in"])
        summary["ip3"].append(ip["3"]["fwd_in"])
        summary["b1"].append(sc["1"]["bwd_in"])
        summary["b3"].append(sc["3"]["bwd_in"])
        u3 = score(res["3"][0], test, union)
        rows.append([b, " + ".join(train), f"{base.mean():.2f} / {union.mean():.2f}",
                     " / ".join(f2(sc[k]["fwd_in"]) for k in ("1", "2", "3", "3 LOO")),
                     f"{f2(ip['1']['fwd_in'])} / {f2(ip['3']['fwd_in'])}",
                     f2(u3["fwd_in"]),
                     " / ".join(f2(sc[k]["fwd_all"]) for k in ("1", "2", "3")),
                     " / ".join(f4(sc[k]["bwd_in"]) for k in ("1", "2", "3")),
                     " / ".join(f"{sc[k]['trusted']:.2f}" for k in ("1", "2", "3"))])
    rows.append(["geometric mean", "", "", " / ".join(f2(gmean(summary[k])) for k in
                                                       ("1", "2", "3", "3 LOO")),
                 f"{f2(gmean(summary['ip1']))} / {f2(gmean(summary['ip3']))}", "", "",
                 f"{f4(gmean(summary['b1']))} / - / {f4(gmean(summary['b3']))}", ""])
    print("\n### Training on one, two, three scenes (held-out scenes; forward 0-255 on the "
          "test pixels inside the first training scene's hull unless said; LOSO: "
          "regulariser weights by leave-one-scene-out, LOO: by leave-one-sample-out)\n")
    print(table(["test", "training scenes (in order)", "in hull of first / of all three",
                 "fwd 1 / 2 / 3 scenes / 3 LOO", "IndPoly fwd 1 / 3",
                 "fwd 3, hull of all three", "fwd all pixels 1 / 2 / 3",
                 "bwd 1 / 2 / 3", "trusted share 1 / 2 / 3"], rows))
    better = sum(s3 < s1 for s1, s3 in zip(summary["1"], summary["3"]))
    print(f"\nthree scenes lower the forward error against one on {better}/{n} test scenes; "
          f"two: {sum(s2 < s1 for s1, s2 in zip(summary['1'], summary['2']))}/{n}")


def diagnose_table(scenes, hulls):
    """Tuning pairs only (issue 16, what still carries the forward error): the default
    model scored in the hull of scene A's pixels (the acceptance protocol) and in the hull
    of A's training samples (the colours the fit was given: block means, without the
    clipped and high-gradient blocks); and two principled changes, each scored in the
    pixel hull: the forward LUT without its unpenalised linear term (affine=False: a global
    linear term extrapolates into colours no sample constrains) and samples that keep
    blocks clipped throughout (pair_samples keep_clipped)."""
    import copy

    from selfcal.pipeline.lattice import LatticeOptions, lattice_regression_lut
    from selfcal.pipeline.pairs import BlockRejection, collect_pair_samples

    rows, cols = [], {k: [] for k in ("pixel", "sample", "affine", "clipped")}
    for a in TUNING:
        s = training_samples(scenes, [a])
        sk = collect_pair_samples([scenes[a]["image_raw"]], [scenes[a]["image_rendered"]],
                                  seed=0, rejection=BlockRejection(keep_clipped=True))[0]
        m, mk = fit_selfcal(s, backward="lut"), fit_selfcal(sk, backward="lut")
        y = np.clip(m.tone_curves(s.raw @ m.matrix.T), 0.0, 1.0)
        ma = copy.copy(m)
        ma.forward_lut = lattice_regression_lut(y, s.rendered, LatticeOptions(affine=False),
                                                smoothness="auto")
        sample_hull = Hull(s.raw)
        for b in TUNING:
            t = scenes[b]
            pix, smp = hulls[a].inside(t["raw"]), sample_hull.inside(t["raw"])
            err = {k: rmse(np.asarray(mod.render(t["raw"])).reshape(-1, 3), t["truth"],
                           mask) * 255
                   for k, mod, mask in (("pixel", m, pix), ("sample", m, smp),
                                        ("affine", ma, pix), ("clipped", mk, pix))}
            if a != b:
                for k in cols:
                    cols[k].append(err[k])
            rows.append([f"{a} → {b}", f"{pix.mean():.2f} / {smp.mean():.2f}",
                         f"{f2(err['pixel'])} / {f2(err['sample'])}", f2(err["affine"]),
                         f"{f2(err['clipped'])} ({len(sk)} vs {len(s)} samples)"])
    rows.append(["geometric mean, cross-scene", "",
                 f"{f2(gmean(cols['pixel']))} / {f2(gmean(cols['sample']))}",
                 f2(gmean(cols["affine"])), f2(gmean(cols["clipped"]))])
    print("\n### Tuning pairs: where the forward error sits (forward RMSE 0-255; hull of A's "
          "pixels / of A's training samples; changes scored in the pixel hull)\n")
    print(table(["train → test", "in hull: pixels / samples",
                 "default fwd: pixel hull / sample hull", "LUT affine=False",
                 "keep_clipped samples"], rows))


#: bench.pipeline's same-scene D7000 figures before issue 16 (BENCHMARKS.md, "RAW path:
#: forward and backward model (issue 4)", targets table): (raw file, block factor) and, per
#: training size, (forward 0-255, backward raw) on every pixel of the 8-bit rendering.
SAME_SCENE_BEFORE = {
    ("colorchart_canon550d.dng", 1): {1500: (1.03, 0.0015), 140: (1.72, 0.0022)},
    ("blackmagic_cinema.dng", 2): {1500: (0.78, 0.0015), 140: (0.96, 0.0018)},
}


def same_scene_table(cam, cache: Path):
    """Same-scene regression: bench.pipeline's protocol (its read_raw_superpixels, 8-bit
    rendering, train_samples and fit_all with seed 0) on the two real raws, against the
    figures recorded before issue 16 (SAME_SCENE_BEFORE); acceptance: no more than 10 %
    worse."""
    from .pipeline import fit_all, scores

    cache.mkdir(parents=True, exist_ok=True)
    rows, ok = [], []
    for (fname, extra), before in SAME_SCENE_BEFORE.items():
        f = cache / f"same-{fname.split('_')[0]}-{extra}.npz"
        if not f.exists():
            rho, wb = read_raw_superpixels(data_dir("raw", fname), extra)
            raw = np.clip(rho * wb, 0.0, 1.0) / cam.gains
            truth = cam.render(raw)
            np.savez(f, raw=raw, truth=truth)
        d = np.load(f)
        ds = {"raw": d["raw"], "truth": d["truth"],
              "rendered": np.round(d["truth"] * 255).astype(np.uint8)}
        for n, (fwd0, bwd0) in before.items():
            fits = fit_all(ds, n, seed=0, with_ls=False)
            fwd, bwd, _ = scores(fits["selfcal"], ds)
            good = (fwd <= 1.1 * fwd0, bwd <= 1.1 * bwd0)
            ok.extend(good)
            rows.append([f"D7000 model on {fname.split('_')[0]}", n,
                         f"{fwd:.2f} / {fwd0:.2f} ({fwd / fwd0:.2f}x)",
                         "yes" if good[0] else "NO",
                         f"{bwd:.4f} / {bwd0:.4f} ({bwd / bwd0:.2f}x)",
                         "yes" if good[1] else "NO"])
            print(f"  same-scene fit {fname}, {n} samples: {fits['fit_seconds']:.0f} s",
                  file=sys.stderr)
    print("\n### Same scene, bench.pipeline's protocol (8-bit rendering, random training "
          "pixels, seed 0, every pixel scored): now / before issue 16 (its BENCHMARKS "
          "targets table)\n")
    print(table(["data", "train", "forward now / before", "<= 1.1x", "backward now / before",
                 "<= 1.1x"], rows))
    print(f"\nsame-scene figures no more than 10 % worse than before issue 16: "
          f"{sum(ok)}/{len(ok)}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", choices=("tuning", "heldout", "swap", "multi", "same",
                                              "diagnose"),
                    action="append", help="run only these tables (repeatable)")
    ap.add_argument("--cache", type=Path,
                    default=Path(tempfile.gettempdir()) / "selfcal-crossscene-cache",
                    help="folder for the rendered scenes (outside the repository)")
    args = ap.parse_args(argv)
    start("pipeline_crossscene", "both")
    parts = set(args.only or ("tuning", "heldout", "swap", "multi", "same"))

    from selfcal.pipeline.nus import read_nus_model

    cam = read_nus_model(data_dir("nus_model_nikon_d7000"), wb_code=WB_CODE)
    t0 = time.perf_counter()
    names = set(() if parts <= {"same", "diagnose"} else TUNING if parts <= {"tuning"}
                else SCENES if "tuning" in parts else HELD_OUT)
    if "diagnose" in parts:
        names |= set(TUNING)
    scenes = {n: load_scene(n, cam, args.cache) for n in sorted(names)}
    hulls = {n: Hull(scenes[n]["raw"]) for n in scenes}
    print(f"## selfcal cross-scene benchmark ({camera_name(cam)}; scenes {', '.join(sorted(scenes))}; "
          f"JPEG q95)")
    if "same" in parts:
        same_scene_table(cam, args.cache)
    if "tuning" in parts:
        tuning_tables(scenes, hulls)
    if "diagnose" in parts:
        diagnose_table(scenes, hulls)
    if parts & {"heldout", "swap", "multi"}:
        fits = heldout_fits(scenes)
        if "heldout" in parts:
            heldout_tables(scenes, hulls, fits, cam)
        if "swap" in parts:
            swap_table(scenes, hulls, fits, cam)
        if "multi" in parts:
            multi_table(scenes, hulls, fits)
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
    finish()
