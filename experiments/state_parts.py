"""What the state reading of Table 4 held-out reads: its one-step error split into the robot's values and the
objects' (result.json `values.state.parts`, state reading runs made since the split), per group at the fewest and
the most episodes of the runs given. Version 4 of the reading read the whole state and gave the split as a
diagnostic; version 5 reads the objects' part and gives the robot's and the whole state's beside, each gated
(outputs/tables/table4_heldout.md holds the verdicts); this table reads either.

    error_part(k)   = sum over held-out steps and the part's values of (s^_{t+1} - s_{t+1})^2 / steps   (one number)
    skill_part(k)   = 1 - error_part(model) / error_part(last state)
    objects' share  = the objects' part of the last state's error (how much of what moves is the objects')

"objects beat the last state" is the gate's margin (skill >= 0.05) on the point skill only, at both counts: the
per-part intervals are not computed. Why a script and not a report spec: one diagnostic read off runs kept out of the
table's runs_dir (they repeat its state readings), written once for the results page.

    python experiments/state_parts.py RUNS_DIR [RUNS_DIR ...] [--out outputs/tables/table4_heldout_state_parts]
                                      [--overwrite]

Writes <out>.md and <out>.json; an existing pair is overwritten only with --overwrite.
"""

from __future__ import annotations

import json
from pathlib import Path

from simeval.cli import OneLineParser

MARGIN = 0.05  # the gate's (protocol.gate.margin)


def collect(run_dirs: list[Path]) -> dict[tuple[str, str], dict[int, dict]]:
    """{(pipeline, group): {episodes: state reading}} of every result.json under `run_dirs` whose state reading has
    parts (runs made before the split have none and are left out)."""
    found: dict[tuple[str, str], dict[int, dict]] = {}
    for root in run_dirs:
        for path in sorted(root.rglob("result.json")):
            rec = json.loads(path.read_text())
            state = (rec.get("values") or {}).get("state") or {}
            if "parts" not in state:
                continue
            ident = rec["identity"]
            found.setdefault((ident["pipeline"], ident["task_group"]), {})[int(ident["episodes"])] = state
    return found


def part_summaries(state: dict) -> tuple[dict[str, dict], dict]:
    """({robot, objects: {dims, model, last_state, skill_vs_last_state, ...}}, the whole state's summary) of a state
    reading of either version: 5 nests each part's numbers under "summary" and gives the whole in "whole_state";
    4's parts are flat and its summary is the whole state's."""
    if "whole_state" in state:
        return ({name: {"dims": p["dims"], **p["summary"]} for name, p in state["parts"].items()},
                state["whole_state"]["summary"])
    return state["parts"], state["summary"]


def rows(found: dict[tuple[str, str], dict[int, dict]]) -> list[dict]:
    """One row per group: the whole state's and each part's model and last-state errors at the fewest and the most
    episodes, the skills, and the objects' share of the last state's error."""
    out = []
    for (pipeline, group), by_k in sorted(found.items()):
        lo, hi = min(by_k), max(by_k)
        split = {k: part_summaries(by_k[k]) for k in (lo, hi)}
        row = {"pipeline": pipeline, "group": group, "counts": [lo, hi],
               "gate": {k: by_k[k]["gate"]["verdict"] for k in (lo, hi)}}
        for part in ("robot", "objects"):
            p = {k: split[k][0][part] for k in (lo, hi)}
            row[part] = {"dims": p[lo]["dims"], "model": [p[lo]["model"], p[hi]["model"]],
                         "last_state": [p[lo]["last_state"], p[hi]["last_state"]],
                         "skill_vs_last_state": [p[lo]["skill_vs_last_state"], p[hi]["skill_vs_last_state"]]}
        row["whole_model"] = [split[lo][1]["model"], split[hi][1]["model"]]
        last = split[lo][0]
        row["objects_share_of_last_state"] = last["objects"]["last_state"] / (
            last["objects"]["last_state"] + last["robot"]["last_state"])
        skills = row["objects"]["skill_vs_last_state"]
        row["objects_beat_last_state"] = all(s is not None and s >= MARGIN for s in skills)
        out.append(row)
    return out


def markdown(table: list[dict]) -> str:
    f = lambda x: f"{x:.3g}"  # noqa: E731
    s = lambda x: "n/a" if x is None else f"{x:.2f}"  # noqa: E731
    lines = ["# Table 4 held-out: the state reading's error, robot and objects apart", "",
             "One-step error per step at the fewest -> the most episodes (model; skill vs the last state), from "
             "`experiments/state_parts.py`. The reading (version 5 on) reads the objects' part; its verdicts, gated "
             "with intervals, are in table4_heldout.md.", "",
             "| pipeline / group | dims robot / objects | whole state | robot | objects | objects' share of the last "
             "state's error | objects beat the last state (skill >= 0.05 at both) |",
             "|---|---|---|---|---|---|---|"]
    for r in table:
        part = {p: f"{f(r[p]['model'][0])} -> {f(r[p]['model'][1])} ({s(r[p]['skill_vs_last_state'][0])} / "
                   f"{s(r[p]['skill_vs_last_state'][1])})" for p in ("robot", "objects")}
        whole = f"{f(r['whole_model'][0])} -> {f(r['whole_model'][1])}"
        beat = "yes" if r["objects_beat_last_state"] else "no"
        lines.append(f"| {r['pipeline']} / {r['group']} ({r['counts'][0]} -> {r['counts'][1]}) | "
                     f"{r['robot']['dims']} / {r['objects']['dims']} | {whole} | {part['robot']} | {part['objects']} | "
                     f"{100 * r['objects_share_of_last_state']:.1f}% | {beat} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = OneLineParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="folders holding state reading runs (result.json)")
    parser.add_argument("--out", type=Path, default=Path("outputs/tables/table4_heldout_state_parts"))
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args()
    missing = [str(p) for p in args.runs if not p.is_dir()]
    if missing:
        parser.error(f"{missing[0]}: no such folder")
    md, js = args.out.with_suffix(".md"), args.out.with_suffix(".json")
    if (md.exists() or js.exists()) and not args.overwrite:
        parser.error(f"{md} exists: pass --overwrite to replace it")
    table = rows(collect(args.runs))
    if not table:
        parser.error("no state reading with parts (runs made since the split) under " + ", ".join(map(str, args.runs)))
    md.write_text(markdown(table))
    js.write_text(json.dumps(table, indent=1) + "\n")
    print(f"wrote {md}, {js}")


if __name__ == "__main__":
    main()
