"""HandEnv: one gymnasium env for every hand task and every backend.

Actions in [-1, 1] map to joint targets over the hand spec's limits, then are clipped to a per-step
motion bound around the present position (max_velocity x control period) and to the limits, as
ROBEL does. The bound is the robot's (``lowcostdex.motion``): narrowed by what a joint may move
while a goal is in flight on a clean bus, so a policy learns with the bound the robot applies. Reward = sum of the task's named terms, each reported in ``info`` as
``reward_<term>``; ``info["success"]`` is the task's success flag. Episodes end by truncation (time
limit) unless the task reaches a terminal state (e.g. the block fell). All randomness comes from
the env's seeded generator (``reset(seed=...)``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.motion import motion_bound
from lowcostdex.sim.effects import DomainRandomization
from lowcostdex.sim.envs.backend import Backend, backend_class
from lowcostdex.sim.envs.task import Goal, Task
from lowcostdex.sim.plant import prepare_spec


def action_to_goal(action: np.ndarray, low: np.ndarray, high: np.ndarray, present: np.ndarray,
                   max_step: np.ndarray) -> np.ndarray:
    """Map normalized actions (..., n) in [-1, 1] to joint goals [rad].

    The goal is the denormalized action, moved at most ``max_step`` [rad] from ``present``, then
    clipped to [low, high].
    """
    a = np.clip(action, -1.0, 1.0)
    target = 0.5 * (high + low) + 0.5 * (high - low) * a
    target = np.clip(target, present - max_step, present + max_step)
    return np.clip(target, low, high)


def goal_to_action(goal: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Inverse of the denormalization: joint goals [rad] -> actions in [-1, 1]."""
    return np.clip((2.0 * goal - (high + low)) / (high - low), -1.0, 1.0)


class HandEnv(gym.Env):
    """A hand task on a backend.

    Args:
      task: the task (model, initial states, observation, reward).
      backend: "sim", "emulated" or "hardware".
      randomization: domain randomization sampled at every reset (sim backend only).
      render_mode: None or "rgb_array".
      backend_kwargs: passed to the backend (e.g. ``port="/dev/ttyUSB0"`` for a D'Claw,
        ``channel="can0"`` for an Allegro).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, task: Task, backend: str = "sim",
                 randomization: DomainRandomization | None = None,
                 render_mode: str | None = None, **backend_kwargs: Any):
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode {render_mode!r}; valid: None, 'rgb_array'")
        self.task = task
        self.randomization = randomization
        spec = task.build_spec()
        if randomization is not None:
            if backend != "sim":
                raise ConfigError("domain randomization needs backend='sim'")
            probe = randomization.sample(np.random.default_rng(0))
            prepare_spec(spec, probe)
        self.model = spec.compile()
        task.bind(self.model)
        self.backend_name = backend
        self._rng_for_backend = np.random.default_rng(0)
        self.backend: Backend = backend_class(backend, task.hand.name)(
            self.model, task=task, rng=self._rng_for_backend, **backend_kwargs)
        self.model, self.data = self.backend.model, self.backend.data
        n = len(task.hand.joints)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(task.obs_dim,),
                                                dtype=np.float32)
        period = task.timing.frame_skip * self.model.opt.timestep
        self.control_period = period
        # every actuator is a motor on the robot's bus
        self._max_step = motion_bound(task.hand, period, self.model.nu)
        self._aux = np.setdiff1d(np.arange(self.model.nu), task.hand_act)  # e.g. valve motor
        self.render_mode = render_mode
        self._renderer: mujoco.Renderer | None = None
        self._goal: Goal = {}
        self._last_action = np.zeros(n)
        self._steps = 0

    # ------------------------------------------------------------------------------------------
    def state_vector(self) -> np.ndarray:
        """Physical state [hand qpos, hand qvel, object qpos, object qvel] (float64).

        Used by learned local models; object entries are every qpos/qvel not in the hand.
        """
        t = self.task
        q, v = self.data.qpos, self.data.qvel
        obj_q = np.delete(q, t.hand_qpos)
        obj_v = np.delete(v, t.hand_dof)
        return np.concatenate([q[t.hand_qpos], v[t.hand_dof], obj_q, obj_v]).astype(np.float64)

    @property
    def max_step(self) -> np.ndarray:
        """Per-step motion bound of the action joints (n,) [rad] (``motion.motion_bound``)."""
        return self._max_step.copy()

    @property
    def goal(self) -> Goal:
        return self._goal

    def _obs(self) -> np.ndarray:
        qpos = self.backend.observed_qpos()
        obs = self.task.observation(qpos, self.data.qvel, self._goal, self._last_action)
        return obs.astype(np.float32)

    def _info(self, terms: dict[str, np.ndarray]) -> dict[str, Any]:
        t = self.task
        info: dict[str, Any] = {f"reward_{k}": float(v) for k, v in terms.items()}
        info["success"] = bool(t.success(self.data.qpos, self._goal))
        info["goal_error"] = float(t.goal_error(self.data.qpos, self._goal))
        info["time"] = self._steps * self.control_period
        if self.backend.real_time:  # robots report currents, temperatures, pauses, resets
            info["telemetry"] = self.backend.telemetry()
        return info

    def _terms(self, action: np.ndarray) -> dict[str, np.ndarray]:
        return self.task.reward_terms(self.data.qpos, self.data.qvel, self._goal, action)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode. ``options`` may hold ``qpos``/``qvel`` (a fixed start state) and
        ``goal`` (a dict overriding the task's goal)."""
        super().reset(seed=seed)
        options = options or {}
        qpos, qvel, goal = self.task.initial_state(self.np_random)
        qpos = np.asarray(options.get("qpos", qpos), dtype=float)
        qvel = np.asarray(options.get("qvel", qvel), dtype=float)
        if self.randomization is not None:
            self.backend.set_effects(self.randomization.sample(self.np_random))
        # Noise effects in the backend draw from a stream derived from the env's generator.
        self._rng_for_backend.bit_generator.state = np.random.default_rng(
            self.np_random.integers(2**63)).bit_generator.state
        self.backend.reset(qpos, qvel)
        goal = options.get("goal") or self.task.start_goal(self.data.qpos, goal)
        self._goal = {k: np.asarray(v, float) for k, v in goal.items()}
        self._steps = 0
        self._last_action = np.zeros(self.action_space.shape[0])
        self._update_marker()
        return self._obs(), self._info(self._terms(self._last_action))

    def step(self, action):
        a = np.asarray(action, dtype=float)
        if a.size != int(np.prod(self.action_space.shape)):
            raise ValueError(f"action has shape {a.shape}; this env takes "
                             f"{self.action_space.shape} (one value in [-1, 1] per joint: "
                             f"{', '.join(self.task.hand.joint_names)})")
        a = a.reshape(self.action_space.shape)
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action has NaN/inf entries: {a}")
        a = np.clip(a, -1.0, 1.0)
        t = self.task
        present = self.data.qpos[t.hand_qpos]
        goal = action_to_goal(a, t.hand_low, t.hand_high, present, self._max_step)
        ctrl = np.empty(self.model.nu)
        ctrl[t.hand_act] = goal
        ctrl[self._aux] = t.aux_ctrl(self.data.qpos)
        self.backend.apply(ctrl, t.timing.frame_skip)
        self._steps += 1
        self._goal = t.advance_goal(self._goal, self._steps)
        self._last_action = a
        self._update_marker()
        terms = self._terms(a)
        reward = float(sum(float(v) for v in terms.values()))
        info = self._info(terms)
        info["goal"] = goal
        terminated = bool(t.terminated(self.data.qpos, self._goal))
        truncated = False  # the TimeLimit wrapper truncates at task.timing.episode_steps
        return self._obs(), reward, terminated, truncated, info

    def _update_marker(self) -> None:
        marker = self.task.goal_marker(self._goal)
        if marker is not None and self.model.nmocap:
            self.data.mocap_pos[0], self.data.mocap_quat[0] = marker

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, 480, 640)
        self._renderer.update_scene(self.data, camera="front")
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.backend.close()


def make_hand_env(task: Task, backend: str = "sim",
                  randomize: Sequence[str] | Mapping[str, Any] | DomainRandomization | None = None,
                  **kwargs: Any) -> HandEnv:
    """Build a HandEnv, optionally with domain randomization: ``randomize`` names effects (each
    over its plausible D'Claw range on every hand joint), or is a ``DomainRandomization`` or its
    ``to_dict()`` mapping (JSON run configs; ranges per joint, e.g. an identified model's)."""
    dr = None
    if isinstance(randomize, DomainRandomization):
        dr = randomize
    elif isinstance(randomize, Mapping):
        dr = DomainRandomization.from_dict(randomize)
    elif randomize:
        dr = DomainRandomization(tuple(randomize), task.hand.joint_names)
    return HandEnv(task, backend=backend, randomization=dr, **kwargs)


def control_period(env: gym.Env) -> float:
    """Seconds per env step: ``control_period`` or ``dt`` of the unwrapped env, else 0."""
    base = env.unwrapped
    for name in ("control_period", "dt"):
        value = getattr(base, name, None)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return 0.0
