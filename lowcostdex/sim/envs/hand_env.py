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

from lowcostdex.errors import ConfigError, check_choice, did_you_mean
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


def check_action(action: Any, n: int, joints: Sequence[str]) -> np.ndarray:
    """The action as a float array (n,), or ValueError naming what is wrong with it.

    Accepted: any real-valued array-like of n values shaped (n,), (1, n) or (n, 1) (a batch of
    one); refused: another number of values, another layout of n values (e.g. (3, 3) for 9),
    booleans, complex numbers, strings, NaN/inf. Values outside [-1, 1] are clipped by the env
    (documented; Gaussian policies sample beyond the bounds).
    """
    what = f"one value in [-1, 1] per joint: {', '.join(joints)}"
    try:
        raw = np.asarray(action)
    except Exception:  # e.g. a ragged nested list
        raise ValueError(f"action of type {type(action).__name__} is not an array of {n} "
                         f"numbers ({what})") from None
    if raw.dtype.kind not in "iuf":
        raise ValueError(f"action of type {type(action).__name__} has dtype {raw.dtype}; this "
                         f"env takes {n} real numbers ({what})")
    if raw.size != n or max(raw.shape, default=1) != raw.size:
        raise ValueError(f"action has shape {raw.shape}; this env takes ({n},) ({what})")
    a = raw.astype(float).reshape(n)
    if not np.all(np.isfinite(a)):
        bad = ", ".join(f"{j}={v}" for j, v in zip(joints, a, strict=False) if not np.isfinite(v))
        raise ValueError(f"action has NaN/inf entries: {bad}")
    return a


def _check_qpos_range(model: mujoco.MjModel, qpos: np.ndarray) -> None:
    """Refuse a start ``qpos`` that puts a limited hinge or slide joint well past its range (the
    mechanical stop): degrees given for radians (30 on a +-0.48 rad joint) started the
    simulation there. A state recorded from the simulation (a contact pushes slightly past a
    stop) stays accepted: 10 % of the range's width + 0.05 of slack."""
    bad = []
    for j in range(model.njnt):
        if not model.jnt_limited[j] or int(model.jnt_type[j]) not in (
                int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            continue
        lo, hi = model.jnt_range[j]
        slack = 0.1 * (hi - lo) + 0.05
        q = float(qpos[model.jnt_qposadr[j]])
        if not lo - slack <= q <= hi + slack:
            bad.append(f"{model.joint(j).name}={q:g} (range {lo:.3g}..{hi:.3g})")
    if bad:
        raise ValueError(f"reset option 'qpos' puts joints past their range: {', '.join(bad)}; "
                         "qpos is in radians (degrees? np.radians(...))")


def _check_options(options: Mapping[str, Any], qpos: np.ndarray, qvel: np.ndarray,
                   goal: Goal, bounds: Mapping[str, tuple[float, float, str]]) -> None:
    """Refuse reset options that would be ignored (unknown keys), fail deep in MuJoCo (shapes),
    put NaN into the simulation or give a goal beyond the task's ``bounds`` (degrees)."""
    if not isinstance(options, Mapping):
        raise ValueError(f"reset options must be a dict with keys 'qpos', 'qvel', 'goal', got "
                         f"{options!r:.80}")
    unknown = sorted(set(options) - {"qpos", "qvel", "goal"})
    if unknown:
        raise ValueError(f"unknown reset option {unknown[0]!r}; valid: 'qpos', 'qvel', 'goal'")
    for key, like in (("qpos", qpos), ("qvel", qvel)):
        if key not in options:
            continue
        try:
            value = np.asarray(options[key], dtype=float)
        except (TypeError, ValueError) as e:
            raise ValueError(f"reset option {key!r} is not an array of numbers: "
                             f"{options[key]!r:.80}") from e
        if value.shape != np.shape(like):
            raise ValueError(f"reset option {key!r} has shape {value.shape}; this env's model "
                             f"takes {np.shape(like)}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"reset option {key!r} has NaN/inf entries")
    given = options.get("goal")
    if given:
        if not isinstance(given, Mapping):
            raise ValueError(f"reset option 'goal' must be a dict with keys "
                             f"{sorted(goal)}, got {given!r:.80}")
        unknown = sorted(set(given) - set(goal))
        missing = sorted(set(goal) - set(given))
        if unknown or missing:
            raise ValueError(f"reset option 'goal' has keys {sorted(given)}; this task's goal "
                             f"has {sorted(goal)}")
        for k, v in given.items():
            try:
                value = np.asarray(v, dtype=float)
            except (TypeError, ValueError) as e:
                raise ValueError(f"reset option goal[{k!r}] is not a number: {v!r:.80}") from e
            if value.shape != np.shape(goal[k]) or not np.all(np.isfinite(value)):
                raise ValueError(f"reset option goal[{k!r}]={v!r:.80} must be finite with shape "
                                 f"{np.shape(goal[k])}")
            low, high, unit = bounds.get(k, (-np.inf, np.inf, ""))
            if not np.all((low <= value) & (value <= high)):
                x, d = float(np.max(np.abs(value))), unit.replace("rad", "deg")
                deg = f"; in {unit}, not {d} ({x:g} {d} is {np.radians(x):.4g} {unit})" if (
                    "rad" in unit) else ""
                raise ValueError(f"reset option goal[{k!r}]={v!r:.80} is outside [{low:.4g}, "
                                 f"{high:.4g}] {unit}, the farthest this task's settings reach{deg}")


def _keywords(cls: type, task: Task) -> list[str]:
    """Keyword arguments ``gym.make`` passes on for this backend: the backend's own, then the
    task's settings (its config's fields)."""
    import dataclasses
    import inspect

    names = [p.name for p in inspect.signature(cls.__init__).parameters.values()
             if p.name not in ("self", "model", "task", "rng")
             and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
    config = getattr(task, "config", None)
    if dataclasses.is_dataclass(config):
        names += [f.name for f in dataclasses.fields(config)]
    # the Allegro's motors are fixed; the D'Claw's model takes a fitted edit
    motor = [] if task.hand.name == "allegro" else ["motor", "model_edit"]
    return names + motor + ["randomize", "render_mode"]


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
        if not isinstance(task, Task):
            raise ConfigError(f"HandEnv takes a task instance (e.g. TurnValve()), not "
                              f"{task!r:.60}")
        if randomization is not None and not isinstance(randomization, DomainRandomization):
            raise ConfigError(f"randomization must be a DomainRandomization, not "
                              f"{type(randomization).__name__} (make_hand_env and gym.make take "
                              "effect names or a to_dict() mapping as randomize=...)")
        self.task = task
        self.randomization = randomization
        spec = task.build_spec()
        if randomization is not None:
            if backend != "sim":
                raise ConfigError("domain randomization needs backend='sim'")
            probe = randomization.sample(np.random.default_rng(0))
            prepare_spec(spec, probe)
        self.model = spec.compile()
        if randomization is not None:  # with no effects, a misspelt joint was taken unsaid
            names = [n for n in (self.model.joint(i).name for i in range(self.model.njnt))
                     if not n.endswith("__play")]
            for joint in randomization.joints:
                check_choice("joint in randomization.joints", joint, names)
        task.bind(self.model)
        self.backend_name = backend
        self._rng_for_backend = np.random.default_rng(0)
        cls = backend_class(backend, task.hand.name)
        try:
            self.backend: Backend = cls(self.model, task=task, rng=self._rng_for_backend,
                                        **backend_kwargs)
        except TypeError as e:
            # a keyword the backend (or the bus behind it) does not take: name it and the valid
            # ones instead of the constructor's own message from deep inside
            bad = [k for k in backend_kwargs if f"argument '{k}'" in str(e)]
            if not bad:
                raise
            valid = list(_keywords(cls, task))
            raise ConfigError(
                f"unknown keyword argument {bad[0]!r} for backend {backend!r} of "
                f"{type(task).__name__}; valid: {', '.join(valid)}"
                + did_you_mean(bad[0], valid)) from None
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
        if isinstance(seed, np.integer):  # a seed from np.arange: gymnasium takes int only
            seed = int(seed)
        super().reset(seed=seed)
        options = options or {}
        qpos, qvel, goal = self.task.initial_state(self.np_random)
        _check_options(options, qpos, qvel, goal, self.task.goal_bounds)
        if "qpos" in options:
            _check_qpos_range(self.model, np.asarray(options["qpos"], dtype=float))
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
        a = check_action(action, self.action_space.shape[0], self.task.hand.joint_names)
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
            try:
                self._renderer = mujoco.Renderer(self.model, 480, 640)
            except Exception as exc:  # mujoco.FatalError / GLFW: no OpenGL context
                import os

                raise ConfigError(
                    f"render_mode='rgb_array' needs an OpenGL context, which MuJoCo could not "
                    f"create (MUJOCO_GL={os.environ.get('MUJOCO_GL', 'unset')}: {exc}); on a "
                    "machine without a display set MUJOCO_GL=egl (GPU) or MUJOCO_GL=osmesa "
                    "(CPU) before importing mujoco") from exc
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
    elif isinstance(randomize, str):  # one effect's name, not its letters
        dr = DomainRandomization((randomize,), task.hand.joint_names)
    elif randomize is not None and not isinstance(randomize, (list, tuple)):
        raise ConfigError(f"randomize={randomize!r:.80} must be effect names (e.g. ['latency', "
                          "'backlash']), a DomainRandomization or its to_dict() mapping")
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
