"""Behaviour cloning recovers a known policy and sets the statistics DAPG relies on."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lowcostdex.algos.bc import BCConfig, behavior_clone
from lowcostdex.algos.policy import GaussianMLPPolicy, PolicyConfig
from lowcostdex.errors import ConfigError

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _linear_demos(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    a_true = np.array([[0.3, -0.2, 0.1], [0.0, 0.25, -0.15]])
    b_true = np.array([0.1, -0.05])
    obs = rng.normal([2.0, -1.0, 0.5], [1.0, 3.0, 0.2], size=(n, 3))
    return obs, obs @ a_true.T + b_true, a_true, b_true


def test_bc_recovers_a_known_linear_policy():
    obs, actions, a_true, b_true = _linear_demos()
    policy = GaussianMLPPolicy(
        3, 2, PolicyConfig(hidden_sizes=()), torch.Generator().manual_seed(0)
    )
    stats = behavior_clone(
        policy, obs, actions, BCConfig(epochs=60, lr=1e-2), torch.Generator().manual_seed(1)
    )
    assert stats["bc_loss_after"] < 1e-6 < stats["bc_loss_before"]
    # Recover the map in the original units by probing the mean.
    x = torch.tensor(np.vstack([np.zeros(3), np.eye(3)]))
    mu = policy(x).detach().numpy()
    np.testing.assert_allclose(mu[0], b_true, atol=2e-4)
    np.testing.assert_allclose((mu[1:] - mu[0]).T, a_true, atol=2e-4)


def test_bc_fits_with_an_mlp_and_sets_demo_statistics():
    obs, actions, _, _ = _linear_demos()
    policy = GaussianMLPPolicy(
        3, 2, PolicyConfig(hidden_sizes=(32, 32)), torch.Generator().manual_seed(0)
    )
    stats = behavior_clone(
        policy, obs, actions, BCConfig(epochs=10), torch.Generator().manual_seed(1)
    )
    assert stats["bc_loss_after"] < 0.02 * stats["bc_loss_before"]
    np.testing.assert_allclose(policy.obs_norm.mean.numpy(), obs.mean(0))
    np.testing.assert_allclose(policy.obs_norm.std.numpy(), obs.std(0))
    assert bool(policy.obs_norm.frozen)
    np.testing.assert_allclose(policy.act_shift.numpy(), actions.mean(0))
    # exploration noise starts at the demo action spread (MSE loss leaves log_std alone)
    np.testing.assert_allclose(policy.log_std.detach().numpy(), np.log(actions.std(0)), rtol=1e-9)


def test_bc_mle_trains_the_noise_and_is_reproducible():
    obs, actions, _, _ = _linear_demos(500)
    actions = actions + np.random.default_rng(3).normal(0.0, 0.05, actions.shape)
    params = []
    for _ in range(2):
        policy = GaussianMLPPolicy(
            3, 2, PolicyConfig(hidden_sizes=(16,)), torch.Generator().manual_seed(0)
        )
        behavior_clone(
            policy,
            obs,
            actions,
            BCConfig(epochs=40, loss="mle", lr=3e-3),
            torch.Generator().manual_seed(1),
        )
        params.append(torch.nn.utils.parameters_to_vector(policy.parameters()).detach())
    assert torch.equal(params[0], params[1])
    std = np.exp(policy.log_std.detach().numpy())
    assert np.all(std < 0.5 * actions.std(0))  # shrank from the demo spread toward the noise


def test_bc_config_validates():
    with pytest.raises(ConfigError, match="'mse', 'mle'"):
        BCConfig(loss="l1")


def test_bc_residual_noise_is_what_the_clone_does_not_explain():
    obs, actions, _, _ = _linear_demos(1000)
    noise = np.array([0.2, 0.01])
    noisy = actions + np.random.default_rng(5).normal(0.0, 1.0, actions.shape) * noise
    policy = GaussianMLPPolicy(
        3, 2, PolicyConfig(hidden_sizes=()), torch.Generator().manual_seed(0)
    )
    behavior_clone(
        policy,
        obs,
        noisy,
        BCConfig(epochs=60, lr=1e-2, log_std="residual"),
        torch.Generator().manual_seed(1),
    )
    # the second dimension is clamped at min_log_std = -3
    np.testing.assert_allclose(np.exp(policy.log_std.detach().numpy()), [0.2, np.exp(-3)], rtol=0.1)
    kept = GaussianMLPPolicy(
        3, 2, PolicyConfig(hidden_sizes=(), init_log_std=-1.0), torch.Generator().manual_seed(0)
    )
    behavior_clone(
        kept, obs, noisy, BCConfig(epochs=1, log_std="keep"), torch.Generator().manual_seed(1)
    )
    np.testing.assert_array_equal(kept.log_std.detach().numpy(), [-1.0, -1.0])
