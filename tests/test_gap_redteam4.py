"""The gap analysis judged on a fourth independently written truth simulator: the holes of the
coverage audit (issue 11 items 1, 2, 4; gap-judge9, session 15; table in bench/RESULTS.md).

``tests/gap_truth_sim4.py`` (mujoco + numpy only) writes one pendulum four ways, as a user's MJCF
would: a ``velocity`` actuator driven by a host position loop (the log's goal is the velocity
command), a ``motor`` driven by a host PD (the goal is the torque it wrote), a ``position``
actuator with kp AND kv, a ``general`` servo; hidden effects at the issue's range edges (gain 3x
with kv kept, armature 3x, link mass 0.3x and 3x, a velocity loop's kv 0.4x, a motor's torque
constant 0.5x and a torque cap at 60 % of its commands, Coulomb at 60 %) and a pair on one joint
(latency 50 ms + reading offset -0.2 rad). Each case is analysed as the CLI does and scored by
``gap_truth_sim2.score`` (the same contract as ``tests/test_gap_redteam.py``): the named causes
exactly the hidden ones (nothing on a clean case), every documented parameter inside its 95 %
interval. Misses are strict xfails whose reason is the measured result (bench/gap_redteam4.py
on the commit named there); they fail (XPASS) when fixed and must then lose their mark.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim4 as sim  # noqa: E402
import redteam_check  # noqa: E402

# in the default run (measured 26 s wall, 7.4 s CPU at load 8); the rest are slow
FAST = ("clean_velocity",)

# what the analysis named instead, per case it misses (bench/gap_redteam4.py --threads 1)
MISSES: dict[str, str] = {}
# gain05_dcmotor was extra on c354756 (gap-judge9; 61 s CPU): gain_error 0.708 [0.681, 0.744]
# (truth 0.5) plus mass_error 1.409, held-out 39.2 -> 3.18 mrad: the truth halves the dcmotor
# controller's kp and keeps its kd, the catalogue's gain_error on a dcmotor scaled P, I and D
# together. Since gain_error scales the P term alone on every kind (gap-dc11, session 16; 111 s
# CPU): exact, 0.5 [0.499, 0.5007], held-out 38.9 -> 0.68 mrad (floor 0.67).
# latency050_offsetm020_position was a miss on 8283b8a (latency 48.4 ms alone, held-out 259 ->
# 200 mrad: the -0.2 rad offset, chosen first, sat on its +-0.2 search bound once the latency
# was fitted beside it and the backward pass dropped it as implausible); since
# gates.widen_at_bounds (gap-judge9, session 15; 54 s CPU) exact: offset -0.2000 [-0.20017,
# -0.19984], latency 50.3 ms [48.7, 50.9], held-out 1.0 mrad.


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim4.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "tempfile",
                     "mujoco", "numpy", "gap_truth_sim2"}, names


def test_every_hidden_effect_is_plain_and_clean_logs_replay_near_the_read_floor():
    """The user's nominal model replayed open loop in plain mujoco (2 ms): clean logs stay
    within a few mrad (the 0.25 ms truth step and the reads' ticks), every hidden effect moves
    the logs by tens of mrad RMS (measured: clean 1.7 / 3.9 mrad, effects 63-316 mrad)."""
    for case in sim.CASES:
        rms = sim.effect_size(case)["rms"][0]
        if case.effects:
            assert rms > 0.03, (case.name, rms)
        else:
            assert rms < 0.006, (case.name, rms)


def _log(case):
    rng = np.random.default_rng(case.seed)
    t = sim.row_times(6.0, case.rate, case.jitter, rng)
    out = sim.simulate(case, t, sim.targets("steps", t, rng), rng)
    keep = t >= 0
    return t[keep], out["qpos"][keep], out["goal"][keep]


def test_latency_delays_the_response_and_a_reading_offset_shifts_every_read():
    """On the position kind (goals are the targets, the same draws with or without effects):
    the 50 ms latency's reads match the clean reads 50 ms earlier (better than 30 or 70 ms),
    and the reading offset moves every read by -0.2 rad while the servo holds the true angle."""
    t, q0, g0 = _log(sim.Case("c", "position", seed=7))
    _, q1, g1 = _log(sim.Case("l", "position", (sim.Effect("latency", 0.05),), seed=7))
    np.testing.assert_array_equal(g0, g1)

    def err(lag):
        inside = t - lag > t[0]
        return np.sqrt(np.mean((q1[inside] - np.interp(t[inside] - lag, t, q0)) ** 2))

    assert err(0.05) < 0.5 * min(err(0.03), err(0.07))
    assert err(0.05) < 0.01
    _, q2, _ = _log(sim.Case("o", "position", (sim.Effect("reading_offset", -0.2),), seed=7))
    assert np.median(q2 - q0) == pytest.approx(-0.2, abs=sim.TICK)


def test_host_loops_write_what_the_actuator_takes():
    """A velocity-mode servo's goals are velocities within +-VMAX (not angles), a torque-driven
    joint's goals torques within its +-1 N m ctrlrange. Held still, a velocity servo's force
    kv x gain x command carries the link's gravity torque m g l_c sin q (written out here), with
    its kv at 1x and at the hidden 0.4x alike."""
    _, qm, gm = _log(sim.Case("m", "motor", seed=3))
    assert np.abs(gm).max() <= sim.UMAX and np.ptp(qm) > 0.5
    p = sim.NOMINAL["velocity"]
    mgl = 9.81 * (p["rod"] * p["length"] / 2 + p["tip"] * p["length"])  # N m at 90 deg
    for gain in (1.0, 0.4):
        effects = (sim.Effect("gain", gain),) if gain != 1.0 else ()
        _, q, g = _log(sim.Case("v", "velocity", effects, seed=3))
        assert np.abs(g).max() <= sim.VMAX and np.corrcoef(g, q)[0, 1] < 0.8
        still = np.flatnonzero((np.abs(q[20:] - q[:-20]) <= sim.TICK) & (np.abs(q[20:]) > 0.2)
                               & (np.abs(g[20:] - g[:-20]) <= 2 * sim.TICK * sim.KP_V))
        assert len(still) > 50
        k = still + 20
        np.testing.assert_allclose(p["kv"] * gain * g[k], mgl * np.sin(q[k]), rtol=0.05,
                                   atol=3 * sim.TICK * p["kv"] * gain * sim.KP_V)
