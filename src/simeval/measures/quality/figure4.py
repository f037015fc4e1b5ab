"""Figure 4 of the paper from quality result.json files: mean scene alignment (x) vs mean task completion (y),
one point per (run label or pipeline), marker area proportional to the mean variance over repeats.

A task is identified by (pipeline, bundle name), not by the record it appears in: re-running the judge on the
same bundles adds repeats of those tasks, not new tasks. Per task the scores of every run are averaged first,
then a point is the mean over its distinct tasks, and the table's "Tasks" column counts distinct tasks. The
runs of one point must agree on the judge (version, judge kind and model, scene-alignment mode, captioner):
mixing two judges in one point is refused with a UserError naming both files (give the runs distinct `label`s).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simeval.errors import UserError
from simeval.writing.figures import save_figure
from simeval.writing.tables import write_table
from simeval.results import identity_difference, read_results, record_identity


def _get(d, *keys):
    for k in keys:
        d = d.get(k) if isinstance(d, dict) else None
    return d


def judge_settings(rec: dict) -> dict:
    """What must agree between runs that feed one point: the judge as the record's config names it, plus whatever
    its `identity` names beyond what may vary between runs of one point (seed, label, pipeline, tasks)."""
    cfg = rec.get("config") or {}
    settings = {"version": rec.get("version"), "judge": rec.get("judge") or _get(cfg, "judge", "kind"),
                "judge_model": _get(cfg, "judge", "provider", "model") or _get(cfg, "judge", "provider", "model_path"),
                "scene_alignment_mode": cfg.get("scene_alignment_mode"), "captioner": _get(cfg, "captioner", "kind"),
                "captioner_model": _get(cfg, "captioner", "provider", "model")
                or _get(cfg, "captioner", "provider", "model_path")}
    varying = ("metric", "seed", "label", "pipeline", "tasks", "task_group")
    return {**settings, **{k: v for k, v in record_identity(rec).items() if k not in varying}}


def quality_points(records: list[dict]) -> list[dict]:
    # label -> (pipeline, task) -> metric -> [per-run mean], and the per-run variances
    points: dict[str, dict] = {}
    first: dict[str, dict] = {}
    for rec in sorted(records, key=lambda r: (r.get("created") or "", r.get("path") or "")):
        if rec.get("status", "ok") != "ok" or rec.get("judge") == "oracle":
            continue
        tasks = rec.get("tasks", {})
        for metric in ("scene_alignment", "task_completion"):
            for task, v in (rec.get("values") or {}).get(metric, {}).items():
                if v.get("mean") is None:
                    continue
                pipeline = (tasks.get(task) or {}).get("pipeline")
                label = rec.get("label") or pipeline or "unlabelled"
                if label in first and judge_settings(first[label]) != judge_settings(rec):
                    raise UserError(
                        f"{first[label].get('path')} and {rec.get('path')} both give Figure 4 point {label!r} but "
                        f"differ in {identity_difference(judge_settings(first[label]), judge_settings(rec))}: give "
                        "the runs distinct label=..., or move one out of report.runs_dir")
                first.setdefault(label, rec)
                t = points.setdefault(label, {}).setdefault((pipeline, task), {"scene_alignment": [],
                                                                               "task_completion": [], "var": []})
                t[metric].append(v["mean"])
                t["var"].append(v.get("var") or 0.0)
    out = []
    for label, tasks in points.items():
        per_task = {m: [float(np.mean(t[m])) for t in tasks.values() if t[m]]
                    for m in ("scene_alignment", "task_completion")}
        means = {m: float(np.mean(v)) if v else None for m, v in per_task.items()}
        variances = [float(np.mean(t["var"])) for t in tasks.values() if t["var"]]
        out.append({"label": label, "n_alignment": len(per_task["scene_alignment"]),
                    "n_completion": len(per_task["task_completion"]), "n_tasks": len(tasks),
                    "scene_alignment": means["scene_alignment"], "task_completion": means["task_completion"],
                    "mean_var": float(np.mean(variances)) if variances else 0.0})
    return out


def build_quality_figure(runs_dir: str | Path, out_dir: str | Path, *, id: str = "figure4",
                         formats=("png", "pdf")) -> dict[str, list[Path]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = quality_points(read_results(runs_dir, "quality"))
    both = [p for p in points if p["scene_alignment"] is not None and p["task_completion"] is not None]
    if not both:
        raise UserError(f"no quality result.json under {runs_dir} with both scene_alignment and "
                                "task_completion scores: run `python src/quality.py metric=all ...` first")
    out = Path(out_dir)
    header = ["Label", "Scene alignment (1-5)", "Task completion (0-10)", "Mean variance", "Tasks"]
    rows = [[p["label"], f"{p['scene_alignment']:.2f}", f"{p['task_completion']:.2f}", f"{p['mean_var']:.2f}",
             str(p["n_tasks"])] for p in both]
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
        written["figure"].append(save_figure(fig, path, dpi=150))
    plt.close(fig)
    return written
