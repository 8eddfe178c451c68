"""Issue 12 item 2's soak with the guards acting: 10^4 control cycles of wild goals on a flaky
emulated bus (20 % dropped, 5 % corrupt, 5 % late status packets) during which motors reach
their critical temperature (the thermal guard relaxes them) and the host falls silent (the
motors' Bus Watchdog stops them), each several times. Checked on the device side
(``chain.goal_audit``: every goal a motor accepted against its true position): 0 goals beyond
the motion bound or the joint limits, and the guards' actions seen on the motors themselves
(torque off at once on the hot one, watchdog trips on every finger motor).
``tests/test_robot_faults.py`` holds the soak without the guards and each guard's scenario.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_robot_faults import (
    HAND,
    MAX_STEP,
    TICK,
    connected_robot,
    heat,
    track_speed,
    watch_joints,
)

from lowcostdex.hardware.bus import BusError, WatchdogTripped
from lowcostdex.hardware.emulated.chain import FaultConfig
from lowcostdex.hardware.robot.robot import RobotConfig
from lowcostdex.hardware.robot.safety import UnsafeCommand

CYCLES = 10_000
EVENT_EVERY = 1000  # a hot motor at cycle 1000 k + 250, a silent host at 1000 k + 750


FAILED_ENABLES = [0]  # torque re-enables that raised BusError: must stay 0 (8-15 of 20 before
# 030057e, when the set-up writes had 4 tries and each caller retried)
HOLDS_PAST_LIMIT: list[float] = []  # torque-on goals past a limit: |goal - true position| [rad]
TORQUE_ON: list[tuple[float, float]] = []  # every torque-on goal: (|goal - true|, age) [rad, s]


def _torque_on(robot, chain) -> None:
    """Re-enable every finger motor (goal := present), again when a write was lost 4 times.
    A joint the watchdog stopped (or the thermal guard let go) past its policy limit gets its
    own position as goal there: such goals are counted apart, each with its distance from the
    motor's true position at receipt (a hold, not a motion)."""
    _recorded_holds(chain, lambda: _enable(robot))


def _enable(robot) -> None:
    """As the env's watchdog resume: every finger joint the thermal guard has not relaxed."""
    names = [n for n, r in zip(HAND.joint_names, robot.thermal.relaxed[:9], strict=True) if not r]
    for _ in range(20):
        try:
            robot.torque(True, names)
            return
        except BusError:
            FAILED_ENABLES[0] += 1
    raise AssertionError("torque could not be re-enabled in 20 tries")


def _recorded_holds(chain, action) -> None:
    audit = chain.goal_audit
    before, n = dict(audit.limit_violations), sum(audit.count.values())
    action()
    new = sum(audit.count.values()) - n
    receipts = list(audit.recent)[-new:] if new else []
    TORQUE_ON.extend((abs(goal - true), age) for _, _, goal, true, _, age in receipts)
    if audit.limit_violations != before:
        for _, motor_id, goal, true, _, _ in receipts:
            low, high = audit._bounds[motor_id][1:]
            if not low <= goal <= high:
                HOLDS_PAST_LIMIT.append(abs(goal - true))
        for k, v in before.items():  # kept apart from the soak's count
            audit.limit_violations[k] = v


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 21])
def test_soak_10k_cycles_through_thermal_relaxations_and_watchdog_trips(seed):
    """Seed 0 failed on c3ff5c5 (a torque-on goal 0.33 rad from its motor), seed 21 once under
    pytest on e9b95ae (0.084 rad beyond the bound at arrival), both the same path."""
    FAILED_ENABLES[0] = 0
    HOLDS_PAST_LIMIT.clear()
    TORQUE_ON.clear()
    chain, robot = connected_robot(RobotConfig(max_invalid_reads=20, motor_speed=None), seed=seed)
    watch_joints(chain, MAX_STEP)
    fastest = track_speed(chain)
    chain.faults = FaultConfig(drop=0.2, corrupt=0.05, late=0.05)
    rng = np.random.default_rng(seed)
    limp_seen, hot = 0, None
    for cycle in range(CYCLES):
        phase = cycle % EVENT_EVERY
        if phase == 250:  # a motor at 74 deg C: above the X430's 80 - 7 critical margin
            hot = HAND.joints[int(rng.integers(9))]
            heat(chain, hot.name, 74.0)
        if hot is not None and phase == 260:  # relaxed at once: seen on the motor
            limp_seen += not chain.motors[hot.motor_id].torque_on
        if hot is not None and phase == 400:  # cooled (a fan): the pause ends, torque back on
            heat(chain, hot.name, 35.0)

            def pause() -> None:
                try:
                    robot.pause_if_hot()
                except BusError:  # its torque re-enable lost a write 4 times
                    FAILED_ENABLES[0] += 1

            _recorded_holds(chain, pause)
            _torque_on(robot, chain)
            hot = None
        if phase == 750:  # the host falls silent for 0.3 s (watchdog 100 ms)
            chain_port = robot.bus.port
            chain_port.sleep(0.3)
        goal = rng.uniform(-2.0, 2.0, size=9)
        if cycle % 100 >= 80:  # pushes past the limits
            goal[:] = 3.0 if cycle % 200 >= 100 else -3.0
        try:
            robot.step(goal)
        except WatchdogTripped:
            _torque_on(robot, chain)  # as the env after a trip: re-armed where they stopped
        except UnsafeCommand:  # pragma: no cover - no NaN goals here
            raise
    audit = chain.goal_audit
    ids = [j.motor_id for j in HAND.joints]
    # every goal sent by a control step: 0 beyond the bound or the limits
    assert audit.violations == 0, (audit.lead_violations, audit.limit_violations)
    # torque-on goals (goal := present; past a limit they are holds inside the motors' EEPROM
    # limits): each set from a read of that motor just before it (sample to arrival <= 3 ms:
    # a 1 ms USB frame each way and the wire time), where the motor truly is within one tick
    # and what the fastest joint moves in that time and one physics step. Before the driver's
    # torque_on module one read served all 9 motors' goals and their writes' retries: seed 0's
    # motor 21 got a goal 0.33 rad from where it had fallen, 120 ms after the reading.
    dt = chain.plant.model.opt.timestep
    assert TORQUE_ON and max(age for _, age in TORQUE_ON) <= 3e-3
    assert all(d <= TICK + fastest[0] * (age + dt) for d, age in TORQUE_ON)
    assert all(d <= TICK + fastest[0] * (3e-3 + dt) for d in HOLDS_PAST_LIMIT)
    assert max(audit.arrival_excess[i] for i in ids) <= fastest[0] * chain.plant.model.opt.timestep
    events = CYCLES // EVENT_EVERY
    assert limp_seen == events and robot.metrics.thermal_relaxations >= events
    trips = [e for e in chain.events if e.kind == "watchdog"]
    assert {e.motor_id for e in trips} == set(ids) and len(trips) >= events * len(ids)
    # the bounds were exercised and the faults happened
    for j in HAND.joints:
        assert audit.high[j.motor_id] > j.high - TICK and audit.low[j.motor_id] < j.low + TICK
    assert robot.metrics.invalid_reads > 0.02 * 10 * CYCLES
    assert sum(audit.count[i] for i in ids) > 0.8 * 9 * CYCLES
    # torque on rides out the lossy bus itself (bounded retries in the driver): no caller retry
    assert FAILED_ENABLES[0] == 0
    print(f"torque-on goals {len(TORQUE_ON)} (longest sample to arrival "
          f"{1e3 * max(age for _, age in TORQUE_ON):.2f} ms); "
          f"torque-on holds past a policy limit: {len(HOLDS_PAST_LIMIT)} (largest distance from "
          f"the true position {max(HOLDS_PAST_LIMIT, default=0.0):.2e} rad); re-enables that "
          f"raised BusError: {FAILED_ENABLES[0]} of "
          f"{2 * events} guard events; goals accepted {sum(audit.count[i] for i in ids)}, "
          f"invalid reads {robot.metrics.invalid_reads}, holds {robot.metrics.holds}")


def test_a_host_stall_while_a_motor_is_thermally_relaxed_resumes_the_others():
    """Found by the soak above: the env's watchdog resume re-enabled every hand joint, and the
    one the thermal guard had relaxed raised UnsafeCommand, ending the run. Device side: after
    the stall the hot motor stays limp, the other 8 finger motors take goals again."""
    import gymnasium as gym

    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated")
    env.reset(seed=0)
    backend = env.unwrapped.backend
    chain, port = backend.chain, backend.robot.bus.port
    action = np.full(9, 0.3, np.float32)
    env.step(action)
    heat(chain, "ff_top", 74.0)
    for _ in range(3):
        env.step(action)
    assert not chain.motors[10].torque_on  # relaxed at once
    port.sleep(0.15)  # the host stalls: every motor's Bus Watchdog trips
    counts = dict(chain.goal_audit.count)
    _, _, _, _, info = env.step(action)
    assert info["telemetry"]["watchdog_stops"] == 1
    assert not chain.motors[10].torque_on
    for j in HAND.joints[1:]:
        assert chain.motors[j.motor_id].torque_on, j.name
        assert chain.goal_audit.count[j.motor_id] > counts[j.motor_id], j.name
    env.close()


def test_torque_on_sets_each_goal_from_a_read_just_before_it_while_limp_fingers_fall():
    """The soak's hole (seed 0 on c3ff5c5: a torque-on goal arrived 0.33 rad from motor 21's
    true position, 120 ms after the reading it was set from). Torque on wrote every motor's
    goal := present from one read taken before all the writes and their retries; a limp finger
    (thermal pause, torque off) falls meanwhile, and the goal pulls it back. Device side: each
    torque-on goal reaches its motor one clean read and one write after the motor's sample
    (age <= 3 ms: a 1 ms USB frame each way and the wire time), within one tick plus what the
    fastest joint moves in that time and one physics step of where the motor truly is."""
    chain, robot = connected_robot(RobotConfig(max_invalid_reads=20), seed=4)
    fastest = track_speed(chain)
    dt = chain.plant.model.opt.timestep
    rng = np.random.default_rng(4)
    worst_age, worst_excess, enables = 0.0, -np.inf, 0
    for _ in range(12):
        for _ in range(3):  # wild goals: the fingers swing at up to ~4 rad/s
            robot.step(rng.uniform(-2.0, 2.0, size=9))
        robot.torque(False)  # limp at once: the fingers fall and coast
        robot.bus.sleep(0.02)
        chain.faults = FaultConfig(drop=0.2, corrupt=0.05)
        n = sum(chain.goal_audit.count.values())
        for _ in range(20):
            try:
                robot.torque(True, HAND.joint_names)
                break
            except BusError:
                pass
        chain.faults = FaultConfig()
        new = sum(chain.goal_audit.count.values()) - n
        assert new >= 9
        enables += new
        for _, _, goal, true, _, age in list(chain.goal_audit.recent)[-new:]:
            worst_age = max(worst_age, age)
            worst_excess = max(worst_excess, abs(goal - true) - TICK - fastest[0] * (age + dt))
    assert fastest[0] > 1.0  # the fingers did move fast
    assert worst_age <= 3e-3, worst_age
    assert worst_excess <= 0.0, worst_excess
    print(f"torque-on goals {enables}, longest sample-to-arrival {1e3 * worst_age:.2f} ms")


def test_a_thermal_relaxation_whose_write_statuses_are_all_lost_is_confirmed_not_raised():
    """Found by the soak (seed 21 after the torque-on fix): the thermal guard's torque-off write
    of the hot motor lost its status 4 times, and ``Robot.step`` raised BusError although the
    motor was off. Every status to a WRITE is lost here (the writes land): the hot motor is
    relaxed on the device, the step returns, the other motors keep their torque."""
    from lowcostdex.hardware.dynamixel.protocol import Instruction

    chain, robot = connected_robot(seed=1)
    dispatch = chain._dispatch

    def lose_write_statuses(pkt, t_in, baudrate):
        out = dispatch(pkt, t_in, baudrate)
        return [] if pkt.instruction == Instruction.WRITE else out

    goal = robot.present[:9]
    robot.step(goal)
    heat(chain, "ff_middle", 74.0)
    chain._dispatch = lose_write_statuses
    robot.step(goal)  # the read sees 74 deg C: relaxed at once
    chain._dispatch = dispatch
    assert not chain.motors[11].torque_on
    assert robot.thermal.relaxed[1] and not robot.torque_enabled[1]
    assert all(chain.motors[j.motor_id].torque_on for j in HAND.joints if j.motor_id != 11)
    robot.close()
