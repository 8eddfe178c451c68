"""Teacher recordings in simulation, written to and read from the one demonstration format
(the HDF5 dataset of ``lowcostdex.demonstrations.file``) as BC/DAPG inputs."""

from __future__ import annotations

import gymnasium as gym
import h5py
import numpy as np
import pytest
from pointmass import demo_info, expert_action, make_pointmass

import lowcostdex  # noqa: F401  (registers the env ids)
from lowcostdex.demonstrations.dataset import Demos, load_demos, save_demos, teacher_episodes
from lowcostdex.demonstrations.file import DatasetInfo, read_episodes, read_info
from lowcostdex.errors import ConfigError


def _expert(env, obs):
    return expert_action(obs)


def test_round_trip_keeps_whole_episodes_and_pairs_drop_the_last_observation(tmp_path):
    env = make_pointmass()
    episodes = teacher_episodes(env, _expert, seeds=[1, 2, 3])
    path = save_demos(tmp_path / "d.h5", episodes, demo_info())
    info, n_episodes, n_steps = read_info(path)
    assert info == demo_info() and (n_episodes, n_steps) == (3, 90)
    for ep, back in zip(episodes, read_episodes(path), strict=True):
        assert back.observations.shape == (31, 3) and back.actions.shape == (30, 1)
        for key in ("observations", "actions", "rewards", "success", "time"):
            np.testing.assert_array_equal(getattr(back, key), getattr(ep, key), err_msg=key)
        assert back.seed == ep.seed and back.success[-1]
    np.testing.assert_allclose(episodes[0].time, 0.1 * np.arange(31))  # steps x dt, no MuJoCo
    assert episodes[0].qpos.shape == (31, 0)  # the point mass has no MuJoCo state
    demos = load_demos(path)
    assert demos.n_episodes == 3 and demos.episode_ends.tolist() == [30, 60, 90]
    for ep, (o, a) in zip(episodes, demos.episodes(), strict=True):
        np.testing.assert_array_equal(o, ep.observations[:-1])  # o_t paired with a_t
        np.testing.assert_array_equal(a, ep.actions)
    two = demos.first(2)
    assert two.n_episodes == 2 and len(two.actions) == 60


def test_save_replaces_a_file_and_load_keeps_only_successful_episodes(tmp_path):
    env = make_pointmass()
    good = teacher_episodes(env, _expert, seeds=[1, 2])
    bad = teacher_episodes(env, lambda e, obs: np.array([1.0]), seeds=[5], only_successful=False)
    assert not bad[0].success[-1]
    path = tmp_path / "d.h5"
    save_demos(path, good + bad, demo_info())
    assert read_info(save_demos(path, good + bad, demo_info()))[1] == 3  # replaced, not appended
    assert not list(tmp_path.glob("*.partial"))
    assert load_demos(path).n_episodes == 2
    assert load_demos(path, only_successful=False).n_episodes == 3
    save_demos(path, bad, demo_info())
    with pytest.raises(ConfigError, match="no successful demonstration"):
        load_demos(path)


def test_other_files_raise_config_errors_naming_the_format(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_demos(tmp_path / "missing.h5")
    old = tmp_path / "old.npz"  # the former NPZ demo files are not read any more
    np.savez(old, observations=np.zeros((2, 3)), actions=np.zeros((2, 1)), episode_ends=[2])
    with pytest.raises(ConfigError, match="HDF5 demonstration dataset .*lowcostdex-demos"):
        load_demos(old)
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f.create_dataset("observations", data=np.zeros((2, 3)))
    with pytest.raises(ConfigError, match="format attribute is None"):
        load_demos(tmp_path / "other.h5")
    with pytest.raises(ConfigError, match="inconsistent"):
        Demos(np.zeros((3, 2)), np.zeros((2, 1)), np.array([3]))
    with pytest.raises(ConfigError, match="demonstration source"):
        DatasetInfo("x", "T", "{}", "dream", 0.1, 3, 1, ("a",))
    with pytest.raises(ConfigError, match="not a lowcostdex hand env"):
        DatasetInfo.from_env(make_pointmass(), "scripted_teacher")


def test_teacher_episodes_keep_successful_runs():
    env = make_pointmass()
    episodes = teacher_episodes(env, _expert, seeds=[1, 2, 3])
    assert [ep.seed for ep in episodes] == [1, 2, 3]
    for ep in episodes:
        assert ep.observations.shape == (31, 3) and ep.actions.shape == (30, 1) and ep.success[-1]
        np.testing.assert_allclose(ep.actions[0], expert_action(ep.observations[0]))
        assert not ep.terminated  # the time limit ended it
    with pytest.raises(ConfigError, match="failed"):
        teacher_episodes(env, lambda e, obs: np.array([1.0]), seeds=[1], max_tries=2)


def test_noisy_execution_keeps_clean_teacher_labels():
    env = make_pointmass()
    (clean,) = teacher_episodes(env, _expert, seeds=[4])
    (noisy,) = teacher_episodes(env, _expert, seeds=[4], action_noise=0.3)
    (again,) = teacher_episodes(env, _expert, seeds=[4], action_noise=0.3)
    np.testing.assert_array_equal(noisy.observations, again.observations)  # seeded noise
    assert not np.allclose(clean.observations, noisy.observations)  # the noise changed states
    for obs, act in zip(noisy.observations, noisy.actions, strict=False):  # ... not the labels
        np.testing.assert_allclose(act, expert_action(obs))


def test_valve_teacher_episode_records_the_mujoco_state_it_visited(tmp_path):
    import lowcostdex.teachers.valve  # noqa: F401  (an import error fails, never skips)
    from lowcostdex.sim.envs import goal_to_action
    from lowcostdex.teachers.valve import ValveTurnTeacher

    class Teacher:
        def __init__(self):
            self.solver = ValveTurnTeacher()

        def reset(self, env):
            self.solver.reset(env.unwrapped)

        def __call__(self, env, obs):
            u = env.unwrapped
            goals = self.solver(u.backend.observed_qpos(), u.goal)
            return goal_to_action(goals, u.task.hand_low, u.task.hand_high)

    env_id = "lowcostdex/DClawTurnValve-v0"
    env = gym.make(env_id)
    (ep,) = teacher_episodes(env, Teacher(), seeds=[3])
    path = save_demos(tmp_path / "valve.h5", [ep], DatasetInfo.from_env(env, "scripted_teacher"))
    info, _, _ = read_info(path)
    u = env.unwrapped
    assert (info.env_id, info.source) == (env_id, "scripted_teacher")
    assert info.task == type(u.task).__name__
    assert info.action_joints == tuple(u.task.hand.joint_names) and info.obs_dim == 30
    (back,) = read_episodes(path)
    assert back.length == 40 and back.success[-1] and back.qpos.shape == (41, u.model.nq)
    np.testing.assert_allclose(back.time, u.control_period * np.arange(41))
    np.testing.assert_allclose(back.goal["angle"], ep.goal["angle"])
    # Replaying the recorded actions from the recorded seed visits the recorded states.
    obs, _ = env.reset(seed=ep.seed)
    np.testing.assert_allclose(back.qpos[0], u.data.qpos)
    for t in range(back.length):
        obs, reward, _, _, step_info = env.step(back.actions[t].astype(np.float32))
        np.testing.assert_allclose(back.qpos[t + 1], u.data.qpos, atol=1e-12)
        np.testing.assert_allclose(back.qvel[t + 1], u.data.qvel, atol=1e-12)
        np.testing.assert_allclose(back.observations[t + 1], obs)
        assert back.rewards[t] == pytest.approx(reward)
        assert back.success[t] == step_info["success"]
    env.close()
