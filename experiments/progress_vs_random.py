"""A trained policy's mean progress against the chance baseline's, per split, from src/generalization.py runs.

    python experiments/progress_vs_random.py --policy RUN [RUN ...] --random RUN [--drop-task NAME ...]

Each RUN is a run folder (its result.json). Per split (train, eval, heldout) the rollouts' progress values
(GenSim's step-wise reward: the share of the task's reward collected; 0 for a task without one) are pooled:

    policy  p (n_p,) = every rollout of every --policy run (one per training seed), minus the --drop-task tasks
    random  r (n_r,) = the same of the --random run(s)
    difference      mean(p) - mean(r)
    its interval    2.5 and 97.5 percentiles of mean(p*) - mean(r*) over 10,000 resamples, p* and r* drawn with
                    replacement from p and r separately (the two groups are independent rollouts)
    p-value         one-sided Mann-Whitney U test that p tends to be larger than r (scipy.stats.mannwhitneyu,
                    ties handled by its normal approximation with tie correction)

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

SPLITS = ("train", "eval", "heldout")


def progress_values(record: dict, split: str, drop: set[str]) -> list[float]:
    """Every rollout's progress in `split` of one generalization result.json, tasks in `drop` left out."""
    return [float(e["progress"]) for t in record["values"]["tasks"] if t["split"] == split and t["task"] not in drop
            for e in t["episodes"]]


def compare(policy: list[float], chance: list[float], n_boot: int = 10_000, seed: int = 0) -> dict:
    """Means, the difference with its percentile interval, and the one-sided Mann-Whitney p (formulas above)."""
    from scipy.stats import mannwhitneyu

    p, r = np.asarray(policy, float), np.asarray(chance, float)
    rng = np.random.default_rng(seed)
    diffs = (p[rng.integers(0, len(p), (n_boot, len(p)))].mean(1)
             - r[rng.integers(0, len(r), (n_boot, len(r)))].mean(1))
    lo, hi = np.percentile(diffs, [2.5, 97.5])
    return {"policy_mean": float(p.mean()), "random_mean": float(r.mean()), "n_policy": len(p), "n_random": len(r),
            "difference": float(p.mean() - r.mean()), "interval": [float(lo), float(hi)],
            "p_one_sided": float(mannwhitneyu(p, r, alternative="greater").pvalue)}


def read_run(folder: Path) -> dict:
    path = folder / "result.json"
    try:
        record = json.loads(path.read_text())
        if not isinstance(record["values"]["tasks"], list):  # a run of another entrypoint has no rollouts
            raise TypeError("values.tasks is not a list of rollouts")
    except FileNotFoundError:
        fail(f"error: {path}: no such file; give src/generalization.py run folders")
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError) as e:
        fail(f"error: {path} is not a src/generalization.py result ({type(e).__name__}: {e})")
    return record


def fail(line: str) -> None:
    print(line, file=sys.stderr)
    sys.exit(2)


def main(argv: list[str] | None = None) -> None:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--policy", type=Path, nargs="+", required=True, help="run folders of the trained policy")
    ap.add_argument("--random", type=Path, nargs="+", required=True, help="run folders of policy=random")
    ap.add_argument("--drop-task", nargs="*", default=[], help="tasks left out (e.g. one that repeats another's scenes)")
    args = ap.parse_args(argv)
    drop = set(args.drop_task)
    policy = [read_run(f) for f in args.policy]
    chance = [read_run(f) for f in args.random]
    print("| split | policy mean (rollouts) | random mean (rollouts) | difference [95% interval] | one-sided Mann-Whitney p |")
    print("|---|---|---|---|---|")
    for split in SPLITS:
        p = [v for rec in policy for v in progress_values(rec, split, drop)]
        r = [v for rec in chance for v in progress_values(rec, split, drop)]
        if not p or not r:
            continue
        c = compare(p, r)
        print(f"| {split} | {c['policy_mean']:.3f} ({c['n_policy']}) | {c['random_mean']:.3f} ({c['n_random']}) | "
              f"{c['difference']:.2f} [{c['interval'][0]:.2f}, {c['interval'][1]:.2f}] | {c['p_one_sided']:.3f} |")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
