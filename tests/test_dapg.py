"""DAPG: demo weight schedule, augmented gradient, Fisher from on-policy samples only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lowcostdex.algos import npg
from lowcostdex.algos.dapg import DAPGConfig, dapg_update, demo_weight
from lowcostdex.algos.policy import GaussianMLPPolicy, PolicyConfig
from lowcostdex.errors import ConfigError

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _setup(seed=0, n=300, m=100):
    policy = GaussianMLPPolicy(
        3, 2, PolicyConfig(hidden_sizes=(16,)), torch.Generator().manual_seed(seed)
    )
    g = torch.Generator().manual_seed(seed + 1)
    obs = torch.randn(n, 3, generator=g, dtype=torch.float64)
    actions = policy.act(obs, generator=g)
    adv = torch.randn(n, generator=g, dtype=torch.float64)
    demo_obs = torch.randn(m, 3, generator=g, dtype=torch.float64)
    demo_actions = 0.5 * torch.tanh(demo_obs[:, :2])  # a teacher the random policy does not match
    return policy, obs, actions, adv, demo_obs, demo_actions


def test_demo_weight_decays_as_configured():
    adv = np.array([-1.0, 0.5, 2.0])
    w = [demo_weight(k, 0.1, 0.95, adv, "paper") for k in range(30)]
    assert w[0] == pytest.approx(0.1 * 2.0)  # lam0 * max advantage
    np.testing.assert_allclose(np.array(w[1:]) / np.array(w[:-1]), 0.95)
    assert demo_weight(5, 0.01, 0.9, adv, "mjrl") == pytest.approx(0.01 * 0.9**5)
    # mjrl form ignores the advantages; paper form scales with them
    assert demo_weight(3, 0.01, 0.9, 10 * adv, "mjrl") == demo_weight(3, 0.01, 0.9, adv, "mjrl")
    assert demo_weight(3, 0.1, 0.9, 10 * adv, "paper") == pytest.approx(
        10 * demo_weight(3, 0.1, 0.9, adv, "paper")
    )
    with pytest.raises(ConfigError, match="'paper', 'mjrl'"):
        demo_weight(0, 0.1, 0.9, adv, "other")


def test_dapg_update_reports_the_decayed_weight_each_iteration():
    cfg, ncfg = DAPGConfig(lam0=0.1, lam1=0.5), npg.NPGConfig()
    weights = []
    for k in range(4):
        policy, obs, actions, adv, d_obs, d_act = _setup()
        stats = dapg_update(policy, obs, actions, adv, d_obs, d_act, k, cfg, ncfg)
        weights.append(stats["demo_weight"])
    white = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-6)
    np.testing.assert_allclose(weights, [0.1 * 0.5**k * float(white.max()) for k in range(4)])


def test_zero_demo_weight_is_exactly_npg_so_the_fisher_ignores_demos():
    ncfg = npg.NPGConfig()
    p1, obs, actions, adv, d_obs, d_act = _setup()
    p2, *_ = _setup()
    dapg_update(p1, obs, actions, adv, d_obs, d_act, 0, DAPGConfig(lam0=0.0), ncfg)
    npg.npg_update(p2, obs, actions, adv, ncfg)
    v1 = torch.nn.utils.parameters_to_vector(p1.parameters())
    v2 = torch.nn.utils.parameters_to_vector(p2.parameters())
    # Equal up to summation order; a Fisher that included the demos differs at O(1).
    torch.testing.assert_close(v1, v2, rtol=1e-6, atol=1e-8)


def test_augmented_gradient_adds_the_weighted_demo_term():
    policy, obs, actions, adv, d_obs, d_act = _setup()
    white = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-6)
    w = 0.7
    params = list(policy.parameters())
    rl = sum(
        npg.flat_grad(policy.log_prob(obs[i : i + 1], actions[i : i + 1])[0] * white[i], params)
        for i in range(len(obs))
    )
    demo = sum(
        npg.flat_grad(policy.log_prob(d_obs[i : i + 1], d_act[i : i + 1])[0] * w, params)
        for i in range(len(d_obs))
    )
    expected = (rl + demo) / len(obs)
    got = npg.surrogate_gradient(
        policy,
        torch.cat([obs, d_obs]),
        torch.cat([actions, d_act]),
        torch.cat([white, torch.full((len(d_obs),), w, dtype=torch.float64)]),
        normalizer=len(obs),
    )
    torch.testing.assert_close(got, expected, rtol=1e-10, atol=1e-12)


def test_demo_term_pulls_the_policy_toward_the_demos():
    ncfg = npg.NPGConfig(step_size=0.05)
    lik = {}
    for lam0 in (0.0, 1.0):
        policy, obs, actions, adv, d_obs, d_act = _setup()
        stats = dapg_update(policy, obs, actions, adv, d_obs, d_act, 0, DAPGConfig(lam0=lam0), ncfg)
        lik[lam0] = stats["demo_log_lik"]
        # same trust region either way (delta/2 to second order)
        assert stats["kl"] == pytest.approx(0.025, rel=0.5)
    assert lik[1.0] > lik[0.0] + 0.05


def test_dapg_config_validates():
    with pytest.raises(ConfigError, match="lam1"):
        DAPGConfig(lam1=1.5)


def test_demo_weight_by_hand_when_the_largest_advantage_is_below_one_or_negative():
    """Issue 19: w_k = lam0 lam1^k max(A) (paper) also when max(A) < 1, 0 when all A < 0;
    the mjrl form is lam0 lam1^k whatever the advantages."""
    assert demo_weight(2, 0.1, 0.95, np.array([-0.3, 0.5, 0.2]), "paper") == pytest.approx(
        0.1 * 0.9025 * 0.5)
    assert demo_weight(0, 0.1, 0.95, np.array([-0.3, -0.1]), "paper") == 0.0
    assert demo_weight(3, 0.01, 0.95, np.array([-5.0, -1.0]), "mjrl") == pytest.approx(
        0.01 * 0.857375)
    with pytest.raises(ValueError, match="k=-1"):
        demo_weight(-1, 0.1, 0.95, np.array([1.0]), "paper")


def test_dapg_update_in_mjrl_mode_uses_the_constant_weight():
    cfg, ncfg = DAPGConfig(lam0=0.01, lam1=0.95, demo_weight="mjrl"), npg.NPGConfig()
    policy, obs, actions, adv, d_obs, d_act = _setup()
    stats = dapg_update(policy, obs, actions, adv, d_obs, d_act, 2, cfg, ncfg)
    assert stats["demo_weight"] == pytest.approx(0.01 * 0.95**2)


def test_augmented_gradient_is_normalised_by_the_on_policy_count_by_hand():
    """g_aug = (1/N) [sum_pi A grad log pi + w sum_D grad log pi] with N on-policy samples
    (not N + M): the reported gradient norm is that of this sum, computed per sample here."""
    policy, obs, actions, adv, d_obs, d_act = _setup(n=40, m=25)
    cfg, ncfg = DAPGConfig(lam0=0.1, lam1=0.95), npg.NPGConfig()
    white = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-6)
    w = 0.1 * float(white.max())
    params = list(policy.parameters())
    g = torch.zeros(sum(p.numel() for p in params), dtype=torch.float64)
    for o, a, weight in [*zip(obs, actions, white, strict=True),
                         *((o, a, w) for o, a in zip(d_obs, d_act, strict=True))]:
        g += weight * npg.flat_grad(policy.log_prob(o[None], a[None])[0], params)
    g /= 40
    stats = dapg_update(policy, obs, actions, adv, d_obs, d_act, 0, cfg, ncfg)
    assert stats["grad_norm"] == pytest.approx(float(torch.linalg.norm(g)), rel=1e-9)


def test_dapg_fisher_subsample_uses_the_given_generator():
    ncfg = npg.NPGConfig(fvp_sample_frac=0.5)
    results = []
    for _ in range(2):
        policy, obs, actions, adv, d_obs, d_act = _setup(seed=3, n=60, m=20)
        dapg_update(policy, obs, actions, adv, d_obs, d_act, 0, DAPGConfig(), ncfg,
                    generator=torch.Generator().manual_seed(4))
        results.append(torch.nn.utils.parameters_to_vector(policy.parameters()).detach())
    assert torch.equal(results[0], results[1])


def test_demo_weight_of_an_empty_batch_is_zero():
    assert demo_weight(0, 0.1, 0.95, np.zeros(0), "paper") == 0.0


def test_numpy_float32_demos_and_batch_give_the_float64_policy_the_same_step():
    results = []
    for as_numpy in (False, True):
        policy, *batch = _setup(seed=5, n=50, m=20)
        batch = [t.float().double() for t in batch]
        if as_numpy:
            batch = [t.float().numpy() for t in batch]
        obs, actions, adv, d_obs, d_act = batch
        dapg_update(policy, obs, actions, adv, d_obs, d_act, 1, DAPGConfig(), npg.NPGConfig())
        results.append(torch.nn.utils.parameters_to_vector(policy.parameters()).detach())
    assert results[1].dtype == torch.float64
    torch.testing.assert_close(results[0], results[1], rtol=1e-12, atol=1e-14)


def test_unnormalised_advantages_dapg_step_by_hand():
    """Issue 19: ``normalize_advantages=False`` in DAPG, by hand. A linear policy seeing only the
    observation 0 has mean b (its bias) and log std s; per sample d log N / db = (x - b) /
    sigma^2, d / ds = (x - b)^2 / sigma^2 - 1, and the on-policy Fisher of (b, s) is
    diag(1 / sigma^2, 2) (+ damping). The demo weight is lam0 lam1^k max(A) of the raw
    advantages (6 here; whitened it would be max((A - 3) / 1.87) = 1.6), the augmented gradient
    sums the on-policy and the weighted demo terms over the N = 4 on-policy samples."""
    policy = GaussianMLPPolicy(1, 1, PolicyConfig(hidden_sizes=(), init_log_std=np.log(0.5)),
                               generator=None)  # weight and bias 0: mean b = 0
    obs = torch.zeros(4, 1, dtype=torch.float64)
    actions = torch.tensor([[0.5], [-0.25], [1.0], [0.0]], dtype=torch.float64)
    adv = np.array([1.0, 2.0, 3.0, 6.0])
    d_obs = torch.zeros(2, 1, dtype=torch.float64)
    d_act = torch.tensor([[0.8], [0.6]], dtype=torch.float64)
    cfg = DAPGConfig(lam0=0.1, lam1=0.95)
    ncfg = npg.NPGConfig(normalize_advantages=False)  # step_size 0.05, damping 1e-4
    stats = dapg_update(policy, obs, actions, adv, d_obs, d_act, 2, cfg, ncfg)

    a, d, sigma, lam = actions.numpy()[:, 0], d_act.numpy()[:, 0], 0.5, ncfg.damping
    w = 0.1 * 0.95**2 * 6.0
    g_b = (np.sum(adv * a) + w * np.sum(d)) / sigma**2 / 4
    g_s = (np.sum(adv * (a**2 / sigma**2 - 1)) + w * np.sum(d**2 / sigma**2 - 1)) / 4
    x_b, x_s = g_b / (1 / sigma**2 + lam), g_s / (2.0 + lam)
    alpha = np.sqrt(ncfg.step_size / (g_b * x_b + g_s * x_s))
    b1, s1 = alpha * x_b, np.log(sigma) + alpha * x_s
    assert stats["demo_weight"] == pytest.approx(w, rel=1e-12)
    assert float(policy.linears[0].bias.detach()[0]) == pytest.approx(b1, rel=1e-8)
    assert float(policy.log_std.detach()[0]) == pytest.approx(s1, rel=1e-8)
    log_lik = -0.5 * ((d - b1) / np.exp(s1)) ** 2 - s1 - 0.5 * np.log(2 * np.pi)
    assert stats["demo_log_lik"] == pytest.approx(float(np.mean(log_lik)), rel=1e-8)
