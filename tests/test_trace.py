"""Driver logs (hardware.trace) are valid gap-analysis logs of what reached the motors."""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.hardware.backend import make_dynamixel_bus, robot_hand
from lowcostdex.hardware.emulator import emulated_dclaw
from lowcostdex.hardware.hands import dclaw_spec
from lowcostdex.hardware.robot import Robot, RobotConfig
from lowcostdex.hardware.trace import excite
from lowcostdex.sim.gap import read_log
from lowcostdex.sim.models.dclaw import build_dclaw

JOINTS = ("ff_top", "ff_middle", "ff_bottom")


def test_excitation_log_round_trips_and_matches_the_device(tmp_path):
    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(0))
    h = robot_hand(hand, model)
    robot = Robot(h, make_dynamixel_bus(h, chain.port(), model), RobotConfig(control_period=0.02))
    t = np.arange(50) * 0.02
    goals = np.stack([0.3 * np.sin(2 * np.pi * t), -0.4 + 0.2 * (t > 0.5), 0.5 * (t > 0.3)], 1)
    goals[10, 0] = 5.0  # outside the limits: the gate clips it and the log says so
    with robot:
        path = excite(robot, JOINTS, goals, tmp_path / "trace.csv")
        final = robot.read().position[robot.index(JOINTS)]
    traj = read_log(path)
    assert traj.actuators == JOINTS and traj.joints == JOINTS
    assert len(traj) == len(goals)
    np.testing.assert_allclose(np.diff(traj.time)[1:], 0.02, atol=1e-3)  # the first tick is short
    high = np.array([hand.joint(j).high for j in JOINTS])
    assert np.all(traj.goal <= high + 1e-9)
    assert traj.goal[10, 0] < 1.0
    # the last logged goal is what the device received (motor ticks back to joint angles)
    _, ticks = chain.goal_log.positions(10)  # ff_top's motor
    q = hand.joint("ff_top").calibration.to_joint(ticks[-1] * 2 * np.pi / 4096)
    assert q == pytest.approx(traj.goal[-1, 0], abs=2 * np.pi / 4096)
    assert np.all(np.isfinite(traj.qpos)) and np.abs(final - traj.goal[-1]).max() < 0.05
    for name in ("current", "voltage", "temperature"):
        assert traj.channels[name].shape == (len(goals), 3)


def test_record_log_and_model_commands_feed_the_gap_analysis(tmp_path):
    from lowcostdex.cli import main
    from lowcostdex.sim.gap import load_dataset

    xml = tmp_path / "finger.xml"
    assert main(["model", "dclaw", "--station", "none", "--fingers", "ff", "--no-thermal",
                 "--out", str(xml)]) == 0
    assert main(["record-log", "--port", "emulated", "--logs", "2", "--seconds", "1.5",
                 "--out", str(tmp_path / "logs")]) == 0
    logs = sorted((tmp_path / "logs").glob("log_*.csv"))
    assert len(logs) == 2
    ds = load_dataset([str(p) for p in logs], model=str(xml))  # columns match the model
    assert len(ds.trajectories) == 2
