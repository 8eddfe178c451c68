"""The Robot on a flaky emulated bus, checked on the device side (``chain.goal_audit``: every goal
a motor accepted against its true joint position).

The motion bound acts on fresh state only: a goal is computed from the position read in the
same control cycle, and a joint whose read failed gets no new goal (it holds). It holds where the
goal arrives: the Robot narrows it by what the joint may move between its sample and the goal's
arrival, so a goal leads the motor's true position at arrival by at most the bound, plus what the
motor moves in one physics step of the emulator (its positions change in 2.5 ms steps, so the
device's sample and arrival positions can be one step further apart than their times)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.bus import WatchdogTripped
from lowcostdex.hardware.emulated.chain import FaultConfig, emulated_dclaw
from lowcostdex.hardware.robot.backend import make_dynamixel_bus
from lowcostdex.hardware.robot.guards import CurrentConfig
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.hardware.robot.safety import UnsafeCommand
from lowcostdex.sim import servo

HAND = dclaw_spec()
TICK = 2 * math.pi / 4096  # one encoder tick of an X-series servo [rad]
# D'Claw spec: max_velocity 2 pi / 3 rad/s, control period 0.1 s
MAX_STEP = 2 * math.pi / 3 * 0.1
# the Robot's default motor speed bound: 1.5 x the XH430-W350's no-load speed, 30 rev/min
SPEED = 1.5 * 30 * 2 * math.pi / 60


def connected_robot(config: RobotConfig | None = None, seed: int = 0, **bus):
    """An emulated D'Claw's Robot; the motion bound narrowed for the time each goal is in
    flight (``motor_speed=None``: the motor spec's speed bound) unless ``config`` says; ``bus``:
    ``DynamixelConfig`` fields."""
    chain = emulated_dclaw("valve", hand=HAND, rng=np.random.default_rng(seed))
    bus = make_dynamixel_bus(HAND, chain.port(), chain.plant.model, handle_signals=False, **bus)
    robot = Robot(HAND, bus, config or RobotConfig(motor_speed=None))
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
    _, _, first, _, at_read, age = [r for r in chain.goal_audit.recent if r[1] == 11][-1]
    # a full step, less what the motor may move (1.5 x 3.14 rad/s) from its sample until the
    # goal arrives (the device's age, plus at most the write's wire time and a 1 ms USB frame)
    assert at_read + MAX_STEP - SPEED * (age + 2e-3) - TICK <= first <= at_read + MAX_STEP + TICK
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
    assert abs(sent[k] - first) < TICK  # (the device's goal is a whole tick)
    chain.faults = FaultConfig()
    sent = robot.send(back)  # a read in this cycle succeeds: bounded around it, sent
    assert not robot.held.any()
    _, _, g, at_arrival, at_read, age = [r for r in chain.goal_audit.recent if r[1] == 11][-1]
    assert abs(g - sent[k]) < TICK
    # the full step back, narrowed the same way
    assert at_read - MAX_STEP - TICK <= g <= at_read - MAX_STEP + SPEED * (age + 2e-3) + TICK
    assert abs(g - at_arrival) <= MAX_STEP + TICK
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


def track_speed(chain) -> list[float]:
    """[fastest |joint velocity| of any finger joint so far, rad/s], updated every physics step:
    the device's own account of how far a motor can move in one step."""
    m = chain.plant.model
    dofs = [m.jnt_dofadr[m.joint(j.name).id] for j in HAND.joints]
    fastest = [0.0]

    def hook(ch) -> None:
        fastest[0] = max(fastest[0], float(np.abs(ch.plant.data.qvel[dofs]).max()))

    chain.add_step_hook(hook)
    return fastest


def soak(faults: FaultConfig, cycles: int, seed: int, **bus):
    """The Robot under ``faults`` for ``cycles`` control steps of wild goals: uniform over
    +-2 rad (outside every finger's limits, many motion bounds away), pushes of every joint
    past its limits, NaN now and then. Returns the chain, the robot and ``track_speed``'s
    record."""
    chain, robot = connected_robot(RobotConfig(max_invalid_reads=20, motor_speed=None),
                                   seed=seed, **bus)
    watch_joints(chain, MAX_STEP)
    fastest = track_speed(chain)
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
    return chain, robot, fastest[0]


FAULT_MIXES = {
    "drop+corrupt": FaultConfig(drop=0.2, corrupt=0.05),
    "late+corrupt": FaultConfig(late=0.2, corrupt=0.05),
    "all": FaultConfig(drop=0.2, corrupt=0.05, late=0.05),
}


def check_device_side(chain, robot, cycles: int, fastest: float) -> None:
    audit = chain.goal_audit
    ids = [j.motor_id for j in HAND.joints]
    assert audit.violations == 0, (audit.lead_violations, audit.limit_violations)
    # the bounds were exercised: goals at the limits and at the motion bound reached the motors
    for j in HAND.joints:
        assert audit.high[j.motor_id] > j.high - TICK and audit.low[j.motor_id] < j.low + TICK
        # the full step less what the motor may move until the goal arrives (see the first test)
        assert any(abs(g - at_read) > MAX_STEP - SPEED * (age + 2e-3) - TICK
                   for _, i, g, _, at_read, age in audit.recent if i == j.motor_id)
    # the bound holds where the goal arrives too (the Robot narrows it by what the joint may
    # move until then): beyond it only what the fastest joint moved in one physics step (the
    # device's positions change in steps). Before reads had to be fresh the lead at arrival
    # reached 2.3 x MAX_STEP; with fresh reads, not narrowed, 1.36 x (0.35 x beyond).
    step = chain.plant.model.opt.timestep
    assert 0 < fastest < SPEED  # the Robot's speed bound held in this soak
    assert max(audit.arrival_excess[i] for i in ids) <= fastest * step
    # the faults really happened, and the Robot held rather than stopped
    assert robot.metrics.invalid_reads > 0.02 * 10 * cycles
    assert robot.metrics.holds > 0.005 * 9 * cycles
    assert sum(audit.count[i] for i in ids) > 0.9 * 9 * cycles
    # nothing the firmware does on its own: no watchdog trip, no hardware error
    assert not chain.events


@pytest.mark.parametrize("mix", FAULT_MIXES)
def test_soak_2000_cycles_no_goal_beyond_the_bound_or_limits_reaches_a_motor(mix):
    chain, robot, fastest = soak(FAULT_MIXES[mix], 2000, seed=11)
    check_device_side(chain, robot, 2000, fastest)


@pytest.mark.slow
def test_soak_10k_cycles_no_goal_beyond_the_bound_or_limits_reaches_a_motor():
    chain, robot, fastest = soak(FAULT_MIXES["all"], 10_000, seed=12)
    check_device_side(chain, robot, 10_000, fastest)


LATE_DELAYS = {"15-40 ms": (0.015, 0.040), "40-300 ms": (0.040, 0.300)}


@pytest.mark.slow
@pytest.mark.parametrize("delay", LATE_DELAYS)
def test_soak_replies_later_than_the_settle_time_do_not_pass_as_fresh(delay):
    """20 % of replies late by ``delay``: beyond the status timeout + 10 ms settle, so a late
    reply can land in the slot of a lost one (Protocol 2.0 has no sequence number). By default
    the first lost reply switches the driver to the block with Realtime Tick: a late reply to
    a 21-byte request is refused by its length, one to a 27-byte request by its tick. 0 goals
    beyond the bound or the limits reach a motor over 2000 cycles. (Before the switch, by
    default: 23 / 0 / 15 goals beyond the bound on seeds 11 / 12 / 13, 15-40 ms.)"""
    faults = FaultConfig(drop=0.2, corrupt=0.05, late=0.2, late_delay=LATE_DELAYS[delay])
    chain, robot, fastest = soak(faults, 2000, seed=11)
    audit, ids = chain.goal_audit, [j.motor_id for j in HAND.joints]
    assert robot.bus._block_addr == 120 and robot.bus._block_len == 27  # e-Manual: 120..146
    assert audit.violations == 0, (audit.lead_violations, audit.limit_violations)
    assert max(audit.arrival_excess[i] for i in ids) <= fastest * chain.plant.model.opt.timestep
    assert robot.bus.stats.stale > 0 and robot.bus.stats.contaminated > 0  # both defences acted
    # a bus this bad costs motion (refused replies hold: 76-80 % of the goals went out), not
    # safety
    assert sum(audit.count[i] for i in ids) > 0.7 * 9 * 2000


@pytest.mark.slow
def test_soak_late_replies_are_refused_by_their_realtime_tick():
    """20 % of replies 15-40 ms late: beyond the status timeout + 10 ms settle, so a late reply
    can land in the slot of a lost one; with ``realtime_tick`` (the tick block from the start)
    the motor's own ms clock, read with the block, tells it: 0 goals beyond the bound or the
    limits reach a motor over 2000 cycles."""
    faults = FaultConfig(drop=0.2, corrupt=0.05, late=0.2, late_delay=(0.015, 0.040))
    chain, robot, fastest = soak(faults, 2000, seed=11, realtime_tick=True)
    audit, ids = chain.goal_audit, [j.motor_id for j in HAND.joints]
    assert robot.bus._block_addr == 120 and robot.bus._block_len == 27  # e-Manual: 120..146
    assert audit.violations == 0, (audit.lead_violations, audit.limit_violations)
    assert max(audit.arrival_excess[i] for i in ids) <= fastest * chain.plant.model.opt.timestep
    assert robot.bus.stats.stale > 0  # the defence acted
    # a bus this bad costs motion (stale replies hold too: 77 % of the goals went out), not safety
    assert sum(audit.count[i] for i in ids) > 0.7 * 9 * 2000

MILD = FaultConfig(drop=0.05, corrupt=0.02, late=0.02)  # unicast torque writes retry 3 times


def heat(chain, joint: str, celsius: float) -> None:
    """Set ``joint``'s winding to ``celsius`` (ambient 25 deg C + the thermal state)."""
    m, d = chain.plant.model, chain.plant.data
    layout = servo.dcmotor_act_layout(m)
    d.act[layout[m.actuator(joint).id, servo.ACT_THERMAL]] = celsius - 25.0
    chain.drive._state = None


def test_thermal_guard_under_faults_relaxes_on_the_device_and_keeps_both_motors_relaxed():
    """X430 firmware limit 80 deg C, critical margin 7 K: a motor at 73.5 deg C is relaxed at
    once, and stays limp when a second one goes critical; the pause rests all of them until
    every motor is below 80 - 30 = 50 deg C. Checked on the motors, not in the host's books."""
    chain, robot = connected_robot(seed=3)
    chain.faults = MILD
    rng = np.random.default_rng(3)
    center = robot.present[:9]

    def steps(n):
        for _ in range(n):
            robot.step(center + rng.uniform(-0.1, 0.1, size=9))

    steps(5)
    assert all(chain.motors[j.motor_id].torque_on for j in HAND.joints)
    heat(chain, "ff_top", 73.5)
    steps(3)
    assert not chain.motors[10].torque_on  # device side: limp
    assert not chain.plant.torque_enabled()[chain.plant.model.actuator("ff_top").id]
    steps(10)
    heat(chain, "mf_top", 74.0)
    steps(3)
    limp = [i for i, m in chain.motors.items() if not m.torque_on]
    assert limp == [10, 20, 50]  # the first stays relaxed; 50 (valve) was never enabled
    assert robot.metrics.thermal_relaxations == 2
    steps(10)
    assert not chain.motors[10].torque_on and not chain.motors[20].torque_on
    record = robot.pause_if_hot()
    assert record is not None and record.hottest in ("ff_top", "mf_top")
    temps = servo.winding_temperature(chain.plant.model, chain.plant.data)
    assert temps.max() < 50.0  # the device's windings, not the last reading
    assert not [e for e in chain.events if e.kind in ("hardware_error", "shutdown")]
    robot.torque(True, HAND.joint_names)  # the next episode may use them again
    assert all(chain.motors[j.motor_id].torque_on for j in HAND.joints)


def test_a_stuck_temperature_sensor_is_found_by_the_thermal_model_and_its_motor_relaxed():
    """ff_middle's sensor sticks at 45 deg C (its firmware's overheating shutdown sees only that)
    while the joint stalls against an obstacle at full lead: the winding heats at ~0.8 K/s from
    60 deg C. Reading flat, the thermal model (the current through the winding's resistance,
    from the stuck 45 deg C) says it has heated >= 5 K: the motor is relaxed before its true
    winding reaches the 73 deg C at which a working sensor would have had it relaxed (without
    the check it reaches 73 after about 20 s and the firmware, blind too, never stops it). Checked on the device: the winding
    temperature of the MuJoCo motor, its torque register, its reported temperature."""
    config = RobotConfig(current=CurrentConfig(fraction=1.0))  # no overload relaxation: heat
    chain, robot = connected_robot(config, seed=6)
    chain.faults = MILD
    m = chain.plant.model
    m.jnt_range[m.joint("ff_middle").id] = [-1.2, 0.1]  # an obstacle the joint cannot pass
    heat(chain, "ff_middle", 60.0)
    chain.motors[11].stuck_temperature = 45.0
    k = robot.index(["ff_middle"])[0]
    goal = robot.present[:9]
    peak, relaxed_at = 0.0, None
    for step in range(600):
        goal[k] = 0.8  # inward, far past the obstacle
        robot.step(goal)
        true = servo.winding_temperature(m, chain.plant.data)[m.actuator("ff_middle").id]
        peak = max(peak, true)
        if not chain.motors[11].torque_on:
            relaxed_at = step
            break
    assert relaxed_at is not None, f"never relaxed; winding at {peak:.1f} deg C"
    assert robot.read().temperature[k] == 45.0  # the device reports its stuck reading
    assert 62.0 <= peak < 73.0  # it really heated, and was relaxed below the critical level
    assert robot.thermal.stuck[k] and robot.telemetry()["temperature_faults"][k]
    assert robot.thermal.stuck.sum() == 1 and robot.thermal.pause_pending
    # a pause does not wait for the stuck reading; the motor stays relaxed afterwards
    robot.pause_if_hot()
    robot.torque(True, HAND.joint_names)
    robot.step(goal)
    assert not chain.motors[11].torque_on
    assert all(chain.motors[j.motor_id].torque_on for j in HAND.joints if j.motor_id != 11)


def test_winding_heating_is_the_dcmotor_thermal_model():
    """``MotorSpec.winding_heating`` (the stuck-sensor check's model) integrates to MuJoCo's own
    dcmotor winding temperature from the same currents: a stalled XH430 over 20 s."""
    chain, robot = connected_robot(RobotConfig(current=CurrentConfig(fraction=1.0)), seed=7)
    m, d = chain.plant.model, chain.plant.data
    m.jnt_range[m.joint("ff_middle").id] = [-1.2, 0.1]
    a = m.actuator("ff_middle").id
    heat(chain, "ff_middle", 40.0)
    motor = servo.motor_spec(HAND.motor)
    model_t, true_t = 40.0, 40.0
    goal = robot.present[:9]
    goal[robot.index(["ff_middle"])[0]] = 0.8
    for _ in range(200):
        before = float(d.time)
        robot.step(goal)
        amps = float(chain.drive.state().current[chain.motors[11].index])
        model_t += (float(d.time) - before) * float(motor.winding_heating(amps, model_t))
        true_t = servo.winding_temperature(m, d)[a]
    assert true_t > 50.0  # it heated
    assert model_t == pytest.approx(true_t, abs=0.05 * (true_t - 40.0))


def test_current_guard_under_faults_bounds_the_goals_that_reach_an_overloaded_motor():
    """A middle joint blocked by an obstacle draws more than 0.6 x its stall current; for 20
    steps its goals may lead its position by 0.02 rad only - checked where they arrive."""
    chain, robot = connected_robot(seed=4)
    m = chain.plant.model
    m.jnt_range[m.joint("ff_middle").id] = [-1.2, 0.1]  # an obstacle the joint cannot pass
    chain.faults = MILD
    k = robot.index(["ff_middle"])[0]
    goal = robot.present[:9]
    relaxed_leads = []
    for _ in range(60):
        goal[k] = 0.8  # inward, far past the obstacle
        relaxed = robot.current_guard.relaxed[k]  # decided by the reads before this goal
        n = chain.goal_audit.count[11]
        robot.step(goal)
        if relaxed and chain.goal_audit.count[11] > n:  # (a held step sends nothing)
            _, motor_id, g, _, at_read, _ = [r for r in chain.goal_audit.recent if r[1] == 11][-1]
            relaxed_leads.append(abs(g - at_read))
    assert robot.metrics.overloads >= 1 and len(relaxed_leads) >= 15
    assert max(relaxed_leads) <= 0.02 + TICK


def test_watchdog_under_faults_stops_the_motors_of_a_silent_host_and_refuses_its_goals():
    """Bus Watchdog 100 ms (the driver's default): a host that falls silent mid-motion (hung,
    killed) leaves motors that stop where they are and accept no goal until torque is
    re-enabled, which starts from the present position."""
    chain, robot = connected_robot(seed=5)
    watch_joints(chain, MAX_STEP)
    chain.faults = FaultConfig(drop=0.2, corrupt=0.05, late=0.05)
    rng = np.random.default_rng(5)
    for _ in range(200):  # faults alone never starve the watchdog: instructions still arrive
        robot.step(rng.uniform(-2.0, 2.0, size=9))
    assert not [e for e in chain.events if e.kind == "watchdog"]
    far = robot.present[:9] + np.where(robot.present[:9] > 0, -1.0, 1.0)
    robot.send(far)  # a full step towards far, then silence
    n = sum(chain.goal_audit.count.values())
    robot.bus.port.sleep(0.3)
    trips = {e.motor_id for e in chain.events if e.kind == "watchdog"}
    assert trips == {j.motor_id for j in HAND.joints}  # the valve motor had no torque
    fingers = [chain.plant.model.joint(j.name).qposadr[0] for j in HAND.joints]
    setpoints = [chain.motors[j.motor_id].setpoint for j in HAND.joints]
    stopped = chain.plant.qpos[fingers].copy()
    robot.bus.port.sleep(0.3)
    # holding where they stopped: the firmware's setpoints stay put, the fingers barely move
    # (the valve, unpowered and pushed, may still turn and brush them)
    assert [chain.motors[j.motor_id].setpoint for j in HAND.joints] == setpoints
    assert np.abs(chain.plant.qpos[fingers] - stopped).max() < 0.02
    with pytest.raises(WatchdogTripped):
        for _ in range(3):  # the first read may not get through
            robot.step(far)
    assert sum(chain.goal_audit.count.values()) == n  # nothing accepted while tripped
    chain.faults = MILD
    robot.torque(True, HAND.joint_names)  # re-armed from the present position
    for _ in range(20):
        robot.step(far)
    assert chain.goal_audit.violations == 0
    assert all(chain.motors[j.motor_id].torque_on for j in HAND.joints)
