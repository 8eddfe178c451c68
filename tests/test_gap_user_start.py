"""A log without a velocity column that opens with a goal step: its first row is read at rest.

The truth is plain MuJoCo written here (a user's one-joint arm on a ``position`` servo, and the
LEAP-like finger of tests/gap_user_leap.py), logged on 4096 ticks with a goal written right
after each row was read. The line fit through a log's first rows reads the response to the
first goal as motion before the log; the analysis's replay of the TRUE model then started every
log moving (LEAP case 1, kp x0.5 + 0.04 rad offset: 1.36 mrad over six 12 s logs, 5-12 mrad over
each log's first 0.4 s; reading floor 0.67 mrad).
"""

from __future__ import annotations

import pathlib
import sys

import mujoco
import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import gap_user_leap as leap  # noqa: E402

from lowcostdex.gap.dataset import Dataset  # noqa: E402
from lowcostdex.gap.trajectory import Trajectory  # noqa: E402

ARM = """<mujoco><compiler angle="radian"/><option timestep="0.0005"/><worldbody><body name="arm" pos="0 0 0.5">
<joint name="j" type="hinge" axis="0 1 0" range="-2 2" damping="0.05" armature="0.002"/>
<geom type="capsule" fromto="0 0 0 0.15 0 0" size="0.012" mass="0.15"/></body></worldbody>
<actuator><position name="m" joint="j" kp="4" forcerange="-2 2" ctrlrange="-2 2"/></actuator>
</mujoco>"""
TICK = 2 * np.pi / 4096


def _arm_log(goal_of_t, settle: float, seconds: float = 1.0, rate: float = 50.0):
    """Plain MuJoCo: run ``goal_of_t`` (t from the log's first row) for ``settle`` s before the
    log (the goal at -settle..0 is goal_of_t(t) too), then log ``seconds`` at ``rate`` Hz:
    time, goal, quantised position, MuJoCo's velocity at each row."""
    m = mujoco.MjModel.from_xml_string(ARM)
    d = mujoco.MjData(m)
    per_row = int(round(1.0 / rate / m.opt.timestep))
    t = -settle
    while t < -1e-9:
        d.ctrl[0] = goal_of_t(t)
        for _ in range(per_row):
            mujoco.mj_step(m, d)
        t += 1.0 / rate
    rows = []
    for i in range(int(seconds * rate)):
        t = i / rate
        rows.append((t, goal_of_t(t), np.round(d.qpos[0] / TICK) * TICK, d.qvel[0]))
        d.ctrl[0] = goal_of_t(t)  # written right after the row was read
        for _ in range(per_row):
            mujoco.mj_step(m, d)
    return np.array(rows)


def _first_velocity(log: np.ndarray, mid_log: bool = False) -> float:
    t, goal, q, _ = log.T
    tr = Trajectory(name="arm", model="user", time=t, goal=goal[:, None], qpos=q[:, None],
                    joints=("j",), actuators=("m",), meta={"mid_log": True} if mid_log else {})
    ds = Dataset(models={"user": ARM}, trajectories=[tr])
    return float(ds.trajectories[0].qvel[0, 0])


def test_a_log_opening_with_a_step_from_rest_starts_at_rest():
    """The joint hangs at rest under goal 0 (static sag settled), the log's first goal is
    0.6 rad: its first rows move fast toward it; the velocity at the first row is 0."""
    log = _arm_log(lambda t: 0.6 if t >= 0 else 0.0, settle=2.0)
    v_true = log[0, 3]
    assert abs(v_true) < 1e-3 and abs(log[2, 2] - log[0, 2]) > 0.05  # rest, then a fast move
    assert abs(_first_velocity(log) - v_true) < 0.1  # rad/s; the line fit gave > 1


def test_a_joint_tracking_a_ramp_when_its_log_began_keeps_its_speed():
    """A servo following a -0.5 rad/s ramp for 2 s before the log (steady, behind its goal and
    sagging away from it): the first goal is ahead of the first reading in the direction of
    motion, as after a step, but the motion is steady: the line fit's speed is kept."""
    log = _arm_log(lambda t: 1.0 - 0.5 * (t + 2.0), settle=2.0)
    v_true = log[0, 3]
    assert v_true == pytest.approx(-0.5, abs=0.05) and log[0, 2] - log[0, 1] > 0.02
    assert _first_velocity(log) == pytest.approx(v_true, abs=0.1)


def test_a_piece_cut_from_inside_a_log_keeps_its_line_fit():
    """The same step log marked as a piece after a gap (its first row inside the log, where
    the joint may be moving): not set to rest."""
    log = _arm_log(lambda t: 0.6 if t >= 0 else 0.0, settle=2.0)
    assert abs(_first_velocity(log, mid_log=True)) > 0.5


def test_the_leap_finger_replays_from_rest_at_each_logs_start(tmp_path):
    """LEAP case 1's robot (kp x0.5 on every servo, +0.04 rad on the if_mcp reading) replayed by
    the analysis with its true model, open loop from each log's first row: the first 0.4 s stay
    within 3 reading floors and whole logs within 1.5 (measured: 1.9-2.5 and 1.24-1.44 floors;
    6.2-10.7 and 2.3-3.6 when the first rows' line fit started each log moving)."""
    from lowcostdex.gap import load_dataset
    from lowcostdex.gap.dataset import Window
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.sim.effects import AppliedEffect

    leap.write_user_folder(tmp_path, seed=0, n_logs=3, seconds=4.0)
    ds = load_dataset(tmp_path / "logs", model=str(tmp_path / "leap_finger.xml"))
    wins = [Window(i, 0, len(tr.time), 0) for i, tr in enumerate(ds.trajectories)]
    truth = [AppliedEffect("gain_error", leap.JOINTS, {"scale": np.full(4, leap.GAIN)}),
             AppliedEffect("position_offset", leap.JOINTS,
                           {"offset": np.array([0.0, leap.OFFSET, 0.0, 0.0])})]
    (pred,), _ = Replayer(ds, ["gain_error", "position_offset"], nthread=1).run(wins, [truth])
    for w, p in zip(wins, pred, strict=True):
        q = ds.trajectories[w.traj].qpos
        first = np.sqrt(np.mean((p[:20] - q[:20]) ** 2))  # the first 0.4 s (50 Hz)
        whole = np.sqrt(np.mean((p - q) ** 2))
        assert first < 3 * leap.FLOOR and whole < 1.5 * leap.FLOOR, (w.traj, first, whole)
