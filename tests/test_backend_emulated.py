"""Env backends on the emulated D'Claw: gym.make with backend="emulated" (the real dynamixel_sdk
path, in-process), agreement with the pure simulation within quantization and timing, the effect
gap, determinism, telemetry, and backend="hardware" over a pty."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from lowcostdex.hardware.robot.backend import EmulatedBackend, default_effects
from lowcostdex.hardware.robot.reset import ResetConfig
from lowcostdex.sim.envs import goal_to_action
from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE
from lowcostdex.sim.registry import register_envs

ENV = "lowcostdex/DClawTurnValve-v0"
TICK = 2 * np.pi / 4096  # [rad] encoder resolution


@pytest.fixture(scope="module", autouse=True)
def _register():
    register_envs()


def free_motion(task, steps: int, seed: int = 0) -> np.ndarray:
    """Smooth actions (steps, 9) that move every joint widely with the tips above the valve.

    Slow enough (0.25 Hz) that no goal hits the per-step motion bound: that clip is taken
    around the position read at the step, so it would turn the bus's few-ms read offset into
    a goal difference that accumulates.
    """
    rng = np.random.default_rng(seed)
    base = goal_to_action(RESET_POSE, task.hand_low, task.hand_high)
    phase = rng.uniform(0, 2 * np.pi, 9)
    amp = np.tile([0.8, 0.4, 0.6], 3)
    t = np.arange(steps)[:, None] * 0.1
    acts = np.clip(base + amp * np.sin(2 * np.pi * 0.25 * t + phase), -1, 1)
    acts[:, 1::3] = np.minimum(acts[:, 1::3], -0.3)  # middles outward: no valve contact
    return acts.astype(np.float32)


def rollout_pair(effects, steps=40):
    emu = gym.make(ENV, backend="emulated", effects=effects)
    sim = gym.make(ENV)
    emu.reset(seed=0)
    # start the simulation where the auto-reset actually left the emulated robot
    sim.reset(seed=0, options={"qpos": emu.unwrapped.data.qpos.copy()})
    q_emu, q_sim, v_sim = [], [], []
    for a in free_motion(sim.unwrapped.task, steps):
        emu.step(a)
        sim.step(a)
        q_emu.append(emu.unwrapped.data.qpos.copy())
        q_sim.append(sim.unwrapped.data.qpos.copy())
        v_sim.append(sim.unwrapped.data.qvel.copy())
    emu.close()
    sim.close()
    return np.array(q_emu), np.array(q_sim), np.array(v_sim)


def test_make_reset_step_and_telemetry():
    env = gym.make(ENV, backend="emulated")
    assert isinstance(env.unwrapped.backend, EmulatedBackend)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert info["telemetry"]["resets"] == 1 and info["telemetry"]["last_reset_attempts"] == 1
    sent = info["telemetry"]["sent"]
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    tel = info["telemetry"]
    for key in ("current", "temperature", "voltage", "pauses", "pause_time", "resets",
                "faults", "overruns", "max_temperature", "reset_success_rate"):
        assert key in tel, key
    assert tel["temperature"].shape == (10,) and np.all(tel["temperature"] >= 20)
    assert tel["sent"] == sent + 5 and np.isfinite(reward)  # one goal write per env step
    backend = env.unwrapped.backend
    hand = env.unwrapped.task.hand_qpos
    true_q = backend.chain.plant.data.qpos[hand]
    np.testing.assert_allclose(env.unwrapped.data.qpos[hand], true_q, atol=2 * TICK + 0.01)
    env.close()
    assert not any(m.torque_on for m in backend.chain.motors.values())


def test_same_actions_on_sim_and_emulated_agree_within_quantization_and_timing():
    q_emu, q_sim, v_sim = rollout_pair(effects=())
    hand = slice(0, 9)
    diff = np.abs(q_emu[:, hand] - q_sim[:, hand])
    # quantization: one tick each way; timing: on the bus the goal lands and the state is read
    # a few ms (wire time of the sync write and sync read, 1 Mbps) off the control tick
    tol = 2 * TICK + np.abs(v_sim[:, hand]) * 0.010
    assert np.all(diff <= tol), np.max(diff - tol)
    assert np.ptp(q_sim[:, hand], axis=0).min() > 0.3  # every joint really moved
    assert np.max(np.abs(q_emu[:, 9] - q_sim[:, 9])) < 0.01  # the valve (barely touched)


def bound_limited_action(task, qpos):
    """Actions (9,) whose targets are each joint's far limit: every joint's goal is clipped."""
    present = qpos[task.hand_qpos]
    return np.where(present > 0.5 * (task.hand_low + task.hand_high), -1.0, 1.0).astype(
        np.float32)


def test_sim_and_emulated_robot_apply_the_same_narrowed_motion_bound():
    """A goal leads the present position by the bound narrowed for the time it is in flight,
    the same in simulation and on the emulated robot's wire. The numbers, written out: the
    D'Claw's 2 pi / 3 rad/s per step (ROBEL's bound) x 0.1 s = 0.2094 rad, narrowed by 1.5 x
    the XH430-W350's no-load speed (e-Manual: 30 rev/min at 12 V = 3.1416 rad/s) times a clean
    1 Mbit/s bus's time from sample to arrival: the fast sync read's reply of 8 + 10 x (21 + 4)
    bytes, then the Goal Position sync write of 14 + 5 x 9 bytes and one 1 ms USB frame, at 10
    bits a byte: 2.58 + 0.59 + 1 = 4.17 ms -> 0.2094 - 4.712 x 0.00417 = 0.18979 rad."""
    expected = 2 * np.pi / 3 * 0.1 - 1.5 * np.pi * (10 * (8 + 10 * 25 + 14 + 5 * 9) / 1e6 + 1e-3)
    assert expected == pytest.approx(0.18979, abs=1e-5)
    sim = gym.make(ENV)
    sim.reset(seed=0)
    task = sim.unwrapped.task
    qpos = sim.unwrapped.data.qpos.copy()
    _, _, _, _, info = sim.step(bound_limited_action(task, qpos))
    lead = np.abs(info["goal"] - qpos[task.hand_qpos])
    far = np.abs(np.where(bound_limited_action(task, qpos) > 0, task.hand_high, task.hand_low)
                 - qpos[task.hand_qpos]) > 0.25
    assert far.sum() >= 6
    np.testing.assert_allclose(lead[far], expected, atol=1e-9)
    sim.close()

    # the Robot's own gate (the env's goal would arrive pre-clipped): far goals straight in
    emu = gym.make(ENV, backend="emulated", effects=())
    emu.reset(seed=0)
    robot = emu.unwrapped.backend.robot
    audit = emu.unwrapped.backend.chain.goal_audit
    audit.recent.clear()
    a = bound_limited_action(task, emu.unwrapped.data.qpos)
    robot.step(np.where(a > 0, task.hand_high, task.hand_low), task.hand.joint_names)
    ids = [j.motor_id for j in task.hand.joints]
    got = {m: (goal, at_read, age) for _, m, goal, _, at_read, age in audit.recent}
    read_lead = np.array([abs(got[m][0] - got[m][1]) for m in ids])
    ages = np.array([got[m][2] for m in ids])
    # sample -> arrival: the wire time alone (the emulated port has no USB adapter to hold the
    # packet), within the 4.17 ms the bound allows for
    np.testing.assert_allclose(ages, 10 * (8 + 10 * 25 + 14 + 5 * 9) / 1e6, atol=1e-6)
    # the goal is computed from the read (one encoder tick from the true sampled position)
    np.testing.assert_allclose(read_lead[far], expected, atol=TICK)
    emu.close()


def test_default_effects_open_a_measurable_gap():
    """The emulated robot's default servo effects make it differ from the nominal simulation
    well beyond quantization and timing (something for the gap analysis to find)."""
    q_nom, q_sim, _ = rollout_pair(effects=())
    q_eff, q_sim2, _ = rollout_pair(effects=default_effects(
        tuple(n for n in gym.make(ENV).unwrapped.task.hand.joint_names)))
    nominal_gap = np.abs(q_nom[:, :9] - q_sim[:, :9]).max()
    effect_gap = np.abs(q_eff[:, :9] - q_sim2[:, :9]).max()
    assert effect_gap > 3 * nominal_gap


def test_emulated_runs_are_deterministic_under_a_seed():
    runs = []
    for _ in range(2):
        env = gym.make(ENV, backend="emulated")
        obs = [env.reset(seed=4)[0]]
        rng = np.random.default_rng(0)
        for _ in range(8):
            obs.append(env.step(rng.uniform(-1, 1, 9).astype(np.float32))[0])
        env.close()
        runs.append(np.array(obs))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_nan_action_raises_and_nothing_reaches_the_motors():
    env = gym.make(ENV, backend="emulated")
    env.reset(seed=0)
    log = env.unwrapped.backend.chain.goal_log
    before = len(log)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(9, np.nan, np.float32))
    assert len(log) == before
    env.close()


def test_a_host_stall_mid_episode_stops_the_motors_and_the_episode_resumes_from_there():
    """The training process stalls 150 ms mid-episode (the Bus Watchdog is 100 ms): the motors
    stop themselves where they are (device side: a watchdog event per finger motor), the next
    step turns torque on from there and its goal reaches the motors; counted in telemetry.
    More than ``MAX_WATCHDOG_STOPS`` stalls in one episode are raised, not hidden."""
    from lowcostdex.hardware.bus import WatchdogTripped

    env = gym.make(ENV, backend="emulated")
    env.reset(seed=0)
    backend = env.unwrapped.backend
    chain, port = backend.chain, backend.robot.bus.port
    action = np.full(9, 0.5, np.float32)
    for _ in range(3):
        env.step(action)
    port.sleep(0.15)  # time passes on the device, the host sends nothing
    _, _, _, _, info = env.step(action)
    trips = [e for e in chain.events if e.kind == "watchdog"]
    assert sorted(e.motor_id for e in trips) == [10, 11, 12, 20, 21, 22, 30, 31, 32]
    assert info["telemetry"]["watchdog_stops"] == 1
    stop = {e.motor_id: int(e.detail.split()[2]) for e in trips}  # "stopped at <ticks> after"
    for motor_id in (10, 21, 32):
        times, ticks = chain.goal_log.positions(motor_id)
        after = ticks[times > trips[0].time]
        # torque on where it stopped (the arm settles a tick or two after the stop) ...
        assert len(after) >= 2 and abs(int(after[0]) - stop[motor_id]) <= 2
        step_ticks = backend.robot.max_step[0] / (2 * np.pi / 4096)
        assert abs(int(after[-1]) - stop[motor_id]) <= step_ticks + 3  # ... then one bounded step
    for _ in range(backend.MAX_WATCHDOG_STOPS - 1):
        port.sleep(0.15)
        env.step(action)
    port.sleep(0.15)
    with pytest.raises(WatchdogTripped):
        env.step(action)
    env.reset(seed=1)  # a new episode starts from a clean count
    port.sleep(0.15)
    _, _, _, _, info = env.step(action)
    assert info["telemetry"]["watchdog_stops"] == backend.MAX_WATCHDOG_STOPS + 1
    env.close()


@pytest.mark.slow
def test_hardware_backend_over_a_pty():
    """backend="hardware" on a serial device: ``lowcostdex emulate dclaw`` serves the emulated
    D'Claw on a Linux pty from its own process, in real time, like a U2D2 would."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "lowcostdex.cli", "emulate", "dclaw",
                             "--quiet"], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().split()
        assert line[0] == "PORT", line
        # a 16 ms latency budget (the SDK default): a loaded CPU delays, not fails, replies
        env = gym.make(ENV, backend="hardware", port=line[1], latency_ms=16,
                       reset_config=ResetConfig(settle=0.1))
        env.reset(seed=0)
        for _ in range(3):
            _, _, _, _, info = env.step(env.action_space.sample())
        assert info["telemetry"]["resets"] == 1 and info["telemetry"]["sent"] >= 3
        env.close()
    finally:
        proc.terminate()
        proc.wait(timeout=10)
