"""Demonstration files and teacher recordings (BC/DAPG inputs)."""

from __future__ import annotations

import numpy as np
import pytest
from pointmass import expert_action, make_pointmass

from lowcostdex.algos.demos import Demos, load_demos, save_demos, teacher_episodes
from lowcostdex.errors import ConfigError


def test_round_trip_and_first_episodes(tmp_path):
    rng = np.random.default_rng(0)
    episodes = [(rng.normal(size=(t, 3)), rng.normal(size=(t, 2))) for t in (4, 6, 5)]
    demos = load_demos(save_demos(tmp_path / "d.npz", episodes))
    assert demos.n_episodes == 3 and demos.episode_ends.tolist() == [4, 10, 15]
    for (o, a), (o2, a2) in zip(episodes, demos.episodes(), strict=True):
        np.testing.assert_array_equal(o, o2)
        np.testing.assert_array_equal(a, a2)
    two = demos.first(2)
    assert two.n_episodes == 2 and len(two.actions) == 10


def test_bad_files_raise_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_demos(tmp_path / "missing.npz")
    np.savez(tmp_path / "bad.npz", observations=np.zeros((2, 3)))
    with pytest.raises(ConfigError, match="lacks"):
        load_demos(tmp_path / "bad.npz")
    with pytest.raises(ConfigError, match="inconsistent"):
        Demos(np.zeros((3, 2)), np.zeros((2, 1)), np.array([3]))


def test_teacher_episodes_keep_successful_runs():
    env = make_pointmass()
    episodes = teacher_episodes(env, lambda e, obs: expert_action(obs), seeds=[1, 2, 3])
    assert len(episodes) == 3
    for obs, act in episodes:
        assert obs.shape == (30, 3) and act.shape == (30, 1)
        np.testing.assert_allclose(act[0], expert_action(obs[0]))
    with pytest.raises(ConfigError, match="failed"):
        teacher_episodes(env, lambda e, obs: np.array([1.0]), seeds=[1], max_tries=2)


def test_noisy_execution_keeps_clean_teacher_labels():
    env = make_pointmass()
    clean = teacher_episodes(env, lambda e, obs: expert_action(obs), seeds=[4])
    noisy = teacher_episodes(env, lambda e, obs: expert_action(obs), seeds=[4], action_noise=0.3)
    again = teacher_episodes(env, lambda e, obs: expert_action(obs), seeds=[4], action_noise=0.3)
    (o1, _), (o2, a2), (o3, _) = clean[0], noisy[0], again[0]
    np.testing.assert_array_equal(o2, o3)  # the noise is seeded by the episode seed
    assert not np.allclose(o1, o2)  # the noise changed the visited states ...
    for obs, act in zip(o2, a2, strict=True):  # ... but the labels are the teacher's actions
        np.testing.assert_allclose(act, expert_action(obs))
