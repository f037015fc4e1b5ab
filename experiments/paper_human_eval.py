"""Extract the paper's appendix tables of human and model scores (scene alignment, task completion) from its LaTeX
source into the score-table JSON that src/agreement.py reads, so Figure 3 can be rebuilt on a machine that has
only this repository.

    python experiments/paper_human_eval.py PAPER.tex [--out src/simeval/report/paper_human_eval.json]

The output is committed (`src/simeval/report/paper_human_eval.json`, shipped with the package); this script says
where its numbers come from and rebuilds it. A cell "2.56(0.9)" is the mean of five judge runs and, in parentheses,
their variance: it becomes {"GPT-4+Blip2": 2.56, "GPT-4+Blip2_var": 0.9}. Rows are grouped by the "Task Name
(<pipeline>)" header above them. tests/test_paper_human_eval.py compares the file with a copy of the same tables
typed independently (`../shared/data/human_eval_tables.json`).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from simeval.cli import OneLineParser

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "src" / "simeval" / "report" / "paper_human_eval.json"
TABLES = {"tab:alignment": "scene_alignment", "tab:completion": "task_completion"}
CELL = re.compile(r"^\s*(-?\d+(?:\.\d+)?)\s*(?:\(\s*(-?\d+(?:\.\d+)?)\s*\))?\s*$")
HEADER = re.compile(r"\\textbf\{Task Name \(([^)]*)\)\}")


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.split("\\\\")[0].split("&")]


def _bold(cell: str) -> str:
    m = re.fullmatch(r"\\textbf\{(.*)\}", cell.strip())
    return m.group(1) if m else cell.strip()


def parse_table(body: str, name: str) -> list[dict]:
    """Rows of one tabular: each data row under a "Task Name (<pipeline>)" header becomes {pipeline, task,
    <column>: value, <column>_var: variance}; the Human column has no variance."""
    rows, columns, pipeline = [], None, None
    for line in body.splitlines():
        header = HEADER.search(line)
        if header:
            pipeline = header.group(1)
            columns = [_bold(c) for c in _cells(line)][1:]
            continue
        if columns is None or "&" not in line or line.lstrip().startswith("\\"):
            continue
        cells = _cells(line)
        if len(cells) != len(columns) + 1:
            raise ValueError(f"{name}: row {line.strip()!r} has {len(cells)} cells, the header {len(columns) + 1}")
        rec: dict = {"pipeline": pipeline, "task": cells[0]}
        for col, cell in zip(columns, cells[1:]):
            m = CELL.match(cell)
            if not m:
                raise ValueError(f"{name}: {cells[0]!r}, column {col!r}: cannot read {cell!r} as value(variance)")
            rec[col] = float(m.group(1))
            if m.group(2) is not None:
                rec[f"{col}_var"] = float(m.group(2))
        rows.append(rec)
    return rows


def extract(tex: str) -> dict[str, list[dict]]:
    """{table name: rows} for the paper's two appendix score tables, found by their \\label."""
    out = {}
    for label, name in TABLES.items():
        at = tex.find(f"\\label{{{label}}}")
        if at < 0:
            raise ValueError(f"no \\label{{{label}}} in the LaTeX source")
        start = tex.rfind("\\begin{tabular}", 0, at)
        end = tex.find("\\end{tabular}", start)
        if start < 0 or end < 0:
            raise ValueError(f"no tabular around \\label{{{label}}}")
        out[name] = parse_table(tex[start:end], name)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("tex", help="the paper's LaTeX source")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    a = ap.parse_args(argv)
    try:
        tables = extract(Path(a.tex).read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        print(f"error: {a.tex}: {e}", file=sys.stderr)
        return 2
    Path(a.out).write_text(json.dumps(tables, indent=1) + "\n")
    print(f"wrote {a.out}: " + ", ".join(f"{k} ({len(v)} rows)" for k, v in tables.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
