"""The Robot on the emulated D'Claw through the real dynamixel_sdk code path, checked on the
device side: what reached the motors (the emulator's goal log), what the firmware did (events,
Hardware Error Status), and the physics (true joint angles and winding temperatures)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.backend import make_dynamixel_bus
from lowcostdex.hardware.robot.guards import CurrentConfig
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.hardware.robot.safety import UnsafeCommand
from lowcostdex.sim import servo
from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE
from lowcostdex.sim.registry import register_envs

HAND = dclaw_spec()
TICKS = 4096 / (2 * np.pi)
MIDDLES = ("ff_middle", "mf_middle", "th_middle")


def connected_robot(config: RobotConfig = RobotConfig(), **chain_kw):
    chain = emulated_dclaw("valve", hand=HAND, rng=np.random.default_rng(0), **chain_kw)
    bus = make_dynamixel_bus(HAND, chain.port(), chain.plant.model)
    robot = Robot(HAND, bus, config)
    robot.connect()
    return chain, robot


def goal_ticks(joint: str, q: np.ndarray) -> np.ndarray:
    j = HAND.joint(joint)
    return np.rint(np.array([j.calibration.to_motor(x) for x in np.atleast_1d(q)]) * TICKS)


def test_goals_outside_limits_or_motion_bound_never_reach_the_motors():
    chain, robot = connected_robot()
    robot.torque(True, HAND.joint_names)
    robot.read()  # goals are bounded around a position read after torque-on
    rng = np.random.default_rng(3)
    n_logged = len(chain.goal_log)
    presents, sents = [], []
    for _ in range(30):  # wild goals: far outside the limits, big jumps
        goal = rng.uniform(-4.0, 4.0, size=9)
        presents.append(robot.present[:9].copy())
        robot.step(goal)
        sents.append(robot.last_sent[:9].copy())
    assert len(chain.goal_log) > n_logged
    for k, joint in enumerate(HAND.joints):
        _, ticks = chain.goal_log.positions(joint.motor_id)
        lo, hi = sorted(goal_ticks(joint.name, np.array([joint.low, joint.high])))
        accepted = ticks[-30:]
        assert np.all(accepted >= lo - 1) and np.all(accepted <= hi + 1), joint.name
        # and every accepted goal is within the per-step motion bound of the present position
        sent_ticks = goal_ticks(joint.name, np.array([s[k] for s in sents]))
        np.testing.assert_array_equal(accepted, sent_ticks)
        lead = np.abs(np.array([s[k] - p[k] for s, p in zip(sents, presents, strict=True)]))
        assert np.all(lead <= robot.max_step[k] + 1e-9)
    assert robot.metrics.limit_clips > 0 and robot.metrics.motion_clips > 0
    robot.close()


def test_nan_goal_is_rejected_and_nothing_reaches_the_motors():
    chain, robot = connected_robot()
    robot.torque(True, HAND.joint_names)
    robot.step(RESET_POSE)
    before = len(chain.goal_log)
    for bad in (np.full(9, np.nan), np.r_[RESET_POSE[:8], np.inf], RESET_POSE[:5]):
        with pytest.raises(UnsafeCommand, match="nothing sent"):
            robot.send(bad)
    assert len(chain.goal_log) == before
    assert robot.metrics.rejected == 3
    robot.close()
    assert not any(m.torque_on for m in chain.motors.values())  # torque off on close


def _jam_middles(chain) -> None:
    """An obstacle the middle joints cannot pass inward (stall against it)."""
    m = chain.plant.model
    for n in MIDDLES:
        m.jnt_range[m.joint(n).id] = [-1.2, 0.1]


def _preheat(chain, rise: float) -> None:
    """Start the windings ``rise`` K above ambient (skip the first minutes of a long run)."""
    m, d = chain.plant.model, chain.plant.data
    layout = servo.dcmotor_act_layout(m)
    for a in range(m.nu):
        if layout[a, servo.ACT_THERMAL] >= 0:
            d.act[layout[a, servo.ACT_THERMAL]] = rise


def test_sustained_load_thermal_pause_before_shutdown_then_training_resumes():
    register_envs()
    # The current guard would bound the stall current; switch it off so heat builds up and the
    # thermal guard is what protects the motors.
    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated",
                   robot_config=RobotConfig(current=CurrentConfig(limit=100.0)))
    backend = env.unwrapped.backend
    chain, robot = backend.chain, backend.robot
    _jam_middles(chain)
    _preheat(chain, 32.0)  # 57 deg C
    push = np.tile([0.0, 1.0, 0.0], 3).astype(np.float32)  # middles inward, into the obstacle
    temps, steps_after_pause = [], 0
    for episode in range(12):
        env.reset(seed=episode)
        for _ in range(40):
            _, _, _, _, info = env.step(push)
            temps.append(info["telemetry"]["temperature"])
            steps_after_pause += bool(robot.metrics.pauses)
        if len(robot.metrics.pauses) >= 2:
            break
    temps = np.array(temps)
    limit = robot.thermal.limit
    assert limit == 80.0
    assert len(robot.metrics.pauses) >= 1
    pause = robot.metrics.pauses[0]
    assert pause.peak >= robot.thermal.warn and pause.end_max < robot.thermal.resume
    assert pause.duration > 10.0  # minutes of cooling in virtual time, seconds of wall time
    assert temps.max() < robot.thermal.critical  # never near the firmware shutdown
    assert steps_after_pause >= 40  # training resumed after the pause
    # device side: no motor latched an error or dropped torque on its own
    assert not [e for e in chain.events if e.kind in ("hardware_error", "shutdown")]
    true_temp = servo.winding_temperature(chain.plant.model, chain.plant.data)
    assert true_temp.max() < limit
    metrics = robot.metrics.as_dict()
    assert metrics["pauses"] >= 1 and metrics["pause_time"] == pytest.approx(
        sum(p.duration for p in robot.metrics.pauses))
    env.close()


def test_without_the_guard_the_same_load_trips_the_firmware():
    """Control for the test above: the load is enough to reach the firmware's shutdown."""
    chain = emulated_dclaw("valve", hand=HAND, rng=np.random.default_rng(0))
    # EEPROM limits from the hand's mechanical ranges; the obstacle comes after
    bus = make_dynamixel_bus(HAND, chain.port(), chain.plant.model)
    _jam_middles(chain)
    _preheat(chain, 45.0)  # 70 deg C: the last 10 K that the guard never lets happen
    with bus:
        ids = [HAND.joint(n).motor_id for n in MIDDLES]
        bus.set_torque(True, ids)
        state = bus.read_state()
        k = [bus.ids.index(i) for i in ids]
        for _ in range(600):  # goal 0.5 rad past the obstacle, held (no guard, no pause)
            bus.write_goal_positions(state.position[k] + 0.6, ids)
            bus.sleep(0.1)
            if any(e.kind == "shutdown" for e in chain.events):
                break
        assert any(e.kind == "shutdown" and "overheating" in e.detail for e in chain.events)
        assert np.all(bus.read_state().hardware_error[k] & 0x04)  # Overheating latched
