"""A tiny deterministic 1-D point-mass task for the NPG/DAPG tests (not a lowcostdex env).

State: position x [m] and velocity v [m/s]; action: force in [-1, 1] [N] on a 1 kg mass;
dt = 0.1 s; 30 steps (TimeLimit truncation). Reward: -|x - goal| - 0.01 a^2, reported as the
terms ``reward_distance`` and ``reward_effort``; success when |x - goal| < 0.1.
The start position is drawn from the env's seeded generator.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit

HORIZON = 30


class PointMass(gym.Env):
    metadata = {"render_modes": []}

    def __init__(self, goal: float = 0.0, backend: str = "sim"):
        assert backend == "sim", "the point mass only exists in simulation"
        self.goal = goal
        self.dt = 0.1
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float64)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
        self.x = self.v = 0.0

    def _obs(self):
        return np.array([self.x, self.v, self.goal - self.x])

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1.5, 1.5))
        self.v = 0.0
        return self._obs(), {}

    def step(self, action):
        a = float(np.clip(action[0], -1, 1))
        self.v += a * self.dt
        self.x += self.v * self.dt
        dist = -abs(self.x - self.goal)
        effort = -0.01 * a * a
        info = {
            "reward_distance": dist,
            "reward_effort": effort,
            "success": abs(self.x - self.goal) < 0.1,
        }
        return self._obs(), dist + effort, False, False, info


def make_pointmass() -> gym.Env:
    """Picklable factory (used by the process sampler in the tests)."""
    return TimeLimit(PointMass(), HORIZON)


def expert_action(obs: np.ndarray) -> np.ndarray:
    """A PD controller that solves the task (the 'teacher' for BC/DAPG tests)."""
    x, v, err = obs
    return np.clip([2.0 * err - 2.0 * v], -1.0, 1.0)


def demo_info():
    """``DatasetInfo`` of point-mass demonstration files (it is not a hand env)."""
    from lowcostdex.demonstrations.file import DatasetInfo

    return DatasetInfo(env_id="test/PointMass", task="PointMass", hand="{}",
                       source="scripted_teacher", control_period=0.1, obs_dim=3, act_dim=1,
                       action_joints=("force",))


def broken_env() -> gym.Env:
    """A factory that fails, as a robot that is not connected would."""
    raise RuntimeError("no robot here")
