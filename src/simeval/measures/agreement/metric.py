"""Agreement between judge scores and human scores, and reliability of a judge across repeats.

For paired scores h (human) and m (model) over n tasks:
    pearson r      = cov(h, m) / (std(h) std(m))              scipy.stats.pearsonr
    mae            = mean |h - m|
    r_over_mae     = r / mae  (the paper's Figure 3)          undefined if r is undefined or mae == 0
    spearman rho   = pearson r of the average ranks           scipy.stats.spearmanr
    kendall tau-b  = (C - D) / sqrt((C + D + T_h)(C + D + T_m))   scipy.stats.kendalltau(variant="b")
                   (C, D: concordant, discordant pairs; T_h, T_m: pairs tied in h only, in m only)
A correlation is undefined when either column is constant (scipy would warn and return NaN; here: None).

Each comes with a percentile bootstrap 95% CI over tasks (resamples where the value is undefined are dropped; no
interval when fewer than 100 of them are defined). The resamples are the ones `bootstrap_ci` would draw (same
seed, same indices), but every statistic is evaluated on all of them at once from the (n_boot, n) matrix of
resample counts W: a weighted mean is W @ x / n, and Kendall's sums over pairs of draws are w^T A w with
A_ij = sign(h_i - h_j) sign(m_i - m_j) (two draws of the same task are tied in both, so they add nothing, as in
the loop over draws). 2000 resamples at n = 100 take milliseconds instead of seconds.

Reliability of one judge over repeats, from an (items, repeats) array with NaN for an invalid reply:
    krippendorff alpha (interval) = 1 - D_o / D_e               (missing values allowed)
        D_o = 1/n_. sum_u sum_{c != k in u} (x_c - x_k)^2 / (m_u - 1)
        D_e = sum_{c != k, all pairable values} (x_c - x_k)^2 / (n_. (n_. - 1))
        over units u with m_u >= 2 values, n_. = number of pairable values
    icc(1,1)                      = (MSB - MSW) / (MSB + (k - 1) MSW)   (complete rows only; Shrout & Fleiss 1979)
        MSB = k/(n-1) sum_i (mean_i - grand)^2,   MSW = 1/(n(k-1)) sum_ij (x_ij - mean_i)^2

Inputs are 1-D float arrays of equal length (n) or the 2-D array above; every function returns a float, or
None for "undefined" (never 0, never NaN, never an exception for a constant column).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import numpy as np
from scipy import stats

from simeval.errors import UserError
from simeval.stats.bootstrap import percentile_interval

METRIC_VERSION = "1.0"  # scipy point estimates and the vectorised bootstrap reproduce the 1.0 numbers (same resamples)
Undefined = None


def _pair(h: Sequence[float], m: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    h, m = np.asarray(h, dtype=float), np.asarray(m, dtype=float)
    if h.shape != m.shape or h.ndim != 1:
        raise ValueError(f"human and model scores must be 1-D of equal length, got {h.shape} and {m.shape}")
    if not (np.all(np.isfinite(h)) and np.all(np.isfinite(m))):
        raise ValueError("scores contain NaN or inf; drop or impute missing scores first")
    return h, m


def _correlation(fn: Callable, h: Sequence[float], m: Sequence[float]) -> float | None:
    """scipy's statistic, or None where it is undefined: fewer than 2 pairs or a constant column."""
    h, m = _pair(h, m)
    if len(h) < 2 or h.min() == h.max() or m.min() == m.max():
        return Undefined  # a constant column has no correlation
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # near-constant input warnings: the value is still returned
        r = float(fn(h, m).statistic)
    return r if np.isfinite(r) else Undefined


def pearson(h: Sequence[float], m: Sequence[float]) -> float | None:
    return _correlation(stats.pearsonr, h, m)


def mae(h: Sequence[float], m: Sequence[float]) -> float | None:
    h, m = _pair(h, m)
    return float(np.abs(h - m).mean()) if len(h) else Undefined


def r_over_mae(h: Sequence[float], m: Sequence[float]) -> float | None:
    r, e = pearson(h, m), mae(h, m)
    if r is None or e is None or e == 0:
        return Undefined
    return r / e


def spearman(h: Sequence[float], m: Sequence[float]) -> float | None:
    return _correlation(stats.spearmanr, h, m)


def kendall_tau_b(h: Sequence[float], m: Sequence[float]) -> float | None:
    return _correlation(lambda a, b: stats.kendalltau(a, b, variant="b"), h, m)


STATISTICS: dict[str, Callable] = {"pearson": pearson, "mae": mae, "r_over_mae": r_over_mae,
                                   "spearman": spearman, "kendall": kendall_tau_b}


def resample_counts(n: int, n_boot: int, seed: int) -> np.ndarray:
    """(n_boot, n) counts of each task in the resamples that `bootstrap_ci(.., n, n_boot=n_boot, seed=seed)` draws."""
    idx = np.random.default_rng(seed).integers(0, n, (n_boot, n))
    flat = (idx + n * np.arange(n_boot)[:, None]).ravel()
    return np.bincount(flat, minlength=n_boot * n).reshape(n_boot, n).astype(float)


def _weighted_pearson(w: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pearson r of each resample; x, y are (n,) or (n_boot, n) values per task, w the (n_boot, n) counts."""
    total = w.sum(1, keepdims=True)
    dx = x - (w * x).sum(1, keepdims=True) / total
    dy = y - (w * y).sum(1, keepdims=True) / total
    sxy, sxx, syy = (w * dx * dy).sum(1), (w * dx * dx).sum(1), (w * dy * dy).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.clip(sxy / np.sqrt(sxx * syy), -1.0, 1.0)


def _resample_ranks(w: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(n_boot, n) average rank, within each resample, of a draw of task i (1-based, ties averaged)."""
    below = w @ (x[:, None] < x[None, :]).astype(float)  # draws with a smaller value
    equal = w @ (x[:, None] == x[None, :]).astype(float)  # draws with the same value (itself included)
    return below + (equal + 1) / 2


def bootstrap_statistics(h: np.ndarray, m: np.ndarray, w: np.ndarray) -> dict[str, np.ndarray]:
    """Every statistic of STATISTICS on each resample given by the counts w (n_boot, n); NaN where undefined."""
    h, m = _pair(h, m)
    present = w > 0
    const_h = np.where(present, h, np.inf).min(1) == np.where(present, h, -np.inf).max(1)
    const_m = np.where(present, m, np.inf).min(1) == np.where(present, m, -np.inf).max(1)
    undefined = const_h | const_m | (w.sum(1) < 2)
    out = {"mae": (w @ np.abs(h - m)) / w.sum(1)}
    r = _weighted_pearson(w, h, m)
    out["pearson"] = np.where(undefined, np.nan, r)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["r_over_mae"] = np.where(out["mae"] > 0, out["pearson"] / out["mae"], np.nan)
    rho = _weighted_pearson(w, _resample_ranks(w, h), _resample_ranks(w, m))
    out["spearman"] = np.where(undefined, np.nan, rho)
    sh, sm = np.sign(h[:, None] - h[None, :]), np.sign(m[:, None] - m[None, :])
    num = ((w @ (sh * sm)) * w).sum(1)
    den = ((w @ np.abs(sh)) * w).sum(1) * ((w @ np.abs(sm)) * w).sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out["kendall"] = np.where(undefined | (den == 0), np.nan, num / np.sqrt(den))
    return out


def agreement_summary(h: Sequence[float], m: Sequence[float], *, n_boot: int = 2000, seed: int = 0) -> dict:
    """{"n", and for each statistic: value (float or None) and "<stat>_ci" ([lo, hi] or None)}.

    Statistic number k (in STATISTICS order) is resampled with seed + k, as it always was."""
    h, m = _pair(h, m)
    if isinstance(n_boot, bool) or not isinstance(n_boot, (int, np.integer)) or n_boot < 1:
        raise UserError(f"n_boot must be an integer >= 1 (bootstrap resamples), got {n_boot!r}")
    out: dict = {"n": int(len(h))}
    for offset, (name, fn) in enumerate(STATISTICS.items()):
        out[name] = fn(h, m)
        if out[name] is None or len(h) == 0:
            out[f"{name}_ci"] = None
            continue
        values = bootstrap_statistics(h, m, resample_counts(len(h), n_boot, seed + offset))[name]
        out[f"{name}_ci"] = percentile_interval(values[np.isfinite(values)], min_defined=100)
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
