"""Wilson score interval: hand-computed values, the reference implementation where installed, and coverage."""

import math

import numpy as np
import pytest

from simeval.errors import UserError
from simeval.stats.intervals import success_summary, wilson_interval


def _hand(k, n, z=1.959963984540054):
    # the formula written out independently: (2k + z^2 -+ z sqrt(z^2 + 4k(n-k)/n)) / (2(n + z^2))
    root = z * math.sqrt(z * z + 4 * k * (n - k) / n)
    return (2 * k + z * z - root) / (2 * (n + z * z)), (2 * k + z * z + root) / (2 * (n + z * z))


@pytest.mark.parametrize("k,n", [(0, 20), (1, 20), (3, 10), (10, 10), (7, 40), (50, 100)])
def test_wilson_matches_the_closed_form(k, n):
    assert wilson_interval(k, n) == pytest.approx(_hand(k, n), abs=1e-12)


def test_known_values_of_a_table_of_small_success_rates():
    # 0/20 is not [0, 0]: a table cell of 0.00 still says up to ~16% is plausible
    assert wilson_interval(0, 20) == pytest.approx((0.0, 0.16113), abs=1e-5)
    assert wilson_interval(3, 10) == pytest.approx((0.10779, 0.60322), abs=1e-5)


def test_matches_statsmodels_when_installed():
    sm = pytest.importorskip("statsmodels.stats.proportion")
    for k, n in [(0, 20), (3, 10), (17, 40)]:
        assert wilson_interval(k, n) == pytest.approx(sm.proportion_confint(k, n, method="wilson"), abs=1e-10)


def test_coverage_is_near_nominal():
    rng = np.random.default_rng(0)
    p, n = 0.15, 40
    ks = rng.binomial(n, p, 4000)
    covered = np.mean([lo <= p <= hi for lo, hi in (wilson_interval(int(k), n) for k in ks)])
    assert 0.92 < covered < 0.98


def test_bad_counts_are_user_errors_and_empty_is_uninformative():
    with pytest.raises(UserError, match="0 <= k <= n"):
        wilson_interval(5, 3)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    assert success_summary([True, False, False, False]) == {"k": 1, "n": 4, "rate": 0.25,
                                                            "ci": list(wilson_interval(1, 4))}
