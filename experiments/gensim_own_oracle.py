"""Which of GenSim's own tasks its oracle solves on this machine: the table of a src/collect.py pipeline=gensim_own run
(its result.json), one row per task with its group, episodes, successes, and the failures (what GenSim raised or
that it timed out), so the groups used for Tables 4 and 5 can be restricted to tasks that run, and the others are
reported, not dropped.

    python src/collect.py pipeline=gensim_own pipeline.root=~/GenSim task_group=all episodes=1 \\
        hydra.run.dir=outputs/runs/gensim_own_probe
    python experiments/gensim_own_oracle.py outputs/runs/gensim_own_probe [more runs] [--out ...]

With several runs (e.g. a rerun of the failed episodes with a longer pipeline.native.timeout_s), the last one gives
the tasks and failures (its summary covers the whole store) and every run its episodes' times.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from simeval.cli import OneLineParser
from simeval.errors import UserError
from simeval.report.tables import refuse_committed


def table(values: dict) -> tuple[list[str], dict]:
    """Markdown lines and a JSON summary from a collect run's `values`."""
    seconds: dict[str, list[float]] = {}
    for row in values.get("new", []):
        seconds.setdefault(row["task"], []).append(row["seconds"])
    errors: dict[str, set[str]] = {}
    for row in values.get("failed", []):
        errors.setdefault(row["task"], set()).add(row["error"])
    lines = ["| group | task | episodes | oracle successes | failed (GenSim raised or timed out) | s / episode |",
             "|---|---|---|---|---|---|"]
    summary = {}
    for task, t in sorted(values["tasks"].items(), key=lambda kv: (kv[1]["group"], kv[0])):
        failed = len(t["failed"])
        secs = seconds.get(task)
        mean = sum(secs) / len(secs) if secs else None
        why = "; ".join(sorted(errors.get(task, ())))
        lines.append(f"| {t['group']} | {task} | {t['episodes']} | {t['success']} | "
                     f"{failed}{': ' + why if why else ''} | {'' if mean is None else f'{mean:.0f}'} |")
        summary[task] = {**t, "errors": sorted(errors.get(task, ())), "seconds_per_episode": mean}
    groups = {}
    for task, t in summary.items():
        g = groups.setdefault(t["group"], {"tasks": 0, "solved": [], "failed": []})
        g["tasks"] += 1
        (g["solved"] if t["episodes"] and t["success"] == t["episodes"] else g["failed"]).append(task)
    lines += ["", "| group | tasks | every episode solved | not (failed, raised or timed out) |", "|---|---|---|---|"]
    lines += [f"| {g} | {v['tasks']} | {len(v['solved'])} | {len(v['failed'])} |" for g, v in sorted(groups.items())]
    return lines, {"tasks": summary, "groups": groups}


def main() -> None:
    ap = OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders of src/collect.py pipeline=gensim_own runs (result.json)")
    ap.add_argument("--out", default="outputs/tables/gensim_own_oracle")
    ap.add_argument("--overwrite", action="store_true", help="replace a committed table")
    args = ap.parse_args()
    values = []
    for run in args.runs:
        source = Path(run) / "result.json"
        if not source.is_file():
            print(f"error: {source} not found: give the run folder of a src/collect.py pipeline=gensim_own run",
                  file=sys.stderr)
            raise SystemExit(2)
        values.append(json.loads(source.read_text())["values"])
    lines, summary = table({**values[-1], "new": [r for v in values for r in v["new"]]})
    out = Path(args.out)
    try:
        refuse_committed([out.with_suffix(".md"), out.with_suffix(".json")], args.overwrite)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    out.with_suffix(".json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
