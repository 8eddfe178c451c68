"""The main job's average over DAPG runs (``main_job.streams``): the weight average, the runs'
seeds. The truth is written out here: for a linear policy (no hidden layer) the mean action is
affine in the weights, so the weight average's mean action is the mean of the policies' mean
actions, computed here by hand with numpy from each policy's own weights."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lowcostdex.algos.configs import PolicyConfig
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import ConfigError
from lowcostdex.main_job.streams import average_weights, stream_seeds


def _policy(seed: int, hidden: tuple[int, ...] = ()) -> GaussianMLPPolicy:
    p = GaussianMLPPolicy(5, 3, PolicyConfig(hidden_sizes=hidden, last_layer_scale=1.0),
                          torch.Generator().manual_seed(seed))
    # the frozen demo statistics every run of one clone shares (BC sets and freezes them)
    p.obs_norm.set_stats(np.arange(1.0, 6.0), np.full(5, 2.0), freeze=True, count=10)
    with torch.no_grad():
        p.act_scale.copy_(torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64))
        p.act_shift.copy_(torch.tensor([0.1, -0.2, 0.0], dtype=torch.float64))
        p.log_std.fill_(-1.0 - seed)
    return p


def _mean_action_by_hand(p: GaussianMLPPolicy, obs: np.ndarray) -> np.ndarray:
    w = p.linears[0].weight.detach().numpy()
    b = p.linears[0].bias.detach().numpy()
    x = (obs - np.arange(1.0, 6.0)) / 2.0
    return (w @ x + b) * np.array([0.5, 1.0, 2.0]) + np.array([0.1, -0.2, 0.0])


def test_the_average_of_linear_policies_acts_as_the_mean_of_their_actions():
    pols = [_policy(s) for s in range(3)]
    avg = average_weights(pols)
    rng = np.random.default_rng(0)
    for obs in rng.normal(3.0, 2.0, size=(6, 5)):
        want = np.mean([_mean_action_by_hand(p, obs) for p in pols], axis=0)
        np.testing.assert_allclose(avg.snapshot().mean(obs), want, rtol=1e-12, atol=1e-12)
    # the exploration noise is averaged in log space: the mean of -1, -2, -3
    np.testing.assert_allclose(avg.log_std.detach().numpy(), -2.0)
    # the inputs are left as they were
    np.testing.assert_allclose(pols[0].log_std.detach().numpy(), -1.0)
    assert avg is not pols[0]


def test_one_policy_averages_to_itself_and_mismatches_are_refused():
    p = _policy(0, (4,))
    q = average_weights([p])
    obs = np.linspace(-1, 1, 5)
    np.testing.assert_array_equal(q.snapshot().mean(obs), p.snapshot().mean(obs))
    with pytest.raises(ConfigError, match="sizes"):
        average_weights([p, _policy(1, (6,))])
    other = _policy(1, (4,))
    other.obs_norm.frozen.fill_(False)
    with pytest.raises(ConfigError, match="frozen"):
        average_weights([p, other])
    with pytest.raises(ConfigError):
        average_weights([])


def test_stream_seeds_start_with_the_runs_seed_and_differ():
    s = stream_seeds(7, 4)
    assert s[0] == 7 and len(set(s)) == 4
    assert s == stream_seeds(7, 4) and s[:2] == stream_seeds(7, 2)
    assert all(0 <= x < 2**31 for x in s)
    assert stream_seeds(8, 3)[1:] != s[1:3]


def test_runs_start_from_one_clone_and_their_last_iterates_are_averaged(tmp_path):
    """Two tiny DAPG runs on the tests' point mass: each its own seed, both from the same clone
    (the same BC seed, so the same bc_policy.pt), the saved average is the mean of the two
    final policies' weights, and its validation count is its successes on the first run's
    validation episodes, rolled out here with the sampler's own rollout."""
    import json

    from pointmass import demo_info, expert_action, make_pointmass

    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import DAPGConfig, NPGConfig, TrainConfig
    from lowcostdex.algos.samplers import rollout
    from lowcostdex.algos.train import evaluation_jobs, load_policy, trajectory_success
    from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes
    from lowcostdex.main_job.streams import AVERAGE_FILE, train_streams

    demos = save_demos(tmp_path / "demos.h5", teacher_episodes(
        make_pointmass(), lambda env, obs: expert_action(obs), seeds=range(1000, 1006)),
        demo_info())
    config = TrainConfig(algo="dapg", env_id="test/PointMass", demos=str(demos), n_iter=2,
                         n_traj=4, eval_every=1, eval_episodes=4, eval_paired=True,
                         progress=False, seed=3, policy=PolicyConfig(hidden_sizes=(8,)),
                         npg=NPGConfig(step_size=0.05), dapg=DAPGConfig(lam0=0.01))
    res = train_streams(config, tmp_path / "train_dapg", 2, env_factory=make_pointmass)
    dirs = [tmp_path / "train_dapg", tmp_path / "train_dapg_run1"]
    assert [r["dir"] for r in res["runs"]] == [d.name for d in dirs]
    seeds = [json.loads((d / "config.json").read_text())["seed"] for d in dirs]
    assert seeds == stream_seeds(3, 2) and seeds[0] == 3
    assert {json.loads((d / "config.json").read_text())["bc_seed"] for d in dirs} == {3}
    clones = [load_policy(d / ex.BC_POLICY_FILE).state_dict() for d in dirs]
    for k in clones[0]:
        torch.testing.assert_close(clones[0][k], clones[1][k], rtol=0, atol=0)
    finals = [load_policy(d / ex.FINAL_POLICY_FILE).state_dict() for d in dirs]
    # other seeds, other training episodes: the runs end apart
    assert any(not torch.equal(finals[0][k], finals[1][k]) for k in finals[0])
    avg = load_policy(dirs[0] / AVERAGE_FILE).state_dict()
    for k, v in avg.items():
        if v.is_floating_point():
            torch.testing.assert_close(v, (finals[0][k] + finals[1][k]) / 2)
    snap = load_policy(dirs[0] / AVERAGE_FILE).snapshot()
    env = make_pointmass()
    solved = sum(trajectory_success(rollout(env, snap, job), config.success)
                 for job in evaluation_jobs(config, 0))
    assert res["average"] == {"file": f"train_dapg/{AVERAGE_FILE}", "eval_successes": solved,
                              "eval_episodes": 4, "eval_success": solved / 4}
