"""``bench/BENCHMARKS.md``, generated from the latest records in ``bench/results/``.

    python3 -m bench.report            # write bench/BENCHMARKS.md
    python3 -m bench.report --check    # exit 1 when the file differs from what it would write

Each script records its run (:mod:`bench.tables`): the tables it printed, the lines around
them, the command, the commit, the date and the split.  This renders every record, in the
order of :data:`SECTIONS`, under the question its script answers; a script with no record
is listed at the end as "not regenerated yet", with the command that would make one.  No
figure is written here by hand: edit a script and run it, then run this.
"""

from __future__ import annotations

import argparse
import json
import sys

from .tables import REPO, RESULTS

OUT = REPO / "bench" / "BENCHMARKS.md"
#: Longest BENCHMARKS.md this writes without complaint (issue 34).
MAX_LINES = 600

#: (script, title, question, the command of its reference run), in the order of the file.
SECTIONS = (
    ("basis", "Response basis", "The built-in response basis against inverse EMoR: how well each fits the "
     "201 DoRF curves, and calibrating with `--basis invemor.txt`.",
     "python3 -m bench.basis --calibrate heldout"),
    ("response_synthetic", "Response against the truth", "The JPEG-only path against the truth: recovered f⁻¹ on DoRF "
     "curves rendered by the simulator, against OpenCV.", "python3 -m bench.response_synthetic"),
    ("response_real", "Response on real stacks", "The JPEG-only path on real stacks: the scale-free linearisation "
     "error (`selfcal.sim.scoring`) against OpenCV and the per-code floor.",
     "python3 -m bench.response_real"),
    ("response_unknown", "Response with unknown times", "Missing exposure times: how far the curve and its exponent γ go "
     "with all, two, one or no known times.", "python3 -m bench.response_unknown --split held-out"),
    ("response_matrix", "Response on the condition matrix", "The response on the condition matrix (`selfcal.sim.conditions`, "
     "`selfcal.sim.exact`) and the D7000 in-camera model, against every peer.",
     "python3 -m bench.response_matrix"),
    ("response_brackets", "Response across scenes", "A camera's curve across its scenes (real_brackets): the spread "
     "of each method's curves.", "python3 -m bench.response_brackets"),
    ("response_speed", "Response: speed and memory", "Calibration speed and memory from files against the decode.",
     "python3 -m bench.response_speed"),
    ("verdict", "The verdict", "The verdict on good stacks and on wrong data.", "python3 -m bench.verdict"),
    ("uncertainty", "Bands and σ", "How sure: curve bands and radiance σ against the truth and on real "
     "odd/even halves.", "python3 -m bench.uncertainty"),
    ("hdr_synthetic", "HDR merge against the truth", "HDR merge accuracy on hard synthetic stacks with known radiance.",
     "python3 -m bench.hdr_synthetic --split held-out"),
    ("hdr_oddeven", "HDR merge on real stacks", "HDR merges on real stacks: odd/even agreement, per pixel and on "
     "block means.", "python3 -m bench.hdr_oddeven"),
    ("measured_exposures", "Exposures measured from the pixels", "Exposures measured from the pixels through the curve: the "
     "files' pre-pass against the arrays'.", "python3 -m bench.measured_exposures --split heldout"),
    ("hdr_alignment", "Alignment", "Aligning handheld frames before the merge.",
     "python3 -m bench.hdr_alignment"),
    ("hdr_speed", "HDR merge: speed and memory", "HDR merge speed and memory on 24 MP frames.", "python3 -m bench.hdr_speed"),
    ("roundtrip", "RAW path: round trips", "Round trips through a RAW-path model.", "python3 -m bench.roundtrip"),
    ("pipeline", "RAW path: forward and backward model", "The RAW path (forward and backward model) against the peers of Gong et al.",
     "python3 -m bench.pipeline"),
    ("pipeline_crossscene", "RAW path across scenes", "The RAW path across scenes.", "python3 -m bench.pipeline_crossscene"),
    ("linear_bracket", "Raw-only brackets", "Raw-only brackets: exposure ratios from the pixels and the merge.",
     "python3 -m bench.linear_bracket --split heldout"),
    ("nus_model", "NUS model folders", "NUS model folders as models: baked tables against the reference.",
     "python3 -m bench.nus_model"),
    ("export_cube", "LUT exports", "LUT exports (shaper + 3D, CLF, OpenColorIO, .cube) applied by "
     "OpenColorIO and ffmpeg.", "python3 -m bench.export_cube"),
    ("batch", "Batch: throughput", "`selfcal batch` on Dask: throughput and the pooled per-camera curve.",
     "python3 -m bench.batch"),
    ("batch_grouping", "Batch: sessions by content", "`selfcal batch`: sessions by content on real and simulated cards.",
     "python3 -m bench.batch_grouping"),
    ("batch_scale", "Batch at scale", "`selfcal batch` at scale: discovery of 10⁵ files, scheduler overhead.",
     "python3 -m bench.batch_scale"),
)

HEADER = """\
# Benchmarks

Generated by `python3 -m bench.report` from the records in `bench/results/`: do not edit
by hand.  Every table below is printed by the command above it, at the commit named
beside it (`+dirty`: code not yet committed then); run the command to print it again, and
`python3 -m bench.report` to write this file.  Seconds depend on the machine (the
project's is 2 shared cores); ratios carry over better.  The scripts read
`../shared/data` and exit with a message when it is absent.

Splits (the developers' rule): choices are made on the **tuning** split (simulator seeds
< 1000, even DoRF curves, one real scene per camera: memorial, fujifilm_xh1/scene1,
sony_ilce6400/scene1) and reported on the **held-out** split (the rest); each record says
which it ran on ("none": the bench chooses nothing, e.g. speed).  The decisions made
with these benches, and the evidence of finished investigations whose scripts are gone,
are in `docs/decisions.md`.
"""


def load_records() -> dict:
    """script -> its records (the default run first, then variants by name)."""
    out: dict = {}
    for path in sorted(RESULTS.glob("*.json")):
        record = json.loads(path.read_text(encoding="utf-8"))
        out.setdefault(record["name"], []).append(record)
    for records in out.values():
        records.sort(key=lambda r: (r["variant"] is not None, r["variant"] or ""))
    return out


def markdown_table(t: dict) -> list:
    def row(cells):
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    return [row(t["headers"]), "|" + "|".join("---" for _ in t["headers"]) + "|"] + [
        row(r) for r in t["rows"]]


def render_record(record: dict) -> list:
    lines = ["```", record["command"], "```", "",
             f"At {record['commit']}, {record['date']}; split: {record['split']}; "
             f"{record['seconds']:.0f} s.", ""]
    for block in record["blocks"]:
        if "table" in block:
            lines += markdown_table(block["table"]) + [""]
        else:
            lines += ["```text", block["text"], "```", ""]
    return lines


def render(records: dict) -> str:
    lines = HEADER.splitlines() + [""]
    missing = []
    known = {name for name, *_ in SECTIONS}
    for name, title, question, command in SECTIONS:
        if name not in records:
            missing.append(command)
            continue
        lines += [f"## {title}", "", f"`bench.{name}`: {question}", ""]
        for record in records[name]:
            lines += render_record(record)
    strays = sorted(set(records) - known)
    if strays:
        raise SystemExit(f"records of scripts not in bench.report.SECTIONS: {strays}")
    if missing:
        lines += ["## Not regenerated yet", "",
                  "These benches have no record yet (too long for the machine the last "
                  "regeneration ran on, or not run since the bench became a package); "
                  "their earlier figures are not carried over:", ""]
        lines += [f"- not regenerated yet: `{c}`" for c in missing] + [""]
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="exit 1 when bench/BENCHMARKS.md is not what this would write")
    args = parser.parse_args(argv)
    text = render(load_records())
    n = text.count("\n")
    if args.check:
        same = OUT.exists() and OUT.read_text(encoding="utf-8") == text
        print(f"{OUT.relative_to(REPO)}: {'up to date' if same else 'out of date'}")
        return 0 if same else 1
    OUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUT.relative_to(REPO)}: {n} lines")
    if n > MAX_LINES:
        print(f"warning: more than {MAX_LINES} lines", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
