"""The gap analysis judged on the seventh independent truth simulator (``tests/gap_truth_sim7.py``:
a one-joint position-servo bench with a scaled reading, a scaled and shifted one, goals 0-2
periods late at random, goal packets lost; the two rows of 04-sysid.md section 6's hidden-effect
table no earlier set had; gap-scale16, session 21; bench/RESULTS.md "gap-scale16").

Each case is analysed as the CLI does and scored by ``redteam_check.grade``: the hidden catalogue
cause named exactly (``sensor_scale``, ``position_offset``), nothing or only the mean latency on
jitter and dropped goals, nothing on the clean case; every documented parameter inside its 95 %
interval. Misses are strict xfails whose reason is the measured result; they fail (XPASS) when
fixed and must then lose their mark.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim7 as sim  # noqa: E402
import redteam_check  # noqa: E402


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim7.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco",
                     "numpy"}, names


def test_the_truths_reading_is_scaled_and_its_goals_arrive_late_or_not_at_all():
    """sim7 written out: the reading is (1 + s) q + offset quantised to ticks (within half a
    tick and the read noise); under jitter the servo holds row i - k's goal with k in {0, 1, 2}
    each about a third of the rows; with drops about 5 % of the rows keep the previous goal."""
    rng = np.random.default_rng(0)
    t = sim.row_times(3.0, 100.0, rng)
    tgt = sim.targets("chirp", t, rng)
    case = sim.CASE_BY_NAME["scale_p10_offset_m40"]
    out = sim.simulate(case, t, tgt, np.random.default_rng(1), true_angles=True)
    err = out["qpos:q"] - (1.010 * out["true:q"] - 0.040)
    assert np.abs(err).max() < sim.TICK / 2 + 4 * sim.READ_NOISE
    assert np.all(np.abs(out["qpos:q"] / sim.TICK - np.round(out["qpos:q"] / sim.TICK)) < 1e-6)
    goals = np.arange(3000) * sim.TICK   # distinct goals, one tick apart
    held = sim.servo_goals(sim.CASE_BY_NAME["jitter2_100hz"], goals, np.random.default_rng(2))
    lag = np.rint((goals - held) / (goals[1] - goals[0])).astype(int)
    assert set(lag[2:]) == {0, 1, 2}
    assert all(0.28 < np.mean(lag[2:] == k) < 0.39 for k in (0, 1, 2))
    held = sim.servo_goals(sim.CASE_BY_NAME["drop5_100hz"], goals, np.random.default_rng(3))
    kept = held[1:] == held[:-1]
    assert 0.035 < kept.mean() < 0.065 and np.all(held[~np.r_[False, kept]] ==
                                                     goals[~np.r_[False, kept]])


# ---------------------------------------------------------------------------------------------
# the analysis on sim7's cases, as a user runs it (gap analyze on the case's files; each case
# 0.2-5 CPU-min: slow but jitter2_100hz and clean_100hz, the fast check of the wiring is
# tests/test_gap_sensor_scale.py)
# ---------------------------------------------------------------------------------------------

# Measured (gap-scale16, session 21, shared 2-core VM, `gap analyze --threads 1`):
# scale_p15 on main f3fe2b5 (no sensor_scale in the catalogue): backlash named (width 19.2 mrad,
# read on the output shaft: sensor widened to 1.5), held-out 6.71 -> 6.18 mrad, 282 s CPU; with
# sensor_scale (104c1b6): exact, scale 1.01487 [1.01465, 1.01511] for 1.015, held-out 6.41 ->
# 0.76 mrad, gain CI [5.42, 5.97] mrad, 134 s CPU. On main 06f04e1: scale_p10_offset_m40 exact,
# scale 1.00979 [1.00822, 1.01236] for 1.010 and offset -40.02 mrad [-41.10, -38.46] for -40,
# held-out 44.4 -> 3.64 mrad, 94 s CPU; jitter2_100hz latency alone, 10.13 ms [5.45, 12.83] (the
# mean lag 10 ms), held-out 34.8 -> 10.7 mrad, 55 s CPU (fast: the one check in the default run
# that random goal lags do not invent friction, inertia or a gain).
# drop5_100hz nothing named (held-out 1.71 mrad), 67 s CPU.
# clean_100hz nothing named (held-out 0.71 mrad), 14 s CPU (fast).
# Cases not listed here were not analysed this session (CPU budget).
FAST: frozenset[str] = frozenset({"jitter2_100hz", "clean_100hz"})
MISSES: dict[str, str] = {}


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_the_scale_and_nothing_or_the_mean_latency_for_jitter_and_drops(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_the_grade_on_hand_written_reports():
    # the scorer itself (tests/redteam_check.grade with sim7's FAMILIES), so a wrong scorer
    # cannot pass the cases: truth and reports written out here
    def rep(*names):
        return {"causes": [{"effect": n, "params": {}, "joints": []} for n in names]}

    scale = {"causes": ["sensor_scale"]}
    jitter = {"causes": [], "allowed": ["latency"]}

    def result(report, truth):
        return redteam_check.grade(report, truth, sim.FAMILIES)["result"]

    assert result(rep("sensor_scale"), scale) == "exact"
    assert result(rep("sensor_scale", "latency"), scale) == "extra"
    assert result(rep("gain_error"), scale) == "family"
    assert result(rep("backlash"), scale) == "miss"
    assert result(rep(), scale) == "miss"
    assert result(rep(), jitter) == "clean"
    assert result(rep("latency"), jitter) == "clean"
    assert result(rep("coulomb_friction"), jitter) == "false"
