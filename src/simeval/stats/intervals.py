"""Confidence intervals for success rates (pure functions).

    wilson_interval(k, n, level=0.95) -> (low, high): the Wilson score interval for a binomial proportion,
        p = k/n, z = the normal (1 + level)/2 quantile,
        centre = (p + z^2/(2n)) / (1 + z^2/n),   half = z / (1 + z^2/n) * sqrt(p(1-p)/n + z^2/(4n^2)),
        [centre - half, centre + half] clipped to [0, 1]. Unlike the normal (Wald) interval it is never [0, 0]
        for 0 successes out of n: 0/20 gives [0, 0.161], which is what a table of small success rates needs.
        n = 0 returns (0.0, 1.0): nothing observed, every rate possible.
    success_summary(successes) -> {"k", "n", "rate", "ci"} for a list of booleans.
    task_bootstrap_interval(k, n) -> (low, high): the group's pooled rate sum(k) / sum(n) over T tasks (k, n: (T,)
        successes and rollouts per task), its interval the percentile bootstrap over tasks (T tasks drawn with
        replacement, each with all its rollouts: a cluster bootstrap). Rollouts of one task are not independent of
        each other (one easy task can hold every success), which the Wilson interval of the pooled counts assumes;
        resampling whole tasks is what a group-level interval must do. None for fewer than 2 tasks.
        With several training seeds, k and n are (S, T) (seed s, task t): seeds and tasks are drawn with
        replacement independently (a crossed two-way cluster bootstrap: the S drawn seeds each contribute the T
        drawn tasks), so the interval holds the spread between training seeds as well as between tasks. For S = 1
        it is the (T,) interval exactly (the task draws come first from the same generator).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from scipy import stats

from simeval.errors import UserError


def wilson_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    if isinstance(k, bool) or isinstance(n, bool) or int(k) != k or int(n) != n or not 0 <= k <= n:
        raise UserError(f"wilson_interval needs whole numbers 0 <= k <= n, got k={k!r}, n={n!r}")
    if not 0 < level < 1:
        raise UserError(f"interval level must be in (0, 1), got {level!r}")
    if n == 0:
        return 0.0, 1.0
    z = float(stats.norm.ppf((1 + level) / 2))
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    # at k = 0 (k = n) the bound is exactly 0 (1); in floats centre - half leaves ~1e-18, above the rate itself
    return (0.0 if k == 0 else max(0.0, centre - half)), (1.0 if k == n else min(1.0, centre + half))


def success_summary(successes: Iterable[bool], level: float = 0.95) -> dict:
    s = [bool(x) for x in successes]
    k, n = sum(s), len(s)
    return {"k": k, "n": n, "rate": k / n if n else None, "ci": list(wilson_interval(k, n, level))}


def task_bootstrap_interval(k, n, level: float = 0.95, n_boot: int = 4000, seed: int = 0) -> tuple[float, float] | None:
    import numpy as np

    k, n = np.atleast_2d(np.asarray(k, float)), np.atleast_2d(np.asarray(n, float))
    if k.shape != n.shape or k.ndim != 2:
        raise UserError(f"task_bootstrap_interval needs k and n of one shape, (tasks,) or (seeds, tasks); got "
                        f"{k.shape} and {n.shape}")
    n_seeds, n_tasks = k.shape
    if n_tasks < 2 or n.sum() == 0:
        return None
    rng = np.random.default_rng(seed)
    tasks = rng.integers(0, n_tasks, (n_boot, n_tasks))
    seeds = rng.integers(0, n_seeds, (n_boot, n_seeds))
    # per draw: the (S*, T*) block of drawn seeds x drawn tasks, summed; per-task sums over the drawn seeds first
    k_task = k[seeds].sum(1)  # (n_boot, T): each task's successes over the drawn seeds
    n_task = n[seeds].sum(1)
    rows = np.arange(n_boot)[:, None]
    num, den = k_task[rows, tasks].sum(1), n_task[rows, tasks].sum(1)
    rates = num[den > 0] / den[den > 0]
    alpha = (1 - level) / 2
    return float(np.quantile(rates, alpha)), float(np.quantile(rates, 1 - alpha))
