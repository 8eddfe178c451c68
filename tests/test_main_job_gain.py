"""The RL stage's gain in the main job, measured on the robot (issue 13 item 3). Slow: one
default-size run of the bus, demos and train stages on the emulated D'Claw (314 s of CPU,
29 min at load 15-17 with six clones and 100 held-out episodes; bench/RESULTS.md, "Best of six
clones"). The gain is the issue's target and is NOT reached: the test is a strict xfail whose
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
# the run takes 10-11 min at load 10 and timed out at the default 600 s at load ~18 (2026-11-26,
# 617 s): a timeout inside a strict xfail would pass as "xfailed" without measuring anything,
# so only the gain's assertions (AssertionError) are the expected failure; with six clones and
# 100 held-out episodes it took 29 min at load 15-17 (2026-11-27): 3600 s
@pytest.mark.timeout(3600)
@pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "2026-11-27 session 9, DAPG from the best of 6 clones, 100 held-out episodes: this test "
    "xfailed (an assertion) on seed 0, 1750 s wall at load 15-17, 314 s CPU. The same clone and "
    "DAPG policy (deterministic: BC seed 436301621, validation 0.32 -> 0.48 at iteration 29) "
    "judged by bench/main_job_sim.py: 37 -> 40 of 100, 19 vs 16 episodes solved by one only "
    "(McNemar p 0.37, needs <= 0.05), final errors 0.144 -> 0.114 rad (Wilcoxon p 0.004). Seed "
    "1 passes both parts on 100 (39 -> 51, 19 vs 7, p 0.015; Wilcoxon p < 1e-4); bench/"
    "RESULTS.md, 'Best of six clones'. 2026-11-27 session 10 (harness, the same seed-0 run's "
    "iterates 9/19/29 on the 100 held-out: 44, 43, 41 vs the clone's 37, McNemar p 0.13, "
    "0.073, 0.30): no final candidate of this run passes; choosing among them on robot "
    "validation episodes (20 or 40) picks iteration 19 (p 0.073): bench/RESULTS.md, 'DAPG's "
    "final candidates judged on the robot'. 2026-11-27 session 11 (bench/main_job_sim.py "
    "candidates --sim gap, each policy on a fresh robot): DAPG trained in the gap-extended "
    "simulation passed on seeds 0 and 2 with session 10's gap report (37 -> 53, p 0.0001; "
    "30 -> 42, p 0.0085; seed 1 50 -> 56, p 0.14), but with today's gap stage on the same logs "
    "(the same fitted values, one more held parameter, so other randomization draws) on seed 2 "
    "only (37 -> 35, p 0.81; 50 -> 47; 30 -> 47, p 8e-6): not adopted; bench/RESULTS.md, "
    "'Paired evaluations that do not depend on order; DAPG in the gap-extended simulation'. "
    "2026-11-27 session 13 (bench/main_job_sim.py streams, the main job's DAPG stage on "
    "today's code, each policy on a fresh robot): seed 0 40 -> 48 of 100 (20 vs 12, McNemar "
    "p 0.11; Wilcoxon p 0.0054) still fails here, while seeds 1 (39 -> 50, p 0.026) and 2 "
    "(20 -> 32, p 0.0145; both Wilcoxon p < 1e-4) pass; three runs averaged (44 of 100) and a "
    "3x batch (47) did not lift seed 0; bench/RESULTS.md, 'The main job's RL stage: averaged "
    "over randomization streams'. 2026-11-27 session 14 (validation after every iteration "
    "from 15, SimTraining.dense_from; the same runs otherwise, bit-identical iterates): seed 0 "
    "chooses iteration 22 (validation 0.43) instead of 29: 40 -> 49 of 100 (17 vs 8, McNemar "
    "p 0.054, Wilcoxon p 0.0019), still short of 0.05; seed 1 39 -> 52 (16 vs 3, p "
    "0.0022) and seed 2 20 -> 37 (24 vs 7, p 0.0017) pass; "
    "bench/RESULTS.md, 'The main job's DAPG validated at every late iterate'"))
def test_dapg_beats_the_clone_it_started_from_on_the_same_heldout_episodes(tmp_path):
    out = tmp_path / "main"
    if main(["main", "--out", str(out), "--stages", "bus,demos,train", "--seed", "0"]) != 0:
        pytest.fail("the main job failed")  # not an AssertionError: a failure, not the xfail
    t = json.loads((out / "results.json").read_text())["train"]
    bc = np.array(t["bc"]["final_goal_errors"])
    dapg = np.array(t["dapg"]["final_goal_errors"])
    # 100 held-out episodes (Budget.heldout_episodes; was 40, on which a real gain of 5 of 40
    # does not reach p 0.05: bench/RESULTS.md, "Best of six clones")
    assert len(bc) == len(dapg) == t["dapg"]["eval_episodes"] == 100
    # the counts the report states are these episodes' successes
    assert t["bc"]["eval_successes"] == int(np.sum(bc < SUCCESS_TOL))
    assert t["dapg"]["eval_successes"] == int(np.sum(dapg < SUCCESS_TOL))
    assert wilcoxon(dapg, bc, alternative="less").pvalue <= 0.01, (bc, dapg)
    only_dapg = int(np.sum((dapg < SUCCESS_TOL) & (bc >= SUCCESS_TOL)))
    only_bc = int(np.sum((bc < SUCCESS_TOL) & (dapg >= SUCCESS_TOL)))
    p = binomtest(only_dapg, only_dapg + only_bc, 0.5, alternative="greater").pvalue
    assert p <= 0.05, (only_dapg, only_bc)
