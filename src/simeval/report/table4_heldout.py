"""Table 4 under the heldout protocol: per (pipeline, group, preset, steps) and training-episode count, the world
model's prediction errors on held-out episodes beside the baselines, with 95% intervals over training seeds and
held-out episodes (simeval.metrics.resample), from dynamics_diversity result.json records of protocol=heldout.

Per cell (the runs of one count: one per training seed, all evaluated on the same held-out episodes), from the
per-episode sums of simeval.models.prediction, with x[r, e] summed squared errors and n[r, e] frames:
    open_loop           sum x_model / sum n           (the primary number: frames imagined from actions)
    open_loop_last      sum x_last / sum n            (copy the last observed frame)
    open_loop_mean      sum x_mean / sum n            (the task's mean training image)
    skill_last          1 - open_loop / open_loop_last;  skill_mean  1 - open_loop / open_loop_mean
    object              the open-loop error per kept (non-robot) pixel and channel; object_skill_last likewise
    one_step, one_step_skill_last, reconstruction (the paper's quantity, here on held-out frames)
and per row the fall from the first to the last count (`drop`, open_loop_<first> - open_loop_<last>) on paired
resamples (the same seeds' indices and held-out episodes for both counts).

    rows = build(read_results(root, "dynamics_diversity"))
    write(rows, "outputs/tables/table4_heldout")      # .csv (every number), .md
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from simeval.errors import UserError
from simeval.metrics import resample
from simeval.report.tables import to_csv, to_markdown
from simeval.results import atomic_write_text

METRIC = "dynamics_diversity"
# name -> (numerator sum key, denominator sum key, scale of the denominator)
RATIOS = {
    "open_loop": ("open_loop/model/full", "open_loop/frames", 1),
    "open_loop_last": ("open_loop/last/full", "open_loop/frames", 1),
    "open_loop_mean": ("open_loop/mean/full", "open_loop/frames", 1),
    "object": ("open_loop/model/object", "open_loop/kept_pixels", 3),
    "object_last": ("open_loop/last/object", "open_loop/kept_pixels", 3),
    "one_step": ("one_step/model/full", "one_step/frames", 1),
    "one_step_last": ("one_step/last/full", "one_step/frames", 1),
    "reconstruction": ("reconstruction/model/full", "reconstruction/frames", 1),
}
SKILLS = {"skill_last": ("open_loop", "open_loop_last"), "skill_mean": ("open_loop", "open_loop_mean"),
          "object_skill_last": ("object", "object_last"), "one_step_skill_last": ("one_step", "one_step_last")}
SHOWN = ("open_loop", "skill_last", "skill_mean", "object", "reconstruction")


def sum_arrays(recs: list[dict]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """({sum key: (R, E)}, tasks (E,)) from the per-episode sums of R runs; every run must have evaluated the same
    held-out episodes (a UserError names the difference)."""
    def episodes(rec):
        return [(e["task"], int(e["seed"])) for e in rec["values"]["prediction"]["per_episode"]]

    order = sorted(episodes(recs[0]))
    for rec in recs[1:]:
        if sorted(episodes(rec)) != order:
            raise UserError(f"{rec.get('path', 'a run')}: evaluated other held-out episodes than "
                            f"{recs[0].get('path', 'the first run')}; a cell compares runs on the same episodes")
    keys = recs[0]["values"]["prediction"]["per_episode"][0]["sums"].keys()
    out = {k: np.zeros((len(recs), len(order))) for k in keys}
    for r, rec in enumerate(recs):
        where = {(e["task"], int(e["seed"])): e["sums"] for e in rec["values"]["prediction"]["per_episode"]}
        for j, ep in enumerate(order):
            for k in keys:
                out[k][r, j] = where[ep][k]
    return out, np.array([t for t, _ in order])


def cell_replicates(sums: dict[str, np.ndarray], draws) -> tuple[dict[str, float], dict[str, np.ndarray]]:
    """Point values and bootstrap replicates (on `draws`) of every RATIOS and SKILLS entry of one cell."""
    point, reps = {}, {}
    for name, (num, den, scale) in RATIOS.items():
        x, n = sums[num], sums[den] * scale
        point[name] = resample.ratio(x, n)
        reps[name] = resample.replicates(x, n, draws)
    with np.errstate(invalid="ignore", divide="ignore"):
        for name, (model, base) in SKILLS.items():
            point[name] = 1 - point[model] / point[base] if point[base] else float("nan")
            reps[name] = 1 - reps[model] / reps[base]
    return point, reps


def build(records: list[dict], *, n_boot: int = 2000, seed: int = 0) -> list[dict]:
    """One row per (pipeline, group, preset, steps) with runs of protocol=heldout (see the module docstring)."""
    cells: dict = defaultdict(lambda: defaultdict(list))
    for rec in records:
        ident = rec.get("identity") or {}
        if rec.get("metric") != METRIC or rec.get("status") != "ok" or ident.get("protocol") != "heldout":
            continue
        cells[(ident["pipeline"], ident["task_group"], ident["preset"], ident.get("steps"))][
            int(ident["episodes"])].append(rec)
    rows = []
    for (p, g, pr, steps), by_k in sorted(cells.items(), key=lambda kv: tuple(map(str, kv[0]))):
        counts = sorted(by_k)
        row = {"pipeline": p, "group": g, "preset": pr, "steps": steps, "counts": "/".join(map(str, counts))}
        reps_by_k = {}
        for k in counts:
            recs = sorted(by_k[k], key=lambda r: int(r["identity"].get("seed", 0)))
            sums, tasks = sum_arrays(recs)
            draws = resample.draws(len(recs), tasks, n_boot, seed)  # the same draws for every count: paired
            point, reps = cell_replicates(sums, draws)
            reps_by_k[k] = reps
            row[f"runs_{k}"] = len(recs)
            row[f"heldout_episodes_{k}"] = len(tasks)
            row[f"robot_mask_{k}"] = all(r["values"]["prediction"].get("robot_mask") for r in recs)
            for name, v in point.items():
                row[f"{name}_{k}"] = v
                row[f"{name}_{k}_lo"], row[f"{name}_{k}_hi"] = resample.percentile(reps[name])
        lo, hi = counts[0], counts[-1]
        if lo != hi and row[f"runs_{lo}"] == row[f"runs_{hi}"] and \
                row[f"heldout_episodes_{lo}"] == row[f"heldout_episodes_{hi}"]:
            drop = reps_by_k[lo]["open_loop"] - reps_by_k[hi]["open_loop"]
            row["drop"] = row[f"open_loop_{lo}"] - row[f"open_loop_{hi}"]
            row["drop_lo"], row["drop_hi"] = resample.percentile(drop)
        rows.append(row)
    return rows


def _ci(row: dict, name: str, digits: int) -> str:
    v = row.get(name)
    if v is None or not np.isfinite(v):
        return "—"
    return f"{v:.{digits}f} [{row[name + '_lo']:.{digits}f}, {row[name + '_hi']:.{digits}f}]"


def display(rows: list[dict]) -> tuple[list[str], list[list[str]]]:
    """A compact Markdown view: per count the open-loop error, its skill against both baselines, the
    object-focused error (masked) and the reconstruction, each with its 95% interval."""
    header = ["Method", "Task group", "preset (steps)", "episodes", "seeds", "open-loop error",
              "skill vs last frame", "skill vs mean image", "object-focused (x1e-3/pixel)", "reconstruction",
              "drop first->last"]
    body = []
    for r in rows:
        for i, k in enumerate(int(c) for c in r["counts"].split("/")):
            obj = "—"
            if r.get(f"object_{k}") is not None and np.isfinite(r[f"object_{k}"]):
                scaled = {f"object_{k}{s}": r[f"object_{k}{s}"] * 1e3 for s in ("", "_lo", "_hi")}
                obj = _ci(scaled, f"object_{k}", 2) + ("" if r[f"robot_mask_{k}"] else " (no masks: full frame)")
            body.append([r["pipeline"] if i == 0 else "", r["group"] if i == 0 else "",
                         f"{r['preset']} ({r['steps']})" if i == 0 else "", str(k), str(r[f"runs_{k}"]),
                         _ci(r, f"open_loop_{k}", 1), _ci(r, f"skill_last_{k}", 2), _ci(r, f"skill_mean_{k}", 2),
                         obj, _ci(r, f"reconstruction_{k}", 1), _ci(r, "drop", 1) if i == 0 else ""])
    return header, body


def write(rows: list[dict], stem: str | Path) -> dict[str, Path]:
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    columns = sorted({k for r in rows for k in r}, key=lambda c: (c not in ("pipeline", "group", "preset", "steps",
                                                                            "counts"), c))
    csv_rows = [[r.get(c, "") for c in columns] for r in rows]
    header, body = display(rows)
    note = ("Held-out episodes (no model of a row trained on them); the same gradient steps for every count; "
            "errors summed over H x W x 3 pixels per frame; [95% interval over training seeds and held-out "
            "episodes]; skill = 1 - error / baseline error (< 0: worse than the baseline).")
    paths = {"csv": stem.with_suffix(".csv"), "md": stem.with_suffix(".md")}
    atomic_write_text(paths["csv"], to_csv(columns, csv_rows))
    atomic_write_text(paths["md"], to_markdown(header, body) + "\n" + note + "\n")
    return paths


def plot(rows: list[dict], path: str | Path, title: str = "") -> Path:
    """Per row, against training episodes: the open-loop error with its interval and the two baselines (left), the
    skill against the last frame with its interval (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    colors = [f"C{i}" for i in range(10)]
    for r, color in zip(rows, colors):
        ks = [int(c) for c in r["counts"].split("/")]
        for ax, name in ((ax1, "open_loop"), (ax2, "skill_last")):
            v = np.array([r[f"{name}_{k}"] for k in ks])
            err = np.array([[v[i] - r[f"{name}_{k}_lo"], r[f"{name}_{k}_hi"] - v[i]] for i, k in enumerate(ks)]).T
            err = np.maximum(err, 0)  # a percentile interval of a ratio may sit beside its point estimate
            ax.errorbar(ks, v, yerr=err, fmt="o-", color=color, capsize=3, label=f"{r['pipeline']}/{r['group']}")
        ax1.plot(ks, [r[f"open_loop_last_{k}"] for k in ks], ":", color=color, label=f"{r['group']}: last frame")
        ax1.plot(ks, [r[f"open_loop_mean_{k}"] for k in ks], "--", color=color, alpha=0.6,
                 label=f"{r['group']}: mean image")
    ax1.set(xlabel="training episodes per task", ylabel="open-loop error (sum over pixels per frame)",
            title="held-out prediction error (95% CI)", xscale="log")
    ax2.axhline(0, color="0.5", lw=0.8)
    ax2.set(xlabel="training episodes per task", ylabel="skill vs last frame (1 - model / baseline)",
            title="skill against copying the last frame", xscale="log")
    for ax in (ax1, ax2):
        ks = sorted({int(c) for r in rows for c in r["counts"].split("/")})
        ax.set_xticks(ks, [str(k) for k in ks])
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
