"""Mirror-descent guided policy search (MDGPS; Montgomery & Levine 2016, arXiv 1607.04614).

Distils M time-varying linear-Gaussian (TVLG) local controllers, one per start condition, into
ONE neural policy pi(u | o) (:class:`~lowcostdex.algos.policy.GaussianMLPPolicy`) that works from
all of them. One iteration (:func:`mdgps_iteration`), with N rollouts of each local controller:

1. expand the cost around each condition's rollouts; add all rollouts to one GMM prior and fit
   TVLG dynamics per condition (:mod:`.dynamics`);
2. on the first iteration only, train the policy on the initial controllers (S-step);
3. linearise the policy per condition at the rollouts' states (:func:`linearize_policy`):
   ``pi_bar(u_t | x_t) = N(K_t x_t + k_t, S_t)`` fitted to (x_t, policy mean at x_t), with the
   policy's own action variance;
4. from the second iteration on, adapt each condition's step_mult from the improvement of the
   policy's linearisation (:func:`mdgps_step_mult`);
5. C-step: per condition, KL-constrained LQR against ``pi_bar`` (not against the previous local
   controller) with ``epsilon = kl_step * step_mult * T`` (:func:`.traj_opt.kl_constrained_update`);
6. S-step: regress the policy mean on the new controllers' means ``K_t x + k_t`` at every sampled
   state, weighted by their precisions ``Sigma_t^-1`` (:func:`precision_weighted_loss`), full-batch
   Adam; the policy's std becomes ``mean(diag(Sigma_t^-1))^-1/2`` as in the GPS code.

The policy observes ``o_t = x_t`` (as in the GPS code) or ``[x_t, t / T]`` (``time_feature``).
Rollouts come from a :class:`~.conditions.ConditionSampler` (:mod:`.conditions`):
:class:`~.conditions.PendulumConditions` (the pendulum of :mod:`.pendulum`) or
:class:`~.conditions.EnvConditions` (the gymnasium tasks of :mod:`.train`, one
:class:`~.train.FixedStart` per condition, built by :func:`~.conditions.env_problem`). :func:`train_mdgps` is
the driver.

Shapes: X (N, T, dX) states, U (N, T, dU) actions, per condition.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from numpy.typing import NDArray

from lowcostdex.algos.configs import PolicyConfig
from lowcostdex.algos.local_models.conditions import ConditionSampler
from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import Cost, QuadraticCost, average_expansion
from lowcostdex.algos.local_models.dynamics import (
    DynamicsConfig,
    GMMPrior,
    LinearGaussianDynamics,
    fit_dynamics,
    update_gmm_prior,
)
from lowcostdex.algos.local_models.policy_fit import fit_policy
from lowcostdex.algos.local_models.traj_opt import (
    TrajOptConfig,
    kl_constrained_update,
    step_mult_update,
)
from lowcostdex.algos.local_models.tvlg import laplace_cost
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import ConfigError, check_choice, check_fields, keyword_hints

Array = NDArray[np.float64]
POLICY_LOSSES = ("precision", "mse")
_UPDATE = 17  # seed purpose of the update generator (GMM EM of dynamics and linearisation)


@keyword_hints
@dataclass(frozen=True)
class MDGPSConfig:
    """Settings of MDGPS.

    Attributes:
      conditions: number of start conditions M (one local controller each).
      samples_per_condition: rollouts N of each local controller per iteration.
      iterations: MDGPS iterations.
      kl_step: KL budget per time step [nats]; epsilon = kl_step * step_mult * T (GPS MDGPS: 1.0).
      min_step_mult: lower bound of each condition's step_mult (GPS MDGPS example: 0.5).
      max_step_mult: upper bound of step_mult (GPS MDGPS example: 3.0).
      initial_eta: dual variable each condition's first search starts from.
      dynamics: dynamics fit and its GMM prior (one prior shared by all conditions).
      policy_fit: fit of the policy linearisation. Its GMM prior over (x, pi(x)) pools all time
        steps, which biases the fit of a time-dependent policy (``time_feature``), so it is off
        by default: plain per-step regression is exact for N >= dX + 1 samples; turn it on for
        N < dX + 1 (a hand), ideally with ``time_feature=False``.
      policy: architecture of the global policy.
      policy_steps: full-batch Adam steps per S-step.
      policy_lr: Adam learning rate.
      policy_loss: one of POLICY_LOSSES: "precision" weights each action error by the local
        controller's precision (the MDGPS loss); "mse" is the plain squared error.
      time_feature: the policy observes ``[x_t, t / T]`` instead of ``x_t``. Off by default: on
        the pendulum the state-only policy generalised better to unseen starts (measured mean
        cost ratio to the nearest local controller over 8 unseen starts: 0.93 vs 1.00, seed 0,
        8 iterations).
      seed: seeds the policy's initial weights and the GMM fits (the rollout noise comes from
        the sampler's own seed).
    """

    conditions: int = 3
    samples_per_condition: int = 5
    iterations: int = 6
    kl_step: float = 1.0
    min_step_mult: float = 0.5
    max_step_mult: float = 3.0
    initial_eta: float = 1.0
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    policy_fit: DynamicsConfig = field(default_factory=lambda: DynamicsConfig(use_prior=False))
    policy: PolicyConfig = field(default_factory=lambda: PolicyConfig(hidden_sizes=(32, 32)))
    policy_steps: int = 300
    policy_lr: float = 1e-2
    policy_loss: str = "precision"
    time_feature: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first
        check_choice("policy loss", self.policy_loss, POLICY_LOSSES)
        for name in ("conditions", "samples_per_condition", "iterations", "policy_steps"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")
        if self.kl_step <= 0 or self.policy_lr <= 0 or self.initial_eta <= 0:
            raise ConfigError("kl_step, policy_lr and initial_eta must be > 0")
        if not 0 < self.min_step_mult <= 1.0 <= self.max_step_mult:
            raise ConfigError(
                "need 0 < min_step_mult <= 1 <= max_step_mult (step_mult starts at 1)"
            )

    @property
    def traj_opt(self) -> TrajOptConfig:
        """The C-step's trust region settings."""
        return TrajOptConfig(
            kl_step=self.kl_step,
            min_step_mult=self.min_step_mult,
            max_step_mult=self.max_step_mult,
        )


# ----------------------------------------------------------------------------------------------
# The policy as a TVLG-like actor, its observations and its linearisation


def policy_observations(X: Array, time_feature: bool) -> Array:
    """Policy inputs (..., T, dO) for states X (..., T, dX): ``[x_t, t / T]`` or ``x_t``."""
    if not time_feature:
        return X
    T = X.shape[-2]
    tau = np.broadcast_to((np.arange(T) / T)[:, None], (*X.shape[:-1], 1))
    return np.concatenate([X, tau], axis=-1)


def policy_mean(policy: GaussianMLPPolicy, X: Array, time_feature: bool) -> Array:
    """Mean action (N, T, dU) of the policy at states X (N, T, dX)."""
    obs = policy_observations(X, time_feature)
    with torch.no_grad():
        mean = policy(torch.as_tensor(obs.reshape(-1, obs.shape[-1]), dtype=policy.log_std.dtype))
    return mean.double().numpy().reshape(*X.shape[:-1], policy.act_dim)


def policy_variance(policy: GaussianMLPPolicy) -> Array:
    """(dU,) action variance of the policy, action units squared."""
    return np.exp(2.0 * policy.log_std.detach().double().numpy())


class PolicyActor:
    """The neural policy behind the TVLG controller interface (``T``, ``dX``, ``dU``,
    ``act(t, x, noise)``), so the pendulum and env rollouts can run it.

    Acts with a numpy snapshot taken at construction: ``mean(o_t) + std * noise``.
    """

    def __init__(self, policy: GaussianMLPPolicy, T: int, dX: int, time_feature: bool):
        self.snapshot = policy.snapshot()
        self.T, self.dX, self.dU = T, dX, policy.act_dim
        self.time_feature = time_feature

    def act(self, t: int, x: Array, noise: Array | None = None) -> Array:
        obs = np.append(x, t / self.T) if self.time_feature else np.asarray(x)
        return self.snapshot.act(obs, noise)


def linearize_policy(
    policy: GaussianMLPPolicy,
    X: Array,
    cfg: DynamicsConfig,
    rng: np.random.Generator,
    time_feature: bool,
) -> LinearGaussianController:
    """TVLG fit ``N(K_t x + k_t, S_t)`` of the policy around the states X (N, T, dX).

    :func:`.policy_fit.fit_policy` on (x_t, policy mean at x_t); ``S_t`` is the fit's residual
    covariance (the mean's nonlinearity over the samples) plus the policy's own diagonal action
    variance.
    """
    mean = policy_mean(policy, X, time_feature)
    fit = fit_policy(X, mean, cfg, rng, min_var=1e-8)
    cov = fit.cov + np.diag(policy_variance(policy))
    return LinearGaussianController.from_cov(fit.K, fit.k, cov)


# ----------------------------------------------------------------------------------------------
# S-step


def controller_targets(controller: LinearGaussianController, X: Array) -> tuple[Array, Array]:
    """Mean actions (N, T, dU) ``K_t x_t + k_t`` of a controller at X (N, T, dX) and its
    precisions (N, T, dU, dU)."""
    means = np.einsum("tux,ntx->ntu", controller.K, X) + controller.k
    prec = np.broadcast_to(controller.inv_cov, (X.shape[0], *controller.inv_cov.shape))
    return means, prec


def precision_weighted_loss(
    mean: torch.Tensor, target: torch.Tensor, precision: torch.Tensor
) -> torch.Tensor:
    """``mean_i (mu_i - u_i)' P_i (mu_i - u_i)``: the MDGPS policy loss.

    Args:
      mean: (n, dU) policy means; target: (n, dU) local controllers' means;
      precision: (n, dU, dU) local controllers' action precisions [1 / action units^2].
    """
    d = mean - target
    return torch.einsum("ni,nij,nj->n", d, precision, d).mean()


def mse_loss(mean: torch.Tensor, target: torch.Tensor, precision: torch.Tensor) -> torch.Tensor:
    """``mean_i |mu_i - u_i|^2`` (``precision`` unused): the unweighted variant."""
    del precision
    return ((mean - target) ** 2).sum(-1).mean()


def policy_std_from_precision(precision: Array) -> Array:
    """(dU,) policy std ``mean(diag(P))^-1/2`` from precisions (n, dU, dU), as the GPS code."""
    return 1.0 / np.sqrt(np.mean(np.diagonal(precision, axis1=-2, axis2=-1), axis=0))


def train_policy(
    policy: GaussianMLPPolicy,
    obs: Array,
    targets: Array,
    precision: Array,
    steps: int,
    lr: float,
    loss: str = "precision",
) -> list[float]:
    """S-step: full-batch Adam on the policy mean, then its std from the mean precision.

    Args:
      obs: (n, dO) observations; targets: (n, dU) target mean actions;
      precision: (n, dU, dU) their precisions.

    Returns:
      The loss before every step and after the last (steps + 1 values).
    """
    check_choice("policy loss", loss, POLICY_LOSSES)
    loss_fn = precision_weighted_loss if loss == "precision" else mse_loss
    dtype = policy.log_std.dtype
    o = torch.as_tensor(obs, dtype=dtype)
    u = torch.as_tensor(targets, dtype=dtype)
    p = torch.as_tensor(np.ascontiguousarray(precision), dtype=dtype)
    policy.update_obs_normalizer(o)
    params = [q for name, q in policy.named_parameters() if name != "log_std"]
    opt = torch.optim.Adam(params, lr=lr)
    history = []
    for _ in range(steps):
        opt.zero_grad()
        value = loss_fn(policy(o), u, p)
        value.backward()
        opt.step()
        history.append(float(value.detach()))
    with torch.no_grad():
        history.append(float(loss_fn(policy(o), u, p)))
        std = policy_std_from_precision(np.asarray(precision))
        policy.log_std.copy_(torch.as_tensor(np.log(std), dtype=dtype))
        policy.clamp_log_std_()
    return history


def s_step(
    policy: GaussianMLPPolicy,
    samples: Sequence[tuple[Array, Array]],
    controllers: Sequence[LinearGaussianController],
    cfg: MDGPSConfig,
) -> list[float]:
    """Train the policy on every condition's controller means at its sampled states."""
    obs, tgt, prec = [], [], []
    for (X, _), ctl in zip(samples, controllers, strict=True):
        means, p = controller_targets(ctl, X)
        obs.append(
            policy_observations(X, cfg.time_feature).reshape(-1, X.shape[2] + cfg.time_feature)
        )
        tgt.append(means.reshape(-1, ctl.dU))
        prec.append(p.reshape(-1, ctl.dU, ctl.dU))
    return train_policy(
        policy,
        np.concatenate(obs),
        np.concatenate(tgt),
        np.concatenate(prec),
        cfg.policy_steps,
        cfg.policy_lr,
        cfg.policy_loss,
    )


# ----------------------------------------------------------------------------------------------
# Step rule


@dataclass(frozen=True, eq=False)
class PreviousCondition:
    """What the MDGPS step rule needs from a condition's last iteration.

    Attributes:
      policy_lin: the policy's linearisation the C-step was constrained to.
      controller: the local controller the C-step produced (sampled this iteration).
      dynamics: the model fitted last iteration.
      cost: the quadratic cost expansion of last iteration.
    """

    policy_lin: LinearGaussianController
    controller: LinearGaussianController
    dynamics: LinearGaussianDynamics
    cost: QuadraticCost


def mdgps_step_mult(
    step_mult: float,
    prev: PreviousCondition,
    policy_lin: LinearGaussianController,
    dyn: LinearGaussianDynamics,
    cost: QuadraticCost,
    cfg: TrajOptConfig,
) -> tuple[float, dict[str, float]]:
    """MDGPS "laplace" step rule for one condition.

    previous = Laplace cost of the previous policy linearisation under the previous model;
    predicted = that of the previous local controller (what the C-step expected);
    actual = that of the current policy linearisation under the current model (what the policy
    achieved after the S-step). Then :func:`.traj_opt.step_mult_update`.

    Returns:
      (new step_mult, {"previous", "predicted", "actual"} costs).
    """
    costs = {
        "previous": laplace_cost(prev.policy_lin, prev.dynamics, prev.cost),
        "predicted": laplace_cost(prev.controller, prev.dynamics, prev.cost),
        "actual": laplace_cost(policy_lin, dyn, cost),
    }
    new = step_mult_update(step_mult, costs["previous"], costs["predicted"], costs["actual"], cfg)
    return new, costs


# ----------------------------------------------------------------------------------------------
# One iteration


@dataclass(frozen=True, eq=False)
class ConditionState:
    """Per-condition state: the local controller to sample next, eta, step_mult, last iteration."""

    controller: LinearGaussianController
    eta: float
    step_mult: float = 1.0
    previous: PreviousCondition | None = None


@dataclass(eq=False)
class MDGPSState:
    """Everything that carries over between iterations (the policy is updated in place).

    Attributes:
      iteration: completed iterations.
      conditions: one :class:`ConditionState` per start condition.
      prior: GMM data window over all conditions' transitions.
      policy: the global policy.
    """

    iteration: int
    conditions: list[ConditionState]
    prior: GMMPrior
    policy: GaussianMLPPolicy

    @classmethod
    def initial(
        cls, controllers: Sequence[LinearGaussianController], cfg: MDGPSConfig
    ) -> MDGPSState:
        """Initial local controllers (one per condition) and a fresh policy seeded by cfg.seed."""
        if len(controllers) != cfg.conditions:
            raise ConfigError(f"{len(controllers)} controllers for {cfg.conditions} conditions")
        c0 = controllers[0]
        gen = torch.Generator().manual_seed(cfg.seed)
        policy = GaussianMLPPolicy(c0.dX + int(cfg.time_feature), c0.dU, cfg.policy, gen)
        conds = [ConditionState(c, cfg.initial_eta) for c in controllers]
        return cls(0, conds, GMMPrior.empty(c0.T, c0.dX, c0.dU), policy)


def mdgps_iteration(
    state: MDGPSState,
    samples: Sequence[tuple[Array, Array]],
    costs: Sequence[Cost],
    cfg: MDGPSConfig,
    rng: np.random.Generator,
) -> tuple[MDGPSState, list[dict[str, float]]]:
    """One MDGPS iteration from N rollouts (X, U) of each condition's local controller.

    Returns:
      The next state (its policy is ``state.policy``, trained in place) and per-condition
      metrics: ``sample_cost`` (mean rollout cost), ``policy_cost_model`` (Laplace cost of the
      policy linearisation under the new model), ``predicted_cost`` (new local controller),
      ``kl``, ``epsilon``, ``eta``, ``step_mult``, ``converged``, plus ``policy_loss``.
    """
    M = len(state.conditions)
    if len(samples) != M or len(costs) != M:
        raise ConfigError(f"need samples and costs for all {M} conditions")
    traj_cfg = cfg.traj_opt
    quads = [average_expansion(c, X, U) for c, (X, U) in zip(costs, samples, strict=True)]
    prior = state.prior
    if cfg.dynamics.use_prior:
        X_all = np.concatenate([X for X, _ in samples])
        U_all = np.concatenate([U for _, U in samples])
        prior = update_gmm_prior(prior, X_all, U_all, cfg.dynamics, rng)
    dyns = [fit_dynamics(X, U, cfg.dynamics, prior.gmm) for X, U in samples]
    if state.iteration == 0:
        s_step(state.policy, samples, [c.controller for c in state.conditions], cfg)
    new_conditions, metrics, new_controllers = [], [], []
    for cond, (X, _), (quad, sample_costs), dyn in zip(
        state.conditions, samples, quads, dyns, strict=True
    ):
        pol_lin = linearize_policy(state.policy, X, cfg.policy_fit, rng, cfg.time_feature)
        step_mult, rule = cond.step_mult, {}
        if cond.previous is not None:
            step_mult, rule = mdgps_step_mult(
                step_mult, cond.previous, pol_lin, dyn, quad, traj_cfg
            )
        epsilon = cfg.kl_step * step_mult * cond.controller.T
        result = kl_constrained_update(dyn, quad, pol_lin, epsilon, cond.eta, traj_cfg)
        new_controllers.append(result.controller)
        new_conditions.append(
            ConditionState(
                result.controller,
                result.eta,
                step_mult,
                PreviousCondition(pol_lin, result.controller, dyn, quad),
            )
        )
        metrics.append({
            "sample_cost": float(np.mean(np.sum(sample_costs, axis=1))),
            "policy_cost_model": laplace_cost(pol_lin, dyn, quad),
            "predicted_cost": laplace_cost(result.controller, dyn, quad),
            "kl": result.kl,
            "epsilon": epsilon,
            "eta": result.eta,
            "step_mult": step_mult,
            "converged": float(result.converged),
            **{f"rule_{k}": v for k, v in rule.items()},
        })  # fmt: skip
    losses = s_step(state.policy, samples, new_controllers, cfg)
    for m in metrics:
        m["policy_loss"] = losses[-1]
    return MDGPSState(state.iteration + 1, new_conditions, prior, state.policy), metrics


# ----------------------------------------------------------------------------------------------
# Rollouts per condition and the driver


def policy_cost(
    sampler: ConditionSampler,
    policy: GaussianMLPPolicy,
    cost: Cost,
    condition: int,
    T: int,
    dX: int,
    time_feature: bool,
) -> float:
    """Total cost of one noise-free rollout of the policy's mean from a condition."""
    actor = PolicyActor(policy, T, dX, time_feature)
    X, U = sampler.sample(condition, actor, 1, 0, deterministic=True)
    return float(np.sum(cost.evaluate(X[0], U[0]).value))


def controller_cost(
    sampler: ConditionSampler, controller: LinearGaussianController, cost: Cost, condition: int
) -> float:
    """Total cost of one noise-free rollout of a TVLG controller from a condition."""
    X, U = sampler.sample(condition, controller, 1, 0, deterministic=True)
    return float(np.sum(cost.evaluate(X[0], U[0]).value))


@dataclass(eq=False)
class MDGPSResult:
    """The final state and per-iteration metrics: ``history[k][m]`` for iteration k, condition m,
    with ``policy_cost`` (noise-free rollout of the policy after iteration k) added."""

    state: MDGPSState
    history: list[list[dict[str, float]]]


def train_mdgps(
    sampler: ConditionSampler,
    costs: Sequence[Cost],
    initial_controllers: Sequence[LinearGaussianController],
    cfg: MDGPSConfig,
    progress: Callable[[int, list[dict[str, float]]], None] | None = None,
) -> MDGPSResult:
    """Run ``cfg.iterations`` MDGPS iterations from the initial local controllers.

    Every random draw derives from ``cfg.seed`` (policy weights) and the sampler's seed
    (rollout noise); the same seeds give the same result.
    """
    if sampler.n_conditions != cfg.conditions or len(costs) != cfg.conditions:
        raise ConfigError(
            f"cfg.conditions={cfg.conditions}, sampler has {sampler.n_conditions}, "
            f"{len(costs)} costs"
        )
    state = MDGPSState.initial(initial_controllers, cfg)
    c0 = initial_controllers[0]
    history = []
    for k in range(cfg.iterations):
        samples = [
            sampler.sample(m, cond.controller, cfg.samples_per_condition, k)
            for m, cond in enumerate(state.conditions)
        ]
        rng = np.random.default_rng(np.random.SeedSequence(cfg.seed, spawn_key=(_UPDATE, k)))
        state, metrics = mdgps_iteration(state, samples, costs, cfg, rng)
        for m, row in enumerate(metrics):
            row["policy_cost"] = policy_cost(
                sampler, state.policy, costs[m], m, c0.T, c0.dX, cfg.time_feature
            )
        history.append(metrics)
        if progress is not None:
            progress(k, metrics)
    return MDGPSResult(state, history)


def nearest_condition(starts: Array, x0: Array) -> int:
    """Index of the start (M, dX) nearest to x0 (dX,) in Euclidean distance."""
    return int(np.argmin(np.linalg.norm(np.asarray(starts) - np.asarray(x0), axis=1)))
