"""Intervals for held-out prediction errors over training seeds and held-out episodes: a two-level percentile
bootstrap of a ratio of sums.

Shapes: x (R, E) and n (R, E): for training seed r and held-out episode e, a summed squared error and the frames it
was summed over (simeval.measures.dynamics_diversity.prediction's per-episode sums); strata (E,): each episode's task.

    statistic(x, n) = sum_{r, e} x[r, e] / sum_{r, e} n[r, e]          (the error over all frames: a ratio of sums)
    one resample    seeds: R of the R drawn with replacement;
                    episodes: within each task, that task's episodes drawn with replacement (the group keeps its
                    tasks and their sizes; every drawn seed gets the same episodes: the seeds' models are evaluated
                    on the same held-out episodes)
    interval        the [alpha/2, 1 - alpha/2] quantiles of the statistic over `n_boot` resamples (percentile)

Why written here and not scipy.stats.bootstrap: that resamples one axis of independent items; here the items are
crossed (seeds x episodes) and stratified by task, and paired comparisons (10 vs 40 training episodes of one group,
evaluated on the same held-out episodes) must use the same draws for both statistics (`draws`, then `ratio`).
With one seed the seed level is degenerate: the interval then covers episodes only.

    paired_draws    two groups whose episode e shares its start and actions (the dynamics controls' shared and
                    varied groups): the same episode indices for both, each group's seeds drawn on their own (their
                    models are different ones), so what the episodes share cancels in a difference of the groups
"""

from __future__ import annotations

import numpy as np


def draws(n_seeds: int, strata, n_boot: int = 2000, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """`n_boot` resamples (seed indices (R,), episode indices (E,)) as described in the module docstring."""
    strata = np.asarray(strata)
    groups = [np.flatnonzero(strata == s) for s in sorted(set(strata.tolist()))]
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_boot):
        seeds = rng.integers(0, n_seeds, n_seeds)
        episodes = np.concatenate([g[rng.integers(0, len(g), len(g))] for g in groups])
        out.append((seeds, episodes))
    return out


def paired_draws(n_seeds_a: int, n_seeds_b: int, strata, n_boot: int = 2000,
                 seed: int = 0) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[tuple[np.ndarray, np.ndarray]]]:
    """`n_boot` resamples for each of two groups with paired episodes (the module docstring): (draws of a, draws of
    b), the k-th of each holding the same episode indices."""
    first = draws(n_seeds_a, strata, n_boot, seed)
    rng = np.random.default_rng([seed, 1])
    second = [(rng.integers(0, n_seeds_b, n_seeds_b), episodes) for _, episodes in first]
    return first, second


def ratio(x, n, seeds: np.ndarray | None = None, episodes: np.ndarray | None = None,
          min_total: float = 0.0) -> float:
    """sum x / sum n over the rows `seeds` and columns `episodes` (all when None; repeats count again); NaN when
    sum n is 0 or below `min_total` (too little to read)."""
    x, n = np.asarray(x, float), np.asarray(n, float)
    if seeds is not None:
        x, n = x[seeds], n[seeds]
    if episodes is not None:
        x, n = x[:, episodes], n[:, episodes]
    total = n.sum()
    return float(x.sum() / total) if total > 0 and total >= min_total else float("nan")


def replicates(x, n, resamples: list[tuple[np.ndarray, np.ndarray]], min_total: float = 0.0) -> np.ndarray:
    """The statistic on every resample: (n_boot,)."""
    return np.array([ratio(x, n, s, e, min_total) for s, e in resamples])


def percentile(values, level: float = 0.95, max_missing: float = 1.0) -> list[float]:
    """The percentile interval of the finite replicates; NaN when more than `max_missing` of them are not finite
    (the interval would hold only for the resamples that happened to have something to count)."""
    values = np.asarray(values, float)
    finite = np.isfinite(values)
    if not finite.any() or 1 - finite.mean() > max_missing:
        return [float("nan"), float("nan")]
    values = values[finite]
    alpha = (1 - level) / 2
    return [float(np.quantile(values, alpha)), float(np.quantile(values, 1 - alpha))]


def ratio_interval(x, n, strata, n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> dict:
    """{value, interval} of the error over seeds and episodes."""
    x = np.asarray(x, float)
    return {"value": ratio(x, n), "interval": percentile(replicates(x, n, draws(x.shape[0], strata, n_boot, seed)),
                                                         level)}
