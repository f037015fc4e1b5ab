"""Figure 4 of the paper from quality result.json files: mean scene alignment (x) vs mean task completion (y),
one point per (run label or pipeline), marker area proportional to the mean variance over repeats."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simeval.report.tables import write_table
from simeval.results import read_results


def quality_points(records: list[dict]) -> list[dict]:
    points: dict[str, dict] = {}
    for rec in records:
        if rec.get("status", "ok") != "ok" or rec.get("judge") == "oracle":
            continue
        tasks = rec.get("tasks", {})
        for metric in ("scene_alignment", "task_completion"):
            for task, v in rec["values"].get(metric, {}).items():
                if v.get("mean") is None:
                    continue
                label = rec.get("label") or (tasks.get(task) or {}).get("pipeline") or "unlabelled"
                p = points.setdefault(label, {"label": label, "scene_alignment": [], "task_completion": [],
                                              "var": []})
                p[metric].append(v["mean"])
                p["var"].append(v.get("var") or 0.0)
    out = []
    for p in points.values():
        out.append({"label": p["label"], "n_alignment": len(p["scene_alignment"]),
                    "n_completion": len(p["task_completion"]),
                    "scene_alignment": float(np.mean(p["scene_alignment"])) if p["scene_alignment"] else None,
                    "task_completion": float(np.mean(p["task_completion"])) if p["task_completion"] else None,
                    "mean_var": float(np.mean(p["var"])) if p["var"] else 0.0})
    return out


def build_quality_figure(runs_dir: str | Path, out_dir: str | Path, *, id: str = "figure4",
                         formats=("png", "pdf")) -> dict[str, list[Path]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = quality_points(read_results(runs_dir, "quality"))
    both = [p for p in points if p["scene_alignment"] is not None and p["task_completion"] is not None]
    if not both:
        raise FileNotFoundError(f"no quality result.json under {runs_dir} with both scene_alignment and "
                                "task_completion scores: run `python src/quality.py metric=all ...` first")
    out = Path(out_dir)
    header = ["Label", "Scene alignment (1-5)", "Task completion (0-10)", "Mean variance", "Tasks"]
    rows = [[p["label"], f"{p['scene_alignment']:.2f}", f"{p['task_completion']:.2f}", f"{p['mean_var']:.2f}",
             str(max(p["n_alignment"], p["n_completion"]))] for p in both]
    written = {"table": write_table(out / id, header, rows, caption="Single-task quality per pipeline.")}
    fig, ax = plt.subplots(figsize=(4.6, 3.8))
    for p in both:
        ax.scatter(p["scene_alignment"], p["task_completion"], s=60 + 400 * p["mean_var"], alpha=0.7)
        ax.annotate(p["label"], (p["scene_alignment"], p["task_completion"]), textcoords="offset points",
                    xytext=(6, 4), fontsize=8)
    ax.set_xlabel("Scene alignment score (1-5)")
    ax.set_ylabel("Task completion score (0-10)")
    ax.set_xlim(1, 5)
    ax.set_ylim(0, 10)
    ax.set_title("Marker size: variance over repeats", fontsize=9)
    fig.tight_layout()
    written["figure"] = []
    for fmt in formats:
        path = out / f"{id}.{fmt}"
        fig.savefig(path, dpi=150)
        written["figure"].append(path)
    plt.close(fig)
    return written
