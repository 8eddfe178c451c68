"""The gap analysis on tests/gap_truth_sim.py's finger logs (issue 11): it names exactly the hidden
effect(s), and separately names them up to a confusable family. Cases, truth and history:
tests/test_gap_independent.py; each case analysed once (tests/gap_independent_cases.py).
"""

from __future__ import annotations

import pytest
from gap_independent_cases import (
    ANALYSIS_TIMEOUT,
    assert_names_exactly,
    assert_names_up_to_family,
    params,
)


@pytest.mark.timeout(ANALYSIS_TIMEOUT)
@pytest.mark.parametrize("cid", params(0, "finger"))
def test_names_exactly_the_hidden_effects(cid, tmp_path_factory):
    assert_names_exactly(cid, tmp_path_factory)


@pytest.mark.timeout(ANALYSIS_TIMEOUT)
@pytest.mark.parametrize("cid", params(1, "finger"))
def test_names_the_hidden_effects_up_to_a_confusable_family(cid, tmp_path_factory):
    assert_names_up_to_family(cid, tmp_path_factory)
