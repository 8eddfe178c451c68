"""Samplers: per-trajectory seeding makes results independent of the worker count."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from pointmass import HORIZON, broken_env, make_pointmass

from lowcostdex.algos.policy import GaussianMLPPolicy, PolicyConfig
from lowcostdex.algos.samplers import (
    ProcessSampler,
    RaySampler,
    SamplerError,
    SerialSampler,
    make_jobs,
    rollout,
)


def _snapshot(seed=0):
    cfg = PolicyConfig(hidden_sizes=(8,), init_log_std=-0.5, last_layer_scale=1.0)
    return GaussianMLPPolicy(3, 1, cfg, torch.Generator().manual_seed(seed)).snapshot()


def _assert_same(paths_a, paths_b):
    assert [p.index for p in paths_a] == [p.index for p in paths_b]
    for a, b in zip(paths_a, paths_b, strict=True):
        np.testing.assert_array_equal(a.observations, b.observations)
        np.testing.assert_array_equal(a.actions, b.actions)
        np.testing.assert_array_equal(a.rewards, b.rewards)


def test_rollout_records_a_truncated_episode_with_terms_and_time():
    env = make_pointmass()
    path = rollout(env, _snapshot(), make_jobs(0, 0, 0, 1)[0])
    assert len(path) == HORIZON and path.truncated and not path.terminated
    assert path.observations.shape == (HORIZON, 3) and path.actions.shape == (HORIZON, 1)
    assert path.reward_terms["reward_distance"] + path.reward_terms[
        "reward_effort"
    ] == pytest.approx(path.total_reward)
    assert path.robot_seconds == pytest.approx(HORIZON * 0.1)
    # the final observation is s_T, after the last action
    assert not np.array_equal(path.final_observation, path.observations[-1])


def test_trajectories_depend_on_index_not_on_order_or_batch():
    sampler = SerialSampler(make_pointmass)
    snap = _snapshot()
    jobs = make_jobs(seed=3, stream=0, iteration=2, n=4)
    forward = sampler.sample(snap, jobs)
    backward = sampler.sample(snap, jobs[::-1])[::-1]
    _assert_same(forward, backward)
    alone = sampler.sample(snap, [jobs[2]])
    _assert_same([forward[2]], alone)
    other_iter = sampler.sample(snap, make_jobs(3, 0, 3, 1))
    assert not np.array_equal(other_iter[0].observations, forward[0].observations)
    det = sampler.sample(snap, make_jobs(3, 0, 2, 1, deterministic=True))[0]
    np.testing.assert_allclose(det.actions[0], snap.mean(det.observations[0]))


def test_results_do_not_depend_on_the_number_of_workers():
    snap = _snapshot(1)
    jobs = make_jobs(seed=11, stream=0, iteration=0, n=7)
    serial = SerialSampler(make_pointmass).sample(snap, jobs)
    for n_workers in (3,):  # (test_train runs a 2-worker pool against a serial run)
        with ProcessSampler(make_pointmass, n_workers) as pool:
            _assert_same(serial, pool.sample(snap, jobs))
            # workers persist across iterations
            pids = [p.pid for p in pool._procs]
            pool.sample(snap, make_jobs(11, 0, 1, 2))
            assert [p.pid for p in pool._procs] == pids and all(p.is_alive() for p in pool._procs)


def test_worker_errors_surface_with_their_traceback():
    with ProcessSampler(broken_env, 1) as pool, pytest.raises(SamplerError, match="no robot here"):
        pool.sample(_snapshot(), make_jobs(0, 0, 0, 1))


@pytest.mark.slow  # starting Ray takes ~30 s on 2 cores
def test_ray_sampler_matches_serial():
    pytest.importorskip("ray", reason="ray (the 'ray' extra) is not installed")
    import ray

    snap = _snapshot(2)
    jobs = make_jobs(seed=5, stream=0, iteration=0, n=4)
    try:
        init = {
            "num_cpus": 2,
            "include_dashboard": False,
            # Ray workers do not inherit sys.path: make the test's env module importable.
            "runtime_env": {"env_vars": {"PYTHONPATH": str(Path(__file__).parent)}},
        }
        with RaySampler(make_pointmass, 2, ray_init_kwargs=init) as s:
            _assert_same(SerialSampler(make_pointmass).sample(snap, jobs), s.sample(snap, jobs))
    finally:
        ray.shutdown()


def test_vector_sampler_is_independent_of_num_envs_and_matches_serial():
    import lowcostdex.sim.vector  # noqa: F401  (an import error fails, never skips)
    from lowcostdex.algos.samplers import EnvFactory, VectorSampler

    env_id = "lowcostdex/DClawTurnValve-v0"
    cfg = PolicyConfig(hidden_sizes=(8,), init_log_std=-0.5, last_layer_scale=1.0)
    snap = GaussianMLPPolicy(30, 9, cfg, torch.Generator().manual_seed(0)).snapshot()
    jobs = make_jobs(seed=3, stream=0, iteration=0, n=5)
    by_n = {}
    for n in (2, 5):
        with VectorSampler(env_id, n, nthread=1) as sampler:
            by_n[n] = sampler.sample(snap, jobs)
    _assert_same(by_n[2], by_n[5])
    with SerialSampler(EnvFactory(env_id)) as serial:
        ref = serial.sample(snap, jobs)
    for a, b in zip(ref, by_n[2], strict=True):
        assert len(a) == len(b) == 40 and a.truncated and b.truncated
        # mujoco.batch vs one MjData: equal up to float32 observation rounding
        np.testing.assert_allclose(a.observations, b.observations, atol=1e-4)
        np.testing.assert_allclose(a.rewards, b.rewards, rtol=1e-4, atol=1e-4)
        assert a.reward_terms.keys() == b.reward_terms.keys()


class _RobotLikePointMass(gym.Wrapper):
    """Reports telemetry as lowcostdex robot backends do: reset time and cumulative pauses."""

    def __init__(self):
        super().__init__(make_pointmass())
        self.pause_total = 0.0
        self.episode = 0

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        pause = 30.0 if self.episode == 1 else 0.0  # a thermal pause before the 2nd episode
        self.pause_total += pause
        self.episode += 1
        info["telemetry"] = {"last_reset_time": 2.0 + pause, "pause_time": self.pause_total}
        return obs, info

    def step(self, action):
        obs, r, term, trunc, info = self.env.step(action)
        info["telemetry"] = {
            "pause_time": self.pause_total,
            "resets": float(self.episode),
            "current": np.ones(3),
        }
        return obs, r, term, trunc, info


def test_serial_sampler_accounts_robot_resets_and_thermal_pauses():
    with SerialSampler(_RobotLikePointMass) as sampler:
        paths = sampler.sample(_snapshot(), make_jobs(0, 0, 0, 3))
    np.testing.assert_allclose([p.robot_seconds for p in paths], [3.0 + 2.0, 3.0 + 32.0, 3.0 + 2.0])
    np.testing.assert_allclose([p.pause_seconds for p in paths], [0.0, 30.0, 0.0])
    assert paths[2].telemetry == {"pause_time": 30.0, "resets": 3.0}  # scalars only
