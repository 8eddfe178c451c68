"""Safety constants no other test pinned (``bench/mutate_constants.py`` +1 survivors at 5d44167).

- ``ThermalConfig.max_pause`` 3600 s: docs/troubleshooting.md ("a pause longer than an hour stops
  the run with a message") and docs/hardware.md ("``max_pause`` (1 h) raises ``ThermalTimeout``").
- ``ThermalConfig.poll_interval`` 1 s: the pause reads the temperatures once a second; the
  stuck-sensor model (``ThermalGuard._check_stuck``) integrates by explicit Euler between reads,
  written for reads 0.1-1 s apart against a winding time constant of ~100 s.
- ``safety.UNIT_MARGIN`` 2 pi rad: "a goal more than a full turn outside its joint's range is not a
  goal in rad" (one turn = 2 pi rad); on the D'Claw (joint limits typed below) a 30 deg goal given
  in degrees is refused, while a goal a little under a turn beyond the limit is clipped.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.hardware.robot.guards import ThermalConfig, ThermalGuard
from lowcostdex.hardware.robot.robot import Robot, ThermalTimeout
from lowcostdex.hardware.robot.safety import UnsafeCommand, check_units, clip_goal


class _Clock:
    def __init__(self):
        self.t, self.slept = 1000.0, []

    def now(self):
        return self.t

    def sleep(self, s):
        self.slept.append(s)
        self.t += s


class _State:
    def __init__(self, temps):
        self.temperature = np.array(temps, float)
        self.temperature_fault = np.zeros(len(temps), bool)


class _Bus:
    def __init__(self):
        self.torque = []

    def set_torque(self, on):
        self.torque.append(on)


class _Hand:
    """What ``Robot.pause_if_hot`` uses of a robot: a bus, a clock, reads, the thermal guard
    (real, default ThermalConfig: limit 80 deg C, resume below 50)."""

    def __init__(self, temps):
        self.temps = list(temps)  # one reading per read(); the last one repeats
        self.reads = 0
        self.clock, self.bus = _Clock(), _Bus()
        self.joint_names = ("a", "b")
        self.thermal = ThermalGuard(ThermalConfig(), limit=80.0, names=self.joint_names)
        self.thermal.pause_pending = True
        self._torque = np.array([True, True])
        self.metrics = type("M", (), {"pauses": []})()
        self.rate = type("R", (), {"restart": lambda self: None})()
        self.enabled = []

    def read(self):
        t = self.temps[min(self.reads, len(self.temps) - 1)]
        self.reads += 1
        return _State(t)

    def torque(self, on, names):
        self.enabled.append((on, list(names)))


def test_a_pause_that_never_cools_stops_the_run_after_one_hour_of_one_second_reads():
    hand = _Hand([[66.0, 40.0]])  # a broken fan: 66 deg C forever
    with pytest.raises(ThermalTimeout, match=r"after 3600 s pause \(resume below 50.0"):
        Robot.pause_if_hot(hand)
    assert hand.bus.torque == [False]  # the hand went limp first (pause_mode torque_off)
    assert set(hand.clock.slept) == {1.0}  # read once a second
    # timed out at the first read more than an hour after the start
    assert hand.clock.t - 1000.0 == pytest.approx(3601.0)
    assert len(hand.clock.slept) == 3601


def test_a_pause_ends_at_the_first_one_second_read_below_resume():
    # 60 s of 55 deg C, then 49: the pause lasts 61 reads' worth of seconds, then torque back on
    hand = _Hand([[66.0, 40.0]] + [[55.0, 40.0]] * 60 + [[49.0, 40.0]])
    record = Robot.pause_if_hot(hand)
    assert record.duration == pytest.approx(61.0) and record.end_max == 49.0
    assert record.hottest == "a" and record.peak == 66.0
    assert hand.enabled == [(True, ["a", "b"])] and not hand.thermal.pause_pending


# D'Claw joint ranges [rad] of ROBEL's MJCF (/work/shared/reference/01-hardware.md 1.9): top
# (abduction) -0.45..1.35, middle and bottom +-2
LOW, HIGH = np.array([-0.45, -2.0, -2.0]), np.array([1.35, 2.0, 2.0])
NAMES = ("top", "middle", "bottom")


def test_a_goal_a_full_turn_beyond_a_limit_is_refused_as_not_rad_and_less_is_clipped():
    turn = 2 * math.pi  # one turn [rad]
    for joint in range(3):
        under = np.zeros(3)
        under[joint] = HIGH[joint] + turn - 0.01
        check_units(under, LOW, HIGH, NAMES)  # within a turn: a (wild) goal in rad
        r = clip_goal(under, LOW, HIGH, np.zeros(3), np.full(3, 10.0))
        assert r.goal[joint] == HIGH[joint]  # ... clipped to the limit
        over = np.zeros(3)
        over[joint] = HIGH[joint] + turn + 0.01
        with pytest.raises(UnsafeCommand, match=f"{NAMES[joint]}=.*degrees or ticks"):
            check_units(over, LOW, HIGH, NAMES)
        below = np.zeros(3)
        below[joint] = LOW[joint] - turn - 0.01
        with pytest.raises(UnsafeCommand, match="far outside the joint limits"):
            check_units(below, LOW, HIGH, NAMES)
        below[joint] = LOW[joint] - turn + 0.01
        check_units(below, LOW, HIGH, NAMES)
    # 30 deg typed as degrees on the top joint (limit 1.35 rad): 30 > 1.35 + 2 pi = 7.63
    with pytest.raises(UnsafeCommand):
        check_units(np.array([30.0, 0.0, 0.0]), LOW, HIGH, NAMES)


# ---- RobotConfig: what a user reads in its docstring, on the emulated D'Claw --------------------
# (no outside number exists for these two: they are the project's documented choices; pinned
# here at the behaviour the docstring states, one step either side)

def _dclaw():
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.emulated.chain import emulated_dclaw
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus
    from lowcostdex.hardware.robot.robot import RobotConfig

    hand = dclaw_spec()
    chain = emulated_dclaw("valve", hand=hand, rng=np.random.default_rng(0))
    robot = Robot(hand, make_dynamixel_bus(hand, chain.port(), chain.plant.model,
                                           handle_signals=False), RobotConfig())
    robot.connect()
    return hand, chain, robot


def test_a_dead_motor_stops_the_default_robot_at_its_sixth_missed_read():
    # RobotConfig.max_invalid_reads 5: "consecutive reads a motor may miss before read raises"
    from lowcostdex.hardware.bus import BusError

    hand, chain, robot = _dclaw()
    chain.kill(hand.joints[4].motor_id)
    for _ in range(5):
        robot.read()
    with pytest.raises(BusError, match=f"{hand.joints[4].name} for 6 consecutive reads"):
        robot.read()


def test_a_persistent_hardware_error_gets_two_reboots_then_stops_the_run():
    # RobotConfig.max_reboots 2: "reboots per motor per session when recovering from hardware
    # errors"; the emulated firmware clears the error at a reboot, so it is latched again
    from lowcostdex.hardware.dynamixel.protocol import HardwareError
    from lowcostdex.hardware.robot.robot import MotorFault

    hand, chain, robot = _dclaw()
    j = hand.joints[1]
    for _ in range(2):
        chain.inject_hardware_error(j.motor_id, HardwareError.OVERLOAD)
        assert robot.recover_faults() == [j.name]
    chain.inject_hardware_error(j.motor_id, HardwareError.OVERLOAD)
    with pytest.raises(MotorFault, match="persists after 2 reboots"):
        robot.recover_faults()
    assert robot.metrics.reboots == 2


def test_the_unit_and_number_refusals_read_in_full():
    # what a user reads when a goal is not numbers, or is far outside the limits (message-
    # dropping / case / separator mutants of check_finite and check_units survived the safety
    # group's tests at 0ea062b)
    from lowcostdex.hardware.robot.safety import check_finite

    with pytest.raises(UnsafeCommand) as e:
        check_finite(["a", 0.0, 0.0], NAMES)
    assert str(e.value) == ("goal ['a', 0.0, 0.0] is not 3 numbers [rad] for joints top, middle, "
                            "bottom; nothing sent")
    with pytest.raises(UnsafeCommand) as e:
        check_units(np.array([30.0, 0.0, -9.0]), LOW, HIGH, NAMES)
    assert str(e.value) == ("goal far outside the joint limits: top=30 (limits -0.45..1.35), "
                            "bottom=-9 (limits -2..2); goals are in rad (degrees or ticks?); "
                            "nothing sent")


def test_a_goal_referenced_bound_lets_the_goal_lead_a_blocked_joint_by_four_steps():
    # RobotConfig.max_lead 4 [motion-bound steps] ("the goal's lead over the present position is
    # then bounded by max_lead steps"): a middle joint blocked 0.02 rad behind where it stands,
    # its goal 1.5 rad past the obstacle. While the current guard relaxes it (its step 0.02 rad
    # for 20 steps) the goal leads by 4 x 0.02; then by 4 full motion-bound steps, no further
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.emulated.chain import emulated_dclaw
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus
    from lowcostdex.hardware.robot.robot import RobotConfig

    hand = dclaw_spec()
    chain = emulated_dclaw("valve", hand=hand, rng=np.random.default_rng(0))
    robot = Robot(hand, make_dynamixel_bus(hand, chain.port(), chain.plant.model,
                                           handle_signals=False),
                  RobotConfig(motion_reference="goal"))
    robot.connect()
    robot.torque(True, hand.joint_names)
    robot.read()
    m = chain.plant.model
    k = robot.index(["ff_middle"])[0]
    p0 = robot.present[k]
    m.jnt_range[m.joint("ff_middle").id] = [p0 - 0.02, 2.0]  # the obstacle
    goal = robot.present[:9].copy()
    goal[k] = p0 - 1.5
    leads = []
    for _ in range(40):
        robot.step(goal)
        leads.append(float(robot.present[k] - robot.last_sent[k]))
    step = float(robot.max_step[k])  # its motion bound per 0.1 s step (0.209 rad)
    assert max(leads) == pytest.approx(4 * step, abs=0.005)
    assert min(x for x in leads[5:]) == pytest.approx(4 * 0.02, abs=0.005)
