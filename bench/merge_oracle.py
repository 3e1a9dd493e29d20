"""Issue 35: selfcal's merge against the oracle merge, under three shutter conditions.

Stacks: those of ``bench.hdr_synthetic`` (``selfcal.sim``, one per DoRF curve): scene
``make_scene(H, W, saturation=0.9, dynamic_range_stops=14, seed)``, camera
``default_pipeline(gamut="smooth", curves=DoRF curve, seed)`` (random colour matrix, smooth
gamut map, one DoRF curve of ``../shared/data/dorf_emor/201_CRF_data.mat`` for the three
channels), six shots 1/250 … 1/8 s, shot and read noise (``SensorModel()``), 8-bit, OpenCV
JPEG 4:2:0 at quality 85, 90 or 95 (by seed).  Each stack is shot under three shutter
conditions, ``simulate_stack(..., jitter=J)`` with the same seed: **exact** (J = 0: the
nominal times are the exposures), **±3 %** and **±8 %** (``true = nominal · (1 + U(−J,
J))`` per frame, independently; one seed draws the same ``U`` for every J, so the
conditions differ in the jitter only).

Splits: curve ``i`` even → seed ``i`` (tuning: seeds < 1000, even curves); curve ``i`` odd
→ seed ``1000 + i`` (held-out: seeds ≥ 1000, odd curves).  ``--step K`` takes the even
curves ``0, K, 2K, …`` (rounded down to even) and the odd curve after each, as
``bench.hdr_synthetic`` (default K = 10: 20 held-out and 21 tuning stacks per condition).

Merges of each stack (``merge_hdr``, all with ``sigma=True``):

* **selfcal**: ``calibrate_response(images, TIMES, **CALIBRATE)`` with the nominal times,
  then ``merge_hdr(images, TIMES, model, options=MergeOptions(sigma=True, **OPTIONS))``;
  ``OPTIONS``: the ``--options KEY=VALUE`` given, ``CALIBRATE``: the ``--calibrate
  KEY=VALUE`` (none by default); the keys ``times``, ``refine`` and ``trend`` are the
  fields of the :class:`selfcal.ExposureRule` passed as ``exposures=`` (to the merge for
  ``--options``, to the calibration for ``--calibrate``).  The frames are arrays, matched
  to the model's by content (``selfcal.stack.frames.model_frame_index``), so the merge
  takes the model's own measured exposures of them under the default rule;
* **oracle**: the true inverse response (``stack.inverse_response()``) and the true
  (jittered) exposures, in a ``ResponseModel`` built as ``bench.hdr_synthetic``'s
  "true f⁻¹, t"; always ``MergeOptions(sigma=True)`` (a fixed reference whatever
  ``--options`` says);
* **curve only**: selfcal's calibrated curve with the true exposures given as the times
  (the model's exposures set to them too), ``OPTIONS`` but with the times held
  (``ExposureRule(times="held")``: the merge uses them exactly): what the curve costs;
* **times only**: the true curve with the nominal times, ``OPTIONS`` (so under the
  default rule the exposures are measured through the true curve): what the exposures
  cost.

Truth and scores (``selfcal.sim.scoring.truth_masks``, ``bench.metrics``): the radiance
``E_true = M ρ · exposure_scale`` on the scored channels (frames that measure a pixel: no
clipping, colour in gamut, channel ≥ 2⁻⁸ of white and code ≥ 3).  Per stack and merge:

* radiance error: the median of ``|s·E/E_true − 1|`` over the scored channels after one
  global scale ``s`` (least squares in log, samples > 2× from the median ratio left out:
  ``bench.metrics.global_scale``, as ``bench.hdr_synthetic`` scores);
* ratios of selfcal's, curve only's and times only's errors to the oracle's (target for
  selfcal ≤ 1.05): the median over stacks of the per-stack ratio, and (selfcal) the ratio
  of the medians;
* σ: the median of ``|s·E − E_true| / (s·σ)`` over the scored channels the merge did not
  flag unmeasured (``bench.uncertainty``'s "after global scale", with the scale of the
  error above; 0.674 for a perfect Gaussian σ; target 0.6–0.8), selfcal's and the
  oracle's;
* the exponential ambiguity ([Lin2011] §4: ``f⁻¹ → (f⁻¹)^γ`` and ``e → e^γ`` fit the
  pixels equally, so no self-calibration sees the exposures' trend over the bracket; the
  times set it): "oracle at the times' trend" scores the oracle's radiance raised to
  ``1/b``, ``b`` the slope of the true exposures against the nominal times in log -- what
  the oracle itself would give with the trend the times say, the floor of any method that
  takes the trend from the times -- as a ratio to the oracle; and "after scale and power"
  scores selfcal and the oracle after a global scale *and* power
  (``bench.metrics.power_scale_error``), the error left once the ambiguity is out;
* exposures: ``HDRResult.exposures`` (what the merge used) against the true exposures, the
  median over the frames of ``|log(e_used/e_true) − mean|`` (one global scale); beside it
  the same for the nominal times (what the times miss).  Target on exact shutters:
  ≤ 0.5 %.

The summary table is per condition (medians over its stacks; seconds: the sum of the
stacks' seconds); the per-stack table has every score and the frames' exposure errors.

    python3 -m bench.merge_oracle --split held-out [--step 10] [--size 256x384] [--jobs 2]
        [--options times=held ...] [--calibrate refine=true]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from multiprocessing import Pool

import numpy as np

from .data import dorf_curve, dorf_stack_arguments, dorf_stacks
from .hdr_synthetic import QUALITIES, SATURATION, TIMES
from .metrics import global_scale, power_scale_error, radiance_scores
from .tables import finish, start, table

#: (label, jitter) of the shutter conditions, in the order printed.
CONDITIONS = (("exact", 0.0), ("±3 %", 0.03), ("±8 %", 0.08))
MERGES = ("selfcal", "oracle", "curve", "times")
TARGET_RATIO = 1.05
TARGET_Z = (0.6, 0.8)
TARGET_EXPOSURE = 0.005
#: MergeOptions fields ``--options`` cannot set: σ is always on, the rest are objects
#: (``exposures`` is set by the keys of :data:`RULE_KEYS`).
NOT_SETTABLE = ("sigma", "noise", "calibrate_options", "exposures")
#: The fields of :class:`selfcal.ExposureRule` that ``--options`` and ``--calibrate`` set
#: (``times=held``, ``refine=true``, ``trend=pixels``): they make the ``exposures=`` rule.
RULE_KEYS = ("times", "refine", "trend")
#: The keywords of ``calibrate_response`` that ``--calibrate`` sets (besides
#: :data:`RULE_KEYS`).
CALIBRATE_KEYS = ("seed",)


def _init_worker():
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    threadpool_limits(limits=1)
    warnings.filterwarnings("ignore")


def parse_options(pairs, fields=None, flag="--options") -> dict:
    """``["KEY=VALUE", ...]`` -> keyword arguments (true/false, none, numbers, else the
    text); KEY one of ``fields`` (default: the MergeOptions fields ``--options`` sets) or
    of :data:`RULE_KEYS`, which make one ``exposures=ExposureRule(...)``."""
    from selfcal import ExposureRule
    from selfcal.errors import InputError
    from selfcal.hdr import MergeOptions

    if fields is None:
        fields = {f.name for f in dataclasses.fields(MergeOptions)} - set(NOT_SETTABLE)
    fields = set(fields) | set(RULE_KEYS)
    out = {}
    for pair in pairs or ():
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            raise SystemExit(f"{flag} {pair!r}: want KEY=VALUE with KEY one of "
                             f"{', '.join(sorted(fields))}")
        low = text.strip().lower()
        if low in ("true", "false"):
            value: object = low == "true"
        elif low == "none":
            value = None
        else:
            try:
                value = int(text)
            except ValueError:
                try:
                    value = float(text)
                except ValueError:
                    value = text
        out[key] = value
    rule = {k: out.pop(k) for k in RULE_KEYS if k in out}
    if rule:
        try:
            out["exposures"] = ExposureRule(**rule)
        except InputError as e:
            raise SystemExit(f"{flag}: {e}") from None
    return out


def exposure_error(used, true) -> tuple[float, list]:
    """Median over the frames of ``|log(used/true) − mean|``, and the per-frame values
    (signed)."""
    d = np.log(np.asarray(used, float)) - np.log(np.asarray(true, float))
    d = d - np.mean(d)
    return float(np.median(np.abs(d))), [float(v) for v in d]


def sigma_z(result, e_true, scored, s) -> float:
    """Median ``|s·E − E_true| / (s·σ)`` over the scored channels of measured pixels."""
    E, S = (np.asarray(a, np.float64) for a in (result.radiance, result.sigma))
    keep = scored & ~result.unmeasured[..., None] & np.isfinite(S) & (S > 0) & np.isfinite(E)
    if not keep.any() or not np.isfinite(s):
        return float("nan")
    return float(np.median(np.abs(s * E[keep] - e_true[keep]) / (s * S[keep])))


def _truth_model(stack, exposures):
    """The true inverse response as a ResponseModel (as ``bench.hdr_synthetic``'s oracle),
    carrying ``exposures``."""
    from selfcal.response.model import ResponseModel

    return ResponseModel(intensity=np.arange(256) / 255.0, inverse=stack.inverse_response(),
                         coefficients=np.zeros((3, 1)), basis_name="truth",
                         exposures=np.asarray(exposures, dtype=float),
                         exposure_times=list(stack.exposure_times),
                         sources=[f"array #{k}" for k in range(len(stack.images))])


def one_stack(task):
    index, seed, size, condition, jitter, options, calibrate = task
    import selfcal
    from selfcal import sim
    from selfcal.hdr import MergeOptions
    from selfcal.sim.scoring import truth_masks

    t0 = time.perf_counter()
    h, w = size
    pipe = sim.default_pipeline(gamut="smooth", curves=dorf_curve(index), seed=seed)
    scene = sim.make_scene(h, w, dynamic_range_stops=14.0, saturation=SATURATION, seed=seed)
    quality = QUALITIES[seed % len(QUALITIES)]
    stack = sim.simulate_stack(scene, pipe, TIMES, jitter=jitter, jpeg_quality=quality,
                               seed=seed)
    e_true, scored, *_ = truth_masks(stack)
    images = stack.images
    true_e = np.asarray(stack.true_exposures, float)

    opts = MergeOptions(sigma=True, **options)
    given = dataclasses.replace(opts, exposures=selfcal.ExposureRule(times="held"))
    model = selfcal.calibrate_response(images, TIMES, **calibrate)
    curve_true_e = dataclasses.replace(model, exposures=true_e.copy())
    results = {
        "selfcal": selfcal.merge_hdr(images, TIMES, model, options=opts),
        "oracle": selfcal.merge_hdr(images, true_e, _truth_model(stack, true_e),
                                    options=MergeOptions(sigma=True)),
        "curve": selfcal.merge_hdr(images, true_e, curve_true_e, options=given),
        "times": selfcal.merge_hdr(images, TIMES, _truth_model(stack, TIMES), options=opts),
    }
    out = {"condition": condition, "index": index, "seed": seed, "quality": quality}
    for name, r in results.items():
        s = global_scale(r.radiance, e_true, scored)
        out[name] = radiance_scores(r.radiance, e_true, scored, np.zeros(scored.shape[:2],
                                                                         bool))[0]
        out[f"{name}_z"] = sigma_z(r, e_true, scored, s)
    # the exponential ambiguity: what the times' trend makes of the oracle (E^(1/b), b the
    # slope of the true exposures against the nominal times in log), and the errors
    # after a global scale and power
    b = float(np.polyfit(np.log(TIMES), np.log(true_e), 1)[0])
    oracle = results["oracle"].radiance.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        tilted = np.where(oracle > 0, oracle, np.nan) ** (1.0 / b)
    out["oracle_trend"] = radiance_scores(tilted, e_true, scored,
                                          np.zeros(scored.shape[:2], bool))[0]
    for name in ("selfcal", "oracle"):
        out[f"{name}_power"] = power_scale_error(results[name].radiance, e_true, scored)
    out["exposure"], out["frames"] = exposure_error(results["selfcal"].exposures, true_e)
    out["nominal"] = exposure_error(TIMES, true_e)[0]
    out["curve_exposure"] = exposure_error(results["curve"].exposures, true_e)[0]
    out["source"] = results["selfcal"].exposure_source
    out["seconds"] = time.perf_counter() - t0
    return out


def _med(rs, key):
    return float(np.median([r[key] for r in rs]))


def _ratio(rs, key):
    return float(np.median([r[key] / r["oracle"] for r in rs]))


def summary(results) -> list:
    rows, lines = [], []
    for label, _ in CONDITIONS:
        rs = [r for r in results if r["condition"] == label]
        if not rs:
            continue
        ratio, of_medians = _ratio(rs, "selfcal"), _med(rs, "selfcal") / _med(rs, "oracle")
        z = _med(rs, "selfcal_z")
        exp_err = _med(rs, "exposure")
        rows.append([label, len(rs), f"{_med(rs, 'selfcal'):.4f}", f"{_med(rs, 'oracle'):.4f}",
                     f"{ratio:.3f}", f"{of_medians:.3f}", f"{_ratio(rs, 'curve'):.3f}",
                     f"{_ratio(rs, 'times'):.3f}", f"{_ratio(rs, 'oracle_trend'):.3f}",
                     f"{float(np.median([r['selfcal_power'] / r['oracle_power'] for r in rs])):.3f}",
                     f"{z:.3f}", f"{_med(rs, 'oracle_z'):.3f}",
                     f"{100 * exp_err:.2f} %", f"{100 * _med(rs, 'nominal'):.2f} %",
                     f"{sum(r['seconds'] for r in rs):.0f}"])
        worse = sum(r["selfcal"] / r["oracle"] > TARGET_RATIO for r in rs)
        verdicts = [f"selfcal/oracle {ratio:.3f} (ratio of medians {of_medians:.3f}) "
                    f"{'met' if max(ratio, of_medians) <= TARGET_RATIO else 'NOT met'} "
                    f"(≤ {TARGET_RATIO}; {worse}/{len(rs)} stacks above)",
                    f"σ median abs z {z:.3f} {'met' if TARGET_Z[0] <= z <= TARGET_Z[1] else 'NOT met'}"
                    f" ({TARGET_Z[0]}-{TARGET_Z[1]})"]
        if label == "exact":
            verdicts.append(f"exposures {100 * exp_err:.2f} % "
                            f"{'met' if exp_err <= TARGET_EXPOSURE else 'NOT met'} "
                            f"(≤ {100 * TARGET_EXPOSURE:.1f} %)")
        lines.append(f"- {label}: " + "; ".join(verdicts))
    head = ["shutters", "stacks", "selfcal error median", "oracle median",
            "selfcal/oracle (median of ratios)", "ratio of medians",
            "curve only/oracle", "times only/oracle", "oracle at the times' trend/oracle",
            "selfcal/oracle after scale and power", "σ: median abs z", "oracle σ: median abs z",
            "exposure error median", "nominal times' error", "seconds"]
    return [table(head, rows), ""] + lines


def detail(results) -> str:
    rows = [[r["condition"], f"dorf{r['index']}", r["seed"], r["quality"],
             f"{r['selfcal']:.4f}", f"{r['oracle']:.4f}",
             f"{r['selfcal'] / r['oracle']:.3f}", f"{r['curve'] / r['oracle']:.3f}",
             f"{r['times'] / r['oracle']:.3f}", f"{r['selfcal_z']:.3f}",
             f"{r['oracle_z']:.3f}", f"{100 * r['exposure']:.2f} %",
             f"{100 * r['nominal']:.2f} %", " ".join(f"{100 * v:+.2f}" for v in r["frames"]),
             r["source"], f"{r['seconds']:.1f}"] for r in results]
    return table(["shutters", "curve", "seed", "JPEG q", "selfcal error", "oracle error",
                  "selfcal/oracle", "curve only/oracle", "times only/oracle", "σ: abs z",
                  "oracle σ: abs z", "exposure error", "nominal times' error",
                  "frames: log(e_used/e_true) − mean, %", "exposure source", "seconds"], rows)


def tasks_for(stacks, size, options, calibrate) -> list:
    # the slow ±8 % stacks are not left to the end: conditions interleaved per stack
    return [(index, seed, size, label, jitter, options, calibrate)
            for index, seed in stacks for label, jitter in CONDITIONS]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    dorf_stack_arguments(parser)
    parser.add_argument("--options", action="append", metavar="KEY=VALUE",
                        help="a MergeOptions field for selfcal's merge, or a field of its "
                        f"ExposureRule ({', '.join(RULE_KEYS)}) (repeatable), e.g. "
                        "times=held")
    parser.add_argument("--calibrate", action="append", metavar="KEY=VALUE",
                        help="a keyword of calibrate_response for selfcal's calibration "
                        f"(repeatable; one of {', '.join(CALIBRATE_KEYS + RULE_KEYS)}: "
                        "the last three make its ExposureRule), e.g. refine=true")
    args = parser.parse_args()
    stacks, (h, w) = dorf_stacks(parser, args)
    options = parse_options(args.options)
    calibrate = parse_options(args.calibrate, set(CALIBRATE_KEYS), "--calibrate")
    start("merge_oracle", args.split)
    tasks = tasks_for(stacks, (h, w), options, calibrate)
    t0 = time.perf_counter()
    with Pool(args.jobs, initializer=_init_worker) as pool:
        results = list(pool.imap_unordered(one_stack, tasks))
    wall = time.perf_counter() - t0
    order = {label: k for k, (label, _) in enumerate(CONDITIONS)}
    results.sort(key=lambda r: (order[r["condition"]], r["index"]))

    named = ", ".join(f"{k}={v!r}" for k, v in options.items())
    cal = "".join(f", {k}={v!r}" for k, v in calibrate.items())
    print(f"{len(results) // len(CONDITIONS)} stacks {h}x{w} per shutter condition "
          f"({args.split} split): bench.hdr_synthetic's stacks (saturation {SATURATION}, "
          "14 stops, smooth gamut map, one DoRF curve, 6 shots 1/250..1/8 s, JPEG q "
          "85/90/95) with exact, ±3 % and ±8 % shutters")
    print(f"selfcal's merge: calibrate_response(images, TIMES{cal}), then merge_hdr with "
          f"MergeOptions(sigma=True{', ' + named if named else ''}); oracle: the true f⁻¹ "
          "and exposures, MergeOptions(sigma=True); curve only: the calibrated curve, the "
          "true exposures; times only: the true curve, the nominal times")
    print("radiance error: median |s·E/E_true − 1| over the scored channels after one "
          "global scale per merge; σ abs z: median |s·E − E_true|/(s·σ); exposure error: "
          "median over the frames of |log(e_used/e_true)| after one global scale\n")
    print("\n".join(summary(results)))
    print("\nper stack:\n")
    print(detail(results))
    print(f"\nwall {wall:.0f} s with {args.jobs} jobs; per stack "
          f"{np.median([r['seconds'] for r in results]):.1f} s (median)")


if __name__ == "__main__":
    main()
    finish()
