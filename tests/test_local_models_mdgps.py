"""MDGPS: distilling per-condition TVLG controllers into one neural policy.

Pure pieces against known answers (policy linearisation of a linear policy, the precision-weighted
loss by hand, the step rule's limits), then the algorithm on the torque-limited pendulum from
three start angles: the C-step's KL to the policy linearisation, the policy's cost on every
training condition, and an unseen start between two training ones.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lowcostdex.algos.configs import PolicyConfig
from lowcostdex.algos.local_models.conditions import PendulumConditions
from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import average_expansion
from lowcostdex.algos.local_models.dynamics import DynamicsConfig, fit_dynamics
from lowcostdex.algos.local_models.lqr import forward_pass, kl_per_step
from lowcostdex.algos.local_models.mdgps import (
    MDGPSConfig,
    PreviousCondition,
    controller_cost,
    controller_targets,
    linearize_policy,
    mdgps_step_mult,
    mse_loss,
    nearest_condition,
    policy_cost,
    policy_std_from_precision,
    precision_weighted_loss,
    train_mdgps,
    train_policy,
)
from lowcostdex.algos.local_models.pendulum import PendulumParams, pendulum_cost
from lowcostdex.algos.local_models.traj_opt import TrajOptConfig, kl_constrained_update
from lowcostdex.algos.local_models.tvlg import laplace_cost
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import ConfigError

P = PendulumParams()
T = P.T
COST = pendulum_cost(P)
STARTS = ((-1.0, 0.0), (0.0, 0.0), (1.0, 0.0))  # theta [rad], omega [rad/s]
UNSEEN = (0.6, 0.0)  # between the 2nd and 3rd training starts, nearest to the 3rd
CFG = MDGPSConfig(conditions=3, samples_per_condition=5, iterations=8, seed=0)


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread():
    """Small networks: one thread is fastest and immune to a busy machine (module scope, so it
    covers the shared training run too)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def zero_controller() -> LinearGaussianController:
    """Zero mean torque with unit variance: random actuation on the first iteration."""
    return LinearGaussianController.from_cov(
        np.zeros((T, 1, 2)), np.zeros((T, 1)), np.ones((T, 1, 1))
    )


def run(cfg: MDGPSConfig, sampler_seed: int = 0):
    sampler = PendulumConditions(STARTS[: cfg.conditions], P, seed=sampler_seed)
    return train_mdgps(sampler, [COST] * cfg.conditions, [zero_controller()] * cfg.conditions, cfg)


@pytest.fixture(scope="module")
def trained():
    """The 8-iteration pendulum run shared by the tests below (about 8 s on 2 cores)."""
    return run(CFG)


# ----------------------------------------------------------------------------------------------
# Pure pieces


def linear_policy(W: np.ndarray, b: np.ndarray, log_std: float) -> GaussianMLPPolicy:
    """A GaussianMLPPolicy without hidden layers: mean = W o + b exactly."""
    policy = GaussianMLPPolicy(W.shape[1], W.shape[0], PolicyConfig(hidden_sizes=()), None)
    with torch.no_grad():
        policy.linears[0].weight.copy_(torch.as_tensor(W))
        policy.linears[0].bias.copy_(torch.as_tensor(b))
        policy.log_std.fill_(log_std)
    return policy


def test_linearize_policy_recovers_a_linear_policy() -> None:
    # o = [x (3,), t / T]; u (2,) = W o + b, so K_t = W[:, :3] and k_t = b + W[:, 3] t / T.
    rng = np.random.default_rng(0)
    W = rng.normal(size=(2, 4))
    b = rng.normal(size=2)
    X = rng.normal(size=(6, 20, 3))
    policy = linear_policy(W, b, log_std=-1.0)
    lin = linearize_policy(policy, X, DynamicsConfig(use_prior=False), rng, True)
    tau = np.arange(20) / 20
    assert np.max(np.abs(lin.K - W[:, :3])) < 1e-4
    assert np.max(np.abs(lin.k - (b + np.outer(tau, W[:, 3])))) < 1e-4
    # The policy's own variance exp(2 log_std) on the diagonal; the fit residual is ~0.
    assert np.allclose(lin.cov, np.exp(-2.0) * np.eye(2), atol=1e-5)
    # A time-invariant policy also through the GMM prior (it pools all steps, which is only
    # unbiased when the policy does not depend on t): measured errors 3.5e-6 (K), 2.0e-6 (k).
    for use_prior in (True, False):
        lin_x = linearize_policy(
            linear_policy(W[:, :3], b, -1.0), X, DynamicsConfig(use_prior=use_prior), rng, False
        )
        assert np.max(np.abs(lin_x.K - W[:, :3])) < 1e-4
        assert np.max(np.abs(lin_x.k - b)) < 1e-4
        assert np.allclose(lin_x.cov, np.exp(-2.0) * np.eye(2), atol=1e-5)


def test_precision_weighted_loss_by_hand() -> None:
    mean = torch.tensor([[1.0, 2.0], [0.0, 1.0]])
    target = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    prec = torch.tensor([[[2.0, 0.0], [0.0, 1.0]], [[1.0, 0.5], [0.5, 1.0]]])
    # d1 = (1, 2): 2*1 + 1*4 = 6; d2 = (-1, 0): 1*1 = 1; mean 3.5.
    assert float(precision_weighted_loss(mean, target, prec)) == pytest.approx(3.5)
    # Plain squared error: (1 + 4 + 1) / 2 = 3.
    assert float(mse_loss(mean, target, prec)) == pytest.approx(3.0)
    # Policy std from the mean precision diagonal: mean(2, 1) = 1.5 and mean(1, 1) = 1.
    std = policy_std_from_precision(prec.numpy())
    assert np.allclose(std, [1 / np.sqrt(1.5), 1.0])


def test_s_step_fits_a_linear_controller_with_its_precision() -> None:
    # A controller u = -2 x0 + 0.5 x1 + 0.1 with variance 0.04; the linear policy learns it.
    rng = np.random.default_rng(1)
    K = np.broadcast_to([[-2.0, 0.5]], (T, 1, 2)).copy()
    ctl = LinearGaussianController.from_cov(K, np.full((T, 1), 0.1), np.full((T, 1, 1), 0.04))
    X = rng.normal(size=(5, T, 2))
    means, prec = controller_targets(ctl, X)
    assert np.allclose(means[..., 0], -2 * X[..., 0] + 0.5 * X[..., 1] + 0.1)
    assert np.allclose(prec, 25.0)
    policy = GaussianMLPPolicy(
        2, 1, PolicyConfig(hidden_sizes=()), torch.Generator().manual_seed(0)
    )
    losses = train_policy(
        policy, X.reshape(-1, 2), means.reshape(-1, 1), prec.reshape(-1, 1, 1), 400, 0.05
    )
    assert losses[-1] < 1e-4 * losses[0]
    lin = linearize_policy(policy, X, DynamicsConfig(), rng, False)
    assert np.max(np.abs(lin.K - K)) < 1e-2 and np.max(np.abs(lin.k - 0.1)) < 1e-2
    assert float(torch.exp(policy.log_std.detach())) == pytest.approx(0.2)


def test_step_rule_uses_the_policy_linearisation() -> None:
    X, U = PendulumConditions(STARTS[1:2], P).sample(0, zero_controller(), 10, 0)
    dyn = fit_dynamics(X, U, DynamicsConfig(use_prior=False))
    quad, _ = average_expansion(COST, X, U)
    cfg = TrajOptConfig(kl_step=1.0, min_step_mult=0.1, max_step_mult=3.0)
    old = zero_controller()
    new = kl_constrained_update(dyn, quad, old, 60.0, 1.0, cfg).controller
    prev = PreviousCondition(old, new, dyn, quad)
    # The policy reached what the C-step predicted: the step may grow (x5, capped at 3).
    mult, costs = mdgps_step_mult(1.0, prev, new, dyn, quad, cfg)
    assert costs["previous"] == pytest.approx(laplace_cost(old, dyn, quad))
    assert costs["predicted"] == pytest.approx(laplace_cost(new, dyn, quad))
    assert costs["predicted"] < costs["previous"] and mult == 3.0
    # The policy did not improve at all: the quadratic model halves the step.
    mult, _ = mdgps_step_mult(1.0, prev, old, dyn, quad, cfg)
    assert mult == pytest.approx(0.5)


def test_config_validation_lists_choices() -> None:
    with pytest.raises(ConfigError, match="precision"):
        MDGPSConfig(policy_loss="l1")
    with pytest.raises(ConfigError):
        MDGPSConfig(iterations=0)
    with pytest.raises(ConfigError):
        MDGPSConfig(min_step_mult=2.0)


# ----------------------------------------------------------------------------------------------
# The algorithm on the pendulum


def test_c_step_kl_to_the_policy_linearisation_holds(trained) -> None:
    for it in trained.history:
        for m in it:
            assert m["converged"] == 1.0
            assert abs(m["kl"] - m["epsilon"]) < 0.1 * m["epsilon"]
    # Recompute the last C-step's KL independently from the stored linearisation and model.
    for cond in trained.state.conditions:
        prev = cond.previous
        mu, sigma = forward_pass(prev.dynamics, prev.controller)
        kl = float(np.sum(kl_per_step(prev.controller, prev.policy_lin, mu, sigma)))
        eps = CFG.kl_step * cond.step_mult * T
        assert abs(kl - eps) < 0.1 * eps


def test_policy_cost_drops_on_every_training_condition(trained) -> None:
    # Measured (seed 0), noise-free rollout of the policy's mean after iterations 1 and 8:
    # start -1: 81.1 -> 49.8; start 0: 71.1 -> 34.6; start +1: 84.8 -> 31.8 (ratios .61/.49/.37).
    # Laplace cost of the policy linearisation under the fitted model: 101.9 -> 55.3,
    # 85.4 -> 34.8, 111.6 -> 32.4 (ratios .54/.41/.29).
    first, last = trained.history[0], trained.history[-1]
    for m in range(3):
        assert last[m]["policy_cost"] < 0.7 * first[m]["policy_cost"]
        assert last[m]["policy_cost_model"] < 0.65 * first[m]["policy_cost_model"]
        # The policy does as well as its condition's own local controller (within 3 %).
        assert last[m]["policy_cost"] < 1.03 * last[m]["sample_cost"]
    # Untrained policy (zero torque) for reference: much worse than the distilled one.
    untrained = GaussianMLPPolicy(2, 1, CFG.policy, torch.Generator().manual_seed(0))
    sampler = PendulumConditions(STARTS, P)
    for m in range(3):
        zero = policy_cost(sampler, untrained, COST, m, T, 2, False)
        assert last[m]["policy_cost"] < 0.5 * zero


def test_policy_beats_nearest_local_controller_on_unseen_start(trained) -> None:
    sampler = PendulumConditions((UNSEEN,), P)
    pol = policy_cost(sampler, trained.state.policy, COST, 0, T, 2, False)
    locals_ = [controller_cost(sampler, c.controller, COST, 0) for c in trained.state.conditions]
    nearest = nearest_condition(np.array(STARTS), np.array(UNSEEN))
    assert nearest == 2
    # Measured (seed 0): policy 33.37; local controllers of starts -1, 0, +1 run from 0.6:
    # 41.94, 39.07, 42.34 (ratio to the nearest, +1: 0.79; to the best, 0: 0.85).
    assert pol < 0.9 * locals_[nearest]
    assert pol < 0.95 * min(locals_)


def test_same_seed_same_result(trained) -> None:
    short = run(MDGPSConfig(conditions=3, iterations=2, seed=0))
    for a, b in zip(short.history, trained.history[:2], strict=False):
        assert a == b
    other_seed = run(MDGPSConfig(conditions=3, iterations=1, seed=1))
    assert other_seed.history[0][0]["policy_cost"] != trained.history[0][0]["policy_cost"]


@pytest.mark.slow
def test_env_driver_runs_on_the_dclaw_valve_conditions() -> None:
    # The interface of the TVLG trainer (FixedStart, offset_start, run_episode) on the simulated
    # D'Claw: two valve offsets, 2 iterations of 3 rollouts (about 3 s). Checks the plumbing and
    # the trust region only; learning the valve turn needs far more iterations.
    from lowcostdex.algos.local_models.conditions import env_problem
    from lowcostdex.algos.local_models.train import default_env_factory
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig

    env = default_env_factory(TVLGTrainConfig())()
    try:
        sampler, costs, ctls = env_problem(env, (-0.2, 0.2), seed=0)
        obj = 2 * len(env.unwrapped.task.hand_qpos)
        X0, _ = sampler.sample(0, ctls[0], 1, 0)
        X1, _ = sampler.sample(1, ctls[1], 1, 0)
        assert X1[0, 0, obj] - X0[0, 0, obj] == pytest.approx(0.4)
        cfg = MDGPSConfig(conditions=2, samples_per_condition=3, iterations=2, seed=0)
        res = train_mdgps(sampler, costs, ctls, cfg)
        again = train_mdgps(sampler, costs, ctls, cfg)
    finally:
        env.close()
    assert res.history == again.history
    for it in res.history:
        for m in it:
            assert m["converged"] == 1.0 and np.isfinite(m["policy_cost"])
            assert abs(m["kl"] - m["epsilon"]) < 0.1 * m["epsilon"]
