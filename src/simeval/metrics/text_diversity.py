"""Text diversity of a set of task descriptions.

Eq. 1 of the paper (after Texygen's embedding similarity), for unit-normalised embeddings e_1..e_N:

    div = -1/N * sum_i log( 1/(N-1) * sum_{j != i} e_i . e_j )

Higher means less similar, i.e. more diverse. Also here, each a pure function of a similarity matrix or texts:

    vendi      = exp( -sum_k lam_k log lam_k ),  lam = eigenvalues of S / N          (effective number of tasks)
    cos_dist   = 1/(N(N-1)) * sum_{i != j} (1 - S_ij)                                  (mean pairwise distance)
    self_bleu  = 1/N * sum_i BLEU-4(text_i ; references = every text but i)           (lower = more diverse)

Shapes: `embeddings` (N, D) float; `similarity` (N, N) float, symmetric, diagonal ignored; `texts` list of N str.
Returns plain floats; `diversity_summary` returns a dict of them with bootstrap 95% CIs over tasks.

Errors (never a NaN): N < 2, a row whose mean off-diagonal similarity is <= 0 (log undefined), non-finite input.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np

METRIC_VERSION = "1.0"


class DiversityInputError(ValueError):
    """The input cannot give a defined diversity value; the message says why and which item."""


def cosine_similarity_matrix(embeddings: np.ndarray) -> np.ndarray:
    """(N, D) -> (N, N) cosine similarities. Zero vectors are an error (their direction is undefined)."""
    emb = np.asarray(embeddings, dtype=np.float64)
    if emb.ndim != 2:
        raise DiversityInputError(f"embeddings must be 2-D (N, D), got shape {emb.shape}")
    if not np.all(np.isfinite(emb)):
        raise DiversityInputError("embeddings contain NaN or inf")
    norms = np.linalg.norm(emb, axis=1)
    if np.any(norms == 0):
        raise DiversityInputError(f"embedding(s) {np.flatnonzero(norms == 0).tolist()} are all zeros")
    unit = emb / norms[:, None]
    return unit @ unit.T


def _check_square(similarity: np.ndarray) -> np.ndarray:
    s = np.asarray(similarity, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] != s.shape[1]:
        raise DiversityInputError(f"similarity must be square (N, N), got shape {s.shape}")
    if s.shape[0] < 2:
        raise DiversityInputError(f"diversity needs at least 2 tasks, got {s.shape[0]}")
    if not np.all(np.isfinite(s)):
        raise DiversityInputError("similarity matrix contains NaN or inf")
    return s


def _offdiag_row_means(s: np.ndarray, same: np.ndarray | None = None) -> np.ndarray:
    """Mean of each row over the pairs that count: j != i, and (for bootstrap) not a copy of the same task."""
    valid = ~np.eye(len(s), dtype=bool) if same is None else ~same
    counts = valid.sum(axis=1)
    if np.any(counts == 0):
        raise DiversityInputError("a task has no other distinct task to be compared with")
    return np.where(valid, s, 0.0).sum(axis=1) / counts


def eq1_diversity(similarity: np.ndarray, *, _same: np.ndarray | None = None) -> float:
    """The paper's Eq. 1 on a (N, N) similarity matrix (diagonal removed)."""
    s = _check_square(similarity)
    row_means = _offdiag_row_means(s, _same)
    bad = np.flatnonzero(row_means <= 0)
    if bad.size:
        raise DiversityInputError(
            f"Eq. 1 is undefined: task(s) {bad.tolist()} have mean similarity <= 0 to the others "
            f"(min {row_means.min():.4f}); the log of a non-positive number has no value"
        )
    return float(-np.mean(np.log(row_means)))


def vendi_score(similarity: np.ndarray) -> float:
    """Vendi score (Friedman & Dieng 2023): exp of the Shannon entropy of the eigenvalues of S/N."""
    s = _check_square(similarity)
    lam = np.linalg.eigvalsh((s + s.T) / 2 / len(s))
    lam = lam[lam > 1e-12]  # clipped: tiny negative eigenvalues are round-off of a PSD kernel
    lam = lam / lam.sum()
    return float(np.exp(-np.sum(lam * np.log(lam))))


def mean_pairwise_cosine_distance(similarity: np.ndarray, *, _same: np.ndarray | None = None) -> float:
    """Mean of 1 - S_ij over ordered pairs i != j."""
    s = _check_square(similarity)
    return float(np.mean(1.0 - _offdiag_row_means(s, _same)))


_TOKEN = re.compile(r"\w+|[^\w\s]")


def tokenize(text: str) -> list[str]:
    return _TOKEN.findall(text.lower())


def _ngrams(tokens: Sequence[str], n: int) -> Counter:
    return Counter(tuple(tokens[i : i + n]) for i in range(len(tokens) - n + 1))


def bleu(hypothesis: Sequence[str], references: Sequence[Sequence[str]], max_n: int = 4) -> float:
    """Sentence BLEU with uniform weights over orders 1..min(max_n, len(hyp)), clipped counts against the
    maximum count in any reference, brevity penalty against the closest reference length, and Chen & Cherry's
    smoothing 1 (a zero match count becomes 0.1) so one missing 4-gram does not zero the score."""
    if not references:
        raise DiversityInputError("BLEU needs at least one reference")
    if not hypothesis:
        return 0.0
    orders = range(1, min(max_n, len(hypothesis)) + 1)
    log_p = 0.0
    for n in orders:
        hyp = _ngrams(hypothesis, n)
        max_ref: Counter = Counter()
        for ref in references:
            for gram, c in _ngrams(ref, n).items():
                if c > max_ref[gram]:
                    max_ref[gram] = c
        matches = sum(min(c, max_ref[g]) for g, c in hyp.items())
        total = sum(hyp.values())
        log_p += math.log((matches if matches > 0 else 0.1) / total)
    log_p /= len(orders)
    hyp_len = len(hypothesis)
    ref_len = min((abs(len(r) - hyp_len), len(r)) for r in references)[1]
    bp = 1.0 if hyp_len > ref_len else math.exp(1 - ref_len / hyp_len)
    return float(bp * math.exp(log_p))


def self_bleu_per_text(texts: Sequence[str], max_n: int = 4) -> np.ndarray:
    """(N,) BLEU of each text against all the others. A text is never among its own references; exact
    duplicates elsewhere in the list are (they are other tasks that happen to share the words)."""
    if len(texts) < 2:
        raise DiversityInputError(f"Self-BLEU needs at least 2 texts, got {len(texts)}")
    tokens = [tokenize(t) for t in texts]
    return np.array([bleu(tokens[i], tokens[:i] + tokens[i + 1 :], max_n) for i in range(len(tokens))])


def bootstrap_ci(
    statistic: Callable[[np.ndarray], float],
    n_items: int,
    *,
    n_boot: int = 1000,
    seed: int = 0,
    level: float = 0.95,
) -> tuple[float, float]:
    """Percentile bootstrap over items: `statistic(indices)` is evaluated on `n_boot` resamples with replacement."""
    rng = np.random.default_rng(seed)
    values = np.array([statistic(rng.integers(0, n_items, n_items)) for _ in range(n_boot)])
    alpha = (1 - level) / 2
    return float(np.quantile(values, alpha)), float(np.quantile(values, 1 - alpha))


def subsample_mean_std(
    statistic: Callable[[np.ndarray], float], n_items: int, size: int, *, repeats: int = 50, seed: int = 0
) -> tuple[float, float]:
    """Mean and std of `statistic` over `repeats` random subsets of `size` items (without replacement)."""
    if not 2 <= size <= n_items:
        raise DiversityInputError(f"subsample size must be in [2, {n_items}], got {size}")
    rng = np.random.default_rng(seed)
    if size == n_items:
        repeats = 1  # every subset is the whole set
    values = np.array([statistic(np.sort(rng.choice(n_items, size, replace=False))) for _ in range(repeats)])
    return float(values.mean()), float(values.std())


def _resampled(similarity: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # Copies of one task drawn twice by the bootstrap are the same task, not two identical ones: they are
    # masked like the diagonal, else resampling alone would inflate similarity and bias Eq. 1 downwards.
    return similarity[np.ix_(idx, idx)], idx[:, None] == idx[None, :]


def diversity_summary(
    embeddings: np.ndarray,
    texts: Sequence[str],
    *,
    n_boot: int = 1000,
    subsample_n: int | None = None,
    subsample_repeats: int = 50,
    seed: int = 0,
) -> dict:
    """All text-diversity metrics of one task group, each with a bootstrap 95% CI over tasks.

    Returns {"n", "div", "div_ci", "vendi", "vendi_ci", "cos_dist", "cos_dist_ci", "self_bleu", "self_bleu_ci"}
    and, when `subsample_n` is given, "subsample" = {"n", "repeats", "<metric>_mean", "<metric>_std"}.
    """
    for i, t in enumerate(texts):
        if not isinstance(t, str) or not t.strip():
            raise DiversityInputError(f"text {i} is not a non-empty string: {t!r}")
    s = cosine_similarity_matrix(embeddings)
    if len(s) != len(texts):
        raise DiversityInputError(f"{len(s)} embeddings for {len(texts)} texts")
    n = len(texts)
    per_text_bleu = self_bleu_per_text(texts)

    def on(idx: np.ndarray, fn) -> float:
        sub, same = _resampled(s, idx)
        return fn(sub, _same=same)

    stats: dict[str, Callable[[np.ndarray], float]] = {
        "div": lambda idx: on(idx, eq1_diversity),
        "vendi": lambda idx: vendi_score(s[np.ix_(idx, idx)]),
        "cos_dist": lambda idx: on(idx, mean_pairwise_cosine_distance),
        # Per-text Self-BLEU is computed once against the full set; the CI resamples those per-text scores.
        "self_bleu": lambda idx: float(per_text_bleu[idx].mean()),
    }
    out: dict = {"n": n}
    everything = np.arange(n)
    for offset, (name, fn) in enumerate(stats.items()):
        out[name] = fn(everything) if name != "div" else eq1_diversity(s)
        try:
            out[f"{name}_ci"] = list(bootstrap_ci(fn, n, n_boot=n_boot, seed=seed + offset))
        except DiversityInputError:
            out[f"{name}_ci"] = None  # a resample can hit an undefined value; the point estimate still stands
    if subsample_n is not None:
        # Self-BLEU grows with the number of references, so within a subsample it is recomputed on the subset.
        stats["self_bleu"] = lambda idx: float(self_bleu_per_text([texts[i] for i in idx]).mean())
        sub = {"n": int(subsample_n), "repeats": int(subsample_repeats if subsample_n < n else 1)}
        for offset, (name, fn) in enumerate(stats.items()):
            mean, std = subsample_mean_std(fn, n, subsample_n, repeats=subsample_repeats, seed=seed + 100 + offset)
            sub[f"{name}_mean"], sub[f"{name}_std"] = mean, std
        out["subsample"] = sub
    return out
