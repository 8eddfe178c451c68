"""identify_verdict: "no reliable gain" when the identified model is worse than the nominal one on
most held-out logs or the gain's interval over logs includes zero (issue 11 item 5).

The per-log MAEs are typed in; what each case must say follows from counting and from the
interval's definition, not from the code under test.
"""

from __future__ import annotations

import numpy as np

from lowcostdex.gap.identify_verdict import verdict


def test_worse_on_most_held_out_logs_is_no_reliable_gain_even_with_a_lower_mean():
    # Pham XL330's up_and_down fold shape: one log much better, two worse; the mean gain is
    # positive (nominal 30.0 vs identified 13.3 mrad) yet the identified model loses on 2 of 3
    nominal = {4: 0.080, 7: 0.005, 9: 0.005}
    identified = {4: 0.020, 7: 0.010, 9: 0.010}
    v = verdict(nominal, identified, [4, 7, 9])
    assert v["gain"] > 0 and v["better"] == 1 and v["logs"] == 3
    assert not v["reliable"]
    assert v["text"].startswith("no reliable gain")
    assert "worse than the nominal model on 2 of 3" in v["text"]


def test_better_on_every_log_by_a_clear_margin_is_a_gain_with_its_interval():
    nominal = {i: 0.300 + 0.01 * i for i in range(8)}
    identified = {i: 0.030 + 0.002 * i for i in range(8)}
    v = verdict(nominal, identified, range(8))
    assert v["reliable"] and v["better"] == 8
    lo, hi = v["gain_ci95"]
    diffs = [nominal[i] - identified[i] for i in range(8)]
    # a bootstrap of the mean lies within the smallest and largest per-log gain
    assert min(diffs) <= lo <= hi <= max(diffs)
    assert abs(v["gain"] - np.mean(diffs)) < 1e-12
    assert "better on 8 of 8" in v["text"]


def test_better_on_most_logs_but_an_interval_through_zero_is_no_reliable_gain():
    # 3 of 4 logs a hair better, one far worse: the mean gain is negative-leaning and the
    # resampled means span zero (a resample of the three small gains alone is > 0, one with the
    # loss twice is < 0)
    nominal = {0: 0.0100, 1: 0.0100, 2: 0.0100, 3: 0.0100}
    identified = {0: 0.0099, 1: 0.0099, 2: 0.0099, 3: 0.0200}
    v = verdict(nominal, identified, [0, 1, 2, 3])
    assert v["better"] == 3
    lo, hi = v["gain_ci95"]
    assert lo < 0 < hi
    assert not v["reliable"] and "interval includes zero" in v["text"]


def test_one_held_out_log_has_no_interval_and_its_sign_decides():
    worse = verdict({2: 0.0442}, {2: 0.0513}, [2])  # STS3250 sin_time_square fold, 2026-11-27
    assert worse["gain_ci95"] is None and not worse["reliable"]
    assert "no reliable gain" in worse["text"] and "one held-out log" in worse["text"]
    better = verdict({2: 0.0513}, {2: 0.0442}, [2])
    assert better["reliable"] and "better on 1 of 1" in better["text"]


def test_no_held_out_logs_measure_nothing_and_the_bootstrap_is_reproducible():
    v = verdict({0: 0.1}, {0: 0.05}, [])
    assert not v["reliable"] and "not measured" in v["text"]
    a = verdict({0: 0.1, 1: 0.2, 2: 0.05}, {0: 0.05, 1: 0.1, 2: 0.06}, [0, 1, 2])
    b = verdict({0: 0.1, 1: 0.2, 2: 0.05}, {0: 0.05, 1: 0.1, 2: 0.06}, [0, 1, 2])
    assert a == b  # seeded: the same logs give the same verdict
