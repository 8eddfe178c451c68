"""The gap analysis on tests/gap_truth_sim.py's bench logs (issue 11): it names exactly the hidden
effect(s), and separately names them up to a confusable family. Cases, truth and history:
tests/test_gap_independent.py; each case analysed once (tests/gap_independent_cases.py). The
interval test reads three of the bench analyses.
"""

from __future__ import annotations

import pytest
from gap_independent_cases import (
    ANALYSIS_TIMEOUT,
    TRUTH,
    analysed,
    assert_names_exactly,
    assert_names_up_to_family,
    params,
)


@pytest.mark.timeout(ANALYSIS_TIMEOUT)
@pytest.mark.parametrize("cid", params(0, "bench"))
def test_names_exactly_the_hidden_effects(cid, tmp_path_factory):
    assert_names_exactly(cid, tmp_path_factory)


@pytest.mark.timeout(ANALYSIS_TIMEOUT)
@pytest.mark.parametrize("cid", params(1, "bench"))
def test_names_the_hidden_effects_up_to_a_confusable_family(cid, tmp_path_factory):
    assert_names_up_to_family(cid, tmp_path_factory)


# Three cheap bench cases whose data-only intervals (residual noise, 0.5 s block spread) all
# missed the truth (measured 2026-11-26: latency 25.99 ms in [25.97, 26.02] for 25.96; gain
# 0.65202 in [0.65184, 0.65220] for 0.65230; Coulomb 0.1415 in [0.1411, 0.1418] for 0.1409): the
# replay's own discretisation biases every stretch of data alike.
INTERVAL_CASES = ("bench-latency", "bench-gain_error", "bench-coulomb_friction")


@pytest.mark.timeout(ANALYSIS_TIMEOUT)
def test_parameter_intervals_hold_the_truth_about_as_often_as_they_claim(tmp_path_factory):
    """Issue 11: 95 % intervals must contain the true value (gap_truth_sim's) >= 90 % of the
    time. On three cases where the data-only intervals held it 0/3, the reported ones (with
    the move of the fit at half the physics step) must hold it in at least 2/3; fails when
    coverage falls well below nominal (at 95 % each, 2/3 or fewer happens 0.7 % of the
    time). Cached cases: free after the exact-name tests above."""
    from lowcostdex.sim.effects import effect

    rows = []
    for cid in INTERVAL_CASES:
        hidden, res = analysed(cid, tmp_path_factory)
        (c,) = [c for c in res.causes if c.effect in hidden]
        # the truth simulator's one parameter per effect is the catalogue's first (picked by
        # name: coulomb_friction also reports its creep, held at its null unless freed)
        d = c.params[effect(c.effect).params[0].name]
        true = float(TRUTH[cid][c.effect][0])
        lo, hi = d["interval"][0]
        rows.append((cid, lo <= true <= hi, true, d["value"][0], (lo, hi), d["step_shift"][0]))
        # the reported interval holds the data's and is centred on the value
        dlo, dhi = d["interval_data"][0]
        assert lo <= dlo <= d["value"][0] <= dhi <= hi
    assert sum(r[1] for r in rows) >= 2, rows
