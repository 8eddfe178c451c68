"""The gap analysis on tests/gap_truth_sim.py's bench logs with real-world sizes beyond the usual
search ranges (issue 11): each case (``gap_truth_sim.WIDE_CASES``) is its own analysis. The other
cases and their history: tests/test_gap_independent.py.
"""

from __future__ import annotations

import gap_truth_sim as ts
import pytest
from gap_independent_cases import ANALYSIS_TIMEOUT, describe

# Sizes beyond the usual search ranges (latency 0.1 s, offsets +-0.2 rad, gain 0.2-4x): the fit
# lands on the bound, the range widens toward the hard limit and the report says so.
WIDENED = {"bench-offset-1tooth", "bench-gain-5x", "bench-latency-130ms"}
# how close the named size must be, per effect [its unit]
TOLERANCE = {"latency": 0.003, "position_offset": 0.003, "gain_error": 0.03 * 5.0}


@pytest.mark.timeout(ANALYSIS_TIMEOUT)
@pytest.mark.parametrize("cid", [c[0] for c in ts.WIDE_CASES])
def test_names_real_world_sizes_beyond_the_usual_ranges(cid, tmp_path_factory):
    from lowcostdex.gap import GapConfig, analyze, load_dataset, report

    _, rig, values, seed, duration = next(c for c in ts.WIDE_CASES if c[0] == cid)
    case = ts.make_case(rig, list(values), seed, duration=duration, values=values)
    model, paths = case.write(tmp_path_factory.mktemp(cid))
    res = analyze(load_dataset(paths, model=model), GapConfig(seed=0))
    assert {c.effect for c in res.causes} == set(values), describe(res)
    (name, truth), = values.items()
    (cause,) = res.causes
    (fitted,) = [d["value"] for d in cause.params.values()]
    assert fitted == pytest.approx([truth], abs=TOLERANCE[name]), describe(res)
    assert not cause.flags
    assert bool(cause.widened) == (cid in WIDENED), cause.widened
    assert ("range widened" in report.markdown(res)) == (cid in WIDENED)
    assert res.extended["heldout_rmse"] < 0.1 * res.baseline["heldout_rmse"]
