"""The generalization gap scene by scene: each eval rollout against the train rollout of the same task and seed.

From src/generalization.py runs.

    python src/generalization_tools.py eval-vs-train RUN [RUN ...] [--drop-task NAME ...]

Each RUN is a run folder (its result.json), one per training seed, all of one setting (pipeline, tasks, policy,
variations, rollout seeds and step limit: what Table 5 pools into one cell). The eval and train splits roll out the same
trained tasks on the same seeds; the eval one under the task's variation (unseen colours, counts, a moved robot).
So every eval rollout has a train twin that differs only by the variation, and the gap is read pair by pair:

    pairs        (task, seed, run) with an eval rollout; eval rollouts left out as unvaried (the variation changed
                 no scene: simeval.measures.generalization.rollouts.rollout_task) have no pair
    d (n,)       eval progress - train progress, per pair (progress: GenSim's step-wise reward; success 0/1 where
                 a task has no reward)
    gap          mean(d)
    its interval 2.5 and 97.5 percentiles of mean(d*) over 10,000 resamples of the pairs with replacement
    p-value      two-sided Wilcoxon signed-rank test of d (scipy.stats.wilcoxon; zero differences dropped, as its
                 default); '-' when every difference is zero

Pooled over runs, the pairs of one task and seed share their scene across training seeds: the interval says how
the policy's weights vary on these scenes more than how scenes vary. Why a task is dropped: GenSim draws some
tasks' scenes alike (separating-piles-seen-colors repeats separating-piles, seed for seed), counting one scene twice.
Table 5 pools each split's rollouts on its own; this compares them where they can be compared, scene by scene.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simeval.cli import OneLineParser
from simeval.measures.generalization import vs_random as reading
from simeval.results import rolled_out


def paired_progress(record: dict, drop: set[str]) -> list[tuple[str, int, float, float]]:
    """(task, seed, train progress, eval progress) for every eval rollout of one result.json that has a train
    rollout of the same task and seed; tasks in `drop` and unvaried eval seeds left out."""
    train = {(t["task"], e["seed"]): e for t in record["values"]["tasks"] if t["split"] == "train"
             for e in rolled_out(t["episodes"])}
    return [(t["task"], e["seed"], float(train[t["task"], e["seed"]]["progress"]), float(e["progress"]))
            for t in record["values"]["tasks"] if t["split"] == "eval" and t["task"] not in drop
            for e in rolled_out(t["episodes"]) if (t["task"], e["seed"]) in train]


def gap(train: list[float], varied: list[float], n_boot: int = 10_000, seed: int = 0) -> dict:
    """Means, the paired gap with its percentile interval, and the two-sided Wilcoxon p (formulas above)."""
    from scipy.stats import wilcoxon

    from simeval.stats.bootstrap import percentile_interval

    t, v = np.asarray(train, float), np.asarray(varied, float)
    d = v - t
    rng = np.random.default_rng(seed)
    lo, hi = percentile_interval(d[rng.integers(0, len(d), (n_boot, len(d)))].mean(1))
    p = float(wilcoxon(v, t).pvalue) if np.any(d != 0) else None
    return {"n": len(d), "train_mean": float(t.mean()), "eval_mean": float(v.mean()), "gap": float(d.mean()),
            "interval": [float(lo), float(hi)], "p_two_sided": p}


def check_one_setting(folders: list[Path], records: list[dict], fail) -> None:
    """The runs differ only by their training seed (Table 5's rule for one cell,
    simeval.measures.generalization.table5), each given once: pooling another variation, policy or step limit, or one
    run twice, would read a gap that is no one's."""
    from simeval.measures.generalization.table5 import cell_setting
    from simeval.results import identity_difference

    seen: dict = {}
    for folder, rec in zip(folders, records):
        where = folder.resolve()
        if where in seen.values():
            fail(f"error: {folder}: given twice; each run counts once")
        seed = (rec.get("identity") or {}).get("seed")
        if seed in seen:
            fail(f"error: {folder} and {seen[seed]}: two runs of training seed {seed}; give one run per seed")
        seen[seed] = where
    first = cell_setting(records[0])
    for folder, rec in zip(folders[1:], records[1:]):
        if (other := cell_setting(rec)) != first:
            fail(f"error: {folder}: another setting than {folders[0]} (differs in "
                 f"{identity_difference(first, other)}); pool runs of one setting, one per training seed")


def main(argv: list[str] | None = None, conf_dir: Path | None = None) -> None:
    """The gap above, printed as a Markdown table (reads run folders only: `conf_dir` is not needed). The run
    reading and its checks are simeval.measures.generalization.vs_random's."""
    ap = OneLineParser(prog="generalization_tools.py eval-vs-train", description=__doc__.splitlines()[0])
    ap.add_argument("runs", type=Path, nargs="+", help="run folders of src/generalization.py (one per training seed)")
    ap.add_argument("--drop-task", nargs="*", default=[],
                    help="tasks left out (e.g. one that repeats another's scenes)")
    args = ap.parse_args(argv)
    records = [reading.read_run(f) for f in args.runs]
    check_one_setting(args.runs, records, reading.fail)
    drop = set(args.drop_task)
    tasks = {t["task"] for rec in records for t in rec["values"]["tasks"]}
    if drop - tasks:  # a misspelt name would silently keep the rollouts it meant to leave out
        reading.fail(f"error: --drop-task {' '.join(sorted(drop - tasks))}: no such task in these runs; they have "
                     f"{', '.join(sorted(tasks))}")
    pairs = [p for rec in records for p in paired_progress(rec, drop)]
    if not pairs:
        evals = [e for rec in records for t in rec["values"]["tasks"] if t["split"] == "eval" and t["task"] not in drop
                 for e in t["episodes"]]
        if evals and all(e.get("unvaried") for e in evals):
            reading.fail(f"error: every eval rollout of these runs ({len(evals)}) was left out as unvaried: the "
                         "variation changed no scene, so there is no gap to read")
        reading.fail("error: no eval rollout has a train rollout of the same task and seed in these runs (run "
                     "src/generalization.py with eval.splits=[train,eval]; after --drop-task)")
    print("| tasks | pairs | train mean | eval mean | gap (eval - train) [95% interval] | two-sided Wilcoxon p |")
    print("|---|---|---|---|---|---|")
    for label, chosen in [("all", pairs), *((task, [p for p in pairs if p[0] == task])
                                            for task in sorted({p[0] for p in pairs}))]:
        g = gap([p[2] for p in chosen], [p[3] for p in chosen])
        p = "-" if g["p_two_sided"] is None else f"{g['p_two_sided']:.3f}"
        print(f"| {label} | {g['n']} | {g['train_mean']:.3f} | {g['eval_mean']:.3f} | {g['gap']:+.3f} "
              f"[{g['interval'][0]:+.3f}, {g['interval'][1]:+.3f}] | {p} |")
