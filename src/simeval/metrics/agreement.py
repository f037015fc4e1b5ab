"""Agreement between judge scores and human scores, and reliability of a judge across repeats.

For paired scores h (human) and m (model) over n tasks:
    pearson r      = cov(h, m) / (std(h) std(m))              undefined if either column is constant
    mae            = mean |h - m|
    r_over_mae     = r / mae  (the paper's Figure 3)          undefined if r is undefined or mae == 0
    spearman rho   = pearson r of the average ranks
    kendall tau-b  = (C - D) / sqrt((C + D + T_h)(C + D + T_m))
Each comes with a percentile bootstrap 95% CI over tasks (resamples where the value is undefined are dropped).

Reliability of one judge over repeats, from an (items, repeats) array with NaN for an invalid reply:
    krippendorff alpha (interval) = 1 - D_o / D_e               (missing values allowed)
    icc(1,1)                      = (MSB - MSW) / (MSB + (k - 1) MSW)   (complete rows only)

Inputs are 1-D float arrays of equal length (n) or the 2-D array above; every function returns a float, or
None for "undefined" (never 0, never NaN, never an exception for a constant column).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence

import numpy as np

from simeval.metrics.bootstrap import bootstrap_ci

METRIC_VERSION = "1.0"
Undefined = None


def _pair(h: Sequence[float], m: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    h, m = np.asarray(h, dtype=float), np.asarray(m, dtype=float)
    if h.shape != m.shape or h.ndim != 1:
        raise ValueError(f"human and model scores must be 1-D of equal length, got {h.shape} and {m.shape}")
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(m))):
        raise ValueError("scores contain NaN or inf; drop or impute missing scores first")
    return h, m


def pearson(h: Sequence[float], m: Sequence[float]) -> float | None:
    h, m = _pair(h, m)
    if len(h) < 2:
        return Undefined
    dh, dm = h - h.mean(), m - m.mean()
    denom = np.sqrt((dh**2).sum() * (dm**2).sum())
    if denom <= 1e-12 * max(1.0, np.abs(h).max(), np.abs(m).max()):
        return Undefined  # a constant column has no correlation
    return float(np.clip((dh * dm).sum() / denom, -1.0, 1.0))


def mae(h: Sequence[float], m: Sequence[float]) -> float | None:
    h, m = _pair(h, m)
    return float(np.abs(h - m).mean()) if len(h) else Undefined


def r_over_mae(h: Sequence[float], m: Sequence[float]) -> float | None:
    r, e = pearson(h, m), mae(h, m)
    if r is None or e is None or e == 0:
        return Undefined
    return r / e


def average_ranks(x: np.ndarray) -> np.ndarray:
    order = np.argsort(x, kind="mergesort")
    ranks = np.empty(len(x))
    sorted_x = x[order]
    i = 0
    while i < len(x):
        j = i
        while j + 1 < len(x) and sorted_x[j + 1] == sorted_x[i]:
            j += 1
        ranks[order[i : j + 1]] = (i + j) / 2 + 1
        i = j + 1
    return ranks


def spearman(h: Sequence[float], m: Sequence[float]) -> float | None:
    h, m = _pair(h, m)
    return pearson(average_ranks(h), average_ranks(m))


def kendall_tau_b(h: Sequence[float], m: Sequence[float]) -> float | None:
    h, m = _pair(h, m)
    conc = disc = tie_h = tie_m = 0
    for i, j in itertools.combinations(range(len(h)), 2):
        dh, dm = h[i] - h[j], m[i] - m[j]
        if dh == 0 and dm == 0:
            continue
        if dh == 0:
            tie_h += 1
        elif dm == 0:
            tie_m += 1
        elif (dh > 0) == (dm > 0):
            conc += 1
        else:
            disc += 1
    denom = np.sqrt((conc + disc + tie_h) * (conc + disc + tie_m))
    return Undefined if denom == 0 else float((conc - disc) / denom)


STATISTICS: dict[str, Callable] = {"pearson": pearson, "mae": mae, "r_over_mae": r_over_mae,
                                   "spearman": spearman, "kendall": kendall_tau_b}


def agreement_summary(h: Sequence[float], m: Sequence[float], *, n_boot: int = 2000, seed: int = 0) -> dict:
    """{"n", and for each statistic: value (float or None) and "<stat>_ci" ([lo, hi] or None)}."""
    h, m = _pair(h, m)
    out: dict = {"n": int(len(h))}
    for offset, (name, fn) in enumerate(STATISTICS.items()):
        out[name] = fn(h, m)
        if out[name] is None:
            out[f"{name}_ci"] = None
            continue
        # resamples over tasks; a resample where the statistic is undefined (e.g. constant) is dropped
        out[f"{name}_ci"] = bootstrap_ci(lambda idx, fn=fn: fn(h[idx], m[idx]), len(h), n_boot=n_boot,
                                         seed=seed + offset, min_defined=100)
    return out


def krippendorff_alpha_interval(scores: np.ndarray) -> float | None:
    """(items, repeats) with NaN for missing. Items with fewer than 2 values are not pairable and are skipped."""
    x = np.asarray(scores, dtype=float)
    if x.ndim != 2:
        raise ValueError(f"scores must be (items, repeats), got shape {x.shape}")
    units = [row[np.isfinite(row)] for row in x]
    units = [u for u in units if len(u) >= 2]
    if not units:
        return Undefined
    n = sum(len(u) for u in units)
    d_o = sum(((u[:, None] - u[None, :]) ** 2).sum() / (len(u) - 1) for u in units) / n
    pooled = np.concatenate(units)
    d_e = ((pooled[:, None] - pooled[None, :]) ** 2).sum() / (n * (n - 1))
    if d_e == 0:
        return Undefined  # every value identical: agreement is perfect but alpha is 0/0
    return float(1.0 - d_o / d_e)


def icc_1_1(scores: np.ndarray) -> float | None:
    """One-way random-effects ICC(1,1) on the complete rows of an (items, repeats) array."""
    x = np.asarray(scores, dtype=float)
    x = x[np.all(np.isfinite(x), axis=1)]
    if x.ndim != 2 or x.shape[0] < 2 or x.shape[1] < 2:
        return Undefined
    n, k = x.shape
    grand = x.mean()
    msb = k * ((x.mean(axis=1) - grand) ** 2).sum() / (n - 1)
    msw = ((x - x.mean(axis=1, keepdims=True)) ** 2).sum() / (n * (k - 1))
    denom = msb + (k - 1) * msw
    return Undefined if denom == 0 else float((msb - msw) / denom)
