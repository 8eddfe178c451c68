"""Allegro tasks: turn a valve 360 deg with the palm-up Allegro hand (BAIR's Allegro valve task).

Conventions as the D'Claw tasks (``dclaw_tasks``): 10 Hz control (40 x 2.5 ms); observation =
joint positions (16), joint velocities (16), valve (cos, sin), goal error, last action (16);
reward terms -5|err|, -0.2||q - q_reset||, -||v[|v| > 0.5]||, +10 (|err| < 0.25),
+50 (|err| < 0.1); success |err| < 0.1 rad. The goal is 2 pi past the start: the valve hinge is
unlimited, its angle is not wrapped, and the error is the plain difference goal - angle.

``ENVS`` lists ``AllegroTurnValve-v0`` and ``AllegroTurnValveRandom-v0``; ``lowcostdex.sim.registry``
reads it (this module does not import the registry: the envs sit below it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import keyword_hints
from lowcostdex.hands import HandSpec, allegro_spec
from lowcostdex.sim.envs.hand_env import HandEnv, make_hand_env
from lowcostdex.sim.envs.task import VALVE_BOUNDS, VALVE_GOAL, Goal, Task, TaskSpec, check_settings
from lowcostdex.sim.models.allegro import AllegroPD, AllegroValve, build_allegro
from lowcostdex.sim.models.common import quat_euler

# [rad] index, middle, ring (joints 0-3), thumb (joints 0-3): fingers flat, thumb tucked in
RESET_POSE = np.array([0.0, 0.0, 0.0, 0.0] * 3 + [0.3, 0.0, 0.0, 0.0])


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(np.square(x), axis=-1))


@keyword_hints
@dataclass(frozen=True)
class AllegroTurnConfig:
    """Valve-turning goal distribution for the Allegro.

    Attributes:
      init_range: initial valve angle ~ U(-init_range, init_range) [rad] (0: fixed at 0).
      goal_offset: goal relative to the initial angle [rad] (2 pi = 360 deg).
      goal_range: goal ~ init + goal_offset + U(-goal_range, goal_range) [rad].
      success_tol: |error| for success [rad].
      pose_noise: std of Gaussian noise on the initial hand pose [rad] (clipped to the limits).
    """

    init_range: float = 0.0
    goal_offset: float = 2 * math.pi
    goal_range: float = 0.0
    success_tol: float = 0.1
    pose_noise: float = 0.0

    def __post_init__(self) -> None:
        check_settings(self, VALVE_BOUNDS)


class AllegroTurnValve(Task):
    """Turn the valve above the palm-up Allegro by ``goal_offset`` (default 360 deg)."""

    object_joint = "valve"
    goal_bounds = VALVE_GOAL

    def __init__(self, config: AllegroTurnConfig = AllegroTurnConfig(),
                 hand: HandSpec | None = None, pd: AllegroPD | None = None,
                 valve: AllegroValve | None = None, timing: TaskSpec | None = None):
        self.config = config
        self.hand = hand or allegro_spec()
        self.pd = pd or AllegroPD()
        self.valve = valve or AllegroValve()
        self.timing = timing or TaskSpec(frame_skip=40, episode_steps=100)

    def build_spec(self) -> mujoco.MjSpec:
        return build_allegro("valve", self.hand, self.pd, self.valve)

    @property
    def obs_dim(self) -> int:
        return 16 + 16 + 2 + 1 + 16

    def initial_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, Goal]:
        c = self.config
        qpos = np.zeros(self.model.nq)
        pose = RESET_POSE + (c.pose_noise * rng.normal(size=16) if c.pose_noise > 0 else 0.0)
        qpos[self.hand_qpos] = np.clip(pose, self.hand_low, self.hand_high)
        init = rng.uniform(-c.init_range, c.init_range) if c.init_range > 0 else 0.0
        goal = init + c.goal_offset + (rng.uniform(-c.goal_range, c.goal_range)
                                       if c.goal_range > 0 else 0.0)
        qpos[self.obj_qpos] = init
        return qpos, np.zeros(self.model.nv), {"angle": np.asarray(goal, float)}

    def error(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        """goal - valve angle [rad], unwrapped (...)."""
        return goal["angle"] - qpos[..., self.obj_qpos]

    def observation(self, qpos, qvel, goal, last_action):
        q, v = qpos[..., self.hand_qpos], qvel[..., self.hand_dof]
        theta = qpos[..., self.obj_qpos]
        err = self.error(qpos, goal)[..., None]
        return np.concatenate([q, v, np.cos(theta)[..., None], np.sin(theta)[..., None], err,
                               last_action], axis=-1)

    def reward_terms(self, qpos, qvel, goal, action):
        err = np.abs(self.error(qpos, goal))
        q, v = qpos[..., self.hand_qpos], qvel[..., self.hand_dof]
        fast = np.where(np.abs(v) >= 0.5, v, 0.0)
        return {"goal_error": -5.0 * err,
                "pose": -0.2 * _norm(q - RESET_POSE),
                "velocity": -1.0 * _norm(fast),
                "bonus_small": 10.0 * (err < 0.25),
                "bonus_big": 50.0 * (err < 0.10)}

    def success(self, qpos, goal):
        return np.abs(self.error(qpos, goal)) < self.config.success_tol

    def goal_error(self, qpos, goal):
        return self.error(qpos, goal)

    def goal_marker(self, goal):
        top = self.model.body("target").pos
        return np.array(top), np.array(quat_euler(z=float(goal["angle"])))


def _allegro(config: AllegroTurnConfig):
    def make(backend: str = "sim", randomize: Sequence[str] | None = None,
             render_mode: str | None = None, **kwargs: Any) -> HandEnv:
        overrides = {k: kwargs.pop(k) for k in list(kwargs) if hasattr(config, k)}
        task = AllegroTurnValve(AllegroTurnConfig(**{**config.__dict__, **overrides}))
        return make_hand_env(task, backend=backend, randomize=randomize,
                             render_mode=render_mode, **kwargs)

    return make


# id -> (factory, max_episode_steps, default kwargs), as ``registry.ENVS``
ENVS: dict[str, tuple[Any, int, dict[str, Any]]] = {
    "AllegroTurnValve-v0": (_allegro(AllegroTurnConfig()), 100, {}),
    "AllegroTurnValveRandom-v0": (
        _allegro(AllegroTurnConfig(init_range=math.pi / 3, goal_range=math.pi / 3)), 100, {}),
}
