"""Agreement of judges with human scores, per table (scene alignment, completion), pipeline and judge.

Input: a JSON mapping table -> list of records {pipeline, task, <human column>, <judge>: score, <judge>_var: ...}
(the layout of the paper's appendix tables), or a CSV with a `table` column and the same fields.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np

from simeval.metrics.agreement import STATISTICS, agreement_summary

RESERVED = {"table", "pipeline", "task"}


def load_score_tables(path: str | os.PathLike) -> dict[str, list[dict]]:
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"score table not found: {path}")
    try:
        if path.suffix.lower() == ".json":
            data = json.loads(path.read_text())
        elif path.suffix.lower() == ".csv":
            data = {}
            for row in csv.DictReader(path.read_text().splitlines()):
                data.setdefault(row.pop("table", "scores"), []).append(row)
        else:
            raise ValueError(f"{path}: expected .json or .csv")
    except json.JSONDecodeError as e:
        raise ValueError(f"cannot parse {path}: {e}") from e
    if not isinstance(data, dict) or not all(isinstance(v, list) for v in data.values()):
        raise ValueError(f"{path}: expected a mapping table -> list of records")
    return data


def judge_columns(records: list[dict], human: str) -> list[str]:
    cols = dict.fromkeys(k for r in records for k in r)
    if human not in cols:
        raise ValueError(f"human score column '{human}' not found; columns: {', '.join(cols)}")
    return [c for c in cols if c not in RESERVED and c != human and not c.endswith("_var")]


def _number(value, where: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{where}: not a number: {value!r}") from e
    if not np.isfinite(x):
        raise ValueError(f"{where}: not finite: {value!r}")
    return x


def agreement_rows(tables: dict[str, list[dict]], human: str = "Human", *, n_boot: int = 2000,
                   seed: int = 0) -> list[dict]:
    """One row per (table, pipeline incl. 'all', judge) with every statistic and its CI."""
    rows = []
    for table, records in tables.items():
        judges = judge_columns(records, human)
        pipelines = list(dict.fromkeys(str(r.get("pipeline", "all")) for r in records))
        scopes = [(p, [r for r in records if str(r.get("pipeline", "all")) == p]) for p in pipelines]
        if len(pipelines) > 1:
            scopes.append(("all", records))
        for pipeline, recs in scopes:
            for judge in judges:
                pairs = [(r[human], r[judge]) for r in recs if r.get(judge) not in (None, "")]
                h = [_number(a, f"{table}/{pipeline}/{human}") for a, _ in pairs]
                m = [_number(b, f"{table}/{pipeline}/{judge}") for _, b in pairs]
                rows.append({"table": table, "pipeline": pipeline, "judge": judge,
                             **agreement_summary(h, m, n_boot=n_boot, seed=seed)})
    return rows


def format_rows(rows: list[dict], digits: int = 2) -> tuple[list[str], list[list[str]]]:
    header = ["Table", "Pipeline", "Judge", "n"] + [s for s in STATISTICS]
    body = []
    for r in rows:
        cells = []
        for s in STATISTICS:
            v, ci = r[s], r[f"{s}_ci"]
            cells.append("undefined" if v is None else f"{v:.{digits}f}" + (
                f" [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]" if ci else ""))
        body.append([r["table"], r["pipeline"], r["judge"], str(r["n"])] + cells)
    return header, body


def plot_figure3(rows: list[dict], stem: str | os.PathLike, formats=("png", "pdf")) -> list[Path]:
    """Bar charts of Pearson r / MAE per judge, one panel per table, one bar per pipeline. Negative bars are
    truncated at 0 as in the paper; undefined values are marked 'n/a'."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from simeval.report.figures import save_figure

    tables = list(dict.fromkeys(r["table"] for r in rows))
    widths = [max(2, len({r["judge"] for r in rows if r["table"] == t})) for t in tables]
    fig, axes = plt.subplots(1, len(tables), figsize=(sum(widths) * 1.3 + 1, 3.6),
                             gridspec_kw={"width_ratios": widths}, squeeze=False)
    for ax, table in zip(axes[0], tables):
        sub = [r for r in rows if r["table"] == table and r["pipeline"] != "all"]
        judges = list(dict.fromkeys(r["judge"] for r in sub))
        pipelines = list(dict.fromkeys(r["pipeline"] for r in sub))
        w = 0.8 / max(1, len(pipelines))
        for k, p in enumerate(pipelines):
            xs, ys = [], []
            for j, judge in enumerate(judges):
                r = next((r for r in sub if r["pipeline"] == p and r["judge"] == judge), None)
                x = j + (k - (len(pipelines) - 1) / 2) * w
                if r is None or r["r_over_mae"] is None:
                    ax.text(x, 0.02, "n/a", ha="center", va="bottom", fontsize=7, rotation=90)
                    continue
                xs.append(x)
                ys.append(max(0.0, r["r_over_mae"]))
            ax.bar(xs, ys, width=w, label=p)
        ax.set_xticks(range(len(judges)))
        ax.set_xticklabels(judges, rotation=30, ha="right", fontsize=8)
        ax.set_title(table.replace("_", " "))
        ax.set_ylabel("Pearson r / MAE")
        ax.legend(fontsize=8)
    fig.tight_layout()
    out = []
    for fmt in formats:
        out.append(save_figure(fig, Path(stem).with_suffix(f".{fmt}"), dpi=150))  # no dates in the file
    plt.close(fig)
    return out
