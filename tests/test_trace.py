"""Driver logs (hardware.trace) are valid gap-analysis logs of what reached the motors."""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.gap import read_log
from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.backend import make_dynamixel_bus, robot_hand
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.hardware.robot.trace import excite
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
    from lowcostdex.gap import load_dataset

    xml = tmp_path / "finger.xml"
    assert main(["model", "dclaw", "--station", "none", "--fingers", "ff", "--no-thermal",
                 "--out", str(xml)]) == 0
    assert main(["record-log", "--port", "emulated", "--logs", "2", "--seconds", "1.5",
                 "--out", str(tmp_path / "logs")]) == 0
    logs = sorted((tmp_path / "logs").glob("log_*.csv"))
    assert len(logs) == 2
    ds = load_dataset([str(p) for p in logs], model=str(xml))  # columns match the model
    assert len(ds.trajectories) == 2


def _robot(effects=(), seed=0):
    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=effects, rng=np.random.default_rng(seed))
    h = robot_hand(hand, model)
    robot = Robot(h, make_dynamixel_bus(h, chain.port(), model),
                  RobotConfig(control_period=0.02, motion_scale=10.0))
    return hand, chain, robot


def test_log_times_are_when_values_were_sampled_and_goals_arrived(tmp_path):
    hand, chain, robot = _robot()
    t = np.arange(50) * 0.02
    goals = np.stack([0.3 * np.sin(2 * np.pi * t), -0.4 + 0.2 * (t > 0.5), 0.5 * (t > 0.3)], 1)
    with robot:
        traj = read_log(excite(robot, JOINTS, goals, tmp_path / "trace.csv"))
    # the goal follows the read's status packets and its own packet: a few ms at 1 Mbit/s
    delay = traj.goal_time - traj.time
    assert np.all((delay > 1e-3) & (delay < 6e-3)), delay
    # device side: the goal log's arrival times of ff_top's goals are the logged goal times
    times = np.array(chain.goal_log.time)[np.array(chain.goal_log.motor_id) == 10]
    arrived = times[-len(goals):]
    np.testing.assert_allclose(arrived - arrived[0], traj.goal_time - traj.goal_time[0],
                               atol=1e-9)
    # the log starts at rest on its first goal (settled before logging)
    assert np.abs(traj.qvel[0]).max() < 0.05
    np.testing.assert_allclose(traj.qpos[0], goals[0], atol=0.01)


def test_a_goal_time_shift_replays_like_the_same_latency():
    """Known answer: goals that take effect d later (``goal_time``) replay like a hidden
    latency of d on the nominal model."""
    from dataclasses import replace

    from lowcostdex.gap import generate
    from lowcostdex.gap.dataset import Dataset, episodes
    from lowcostdex.gap.replay import Replayer

    syn = generate.generate("finger", ["latency"], np.random.default_rng(4), n_logs=1,
                            duration=4.0, level=0.6)
    (latency,) = syn.hidden
    d = float(np.mean(latency.values["delay"]))
    ds = Dataset({"model": syn.xml}, syn.trajectories)
    shifted = Dataset(ds.models, [replace(tr, goal_time=tr.time + d) for tr in ds.trajectories])
    errs = []
    for data in (ds, shifted):
        eps = episodes(data)
        pred, _ = Replayer(data).run(eps, [[]])
        errs.append(np.sqrt(np.mean(np.concatenate(
            [data.trajectories[w.traj].qpos[w.start:w.stop] - p
             for w, p in zip(eps, pred[0], strict=True)]) ** 2)))
    assert d > 0.005
    # (measured: 26 mrad without the shift, 1.0 with it; floor 0.53: the delay is applied on
    # the 2.5 ms physics grid and the synthetic driver's timing jitters)
    assert errs[1] < 3 * syn.settings.floor and errs[1] < 0.1 * errs[0], errs


def test_the_effect_free_emulator_replays_at_the_noise_floor(tmp_path):
    """Negative control of the whole chain (driver timing, emulated firmware, nominal model):
    logs of an emulated D'Claw without hidden effects replay on the nominal finger within the
    encoder's noise floor, and the gap analysis finds nothing to explain."""
    from lowcostdex.gap import GapConfig, analyze, load_dataset
    from lowcostdex.hardware.robot.trace import identification_logs

    hand, _, robot = _robot(seed=1)
    with robot:
        paths = identification_logs(robot, JOINTS, tmp_path, 3, 6.0, np.random.default_rng(2))
    xml = tmp_path / "finger.xml"
    xml.write_text(build_dclaw("none", hand, thermal=False, fingers=("ff",)).to_xml())
    result = analyze(load_dataset([str(p) for p in paths], model=str(xml)), GapConfig())
    assert not result.causes, result.verdict
    floor = float(np.sqrt(np.mean(result.floor ** 2)))
    assert result.gain.baseline_rmse < 1.5 * floor


def test_identification_poses_touch_nothing_with_the_neighbours_parked():
    import mujoco

    from lowcostdex.hardware.robot.trace import contact_free, dclaw_park

    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    park = dclaw_park(hand.joint_names, JOINTS)
    assert park == {"mf_middle": -1.0, "th_middle": -1.0}
    touching = np.array([-0.38, 0.84, 1.05])  # ff curled in, swung onto the middle finger's base
    free = np.array([0.1, -0.3, 0.4])
    goals = np.stack([free, touching, free])
    out, changed = contact_free(model, JOINTS, goals, park)
    assert changed == 1
    np.testing.assert_array_equal(out[[0, 2]], goals[[0, 2]])  # free poses are left alone
    assert np.linalg.norm(out[1]) < np.linalg.norm(touching)  # pulled toward the centre
    data = mujoco.MjData(model)
    for row in (touching, out[1]):
        data.qpos[:] = model.qpos0
        for name, value in park.items():
            data.qpos[model.jnt_qposadr[model.joint(name).id]] = value
        for name, value in zip(JOINTS, row, strict=True):
            data.qpos[model.jnt_qposadr[model.joint(name).id]] = value
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        assert (data.ncon > 0) == (row is touching)


def _lossy_robot(seed: int, drop: float):
    """An effect-free emulated D'Claw losing ``drop`` of its status packets (the driver retries
    a sync read once, so a reading is missed with probability ~drop^2 per motor)."""
    from lowcostdex.hardware.emulated.chain import FaultConfig

    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(seed),
                           faults=FaultConfig(drop=drop))
    h = robot_hand(hand, model)
    return Robot(h, make_dynamixel_bus(h, chain.port(), model),
                 RobotConfig(control_period=0.02, motion_scale=10.0))


def test_an_identification_log_with_a_missed_reading_is_recorded_again(tmp_path):
    """A reading missed mid-log leaves NaN in its row, which the gap analysis refuses; the log
    is recorded again and only complete logs are written (measured: seed 2 misses 2 readings
    in log 0's first recording, none in its second)."""
    from lowcostdex.hardware.robot.trace import identification_logs

    robot = _lossy_robot(seed=2, drop=0.12)
    with robot:
        paths = identification_logs(robot, JOINTS, tmp_path, 2, 2.0, np.random.default_rng(2))
        missed = robot.metrics.invalid_reads
    assert missed > 0  # readings were lost on the wire during the run
    assert [p.name for p in paths] == ["log_0.csv", "log_1.csv"]
    for p in paths:
        traj = read_log(p)  # refuses NaN/inf values
        assert len(traj) == 100  # 2 s at 50 Hz: one recording, not two glued together


def test_identification_stops_with_a_bus_error_when_every_recording_misses(tmp_path):
    from lowcostdex.hardware.bus import BusError
    from lowcostdex.hardware.robot.trace import identification_logs

    robot = _lossy_robot(seed=4, drop=0.12)  # measured: log 1 misses 1, 4, 1 readings
    with robot, pytest.raises(BusError, match="readings were missed in each of 3 recordings"):
        identification_logs(robot, JOINTS, tmp_path, 2, 2.0, np.random.default_rng(2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log_0.csv"]  # no log with gaps


def test_a_host_stall_that_trips_the_bus_watchdog_re_records_the_log(tmp_path):
    """The host falls silent for 150 ms mid-log (a stalled machine; the Bus Watchdog is 100 ms):
    the emulated motors stop themselves (seen on the device side as a watchdog event), the
    parked finger is held again and the log is recorded again from its start, complete. A second
    stall in every recording ends with a BusError that names the watchdog."""
    from lowcostdex.hardware.bus import BusError
    from lowcostdex.hardware.robot.trace import dclaw_park, identification_logs

    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(0))
    h = robot_hand(hand, model)
    robot = Robot(h, make_dynamixel_bus(h, chain.port(), model),
                  RobotConfig(control_period=0.02, motion_scale=10.0))
    port = robot.bus.port
    steps: list[int] = []

    def stall_once(k):
        steps.append(k)
        if len(steps) == 30:  # mid-way through log 0's first recording
            port.sleep(0.15)  # time passes on the device, no packet is sent

    park = dclaw_park(hand.joint_names, JOINTS)
    with robot:
        paths = identification_logs(robot, JOINTS, tmp_path / "a", 2, 1.0,
                                    np.random.default_rng(2), on_step=stall_once, park=park)
        parked = robot.present[robot.index(tuple(park))]
    trips = [e for e in chain.events if e.kind == "watchdog"]
    assert trips and {e.motor_id for e in trips} >= {10, 11, 12}  # the logged finger stopped
    for e in trips:  # "stopped at <ticks> after <silence> s silent": just past the 100 ms
        silence = float(e.detail.split(" after ")[1].split()[0])
        assert 0.100 <= silence <= 0.101  # printed to 1 us: a trip 1e-13 s past reads 0.100000
    assert len(steps) == 30 + 2 * 50  # the interrupted recording, then two whole logs
    for p in paths:
        assert len(read_log(p)) == 50  # 1 s at 50 Hz, one recording each
    assert np.abs(parked - np.array(list(park.values()))).max() < 0.05

    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(0))
    robot = Robot(h, make_dynamixel_bus(h, chain.port(), model),
                  RobotConfig(control_period=0.02, motion_scale=10.0))
    port = robot.bus.port
    with robot, pytest.raises(BusError, match="3 of them stopped by the bus watchdog"):
        identification_logs(robot, JOINTS, tmp_path / "b", 1, 1.0, np.random.default_rng(2),
                            on_step=lambda k: port.sleep(0.15) if k == 10 else None)
