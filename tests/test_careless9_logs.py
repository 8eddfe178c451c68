"""Careless logs (issue 13/11), session 15: a log with a hole in it (logging paused, rows lost).

The frozen-encoder check took the goal acting on the first row after a hole to be the last goal
logged before it (a row's goal is written after its reading, so row a's acting goal is row
a - 1's). Across a hole that goal is seconds old. A measured BAM log (Rhoban XL330, sin_sin)
with 400 rows cut out was refused as "'qpos:arm' is frozen at -0.314 rad for 0.66 s while
'goal:arm' moves over [-1.46, 1.56] rad": 1.56 rad was the goal 2 s before. The same rows, in
the log without the hole, pass. A log with a hole is split there and each piece is judged on its
own (``logs.split_at_gaps``); the check now judges them the same way.
"""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import numpy as np
import pytest

from lowcostdex.gap import LogError, load_dataset
from lowcostdex.gap.log_checks import FROZEN_CROSS, check_signals, frozen_crossing
from lowcostdex.gap.trajectory import Trajectory

RATE = 100.0  # [Hz]


def _log(pieces: list[tuple[np.ndarray, np.ndarray]], hole: float = 2.0) -> Trajectory:
    """One joint's log from (goal, reading) pieces, each at RATE, ``hole`` s between pieces."""
    times, goals, reads, t0 = [], [], [], 0.0
    for goal, q in pieces:
        times.append(t0 + np.arange(len(goal)) / RATE)
        goals.append(goal)
        reads.append(q)
        t0 = times[-1][-1] + hole
    return Trajectory("log.csv", np.concatenate(times), np.concatenate(goals)[:, None],
                      np.concatenate(reads)[:, None], ("arm",), ("arm",))


def _tracking(n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """A ramp 0 -> 1 rad then a hold; each reading is the goal written one row earlier (a servo
    that keeps up, read before the row's goal is sent)."""
    goal = np.minimum(np.arange(n) / 50.0, 1.0)
    return goal, np.concatenate([[0.0], goal[:-1]])


def _resting(goal_offset: float, n: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """The joint resting at -0.3 rad (against friction, or a stop) with its goal held
    ``goal_offset`` below it: one side only, nothing frozen."""
    return np.full(n, -0.3 - goal_offset), np.full(n, -0.3)


def test_a_joint_at_rest_after_a_hole_is_judged_on_its_own_goals():
    before, after = _tracking(), _resting(goal_offset=1.5 * FROZEN_CROSS - 0.05)
    for alone in (before, after):  # each piece, as a log of its own, is not frozen
        assert frozen_crossing(_log([alone]), 0)[0] <= FROZEN_CROSS
    assert frozen_crossing(_log([before, after]), 0)[0] <= FROZEN_CROSS  # nor is the two
    check_signals(_log([before, after]))  # with a hole between: the log passes


def test_a_reading_frozen_after_a_hole_while_the_goal_passes_it_both_ways_is_still_refused():
    goal, q = _tracking()
    sweep = np.linspace(-0.3 - 1.5 * FROZEN_CROSS, -0.3 + 1.5 * FROZEN_CROSS, 100)
    with pytest.raises(LogError, match=r"'qpos:arm' is frozen at -0.3 rad .* while 'goal:arm' "
                                       r"moves over \[-0\.6, -0\.006"):
        check_signals(_log([(goal, q), (sweep, np.full(100, -0.3))]))


BAM = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA", "/work/shared/data/measured"))
XL330 = BAM / "rhoban-bam-xl330" / "2026-01-15_10h28m10.json"


@pytest.mark.skipif(not XL330.exists(), reason=f"measured BAM log {XL330} not present")
def test_a_measured_bam_log_with_rows_cut_out_loads_split_at_the_hole(tmp_path):
    """The truth is the measured log: it loads whole; the same log with rows 300-699 cut out (a
    logger that lost 2.1 s) holds the same readings and goals, so it loads too, in two pieces,
    and says where the hole is."""
    raw = json.loads(XL330.read_text())
    whole = load_dataset([XL330])
    assert len(whole.trajectories) == 1
    holed = copy.deepcopy(raw)
    del holed["entries"][300:700]
    path = tmp_path / "holed.json"
    path.write_text(json.dumps(holed))
    ds = load_dataset([path])  # raised "frozen at -0.314466 rad for 0.66 s" before
    assert len(ds.trajectories) == 2
    assert any("time jumps 2.15 s after 1.58" in note and "split into 2" in note
               for note in ds.notes), ds.notes
