"""Paper Table 5 from generalization result.json files: the paper's value beside ours, per task group.

    python -m simeval.models.policy.table5 [--runs outputs] [--out outputs/tables/table5]
writes table5.md and table5.csv. Ours: success rate of the `eval` split (the paper's protocol: the group's
tasks under variations) with its Wilson 95% interval, and the train/heldout splits beside it when run. Several
runs of one cell must agree on their identity (settings); seeds are pooled (successes and rollouts add up).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from simeval.errors import UserError
from simeval.metrics.intervals import wilson_interval
from simeval.results import atomic_write_text, identity_difference, read_results

# paper Table 5: GenSim reports step-wise reward (1.0 = success), RoboGen/BBSEA success rate
PAPER = {("gensim", "stacking"): 0.15, ("gensim", "placement"): 0.32, ("gensim", "piles"): 0.2,
         ("gensim", "assembling"): 0.08, ("robogen", "table-top"): 0.0, ("robogen", "ground"): 0.0,
         ("bbsea", "table-top"): 0.0, ("bbsea", "drawer"): 0.0}
SPLITS = ("eval", "train", "heldout")


def build(records: list[dict]) -> list[dict]:
    cells: dict = {}
    for rec in records:
        ident = rec["identity"]
        key = (ident["pipeline"], ident["task_group"])
        base = {k: v for k, v in ident.items() if k != "seed"}
        if key in cells and cells[key]["identity"] != base:
            raise UserError(f"{rec['path']}: runs of {key} differ in {identity_difference(cells[key]['identity'], base)}")
        cell = cells.setdefault(key, {"identity": base, "counts": {}, "runs": []})
        cell["runs"].append(rec["path"])
        for split, v in rec["values"].get("splits", {}).items():
            k, n = cell["counts"].get(split, (0, 0))
            cell["counts"][split] = (k + v["success"]["k"], n + v["success"]["n"])
    rows = []
    for (pipeline, group) in [*PAPER, *sorted(set(cells) - set(PAPER))]:
        cell = cells.get((pipeline, group))
        row = {"pipeline": pipeline, "group": group, "paper": PAPER.get((pipeline, group)),
               "policy": cell["identity"]["policy"] if cell else None, "runs": len(cell["runs"]) if cell else 0}
        for split in SPLITS:
            k, n = (cell or {"counts": {}})["counts"].get(split, (0, 0))
            row[split] = {"k": k, "n": n, "rate": k / n, "ci": wilson_interval(k, n)} if n else None
        rows.append(row)
    return rows


def _fmt(v) -> str:
    return "-" if v is None else f"{v['rate']:.2f} [{v['ci'][0]:.2f}, {v['ci'][1]:.2f}] ({v['k']}/{v['n']})"


def write(rows: list[dict], out: str | Path) -> tuple[Path, Path]:
    out = Path(out)
    head = ["Pipeline", "Task group", "Paper", "Ours: eval (varied)", "Ours: train", "Ours: held-out", "Policy", "Runs"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    table = []
    for r in rows:
        cells = [r["pipeline"], r["group"], "-" if r["paper"] is None else f"{r['paper']:.2f}",
                 *(_fmt(r[s]) for s in SPLITS), r["policy"] or "-", str(r["runs"])]
        table.append(cells)
        lines.append("| " + " | ".join(cells) + " |")
    note = ("\nSuccess rate with Wilson 95% interval (successes/rollouts). Paper: GenSim step-wise reward, "
            "RoboGen/BBSEA success rate; '-' = not run.\n")
    md = atomic_write_text(out.with_suffix(".md"), "\n".join(lines) + "\n" + note)
    import io

    buf = io.StringIO()
    csv.writer(buf).writerows([head, *table])
    return md, atomic_write_text(out.with_suffix(".csv"), buf.getvalue())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="paper Table 5 from generalization result.json files")
    ap.add_argument("--runs", default="outputs", help="folder searched for result.json files")
    ap.add_argument("--out", default="outputs/tables/table5", help="output path without suffix")
    args = ap.parse_args(argv)
    md, _ = write(build(read_results(args.runs, metric="generalization")), args.out)
    print(md.read_text())


if __name__ == "__main__":
    main()
