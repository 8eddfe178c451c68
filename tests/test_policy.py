"""Gaussian MLP policy, observation normalisation, value baseline."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lowcostdex.algos.baseline import BaselineConfig, MLPBaseline
from lowcostdex.algos.experiment import load_state, save_state
from lowcostdex.algos.policy import GaussianMLPPolicy, ObsNormalizer, PolicyConfig, gaussian_kl
from lowcostdex.errors import ConfigError

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _gen(seed):
    return torch.Generator().manual_seed(seed)


def test_mjrl_style_initialisation_and_seeding():
    cfg = PolicyConfig(hidden_sizes=(32, 32), init_log_std=-0.5)
    p1 = GaussianMLPPolicy(6, 3, cfg, _gen(0))
    p2 = GaussianMLPPolicy(6, 3, cfg, _gen(0))
    p3 = GaussianMLPPolicy(6, 3, cfg, _gen(1))
    v = [torch.nn.utils.parameters_to_vector(p.parameters()) for p in (p1, p2, p3)]
    assert torch.equal(v[0], v[1]) and not torch.equal(v[0], v[2])
    torch.testing.assert_close(p1.log_std.detach(), torch.full((3,), -0.5, dtype=torch.float64))
    obs = torch.randn(100, 6, generator=_gen(2), dtype=torch.float64)
    # last layer scaled by 1e-2: the initial mean is tiny compared with the noise
    assert float(p1(obs).detach().abs().max()) < 0.05
    # hidden layers keep PyTorch's default scale
    assert float(p1.linears[0].weight.detach().abs().max()) > 0.2


def test_policy_does_not_touch_the_global_rng():
    torch.manual_seed(123)
    expected = torch.rand(1)
    torch.manual_seed(123)
    GaussianMLPPolicy(4, 2, PolicyConfig(), _gen(0))
    assert torch.equal(torch.rand(1), expected)


def test_deterministic_mode_returns_mean_and_noise_needs_generator():
    p = GaussianMLPPolicy(4, 2, PolicyConfig(hidden_sizes=(8,)), _gen(0))
    obs = np.ones((3, 4))
    torch.testing.assert_close(
        p.act(obs, deterministic=True), p(torch.ones(3, 4, dtype=torch.float64))
    )
    with pytest.raises(ValueError, match="Generator"):
        p.act(obs)
    a1, a2 = p.act(obs, _gen(5)), p.act(obs, _gen(5))
    assert torch.equal(a1, a2)


def test_log_prob_and_kl_closed_forms():
    mean = torch.tensor([[0.3, -1.0]], dtype=torch.float64)
    log_std = torch.tensor([0.2, -0.4], dtype=torch.float64)
    x = torch.tensor([[0.5, 0.0]], dtype=torch.float64)
    p = GaussianMLPPolicy(1, 2, PolicyConfig(hidden_sizes=()), None)
    from torch.distributions import Normal

    ref = Normal(mean, torch.exp(log_std)).log_prob(x).sum(-1)
    from lowcostdex.algos.policy import gaussian_log_prob

    torch.testing.assert_close(gaussian_log_prob(mean, log_std, x), ref)
    m1, s1 = mean + 0.1, log_std - 0.3
    ref_kl = torch.distributions.kl_divergence(
        Normal(mean, log_std.exp()), Normal(m1, s1.exp())
    ).sum(-1)
    torch.testing.assert_close(gaussian_kl(mean, log_std, m1, s1), ref_kl)
    assert p.act_dim == 2


def test_running_normalizer_matches_full_batch_statistics():
    rng = np.random.default_rng(0)
    data = rng.normal([1.0, -3.0], [2.0, 0.5], size=(1000, 2))
    norm = ObsNormalizer(2)
    for chunk in np.array_split(data, [10, 11, 400]):
        norm.update(chunk)
    np.testing.assert_allclose(norm.mean.numpy(), data.mean(0), rtol=1e-12)
    np.testing.assert_allclose(norm.std.numpy(), data.std(0), rtol=1e-12)
    norm.set_stats([0.0, 0.0], [1.0, 1.0], freeze=True)
    norm.update(data)
    np.testing.assert_array_equal(norm.mean.numpy(), [0.0, 0.0])


def test_normalizer_update_preserves_the_policy_mean():
    p = GaussianMLPPolicy(3, 2, PolicyConfig(hidden_sizes=(16,), last_layer_scale=1.0), _gen(0))
    rng = np.random.default_rng(1)
    probe = torch.as_tensor(rng.normal(size=(50, 3)) * 5 + 2)
    before = p(probe).detach()
    p.update_obs_normalizer(rng.normal([4.0, -2.0, 0.0], [3.0, 0.2, 1.0], size=(200, 3)))
    assert float(p.obs_norm.mean[0]) == pytest.approx(4.0, abs=0.5)
    torch.testing.assert_close(p(probe).detach(), before, rtol=1e-10, atol=1e-12)


def test_snapshot_matches_torch_forward():
    p = GaussianMLPPolicy(5, 3, PolicyConfig(hidden_sizes=(8, 8), last_layer_scale=1.0), _gen(3))
    p.update_obs_normalizer(np.random.default_rng(0).normal(size=(30, 5)))
    snap = p.snapshot()
    obs = np.random.default_rng(1).normal(size=(4, 5))
    expected = p(torch.as_tensor(obs)).detach().numpy()
    for i in range(4):
        np.testing.assert_allclose(snap.mean(obs[i]), expected[i], rtol=1e-12, atol=1e-14)
    noise = np.ones(3)
    np.testing.assert_allclose(
        snap.act(obs[0], noise), expected[0] + np.exp(p.log_std.detach().numpy())
    )


def test_checkpoint_round_trip_is_weights_only(tmp_path):
    p = GaussianMLPPolicy(4, 2, PolicyConfig(hidden_sizes=(8,)), _gen(0))
    p.update_obs_normalizer(np.random.default_rng(0).normal(size=(10, 4)))
    save_state(tmp_path / "p.pt", {"policy": p.to_checkpoint()})
    q = GaussianMLPPolicy.from_checkpoint(load_state(tmp_path / "p.pt")["policy"])
    obs = torch.randn(5, 4, generator=_gen(1), dtype=torch.float64)
    torch.testing.assert_close(q(obs), p(obs), rtol=0, atol=0)
    assert q.config == p.config


def test_policy_config_validates():
    with pytest.raises(ConfigError, match="'tanh', 'relu'"):
        PolicyConfig(activation="elu")
    with pytest.raises(ConfigError, match="init_log_std"):
        PolicyConfig(init_log_std=-5.0)


def test_baseline_predicts_zero_until_fitted_then_fits_returns():
    horizon = 20
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(2000, 3))
    t = rng.integers(0, horizon, size=2000)
    target = 10.0 + 5.0 * obs[:, 0] - 3.0 * (t / horizon)  # depends on state and time
    b = MLPBaseline(3, horizon, BaselineConfig(epochs=30), _gen(0))
    np.testing.assert_array_equal(b.predict(obs[:5], t[:5]), np.zeros(5))
    stats = b.fit(obs, t, target, _gen(1))
    assert stats["vf_error_before"] > 1.0  # zeros are worse than the mean
    assert stats["vf_error_after"] < 0.02


def test_baseline_target_rescaling_keeps_predictions():
    b = MLPBaseline(2, 10, BaselineConfig(epochs=1), _gen(0))
    rng = np.random.default_rng(0)
    obs, t = rng.normal(size=(64, 2)), rng.integers(0, 10, 64)
    b.fit(obs, t, rng.normal(size=64), _gen(1))
    before = b.predict(obs, t)
    b._rescale_targets(torch.as_tensor(rng.normal(100.0, 30.0, size=64)))
    np.testing.assert_allclose(b.predict(obs, t), before, rtol=1e-10, atol=1e-10)
