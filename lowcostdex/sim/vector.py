"""A batched gymnasium VectorEnv: many copies of a hand task stepped by ``mujoco.batch``.

All sub-environments share one compiled model; per-simulation model fields carry each copy's
domain-randomized effect values (``BatchPlant``). Observations, rewards and success flags are
computed for every copy at once by the task's array functions. Sub-env ``i`` behaves exactly like
``gym.make(env_id)`` reset with ``seed + i`` (the equivalence test checks it), except for noise
effects (observation/action noise), whose random streams are shared across the batch.

Autoreset follows gymnasium's default NEXT_STEP mode: after an episode ends, the next ``step``
resets that copy (its action is ignored) and returns the first observation with reward 0.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

import lowcostdex  # noqa: F401  (registers ids)
from lowcostdex.errors import ClosedError, ConfigError, check_at_most, check_number, did_you_mean
from lowcostdex.sim.effects import DomainRandomization
from lowcostdex.sim.envs.hand_env import HandEnv, action_to_goal
from lowcostdex.sim.envs.task import Goal, Task
from lowcostdex.sim.plant import BatchPlant


def _stack_goals(goals: list[Goal]) -> Goal:
    """The copies' goals as one dict of (num_envs, ...) arrays, read-only (they are cached:
    a task function that wrote into one would change the goal of later calls)."""
    stacked = {k: np.stack([np.asarray(g[k], float) for g in goals]) for k in goals[0]}
    for v in stacked.values():
        v.flags.writeable = False
    return stacked


MAX_ENVS = 100_000
"""Most copies a vector env takes (~0.7 GB of MuJoCo state for the valve task)."""


class HandVectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of a task on one ``BatchPlant``.

    Args:
      task: the task (its model is compiled here).
      num_envs: number of copies.
      randomization: effects sampled per copy at every reset.
      nthread: mujoco.batch threads (0: all CPUs).
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, task: Task, num_envs: int, randomization: DomainRandomization | None = None,
                 nthread: int = 0):
        check_number("num_envs", num_envs, 1, integer=True)
        check_number("nthread", nthread, 0, integer=True)
        check_at_most("num_envs", num_envs, MAX_ENVS, "each copy holds ~7 KB of MuJoCo state "
                      "(the valve task, measured), so 1e9 copies ended in 'std::bad_alloc'; "
                      "PPO runs 16-4096")
        num_envs, nthread = int(num_envs), int(nthread)  # np.int64(2) read back as a plain int
        # A template env builds and binds the model exactly as the single env does.
        self._template = HandEnv(task, backend="sim", randomization=randomization)
        self.task, self.randomization = task, randomization
        self.num_envs = num_envs
        self.plant = BatchPlant(self._template.model, num_envs, nthread=nthread)
        if len(task.passive_act):
            self.plant.set_torque_enabled(task.passive_act, False)
        self._effects: list[list] = [[] for _ in range(num_envs)]
        self.single_observation_space = self._template.observation_space
        self.single_action_space = self._template.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._max_step = self._template._max_step
        self._episode_steps = task.timing.episode_steps
        self._rngs = [np.random.default_rng(i) for i in range(num_envs)]
        self._goals: list[Goal] = [{} for _ in range(num_envs)]
        # The stacked goals, built once per step instead of in each of step, _infos and _obs
        # (3x per step: ~6 % of a valve rollout); None when a reset or a moving goal changed them.
        self._goal_stack: Goal | None = None
        self._moving_goal = type(task).advance_goal is not Task.advance_goal
        self._steps = np.zeros(num_envs, dtype=int)
        self._last_action = np.zeros((num_envs, self.single_action_space.shape[0]))
        self._needs_reset = np.zeros(num_envs, dtype=bool)
        self._was_reset = False  # step() before the first reset() has no goal to reward
        self._closed = False
        self._aux = np.setdiff1d(np.arange(self.plant.model.nu), task.hand_act)

    # ------------------------------------------------------------------------------------------
    def _reset_rows(self, rows: np.ndarray) -> None:
        t = self.task
        qpos = np.zeros((len(rows), self.plant.model.nq))
        qvel = np.zeros((len(rows), self.plant.model.nv))
        for k, i in enumerate(rows):
            qpos[k], qvel[k], self._goals[i] = t.initial_state(self._rngs[i])
            if self.randomization is not None:
                self._effects[i] = self.randomization.sample(self._rngs[i])
            # keep the generator stream aligned with HandEnv.reset (backend noise seed)
            self._rngs[i].integers(2**63)
        if self.randomization is not None:
            self.plant.set_effects(self._effects)
        self.plant.reset(qpos, qvel, sims=rows)
        for i in rows:
            self._goals[i] = t.start_goal(self.plant.qpos[i], self._goals[i])
        self._goal_stack = None
        self._steps[rows] = 0
        self._last_action[rows] = 0.0
        self._needs_reset[rows] = False

    def _goal(self) -> Goal:
        if self._goal_stack is None:
            self._goal_stack = _stack_goals(self._goals)
        return self._goal_stack

    def _obs(self) -> np.ndarray:
        qpos = self.plant.measured_qpos()
        return self.task.observation(qpos, self.plant.qvel, self._goal(),
                                     self._last_action).astype(np.float32)

    def _infos(self, action: np.ndarray, terms: dict[str, np.ndarray] | None = None
               ) -> dict[str, Any]:
        t, goal = self.task, self._goal()
        if terms is None:
            terms = t.reward_terms(self.plant.qpos, self.plant.qvel, goal, action)
        info: dict[str, Any] = {f"reward_{k}": np.asarray(v, float) for k, v in terms.items()}
        info["success"] = np.asarray(t.success(self.plant.qpos, goal), bool)
        info["goal_error"] = np.asarray(t.goal_error(self.plant.qpos, goal), float)
        for key in list(info):
            info[f"_{key}"] = np.ones(self.num_envs, dtype=bool)
        return info

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        """Reset every copy; copy ``i`` is seeded with ``seed + i`` (or ``seed[i]``). No
        ``options``: the copies start from the task's own distribution."""
        self._check_open("reset")
        if options:  # (before: ignored without a word: a goal or start given here did nothing)
            raise ConfigError(f"reset(options={{{', '.join(map(repr, options))}}}): the vector "
                              "env takes no reset options (its copies start from the task's own "
                              "distribution); a fixed qpos / qvel / goal works on one env "
                              "(gym.make(...).reset(options=...))")
        if seed is not None:
            many = isinstance(seed, (list, tuple, np.ndarray))
            if many and len(seed) != self.num_envs:
                raise ConfigError(f"reset(seed=...) got {len(seed)} seeds for {self.num_envs} "
                                  "copies: give one seed per copy, or one int (copy i gets "
                                  "seed + i)")
            for s in (seed if many else [seed]):
                check_number("reset seed", s, 0, integer=True)
            seeds = list(seed) if many else [seed + i for i in range(self.num_envs)]
            self._rngs = [np.random.default_rng(s) for s in seeds]
        self._reset_rows(np.arange(self.num_envs))
        self._was_reset = True
        return self._obs(), self._infos(self._last_action)

    def _check_open(self, call: str) -> None:
        if self._closed:  # before: a closed vector env kept stepping
            raise ClosedError(f"{call}() on a vector env that was closed (by vec.close()); "
                              "make a new one with make_vec")

    def step(self, actions: np.ndarray):
        self._check_open("step")
        if not self._was_reset:  # as gymnasium's single envs refuse it (OrderEnforcing)
            raise gym.error.ResetNeeded("cannot call step() before reset() on a vector env: "
                                        "call vec.reset(seed=...) first")
        raw = np.asarray(actions)
        if raw.dtype.kind not in "iuf" or raw.shape != self.action_space.shape:
            raise ValueError(f"actions of shape {raw.shape} and dtype {raw.dtype}; this vector "
                             f"env takes real numbers of shape {self.action_space.shape} (one "
                             "row per copy, one value in [-1, 1] per joint)")
        a = raw.astype(float)
        if not np.all(np.isfinite(a)):
            raise ValueError("actions have NaN/inf entries")
        a = np.clip(a, -1.0, 1.0)
        t = self.task
        resetting = np.flatnonzero(self._needs_reset)
        present = self.plant.qpos[:, t.hand_qpos]
        ctrl = np.empty((self.num_envs, self.plant.model.nu))
        ctrl[:, t.hand_act] = action_to_goal(a, t.hand_low, t.hand_high, present, self._max_step)
        ctrl[:, self._aux] = t.aux_ctrl(self.plant.qpos)
        self.plant.step_unchecked(ctrl, t.timing.frame_skip)  # from checked, clipped actions
        self._steps += 1
        self._last_action = a.copy()
        if self._moving_goal:  # Task.advance_goal returns the goal unchanged
            for i in range(self.num_envs):
                self._goals[i] = t.advance_goal(self._goals[i], int(self._steps[i]))
            self._goal_stack = None
        goal = self._goal()
        terms = t.reward_terms(self.plant.qpos, self.plant.qvel, goal, a)
        reward = np.sum([np.asarray(v, float) for v in terms.values()], axis=0)
        terminated = np.asarray(t.terminated(self.plant.qpos, goal), bool)
        truncated = self._steps >= self._episode_steps
        infos = self._infos(a, terms)
        if len(resetting):
            self._reset_rows(resetting)
            reward[resetting] = 0.0
            terminated[resetting] = False
            truncated[resetting] = False
            infos = self._infos(self._last_action)
        self._needs_reset = terminated | truncated
        return self._obs(), reward, terminated, truncated, infos

    @property
    def episode_steps(self) -> int:
        """Control steps per episode (the time limit)."""
        return int(self._episode_steps)

    @property
    def control_period(self) -> float:
        """Seconds per step."""
        return float(self._template.control_period)

    def state_vector(self) -> np.ndarray:
        """Physical states (num_envs, n), ordered as ``HandEnv.state_vector``."""
        t = self.task
        q, v = self.plant.qpos, self.plant.qvel
        return np.concatenate([q[:, t.hand_qpos], v[:, t.hand_dof],
                               np.delete(q, t.hand_qpos, axis=1),
                               np.delete(v, t.hand_dof, axis=1)], axis=1)

    def close(self, **kwargs: Any) -> None:
        self._template.close()
        self._closed = True


def make_vec(env_id: str, num_envs: int, nthread: int = 0, **kwargs: Any) -> HandVectorEnv:
    """Batched copies of a registered ``lowcostdex/...`` env (sim backend).

    Keyword arguments are those of ``gym.make(env_id, ...)`` (e.g. ``randomize``, ``motor``).
    """
    if kwargs.get("backend", "sim") != "sim":
        raise ConfigError("make_vec batches the sim backend only")
    if not isinstance(env_id, str) or env_id not in gym.registry:  # before: gymnasium's bare
        ours = sorted(k for k in gym.registry if k.startswith("lowcostdex/"))  # NameNotFound
        hint = did_you_mean(env_id, ours) or did_you_mean(f"lowcostdex/{env_id}", ours)
        raise ConfigError(f"unknown env {env_id!r}; make_vec batches: {', '.join(ours)}{hint}")
    single = gym.make(env_id, **kwargs).unwrapped
    if not isinstance(single, HandEnv):
        raise ConfigError(f"{env_id} is not a lowcostdex HandEnv")
    vec = HandVectorEnv(single.task, num_envs, single.randomization, nthread=nthread)
    single.close()
    return vec
