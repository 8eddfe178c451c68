"""The Robot on a flaky emulated bus, checked on the device side (``chain.goal_audit``: every goal
a motor accepted against its true joint position).

The motion bound acts on fresh state only: a goal is computed from the position read in the
same control cycle, and a joint whose read failed gets no new goal (it holds)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.hardware.backend import make_dynamixel_bus
from lowcostdex.hardware.emulator import FaultConfig, emulated_dclaw
from lowcostdex.hardware.hands import dclaw_spec
from lowcostdex.hardware.robot import Robot, RobotConfig
from lowcostdex.hardware.safety import UnsafeCommand

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


def watch_joints(chain, max_step: float) -> None:
    """Count, on the device, goals beyond the motion bound over the position sampled for the
    cycle's read (+ one tick: the reading and the goal are both whole ticks) and beyond the
    joint limits (+ half a tick: the goal on the wire is a whole tick)."""
    for j in HAND.joints:
        chain.goal_audit.watch(j.motor_id, max_step + TICK, j.low - TICK / 2, j.high + TICK / 2)


def soak(faults: FaultConfig, cycles: int, seed: int):
    """The Robot under ``faults`` for ``cycles`` control steps of wild goals: uniform over
    +-2 rad (outside every finger's limits, many motion bounds away), pushes of every joint
    past its limits, NaN now and then."""
    chain, robot = connected_robot(RobotConfig(max_invalid_reads=20), seed=seed)
    watch_joints(chain, MAX_STEP)
    chain.faults = faults
    rng = np.random.default_rng(seed)
    rejected = 0
    for cycle in range(cycles):
        goal = rng.uniform(-2.0, 2.0, size=9)
        if cycle % 100 >= 80:  # 20 steps pushing every joint to one side, past its limits
            goal[:] = 3.0 if cycle % 200 >= 100 else -3.0
        if cycle % 97 == 0:
            goal[rng.integers(9)] = np.nan
            rejected += 1
            with pytest.raises(UnsafeCommand):
                robot.step(goal)
            robot.wait()
            robot.read()
            continue
        robot.step(goal)
    assert robot.metrics.rejected == rejected
    return chain, robot


FAULT_MIXES = {
    "drop+corrupt": FaultConfig(drop=0.2, corrupt=0.05),
    "late+corrupt": FaultConfig(late=0.2, corrupt=0.05),
    "all": FaultConfig(drop=0.2, corrupt=0.05, late=0.05),
}


def check_device_side(chain, robot, cycles: int) -> None:
    audit = chain.goal_audit
    ids = [j.motor_id for j in HAND.joints]
    assert audit.violations == 0, (audit.lead_violations, audit.limit_violations)
    # the bounds were exercised: goals at the limits and at the motion bound reached the motors
    for j in HAND.joints:
        assert audit.high[j.motor_id] > j.high - TICK and audit.low[j.motor_id] < j.low + TICK
        assert audit.max_read_lead[j.motor_id] > MAX_STEP - TICK
    # the lead over the position at arrival adds what the motor moved since the sample (up to
    # tens of ms when a read was retried); before reads had to be fresh it reached 2.3 x
    assert max(audit.max_lead[i] for i in ids) < 1.5 * MAX_STEP
    # the faults really happened, and the Robot held rather than stopped
    assert robot.metrics.invalid_reads > 0.02 * 10 * cycles
    assert robot.metrics.holds > 0.005 * 9 * cycles
    assert sum(audit.count[i] for i in ids) > 0.9 * 9 * cycles
    # nothing the firmware does on its own: no watchdog trip, no hardware error
    assert not chain.events


@pytest.mark.parametrize("mix", FAULT_MIXES)
def test_soak_2000_cycles_no_goal_beyond_the_bound_or_limits_reaches_a_motor(mix):
    chain, robot = soak(FAULT_MIXES[mix], 2000, seed=11)
    check_device_side(chain, robot, 2000)


@pytest.mark.slow
def test_soak_10k_cycles_no_goal_beyond_the_bound_or_limits_reaches_a_motor():
    chain, robot = soak(FAULT_MIXES["all"], 10_000, seed=12)
    check_device_side(chain, robot, 10_000)
