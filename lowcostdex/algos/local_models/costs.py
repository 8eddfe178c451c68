"""Trajectory costs with analytic derivatives for learned-local-model optimisation.

Every cost maps one trajectory (states ``X`` of shape (T, dX), actions ``U`` of shape (T, dU))
to a :class:`CostDerivatives` holding the per-step value and its first and second derivatives.
:func:`quadratic_expansion` re-centres those derivatives into the quadratic form the LQR solver
uses, ``l(y) ~ 1/2 y^T C y + c^T y + cc`` with ``y = [x; u]``, and :func:`average_expansion`
averages it over the N rollouts of an iteration.

Units follow the state and action: a state cost weight ``w`` on an angle in rad gives a cost in
``w * rad^2``. Costs are dimensionless to the optimiser; only their relative scale matters (the KL
trust region, not the cost scale, sets the step size).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from lowcostdex.errors import ConfigError, check_choice, check_number

Array = NDArray[np.float64]
RampKind = Literal["constant", "linear", "quadratic", "final_only"]
RAMP_KINDS: tuple[str, ...] = ("constant", "linear", "quadratic", "final_only")


@dataclass(frozen=True)
class CostDerivatives:
    """Per-step cost and derivatives along one trajectory of T steps.

    Attributes:
      value: (T,) cost at each step.
      lx: (T, dX) gradient with respect to the state.
      lu: (T, dU) gradient with respect to the action.
      lxx: (T, dX, dX) state Hessian.
      luu: (T, dU, dU) action Hessian.
      lux: (T, dU, dX) mixed second derivative d^2 l / (du dx).
    """

    value: Array
    lx: Array
    lu: Array
    lxx: Array
    luu: Array
    lux: Array

    def __add__(self, other: CostDerivatives) -> CostDerivatives:
        return CostDerivatives(
            self.value + other.value,
            self.lx + other.lx,
            self.lu + other.lu,
            self.lxx + other.lxx,
            self.luu + other.luu,
            self.lux + other.lux,
        )

    def scaled(self, weight: float) -> CostDerivatives:
        """All terms multiplied by ``weight``."""
        return CostDerivatives(
            weight * self.value,
            weight * self.lx,
            weight * self.lu,
            weight * self.lxx,
            weight * self.luu,
            weight * self.lux,
        )


class Cost(Protocol):
    """A trajectory cost: ``evaluate(X (T, dX), U (T, dU)) -> CostDerivatives``."""

    def evaluate(self, X: Array, U: Array) -> CostDerivatives: ...


def ramp_weights(kind: str, T: int, final_multiplier: float = 1.0, final_steps: int = 1) -> Array:
    """Per-step multipliers (T,) of a cost term over the horizon.

    ``constant``: 1; ``linear``: (t+1)/T; ``quadratic``: ((t+1)/T)^2; ``final_only``: 1 on the
    last ``final_steps`` steps, 0 elsewhere (a goal that must be reached and then held). The last
    step is then multiplied by ``final_multiplier``.
    """
    check_choice("ramp", kind, RAMP_KINDS)
    if T < 1:
        raise ConfigError(f"horizon T={T} must be >= 1")
    if not 1 <= final_steps <= T:
        raise ConfigError(f"final_steps={final_steps} must be in [1, T={T}]")
    frac = np.arange(1, T + 1, dtype=np.float64) / T
    if kind == "constant":
        ramp = np.ones(T)
    elif kind == "linear":
        ramp = frac
    elif kind == "quadratic":
        ramp = frac**2
    else:
        ramp = np.zeros(T)
        ramp[T - final_steps :] = 1.0
    ramp[-1] *= final_multiplier
    return ramp


def _zeros(T: int, dX: int, dU: int) -> CostDerivatives:
    return CostDerivatives(
        np.zeros(T),
        np.zeros((T, dX)),
        np.zeros((T, dU)),
        np.zeros((T, dX, dX)),
        np.zeros((T, dU, dU)),
        np.zeros((T, dU, dX)),
    )


def _check_vector(name: str, value: Array) -> None:
    if value.ndim != 1 or not np.all(np.isfinite(value)):
        raise ConfigError(f"{name} must be a finite 1-D array, got shape {value.shape}")


@dataclass(frozen=True, eq=False)
class StateCost:
    """Distance of the state to a target: ``ramp_t * (l2/2 d'Wd + l1 sqrt(alpha + d'Wd))``.

    ``d = x - target`` and ``W = diag(weights)``. The l2 term is a quadratic bowl; the l1 term is a
    smooth absolute value (pseudo-Huber) that keeps pulling when the state is already close. Both use
    the same weighting ``W``.

    Attributes:
      target: (dX,) target state, or (T, dX) one per step (a moving goal), units of the state.
      weights: (dX,) non-negative per-coordinate weights (0 ignores a coordinate).
      l2: weight of the quadratic term.
      l1: weight of the smooth-absolute term.
      alpha: smoothing of the l1 term (> 0), units of d'Wd.
      ramp: how the weight grows over the horizon, one of ``RAMP_KINDS``.
      final_multiplier: extra factor on the last step.
      final_steps: steps at the end weighted by the ``final_only`` ramp.
    """

    target: Array
    weights: Array
    l2: float = 1.0
    l1: float = 0.0
    alpha: float = 1e-2
    ramp: str = "constant"
    final_multiplier: float = 1.0
    final_steps: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "target", np.asarray(self.target, dtype=np.float64))
        object.__setattr__(self, "weights", np.asarray(self.weights, dtype=np.float64))
        _check_vector("weights", self.weights)
        if self.target.ndim not in (1, 2) or not np.all(np.isfinite(self.target)):
            raise ConfigError(f"target must be finite, (dX,) or (T, dX); got {self.target.shape}")
        if self.target.shape[-1:] != self.weights.shape:
            raise ConfigError(
                f"target {self.target.shape} and weights {self.weights.shape} differ in shape"
            )
        if np.any(self.weights < 0):
            raise ConfigError("StateCost weights must be >= 0")
        check_number("StateCost.l2", self.l2, 0)  # (a NaN passed every comparison: a NaN cost)
        check_number("StateCost.l1", self.l1, 0)
        check_number("StateCost.alpha", self.alpha, 0, low_open=True)
        check_number("StateCost.final_multiplier", self.final_multiplier)
        check_choice("ramp", self.ramp, RAMP_KINDS)
        check_number("StateCost.final_steps", self.final_steps, 1, integer=True)

    def evaluate(self, X: Array, U: Array) -> CostDerivatives:
        T, dX = X.shape
        if dX != self.weights.shape[0]:  # (before: numpy's broadcast error)
            raise ConfigError(f"states of {dX} coordinates; this cost weighs "
                              f"{self.weights.shape[0]} (weights, target)")
        if self.target.ndim == 2 and self.target.shape[0] != T:
            raise ConfigError(f"target has {self.target.shape[0]} steps, the trajectory {T}")
        out = _zeros(T, dX, U.shape[1])
        ramp = ramp_weights(self.ramp, T, self.final_multiplier, self.final_steps)
        w = self.weights
        d = X - self.target  # (T, dX)
        wd = w * d
        sq = np.einsum("ti,ti->t", d, wd)  # d'Wd
        root = np.sqrt(self.alpha + sq)
        value = 0.5 * self.l2 * sq + self.l1 * root
        lx = self.l2 * wd + self.l1 * wd / root[:, None]
        lxx = self.l2 * np.diag(w)[None] + self.l1 * (
            np.diag(w)[None] / root[:, None, None]
            - np.einsum("ti,tj->tij", wd, wd) / root[:, None, None] ** 3
        )
        return CostDerivatives(
            ramp * value,
            ramp[:, None] * lx,
            out.lu,
            ramp[:, None, None] * lxx,
            out.luu,
            out.lux,
        )


@dataclass(frozen=True, eq=False)
class ActionCost:
    """Quadratic action penalty ``ramp_t * 1/2 sum_i weights_i (u_t,i - target_t,i)^2``.

    Attributes:
      weights: (dU,) non-negative per-action weights.
      target: (dU,) action that costs nothing (e.g. the one holding the start pose), or (T, dU)
        one per step (e.g. the demonstrated actions); None is 0.
      ramp: how the weight varies over the horizon, one of ``RAMP_KINDS``.
      final_multiplier: factor on the last step (0 drops the action cost at the end).
    """

    weights: Array
    target: Array | None = None
    ramp: str = "constant"
    final_multiplier: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "weights", np.asarray(self.weights, dtype=np.float64))
        _check_vector("weights", self.weights)
        if np.any(self.weights < 0):
            raise ConfigError("action weights must be >= 0")
        target = np.zeros_like(self.weights) if self.target is None else self.target
        object.__setattr__(self, "target", np.asarray(target, dtype=np.float64))
        if self.target.ndim not in (1, 2) or self.target.shape[-1:] != self.weights.shape:
            raise ConfigError(
                f"action target {self.target.shape} must be (dU,) or (T, dU) with "
                f"dU = {self.weights.shape[0]} (the weights)"
            )
        if not np.all(np.isfinite(self.target)):
            raise ConfigError("action target must be finite")
        check_choice("ramp", self.ramp, RAMP_KINDS)
        check_number("ActionCost.final_multiplier", self.final_multiplier)

    def evaluate(self, X: Array, U: Array) -> CostDerivatives:
        T, dU = U.shape
        if dU != self.weights.shape[0]:  # (before: numpy's einsum error)
            raise ConfigError(f"actions of {dU} coordinates; this cost weighs "
                              f"{self.weights.shape[0]} (weights, target)")
        if self.target.ndim == 2 and self.target.shape[0] != T:
            raise ConfigError(f"action target has {self.target.shape[0]} steps, the trajectory {T}")
        out = _zeros(T, X.shape[1], dU)
        ramp = ramp_weights(self.ramp, T, self.final_multiplier)
        d = U - self.target
        value = 0.5 * np.einsum("ti,i,ti->t", d, self.weights, d)
        lu = self.weights * d
        luu = np.broadcast_to(np.diag(self.weights), (T, dU, dU))
        return CostDerivatives(
            ramp * value, out.lx, ramp[:, None] * lu, out.lxx, ramp[:, None, None] * luu, out.lux
        )


@dataclass(frozen=True, eq=False)
class SumCost:
    """Weighted sum of costs."""

    costs: Sequence[Cost]
    weights: Sequence[float] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        if len(self.costs) == 0:
            raise ConfigError("SumCost needs at least one cost")
        if self.weights and len(self.weights) != len(self.costs):
            raise ConfigError(
                f"{len(self.weights)} weights for {len(self.costs)} costs; give one per cost"
            )

    def evaluate(self, X: Array, U: Array) -> CostDerivatives:
        weights = self.weights or (1.0,) * len(self.costs)
        total = _zeros(X.shape[0], X.shape[1], U.shape[1])
        for cost, weight in zip(self.costs, weights, strict=True):
            total = total + cost.evaluate(X, U).scaled(weight)
        return total


@dataclass(frozen=True)
class QuadraticCost:
    """Quadratic model of the cost per step: ``l_t(y) = 1/2 y'C_t y + c_t'y + cc_t``, y = [x; u].

    Attributes:
      C: (T, dX+dU, dX+dU) Hessians.
      c: (T, dX+dU) linear terms.
      cc: (T,) constants.
    """

    C: Array
    c: Array
    cc: Array


def quadratic_expansion(derivs: CostDerivatives, X: Array, U: Array) -> QuadraticCost:
    """Re-centre the derivatives taken at (X, U) into absolute quadratic coefficients.

    With y_hat = [x_t; u_t], gradient g and Hessian C: ``c = g - C y_hat`` and
    ``cc = l - g'y_hat + 1/2 y_hat'C y_hat``, so the model equals ``l`` exactly at y_hat.
    """
    dX = X.shape[1]
    y = np.concatenate([X, U], axis=1)  # (T, dXU)
    T, dXU = y.shape
    C = np.zeros((T, dXU, dXU))
    C[:, :dX, :dX] = derivs.lxx
    C[:, dX:, dX:] = derivs.luu
    C[:, dX:, :dX] = derivs.lux
    C[:, :dX, dX:] = np.swapaxes(derivs.lux, 1, 2)
    g = np.concatenate([derivs.lx, derivs.lu], axis=1)
    Cy = np.einsum("tij,tj->ti", C, y)
    c = g - Cy
    cc = derivs.value - np.einsum("ti,ti->t", g, y) + 0.5 * np.einsum("ti,ti->t", y, Cy)
    return QuadraticCost(C, c, cc)


def average_expansion(cost: Cost, X: Array, U: Array) -> tuple[QuadraticCost, Array]:
    """Quadratic cost model averaged over N rollouts, and the raw per-step sample costs.

    Args:
      cost: the cost to expand.
      X: (N, T, dX) states of N rollouts.
      U: (N, T, dU) actions.

    Returns:
      (averaged QuadraticCost, sample costs of shape (N, T)).
    """
    expansions = []
    sample_costs = []
    for Xi, Ui in zip(X, U, strict=True):
        derivs = cost.evaluate(Xi, Ui)
        expansions.append(quadratic_expansion(derivs, Xi, Ui))
        sample_costs.append(derivs.value)
    mean = QuadraticCost(
        np.mean([e.C for e in expansions], axis=0),
        np.mean([e.c for e in expansions], axis=0),
        np.mean([e.cc for e in expansions], axis=0),
    )
    return mean, np.asarray(sample_costs)
