"""Our metrics against reference implementations (dev-only packages pinned in requirements-dev.txt; each test
skips when its package is missing) and against published values."""

import math
import warnings

import numpy as np
import pytest
from scipy import stats

from simeval.measures.agreement.metric import (
    agreement_summary,
    bootstrap_statistics,
    icc_1_1,
    kendall_tau_b,
    krippendorff_alpha_interval,
    pearson,
    resample_counts,
    spearman,
)
from simeval.measures.text_diversity.metric import cosine_similarity_matrix, self_bleu_per_text, tokenize, vendi_score

# Shrout & Fleiss (1979), Table 2: 6 targets rated by 4 judges. Published: ICC(1,1) = 0.17 (BMS 11.24, WMS 6.26).
SHROUT_FLEISS = np.array([[9, 2, 5, 8], [6, 1, 3, 2], [8, 4, 6, 8], [7, 1, 2, 6], [10, 5, 6, 9], [6, 2, 4, 7.0]])


def test_icc_1_1_reproduces_shrout_fleiss_table_2():
    assert round(icc_1_1(SHROUT_FLEISS), 2) == 0.17
    # by hand: row means 6, 3, 6.5, 4, 7.5, 4.75, grand mean 127/24; within-row squared deviations sum to 112.75
    msb = 4 * sum((r - 127 / 24) ** 2 for r in (6, 3, 6.5, 4, 7.5, 4.75)) / 5
    msw = 112.75 / (6 * 3)
    assert (round(msb, 2), round(msw, 2)) == (11.24, 6.26)  # the paper's BMS and WMS
    assert icc_1_1(SHROUT_FLEISS) == pytest.approx((msb - msw) / (msb + 3 * msw), abs=1e-12)


def _ratings(rng, items, repeats, missing):
    truth = rng.normal(size=(items, 1)) * 2
    x = np.round(truth + rng.normal(size=(items, repeats)), 1)
    x[rng.random(x.shape) < missing] = np.nan
    return x


@pytest.mark.parametrize("seed,items,repeats,missing", [(0, 20, 3, 0.0), (1, 30, 5, 0.2), (2, 8, 2, 0.3),
                                                         (3, 50, 4, 0.5)])
def test_krippendorff_alpha_matches_the_krippendorff_package(seed, items, repeats, missing):
    krippendorff = pytest.importorskip("krippendorff")
    x = _ratings(np.random.default_rng(seed), items, repeats, missing)
    ours = krippendorff_alpha_interval(x)
    ref = krippendorff.alpha(reliability_data=x.T, level_of_measurement="interval")  # (coders, units)
    assert ours == pytest.approx(ref, abs=1e-10)


def test_krippendorff_constant_ratings_undefined_where_the_package_refuses():
    krippendorff = pytest.importorskip("krippendorff")
    x = np.full((4, 3), 2.0)
    with pytest.raises(ValueError, match="more than one value"):
        krippendorff.alpha(reliability_data=x.T, level_of_measurement="interval")
    assert krippendorff_alpha_interval(x) is None


def _embeddings(regime, rng, n=25, dim=12):
    if regime == "random":
        return rng.normal(size=(n, dim))
    if regime == "clustered":
        return rng.normal(size=(3, dim))[rng.integers(0, 3, n)] + 0.3 * rng.normal(size=(n, dim))
    return rng.normal(size=(5, dim))[rng.integers(0, 5, n)]  # exact duplicates


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # vendi_score 0.0.3 touches scipy.sparse.csr
@pytest.mark.parametrize("regime", ["random", "clustered", "duplicates", "wide"])
def test_vendi_matches_the_vendi_score_package(regime):
    vendi = pytest.importorskip("vendi_score.vendi")
    rng = np.random.default_rng(0)
    emb = rng.normal(size=(10, 64)) if regime == "wide" else _embeddings(regime, rng)
    s = cosine_similarity_matrix(emb)
    assert vendi_score(s) == pytest.approx(vendi.score_K(s), rel=1e-8)
    assert vendi_score(s) == pytest.approx(vendi.score_dual(emb), rel=1e-8)  # the (D, D) form, normalised rows


def _nltk_self_bleu(texts, weights_for):
    bleu_score = pytest.importorskip("nltk.translate.bleu_score")
    smooth = bleu_score.SmoothingFunction().method1
    tokens = [tokenize(t) for t in texts]
    out = []
    for i, hyp in enumerate(tokens):
        refs = tokens[:i] + tokens[i + 1 :]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out.append(bleu_score.sentence_bleu(refs, hyp, weights=weights_for(len(hyp)), smoothing_function=smooth))
    return np.array(out)


TEXTS = ["stack the red block on the blue block", "put the red block on the green block",
         "stack all the blocks into a tower of three", "open the drawer and put the cube inside",
         "push the pile of small blocks into the zone", "stack the red block on the blue block",
         "place the bowl on the table near the drawer", "sweep the pile into the green zone"]


def test_self_bleu_matches_nltk_sentence_bleu_for_texts_of_four_or_more_tokens():
    ref = _nltk_self_bleu(TEXTS, lambda k: (0.25, 0.25, 0.25, 0.25))
    assert self_bleu_per_text(TEXTS) == pytest.approx(ref, abs=1e-12)


def test_self_bleu_under_four_tokens_averages_only_the_orders_the_text_has():
    texts = ["push", "push it", "open the drawer", "close drawer", "open the top drawer"]
    ours = self_bleu_per_text(texts)
    # the documented difference: NLTK with weights (1/k,)*k for a k-token text gives our value ...
    assert ours == pytest.approx(_nltk_self_bleu(texts, lambda k: (1 / min(k, 4),) * min(k, 4)), abs=1e-12)
    # ... while NLTK's default weights count each missing order as a smoothed 0.1 and pull short texts down
    default = _nltk_self_bleu(texts, lambda k: (0.25, 0.25, 0.25, 0.25))
    # "push": its unigram matches, brevity penalty exp(1 - 2/1) against the closest length 2; NLTK adds 0.1^(3/4)
    assert ours[0] == pytest.approx(math.exp(-1)) and default[0] == pytest.approx(math.exp(-1) * 0.1 ** 0.75)
    assert np.all(default[:4] < ours[:4]) and default[4] == pytest.approx(ours[4])


def _score_columns(rng, kind, n=40):
    h = rng.normal(size=n)
    m = h + rng.normal(size=n)
    if kind == "ties":
        h, m = np.round(h), np.round(m)  # integer scores: many ties in both columns
    return h, m


@pytest.mark.parametrize("kind", ["continuous", "ties"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_correlations_match_scipy(kind, seed):
    h, m = _score_columns(np.random.default_rng(seed), kind)
    assert pearson(h, m) == pytest.approx(stats.pearsonr(h, m).statistic, abs=1e-12)
    assert spearman(h, m) == pytest.approx(stats.spearmanr(h, m).statistic, abs=1e-12)
    assert kendall_tau_b(h, m) == pytest.approx(stats.kendalltau(h, m, variant="b").statistic, abs=1e-12)


def test_constant_columns_are_undefined_where_scipy_gives_nan():
    h, m = np.array([1.0, 2.0, 3.0, 4.0]), np.full(4, 7.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert math.isnan(stats.pearsonr(h, m).statistic) and math.isnan(stats.spearmanr(h, m).statistic)
        assert math.isnan(stats.kendalltau(h, m).statistic)
    for fn in (pearson, spearman, kendall_tau_b):
        assert fn(h, m) is None and fn(m, h) is None


@pytest.mark.parametrize("kind", ["continuous", "ties"])
def test_vectorised_bootstrap_equals_scipy_on_each_resample(kind):
    """Every resample's value from the count matrix equals scipy on the resampled rows (NaN: undefined)."""
    h, m = _score_columns(np.random.default_rng(5), kind, n=12)
    n_boot, seed = 300, 3
    fast = bootstrap_statistics(h, m, resample_counts(len(h), n_boot, seed))
    idx = np.random.default_rng(seed).integers(0, len(h), (n_boot, len(h)))  # the same resamples
    for name, ref in (("pearson", stats.pearsonr), ("spearman", stats.spearmanr),
                      ("kendall", lambda a, b: stats.kendalltau(a, b, variant="b"))):
        expected = []
        for ix in idx:
            a, b = h[ix], m[ix]
            constant = a.min() == a.max() or b.min() == b.max()
            expected.append(np.nan if constant else ref(a, b).statistic)
        np.testing.assert_allclose(fast[name], expected, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(fast["mae"], np.abs(h[idx] - m[idx]).mean(1), atol=1e-12)


def test_agreement_intervals_use_the_documented_resamples():
    h, m = _score_columns(np.random.default_rng(9), "ties", n=30)
    out = agreement_summary(h, m, n_boot=400, seed=2)
    idx = np.random.default_rng(2 + 4).integers(0, 30, (400, 30))  # kendall is statistic 4: seed + 4
    values = [stats.kendalltau(h[ix], m[ix], variant="b").statistic for ix in idx]
    values = [v for v in values if np.isfinite(v)]
    assert out["kendall_ci"] == pytest.approx(list(np.quantile(values, [0.025, 0.975])), abs=1e-12)
