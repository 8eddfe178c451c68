"""KL-constrained trajectory optimisation: the dual variable eta and the step-size rule.

``min_p E_p[sum_t l_t]  s.t.  sum_t E_p[KL(p(u_t|x_t) || p_old(u_t|x_t))] <= epsilon``

For a fixed dual variable eta the minimiser is the LQR controller of the augmented cost
(:func:`lqr.augment_cost`). The KL decreases monotonically in eta, so eta is found by a
bracketing search in log space until the KL is within ``kl_tolerance * epsilon`` of epsilon
(:func:`kl_constrained_update`). ``epsilon = kl_step * step_mult * T``; ``step_mult`` adapts from the
ratio of predicted to actual improvement (:func:`step_mult_update`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import QuadraticCost
from lowcostdex.algos.local_models.dynamics import LinearGaussianDynamics
from lowcostdex.algos.local_models.lqr import (
    NotPositiveDefiniteError,
    augment_cost,
    forward_pass,
    kl_per_step,
    lqr_backward,
)
from lowcostdex.errors import (
    ConfigError,
    LowcostdexError,
    check_fields,
    check_number,
    keyword_hints,
)

# Bounds of the per-iteration change of step_mult (the improvement model's validity range).
STEP_CHANGE_MIN = 0.1
STEP_CHANGE_MAX = 5.0


class TrajOptError(LowcostdexError, ArithmeticError):
    """The KL-constrained LQR could not produce a controller (NaN model or eta overflow)."""


@keyword_hints
@dataclass(frozen=True)
class TrajOptConfig:
    """KL trust region and dual search.

    Attributes:
      kl_step: KL budget per time step in nats; epsilon = kl_step * step_mult * T.
      min_step_mult: lower bound of step_mult.
      max_step_mult: upper bound of step_mult.
      min_eta: lower end of the eta bracket.
      max_eta: upper end of the eta bracket; reaching it while fixing Q_uu is an error.
      eta_delta0: first increment of eta when Q_uu is not positive definite (doubles each retry).
      max_dual_iterations: bracket-search iterations.
      kl_tolerance: accept |KL - epsilon| < kl_tolerance * epsilon.
    """

    kl_step: float = 0.2
    min_step_mult: float = 0.01
    max_step_mult: float = 10.0
    min_eta: float = 1e-8
    max_eta: float = 1e16
    eta_delta0: float = 1e-4
    max_dual_iterations: int = 50
    kl_tolerance: float = 0.1

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first (a NaN passes every comparison)
        if self.kl_step <= 0:
            raise ConfigError(f"kl_step={self.kl_step} must be > 0")
        if not 0 < self.min_step_mult <= self.max_step_mult:
            raise ConfigError("need 0 < min_step_mult <= max_step_mult")
        if not 0 < self.min_eta < self.max_eta:
            raise ConfigError("need 0 < min_eta < max_eta")
        if self.eta_delta0 <= 0 or self.max_dual_iterations < 1:
            raise ConfigError("eta_delta0 must be > 0 and max_dual_iterations >= 1")
        if not 0 < self.kl_tolerance < 1:
            raise ConfigError(f"kl_tolerance={self.kl_tolerance} must be in (0, 1)")


@dataclass(frozen=True, eq=False)
class TrajOptResult:
    """Outcome of one KL-constrained update.

    Attributes:
      controller: the new controller.
      eta: dual variable it was solved with.
      kl: its KL to the old controller (nats, summed over steps).
      epsilon: the KL target.
      converged: |kl - epsilon| < tol * epsilon, or the constraint is inactive at min_eta.
      dual_iterations: bracket-search iterations used.
      pd_fixes: times eta had to be raised because Q_uu was not positive definite.
    """

    controller: LinearGaussianController
    eta: float
    kl: float
    epsilon: float
    converged: bool
    dual_iterations: int
    pd_fixes: int


def solve_for_eta(
    dyn: LinearGaussianDynamics,
    cost: QuadraticCost,
    prev: LinearGaussianController,
    eta: float,
    cfg: TrajOptConfig,
) -> tuple[LinearGaussianController, float, int]:
    """Backward pass at ``eta``; if Q_uu is not PD, retry with eta + delta, delta doubling.

    Returns:
      (controller, the eta actually used, number of retries).

    Raises:
      TrajOptError: when eta would exceed ``max_eta`` (the message says if the model has NaNs).
    """
    if not (np.all(np.isfinite(dyn.F)) and np.all(np.isfinite(dyn.f))):
        raise TrajOptError("NaNs in dynamics: the fitted F or f is not finite")
    delta = cfg.eta_delta0
    eta_used = eta
    retries = 0
    while True:
        C, c = augment_cost(cost, prev, eta_used)
        try:
            return lqr_backward(dyn.F, dyn.f, C, c), eta_used, retries
        except NotPositiveDefiniteError as exc:
            eta_used = eta + delta
            delta *= 2.0
            retries += 1
            if eta_used >= cfg.max_eta:
                raise TrajOptError(
                    f"Q_uu stayed non-positive-definite up to eta={eta_used:.3g} ({exc})"
                ) from exc


def kl_constrained_update(
    dyn: LinearGaussianDynamics,
    cost: QuadraticCost,
    prev: LinearGaussianController,
    epsilon: float,
    eta: float,
    cfg: TrajOptConfig,
) -> TrajOptResult:
    """Find eta such that the new controller's KL to ``prev`` is ``epsilon`` (nats) within tolerance.

    Bracket search starting from ``eta``: if the KL is below epsilon eta was too large, so the upper
    end moves down to it; otherwise the lower end moves up. The next eta is the geometric mean of
    the bracket, but at most a factor 10 from the end just moved. If the search does not converge,
    the feasible controller with the largest KL found is returned (``converged=False``).
    """
    check_number("epsilon (KL budget, nats)", epsilon, 0, low_open=True)
    check_number("eta (dual variable)", eta, 0, low_open=True)
    _check_sizes(dyn, cost, prev)
    lo, hi = cfg.min_eta, cfg.max_eta
    eta = float(np.clip(eta, lo, hi))
    best: TrajOptResult | None = None
    pd_fixes = 0
    result: TrajOptResult | None = None
    for it in range(1, cfg.max_dual_iterations + 1):
        controller, eta, fixes = solve_for_eta(dyn, cost, prev, eta, cfg)
        pd_fixes += fixes
        mu, sigma = forward_pass(dyn, controller)
        kl = float(np.sum(kl_per_step(controller, prev, mu, sigma)))
        gap = kl - epsilon
        inactive = gap < 0 and eta <= lo * (1 + 1e-9)
        converged = abs(gap) < cfg.kl_tolerance * epsilon or inactive
        result = TrajOptResult(controller, eta, kl, epsilon, converged, it, pd_fixes)
        if converged:
            return result
        if gap < 0:
            if best is None or kl > best.kl:
                best = result
            hi = eta
            eta = max(math.sqrt(lo * hi), 0.1 * hi)
        else:
            if eta >= hi * (1 - 1e-9):
                break
            lo = eta
            eta = min(math.sqrt(lo * hi), 10.0 * lo)
    assert result is not None
    chosen = best if best is not None else result
    return TrajOptResult(
        chosen.controller, chosen.eta, chosen.kl, epsilon, False, result.dual_iterations, pd_fixes
    )


def _check_sizes(dyn: LinearGaussianDynamics, cost: QuadraticCost,
                 prev: LinearGaussianController) -> None:
    """ConfigError unless the model, the cost and the controller share T, dX and dU (before:
    a numpy matmul error deep in the backward pass)."""
    T, dU, dX = prev.K.shape
    want = {"dynamics F": (dyn.F.shape, (T - 1, dX, dX + dU)),
            "cost C": (np.shape(cost.C), (T, dX + dU, dX + dU))}
    for name, (got, need) in want.items():
        if got != need:
            raise ConfigError(f"{name} has shape {got}; the controller (T={T}, dU={dU}, "
                              f"dX={dX}) needs {need}")


def step_mult_update(
    step_mult: float, previous: float, predicted: float, actual: float, cfg: TrajOptConfig
) -> float:
    """Adapt the KL step multiplier from predicted vs actual improvement.

    Models the improvement as ``I(e) = a e + b e^2`` through (0, 0) and the last step; its
    maximiser relative to the last step is ``predicted_impr / (2 (predicted_impr - actual_impr))``,
    limited to [0.1, 5] per iteration and to [min_step_mult, max_step_mult] overall.

    Args:
      step_mult: current multiplier.
      previous: expected cost of the previous controller under the previous model.
      predicted: expected cost of the current controller under the previous model.
      actual: expected cost of the current controller under the new model.
    """
    predicted_impr = previous - predicted
    actual_impr = previous - actual
    change = predicted_impr / (2.0 * max(1e-4, predicted_impr - actual_impr))
    change = float(np.clip(change, STEP_CHANGE_MIN, STEP_CHANGE_MAX))
    return float(np.clip(step_mult * change, cfg.min_step_mult, cfg.max_step_mult))
