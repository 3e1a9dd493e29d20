"""Issue 13: truth-free odd/even agreement of HDR merges on real stacks.

For each real stack (memorial with its shutter_times.txt, piccante, ntu, frobisher and
every scene of ../shared/data/real_brackets, with EXIF times), frames sorted by exposure:

* one response is calibrated from **all** frames -- selfcal's ``calibrate_response`` with
  its defaults, OpenCV's ``CalibrateDebevec``, colour-hdri's
  ``camera_response_functions_Debevec1997``;
* the **even**-indexed frames (0, 2, 4, ... in exposure order) and the **odd**-indexed
  ones (1, 3, ...) are merged separately with that response: selfcal's ``merge_hdr`` with
  its defaults, with ``weighting="noise"`` and with ``weighting="hat"``, and with
  ``--before-26`` its default before issue 26 ("selfcal before":
  ``MergeOptions(code_error=False, merge_unchecked=False)`` -- no code-error term in the
  weights, frames too far from the bracket left out; never a candidate of the "lowest"
  column); OpenCV's
  ``MergeDebevec``; colour-hdri's ``image_stack_to_HDRI``;
* where both halves measured a pixel the two radiance maps should agree up to one global
  scale.  The score is the median (and the 90th percentile) of ``|log(E_odd / E_even) − s|``
  with ``s`` the median log ratio, per channel, pooled over the three channels, over the
  pixels measured in both halves.
* the same median score on **block-averaged** maps (bias vs noise): each half's radiance is
  averaged per channel over non-overlapping B×B pixel blocks (reshape mean, the last
  incomplete row/column of blocks dropped), scoring only blocks whose every pixel is
  measured in both halves; a block holding a non-finite or ≤ 0 value counts as an infinite
  disagreement.  Averaging 64 pixels cuts pixel-independent noise by 8 while a systematic
  disagreement between the halves (wrong response, wrong weights, clip handling) stays, so
  the 8×8 table bounds what any merge can fix; JPEG noise is partly correlated over a few
  pixels (demosaicing, compression), so 8×8 does not remove all noise either.  A third
  table gives selfcal's default merge at B = 1 (the per-pixel score), 2, 4, 8, 16 and the
  difference per-pixel − 8×8 (the part of the per-pixel score that 8×8 averaging removes:
  an estimate of the noise share, not a noise floor measured independently).

"Measured" is defined once per half from the codes, the same for every method: some frame
of that half has every channel strictly inside selfcal's clip limits
(``selfcal.stack.frames.clip_limits`` with the default 2-code margin: 2 < code < 253 for 8-bit
frames).  A non-finite or non-positive radiance value on a scored pixel counts as an
infinite disagreement (colour-hdri's polynomial extrapolation can go negative).  No
method's own notion of clipping enters the pixel set.

The split: memorial and the first real_brackets scene of each camera are the **tuning**
split (the merge may be tuned on them); every other stack is **held out**.

A second table is the memorial comparison of the issue: the default merge and the hat
merge of all 16 frames against the noise-weighted one (same model), median log ratio and
p95 |log ratio| (no rescaling; the exposures are the same), over all pixels and over the
pixels some frame measured.

    python3 -m bench.hdr_oddeven                 # every stack (6 min, 6 GB peak)
    python3 -m bench.hdr_oddeven --only memorial --only sony_ilce6400/scene3
    python3 -m bench.hdr_oddeven --reduce 4      # every JPEG at 1/4 (quick)
    python3 -m bench.hdr_oddeven --exposure-variants    # + the exposures' variant columns

The ntu frames (6000×4000) are always decoded at 1/4 or less (libjpeg DCT scaling,
``read_image(..., reduce=4)``); the "size" column gives the size merged.  Colour-hdri runs
with one BLAS thread (threadpoolctl), as does everything else here; its float64 copies of
the 6 MP Sony stacks set the peak memory (about 6 GB).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .data import TUNING_STACKS as TUNING, exposure_meta, sorted_frames, stack_list
from .metrics import agreement, block_agreement, measured
from .tables import finish, start, table

METHODS = ("selfcal default", "selfcal noise", "selfcal hat", "OpenCV",
           "colour-hdri")
#: Not a candidate for the "lowest" column: the default before issue 26's change.
BEFORE = "selfcal before"
#: With --exposure-variants: the default merge with the measured exposures' trend over the
#: bracket the pixels' (``ExposureRule(trend="pixels")``), and with the times held as they
#: are (``ExposureRule(times="held")``, the default before issue 35); not candidates of the
#: "lowest" column either.  The values are the fields of the merge's
#: :class:`selfcal.ExposureRule` (``MergeOptions(exposures=ExposureRule(**fields))``).
MEASURED = {"selfcal, pixels' trend": {"trend": "pixels"},
            "selfcal before 35": {"times": "held"}}
NOT_CANDIDATES = (BEFORE, *MEASURED)
#: Block size of the block-averaged score (every method) and the sizes of the scaling table.
BLOCK = 8
BLOCKS = (2, 4, 8, 16)


# --------------------------------------------------------------------------------------
# stacks
# --------------------------------------------------------------------------------------

# --------------------------------------------------------------------------------------
# scoring
# --------------------------------------------------------------------------------------

# --------------------------------------------------------------------------------------
# the three merges
# --------------------------------------------------------------------------------------

def selfcal_merges(frames, times, halves, methods=METHODS):
    """selfcal's merges of the halves; "selfcal before" (``--before-26``) is the default with
    issue 26's options off (``MergeOptions(code_error=False, merge_unchecked=False)``: no
    code-error term in the weights, frames the calibration ignored as too far from the
    bracket left out): the default of b8a2705."""
    import selfcal
    from selfcal.hdr import MergeOptions

    model = selfcal.calibrate_response(frames, times)
    out, flagged = {}, {}
    # built only when asked for: the options of the variants are fields of MergeOptions
    variants = [(BEFORE, lambda: {"options": MergeOptions(code_error=False,
                                                          merge_unchecked=False)}),
                ("selfcal default", dict), ("selfcal noise", lambda: {"weighting": "noise"}),
                ("selfcal hat", lambda: {"weighting": "hat"})]
    variants += [(m, lambda fields=fields: {
        "options": MergeOptions(exposures=selfcal.ExposureRule(**fields))})
                 for m, fields in MEASURED.items()]
    for label, make in variants:
        if label not in methods:
            continue
        kwargs = make()
        results = [selfcal.merge_hdr([frames[k] for k in h], [times[k] for k in h],
                                     model, **kwargs) for h in halves]
        out[label] = [r.radiance for r in results]
        flagged[label] = results[0].unmeasured | results[1].unmeasured
        unchecked = [r.unchecked for r in results if r.unchecked is not None]
        flagged[label + " unchecked"] = (np.logical_or.reduce(unchecked) if unchecked
                                         else np.zeros_like(flagged[label]))
    return out, flagged, model


def opencv_merges(frames, times, halves):
    import cv2

    bgr = [np.ascontiguousarray(im[:, :, ::-1]) for im in frames]
    t = np.asarray(times, dtype=np.float32)
    response = cv2.createCalibrateDebevec().process(bgr, t)
    merge = cv2.createMergeDebevec()
    return [merge.process([bgr[k] for k in h], t[list(h)], response)[:, :, ::-1]
            for h in halves]


def colour_hdri_merges(frames, times, meta, halves):
    from colour_hdri import (Image, ImageStack, Metadata,
                             camera_response_functions_Debevec1997, image_stack_to_HDRI)

    def stack(indices):
        s = ImageStack()
        for k in indices:  # already in increasing exposure
            n, iso = meta[k]
            s.append(Image(data=frames[k] / 255.0,
                           metadata=Metadata(f_number=n, exposure_time=times[k], iso=iso)))
        return s

    crfs = camera_response_functions_Debevec1997(stack(range(len(frames))))
    return [image_stack_to_HDRI(stack(h), camera_response_functions=crfs) for h in halves]


# --------------------------------------------------------------------------------------
# one stack
# --------------------------------------------------------------------------------------

def run_stack(name, paths, times, reduce: int, methods=METHODS):
    t0 = time.perf_counter()
    frames, paths, times = sorted_frames(name, paths, times, reduce)
    if any(f.dtype != np.uint8 for f in frames):
        sys.exit(f"{name}: 8-bit frames expected")
    meta = exposure_meta(paths)
    n = len(frames)
    even, odd = tuple(range(0, n, 2)), tuple(range(1, n, 2))
    halves = (odd, even)
    mask = measured([frames[k] for k in odd]) & measured([frames[k] for k in even])

    maps, flagged, model = selfcal_merges(frames, times, halves, methods)
    maps["OpenCV"] = opencv_merges(frames, times, halves)
    maps["colour-hdri"] = colour_hdri_merges(frames, times, meta, halves)
    scores = {m: agreement(maps[m][0], maps[m][1], mask) for m in methods}
    blocks = {m: block_agreement(maps[m][0], maps[m][1], mask, BLOCK) for m in methods}
    scaling = {b: block_agreement(*maps["selfcal default"], mask, b) for b in BLOCKS}
    h, w = frames[0].shape[:2]
    info = {
        "frames": f"{len(odd)}/{len(even)}",
        "size": f"{w}×{h}" + (f" (1/{reduce})" if reduce > 1 and paths[0].suffix.lower()
                              in (".jpg", ".jpeg") else ""),
        "measured": float(mask.mean()),
        "flagged": float(flagged["selfcal default"][mask].mean()) if mask.any() else 0.0,
        "flagged before": (float(flagged[BEFORE][mask].mean()) if mask.any() and BEFORE in flagged
                           else 0.0),
        "unchecked": (float(flagged["selfcal default unchecked"][mask].mean()) if mask.any()
                      else 0.0),
        "seconds": time.perf_counter() - t0,
        "blocks": blocks,
        "scaling": scaling,
    }
    extra = memorial_comparison(frames, times, model) if name == "memorial" else None
    return scores, info, extra


def memorial_comparison(frames, times, model):
    """Default and hat merges of all frames against the noise-weighted one."""
    import selfcal

    ref = selfcal.merge_hdr(frames, times, model, weighting="noise").radiance
    some = measured(frames)
    wheres = [("all pixels", np.ones(some.shape, bool))]
    if not some.all():
        wheres.append(("measured by some frame", some))
    rows = []
    for label, kwargs in (("default", {}), ("hat", {"weighting": "hat"})):
        r = selfcal.merge_hdr(frames, times, model, **kwargs).radiance
        for where, mask in wheres:
            x, y = r[mask].astype(np.float64).ravel(), ref[mask].astype(np.float64).ravel()
            ok = (x > 0) & (y > 0) & np.isfinite(x) & np.isfinite(y)
            lr = np.log(x[ok]) - np.log(y[ok])
            rows.append([f"{label} / noise", where, f"{100 * mask.mean():.1f}%",
                         f"{np.median(lr):+.3f}", f"{np.percentile(np.abs(lr), 95):.3f}",
                         f"{100 * (1 - ok.mean()):.2g}%"])
    return rows


# --------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------

def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", metavar="NAME",
                        help="a stack (memorial, piccante, ntu, frobisher, "
                        "sony_ilce6400/scene1, ...) or a camera folder (sony_ilce6400); "
                        "repeatable")
    parser.add_argument("--reduce", type=int, default=1, choices=(1, 2, 4, 8),
                        help="decode every JPEG at 1/K (DCT scaling; ntu at 1/max(K, 4)); "
                        "memorial's PNGs are used as they are")
    parser.add_argument("--exposure-variants", action="store_true",
                        help="add the columns " + ", ".join(f'"{m}"' for m in MEASURED))
    parser.add_argument("--before-26", action="store_true",
                        help=f'add the column "{BEFORE}": MergeOptions(code_error=False, '
                        "merge_unchecked=False), the default before issue 26")
    args = parser.parse_args(argv)
    start("hdr_oddeven", "both")
    methods = ((BEFORE,) if args.before_26 else ()) + METHODS + (
        tuple(MEASURED) if args.exposure_variants else ())
    # the exposures move the scores in the fourth digit
    digits = 4 if args.exposure_variants else 3

    import warnings

    from threadpoolctl import threadpool_limits

    # colour-hdri warns for every frame holding a code 0; the tables count what it costs
    warnings.filterwarnings("ignore", message=".*negative or equal to zero values")

    stacks = stack_list()
    if args.only:
        chosen = {k: v for k, v in stacks.items()
                  if any(k == o or k.startswith(o.rstrip("/") + "/") for o in args.only)}
        if not chosen:
            sys.exit(f"no stack matches {args.only}; stacks: {', '.join(stacks)}")
        stacks = chosen

    t_start = time.perf_counter()
    results, extra = {}, None
    with threadpool_limits(limits=1, user_api="blas"):
        for name, (paths, times) in stacks.items():
            scores, info, ex = run_stack(name, paths, times, args.reduce, methods)
            results[name] = (scores, info)
            extra = ex if ex is not None else extra
            print(f"[{name}: {info['seconds']:.0f} s]", file=sys.stderr, flush=True)
    total = time.perf_counter() - t_start

    def split(name):
        return "tuning" if name in TUNING else "held out"

    for title, idx, fmt in (("median |log ratio|", 0, f"{{:.{digits}f}}"),
                            ("p90 |log ratio|", 1, f"{{:.{digits}f}}")):
        rows = []
        for name, (scores, info) in results.items():
            vals = [scores[m][idx] for m in methods]
            shown = [fmt.format(v) for v in vals]
            low = min(float(v) for m, v in zip(methods, shown) if m not in NOT_CANDIDATES)
            best = ", ".join(m for m, v in zip(methods, shown)
                             if m not in NOT_CANDIDATES and float(v) == low)
            rows.append([name, split(name), info["frames"], info["size"],
                         f"{100 * info['measured']:.1f}%"]
                        + shown + [best])
        print(f"\nOdd/even agreement, {title} after one global scale (per channel, "
              "pixels measured in both halves):\n")
        print(table(["stack", "split", "frames odd/even", "size", "measured"]
                    + list(methods) + ["lowest"], rows))

    rows = []
    for name, (scores, info) in results.items():
        blocks = info["blocks"]
        shown = [f"{blocks[m][0]:.{digits}f}" for m in methods]
        finite = [float(v) for m, v in zip(methods, shown)
                  if v != "nan" and m not in NOT_CANDIDATES]
        best = ", ".join(m for m, v in zip(methods, shown) if finite and v != "nan"
                         and m not in NOT_CANDIDATES and float(v) == min(finite))
        rows.append([name, split(name), str(blocks[methods[0]][3])] + shown + [best])
    print(f"\nOdd/even agreement on {BLOCK}×{BLOCK} block means, median |log ratio| after one "
          "global scale (per channel, blocks whose every pixel is measured in both halves; "
          "a block with a non-finite or ≤ 0 value counts as infinite):\n")
    print(table(["stack", "split", "blocks"] + list(methods) + ["lowest"], rows))

    rows = []
    for name, (scores, info) in results.items():
        sc = info["scaling"]
        pix = scores["selfcal default"][0]
        rows.append([name, split(name), f"{pix:.3f}"] + [f"{sc[b][0]:.3f}" for b in BLOCKS]
                    + [f"{pix - sc[BLOCK][0]:.3f}"])
    print("\nselfcal default, odd/even median |log ratio| against block size B (B = 1 is the "
          f"per-pixel score above); last column: per-pixel − {BLOCK}×{BLOCK}, the part that "
          "block averaging removes (an estimate of the noise share, not an independent "
          "noise-floor measurement):\n")
    print(table(["stack", "split", "B=1"] + [f"B={b}" for b in BLOCKS]
                + [f"B=1 − B={BLOCK}"], rows))

    bad = [f"{name} {m} {100 * scores[m][2]:.2g}%" for name, (scores, _) in results.items()
           for m in methods if scores[m][2] > 0]
    if bad:
        print("\nScored values non-finite or ≤ 0, counted as infinite disagreement (colour-hdri: "
              "its Debevec curve, extrapolated by a polynomial, goes ≤ 0 at low codes): "
              + "; ".join(bad))
    flagged = [f"{name} {100 * info['flagged']:.2g}%"
               + (f" (before {100 * info['flagged before']:.2g}%)" if args.before_26 else "")
               for name, (_, info) in results.items()
               if info["flagged"] > 0 or info["flagged before"] > 0]
    if flagged:
        print("\nScored pixels that selfcal's default merge flags unmeasured in a half (its "
              "clip rules or frames it leaves out; their values are its fill, a bound): "
              + "; ".join(flagged))
    unchecked = [f"{name} {100 * info['unchecked']:.2g}%" for name, (_, info) in results.items()
                 if info["unchecked"] > 0]
    if unchecked:
        print("\nScored pixels that selfcal's default merge flags unchecked in a half (measured "
              "only by a frame merged with a time the pixels could not check): "
              + "; ".join(unchecked))
    if extra is not None:
        print("\nmemorial, all 16 frames, one model (the one above): the default and the hat "
              "merge against the noise-weighted one (log ratio per channel, no rescaling):\n")
        print(table(["merge", "pixels", "fraction", "median log ratio", "p95 |log ratio|",
                     "non-finite/≤0"], extra))
    print(f"\n{len(results)} stacks in {total:.0f} s "
          f"({', '.join('%s %.0f' % (k, v[1]['seconds']) for k, v in results.items())})")


if __name__ == "__main__":
    main()
    finish()
