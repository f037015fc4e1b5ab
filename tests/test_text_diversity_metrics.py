"""Text-diversity metrics on cases computable by hand, their errors, and their intervals."""

import math

import numpy as np
import pytest

from simeval.measures.text_diversity.run import text_diversity_by_group
from simeval.errors import UserError
from simeval.stats.bootstrap import jackknife_interval, jackknife_se
from simeval.measures.text_diversity.metric import (
    DiversityInputError,
    bleu,
    cosine_similarity_matrix,
    diversity_summary,
    eq1_diversity,
    mean_pairwise_cosine_distance,
    self_bleu_leave_one_out,
    self_bleu_per_text,
    subsample_mean_std,
    tokenize,
    vendi_leave_one_out,
    vendi_score,
)
from simeval.pipelines.task_texts import TaskText


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


def test_jackknife_of_a_mean_is_the_textbook_standard_error():
    # leave-one-out means of x: (sum - x_i)/(n-1); the jackknife se of a mean is exactly s / sqrt(n)
    x = np.array([2.0, 4.0, 4.0, 5.0, 9.0])
    loo = (x.sum() - x) / (len(x) - 1)
    assert jackknife_se(loo) == pytest.approx(x.std(ddof=1) / math.sqrt(len(x)))
    lo, hi = jackknife_interval(x.mean(), loo)
    assert (lo + hi) / 2 == pytest.approx(x.mean()) and hi - lo == pytest.approx(2 * 1.959964 * jackknife_se(loo))
    assert jackknife_interval(0.5, loo / 10, bounds=(0.0, 1.0))[0] >= 0.0
    with pytest.raises(DiversityInputError, match="subsample size"):
        subsample_mean_std(lambda idx: 0.0, 5, 6)


def test_leave_one_out_values_by_hand():
    # three orthogonal tasks: any two left are orthogonal, Vendi 2; plus a copy of task 0: leaving a copy out
    # gives 3 distinct tasks (Vendi 3), leaving task 1 out gives {0, 0, 2} with eigenvalues 2/3, 1/3
    s = cosine_similarity_matrix(np.eye(3))
    assert vendi_leave_one_out(s) == pytest.approx([2.0, 2.0, 2.0])
    s = cosine_similarity_matrix(np.array([[1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]))
    two_one = math.exp(-(2 / 3 * math.log(2 / 3) + 1 / 3 * math.log(1 / 3)))
    assert vendi_leave_one_out(s) == pytest.approx([3.0, 3.0, two_one, two_one])
    texts = ["open the drawer", "open the drawer", "sweep the pile"]
    # without text 0 or 1: {"open the drawer", "sweep the pile"}; without text 2: the two copies score 1.0 each
    others = self_bleu_per_text(["open the drawer", "sweep the pile"]).mean()
    assert self_bleu_leave_one_out(texts) == pytest.approx([others, others, 1.0])


def _embeddings(regime: str, rng: np.random.Generator, n: int, dim: int = 16) -> np.ndarray:
    """Three kinds of task sets: independent tasks, four clusters, and draws from 8 tasks (many exact copies)."""
    if regime == "random":
        return rng.normal(size=(n, dim)) + 1.0
    if regime == "clustered":
        centres = np.random.default_rng(123).normal(size=(4, dim)) + 1.0
        return centres[rng.integers(0, 4, n)] + rng.normal(scale=0.7, size=(n, dim))
    pool = np.random.default_rng(7).normal(size=(8, dim)) + 1.0
    return pool[rng.integers(0, 8, n)]


_WORDS = [f"w{i}" for i in range(40)]
_COLOURS, _OBJECTS = ["red", "blue", "green", "yellow", "purple"], ["block", "bowl", "cube", "cylinder"]
_TEMPLATES = ["stack the {} {} on the {} {}", "put the {} {} into the {} {} in the corner",
              "push the pile of {} {} into the {} {} zone", "open the drawer and place the {} {} beside the {} {}"]
_POOL = ["stack the red block on the blue block", "open the drawer", "push the pile into the zone",
         "place the green cube in the bowl", "sweep the blue cylinders to the left", "build a tower of three blocks",
         "put the yellow bowl on the red block", "close the top drawer slowly"]


def _texts(regime: str, rng: np.random.Generator, n: int) -> list[str]:
    if regime == "random":
        return [" ".join(rng.choice(_WORDS, rng.integers(3, 11))) for _ in range(n)]
    if regime == "clustered":
        return [_TEMPLATES[rng.integers(4)].format(rng.choice(_COLOURS), rng.choice(_OBJECTS), rng.choice(_COLOURS),
                                                   rng.choice(_OBJECTS)) for _ in range(n)]
    return [_POOL[i] for i in rng.integers(0, 8, n)]


@pytest.mark.parametrize("regime", ["random", "clustered", "duplicates"])
def test_every_interval_contains_its_estimate(regime):
    """Version 1.0's bootstrap Vendi interval lay below its own estimate (Table 3: 4.86 [3.84, 4.79])."""
    for seed in range(4):
        rng = np.random.default_rng(seed)
        out = diversity_summary(_embeddings(regime, rng, 30), _texts(regime, rng, 30), n_boot=200, seed=seed)
        for name in ("div", "vendi", "cos_dist", "self_bleu"):
            lo, hi = out[f"{name}_ci"]
            assert lo <= out[name] <= hi, (regime, seed, name, out[name], out[f"{name}_ci"])
        assert 1.0 <= out["vendi_ci"][0] and out["vendi_ci"][1] <= 30 and 0 <= out["self_bleu_ci"][0]
        assert out["ci_method"] == {"div": "bootstrap", "vendi": "jackknife", "cos_dist": "bootstrap",
                                    "self_bleu": "jackknife"}


def _coverage(statistic, leave_one_out, draw, bounds, n, replicates, truth_sets=1000, seed=0):
    """Share of `replicates` task sets of size n whose interval holds E[statistic at n] (from `truth_sets` more),
    and the mean interval width over the width of the statistic's own central 95% across sets."""
    rng = np.random.default_rng(seed)
    truth_draws = np.array([statistic(draw(rng, n)) for _ in range(truth_sets)])
    truth = truth_draws.mean()
    hits, widths = 0, []
    for _ in range(replicates):
        x = draw(rng, n)
        lo, hi = jackknife_interval(statistic(x), leave_one_out(x), bounds=bounds)
        hits += lo <= truth <= hi
        widths.append(hi - lo)
    spread = np.subtract(*np.quantile(truth_draws, [0.975, 0.025]))
    return hits / replicates, float(np.mean(widths) / spread)


# Nominal 95%. With 100 (60) replicate sets the binomial sd of a 0.95 coverage is 0.022 (0.028): the floor sits
# about 3 sd below nominal. Version 1.0's bootstrap covered E[Vendi] in 16-84% of sets (n = 12-30) and E[Self-BLEU]
# in 49% of the duplicate-heavy sets (its per-text resampling held every reference set fixed). The width bound
# keeps the interval informative: no wider than twice the true sampling spread.
@pytest.mark.parametrize("regime", ["random", "clustered", "duplicates"])
def test_vendi_jackknife_covers_the_expected_vendi(regime):
    coverage, width = _coverage(lambda e: vendi_score(cosine_similarity_matrix(e)),
                                lambda e: vendi_leave_one_out(cosine_similarity_matrix(e)),
                                lambda rng, n: _embeddings(regime, rng, n), (1.0, 30.0), n=30, replicates=100)
    assert coverage >= 0.88, coverage
    assert 0.5 <= width <= 2.0, width


@pytest.mark.parametrize("regime", ["random", "clustered", "duplicates"])
def test_self_bleu_jackknife_covers_the_expected_self_bleu(regime):
    coverage, width = _coverage(lambda t: self_bleu_per_text(t).mean(), self_bleu_leave_one_out,
                                lambda rng, n: _texts(regime, rng, n), (0.0, 1.0), n=20, replicates=60, truth_sets=400)
    assert coverage >= 0.85, coverage
    assert 0.5 <= width <= 2.0, width


def _tasks(n_per_group: dict[str, int]) -> list[TaskText]:
    return [TaskText("p", g, f"{g}{i}", f"move block {i} of {g}", f"move block {i} of {g}")
            for g, k in n_per_group.items() for i in range(k)]


def _encode(texts: list[str]) -> np.ndarray:
    return np.abs(np.random.default_rng(len(texts)).normal(size=(len(texts), 8))) + 0.1


@pytest.mark.parametrize("setting,value,message", [
    ("n_boot", 0, "metrics.n_boot must be an integer >= 10"),
    ("n_boot", -5, "metrics.n_boot must be an integer >= 10"),
    ("n_boot", 3, "metrics.n_boot must be an integer >= 10"),
    ("n_boot", "many", "metrics.n_boot must be an integer >= 10"),
    ("subsample_n", 1, "metrics.subsample_n must be auto, null, or an integer >= 2"),
    ("subsample_n", -3, "metrics.subsample_n must be auto, null, or an integer >= 2"),
    ("subsample_n", "half", "metrics.subsample_n must be auto, null, or an integer >= 2"),
    ("subsample_n", 50, r"metrics.subsample_n=50 is larger than every task group here \(largest: 9 tasks\)"),
    ("subsample_repeats", 0, "metrics.subsample_repeats must be an integer >= 1"),
])
def test_nonsense_metric_settings_are_user_errors_naming_the_key(setting, value, message):
    with pytest.raises(UserError, match=message):
        text_diversity_by_group(_tasks({"a": 4, "b": 5}), _encode, **{setting: value})
    with pytest.raises(UserError):
        text_diversity_by_group(_tasks({"a": 4, "b": 5}), _encode, task_group="a", **{setting: value})


def test_sensible_metric_settings_still_run():
    out = text_diversity_by_group(_tasks({"a": 4, "b": 5}), _encode, n_boot=10, subsample_n=5, subsample_repeats=1)
    assert set(out) == {"a", "b", "all"} and "subsample" not in out["a"] and out["b"]["subsample"]["n"] == 5


def test_non_text_entries_are_rejected():
    with pytest.raises(DiversityInputError, match="text 1"):
        diversity_summary(np.ones((2, 3)), ["ok", 7])
