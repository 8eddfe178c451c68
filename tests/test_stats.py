"""Wilson score intervals against published values."""

from __future__ import annotations

import pytest

from lowcostdex.stats import rate_text, wilson_interval


@pytest.mark.parametrize("k, n, low, high", [
    # Newcombe (1998), Statistics in Medicine 17:857-872, Table I, method 3 (score interval
    # without continuity correction): 81/263 -> 0.2553-0.3662; 15/148 -> 0.0624-0.1605;
    # 0/20 -> 0.0000-0.1611; 1/29 -> 0.0061-0.1718.
    (81, 263, 0.2553, 0.3662),
    (15, 148, 0.0624, 0.1605),
    (0, 20, 0.0, 0.1611),
    (1, 29, 0.0061, 0.1718),
])
def test_wilson_matches_newcombe_table(k, n, low, high):
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(low, abs=6e-5)
    assert hi == pytest.approx(high, abs=6e-5)


def test_interval_is_symmetric_under_relabelling_and_not_empty_at_the_ends():
    lo, hi = wilson_interval(3, 10)
    lo2, hi2 = wilson_interval(7, 10)
    assert lo == pytest.approx(1 - hi2) and hi == pytest.approx(1 - lo2)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and 0.6 < lo < 0.75      # 10/10 still leaves room below 1


def test_rate_text_and_bad_counts():
    assert rate_text(7, 10) == "0.70 (7/10; 95 % CI 0.40-0.89)"
    assert rate_text(0, 0) == "n/a (not evaluated)"
    with pytest.raises(ValueError):
        wilson_interval(11, 10)
    with pytest.raises(ValueError):
        wilson_interval(0, 0)


@pytest.mark.parametrize("n, low_rank, coverage", [
    # ranks of the distribution-free 95 % interval of a median, [x_(k), x_(n+1-k)], and its
    # coverage 1 - 2 P(Bin(n, 1/2) <= k - 1), worked by hand: n = 10: P(B <= 1) = (1 + 10)/1024,
    # P(B <= 2) = 56/1024 = 0.055 > 0.025, so k = 2 (ranks 2 and 9; Conover, Practical
    # Nonparametric Statistics, 3rd ed., Table A3 gives the same ranks); n = 30: k = 10 (P(B <=
    # 9) = 0.0214, P(B <= 10) = 0.0494); n = 50: k = 18 (P(B <= 17) = 0.0164, P(B <= 18) =
    # 0.0325); n = 3: no rank reaches 95 %, the range, 1 - 2/8; n = 6: 1 - 2/64.
    (10, 2, 1 - 2 * 11 / 1024),
    (30, 10, 1 - 2 * 0.021387),
    (50, 18, 1 - 2 * 0.016420),
    (3, 1, 0.75),
    (6, 1, 1 - 2 / 64),
])
def test_median_interval_ranks_match_the_binomial_by_hand(n, low_rank, coverage):
    from lowcostdex.stats import median_interval

    values = [10.0 * (i + 1) for i in range(n)]  # x_(i) = 10 i
    shuffled = values[1::2] + values[0::2]  # the order given does not matter
    median, lo, hi, cov = median_interval(shuffled)
    assert median == pytest.approx(10.0 * (n + 1) / 2)  # n even: the mean of the middle two
    assert lo == 10.0 * low_rank and hi == 10.0 * (n + 1 - low_rank)
    assert cov == pytest.approx(coverage, abs=1e-5)


def test_median_interval_of_one_value_and_bad_input():
    from lowcostdex.stats import median_interval

    assert median_interval([0.3]) == (0.3, 0.3, 0.3, 0.0)  # one value: no coverage at all
    with pytest.raises(ValueError):
        median_interval([])
    with pytest.raises(ValueError):
        median_interval([0.1, float("nan")])
