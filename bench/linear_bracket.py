"""Raw-only brackets (issue 18): linear 16-bit TIFF brackets, their exposure ratios measured
from the pixels, and the HDR merge, against the simulator's truth.

Each case is a bracket of linear frames written as 16-bit TIFFs (what ``dcraw -4 -T`` or a
raw converter writes: no tone curve, black at 0), with a shutter jitter of ±``--jitter``
per shot, through :class:`selfcal.sim.SensorModel` (shot and read noise, white clip):

* ``synth<seed>``: :func:`selfcal.sim.make_scene` scenes of 8–14 stops, saturation
  0.2–0.9, 3–7 frames 1–2 stops apart, full wells 3,000–40,000 e⁻ (high to low ISO), read
  noise 0.05–0.3 % of white; a third of them with EXIF ExposureTime tags (nominal times);
* ``raw:<file>``: the shared DNGs (``../shared/data/raw``) read linear with rawpy as the
  scene -- real content -- then bracketed the same way (held-out; skipped without the
  folder).

Per case: whether the bracket is recognised as linear
(:func:`selfcal.exposure.linear_evidence.linear_evidence`, what ``selfcal merge`` acts on), the
largest error of the exposure ratios (to the first frame) measured by
:func:`selfcal.merge_hdr` (``linear=True``; :mod:`selfcal.exposure.linear`) against the
true, jittered ones, that of the nominal times, and the radiance's median relative error
(best scale, pixels lit in the truth) merged with each.

Tuning split: seeds < 1000 (nothing was tuned on this bench: the measurement's thresholds
are those of :func:`selfcal.exposure.raw_ratios.raw_exposure_ratios`, set for the RAW+JPEG path); held
out: seeds ≥ 1000 and the two real raws.

    python3 -m bench.linear_bracket                 # both splits
    python3 -m bench.linear_bracket --split heldout
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from .data import SHARED_DATA
from .tables import finish, start, table

TUNING_SEEDS = tuple(range(6))
HELDOUT_SEEDS = tuple(range(1000, 1012))


def _case_params(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    frames = int(rng.integers(3, 8))
    step = float(rng.choice([1.0, 1.5, 2.0]))
    return {"stops": float(rng.uniform(8, 14)), "saturation": float(rng.uniform(0.2, 0.9)),
            "frames": frames, "step": step,
            "full_well": float(np.exp(rng.uniform(np.log(3000), np.log(40000)))),
            "read_noise": float(rng.uniform(0.0005, 0.003)),
            "with_times": bool(seed % 3 == 0)}


def _times(frames: int, step: float):
    return [float(2.0 ** (step * k) / 250) for k in range(frames)]


def _bracket(scene, times, *, sensor, jitter, seed):
    """The stack of linear frames of ``scene`` at the jittered ``times`` (the middle frame
    puts the scene's median at 0.18)."""
    from selfcal import sim

    return sim.simulate_stack(scene, sim.default_pipeline(seed=seed), times,
                                jitter=jitter, sensor=sensor, seed=seed)


def _radiance_error(radiance, unmeasured, truth) -> float:
    ok = (truth > 1e-3).all(axis=2) & ~unmeasured
    rad = radiance[ok]
    scale = np.median(rad / truth[ok])
    return float(np.median(np.abs(rad / (scale * truth[ok]) - 1)))


def _measure(name, split, scene, times, sensor, jitter, seed, with_times, root: Path):
    import selfcal
    from selfcal.exposure.linear_evidence import linear_evidence

    stack = _bracket(scene, times, sensor=sensor, jitter=jitter, seed=seed)
    true = np.asarray(stack.true_exposures, dtype=float)
    paths = stack.write_raws(root / name.replace(":", "_"), with_times=with_times)
    known = list(times) if with_times else [None] * len(times)
    why = linear_evidence(paths, known)
    t0 = time.perf_counter()
    result = selfcal.merge_hdr(paths, linear=True)
    seconds = time.perf_counter() - t0
    held = selfcal.hdr.MergeOptions(exposures=selfcal.ExposureRule(times="held"))
    nominal = selfcal.merge_hdr(paths, list(times), linear=True, options=held)
    true_r = true / true[0]
    meas_r = result.exposures / result.exposures[0]
    nom_r = np.asarray(times) / times[0]
    truth = scene * 1.0
    return {"case": name, "split": split, "frames": len(times),
            "recognised": "yes" if why else "NO",
            "exif": "yes" if with_times else "no",
            "ratio_err": float(np.max(np.abs(meas_r / true_r - 1))),
            "nominal_err": float(np.max(np.abs(nom_r / true_r - 1))),
            "rad_err": _radiance_error(result.radiance, result.unmeasured, truth),
            "rad_err_nominal": _radiance_error(nominal.radiance, nominal.unmeasured, truth),
            "source": result.exposure_source, "seconds": seconds}


def synthetic_cases(seeds, split, args, root):
    from selfcal import sim

    rows = []
    for seed in seeds:
        p = _case_params(seed)
        scene = sim.make_scene(args.height, args.width, dynamic_range_stops=p["stops"],
                                 saturation=p["saturation"], seed=seed)
        sensor = sim.SensorModel(full_well_electrons=p["full_well"],
                                   read_noise=p["read_noise"])
        rows.append(_measure(f"synth{seed}", split, scene, _times(p["frames"], p["step"]),
                             sensor, args.jitter, seed, p["with_times"], root))
    return rows


def raw_cases(args, root):
    from selfcal import sim
    from selfcal.io.raw import read_raw_linear

    folder = SHARED_DATA / "raw"
    if not folder.is_dir():
        print(f"(skipped the real raws: {folder} is absent)")
        return []
    rows = []
    for k, dng in enumerate(sorted(folder.glob("*.dng"))):
        scene = read_raw_linear(dng, half_size=True).rgb.astype(np.float32)
        scene = np.maximum(scene, 0) + 1e-5          # rawpy's black-subtracted zeros
        sensor = sim.SensorModel(full_well_electrons=15000.0, read_noise=0.001)
        rows.append(_measure(f"raw:{dng.name}", "held-out", scene, _times(5, 1.5), sensor,
                             args.jitter, 2000 + k, k % 2 == 0, root))
    return rows


def rendered_controls(seeds, split, args, root):
    """Negative controls: 16-bit *rendered* TIFF brackets (the simulator's default camera:
    colour matrix, gamut map, tone curves; and a pure gamma 2.2), which must not be said
    linear.  Without times a pure power law cannot be told from linear data (the
    exponential ambiguity), so gamma 2.2 is run with times only."""
    from selfcal import sim
    from selfcal.exposure.linear_evidence import linear_evidence

    rows = []
    for seed in seeds:
        p = _case_params(seed)
        scene = sim.make_scene(args.height, args.width, dynamic_range_stops=p["stops"],
                                 saturation=p["saturation"], seed=seed)
        times = _times(p["frames"], p["step"])
        for label, pipeline, timed in (
                ("default camera", sim.default_pipeline(seed=seed), p["with_times"]),
                ("gamma 2.2", sim.CameraPipeline(matrix=np.eye(3), curves=sim.ToneCurve.gamma(2.2), gamut="none"), True)):
            stack = sim.simulate_stack(scene, pipeline, times, jitter=args.jitter,
                                         seed=seed, output=sim.FrameOutput(bit_depth=16),
                                         jpeg_quality=None)
            folder = root / f"rendered{seed}-{label.replace(' ', '')}"
            paths = stack.write(folder, fmt="tif")
            known = list(times) if timed else [None] * len(times)
            why = linear_evidence(paths, known) if timed else linear_evidence(
                _strip_times(paths), known)
            rows.append({"case": f"rendered{seed} ({label})", "split": split,
                         "frames": len(times), "exif": "yes" if timed else "no",
                         "said_linear": "YES" if why else "no"})
    return rows


def _strip_times(paths):
    """The same TIFFs without their EXIF tags (a converter that drops them)."""
    import tifffile

    out = []
    for p in paths:
        q = p.with_name("bare_" + p.name)
        tifffile.imwrite(q, tifffile.imread(p), photometric="rgb")
        out.append(q)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--split", choices=("tuning", "heldout", "both"), default="both")
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--width", type=int, default=768)
    ap.add_argument("--jitter", type=float, default=0.05)
    args = ap.parse_args()
    start("linear_bracket", args.split)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if args.split in ("tuning", "both"):
            rows += synthetic_cases(TUNING_SEEDS, "tuning", args, root)
        if args.split in ("heldout", "both"):
            rows += synthetic_cases(HELDOUT_SEEDS, "held-out", args, root)
            rows += raw_cases(args, root)
    controls = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.split in ("tuning", "both"):
            controls += rendered_controls(TUNING_SEEDS, "tuning", args, Path(tmp))
        if args.split in ("heldout", "both"):
            controls += rendered_controls(HELDOUT_SEEDS, "held-out", args, Path(tmp))
    print(f"linear 16-bit TIFF brackets, {args.height}x{args.width} (raws: half size), "
          f"shutter jitter ±{100 * args.jitter:.0f}%")
    print(table(["case", "split", "frames", "EXIF times", "recognised linear",
                 "ratio err (pixels)", "ratio err (nominal)", "radiance err (pixels)",
                 "radiance err (nominal)", "exposures", "merge s"],
                [[r["case"], r["split"], r["frames"], r["exif"], r["recognised"],
                  f"{100 * r['ratio_err']:.2f}%", f"{100 * r['nominal_err']:.2f}%",
                  f"{100 * r['rad_err']:.2f}%", f"{100 * r['rad_err_nominal']:.2f}%",
                  r["source"], f"{r['seconds']:.2f}"] for r in rows]))
    for split in ("tuning", "held-out"):
        sel = [r for r in rows if r["split"] == split]
        if not sel:
            continue
        worst = max(r["ratio_err"] for r in sel)
        rec = sum(r["recognised"] == "yes" for r in sel)
        print(f"{split}: {len(sel)} brackets; recognised as linear {rec}/{len(sel)}; "
              f"largest ratio error {100 * worst:.2f}% (nominal times: "
              f"{100 * max(r['nominal_err'] for r in sel):.2f}%); median radiance error "
              f"{100 * np.median([r['rad_err'] for r in sel]):.2f}% (nominal: "
              f"{100 * np.median([r['rad_err_nominal'] for r in sel]):.2f}%)")
    print()
    print("negative controls: 16-bit rendered TIFF brackets (must not be said linear)")
    print(table(["case", "split", "frames", "EXIF times", "said linear"],
                [[r["case"], r["split"], r["frames"], r["exif"], r["said_linear"]]
                 for r in controls]))
    for split in ("tuning", "held-out"):
        sel = [r for r in controls if r["split"] == split]
        if sel:
            print(f"{split}: rendered brackets said linear {sum(r['said_linear'] == 'YES' for r in sel)}"
                  f"/{len(sel)}")
    held = [r for r in rows if r["split"] == "held-out"]
    if held:
        ok = (max(r["ratio_err"] for r in held) <= 0.01
              and all(r["recognised"] == "yes" for r in held)
              and not any(r["said_linear"] == "YES" for r in controls
                          if r["split"] == "held-out"))
        print(f"acceptance (held-out: ratios within 1 % of the truth, every linear bracket "
              f"said linear, no rendered one): {'met' if ok else 'NOT met'}")


if __name__ == "__main__":
    main()
    finish()
