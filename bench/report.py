"""``bench/BENCHMARKS.md``, generated from the latest records in ``bench/results/``.

    python3 -m bench.report            # write bench/BENCHMARKS.md
    python3 -m bench.report --check    # exit 1 when the file differs from what it would write

Each script records its run (:mod:`bench.tables`): the tables it printed, the lines around
them, the command, the commit, the date and the split.  This renders every record, in the
order of :data:`SECTIONS`, under the question its script answers (a tuning-split run
beside a held-out one is named, not shown: its figures are in its record); a table longer than
:data:`MAX_ROWS` rows shows its first and last rows and names the JSON file that holds
them all (likewise a long block of text).  A script with no record is listed at the end
as "not regenerated yet", with the command that would make one.  No figure is written
here by hand: edit a script and run it, then run this.
"""

from __future__ import annotations

import argparse
import json
import sys

from .tables import REPO, RESULTS

OUT = REPO / "bench" / "BENCHMARKS.md"
#: Longest BENCHMARKS.md this writes without complaint (issue 34).
MAX_LINES = 600
#: A longer table shows its first and last rows here; every row is in its JSON record.
MAX_ROWS, HEAD_ROWS, TAIL_ROWS = 3, 1, 1
#: Likewise a longer block of text.
MAX_TEXT_LINES, HEAD_TEXT, TAIL_TEXT = 1, 1, 0

#: (script, title, question, the commands of its reference runs), in the order of the
#: file; a reference command with no record of that exact command is listed as not
#: regenerated.
SECTIONS = (
    ("basis", "Response basis", "The built-in response basis against inverse EMoR: how well each fits the "
     "201 DoRF curves, and calibrating with `--basis invemor.txt`.",
     ("python3 -m bench.basis", "python3 -m bench.basis --calibrate heldout")),
    ("response_synthetic", "Response against the truth", "The JPEG-only path against the truth: recovered f⁻¹ on DoRF "
     "curves rendered by the simulator, against OpenCV.",
     ("python3 -m bench.response_synthetic",)),
    ("response_real", "Response on real stacks", "The JPEG-only path on real stacks: the scale-free linearisation "
     "error (`selfcal.sim.scoring`) against OpenCV and the per-code floor.",
     ("python3 -m bench.response_real",)),
    ("response_unknown", "Response with unknown times", "Missing exposure times: how far the curve and its exponent γ go "
     "with all, two, one or no known times.",
     ("python3 -m bench.response_unknown --split held-out --step 5 --known all,two,one,none "
      "--band --jobs 2",)),
    ("response_matrix", "Response on the condition matrix", "The response on the condition matrix (`selfcal.sim.conditions`, "
     "`selfcal.sim.exact`) and the D7000 in-camera model, against every peer.",
     ("python3 -m bench.response_matrix",)),
    ("response_top", "Response at the top of the curve", "The response's error per code range "
     "(codes 245-255 apart), with and without the hidden white samples.",
     ("python3 -m bench.response_top --curves 2",)),
    ("response_brackets", "Response across scenes", "A camera's curve across its scenes (real_brackets): the spread "
     "of each method's curves.",
     ("python3 -m bench.response_brackets",)),
    ("response_speed", "Response: speed and memory", "Calibration speed and memory from files against the decode.",
     ("python3 -m bench.response_speed",)),
    ("verdict", "The verdict", "The verdict on good stacks and on wrong data.",
     ("python3 -m bench.verdict",)),
    ("uncertainty", "Bands and σ", "How sure: curve bands and radiance σ against the truth and on real "
     "odd/even halves.",
     ("python3 -m bench.uncertainty", "python3 -m bench.uncertainty --parts cost")),
    ("hdr_synthetic", "HDR merge against the truth", "HDR merge accuracy on hard synthetic stacks with known radiance.",
     ("python3 -m bench.hdr_synthetic --split held-out",)),
    ("merge_oracle", "HDR merge against the oracle", "selfcal's merge against the oracle (the true "
     "curve and exposures) on exact, ±3 % and ±8 % shutters: the radiance error ratio, what "
     "the curve and the exposures each cost, σ and the exposures used.",
     ("python3 -m bench.merge_oracle --split held-out",)),
    ("hdr_oddeven", "HDR merge on real stacks", "HDR merges on real stacks: odd/even agreement, per pixel and on "
     "block means.",
     ("python3 -m bench.hdr_oddeven",
      "python3 -m bench.hdr_oddeven --exposure-variants --reduce 4")),
    ("measured_exposures", "Exposures measured from the pixels", "Exposures measured from the pixels through the curve: the "
     "files' pre-pass against the arrays'.",
     ("python3 -m bench.measured_exposures --split heldout",)),
    ("hdr_alignment", "Alignment", "Aligning handheld frames before the merge.",
     ("python3 -m bench.hdr_alignment",)),
    ("vignetting", "Vignetting self-calibrated", "Vignetting self-calibrated from handheld "
     "brackets (simulated, with truth): the map against the truth, the response with and "
     "without the joint fit, tripods said not observable.",
     ("python3 -m bench.vignetting --split held-out --jobs 1",)),
    ("vignetting_merge", "Merge through a vignetting lens", "The merge of handheld brackets "
     "through a vignetting lens: corner against centre, the falloff's bias, σ.",
     ("python3 -m bench.vignetting_merge --split held-out --jobs 1",)),
    ("vignetting_real", "Vignetting on real frames", "Which vignetting each real stack gets "
     "(self, lens database, none) and the self-calibrated falloff of the real panoramas.",
     ("python3 -m bench.vignetting_real --skip-ntu",)),
    ("lens_sources", "Lens profiles", "What lensfun's database matches for the real stacks' "
     "EXIF, and how uncertain an interpolated profile is.",
     ("python3 -m bench.lens_sources",)),
    ("luminance", "Absolute luminance", "Radiance in cd/m²: a reference reading of one region "
     "against the truth elsewhere, the EXIF convention's error, σ of the scale.",
     ("python3 -m bench.luminance --split held-out",)),
    ("vignetting_speed", "Vignetting: cost in the merge", "What dividing the vignetting out "
     "costs a merge with σ on 24 MP frames.",
     ("python3 -m bench.vignetting_speed",)),
    ("hdr_speed", "HDR merge: speed and memory", "HDR merge speed and memory on 24 MP frames.",
     ("python3 -m bench.hdr_speed",)),
    ("measure_speed", "HDR merge: the cost of measured exposures",
     "The merge with exposures measured from the pixels against the same merge with the "
     "times held, and OpenCV's MergeDebevec, on frames the model has not seen (issue 43): "
     "five 24 MP arrays and ntu's 17 files.",
     ("python3 -m bench.measure_speed --repeats 6",)),
    ("roundtrip", "RAW path: round trips", "Round trips through a RAW-path model.",
     ("python3 -m bench.roundtrip",)),
    ("pipeline", "RAW path: forward and backward model", "The RAW path (forward and backward model) against the peers of Gong et al.",
     ("python3 -m bench.pipeline",)),
    ("pipeline_crossscene", "RAW path across scenes", "The RAW path across scenes.",
     ("python3 -m bench.pipeline_crossscene",)),
    ("linear_bracket", "Raw-only brackets", "Raw-only brackets: exposure ratios from the pixels and the merge.",
     ("python3 -m bench.linear_bracket --split heldout",)),
    ("nus_model", "NUS model folders", "NUS model folders as models: baked tables against the reference.",
     ("python3 -m bench.nus_model",)),
    ("export_cube", "LUT exports", "LUT exports (shaper + 3D, CLF, OpenColorIO, .cube) applied by "
     "OpenColorIO and ffmpeg.",
     ("python3 -m bench.export_cube",)),
    ("batch", "Batch: throughput", "`selfcal batch` on Dask: throughput and the pooled per-camera curve.",
     ("python3 -m bench.batch",)),
    ("batch_grouping", "Batch: sessions by content", "`selfcal batch`: sessions by content on real and simulated cards.",
     ("python3 -m bench.batch_grouping",)),
    ("batch_sessions_scale", "Batch: the session search at scale", "The session search on "
     "10⁴ and 10⁵ simulated frames (one process): time and peak memory, beside the grouping "
     "before issue 37.",
     ("python3 -m bench.batch_sessions_scale",)),
    ("batch_scale", "Batch at scale", "`selfcal batch` at scale: discovery of 10⁵ files, scheduler overhead.",
     ("python3 -m bench.batch_scale",)),
    ("batch_raw", "Batch: RAW+JPEG libraries", "One RAW-path model from a camera's RAW+JPEG "
     "library, against one pair, on scenes it was not fitted on.",
     ("python3 -m bench.batch_raw --split tuning", "python3 -m bench.batch_raw --split heldout")),
)

#: Tables left out here to keep the file short (script -> indices of its tables, in the
#: order printed); a line names each and the JSON record that holds it.  Per-case detail
#: behind a summary, tuning tables beside held-out ones, a second statistic of one score;
#: keyed by script, or by ``script.variant`` for one record of it.
DETAIL_TABLES = {
    "verdict": {0, 1},             # case by case (the summary below them is shown)
    "hdr_oddeven": {1, 3, 4},      # p90 of the per-pixel score; the block-size scaling; memorial's weightings
    "export_cube": {1, 2, 3, 4},   # Resolve .cube against CLF; ffmpeg; response models; OCIO round trip
    "pipeline": {0, 1, 2},         # forward and backward RMSE (the targets table sums them up)
    "linear_bracket": {1},         # the negative controls, case by case (their count is shown)
    "batch_grouping": {0, 1},      # the correlation's spread; the simulated cards, card by card
    "batch_sessions_scale": {0, 1, 2, 3},  # each run alone (the table of all runs is shown)
    "batch_raw": {0, 1},           # scene by scene (each card's targets line is shown)
    "response_unknown": {1},       # stack by stack
    "uncertainty": {1},            # σ curve by curve (bands and σ summed up below them)
    "response_real": {1},          # the metric by saturation band
    "response_synthetic": {1},     # the real-stack metric on the same stacks (a proxy)
    # the from-files seconds and peaks (the runs table repeats them); what a merge holds
    "hdr_speed": {1, 2},
    "response_speed": {1},         # where selfcal's seconds go (the ratio is shown)
    "merge_oracle": {1},           # stack by stack (the summary per shutter condition is shown)
    "response_top": {1, 2},        # cell by cell; the brightest kept codes (the per-code-range table is shown)
    "response_brackets": {1, 2},   # the cross-scene error (not a target); seconds per scene
    "basis": {0},                  # the fit per basis size (the target line is shown)
    "basis.calibrate-heldout": set(),
    "vignetting": {0},             # stack by stack (the medians are shown)
    "batch": {1},                  # the pooled curve per body (the throughput table is shown)
    "lens_sources": {0},           # the matches (bench.vignetting_real's table names them too)
    "vignetting_merge": {0},       # stack by stack (the medians are shown)
    "luminance": {0},              # stack by stack (the medians line is shown)
    # the band runs: their γ summary repeats the first run's (the bands are shown)
    "response_unknown.split-held-out.step-5.known-all_two_one_none.band": {0, 1},
}

#: Tables shown whole however long (script -> indices): the acceptance figures are rows
#: of them, side by side with their baselines.
WHOLE_TABLES = {
    "batch_grouping": {2},         # content / before / time on each split
    "batch_sessions_scale": {4},   # 10⁴ and 10⁵ frames, new and before
}

#: Scripts whose blocks of text are shown whole (their figures are lines of text).
WHOLE_TEXT = {"batch_scale"}

HEADER = """\
# Benchmarks

Generated by `python3 -m bench.report` from the records in `bench/results/`: do not edit
by hand.  Every table is printed by the command above it, at the commit named there
(`+dirty`: code not committed then); long and per-case tables are cut short or left out,
and the JSON record named in their place holds every row.  Seconds depend on the machine
(2 shared cores); ratios carry over better.  The scripts need `../shared/data`.

Splits (the developers' rule): choices are made on the **tuning** split (simulator seeds
< 1000, even DoRF curves, one real scene per camera: memorial, fujifilm_xh1/scene1,
sony_ilce6400/scene1) and reported on the **held-out** split (the rest); each record says
which it ran on ("none": the bench chooses nothing).  The decisions made with these
benches are in `docs/decisions.md`; baseline runs (a new default off, or before a change)
are records in `bench/results/baselines/`, not shown here.
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


def record_file(record: dict) -> str:
    variant = record["variant"]
    return f"bench/results/{record['name']}" + (f".{variant}" if variant else "") + ".json"


def markdown_table(t: dict, source: str, *, whole: bool = False) -> list:
    def row(cells):
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    rows = t["rows"]
    out = [row(t["headers"]), "|" + "|".join("---" for _ in t["headers"]) + "|"]
    if whole or len(rows) <= MAX_ROWS:
        return out + [row(r) for r in rows]
    hidden = len(rows) - HEAD_ROWS - TAIL_ROWS
    gap = [f"… {hidden} rows in `{source}` …"] + [""] * (len(t["headers"]) - 1)
    return out + [row(r) for r in rows[:HEAD_ROWS]] + [row(gap)] + [
        row(r) for r in rows[-TAIL_ROWS:]]


def plain(line: str) -> str:
    """One line of a script's output as a Markdown paragraph: its own headings in bold,
    Markdown's special characters escaped."""
    import re

    heading = re.match(r"#+\s*(.*)", line)
    text = heading.group(1) if heading else line
    text = re.sub(r"([\\`*_<>|\[\]])", r"\\\1", text)
    return f"**{text}**" if heading else text


def text_block(text: str, source: str, *, whole: bool = False) -> list:
    lines = text.splitlines()
    if len(lines) == 1:
        return [plain(lines[0])]
    if len(lines) > MAX_TEXT_LINES and not whole:
        hidden = len(lines) - HEAD_TEXT - TAIL_TEXT
        if TAIL_TEXT == 0:          # the pointer closes the last line shown
            return [plain(line) + "\\" for line in lines[:HEAD_TEXT - 1]] + [
                plain(lines[HEAD_TEXT - 1]) + f" (… {hidden} more line{'s' if hidden > 1 else ''} in `{source}`)"]
        lines = (lines[:HEAD_TEXT] + [f"[… {hidden} lines in {source} …]"]
                 + lines[len(lines) - TAIL_TEXT:])
    # a paragraph per run of lines, each line kept (a hard break ends all but the last)
    out = []
    for k, line in enumerate(lines):
        last = k + 1 == len(lines) or not lines[k + 1].strip()
        out.append(plain(line) + ("" if last or not line.strip() else "\\"))
    return out


def _left_out_line(rows: list, source: str) -> str:
    if len(rows) == 1:
        return f"(A table of {rows[0]} rows: in `{source}`.)"
    return f"({len(rows)} tables, of {', '.join(map(str, rows))} rows: in `{source}`.)"


def render_record(record: dict, lead: str = "") -> list:
    """A record's lines; ``lead``: a line put before its command, in the same paragraph."""
    lines = ([lead + "\\"] if lead else []) + [
        f"`{record['command']}` at {record['commit']} ({record['date']}; split: "
        f"{record['split']}; {record['seconds']:.0f} s):", ""]
    source = record_file(record)
    hidden = DETAIL_TABLES.get(f"{record['name']}.{record['variant']}",
                               DETAIL_TABLES.get(record["name"], set()))
    k = -1
    left_out: list = []         # row counts of the run of tables left out just now
    blocks = record["blocks"]
    named = False               # the table left out was named by its title line
    for i, block in enumerate(blocks):
        if "table" in block:
            k += 1
            t = block["table"]
            if k in hidden:
                if not named:
                    left_out.append(len(t["rows"]))
                    line = _left_out_line(left_out, source)
                    if len(left_out) > 1:           # one line for a run of tables left out
                        lines[-2] = line
                    elif len(lines) > 1 and lines[-1] == "" and lines[-2] \
                            and not lines[-2].startswith("|"):
                        lines[-1:] = [line, ""]     # in the paragraph before it
                        lines[-3] += "\\"
                    else:
                        lines += [line, ""]
                named = False
                continue
            left_out = []
            lines += markdown_table(t, source,
                                    whole=k in WHOLE_TABLES.get(record["name"], set())) + [""]
            continue
        nxt = blocks[i + 1] if i + 1 < len(blocks) else None
        if nxt and "table" in nxt and (k + 1) in hidden and "\n" not in block["text"]:
            # the title of a table left out: one line names both
            lines += [plain(block["text"].rstrip(":")) + f" ({len(nxt['table']['rows'])} "
                      f"rows: in `{source}`)", ""]
            named = True
            left_out = []
            continue
        lines += text_block(block["text"], source,
                            whole=record["name"] in WHOLE_TEXT) + [""]
        left_out = []
    return lines


def render(records: dict) -> str:
    lines = HEADER.splitlines() + [""]
    missing = []
    known = {name for name, *_ in SECTIONS}
    for name, title, question, commands in SECTIONS:
        done = {r["command"] for r in records.get(name, ())}
        missing += [c for c in commands if c not in done]
        if name not in records:
            continue
        lines += [f"## {title}", ""]
        held_out = any(r.get("split") == "held-out" for r in records[name])
        lead = f"`bench.{name}`: {question}"
        for record in records[name]:
            if held_out and record.get("split") == "tuning":
                # the figures to judge by are the held-out run's; the tuning run is named
                lines += [f"The tuning split's run, `{record['command']}` at "
                          f"{record['commit']}: in `{record_file(record)}`.", ""]
                continue
            lines += render_record(record, lead)
            lead = ""
    strays = sorted(set(records) - known)
    if strays:
        raise SystemExit(f"records of scripts not in bench.report.SECTIONS: {strays}")
    if missing:
        lines += ["## Not regenerated yet", "",
                  "Reference runs with no record (too long for the machine the records "
                  "were made on); no earlier figures are carried over:", ""]
        lines += [", ".join(f"`{c}`" for c in missing) + ".", ""]
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
