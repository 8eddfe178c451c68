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
