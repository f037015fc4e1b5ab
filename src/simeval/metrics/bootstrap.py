"""Percentile bootstrap over items, shared by the metric modules.

    bootstrap_ci(statistic, n): statistic(idx) on n_boot resamples idx ~ Uniform{0..n-1}^n (with replacement);
    the interval is the [alpha/2, 1 - alpha/2] quantiles of the defined values (statistic returned a float).
Returns [low, high], or None when fewer than `min_defined` resamples gave a defined value.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


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
