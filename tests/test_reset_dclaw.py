"""Auto-reset on the emulated D'Claw, verified on the device side (true joint angles of the
emulator's physics, the valve motor's torque state): success from random tangles, retries with
disentangle, joints pushed past their policy limits, and a bounded ResetFailed on a jammed valve."""

from __future__ import annotations

import math
import time

import mujoco
import numpy as np
import pytest

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.backend import default_effects, make_dynamixel_bus
from lowcostdex.hardware.robot.reset import ResetConfig, ResetFailed
from lowcostdex.hardware.robot.reset_dclaw import DClawReset
from lowcostdex.hardware.robot.reset_trials import reset_trials
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE
from lowcostdex.sim.envs.task import wrap_angle

HAND = dclaw_spec()


@pytest.fixture
def claw():
    chain = emulated_dclaw("valve", hand=HAND, effects=default_effects(HAND.joint_names),
                           rng=np.random.default_rng(0))
    robot = Robot(HAND, make_dynamixel_bus(HAND, chain.port(), chain.plant.model), RobotConfig())
    robot.connect()
    yield chain, robot
    robot.close()


def true_angles(chain, names) -> np.ndarray:
    m, d = chain.plant.model, chain.plant.data
    return np.array([d.qpos[m.jnt_qposadr[m.joint(n).id]] for n in names])


def test_reset_succeeds_from_random_tangles(claw):
    chain, robot = claw
    reset = DClawReset(robot)
    rng = np.random.default_rng(7)
    checks = []

    def check(k, ok, duration):
        checks.append((ok, true_angles(chain, HAND.joint_names), chain.motors[50].torque_on))

    stats = reset_trials(robot, reset, RESET_POSE, 8, rng, on_trial=check)
    assert stats.success_rate == 1.0, stats.failures
    for _ok, q, valve_torque in checks:
        assert np.max(np.abs(q - RESET_POSE)) < ResetConfig().tolerance  # device side
        assert not valve_torque  # the valve is released for the episode
    assert max(stats.times) < 30.0
    assert robot.metrics.resets == 8 and robot.metrics.reset_failures == 0


def test_valve_is_driven_to_its_start_angle_then_released(claw):
    chain, robot = claw
    chain.plant.data.qpos[chain.plant.model.jnt_qposadr[chain.plant.model.joint("valve").id]] = 2.5
    report = DClawReset(robot)(RESET_POSE, -0.7)
    assert report.success and [s.name for s in report.stages][-1] == "valve"
    valve = true_angles(chain, ["valve"])[0]
    assert abs(wrap_angle(valve + 0.7)) < ResetConfig().valve_tolerance
    assert not chain.motors[50].torque_on


def test_a_finger_held_during_the_first_attempt_is_freed_by_a_retry(claw):
    """Something holds the middle finger (a hand, a snag) for the first 3 s: the first attempt
    fails its verification, the disentangle + retry succeeds."""
    chain, robot = claw
    m = chain.plant.model
    dof = m.jnt_dofadr[m.joint("mf_middle").id]
    release = chain.now + 3.0

    def snag(c):
        c.plant.data.qfrc_applied[dof] = 6.0 if c.physics_time < release else 0.0

    chain.add_step_hook(snag)
    report = DClawReset(robot)(RESET_POSE, 0.0)
    assert report.success and report.attempts == 2
    assert any(s.name.startswith("disentangle") for s in report.stages)
    assert np.max(np.abs(true_angles(chain, HAND.joint_names) - RESET_POSE)) < math.radians(5)


def test_joint_pushed_past_its_policy_limit_is_pulled_back(claw):
    chain, robot = claw
    robot.torque(False)
    m, d = chain.plant.model, chain.plant.data
    d.qpos[m.jnt_qposadr[m.joint("th_bottom").id]] = 1.85  # limit pi/2; mechanical stop 2.0
    mujoco.mj_forward(m, d)
    robot.rest(0.3)
    assert robot.present[robot.index(["th_bottom"])[0]] > HAND.joint("th_bottom").high
    report = DClawReset(robot)(RESET_POSE, 0.0)
    assert report.success
    assert np.all(np.abs(true_angles(chain, HAND.joint_names) - RESET_POSE) < math.radians(5))


def test_jammed_valve_ends_in_reset_failed_within_a_bounded_time(claw):
    chain, robot = claw
    m = chain.plant.model
    m.jnt_limited[m.joint("valve").id] = 1  # seized valve (the hinge is normally free)
    m.jnt_range[m.joint("valve").id] = [-0.02, 0.02]
    config = ResetConfig(max_retries=2, valve_timeout=4.0)
    t_bus, t_wall = chain.now, time.monotonic()
    with pytest.raises(ResetFailed, match=r"stage 'valve' after 3 attempt\(s\): valve off by"):
        DClawReset(robot, config)(RESET_POSE, 1.5)
    bus_time = chain.now - t_bus
    # bound: every attempt is at most the finger moves plus one valve timeout plus settling
    assert bus_time < 3 * (3 * config.move_timeout + config.valve_timeout + 4.0)
    assert time.monotonic() - t_wall < 60.0
    assert not chain.motors[50].torque_on  # released, not left straining
    assert robot.metrics.reset_failures == 1 and robot.metrics.resets == 0


def test_robel_baseline_runs_through_the_same_gate_and_never_blocks(claw):
    """ROBEL's sequence (the benchmark baseline, bench/reset.py) resets a tangle, and raises
    instead of waiting on input() when it cannot."""
    from lowcostdex.hardware.robot.reset_robel import RobelReset

    chain, robot = claw
    stats = reset_trials(robot, RobelReset(robot), RESET_POSE, 2, np.random.default_rng(3))
    assert stats.success_rate == 1.0
    m = chain.plant.model
    m.jnt_range[m.joint("ff_middle").id] = [0.5, 0.6]  # a finger stuck inward
    with pytest.raises(ResetFailed, match="ROBEL would block on input"):
        RobelReset(robot, ResetConfig(max_retries=1))(RESET_POSE, 0.0)
