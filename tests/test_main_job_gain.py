"""The RL stage's gain in the main job, measured on the robot (issue 13 item 3). Slow: one
default-size run of the bus, demos, gap and train stages on the emulated D'Claw (~13 min of CPU).

Until session 15 this was a strict xfail (seed 0 one discordant episode short: 40 -> 49 of 100,
17 vs 8, McNemar p 0.054, with DAPG's iterate chosen in its catalogue-randomized training sim).
With the gap stage before train and DAPG's iterates validated in the simulation it identified
(``main_job.gapsim``), seed 0 chooses iteration 21: 40 -> 54 of 100, 20 vs 6 episodes solved by
one only, McNemar p 0.0047, Wilcoxon p < 1e-4 (measured with the main job's DAPG stage on the
same demonstrations, bit-identical iterates; seeds 1 and 2: 39 -> 53, p 0.0007; 20 -> 37,
p 0.0017; bench/RESULTS.md, "DAPG's iterate chosen in the gap-identified simulation").

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
# with six clones, 100 held-out episodes and the gap stage it takes ~13 min of CPU, 25-30 min
# wall under load 10-17 (2026-11-27): 3600 s
@pytest.mark.timeout(3600)
def test_dapg_beats_the_clone_it_started_from_on_the_same_heldout_episodes(tmp_path):
    out = tmp_path / "main"
    # the gap stage before train: DAPG's iterates are validated in the simulation it identified
    if main(["main", "--out", str(out), "--stages", "bus,demos,gap,train", "--seed", "0"]) != 0:
        pytest.fail("the main job failed")
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
