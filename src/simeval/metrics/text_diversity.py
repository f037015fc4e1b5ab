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

from simeval.metrics.bootstrap import percentile_interval
from simeval.errors import UserError

METRIC_VERSION = "1.0"
STATISTICS = ("div", "vendi", "cos_dist", "self_bleu")


class DiversityInputError(UserError):
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


def _offdiag_row_means(s: np.ndarray) -> np.ndarray:
    """Mean of each row over j != i."""
    return (s.sum(axis=1) - np.diag(s)) / (len(s) - 1)


def eq1_diversity(similarity: np.ndarray) -> float:
    """The paper's Eq. 1 on a (N, N) similarity matrix (diagonal removed)."""
    s = _check_square(similarity)
    row_means = _offdiag_row_means(s)
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


def mean_pairwise_cosine_distance(similarity: np.ndarray) -> float:
    """Mean of 1 - S_ij over ordered pairs i != j."""
    s = _check_square(similarity)
    return float(np.mean(1.0 - _offdiag_row_means(s)))


_TOKEN = re.compile(r"\w+|[^\w\s]")


def tokenize(text: str) -> list[str]:
    return _TOKEN.findall(text.lower())


def _ngrams(tokens: Sequence[str], n: int) -> Counter:
    return Counter(tuple(tokens[i : i + n]) for i in range(len(tokens) - n + 1))


def _all_ngrams(tokens: Sequence[str], max_n: int) -> list[Counter]:
    return [_ngrams(tokens, n) for n in range(1, min(max_n, len(tokens)) + 1)]


def _bleu_against_others(tokens: Sequence[Sequence[str]], max_n: int, items: Sequence[int]) -> list[float]:
    """BLEU of tokens[i] against every other entry of `tokens`, for each i in `items`.

    Clipping needs, per n-gram, the largest count in any reference; keeping the two largest counts over all
    texts (with their owners) gives that maximum "excluding i" in O(1), so the whole set costs O(total n-grams)
    instead of O(N^2)."""
    grams = [_all_ngrams(t, max_n) for t in tokens]
    lengths = [len(t) for t in tokens]
    top2: list[dict] = [{} for _ in range(max_n)]  # gram -> [(count, owner), (count, owner)]
    for owner, per_order in enumerate(grams):
        for n, counter in enumerate(per_order):
            table = top2[n]
            for gram, c in counter.items():
                e = table.get(gram)
                if e is None:
                    table[gram] = [(c, owner), (0, -1)]
                elif c > e[0][0]:
                    table[gram] = [(c, owner), e[0]]
                elif c > e[1][0]:
                    e[1] = (c, owner)
    scores = []
    for i in items:
        hyp_len = lengths[i]
        if hyp_len == 0:
            scores.append(0.0)
            continue
        log_p = 0.0
        for n, counter in enumerate(grams[i]):
            table, matches = top2[n], 0
            for gram, c in counter.items():
                (c1, o1), (c2, _) = table[gram]
                matches += min(c, c1 if o1 != i else c2)
            log_p += math.log((matches if matches > 0 else 0.1) / sum(counter.values()))
        log_p /= len(grams[i])
        ref_len = min((abs(r - hyp_len), r) for j, r in enumerate(lengths) if j != i)[1]
        bp = 1.0 if hyp_len > ref_len else math.exp(1 - ref_len / hyp_len)
        scores.append(float(bp * math.exp(log_p)))
    return scores


def bleu(hypothesis: Sequence[str], references: Sequence[Sequence[str]], max_n: int = 4) -> float:
    """Sentence BLEU with uniform weights over orders 1..min(max_n, len(hyp)), clipped counts against the
    maximum count in any reference, brevity penalty against the closest reference length, and Chen & Cherry's
    smoothing 1 (a zero match count becomes 0.1) so one missing 4-gram does not zero the score."""
    if not references:
        raise DiversityInputError("BLEU needs at least one reference")
    return _bleu_against_others([list(hypothesis)] + [list(r) for r in references], max_n, [0])[0]


def self_bleu_per_text(texts: Sequence[str], max_n: int = 4) -> np.ndarray:
    """(N,) BLEU of each text against all the others. A text is never among its own references; exact
    duplicates elsewhere in the list are (they are other tasks that happen to share the words)."""
    if len(texts) < 2:
        raise DiversityInputError(f"Self-BLEU needs at least 2 texts, got {len(texts)}")
    tokens = [tokenize(t) for t in texts]
    return np.array(_bleu_against_others(tokens, max_n, range(len(tokens))))


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


def _bootstrap_draws(similarity: np.ndarray, per_text_bleu: np.ndarray, n_boot: int, seed: int,
                     max_elements: int = 20_000_000) -> dict[str, np.ndarray]:
    """Every statistic on `n_boot` resamples of the tasks (with replacement), vectorised over resamples.

    Two draws of the same task are one task, not two identical ones: such pairs are masked like the diagonal,
    else resampling alone would inflate similarity and bias Eq. 1 downwards. A resample in which some task has
    no distinct partner, or Eq. 1 is undefined, is dropped (counted in the returned "dropped")."""
    n = len(similarity)
    idx = np.random.default_rng(seed).integers(0, n, (n_boot, n))
    chunk = max(1, max_elements // (n * n))
    parts: dict[str, list] = {"div": [], "vendi": [], "cos_dist": [], "self_bleu": []}
    dropped = 0
    for lo in range(0, n_boot, chunk):
        ix = idx[lo : lo + chunk]
        sub = similarity[ix[:, :, None], ix[:, None, :]]
        valid = ix[:, :, None] != ix[:, None, :]
        counts = valid.sum(-1)
        row_means = np.where(valid, sub, 0.0).sum(-1) / np.maximum(counts, 1)
        ok = np.all(counts > 0, axis=1) & np.all(row_means > 0, axis=1)
        dropped += int((~ok).sum())
        parts["div"].append(-np.log(row_means[ok]).mean(1))
        parts["cos_dist"].append((1.0 - row_means[ok]).mean(1))
        lam = np.clip(np.linalg.eigvalsh(sub[ok] / n), 0.0, None)
        lam = lam / lam.sum(-1, keepdims=True)
        log_lam = np.log(np.where(lam > 1e-12, lam, 1.0))  # 0 log 0 = 0, as vendi_score drops those eigenvalues
        parts["vendi"].append(np.exp(-np.sum(lam * log_lam, -1)))
        parts["self_bleu"].append(per_text_bleu[ix[ok]].mean(1))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["dropped"] = np.array(dropped)
    return out


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

    Returns {"n", "div", "div_ci", "vendi", "vendi_ci", "cos_dist", "cos_dist_ci", "self_bleu", "self_bleu_ci",
    "boot": {"n_boot", "dropped"}} and, when `subsample_n` is given, "subsample" = {"n", "repeats",
    "<metric>_mean", "<metric>_std"}. A CI is None when too few resamples are defined (tiny groups).
    """
    for i, t in enumerate(texts):
        if not isinstance(t, str) or not t.strip():
            raise DiversityInputError(f"text {i} is not a non-empty string: {t!r}")
    s = cosine_similarity_matrix(embeddings)
    if len(s) != len(texts):
        raise DiversityInputError(f"{len(s)} embeddings for {len(texts)} texts")
    n = len(texts)
    per_text_bleu = self_bleu_per_text(texts)
    out: dict = {
        "n": n,
        "div": eq1_diversity(s),
        "vendi": vendi_score(s),
        "cos_dist": mean_pairwise_cosine_distance(s),
        # Per-text Self-BLEU is computed once against the full set; the CI resamples those per-text scores.
        "self_bleu": float(per_text_bleu.mean()),
    }
    draws = _bootstrap_draws(s, per_text_bleu, n_boot, seed)
    for name in STATISTICS:
        out[f"{name}_ci"] = percentile_interval(draws[name])
    out["boot"] = {"n_boot": n_boot, "dropped": int(draws["dropped"])}
    if subsample_n is not None:
        stats: dict[str, Callable[[np.ndarray], float]] = {
            "div": lambda idx: eq1_diversity(s[np.ix_(idx, idx)]),
            "vendi": lambda idx: vendi_score(s[np.ix_(idx, idx)]),
            "cos_dist": lambda idx: mean_pairwise_cosine_distance(s[np.ix_(idx, idx)]),
            # Self-BLEU grows with the number of references, so within a subsample it is recomputed on the subset.
            "self_bleu": lambda idx: float(self_bleu_per_text([texts[i] for i in idx]).mean()),
        }
        sub = {"n": int(subsample_n), "repeats": int(subsample_repeats if subsample_n < n else 1)}
        for offset, (name, fn) in enumerate(stats.items()):
            mean, std = subsample_mean_std(fn, n, subsample_n, repeats=subsample_repeats, seed=seed + 100 + offset)
            sub[f"{name}_mean"], sub[f"{name}_std"] = mean, std
        out["subsample"] = sub
    return out
