"""NPG maths against known answers: CG, Fisher-vector product, step size and KL, GAE."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.func import functional_call, grad, jacrev, vmap

from lowcostdex.algos import npg
from lowcostdex.algos.policy import GaussianMLPPolicy, PolicyConfig, gaussian_log_prob
from lowcostdex.algos.returns import discounted_returns, gae, whiten
from lowcostdex.errors import ConfigError

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _policy(seed=0, obs_dim=3, act_dim=2, hidden=(5,), init_log_std=-0.3):
    cfg = PolicyConfig(hidden_sizes=hidden, init_log_std=init_log_std, last_layer_scale=1.0)
    return GaussianMLPPolicy(obs_dim, act_dim, cfg, torch.Generator().manual_seed(seed))


def _batch(policy, n=64, seed=1):
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(n, policy.obs_dim, generator=g, dtype=torch.float64)
    actions = policy.act(obs, generator=g)
    adv = torch.randn(n, generator=g, dtype=torch.float64)
    return obs, actions, adv


@pytest.mark.parametrize("n", [1, 2, 5, 12])
def test_conjugate_gradient_equals_direct_solve(n):
    rng = np.random.default_rng(n)
    m = rng.standard_normal((n, n))
    a = m @ m.T + 0.1 * np.eye(n)  # SPD
    b = rng.standard_normal(n)
    a_t, b_t = torch.tensor(a), torch.tensor(b)
    x = npg.conjugate_gradient(lambda v: a_t @ v, b_t, iters=n, residual_tol=0.0)
    np.testing.assert_allclose(x.numpy(), np.linalg.solve(a, b), rtol=1e-6, atol=1e-9)


def test_truncated_conjugate_gradient_satisfies_x_a_x_equals_b_x():
    # The property that makes alpha = sqrt(delta / g^T x) give KL = delta/2 for any truncation.
    rng = np.random.default_rng(0)
    m = rng.standard_normal((30, 30))
    a = torch.tensor(m @ m.T + np.eye(30))
    b = torch.tensor(rng.standard_normal(30))
    for iters in (1, 3, 7):
        x = npg.conjugate_gradient(lambda v: a @ v, b, iters=iters)
        assert float(x @ a @ x) == pytest.approx(float(b @ x), rel=1e-9)


def _explicit_fisher(policy, obs):
    """sum_i J_i^T diag(1/sigma^2) J_i / n for the mean parameters, 2 I for log_std."""
    names = [name for name, _ in policy.named_parameters()]
    params = {name: p.detach() for name, p in policy.named_parameters()}

    def mean_of(flat_params, x):
        return functional_call(policy, {**dict(policy.named_buffers()), **flat_params}, (x,))

    jac = jacrev(mean_of)(params, obs)  # name -> (n, act_dim, *param_shape)
    n, act_dim = obs.shape[0], policy.act_dim
    j = torch.cat([jac[name].reshape(n, act_dim, -1) for name in names], dim=2)  # (n, m, P)
    inv_var = torch.exp(-2 * policy.log_std.detach())
    fisher = torch.einsum("nap,a,naq->pq", j, inv_var, j) / n
    offset = 0
    for name, p in policy.named_parameters():
        if name == "log_std":
            break
        offset += p.numel()
    idx = torch.arange(offset, offset + act_dim)
    fisher[idx, idx] += 2.0
    return fisher


def test_fisher_vector_product_equals_explicit_fisher():
    policy = _policy()
    obs, _, _ = _batch(policy, n=20)
    damping = 1e-3
    fvp = npg.make_fisher_vector_product(policy, obs, damping)
    n_params = sum(p.numel() for p in policy.parameters())
    fvp_matrix = torch.stack([fvp(e) for e in torch.eye(n_params, dtype=torch.float64)], dim=1)
    expected = _explicit_fisher(policy, obs) + damping * torch.eye(n_params, dtype=torch.float64)
    torch.testing.assert_close(fvp_matrix, expected, rtol=1e-9, atol=1e-11)


def test_fisher_is_the_expected_outer_product_of_scores():
    # The analytic Fisher equals E_a[grad log pi grad log pi^T]; Monte Carlo over actions.
    policy = _policy(hidden=(3,), obs_dim=2, act_dim=1)
    obs = torch.randn(4, 2, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    n = 16_000
    obs_rep = obs.repeat(n // 4, 1)
    actions = policy.act(obs_rep, generator=torch.Generator().manual_seed(4))
    names = [name for name, _ in policy.named_parameters()]
    params = {name: p.detach() for name, p in policy.named_parameters()}
    buffers = dict(policy.named_buffers())

    def log_prob(p, o, a):
        mean = functional_call(policy, {**buffers, **p}, (o[None],))
        return gaussian_log_prob(mean, p["log_std"], a[None])[0]

    per_sample = vmap(grad(log_prob), in_dims=(None, 0, 0))(params, obs_rep, actions)
    s = torch.cat([per_sample[name].reshape(n, -1) for name in names], dim=1)  # (n, P)
    mc = s.T @ s / n
    exact = _explicit_fisher(policy, obs)
    assert float(torch.linalg.norm(mc - exact) / torch.linalg.norm(exact)) < 0.05


@pytest.mark.parametrize("hidden", [(16,), (32, 32)])
@pytest.mark.parametrize("delta", [0.01, 0.05])
def test_npg_step_kl_is_about_half_delta(hidden, delta):
    # mjrl defaults: 10 CG iterations, damping 1e-4. The policy starts near zero mean, as
    # after mjrl's initialisation.
    cfg_p = PolicyConfig(hidden_sizes=hidden, init_log_std=-0.3)
    policy = GaussianMLPPolicy(3, 2, cfg_p, torch.Generator().manual_seed(0))
    obs, actions, adv = _batch(policy, n=1000)
    cfg = npg.NPGConfig(step_size=delta)
    stats = npg.npg_update(policy, obs, actions, adv, cfg)
    assert stats["kl"] == pytest.approx(delta / 2, rel=0.1)
    assert stats["alpha"] == pytest.approx(np.sqrt(delta / stats["g_f_g"]))
    assert stats["surr_improvement"] > 0


def test_normalized_step_size_formula():
    g = torch.tensor([1.0, 2.0])
    x = torch.tensor([0.5, 0.25])  # g^T x = 1
    assert npg.normalized_step_size(g, x, 0.05) == pytest.approx(np.sqrt(0.05))


def test_kl_check_backtracks_below_bound():
    policy = _policy(hidden=(8,))
    obs, actions, adv = _batch(policy, n=100)
    cfg = npg.NPGConfig(step_size=0.05, max_kl=0.005, backtrack_ratio=0.5)
    stats = npg.npg_update(policy, obs, actions, adv, cfg)
    assert stats["n_backtracks"] >= 1
    assert 0 < stats["kl"] <= 0.005
    measured = []
    alpha, kl, n = npg.backtrack_kl(lambda a: measured.append(a) or a**2, 1.0, 0.01, 0.5, 10)
    assert measured == [1.0, 0.5, 0.25, 0.125, 0.0625] and n == 4 and kl == 0.0625**2


def test_rejected_step_restores_parameters():
    policy = _policy(hidden=(4,))
    obs, actions, adv = _batch(policy, n=50)
    before = torch.nn.utils.parameters_to_vector(policy.parameters()).detach().clone()
    cfg = npg.NPGConfig(step_size=0.05, max_kl=1e-12, max_backtracks=2)
    stats = npg.npg_update(policy, obs, actions, adv, cfg)
    assert stats["alpha"] == 0.0
    assert torch.equal(torch.nn.utils.parameters_to_vector(policy.parameters()), before)


def test_npg_update_is_reproducible_and_subsamples_with_the_generator():
    cfg = npg.NPGConfig(fvp_sample_frac=0.5)
    results = []
    for _ in range(2):
        policy = _policy(seed=5, hidden=(8,))
        obs, actions, adv = _batch(policy, n=80, seed=6)
        npg.npg_update(policy, obs, actions, adv, cfg, generator=torch.Generator().manual_seed(9))
        results.append(torch.nn.utils.parameters_to_vector(policy.parameters()).detach())
    assert torch.equal(results[0], results[1])
    with pytest.raises(ValueError, match="Generator"):
        npg.npg_update(policy, obs, actions, adv, cfg)


def test_npg_config_validates():
    with pytest.raises(ConfigError, match="step_size"):
        npg.NPGConfig(step_size=0)
    with pytest.raises(ConfigError, match="fvp_sample_frac"):
        npg.NPGConfig(fvp_sample_frac=1.5)


def test_gae_matches_hand_computed_example():
    r = np.array([1.0, 0.0, 2.0])
    v = np.array([0.5, 1.0, 1.5])
    # deltas: 1 + .9*1 - .5 = 1.4 ; 0 + .9*1.5 - 1 = .35 ; 2 + .9*2 - 1.5 = 2.3 (truncated, V_T=2)
    np.testing.assert_allclose(
        gae(r, v, 2.0, 0.9, 0.8), [1.4 + 0.72 * 2.006, 0.35 + 0.72 * 2.3, 2.3]
    )
    # terminated: V_T = 0 -> last delta 0.5
    np.testing.assert_allclose(gae(r, v, 0.0, 0.9, 0.8), [1.4 + 0.72 * 0.71, 0.71, 0.5])
    # lambda = 1: returns minus values; lambda = 0: one-step TD errors
    np.testing.assert_allclose(gae(r, v, 2.0, 0.9, 1.0), discounted_returns(r, 0.9, 2.0) - v)
    np.testing.assert_allclose(gae(r, v, 2.0, 0.9, 0.0), [1.4, 0.35, 2.3])
    np.testing.assert_allclose(
        discounted_returns(r, 0.9, 2.0), [1 + 0.81 * 2 + 0.729 * 2, 0.9 * 2 + 0.81 * 2, 2 + 0.9 * 2]
    )


def test_whiten():
    w = whiten(np.array([1.0, 2.0, 3.0, 6.0]))
    assert w.mean() == pytest.approx(0.0, abs=1e-12) and w.std() == pytest.approx(1.0, rel=1e-5)


def test_backtracking_gives_up_after_exactly_max_backtracks_more_trials():
    """Issue 19: the give-up count. 1 + max_backtracks trials, then (0, 0, max_backtracks + 1)."""
    tried = []
    alpha, kl, n = npg.backtrack_kl(lambda a: tried.append(a) or 1.0, 2.0, 0.5, 0.5, 3)
    assert tried == [2.0, 1.0, 0.5, 0.25] and (alpha, kl, n) == (0.0, 0.0, 4)
    # KL equal to the bound is accepted (<=): kl(a) = a, bound 0.512 = 0.8**3 exactly reachable
    alpha, kl, n = npg.backtrack_kl(lambda a: a, 1.0, 0.8**3, 0.8, 10)
    assert n == 3 and alpha == pytest.approx(0.512)


def test_conjugate_gradient_stops_on_the_residual_tolerance():
    """r^T r below the tolerance stops CG before any product; equal to it does not."""
    calls = []

    def twice(v):
        calls.append(1)
        return 2.0 * v

    b = torch.tensor([0.5], dtype=torch.float64)          # r^T r = 0.25 at x = 0
    x = npg.conjugate_gradient(twice, b, iters=10, residual_tol=0.25)
    assert x.item() == pytest.approx(0.25) and len(calls) == 1   # one step solves 2x = 0.5
    calls.clear()
    x = npg.conjugate_gradient(twice, b, iters=10, residual_tol=0.2500001)
    assert x.item() == 0.0 and calls == []
    # 3x3 SPD system, tolerance never reached: exactly `iters` products
    a = torch.tensor([[4.0, 1, 0], [1, 3, 1], [0, 1, 2]], dtype=torch.float64)
    calls.clear()
    npg.conjugate_gradient(lambda v: calls.append(1) or a @ v,
                           torch.tensor([1.0, 2, 3], dtype=torch.float64), iters=2,
                           residual_tol=0.0)
    assert len(calls) == 2


@pytest.mark.parametrize("frac, n, expected", [(0.25, 40, 10), (0.26, 40, 10), (0.01, 40, 1),
                                               (0.5, 81, 40)])
def test_fisher_subsample_size(monkeypatch, frac, n, expected):
    """The Fisher uses round(frac * N) observations (at least 1), drawn without replacement."""
    seen = []
    real = npg.make_fisher_vector_product

    def spy(policy, obs, damping):
        seen.append(obs)
        return real(policy, obs, damping)

    monkeypatch.setattr(npg, "make_fisher_vector_product", spy)
    policy = _policy(hidden=(4,))
    obs, actions, adv = _batch(policy, n=n)
    npg.npg_update(policy, obs, actions, adv, npg.NPGConfig(fvp_sample_frac=frac),
                   generator=torch.Generator().manual_seed(0))
    (used,) = seen
    assert used.shape[0] == expected
    assert len({tuple(r.tolist()) for r in used}) == expected        # no repeats
    rows = {tuple(r.tolist()) for r in obs}
    assert all(tuple(r.tolist()) in rows for r in used)


def test_defaults_are_mjrls_cg_and_backtracking_settings():
    """mjrl's cg_solve (10 iterations, residual_tol 1e-10) and TRPO line search (ratio 0.8,
    10 backtracks after the first trial) as the functions' defaults, counted from outside."""
    calls = []
    a = torch.tensor(np.diag(np.arange(1.0, 31.0)))      # 30 distinct eigenvalues: CG needs 30
    b = torch.ones(30, dtype=torch.float64)
    npg.conjugate_gradient(lambda v: calls.append(1) or a @ v, b)
    assert len(calls) == 10
    # r^T r just below / above 1e-10 at x = 0: no product / one product
    calls.clear()
    x = npg.conjugate_gradient(lambda v: calls.append(1) or 2.0 * v,
                               torch.tensor([0.99e-5], dtype=torch.float64))
    assert calls == [] and x.item() == 0.0
    x = npg.conjugate_gradient(lambda v: calls.append(1) or 2.0 * v,
                               torch.tensor([1.01e-5], dtype=torch.float64))
    assert calls == [1] and x.item() == pytest.approx(0.505e-5)
    tried = []
    assert npg.backtrack_kl(lambda s: tried.append(s) or 1.0, 1.0, 0.5) == (0.0, 0.0, 11)
    np.testing.assert_allclose(tried, 0.8 ** np.arange(11))


def test_zero_gradient_gives_a_finite_step_length_and_no_step():
    g = torch.zeros(3, dtype=torch.float64)
    assert npg.normalized_step_size(g, g, 0.05) == pytest.approx(np.sqrt(0.05 / 1e-20))
    policy = _policy(hidden=(4,))
    obs, actions, _ = _batch(policy, n=30)
    before = torch.nn.utils.parameters_to_vector(policy.parameters()).detach().clone()
    stats = npg.natural_gradient_step(policy, torch.zeros_like(before), obs, npg.NPGConfig())
    assert torch.equal(torch.nn.utils.parameters_to_vector(policy.parameters()), before)
    assert stats["g_f_g"] == 0.0 and stats["kl"] == 0.0


def test_surrogate_gradient_is_the_mean_score_times_weight_by_hand():
    """(1/N) sum_i w_i grad log pi(a_i|s_i), each score from its own backward pass; N = the
    number of samples by default (N != obs_dim here), else the given normaliser."""
    policy = _policy(obs_dim=3, hidden=(4,))
    obs, actions, w = _batch(policy, n=7)
    params = list(policy.parameters())
    expected = torch.zeros(sum(p.numel() for p in params), dtype=torch.float64)
    for i in range(7):
        lp = policy.log_prob(obs[i:i + 1], actions[i:i + 1])[0]
        expected += w[i] * npg.flat_grad(lp, params)
    torch.testing.assert_close(npg.surrogate_gradient(policy, obs, actions, w), expected / 7)
    torch.testing.assert_close(npg.surrogate_gradient(policy, obs, actions, w, normalizer=2),
                               expected / 2)


def test_flat_grad_puts_zeros_for_parameters_the_output_does_not_use():
    a = torch.nn.Parameter(torch.tensor([1.0, 2.0]))
    unused = torch.nn.Parameter(torch.tensor([5.0, 6.0, 7.0]))
    g = npg.flat_grad((a**2).sum(), [a, unused])
    torch.testing.assert_close(g, torch.tensor([2.0, 4.0, 0.0, 0.0, 0.0]))


def test_step_statistics_by_their_definitions():
    """The reported numbers, recomputed from outside: ||g||, g^T x, the CG residual
    ||F x - g|| / ||g|| (with x from CG run the same way), surrogate before/after, and the
    backtrack count with and without the KL check."""
    policy = _policy(hidden=(6,))
    obs, actions, adv = _batch(policy, n=60)
    cfg = npg.NPGConfig(step_size=0.05, cg_iters=3)
    white = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-6)
    grad = npg.surrogate_gradient(policy, obs, actions, white)
    fvp = npg.make_fisher_vector_product(policy, obs, cfg.damping)
    x = npg.conjugate_gradient(fvp, grad, 3, cfg.cg_residual_tol)
    residual = float(torch.linalg.norm(fvp(x) - grad) / torch.linalg.norm(grad))
    logp_old = policy.log_prob(obs, actions).detach()
    stats = npg.npg_update(policy, obs, actions, adv, cfg)
    assert stats["grad_norm"] == pytest.approx(float(torch.linalg.norm(grad)), rel=1e-9)
    assert stats["g_f_g"] == pytest.approx(float(grad @ x), rel=1e-9)
    assert 1e-3 < residual < 1 and stats["cg_residual"] == pytest.approx(residual, rel=1e-6)
    assert stats["n_backtracks"] == 0.0
    assert stats["surr_before"] == pytest.approx(float(white.mean()), abs=1e-12)
    with torch.no_grad():
        after = float((torch.exp(policy.log_prob(obs, actions) - logp_old) * white).mean())
    assert stats["surr_after"] == pytest.approx(after, rel=1e-9)
    assert stats["surr_improvement"] == pytest.approx(after - stats["surr_before"], rel=1e-9)
    # a huge residual tolerance stops CG at x = 0: no step at all
    policy = _policy(hidden=(6,))
    before = torch.nn.utils.parameters_to_vector(policy.parameters()).detach().clone()
    stats = npg.npg_update(policy, obs, actions, adv, npg.NPGConfig(cg_residual_tol=1e30))
    assert stats["g_f_g"] == 0.0
    assert torch.equal(torch.nn.utils.parameters_to_vector(policy.parameters()), before)
    # KL check that rejects every trial: 1 + max_backtracks trials counted
    stats = npg.npg_update(_policy(hidden=(6,)), obs, actions, adv,
                           npg.NPGConfig(max_kl=1e-15, max_backtracks=2))
    assert stats["n_backtracks"] == 3.0 and stats["alpha"] == 0.0


def test_numpy_float32_batches_give_the_float64_policy_the_same_step():
    """The samplers hand over numpy arrays; a float32 batch is converted to the policy's dtype
    (the same update as from float64 tensors of the same numbers)."""
    results = []
    for as_numpy in (False, True):
        policy = _policy(seed=2, hidden=(5,))
        obs, actions, adv = _batch(policy, n=40, seed=3)
        obs, actions, adv = (t.float().double() for t in (obs, actions, adv))
        if as_numpy:
            obs, actions, adv = (t.float().numpy() for t in (obs, actions, adv))
        npg.npg_update(policy, obs, actions, adv, npg.NPGConfig())
        results.append(torch.nn.utils.parameters_to_vector(policy.parameters()).detach())
    assert results[1].dtype == torch.float64
    torch.testing.assert_close(results[0], results[1], rtol=1e-12, atol=1e-14)


def _gauss(x, mean, std):
    return np.exp(-0.5 * ((x - mean) / std) ** 2) / (std * np.sqrt(2 * np.pi))


def test_unnormalised_advantages_step_and_surrogate_improvement_by_hand():
    """Issue 19: ``normalize_advantages=False`` on a case small enough to do by hand. A linear
    policy (no hidden layer) with 1-D observation and action sees the observation 0 only, so its
    mean is the bias b (the weight has zero gradient and zero Fisher) and its parameters that
    matter are (b, s = log std). Per sample, d log N(a; b, e^s) / db = (a - b) / sigma^2 and
    / ds = (a - b)^2 / sigma^2 - 1; the Fisher of (b, s) is diag(1 / sigma^2, 2) (+ damping).
    With the raw advantages A = (1, 2, 3, 6) the surrogate starts at mean(A) = 3 (whitened it
    would start at 0), and a step of KL ~ delta / 2 along F^-1 g raises it by a little: the
    improvement is after - before, small and positive, not after + before (~ 6)."""
    policy = GaussianMLPPolicy(1, 1, PolicyConfig(hidden_sizes=(), init_log_std=np.log(0.5)),
                               generator=None)  # weight and bias 0: mean b = 0
    obs = torch.zeros(4, 1, dtype=torch.float64)
    actions = torch.tensor([[0.5], [-0.25], [1.0], [0.0]], dtype=torch.float64)
    adv = np.array([1.0, 2.0, 3.0, 6.0])
    cfg = npg.NPGConfig(normalize_advantages=False)  # step_size 0.05, damping 1e-4
    stats = npg.npg_update(policy, obs, actions, adv, cfg)

    a, sigma, lam, delta = actions.numpy()[:, 0], 0.5, cfg.damping, cfg.step_size
    g_b = np.mean(adv * a / sigma**2)
    g_s = np.mean(adv * (a**2 / sigma**2 - 1.0))
    x_b, x_s = g_b / (1 / sigma**2 + lam), g_s / (2.0 + lam)  # (F + lam I)^-1 g
    g_f_g = g_b * x_b + g_s * x_s
    alpha = np.sqrt(delta / g_f_g)
    b1, s1 = alpha * x_b, np.log(sigma) + alpha * x_s
    after = np.mean(adv * _gauss(a, b1, np.exp(s1)) / _gauss(a, 0.0, sigma))
    assert stats["g_f_g"] == pytest.approx(g_f_g, rel=1e-8)
    assert float(policy.linears[0].bias.detach()[0]) == pytest.approx(b1, rel=1e-8)
    assert float(policy.log_std.detach()[0]) == pytest.approx(s1, rel=1e-8)
    assert float(policy.linears[0].weight.detach()[0, 0]) == 0.0
    assert stats["surr_before"] == pytest.approx(3.0, rel=1e-12)
    assert stats["surr_after"] == pytest.approx(after, rel=1e-8)
    assert stats["surr_improvement"] == pytest.approx(after - 3.0, rel=1e-6)
    assert 0.0 < stats["surr_improvement"] < 0.5 * 3.0
