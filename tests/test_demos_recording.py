"""Kinesthetic demonstrations: (observation, action) conversion, the virtual teacher recording on
the emulated D'Claw through the same recorder path a person uses, the HDF5 round trip (also
through ``lowcostdex.demonstrations.dataset.load_demos``), appending, and crash safety (a SIGKILLed recorder
leaves a readable file holding every finished episode)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import gymnasium as gym
import h5py
import numpy as np
import pytest

from lowcostdex.demonstrations.dataset import load_demos
from lowcostdex.demonstrations.file import (
    FORMAT,
    DatasetInfo,
    DemoWriter,
    read_demo_pairs,
    read_episodes,
    read_info,
    read_label_model,
)
from lowcostdex.demonstrations.kinesthetic import (
    KinestheticRecorder,
    ServoResponse,
    VirtualTeacher,
    episode_from_states,
    identify_servo_response,
    servo_goal_labels,
)
from lowcostdex.errors import ConfigError
from lowcostdex.sim.envs import goal_to_action
from lowcostdex.sim.registry import register_envs

ENV = "lowcostdex/DClawTurnValve-v0"


@pytest.fixture(scope="module", autouse=True)
def _register():
    register_envs()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two virtual-teacher demonstrations on the emulated D'Claw."""
    path = tmp_path_factory.mktemp("demos") / "valve.h5"
    env = gym.make(ENV, backend="emulated")
    teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task)
    recorder = KinestheticRecorder(env, path, ENV, teacher=teacher)
    episodes = [recorder.record_episode(seed) for seed in (0, 1)]
    chain = env.unwrapped.backend.chain
    env.close()
    return path, episodes, recorder, chain


def test_pairs_are_next_joint_targets_and_previous_actions():
    env = gym.make(ENV)
    env.reset(seed=0)
    task = env.unwrapped.task
    rng = np.random.default_rng(0)
    qpos = np.tile(env.unwrapped.data.qpos, (6, 1))
    qpos[:, task.hand_qpos] += rng.uniform(-0.2, 0.2, (6, 9))
    qvel = np.zeros((6, env.unwrapped.model.nv))
    ep = episode_from_states(task, qpos, qvel, {"angle": np.array(np.pi)}, np.arange(6) * 0.1)
    assert ep.observations.shape == (6, task.obs_dim) and ep.actions.shape == (5, 9)
    np.testing.assert_allclose(ep.actions, goal_to_action(qpos[1:, task.hand_qpos],
                                                          task.hand_low, task.hand_high))
    np.testing.assert_array_equal(ep.observations[0, -9:], 0.0)  # no action before the first
    np.testing.assert_allclose(ep.observations[1:, -9:], ep.actions)  # last_action = a_{t-1}
    np.testing.assert_allclose(ep.observations[:, :9], qpos[:, task.hand_qpos])
    env.close()


def test_virtual_teacher_demos_solve_the_valve_and_round_trip(recorded):
    path, episodes, recorder, chain = recorded
    assert recorder.stats.episodes == 2 and recorder.stats.successes == 2
    info, n_episodes, n_steps = read_info(path)
    assert (n_episodes, n_steps) == (2, 80)
    assert info.source == "virtual_teacher" and info.env_id == ENV and info.act_dim == 9
    back = read_episodes(path)
    for mine, theirs in zip(episodes, back, strict=True):
        for name in ("observations", "actions", "rewards", "qpos", "qvel", "time", "success"):
            np.testing.assert_array_equal(getattr(mine, name), getattr(theirs, name))
        assert theirs.success[-1] and theirs.reset_attempts >= 1
    with h5py.File(path, "r") as f:  # Minari-style per-episode layout, documented attributes
        assert f.attrs["format"] == FORMAT
        g = f["episode_1"]
        assert g["truncations"][-1] and not g["terminations"][-1]
        assert g["observations"].shape == (41, info.obs_dim)
    demos = load_demos(path)  # the BC/DAPG loader reads robot recordings too
    assert demos.observations.shape == (80, info.obs_dim) and demos.actions.shape == (80, 9)
    np.testing.assert_array_equal(demos.episode_ends, [40, 80])
    assert np.all(np.abs(demos.actions) <= 1.0)
    # the fingers were limp while the teacher moved them: no goal reached the finger motors
    finger_ids = set(range(10, 33))
    times = np.array(chain.goal_log.time)
    ids = np.array(chain.goal_log.motor_id)
    for ep in episodes:
        during = (times > ep.time[0] + 1e-6) & (times <= ep.time[-1])
        assert not np.isin(ids[during], list(finger_ids)).any()


def test_replaying_the_demo_actions_in_simulation_turns_the_valve(recorded):
    path, _, _, _ = recorded
    env = gym.make(ENV)
    for ep in read_episodes(path):
        env.reset(seed=ep.seed, options={"qpos": ep.qpos[0], "goal": ep.goal})
        start = abs(float(env.unwrapped.task.goal_error(ep.qpos[0], ep.goal)))
        for a in ep.actions:
            _, _, _, _, info = env.step(a.astype(np.float32))
        assert start > 3.0 and abs(info["goal_error"]) < 0.5  # open loop: >150 of 180 deg
    env.close()


def test_appending_keeps_episodes_and_mismatched_files_are_refused(recorded, tmp_path):
    path, episodes, _, _ = recorded
    copy = tmp_path / "copy.h5"
    copy.write_bytes(path.read_bytes())
    info, _, _ = read_info(copy)
    DemoWriter(copy, info).append(episodes[0])
    assert read_info(copy)[1:] == (3, 120)
    np.testing.assert_array_equal(read_demo_pairs(copy)[2][1], episodes[0].actions)
    other = DatasetInfo(**{**info.__dict__, "env_id": "lowcostdex/DClawScrew-v0"})
    with pytest.raises(ConfigError, match="cannot append"):
        DemoWriter(copy, other)
    with pytest.raises(ConfigError, match="robot backend"):
        KinestheticRecorder(gym.make(ENV), tmp_path / "x.h5", ENV)


def test_an_error_mid_episode_keeps_the_file_and_releases_the_fingers(tmp_path):
    env = gym.make(ENV, backend="emulated")
    chain = env.unwrapped.backend.chain
    calls = {"n": 0}

    class Failing:
        def reset(self, task):
            pass

        def __call__(self, qpos, goal):
            calls["n"] += 1
            if calls["n"] > 45:  # fails during the second episode
                raise RuntimeError("teacher fell over")
            return qpos[env.unwrapped.task.hand_qpos]

    teacher = VirtualTeacher(chain, env.unwrapped.task, solver=Failing())
    recorder = KinestheticRecorder(env, tmp_path / "d.h5", ENV, teacher=teacher)
    recorder.record_episode(0)
    with pytest.raises(RuntimeError, match="fell over"):
        recorder.record_episode(1)
    assert read_info(tmp_path / "d.h5")[1:] == (1, 40)
    assert np.all(chain.plant.data.qfrc_applied == 0.0)
    env.close()


RECORDER = textwrap.dedent("""
    import sys
    import gymnasium as gym
    from lowcostdex.sim.registry import register_envs
    from lowcostdex.demonstrations.kinesthetic import KinestheticRecorder, VirtualTeacher
    register_envs()
    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated")
    teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task)
    rec = KinestheticRecorder(env, sys.argv[1], "lowcostdex/DClawTurnValve-v0", teacher=teacher,
                              on_episode=lambda k, ep: print("EPISODE", k, flush=True))
    rec.record(100)
""")


def test_recorder_killed_mid_episode_leaves_every_finished_episode(tmp_path):
    path = tmp_path / "crash.h5"
    proc = subprocess.Popen([sys.executable, "-c", RECORDER, str(path)],
                            stdout=subprocess.PIPE, text=True)
    try:
        for expected in range(2):
            assert proc.stdout.readline().split() == ["EPISODE", str(expected)]
        proc.send_signal(signal.SIGKILL)  # now recording the third episode
    finally:
        proc.kill()
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    info, n_episodes, n_steps = read_info(path)
    assert n_episodes >= 2 and n_steps == 40 * n_episodes
    pairs = read_demo_pairs(path)
    assert len(pairs) == n_episodes
    assert all(np.all(np.isfinite(o)) and np.all(np.isfinite(a)) for o, a in pairs)
    assert os.path.getsize(path) > 0


# ------------------------------------------------------------------------------------------------
# servo response, servo-goal labels and playbacks


def test_servo_response_fit_recovers_a_known_servo_and_inverts_exactly():
    rng = np.random.default_rng(3)
    truth = ServoResponse(alpha=(0.4, 0.6), beta=(0.2, 0.05), offset=(0.0, -0.01), period=0.1)
    q = rng.uniform(-1, 1, (400, 2))
    v = rng.uniform(-2, 2, (400, 2))
    g = q + rng.uniform(-0.3, 0.3, (400, 2))
    q_next = truth.predict(q, v, g) + 1e-4 * rng.normal(size=(400, 2))
    fit = ServoResponse.fit(q, v, g, q_next, period=0.1)
    np.testing.assert_allclose(fit.alpha, truth.alpha, atol=2e-3)
    np.testing.assert_allclose(fit.beta, truth.beta, atol=5e-3)
    np.testing.assert_allclose(fit.offset, truth.offset, atol=1e-3)
    assert min(fit.r2) > 0.99
    # the label is the goal that reproduces the recorded step
    np.testing.assert_allclose(truth.predict(q, v, truth.goal(q, v, q_next)), q_next, atol=1e-12)
    assert ServoResponse.from_dict(fit.to_dict()) == fit
    # a joint that never follows its goals (torque off) is refused, not fitted to alpha ~ 0
    with pytest.raises(ConfigError, match="did not follow"):
        ServoResponse.fit(q, v, g, q + 0.01 * v * 0.1, period=0.1)


@pytest.fixture(scope="module")
def played(tmp_path_factory):
    """The servo response identified on the emulated D'Claw, one servo-goal-labelled
    demonstration and two noisy playbacks of it."""
    path = tmp_path_factory.mktemp("playback") / "valve.h5"
    env = gym.make(ENV, backend="emulated")
    response, seconds = identify_servo_response(env, episodes=2, seed=7)
    teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task)
    recorder = KinestheticRecorder(env, path, ENV, teacher=teacher, response=response,
                                   playbacks=2, playback_noise=0.05,
                                   rng=np.random.default_rng(0))
    demo = recorder.record_episode(3)
    chain = env.unwrapped.backend.chain
    task = env.unwrapped.task
    env.close()
    return path, response, seconds, demo, recorder, chain, task


def test_servo_response_identified_on_the_emulated_robot(played):
    _, response, seconds, _, _, _, _ = played
    # 2 episodes of 4 s plus their auto-resets, in robot time
    assert 8.0 <= seconds < 60.0
    alpha = np.array(response.alpha)
    # a position servo covers a share of a commanded step in one 0.1 s period, not all of it
    assert np.all((alpha > 0.15) & (alpha < 0.95)), alpha
    assert np.median(response.r2) > 0.7, response.r2


def test_playbacks_are_the_robots_own_motion_labelled_with_the_clean_goals(played):
    path, response, _, demo, recorder, chain, task = played
    assert demo.success[-1] and demo.label == "servo_goal"
    assert recorder.stats.playbacks == 2 and recorder.stats.episodes == 1
    eps = read_episodes(path)
    assert [(e.source, e.label) for e in eps] == [
        ("virtual_teacher", "servo_goal"), ("playback", "commanded"), ("playback", "commanded")]
    assert read_label_model(path) == response.to_dict()
    # servo-goal labels: the goals the identified servo model needs to reproduce each step
    q = demo.qpos[:, task.hand_qpos]
    v = demo.qvel[:, task.hand_dof]
    np.testing.assert_allclose(
        demo.actions, servo_goal_labels(task, demo.qpos, demo.qvel, response, recorder.max_step))
    unclipped = goal_to_action(response.goal(q[:-1], v[:-1], q[1:]), task.hand_low,
                               task.hand_high)
    inside = np.abs(unclipped) < 0.999
    assert inside.mean() > 0.5  # most labels are the model's inverse, not the motion bound
    sent = []
    log = chain.goal_log
    times, ids, values = (np.array(x) for x in (log.time, log.motor_id, log.value))
    for pb in eps[1:]:
        assert pb.seed == demo.seed and pb.length == demo.length
        assert pb.time[0] > demo.time[-1]  # robot clock times, after the demonstration
        np.testing.assert_array_equal(pb.actions, demo.actions)  # the clean labels
        # device side: the goals that reached the first finger's top motor (id 10)
        during = (times > pb.time[0] + 1e-6) & (times <= pb.time[-1] + 1e-6) & (ids == 10)
        sent.append(values[during])
    # the same clean labels reached the motor as different, noisy goals: 0.05 action units of
    # the top joint's +-0.48 rad is +-0.024 rad, so two playbacks differ by <= 0.048 rad
    # (31 ticks) per goal, plus what their different states do to the env's motion bound
    n = min(len(x) for x in sent)
    assert n >= pb.length - 5
    diff = np.abs(sent[0][:n].astype(float) - sent[1][:n])
    assert np.mean(diff > 0) > 0.7 and np.median(diff) <= 31, diff
    assert read_episodes(path, only_successful=True)[0].label == "servo_goal"


def test_playbacks_need_a_servo_response_and_version_1_files_read_as_next_position(
        recorded, tmp_path):
    path, _, _, _ = recorded
    with pytest.raises(ConfigError, match="servo response"):
        KinestheticRecorder(gym.make(ENV, backend="emulated"), tmp_path / "y.h5", ENV,
                            playbacks=1)
    copy = tmp_path / "v1.h5"
    copy.write_bytes(path.read_bytes())
    with h5py.File(copy, "r+") as f:  # what a format-version-1 file looked like
        f.attrs["format_version"] = 1
        for k in range(int(f.attrs["total_episodes"])):
            del f[f"episode_{k}"].attrs["label"]
    assert {e.label for e in read_episodes(copy)} == {"next_position"}


def test_each_servo_goal_episode_keeps_the_servo_response_it_was_labelled_with(played, tmp_path):
    path, response, _, demo, _, _, _ = played
    copy = tmp_path / "two_sessions.h5"
    copy.write_bytes(path.read_bytes())
    info, n, _ = read_info(copy)
    later = ServoResponse(alpha=tuple(0.5 for _ in response.alpha), beta=response.beta,
                          offset=response.offset, period=response.period)
    DemoWriter(copy, info, label_model=later.to_dict()).append(demo)  # a later session
    assert read_label_model(copy, episode=0) == response.to_dict()
    assert read_label_model(copy, episode=n) == later.to_dict()
    assert read_label_model(copy, episode=1) is None  # a playback: commanded labels
    with pytest.raises(ConfigError, match="label_model"):
        DemoWriter(copy, info).append(demo)


def test_foam_valve_demonstration_and_its_playbacks_turn_it_on_the_emulated_robot(tmp_path):
    # The foam valve (dry friction, damped: it stops when the fingers let go) through the user's
    # command. With ROBEL's spoke phase the relay teacher ran out of the 40 steps here (issue
    # 18: demonstrations ended at 173 deg, 0 of 6); success is the task's own criterion (valve
    # within 0.1 rad of the goal at the last step), measured by the emulated robot's physics.
    from lowcostdex.cli import main

    out = tmp_path / "foam.h5"
    assert main(["record-demos", "--hand", "dclaw", "--task", "turn-foam-valve", "--port",
                 "emulated", "--episodes", "1", "--seed", "0", "--out", str(out)]) == 0
    demo, *playbacks = read_episodes(out)
    assert demo.source == "virtual_teacher"
    assert demo.success[-1], "the demonstration did not turn the foam valve"
    assert len(playbacks) == 2  # a successful demonstration is played back twice
    # with time to spare: in success for the last 3 steps at least
    assert np.all(demo.success[-3:])
    # the open-loop playbacks (servos under load, noisy goals) lag the demonstration; one of
    # the two reaching the goal is the floor (seeds 0-2: 33 of 36 did)
    assert sum(bool(p.success[-1]) for p in playbacks) >= 1


def test_playbacks_of_the_valve_demonstrations_mostly_turn_it_on_the_emulated_robot(tmp_path):
    """The open-loop playbacks (the teacher's servo goals again, +-0.05 noise on every goal) of
    12 fixed-valve demonstrations reach the goal at the last step in at least 2/3 of 24.
    Measured 2026-11-26 with the motion bound narrowed in flight: 20/24 (seed 0) and 19/24
    (seed 100); before the narrowing the vendor's measure was 33/36. Success is the task's own
    criterion, judged by the emulated robot's physics."""
    from lowcostdex.cli import main

    out = tmp_path / "valve.h5"
    assert main(["record-demos", "--task", "turn-valve", "--port", "emulated", "--episodes",
                 "12", "--seed", "0", "--out", str(out)]) == 0
    episodes = read_episodes(out)
    demos = [e for e in episodes if e.source == "virtual_teacher"]
    playbacks = [e for e in episodes if e.source == "playback"]
    assert len(demos) == 12 and all(e.success[-1] for e in demos)
    assert len(playbacks) == 24
    assert sum(bool(p.success[-1]) for p in playbacks) >= 16


def test_screw_demonstrations_follow_the_moving_goal_on_the_emulated_robot(tmp_path):
    """ROBEL's screw (robel/dclaw/screw.py, 01-hardware.md section 1.5): the target turns at
    0.5 rad/s from 0 (Fixed), 80 steps of 40 x 2.5 ms, success |err| < 0.2 rad. The virtual
    teacher must chase where the goal is now, not where it was at the start (it held the start
    goal: demonstrations stopped at 8 deg, 0 of 6; issue 18). Checked from the recorded valve
    angles against that schedule written out here, goal(k) = 0.5 rad/s x 0.1 s x k."""
    from lowcostdex.cli import main

    out = tmp_path / "screw.h5"
    assert main(["record-demos", "--hand", "dclaw", "--task", "screw", "--port", "emulated",
                 "--episodes", "1", "--seed", "0", "--out", str(out)]) == 0
    demo, *playbacks = read_episodes(out)
    assert demo.source == "virtual_teacher" and demo.length == 80
    task = gym.make("lowcostdex/DClawScrew-v0").unwrapped.task
    valve = np.ravel(demo.qpos[:, task.obj_qpos])
    goal = 0.5 * 0.1 * np.arange(len(valve))  # [rad], from the start angle 0
    error = np.abs(valve - goal)
    assert valve[-1] > 3.8  # turned ~4 rad (229 deg), not stuck near the start
    assert error[-1] < 0.2  # ROBEL's screw success: within 0.2 rad at the end
    assert np.mean(error < 0.2) >= 0.9, np.round(error, 2)  # tracking all along
    assert demo.success[-1] and len(playbacks) == 2
    assert sum(bool(p.success[-1]) for p in playbacks) >= 1
