"""Text-diversity metrics on cases computable by hand, their errors, and their intervals."""

import math

import numpy as np
import pytest

from simeval.metrics.bootstrap import bootstrap_ci
from simeval.metrics.text_diversity import (
    DiversityInputError,
    bleu,
    cosine_similarity_matrix,
    diversity_summary,
    eq1_diversity,
    mean_pairwise_cosine_distance,
    self_bleu_per_text,
    subsample_mean_std,
    tokenize,
    vendi_score,
)


def test_identical_embeddings_have_zero_diversity():
    s = cosine_similarity_matrix(np.ones((4, 3)))
    assert eq1_diversity(s) == pytest.approx(0.0)
    assert vendi_score(s) == pytest.approx(1.0)
    assert mean_pairwise_cosine_distance(s) == pytest.approx(0.0)


def test_eq1_by_hand_three_vectors():
    # e1.e2 = 0.5, e1.e3 = 0.25, e2.e3 = 0.75 (a symmetric "similarity" we write by hand)
    s = np.array([[1, 0.5, 0.25], [0.5, 1, 0.75], [0.25, 0.75, 1]])
    expected = -(math.log(0.375) + math.log(0.625) + math.log(0.5)) / 3
    assert eq1_diversity(s) == pytest.approx(expected)
    assert mean_pairwise_cosine_distance(s) == pytest.approx(1 - (0.5 + 0.25 + 0.75) / 3)


def test_diagonal_is_ignored():
    s = np.array([[1, 0.5, 0.25], [0.5, 1, 0.75], [0.25, 0.75, 1]])
    t = s.copy()
    np.fill_diagonal(t, 123.0)
    assert eq1_diversity(t) == pytest.approx(eq1_diversity(s))


def test_orthogonal_embeddings_make_eq1_undefined_not_nan():
    s = cosine_similarity_matrix(np.eye(3))
    with pytest.raises(DiversityInputError, match="mean similarity <= 0"):
        eq1_diversity(s)
    assert vendi_score(s) == pytest.approx(3.0)  # three orthogonal tasks: three effective tasks
    assert mean_pairwise_cosine_distance(s) == pytest.approx(1.0)


@pytest.mark.parametrize("n", [0, 1])
def test_fewer_than_two_tasks_is_an_error(n):
    with pytest.raises(DiversityInputError, match="at least 2"):
        eq1_diversity(np.ones((n, n)))


def test_zero_and_nonfinite_embeddings_are_errors():
    with pytest.raises(DiversityInputError, match="all zeros"):
        cosine_similarity_matrix(np.array([[1.0, 0.0], [0.0, 0.0]]))
    with pytest.raises(DiversityInputError, match="NaN"):
        cosine_similarity_matrix(np.array([[1.0, np.nan], [0.0, 1.0]]))


def test_bleu_by_hand():
    # hyp "a b c d" vs ref "a b c e": p1=3/4, p2=2/3, p3=1/2, p4=0 -> smoothed 0.1/1; equal lengths: BP=1
    expected = (0.75 * (2 / 3) * 0.5 * 0.1) ** 0.25
    assert bleu(tokenize("a b c d"), [tokenize("a b c e")]) == pytest.approx(expected)
    assert bleu(tokenize("the cat sat on the mat"), [tokenize("The cat sat on the mat")]) == pytest.approx(1.0)


def test_bleu_brevity_penalty_and_clipping():
    # "the the the" vs "the cat": unigram clipped to 1/3; bigram "the the" unmatched -> 0.1/2; len 3 > 2: BP=1
    expected = ((1 / 3) * (0.1 / 2) * (0.1 / 1)) ** (1 / 3)
    assert bleu(tokenize("the the the"), [tokenize("the cat")]) == pytest.approx(expected)
    short = bleu(tokenize("a b"), [tokenize("a b c d")])
    assert short == pytest.approx(math.exp(1 - 4 / 2))  # all n-grams match; only the brevity penalty remains


def test_self_bleu_never_uses_the_hypothesis_as_its_own_reference():
    texts = ["stack the red block", "push the pile into the zone", "open the drawer"]
    scores = self_bleu_per_text(texts)
    assert np.all(scores < 1.0)  # each text would score 1.0 against itself
    assert self_bleu_per_text(["same words here"] * 3) == pytest.approx(np.ones(3))  # other copies are references
    mixed = self_bleu_per_text(["open the drawer", "open the drawer", "sweep the pile"])
    assert mixed[0] == pytest.approx(1.0) and mixed[2] < 0.5


def test_bootstrap_and_subsample():
    rng = np.random.default_rng(0)
    emb = rng.normal(size=(30, 16)) + 2.0
    texts = [f"task {i} moves block {i % 5}" for i in range(30)]
    out = diversity_summary(emb, texts, n_boot=200, subsample_n=10, subsample_repeats=20, seed=1)
    for name in ("div", "vendi", "cos_dist", "self_bleu"):
        lo, hi = out[f"{name}_ci"]
        assert lo <= out[name] <= hi, name
    assert out["n"] == 30 and out["subsample"]["n"] == 10
    again = diversity_summary(emb, texts, n_boot=200, subsample_n=10, subsample_repeats=20, seed=1)
    assert again == out  # deterministic per seed
    full = diversity_summary(emb, texts, n_boot=50, subsample_n=30, seed=1)["subsample"]
    assert full["div_mean"] == pytest.approx(out["div"]) and full["div_std"] == 0.0 and full["repeats"] == 1


def test_bootstrap_ci_of_a_constant_statistic_is_a_point():
    assert bootstrap_ci(lambda idx: 3.0, 10, n_boot=50) == [3.0, 3.0]
    with pytest.raises(DiversityInputError, match="subsample size"):
        subsample_mean_std(lambda idx: 0.0, 5, 6)


def test_non_text_entries_are_rejected():
    with pytest.raises(DiversityInputError, match="text 1"):
        diversity_summary(np.ones((2, 3)), ["ok", 7])
