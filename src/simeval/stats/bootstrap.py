"""Intervals shared by the metric modules: percentile bootstrap and jackknife.

    bootstrap_ci(statistic, n): statistic(idx) on n_boot resamples idx ~ Uniform{0..n-1}^n (with replacement);
        the interval is the [alpha/2, 1 - alpha/2] quantiles of the defined values (statistic returned a float).
        Returns [low, high], or None when fewer than `min_defined` resamples gave a defined value.
    jackknife_interval(estimate, loo): loo (n,) = the statistic on the n sets that leave one item out (no item is
        ever repeated);  se^2 = (n-1)/n * sum_i (loo_i - mean(loo))^2;  [estimate - z se, estimate + z se] with
        z the normal (1 + level)/2 quantile, clipped to the statistic's range. Returns [low, high], or None when n < 3.

Which to use: the bootstrap suits statistics whose value does not depend on how many items there are (a mean, a
mean over pairs with a resample's duplicate pairs masked). A statistic that counts effective distinct items
(Vendi) or that scores each item against all the others (Self-BLEU) changes when an item is drawn twice, so every
bootstrap resample is biased (Vendi low; a duplicated text would be its own reference) and the percentile
interval can exclude the estimate. The jackknife never repeats an item, and removing one item shifts a
size-dependent statistic by a first-order amount that the spread of the leave-one-out values measures directly;
the interval is centred on the estimate (it contains it by construction) and its coverage of E[statistic at this
n] is checked by simulation in tests/test_text_diversity_metrics.py.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import stats


def percentile_interval(values, level: float = 0.95, min_defined: int = 10) -> list[float] | None:
    values = np.asarray(values, dtype=float)
    if values.size < min_defined:
        return None  # too few defined resamples for a percentile interval
    alpha = (1 - level) / 2
    return [float(np.quantile(values, alpha)), float(np.quantile(values, 1 - alpha))]


def bootstrap_ci(statistic: Callable[[np.ndarray], float | None], n_items: int, *, n_boot: int = 1000,
                 seed: int = 0, level: float = 0.95, min_defined: int = 10) -> list[float] | None:
    rng = np.random.default_rng(seed)
    values = [statistic(rng.integers(0, n_items, n_items)) for _ in range(n_boot)]
    return percentile_interval([v for v in values if v is not None], level, min_defined)


def jackknife_se(leave_one_out) -> float:
    """Jackknife standard error from the (n,) leave-one-out values."""
    loo = np.asarray(leave_one_out, dtype=float)
    n = loo.size
    return float(np.sqrt((n - 1) / n * np.sum((loo - loo.mean()) ** 2)))


def jackknife_interval(estimate: float, leave_one_out, level: float = 0.95,
                       bounds: tuple[float, float] = (-np.inf, np.inf)) -> list[float] | None:
    """Normal interval from the jackknife se, clipped to `bounds` (the values the statistic can take)."""
    loo = np.asarray(leave_one_out, dtype=float)
    if loo.size < 3 or not np.all(np.isfinite(loo)):
        return None  # two leave-one-out values give no useful spread
    half = float(stats.norm.ppf((1 + level) / 2)) * jackknife_se(loo)
    return [float(max(estimate - half, bounds[0])), float(min(estimate + half, bounds[1]))]
