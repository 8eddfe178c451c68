"""MDGPS's start conditions, where its rollouts come from: the pendulum started at several states
(``PendulumConditions``) or a gymnasium task reset to one fixed start per condition
(``EnvConditions``, built with its costs and initial controllers by ``env_problem``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController, pd_controller
from lowcostdex.algos.local_models.costs import SumCost
from lowcostdex.algos.local_models.episodes import (
    FixedStart,
    capture_start,
    controller_state,
    hold_action,
    offset_start,
    run_episode,
)
from lowcostdex.algos.local_models.pendulum import PendulumParams, pendulum_rollouts
from lowcostdex.algos.local_models.task_cost import task_cost
from lowcostdex.algos.local_models.train_config import TaskCostConfig
from lowcostdex.algos.samplers import RolloutJob

Array = NDArray[np.float64]
_TRAIN_STREAM = 0  # rollout stream of the training samples


class Actor(Protocol):
    """A TVLG controller or a :class:`PolicyActor`."""

    T: int
    dX: int
    dU: int

    def act(self, t: int, x: Array, noise: Array | None = None) -> Array: ...


class ConditionSampler(Protocol):
    """Rollouts from a numbered start condition."""

    n_conditions: int

    def sample(
        self, condition: int, actor: Actor, n: int, iteration: int, deterministic: bool = False
    ) -> tuple[Array, Array]:
        """n rollouts X (n, T, dX), U (n, T, dU); noise-free if ``deterministic``."""
        ...


class _NoiseFree:
    """An actor that ignores the exploration noise (its mean action)."""

    def __init__(self, actor: Actor):
        self.actor, self.T, self.dX, self.dU = actor, actor.T, actor.dX, actor.dU

    def act(self, t: int, x: Array, noise: Array | None = None) -> Array:
        return self.actor.act(t, x, None)


@dataclass(frozen=True)
class PendulumConditions:
    """The pendulum of :mod:`.pendulum` started at several states.

    Attributes:
      starts: one (theta [rad], omega [rad/s]) per condition.
      params: the pendulum.
      seed: seed of the exploration noise (stream per condition, iteration, purpose).
    """

    starts: tuple[tuple[float, float], ...]
    params: PendulumParams = PendulumParams()
    seed: int = 0

    @property
    def n_conditions(self) -> int:
        return len(self.starts)

    def sample(
        self, condition: int, actor: Actor, n: int, iteration: int, deterministic: bool = False
    ) -> tuple[Array, Array]:
        rng = np.random.default_rng(
            np.random.SeedSequence(self.seed, spawn_key=(_TRAIN_STREAM, iteration, condition))
        )
        act = _NoiseFree(actor) if deterministic else actor
        return pendulum_rollouts(act, n, rng, self.params, np.asarray(self.starts[condition]))  # type: ignore[arg-type]


class EnvConditions:
    """A gymnasium task of :mod:`.train` reset to one :class:`~.train.FixedStart` per condition.

    Runs :func:`.train.run_episode`, the TVLG trainer's episodes (controller state =
    ``state_vector()`` plus the last applied action if ``include_last_action``); condition m
    draws its noise from rollout stream ``100 + m`` of ``seed``.
    """

    def __init__(
        self,
        env: gym.Env,
        starts: Sequence[FixedStart],
        hold: Array,
        include_last_action: bool = True,
        smooth_noise: float = 0.0,
        seed: int = 0,
    ):
        self.env, self.starts, self.hold = env, list(starts), hold
        self.include_last_action = include_last_action
        self.smooth_noise, self.seed = smooth_noise, seed

    @property
    def n_conditions(self) -> int:
        return len(self.starts)

    def sample(
        self, condition: int, actor: Actor, n: int, iteration: int, deterministic: bool = False
    ) -> tuple[Array, Array]:
        episodes = [
            run_episode(
                self.env,
                actor,  # type: ignore[arg-type]  # duck-typed: T, dX, dU, act
                self.starts[condition],
                RolloutJob(self.seed, 100 + condition, iteration, i, deterministic),
                self.include_last_action,
                self.hold,
                self.smooth_noise,
            )
            for i in range(n)
        ]
        return np.stack([e.X for e in episodes]), np.stack([e.U for e in episodes])


def env_problem(
    env: gym.Env,
    offsets: Sequence[float],
    seed: int = 0,
    init_noise: float = 0.3,
    cost: TaskCostConfig | None = None,
    include_last_action: bool = True,
) -> tuple[EnvConditions, list[SumCost], list[LinearGaussianController]]:
    """Conditions, costs and initial controllers of a valve/screw task for :func:`train_mdgps`.

    Condition m starts from the state captured with ``seed`` with the object and its goal both
    turned by ``offsets[m]`` [rad] (:func:`.train.offset_start`); its cost is
    :func:`.train.task_cost` and its initial controller holds the start pose with exploration
    noise of std ``init_noise`` [normalised action] (the TVLG trainer's "pd" init, gain 0).
    """
    base = capture_start(env, seed)
    hold = hold_action(env, base)
    starts = [offset_start(env, base, o) for o in offsets]
    spec_steps = env.spec.max_episode_steps if env.spec else None
    T = int(spec_steps or env.unwrapped.task.timing.episode_steps) + 1
    n_hand = len(env.unwrapped.task.hand_qpos)
    costs, controllers = [], []
    for start in starts:
        env.reset(options=start.reset_options())
        x0 = controller_state(env, hold if include_last_action else None)
        costs.append(task_cost(env, start, hold, cost or TaskCostConfig(), T, x0.shape[0]))
        controllers.append(
            pd_controller(x0, hold, T, list(range(n_hand)), None, 0.0, 0.0, init_noise**2)
        )
    sampler = EnvConditions(env, starts, hold, include_last_action, 0.0, seed)
    return sampler, costs, controllers
