"""A reward term for DAPG's simulation that grades how near the goal an episode ends up.

The valve task's reward (``sim.envs.dclaw_tasks.ValveTask.reward_terms``) pays -5 |error| per
step plus flat bonuses: 10 under 0.25 rad, 50 more under 0.1 rad (the success tolerance). Inside
each band the bonus is flat, so an episode that settles at 0.12 rad earns the same bonus as one
at 0.2, and one at 0.09 the same as one at 0.01; the -5 |error| term separates them by a few
tenths per step, far below the episode-to-episode spread of the return. The main job's policy
is judged on the robot by its deterministic final error against 0.1 rad, where most of DAPG's
misses are near misses (0.1-0.2 rad; bench/RESULTS.md, "The main job's RL stage"), and a
policy that ends at 0.09 rad in simulation can end at 0.12 on a robot with other friction.

``GoalRamp`` adds ``weight * max(0, 1 - |error| / radius)`` per step (``info["goal_error"]``
after the step): a ramp that rises toward the goal through the near-miss band and the
tolerance alike. It changes the training reward only: success (``info["success"]``: final
|error| < the task's tolerance), the validation and every reported count are the task's own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np


@dataclass(frozen=True)
class GoalRamp:
    """The ramp's settings.

    Attributes:
      weight: reward per step at zero error (the task's success bonus is 50 per step).
      radius: error [rad] at which the ramp reaches zero.
    """

    weight: float = 50.0
    radius: float = 0.2

    def __post_init__(self) -> None:
        from lowcostdex.errors import check_number

        check_number("GoalRamp.weight", self.weight, 0, low_open=True)
        check_number("GoalRamp.radius", self.radius, 0, low_open=True)

    def reward(self, goal_error: float) -> float:
        """The ramp's reward for one step whose signed goal error is ``goal_error`` [rad]."""
        return self.weight * max(0.0, 1.0 - abs(goal_error) / self.radius)


class GoalRampReward(gym.Wrapper):
    """``env`` with ``ramp.reward(info["goal_error"])`` added to every step's reward (and
    reported as ``info["reward_goal_ramp"]``)."""

    def __init__(self, env: gym.Env, ramp: GoalRamp):
        super().__init__(env)
        self.ramp = ramp

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        extra = self.ramp.reward(float(np.asarray(info["goal_error"])))
        info = {**info, "reward_goal_ramp": extra}
        return obs, float(reward) + extra, terminated, truncated, info


@dataclass(frozen=True)
class ShapedEnvFactory:
    """An env factory (``algos.samplers.EnvFactory``) whose envs carry ``GoalRampReward``."""

    factory: Any
    ramp: GoalRamp

    def __call__(self) -> gym.Env:
        return GoalRampReward(self.factory(), self.ramp)
