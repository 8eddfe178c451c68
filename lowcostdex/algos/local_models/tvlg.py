"""One iteration of learned-local-model optimisation (Levine & Abbeel 2014; Kumar et al. 2016).

Given N rollouts of the current TVLG controller from a fixed start state:

1. expand the cost to second order around every rollout and average (:mod:`.costs`);
2. add the rollouts to the GMM data window, refit the GMM, fit TVLG dynamics with its prior
   (:mod:`.dynamics`);
3. from the second iteration on, adapt step_mult from predicted vs actual improvement;
4. solve the KL-constrained LQR against the current controller with
   epsilon = kl_step * step_mult * T (:mod:`.traj_opt`).

The state needed to continue (controller, data window, GMM, eta, step_mult and the previous
iteration's controller, model and cost) is a :class:`TVLGState` that saves to plain arrays.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import Cost, QuadraticCost, average_expansion
from lowcostdex.algos.local_models.dynamics import (
    DynamicsConfig,
    GMMPrior,
    LinearGaussianDynamics,
    check_rollouts,
    fit_dynamics,
    update_gmm_prior,
)
from lowcostdex.algos.local_models.gmm import GaussianMixture
from lowcostdex.algos.local_models.lqr import expected_cost, forward_pass
from lowcostdex.algos.local_models.traj_opt import (
    TrajOptConfig,
    kl_constrained_update,
    step_mult_update,
)
from lowcostdex.errors import ConfigError, check_fields, keyword_hints

Array = NDArray[np.float64]


@keyword_hints
@dataclass(frozen=True)
class TVLGConfig:
    """Settings of the learned-local-model optimiser.

    Attributes:
      dynamics: dynamics fit and GMM prior.
      traj_opt: KL trust region and dual search.
      initial_eta: dual variable the first search starts from.
      initial_step_mult: step multiplier of the first iteration.
    """

    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    traj_opt: TrajOptConfig = field(default_factory=TrajOptConfig)
    initial_eta: float = 1.0
    initial_step_mult: float = 1.0

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first (a NaN passes every comparison)
        if self.initial_eta <= 0:
            raise ConfigError(f"initial_eta={self.initial_eta} must be > 0")
        t = self.traj_opt
        if not t.min_step_mult <= self.initial_step_mult <= t.max_step_mult:
            raise ConfigError(
                f"initial_step_mult={self.initial_step_mult} is outside "
                f"[{t.min_step_mult}, {t.max_step_mult}]"
            )


@dataclass(frozen=True, eq=False)
class PreviousIteration:
    """What the step rule needs from the last iteration: its controller, model and cost."""

    controller: LinearGaussianController
    dynamics: LinearGaussianDynamics
    cost: QuadraticCost


@dataclass(frozen=True, eq=False)
class TVLGState:
    """Everything that carries over between iterations.

    Attributes:
      iteration: number of completed iterations.
      controller: the controller to run next.
      prior: GMM data window and mixture.
      eta: last dual variable (warm start of the next search).
      step_mult: current KL step multiplier.
      previous: the last iteration's controller, dynamics and cost, or None.
    """

    iteration: int
    controller: LinearGaussianController
    prior: GMMPrior
    eta: float
    step_mult: float
    previous: PreviousIteration | None = None

    @classmethod
    def initial(cls, controller: LinearGaussianController, cfg: TVLGConfig) -> TVLGState:
        prior = GMMPrior.empty(controller.T, controller.dX, controller.dU)
        return cls(0, controller, prior, cfg.initial_eta, cfg.initial_step_mult)


def laplace_cost(
    controller: LinearGaussianController, dyn: LinearGaussianDynamics, cost: QuadraticCost
) -> float:
    """Expected total cost of ``controller`` under the model ``dyn`` and quadratic ``cost``."""
    mu, sigma = forward_pass(dyn, controller)
    return float(np.sum(expected_cost(cost, mu, sigma)))


def tvlg_iteration(
    state: TVLGState,
    X: Array,
    U: Array,
    cost: Cost,
    cfg: TVLGConfig,
    rng: np.random.Generator,
) -> tuple[TVLGState, dict[str, float]]:
    """Improve the controller from N rollouts X (N, T, dX), U (N, T, dU) of ``state.controller``.

    Returns:
      The next state and metrics: ``sample_cost`` (mean total cost of the rollouts),
      ``predicted_cost`` (Laplace estimate of the new controller under the new model), ``kl``,
      ``epsilon``, ``eta``, ``step_mult``, ``dual_iterations``, ``converged``, ``pd_fixes``.
    """
    T = state.controller.T
    X, U = check_rollouts(X, U, min_steps=2)
    if X.shape[1] != T or U.shape[1] != T:
        raise ConfigError(f"rollouts have {X.shape[1]} steps, the controller has {T}")
    c = state.controller
    if (X.shape[2], U.shape[2]) != (c.dX, c.dU):
        raise ConfigError(f"rollouts of {X.shape[2]} states and {U.shape[2]} actions; the "
                          f"controller has {c.dX} and {c.dU}")
    quad, sample_costs = average_expansion(cost, X, U)
    prior = state.prior
    if cfg.dynamics.use_prior:
        prior = update_gmm_prior(prior, X, U, cfg.dynamics, rng)
    dyn = fit_dynamics(X, U, cfg.dynamics, prior.gmm)
    step_mult = state.step_mult
    if state.previous is not None:
        prev = state.previous
        previous = laplace_cost(prev.controller, prev.dynamics, prev.cost)
        predicted = laplace_cost(state.controller, prev.dynamics, prev.cost)
        actual = laplace_cost(state.controller, dyn, quad)
        step_mult = step_mult_update(step_mult, previous, predicted, actual, cfg.traj_opt)
    epsilon = cfg.traj_opt.kl_step * step_mult * T
    result = kl_constrained_update(dyn, quad, state.controller, epsilon, state.eta, cfg.traj_opt)
    new_state = TVLGState(
        iteration=state.iteration + 1,
        controller=result.controller,
        prior=prior,
        eta=result.eta,
        step_mult=step_mult,
        previous=PreviousIteration(state.controller, dyn, quad),
    )
    metrics = {
        "sample_cost": float(np.mean(np.sum(sample_costs, axis=1))),
        "current_cost_model": laplace_cost(state.controller, dyn, quad),
        "predicted_cost": laplace_cost(result.controller, dyn, quad),
        "kl": result.kl,
        "epsilon": epsilon,
        "eta": result.eta,
        "step_mult": step_mult,
        "dual_iterations": float(result.dual_iterations),
        "converged": float(result.converged),
        "pd_fixes": float(result.pd_fixes),
    }
    return new_state, metrics


def state_to_arrays(state: TVLGState) -> dict[str, Array]:
    """Flatten a state into named arrays for an NPZ checkpoint (no pickle)."""
    out: dict[str, Array] = {
        "iteration": np.asarray(state.iteration),
        "eta": np.asarray(state.eta),
        "step_mult": np.asarray(state.step_mult),
        "prior/X": state.prior.X,
        "prior/U": state.prior.U,
    }
    out.update({f"controller/{k}": v for k, v in state.controller.to_arrays().items()})
    if state.prior.gmm is not None:
        out.update({f"gmm/{k}": v for k, v in state.prior.gmm.to_arrays().items()})
    if state.previous is not None:
        p = state.previous
        out.update({f"prev_controller/{k}": v for k, v in p.controller.to_arrays().items()})
        out.update({f"prev_dynamics/{k}": v for k, v in p.dynamics.to_arrays().items()})
        out.update({"prev_cost/C": p.cost.C, "prev_cost/c": p.cost.c, "prev_cost/cc": p.cost.cc})
    return out


def _group(arrays: dict[str, Any], prefix: str) -> dict[str, Array]:
    return {
        k[len(prefix) + 1 :]: np.asarray(v) for k, v in arrays.items() if k.startswith(prefix + "/")
    }


def _scalar(value: Any) -> Array:
    """A scalar stored as a 0-d or (1,) array."""
    return np.asarray(value).reshape(())


def state_from_arrays(arrays: dict[str, Any]) -> TVLGState:
    """Inverse of :func:`state_to_arrays`."""
    gmm_arrays = _group(arrays, "gmm")
    prior = GMMPrior(
        np.asarray(arrays["prior/X"]),
        np.asarray(arrays["prior/U"]),
        GaussianMixture.from_arrays(gmm_arrays) if gmm_arrays else None,
    )
    previous = None
    if "prev_cost/C" in arrays:
        previous = PreviousIteration(
            LinearGaussianController.from_arrays(_group(arrays, "prev_controller")),
            LinearGaussianDynamics.from_arrays(_group(arrays, "prev_dynamics")),
            QuadraticCost(
                np.asarray(arrays["prev_cost/C"]),
                np.asarray(arrays["prev_cost/c"]),
                np.asarray(arrays["prev_cost/cc"]),
            ),
        )
    return TVLGState(
        iteration=int(_scalar(arrays["iteration"])),
        controller=LinearGaussianController.from_arrays(_group(arrays, "controller")),
        prior=prior,
        eta=float(_scalar(arrays["eta"])),
        step_mult=float(_scalar(arrays["step_mult"])),
        previous=previous,
    )
