"""Issue 26: does the odd/even test measure accuracy?  Both on the same simulated stacks.

The real-stack acceptance lines of issue 26 are truth-free: (a) odd/even agreement on 8×8
block means (``bench_hdr_oddeven.py``) and (b) odd/even median |z| in 0.55–0.85
(``bench_uncertainty.py --parts real``).  Here both are measured on simulated stacks where
the radiance is known, beside the error against the truth, so that one can see whether the
odd/even ranking of the methods follows the truth ranking and whether |z| lands in the
window where σ is calibrated against the truth.  Nothing is chosen here.

Stacks: the hard stacks of ``bench_hdr_synthetic.py`` (``make_scene(saturation 0.9, 14
stops)``, random colour matrix, smooth gamut map, one DoRF curve, shot + read noise, OpenCV
JPEG 4:2:0 at quality 85/90/95 by seed), shot in *cells* shaped like the real stacks:
``frames`` shots from 1/250 s in steps of ``step`` stops, shutter jitter uniform ±``jitter``
(``simulate_stack``'s relative jitter; 0.08 puts the largest |log(true/nominal)| of a
stack near the 0.05–0.09 that the real EXIF times show in BENCHMARKS, "What the bias is
not"; 0 = exact times, where every peer's model holds best).  The same curves and seeds in
every cell (held-out: odd curves ``1, 1+step, …``, seed 1000 + i; tuning: even curves,
seed i).

Methods, each calibrating its own curve from **all** frames with the nominal times, as the
real bench does: selfcal default (``calibrate_response`` + ``merge_hdr``), selfcal hat
(same model, ``weighting="hat"``), OpenCV (``CalibrateDebevec`` + ``MergeDebevec``),
colour-hdri (``camera_response_functions_Debevec1997`` + ``image_stack_to_HDRI``); and the
oracle: selfcal's merge given the true inverse response and the true (jittered) times.

Per stack and method:

* **truth** -- the full-stack merge against the radiance, scored by
  ``bench_hdr_synthetic.scores`` (median relative error over the scored channels of
  ``truth_masks`` after one global scale); "8×8": the same on 8×8 block means of the merge
  and of the truth (``bench_hdr_oddeven.block_mean``), over the (block, channel) pairs
  whose every pixel is scored;
* **odd/even** -- frames in exposure order, the odd- and even-indexed ones merged
  separately with the method's one curve, scored by ``bench_hdr_oddeven.agreement`` per
  pixel and ``block_agreement`` on 8×8 block means over the pixels both halves measure
  (``bench_hdr_oddeven.measured``): the real bench's scoring, imported.

For selfcal's default and the oracle, the halves are merged again with
``MergeOptions(sigma=True)``: the odd/even ``|z|`` exactly as ``bench_uncertainty.py``'s
real part (σ "noise": the model's band removed; "full": as returned), and each half's
``|E − E_true| / σ`` over its scored channels that it measures (absolute, and after the
global scale of ``bench_hdr_synthetic``'s score; 0.674 for a perfect Gaussian σ).

    python bench/bench_hdr_oddeven_truth.py [--split heldout|tuning] [--step 20]
        [--size 192x288] [--cells 6:1:0.08,6:1:0,...] [--detail] [--jobs 2]

Default cells: 6 and 12 frames × 1 and 1/2 stop steps × jitter 0.08 and 0 (eight cells).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from multiprocessing import Pool
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import colour_hdri_stack, data_dir, table  # noqa: E402

T0 = 1 / 250
METHODS = ("selfcal", "selfcal hat", "OpenCV", "colour-hdri", "oracle")
PEERS = ("OpenCV", "colour-hdri")
CALIBRATING = METHODS[:4]
BLOCK = 8
#: (frames, step in stops, jitter): shaped like the real stacks (3-9 frames per half, 1/3
#: to 1 stop apart; here 3 or 6 per half), each with the real shutters' error and exact.
CELLS = tuple((f, s, j) for f in (6, 12) for s in (1.0, 0.5) for j in (0.08, 0.0))


def _init_worker():
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    warnings.filterwarnings("ignore")


def cell_name(cell) -> str:
    frames, step, jitter = cell
    return f"{frames} fr, {step:g} stop, ±{jitter:g}"


# --------------------------------------------------------------------------------------
# merges: (full, odd half, even half) per method
# --------------------------------------------------------------------------------------

def selfcal_merges(images, times, halves, model, **kwargs):
    import selfcal

    full = selfcal.merge_hdr(images, times, model, **kwargs).radiance
    return [full] + [selfcal.merge_hdr([images[k] for k in h], [times[k] for k in h], model,
                                       **kwargs).radiance for h in halves]


def opencv_merges(images, times, halves):
    import cv2

    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in images]
    t = np.asarray(times, np.float32)
    response = cv2.createCalibrateDebevec().process(bgr, t)
    merge = cv2.createMergeDebevec()
    return [merge.process([bgr[k] for k in h], t[list(h)], response)[:, :, ::-1]
            for h in (tuple(range(len(images))),) + halves]


def colour_hdri_merges(images, times, halves):
    from colour_hdri import camera_response_functions_Debevec1997, image_stack_to_HDRI

    crfs = camera_response_functions_Debevec1997(colour_hdri_stack(images, times))
    # image_stack_to_HDRI empties the stack it is given: a fresh one per merge
    return [image_stack_to_HDRI(colour_hdri_stack([images[k] for k in h],
                                                  [times[k] for k in h]),
                                camera_response_functions=crfs)
            for h in (tuple(range(len(images))),) + halves]


# --------------------------------------------------------------------------------------
# scores
# --------------------------------------------------------------------------------------

def truth_scores(est, e_true, scored):
    """(per pixel, 8×8) median relative error against the truth, ``scores``' global scale."""
    from bench_hdr_oddeven import block_mean
    from bench_hdr_synthetic import scores

    none = np.zeros(scored.shape[:2], bool)
    px = scores(est, e_true, scored, none)[0]
    h, w = (scored.shape[0] // BLOCK) * BLOCK, (scored.shape[1] // BLOCK) * BLOCK
    bscored = scored[:h, :w].reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3).all(axis=(1, 3))
    blk = scores(block_mean(est, BLOCK), block_mean(e_true, BLOCK), bscored,
                 np.zeros(bscored.shape[:2], bool))[0]
    return px, blk


def z_median(res, mask, channels=None):
    """Median odd/even |z| as ``bench_uncertainty.real_task`` computes it; ``channels``
    (HxWx3 bool): only those (pixel, channel) pairs."""
    keep = mask & ~res[0].unmeasured & ~res[1].unmeasured
    if channels is not None:
        keep = keep[..., None] & channels
    a, b = (np.asarray(r.radiance, np.float64)[keep] for r in res)
    sa, sb = (np.asarray(r.sigma, np.float64)[keep] for r in res)
    ok = (a > 0) & (b > 0) & np.isfinite(sa) & np.isfinite(sb)
    g = np.exp(-float(np.median(np.log(a[ok] / b[ok]))))
    z = (a[ok] * g - b[ok]) / np.sqrt((sa[ok] * g) ** 2 + sb[ok] ** 2)
    return float(np.median(np.abs(z)))


def truth_over_sigma(r, e_true, scored):
    """(absolute, after the global scale) median |E − E_true|/σ of one merge, as
    ``bench_uncertainty.sim_task``."""
    keep = scored & ~r.unmeasured[..., None]
    E, S, T = (np.asarray(a, np.float64)[keep] for a in (r.radiance, r.sigma, e_true))
    ok = (E > 0) & np.isfinite(S) & (S > 0)
    E, S, T = E[ok], S[ok], T[ok]
    lr = np.log(T / E)
    s = float(np.exp(np.median(lr[np.abs(lr - np.median(lr)) <= np.log(2)])))
    return float(np.median(np.abs(E - T) / S)), float(np.median(np.abs(s * E - T) / (s * S)))


def sigma_checks(images, times, halves, mask, e_true, scored, model, label):
    """|z| and half-vs-truth |E − E_true|/σ for one model (noise σ and, if the model has a
    band, full σ)."""
    from dataclasses import replace

    import selfcal
    from selfcal.hdr import MergeOptions

    out = {}
    variants = [("noise", replace(model, inverse_log_sigma=None))]
    if model.inverse_log_sigma is not None:
        variants.append(("full", model))
    for name, m in variants:
        res = [selfcal.merge_hdr([images[k] for k in h], [times[k] for k in h], m,
                                 options=MergeOptions(sigma=True)) for h in halves]
        out[f"{label} z {name}"] = z_median(res, mask)
        # the same on the channels the truth scores (in gamut, above the floor): the two
        # checks on one pixel set
        out[f"{label} z {name} scored"] = z_median(res, mask, scored)
        ts = [truth_over_sigma(r, e_true, scored) for r in res]
        out[f"{label} t/s {name}"] = float(np.mean([t[0] for t in ts]))
        out[f"{label} t/s {name} scaled"] = float(np.mean([t[1] for t in ts]))
    return out


# --------------------------------------------------------------------------------------
# one stack
# --------------------------------------------------------------------------------------

def one_stack(task):
    cell, index, seed, size = task
    import scipy.io as sio

    import selfcal
    from bench_hdr_oddeven import agreement, block_agreement, measured
    from bench_hdr_synthetic import QUALITIES, SATURATION, truth_masks
    from selfcal import sim
    from selfcal.response.model import ResponseModel

    t0 = time.perf_counter()
    frames, step, jitter = cell
    times = [T0 * 2.0 ** (step * k) for k in range(frames)]
    mat = sio.loadmat(data_dir("dorf_emor", "201_CRF_data.mat"))
    curve = sim.ToneCurve.from_table(mat["I"][index], mat["B"][index], name=f"dorf{index}")
    pipe = sim.default_pipeline(gamut="smooth", curves=curve, seed=seed)
    scene = sim.make_scene(*size, dynamic_range_stops=14.0, saturation=SATURATION, seed=seed)
    stack = sim.simulate_stack(scene, pipe, times, jitter=jitter,
                               jpeg_quality=QUALITIES[seed % len(QUALITIES)], seed=seed)
    e_true, scored, *_ = truth_masks(stack)
    images = stack.images
    true_t = [float(t) for t in stack.true_exposures]
    halves = (tuple(range(1, frames, 2)), tuple(range(0, frames, 2)))
    mask = measured([images[k] for k in halves[0]]) & measured([images[k] for k in halves[1]])

    model = selfcal.calibrate_response(images, times)
    truth = ResponseModel(intensity=np.arange(256) / 255.0, inverse=stack.inverse_response(),
                          coefficients=np.zeros((3, 1)), basis_name="truth",
                          exposures=np.asarray(true_t), exposure_times=list(times),
                          sources=[f"array #{k}" for k in range(frames)])
    maps = {"selfcal": selfcal_merges(images, times, halves, model),
            "selfcal hat": selfcal_merges(images, times, halves, model, weighting="hat"),
            "OpenCV": opencv_merges(images, times, halves),
            "colour-hdri": colour_hdri_merges(images, times, halves),
            "oracle": selfcal_merges(images, true_t, halves, truth)}
    out = {"cell": cell, "index": index, "seed": seed, "measured": float(mask.mean()),
           "t_off": float(np.max(np.abs(np.log(np.asarray(true_t) / np.asarray(times)))))}
    for m, (full, odd, even) in maps.items():
        out[m] = {"truth": truth_scores(full, e_true, scored),
                  "oe": (agreement(odd, even, mask)[0],
                         block_agreement(odd, even, mask, BLOCK)[0])}
    out.update(sigma_checks(images, times, halves, mask, e_true, scored, model, "selfcal"))
    out.update(sigma_checks(images, true_t, halves, mask, e_true, scored, truth, "oracle"))
    out["seconds"] = time.perf_counter() - t0
    return out


# --------------------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------------------

def _rank_stats(rs, truth_k, oe_k):
    """Per stack: Kendall τ between the truth and the odd/even scores of the four
    calibrating methods; whether the winners match; the (a) question, selfcal ≤ the best
    peer, answered by odd/even and by the truth."""
    from scipy.stats import kendalltau

    taus, same_winner, a = [], 0, {"both": 0, "odd/even only": 0, "truth only": 0,
                                   "neither": 0}
    for r in rs:
        t = [r[m]["truth"][truth_k] for m in CALIBRATING]
        o = [r[m]["oe"][oe_k] for m in CALIBRATING]
        taus.append(kendalltau(t, o)[0])
        same_winner += int(np.argmin(t) == np.argmin(o))
        by_oe = r["selfcal"]["oe"][oe_k] <= min(r[p]["oe"][oe_k] for p in PEERS)
        by_t = r["selfcal"]["truth"][truth_k] <= min(r[p]["truth"][truth_k] for p in PEERS)
        a[{(True, True): "both", (True, False): "odd/even only",
           (False, True): "truth only", (False, False): "neither"}[(by_oe, by_t)]] += 1
    return float(np.median(taus)), same_winner, a


def method_table(rs):
    rows = []
    for m in METHODS:
        wins_t = sum(min(CALIBRATING, key=lambda k: r[k]["truth"][0]) == m for r in rs)
        wins_o = sum(min(CALIBRATING, key=lambda k: r[k]["oe"][1]) == m for r in rs)
        rows.append([m] + [f"{np.median([r[m][k][i] for r in rs]):.4f}"
                           for k, i in (("truth", 0), ("truth", 1), ("oe", 0), ("oe", 1))]
                    + (["", ""] if m == "oracle" else [wins_t, wins_o]))
    return table(["method", "truth: per pixel", "truth: 8×8", "odd/even: per pixel",
                  "odd/even: 8×8", "truth best (px)", "odd/even best (8×8)"], rows)


def ranking_table(groups):
    rows = []
    for name, rs in groups:
        oracle_first = sum(r["oracle"]["oe"][1] <= min(r[m]["oe"][1] for m in CALIBRATING)
                           for r in rs)
        for truth_k, oe_k in ((0, 1), (1, 1), (0, 0)):
            tau, same, a = _rank_stats(rs, truth_k, oe_k)
            rows.append([name, len(rs), ("per pixel", "8×8")[truth_k],
                         ("per pixel", "8×8")[oe_k], f"{tau:+.2f}", same, a["both"],
                         a["odd/even only"], a["truth only"], a["neither"],
                         oracle_first if oe_k else ""])
    return table(["cell", "stacks", "truth", "odd/even", "τ", "same winner",
                  "selfcal ≤ best peer: by both", "by odd/even only", "by truth only",
                  "by neither", "oracle lowest o/e 8×8"], rows)


def sigma_table(groups):
    rows = []
    for name, rs in groups:
        row = [name]
        for label in ("selfcal z noise", "selfcal z full", "selfcal t/s noise",
                      "selfcal t/s noise scaled", "selfcal t/s full",
                      "selfcal t/s full scaled", "oracle z noise", "oracle t/s noise"):
            row.append(f"{np.median([r[label] for r in rs]):.3f}")
        for who, kind in (("selfcal", "full"), ("selfcal", "noise"), ("oracle", "noise")):
            ok = [r for r in rs if 0.6 <= r[f"{who} t/s {kind}"] <= 0.8]
            inside = sum(0.55 <= r[f"{who} z {kind}"] <= 0.85 for r in ok)
            z_in = sum(0.55 <= r[f"{who} z {kind}"] <= 0.85 for r in rs)
            row.append(f"{len(ok)} / {inside} / {z_in}")
        rows.append(row)
    return table(["cell", "selfcal |z| noise", "|z| full", "|E−E*|/σ noise",
                  "(scaled)", "|E−E*|/σ full", "(scaled)", "oracle |z|",
                  "oracle |E−E*|/σ",
                  "selfcal full: σ calibrated / of them |z| in window / |z| in window",
                  "selfcal noise: same", "oracle: same"], rows)


def same_pixels_table(groups):
    rows = []
    for name, rs in groups:
        rows.append([name] + [f"{np.median([r[k] for r in rs]):.3f}" for k in (
            "oracle z noise", "oracle z noise scored", "oracle t/s noise",
            "selfcal z noise", "selfcal z noise scored", "selfcal z full",
            "selfcal z full scored")])
    return table(["cell", "oracle |z|: o/e pixels", "truth-scored channels",
                  "oracle |E−E*|/σ", "selfcal |z| noise: o/e pixels",
                  "truth-scored channels", "selfcal |z| full: o/e pixels",
                  "truth-scored channels"], rows)


def detail_table(results):
    rows = []
    for r in results:
        rows.append([cell_name(r["cell"]), r["index"], f"{r['t_off']:.3f}",
                     f"{100 * r['measured']:.0f} %"]
                    + [f"{r[m]['truth'][0]:.4f} / {r[m]['oe'][1]:.4f}" for m in METHODS]
                    + [f"{r['selfcal z full']:.2f} / {r['selfcal t/s full']:.2f}",
                       f"{r['oracle z noise']:.2f} / {r['oracle t/s noise']:.2f}"])
    return table(["cell", "curve", "max |log t/t_nom|", "o/e pixels"]
                 + [f"{m}: truth px / o/e 8×8" for m in METHODS]
                 + ["selfcal |z| / |E−E*|/σ (full)", "oracle |z| / |E−E*|/σ"], rows)


def parse_cells(text):
    cells = []
    for part in text.split(","):
        frames, step, jitter = part.split(":")
        cells.append((int(frames), float(step), float(jitter)))
    return tuple(cells)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", choices=("heldout", "tuning"), default="heldout")
    parser.add_argument("--step", type=int, default=20, help="DoRF curve step")
    parser.add_argument("--size", default="192x288")
    parser.add_argument("--cells", default=",".join(f"{f}:{s:g}:{j:g}" for f, s, j in CELLS),
                        help="frames:step (stops):jitter, comma-separated")
    parser.add_argument("--detail", action="store_true", help="print every stack too")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    cells = parse_cells(args.cells)
    heldout = args.split == "heldout"
    step = max(2, args.step - args.step % 2)
    curves = list(range(1 if heldout else 0, 201, step))
    tasks = [(c, i, (1000 + i) if heldout else i, size) for c in cells for i in curves]
    tasks.sort(key=lambda t: -t[0][0])                   # 12 frames first
    t0 = time.perf_counter()
    with Pool(args.jobs, initializer=_init_worker) as pool:
        results = pool.map(one_stack, tasks, chunksize=1)
    wall = time.perf_counter() - t0
    split = ("held-out split (odd DoRF curves, seeds ≥ 1000)" if heldout
             else "tuning split (even DoRF curves, seeds < 1000)")
    print(f"# {split}: {len(curves)} curves × {len(cells)} cells, {args.size}\n")
    groups = [(cell_name(c), [r for r in results if r["cell"] == c]) for c in cells]
    for name, rs in groups:
        print(f"## {name} ({len(rs)} stacks; median over stacks)\n")
        print(method_table(rs) + "\n")
    groups.append(("all cells", results))
    print("## Does the odd/even ranking follow the truth ranking? (τ: median over stacks of "
          "Kendall's τ over the 4 calibrating methods; 'same winner': stacks where the "
          "lowest truth error and the lowest odd/even disagreement are the same method)\n")
    print(ranking_table(groups) + "\n")
    print("## selfcal's σ: odd/even |z| and each half's |E − E_true|/σ (median over stacks; "
          "the last three columns count stacks: |E−E*|/σ (absolute) in 0.6-0.8 / of those, "
          "|z| in 0.55-0.85 / |z| in 0.55-0.85 at all)\n")
    print(sigma_table(groups) + "\n")
    print("## |z| on the pixels both halves measure against |z| on the channels the truth "
          "scores (median over stacks)\n")
    print(same_pixels_table(groups) + "\n")
    if args.detail:
        print("## Every stack\n")
        print(detail_table(results) + "\n")
    print(f"wall {wall:.0f} s with {args.jobs} jobs; per stack "
          f"{np.median([r['seconds'] for r in results]):.1f} s (median)")


if __name__ == "__main__":
    main()
