"""The Robot on a flaky emulated bus, checked on the device side (``chain.goal_audit``: every goal
a motor accepted against its true joint position).

The motion bound acts on fresh state only: a goal is computed from the position read in the
same control cycle, and a joint whose read failed gets no new goal (it holds)."""

from __future__ import annotations

import math

import numpy as np

from lowcostdex.hardware.backend import make_dynamixel_bus
from lowcostdex.hardware.emulator import FaultConfig, emulated_dclaw
from lowcostdex.hardware.hands import dclaw_spec
from lowcostdex.hardware.robot import Robot, RobotConfig

HAND = dclaw_spec()
TICK = 2 * math.pi / 4096  # one encoder tick of an X-series servo [rad]
# D'Claw spec: max_velocity 2 pi / 3 rad/s, control period 0.1 s
MAX_STEP = 2 * math.pi / 3 * 0.1


def connected_robot(config: RobotConfig | None = None, seed: int = 0):
    chain = emulated_dclaw("valve", hand=HAND, rng=np.random.default_rng(seed))
    bus = make_dynamixel_bus(HAND, chain.port(), chain.plant.model, handle_signals=False)
    robot = Robot(HAND, bus, config or RobotConfig())
    robot.connect()
    robot.torque(True, HAND.joint_names)
    return chain, robot


def test_a_failed_read_holds_instead_of_bounding_around_a_stale_position():
    chain, robot = connected_robot()
    k = robot.index(["ff_middle"])[0]
    p0 = robot.read().position.copy()
    goal = p0[:9].copy()
    goal[k] += MAX_STEP  # one full step outward ...
    robot.step(goal)  # ... the motor gets there within the period, then the read
    chain.faults = FaultConfig(drop=1.0)  # every status packet lost from here on
    robot.wait()
    assert not robot.read().valid.any()
    n = sum(chain.goal_audit.count.values())
    back = p0[:9].copy()
    back[k] -= MAX_STEP  # bounded around the stale p0 this would lead the motor by 2 steps
    sent = robot.send(back)
    assert sum(chain.goal_audit.count.values()) == n  # device side: nothing arrived
    assert robot.held[:9].all() and robot.metrics.holds == 9
    assert robot.telemetry()["held"][:9].all() and robot.telemetry()["holds"] == 9.0
    np.testing.assert_allclose(sent, robot.last_sent[:9])  # the goals in force, unchanged
    assert sent[k] == goal[k]
    chain.faults = FaultConfig()
    sent = robot.send(back)  # a read in this cycle succeeds: bounded around it, sent
    assert not robot.held.any()
    q = chain.plant.qpos[chain.plant.model.joint("ff_middle").qposadr[0]]
    assert abs(sent[k] - (q - MAX_STEP)) < 2 * TICK
    assert chain.goal_audit.max_read_lead[11] <= MAX_STEP + TICK
    robot.close()


def test_only_the_joints_without_a_fresh_read_hold():
    chain, robot = connected_robot()
    chain.kill(21)  # mf_middle's motor goes silent
    robot.read()
    n_mf = chain.goal_audit.count.get(21, 0)
    n_ff = chain.goal_audit.count[11]
    present = robot.present[:9]
    sent = robot.send(present + 0.05)
    held = robot.held[:9]
    assert held.tolist() == [j.name == "mf_middle" for j in HAND.joints]
    assert chain.goal_audit.count.get(21, 0) == n_mf and chain.goal_audit.count[11] == n_ff + 1
    np.testing.assert_allclose(np.delete(sent - present, 4), 0.05, atol=1e-12)
