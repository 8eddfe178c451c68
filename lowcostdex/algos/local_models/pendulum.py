"""A torque-limited pendulum: the small nonlinear test system of the local-model optimiser.

The pendulum starts hanging at rest (theta = 0) and must reach horizontal (theta = pi/2) at the
end of a 3 s episode. Holding it there needs 9.81 N m, more than the 6 N m limit, so the optimal
motion is a swing timed to arrive at the end; saturation makes the dynamics nonlinear. Used by the
tests, by ``bench/local_models.py`` (TVLG vs NPG samples) and as a reference for the cost scale
(reference 03, section 8.7: a NumPy re-implementation converged to 34.4-34.6).

Units: theta [rad] from hanging, omega [rad/s], torque [N m] on a unit point mass at unit length.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController, exploration_noise
from lowcostdex.algos.local_models.costs import ActionCost, StateCost, SumCost

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PendulumParams:
    """Physical and task constants.

    Attributes:
      dt: control period [s].
      T: steps per episode (states x_0..x_{T-1}).
      max_torque: torque limit [N m].
      damping: viscous damping [1/s].
      gravity: g / l [1/s^2].
      target: goal angle [rad].
      state_weights: cost weights of (theta, omega).
      action_weight: cost weight of the torque.
      final_multiplier: weight of the last step's state cost.
    """

    dt: float = 0.05
    T: int = 60
    max_torque: float = 6.0
    damping: float = 0.1
    gravity: float = 9.81
    target: float = np.pi / 2
    state_weights: tuple[float, float] = (1.0, 0.05)
    action_weight: float = 1e-3
    final_multiplier: float = 10.0


def pendulum_step(x: Array, torque: float, p: PendulumParams) -> Array:
    """Semi-implicit Euler step of theta'' = clip(torque) - g sin(theta) - damping theta'."""
    theta, omega = x
    tau = float(np.clip(torque, -p.max_torque, p.max_torque))
    omega = omega + p.dt * (tau - p.gravity * np.sin(theta) - p.damping * omega)
    return np.array([theta + p.dt * omega, omega])


def pendulum_cost(p: PendulumParams) -> SumCost:
    """Quadratic cost on (theta - target, omega) with a final x``final_multiplier``, plus torque."""
    return SumCost(
        [
            StateCost(
                np.array([p.target, 0.0]),
                np.array(p.state_weights),
                final_multiplier=p.final_multiplier,
            ),
            ActionCost(np.array([p.action_weight])),
        ]
    )


def pendulum_rollouts(
    controller: LinearGaussianController,
    n: int,
    rng: np.random.Generator,
    p: PendulumParams,
    x0: Array | None = None,
) -> tuple[Array, Array]:
    """n episodes: X (n, T, 2), U (n, T, 1), recording the commanded torque.

    Episodes start at ``x0`` = (theta [rad], omega [rad/s]), at rest hanging if None. Any object
    with ``T`` and ``act(t, x, noise)`` can stand in for the controller (e.g. a neural policy).
    """
    T = controller.T
    start = np.zeros(2) if x0 is None else np.asarray(x0, dtype=np.float64)
    X, U = np.zeros((n, T, 2)), np.zeros((n, T, 1))
    for i in range(n):
        x, noise = start.copy(), exploration_noise(rng, T, 1)
        for t in range(T):
            X[i, t] = x
            U[i, t] = controller.act(t, x, noise[t])
            x = pendulum_step(x, U[i, t, 0], p)
    return X, U


class PendulumSwingEnv(gym.Env):
    """The same task as a gymnasium env, for model-free baselines.

    Observation: (theta, omega, t / T). Action: torque / max_torque in [-1, 1].
    Reward: minus the per-step cost of :func:`pendulum_cost`, so an episode's return is minus the
    trajectory cost the local-model optimiser minimises. The episode has T - 1 actions; the last
    reward includes the final-state term. ``info["success"]``: |theta - target| < 0.1 at the end.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, params: PendulumParams = PendulumParams()):
        self.p = params
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float64)
        self.control_period = params.dt
        self._cost = pendulum_cost(params)
        self._x = np.zeros(2)
        self._t = 0

    def _obs(self) -> Array:
        return np.array([self._x[0], self._x[1], self._t / self.p.T])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._x, self._t = np.zeros(2), 0
        return self._obs(), {}

    def step(self, action):
        tau = (
            float(np.clip(np.asarray(action, dtype=float).reshape(-1)[0], -1, 1))
            * self.p.max_torque
        )
        p = self.p
        w = np.array(p.state_weights)
        cost = 0.5 * np.sum(w * (self._x - [p.target, 0.0]) ** 2) + 0.5 * p.action_weight * tau**2
        self._x = pendulum_step(self._x, tau, p)
        self._t += 1
        last = self._t == p.T - 1
        if last:  # the final state x_{T-1} has no action: its cost is paid here
            cost += p.final_multiplier * 0.5 * np.sum(w * (self._x - [p.target, 0.0]) ** 2)
        info = {"success": bool(last and abs(self._x[0] - p.target) < 0.1)}
        return self._obs(), -float(cost), False, last, info
