"""The RL stage's gain in the main job, measured on the robot (issue 13 item 3). Slow: one
default-size run of the bus, demos and train stages on the emulated D'Claw (3 min 16 s of CPU,
11 min at load 10; bench/RESULTS.md, "The RL stage in the main job", records seeds with
wall-clock). The gain is the issue's target and is NOT reached: the test is a strict xfail whose
reason gives the measured counts; it turns into a failure (XPASS) the day DAPG beats its clone.

The truth is not the report's own verdict but scipy's exact tests on the held-out episodes that
the clone and DAPG's policy both ran (the same reset seeds, so the comparison is paired per
episode): final |goal error|, one-sided Wilcoxon signed-rank; success (ROBEL's |error| < 0.1 rad,
``TurnConfig.success_tol``), one-sided exact McNemar test (a binomial test on the episodes only
one of the two solved).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.stats import binomtest, wilcoxon

from lowcostdex.cli import main

SUCCESS_TOL = 0.1
"""ROBEL's valve success threshold [rad], typed in (the env's ``TurnConfig.success_tol``)."""


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "2026-11-26, seed 0: no DAPG iterate beat the clone on validation (6, 4, 5 of 20 vs 7), so "
    "DAPG's policy is the clone: held-out 17/40 both, no episode solved by one only"))
def test_dapg_beats_the_clone_it_started_from_on_the_same_heldout_episodes(tmp_path):
    out = tmp_path / "main"
    assert main(["main", "--out", str(out), "--stages", "bus,demos,train", "--seed", "0"]) == 0
    t = json.loads((out / "results.json").read_text())["train"]
    bc = np.array(t["bc"]["final_goal_errors"])
    dapg = np.array(t["dapg"]["final_goal_errors"])
    assert len(bc) == len(dapg) == t["dapg"]["eval_episodes"] == 40
    # the counts the report states are these episodes' successes
    assert t["bc"]["eval_successes"] == int(np.sum(bc < SUCCESS_TOL))
    assert t["dapg"]["eval_successes"] == int(np.sum(dapg < SUCCESS_TOL))
    assert wilcoxon(dapg, bc, alternative="less").pvalue <= 0.01, (bc, dapg)
    only_dapg = int(np.sum((dapg < SUCCESS_TOL) & (bc >= SUCCESS_TOL)))
    only_bc = int(np.sum((bc < SUCCESS_TOL) & (dapg >= SUCCESS_TOL)))
    p = binomtest(only_dapg, only_dapg + only_bc, 0.5, alternative="greater").pvalue
    assert p <= 0.05, (only_dapg, only_bc)
