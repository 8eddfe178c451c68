"""Kinesthetic demonstrations: (observation, action) conversion, the virtual teacher recording on
the emulated D'Claw through the same recorder path a person uses, the HDF5 round trip (also
through ``lowcostdex.algos.demos.load_demos``), appending, and crash safety (a SIGKILLed recorder
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

from lowcostdex.algos.demos import load_demos
from lowcostdex.errors import ConfigError
from lowcostdex.demo_file import FORMAT, DatasetInfo, DemoWriter, read_episodes, read_info
from lowcostdex.hardware.demos import (
    KinestheticRecorder,
    VirtualTeacher,
    episode_from_states,
    read_demo_pairs,
)
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
    from lowcostdex.hardware.demos import KinestheticRecorder, VirtualTeacher
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
