"""Text diversity of a set of task descriptions.

Eq. 1 of the paper (after Texygen's embedding similarity), for unit-normalised embeddings e_1..e_N:

    div = -1/N * sum_i log( 1/(N-1) * sum_{j != i} e_i . e_j )

Higher means less similar, i.e. more diverse. Also here, each a pure function of a similarity matrix or texts:

    vendi      = exp( -sum_k lam_k log lam_k ),  lam = eigenvalues of S / N          (effective number of tasks)
    cos_dist   = 1/(N(N-1)) * sum_{i != j} (1 - S_ij)                                  (mean pairwise distance)
    self_bleu  = 1/N * sum_i BLEU-4(text_i ; references = every text but i)           (lower = more diverse)

BLEU-4 here is NLTK's sentence_bleu with SmoothingFunction().method1 (a zero match count becomes 0.1), closest
reference length for the brevity penalty, except for texts of k < 4 tokens: those average only the k orders they
have (NLTK with weights (1/k,)*k), where NLTK's default weights count each missing order as a smoothed 0.1: "open
the drawer" against an identical reference scores 1.0 here and 0.1^(1/4) = 0.56 in NLTK (tests/test_reference_
crosschecks.py checks both). Texts of 4 or more tokens score exactly as in NLTK.

Shapes: `embeddings` (N, D) float; `similarity` (N, N) float, symmetric, diagonal ignored; `texts` list of N str.
Returns plain floats; `diversity_summary` returns a dict of them with 95% CIs over tasks.

Intervals (`diversity_summary`): div and cos_dist by percentile bootstrap over tasks, a resample's pairs of two
draws of the same task masked like the diagonal. vendi and self_bleu by jackknife (estimate +- 1.96 se_jack from
the N leave-one-out values; simeval.stats.bootstrap): both depend on the number of distinct tasks, so a
bootstrap resample (about 63% distinct tasks) is biased. Vendi counts a repeated task once and came out lower in
every resample (1.0 reported GenSim Stacking 4.86 [3.84, 4.79]); resampling Self-BLEU by recomputing would make a
repeated text its own reference (BLEU 1), and resampling the per-text scores instead (version 1.0) held every
text's reference set fixed, leaving out the variability from each text's role as a reference. The jackknife
interval contains the estimate and covers E[statistic at this N] near 95% in simulation (random, clustered and
heavily duplicated embeddings; tests/test_text_diversity_metrics.py).

Errors (never a NaN): N < 2, a row whose mean off-diagonal similarity is <= 0 (log undefined), non-finite input,
n_boot < 10, subsample sizes outside [2, N].
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Callable, Sequence

import numpy as np

from simeval.stats.bootstrap import jackknife_interval, percentile_interval
from simeval.errors import UserError

# 1.1: Vendi and Self-BLEU intervals by jackknife (1.0's bootstrap intervals for them were biased low and could
# exclude the estimate); every point estimate and the div / cos_dist intervals are unchanged.
METRIC_VERSION = "1.1"
STATISTICS = ("div", "vendi", "cos_dist", "self_bleu")
CI_METHOD = {"div": "bootstrap", "vendi": "jackknife", "cos_dist": "bootstrap", "self_bleu": "jackknife"}


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


def _bleu_against_others(grams: Sequence[list[Counter]], lengths: Sequence[int], max_n: int,
                         members: Sequence[int]) -> list[float]:
    """BLEU of text i against every other text of `members`, for each i in `members` (grams and lengths are
    per text, from `_all_ngrams`).

    Clipping needs, per n-gram, the largest count in any reference; keeping the two largest counts over the
    members (with their owners) gives that maximum "excluding i" in O(1), so the whole set costs O(total n-grams)
    instead of O(N^2)."""
    members = list(members)
    top2: list[dict] = [{} for _ in range(max_n)]  # gram -> [(count, owner), (count, owner)]
    for owner in members:
        for n, counter in enumerate(grams[owner]):
            table = top2[n]
            for gram, c in counter.items():
                e = table.get(gram)
                if e is None:
                    table[gram] = [(c, owner), (0, -1)]
                elif c > e[0][0]:
                    table[gram] = [(c, owner), e[0]]
                elif c > e[1][0]:
                    e[1] = (c, owner)
    member_lengths = np.array([lengths[j] for j in members])
    length_scale = int(member_lengths.max()) + 1
    scores = []
    for pos, i in enumerate(members):
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
        # closest reference length, the shorter one on a tie (as NLTK); the hypothesis itself is not a reference
        key = np.abs(member_lengths - hyp_len) * length_scale + member_lengths
        key[pos] = np.iinfo(key.dtype).max
        ref_len = int(member_lengths[np.argmin(key)])
        bp = 1.0 if hyp_len > ref_len else math.exp(1 - ref_len / hyp_len)
        scores.append(float(bp * math.exp(log_p)))
    return scores


def bleu(hypothesis: Sequence[str], references: Sequence[Sequence[str]], max_n: int = 4) -> float:
    """Sentence BLEU with uniform weights over orders 1..min(max_n, len(hyp)), clipped counts against the
    maximum count in any reference, brevity penalty against the closest reference length, and Chen & Cherry's
    smoothing 1 (a zero match count becomes 0.1) so one missing 4-gram does not zero the score."""
    if not references:
        raise DiversityInputError("BLEU needs at least one reference")
    tokens = [list(hypothesis)] + [list(r) for r in references]
    return _bleu_against_others([_all_ngrams(t, max_n) for t in tokens], [len(t) for t in tokens], max_n,
                                range(len(tokens)))[0]


def self_bleu_per_text(texts: Sequence[str], max_n: int = 4) -> np.ndarray:
    """(N,) BLEU of each text against all the others. A text is never among its own references; exact
    duplicates elsewhere in the list are (they are other tasks that happen to share the words)."""
    if len(texts) < 2:
        raise DiversityInputError(f"Self-BLEU needs at least 2 texts, got {len(texts)}")
    tokens = [tokenize(t) for t in texts]
    grams = [_all_ngrams(t, max_n) for t in tokens]
    return np.array(_bleu_against_others(grams, [len(t) for t in tokens], max_n, range(len(tokens))))


def self_bleu_leave_one_out(texts: Sequence[str], max_n: int = 4) -> np.ndarray:
    """(N,) Self-BLEU of the N - 1 texts left when text i is removed (each scored against the other N - 2),
    for the jackknife interval. Needs N >= 3."""
    if len(texts) < 3:
        raise DiversityInputError(f"leave-one-out Self-BLEU needs at least 3 texts, got {len(texts)}")
    tokens = [tokenize(t) for t in texts]
    grams, lengths = [_all_ngrams(t, max_n) for t in tokens], [len(t) for t in tokens]
    everyone = range(len(texts))
    return np.array([np.mean(_bleu_against_others(grams, lengths, max_n, [j for j in everyone if j != i]))
                     for i in everyone])


def vendi_leave_one_out(similarity: np.ndarray, max_elements: int = 20_000_000) -> np.ndarray:
    """(N,) Vendi score of the N - 1 tasks left when task i is removed, for the jackknife interval. N >= 3."""
    s = _check_square(similarity)
    n = len(s)
    if n < 3:
        raise DiversityInputError(f"leave-one-out Vendi needs at least 3 tasks, got {n}")
    s = (s + s.T) / 2
    keep = np.array([np.delete(np.arange(n), i) for i in range(n)])  # (N, N-1)
    out = []
    for lo in range(0, n, max(1, max_elements // (n * n))):
        ix = keep[lo : lo + max(1, max_elements // (n * n))]
        lam = np.linalg.eigvalsh(s[ix[:, :, None], ix[:, None, :]] / (n - 1))
        lam = np.where(lam > 1e-12, lam, 0.0)  # as vendi_score: round-off of a PSD kernel is dropped
        lam = lam / lam.sum(-1, keepdims=True)
        out.append(np.exp(-np.sum(lam * np.log(np.where(lam > 0, lam, 1.0)), -1)))
    return np.concatenate(out)


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


def _bootstrap_draws(similarity: np.ndarray, n_boot: int, seed: int,
                     max_elements: int = 20_000_000) -> dict[str, np.ndarray]:
    """Eq. 1 and the mean pairwise distance on `n_boot` resamples of the tasks (with replacement), vectorised.

    Two draws of the same task are one task, not two identical ones: such pairs are masked like the diagonal,
    else resampling alone would inflate similarity and bias Eq. 1 downwards. A resample in which some task has
    no distinct partner, or Eq. 1 is undefined, is dropped (counted in the returned "dropped"). The resample
    indices are the ones version 1.0 drew, so these two intervals are unchanged."""
    n = len(similarity)
    idx = np.random.default_rng(seed).integers(0, n, (n_boot, n))
    chunk = max(1, max_elements // (n * n))
    parts: dict[str, list] = {"div": [], "cos_dist": []}
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
    out = {k: np.concatenate(v) for k, v in parts.items()}
    out["dropped"] = np.array(dropped)
    return out


def _check_int(name: str, value, low: int, high: int | None = None, why: str = "") -> int:
    """`value` as an int in [low, high], else a UserError naming the key (`name`) and the valid range."""
    ok = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if ok and value >= low and (high is None or value <= high):
        return int(value)
    valid = f"an integer >= {low}" if high is None else f"an integer in [{low}, {high}]"
    raise DiversityInputError(f"{name} must be {valid}{why}, got {value!r}")


def diversity_summary(
    embeddings: np.ndarray,
    texts: Sequence[str],
    *,
    n_boot: int = 1000,
    subsample_n: int | None = None,
    subsample_repeats: int = 50,
    seed: int = 0,
) -> dict:
    """All text-diversity metrics of one task group, each with a 95% CI over tasks.

    Returns {"n", "div", "div_ci", "vendi", "vendi_ci", "cos_dist", "cos_dist_ci", "self_bleu", "self_bleu_ci",
    "ci_method": {metric: "bootstrap" | "jackknife"}, "boot": {"n_boot", "dropped"}} and, when `subsample_n` is
    given, "subsample" = {"n", "repeats", "<metric>_mean", "<metric>_std"}. A CI is None when too few resamples
    are defined (tiny groups) or, for the jackknife ones, when N < 3.

    div and cos_dist: percentile bootstrap (`n_boot` resamples, duplicate pairs masked). vendi and self_bleu:
    jackknife (see simeval.stats.bootstrap), because both depend on how many distinct tasks there are and a
    resample with repeated tasks is biased (Vendi: always lower; Self-BLEU: a repeated text scores BLEU 1 against
    its own copy).
    """
    n_boot = _check_int("n_boot", n_boot, 10, why=" (bootstrap resamples; fewer than 10 can give no interval)")
    subsample_repeats = _check_int("subsample_repeats", subsample_repeats, 1)
    for i, t in enumerate(texts):
        if not isinstance(t, str) or not t.strip():
            raise DiversityInputError(f"text {i} is not a non-empty string: {t!r}")
    s = cosine_similarity_matrix(embeddings)
    if len(s) != len(texts):
        raise DiversityInputError(f"{len(s)} embeddings for {len(texts)} texts")
    n = len(texts)
    if subsample_n is not None:
        subsample_n = _check_int("subsample_n", subsample_n, 2, max(n, 2), why=f" (this group has {n} tasks)")
    per_text_bleu = self_bleu_per_text(texts)
    out: dict = {
        "n": n,
        "div": eq1_diversity(s),
        "vendi": vendi_score(s),
        "cos_dist": mean_pairwise_cosine_distance(s),
        "self_bleu": float(per_text_bleu.mean()),
    }
    draws = _bootstrap_draws(s, n_boot, seed)
    for name in ("div", "cos_dist"):
        out[f"{name}_ci"] = percentile_interval(draws[name])
    # clipped to the range each statistic can take (Vendi of N tasks: [1, N]; BLEU: [0, 1])
    out["vendi_ci"] = jackknife_interval(out["vendi"], vendi_leave_one_out(s), bounds=(1.0, n)) if n >= 3 else None
    out["self_bleu_ci"] = (jackknife_interval(out["self_bleu"], self_bleu_leave_one_out(texts), bounds=(0.0, 1.0))
                           if n >= 3 else None)
    out["ci_method"] = dict(CI_METHOD)
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
