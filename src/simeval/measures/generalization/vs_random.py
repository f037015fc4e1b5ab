"""A trained policy's mean progress against the chance baseline's, per split, from src/generalization.py runs.

    python src/generalization_tools.py vs-random --policy RUN [RUN ...] --random RUN [--drop-task NAME ...]

Each RUN is a run folder (its result.json). Per split (train, eval, heldout) the rollouts' progress values
(GenSim's step-wise reward: the share of the task's reward collected; 0 for a task without one) are pooled:

    policy  p (n_p,) = every rollout of every --policy run (one per training seed), minus the --drop-task tasks
    random  r (n_r,) = the same of the --random run(s)
    difference      mean(p) - mean(r)
    its interval    2.5 and 97.5 percentiles of mean(p*) - mean(r*) over 10,000 resamples, p* and r* drawn with
                    replacement from p and r separately (the two groups are independent rollouts)
    p-value         one-sided Mann-Whitney U test that p tends to be larger than r (scipy.stats.mannwhitneyu,
                    exact without ties in small samples, else its normal approximation with tie correction, which with a
                    handful of tied values can come out below the exact permutation p)

Why a task is dropped: GenSim draws some tasks' scenes from the same seeds (separating-piles and
separating-piles-seen-colors give the same scene for the same seed in its train mode), so one of them counts the
same rollouts twice. The rollout seeds are the same for every training seed: the policy's rollouts differ by its
weights, not by scene, and the pooled values are not independent draws of scenes (read the interval with that).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from simeval.cli import OneLineParser
from simeval.results import rolled_out

SPLITS = ("train", "eval", "heldout")


def progress_values(record: dict, split: str, drop: set[str]) -> list[float]:
    """Every rollout's progress in `split` of one generalization result.json, tasks in `drop` left out, and the
    seeds left out as unvaried (the eval variation left their scene as the train split's: nothing was rolled out)."""
    return [float(e["progress"]) for t in record["values"]["tasks"] if t["split"] == split and t["task"] not in drop
            for e in rolled_out(t["episodes"])]


def compare(policy: list[float], chance: list[float], n_boot: int = 10_000, seed: int = 0) -> dict:
    """Means, the difference with its percentile interval, and the one-sided Mann-Whitney p (formulas above)."""
    from scipy.stats import mannwhitneyu

    from simeval.stats.bootstrap import percentile_interval

    p, r = np.asarray(policy, float), np.asarray(chance, float)
    rng = np.random.default_rng(seed)
    diffs = (p[rng.integers(0, len(p), (n_boot, len(p)))].mean(1)
             - r[rng.integers(0, len(r), (n_boot, len(r)))].mean(1))
    lo, hi = percentile_interval(diffs)
    return {"policy_mean": float(p.mean()), "random_mean": float(r.mean()), "n_policy": len(p), "n_random": len(r),
            "difference": float(p.mean() - r.mean()), "interval": [float(lo), float(hi)],
            "p_one_sided": float(mannwhitneyu(p, r, alternative="greater").pvalue)}


def read_run(folder: Path, policy: str | None = None) -> dict:
    """A src/generalization.py run's result.json, checked: its metric, its rollouts' fields and, when `policy` is
    given, that the run used that policy (`--random` runs must be policy=random)."""
    path = folder / "result.json"
    try:
        record = json.loads(path.read_text())
    except FileNotFoundError:
        fail(f"error: {path}: no such file; give src/generalization.py run folders")
    except OSError as e:  # a file given for the folder, a folder named result.json
        fail(f"error: {path}: cannot read it ({e.strerror}); give src/generalization.py run folders")
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        fail(f"error: {path} is not a src/generalization.py result ({type(e).__name__}: {e})")
    metric = record.get("metric") if isinstance(record, dict) else None
    if metric != "generalization":
        fail(f"error: {path} is not a src/generalization.py result (its metric is {metric!r}, not 'generalization')")
    try:
        if not all(isinstance(t["task"], str) and isinstance(t["split"], str) and
                   all(e.get("unvaried") or isinstance(e["progress"], (int, float)) for e in t["episodes"])
                   for t in record["values"]["tasks"]):
            raise TypeError("a task, split or progress of the wrong type")
    except (KeyError, TypeError) as e:
        fail(f"error: {path}: a rollout row without task, split or progress ({type(e).__name__}: {e})")
    used = (record.get("identity") or {}).get("policy")
    if policy is not None and used != policy:
        fail(f"error: {folder} is a policy={used} run; --random takes runs of policy={policy}")
    return record


def fail(line: str) -> None:
    print(line, file=sys.stderr)
    sys.exit(2)


def main(argv: list[str] | None = None, conf_dir: Path | None = None) -> None:
    """The comparison above, printed as a Markdown table (reads run folders only: `conf_dir` is not needed)."""
    ap = OneLineParser(prog="generalization_tools.py vs-random", description=__doc__.splitlines()[0])
    ap.add_argument("--policy", type=Path, nargs="+", required=True, help="run folders of the trained policy")
    ap.add_argument("--random", type=Path, nargs="+", required=True, help="run folders of policy=random")
    ap.add_argument("--drop-task", nargs="*", default=[],
                    help="tasks left out (e.g. one that repeats another's scenes)")
    args = ap.parse_args(argv)
    drop = set(args.drop_task)
    policy = [read_run(f) for f in args.policy]
    chance = [read_run(f, policy="random") for f in args.random]
    tasks = {t["task"] for rec in policy + chance for t in rec["values"]["tasks"]}
    if drop - tasks:  # a misspelt name would silently keep the rollouts it meant to leave out
        fail(f"error: --drop-task {' '.join(sorted(drop - tasks))}: no such task in these runs; they have "
             f"{', '.join(sorted(tasks))}")
    rows = []
    notes = []
    for split in SPLITS:
        p = [v for rec in policy for v in progress_values(rec, split, drop)]
        r = [v for rec in chance for v in progress_values(rec, split, drop)]
        if not p or not r:
            if p or r:  # one side has rollouts there: say why the split has no row
                notes.append(f"{split}: no row ({'no policy' if not p else 'no random'} rollouts in that split)")
            continue
        c = compare(p, r)
        rows.append(f"| {split} | {c['policy_mean']:.3f} ({c['n_policy']}) | {c['random_mean']:.3f} "
                    f"({c['n_random']}) | {c['difference']:.2f} [{c['interval'][0]:.2f}, {c['interval'][1]:.2f}] "
                    f"| {c['p_one_sided']:.3f} |")
    if not rows:
        fail("error: no split has rollouts of both the --policy and the --random runs (after --drop-task)")
    print("| split | policy mean (rollouts) | random mean (rollouts) | difference [95% interval] "
          "| one-sided Mann-Whitney p |")
    print("|---|---|---|---|---|")
    print("\n".join(rows + [f"\n{n}" for n in notes]))
