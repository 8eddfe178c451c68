"""Episodes of a local controller on a hand env from a fixed start: capturing the start
(``FixedStart``), the controller's state vector, the hold action, ``run_episode``."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController, exploration_noise
from lowcostdex.algos.samplers import RolloutJob, control_period
from lowcostdex.errors import ConfigError

Array = NDArray[np.float64]
@dataclass(frozen=True)
class FixedStart:
    """The start every episode resets to: qpos (nq,), qvel (nv,) and the task goal.

    ``reference`` [rad], when finite, is an object angle the goal is unwrapped next to (the end
    angle of a teacher episode, so the cost turns the way the teacher did).
    """

    qpos: Array
    qvel: Array
    goal: dict[str, Array]
    reference: float = math.nan

    def reset_options(self) -> dict[str, Any]:
        return {"qpos": self.qpos, "qvel": self.qvel, "goal": self.goal}

    def to_arrays(self) -> dict[str, Array]:
        out = {"qpos": self.qpos, "qvel": self.qvel, "reference": np.asarray(self.reference)}
        out.update({f"goal/{k}": np.asarray(v) for k, v in self.goal.items()})
        return out

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, Any]) -> FixedStart:
        # Scalars may come back as (1,) arrays from a checkpoint; goals are scalars or vectors.
        goal = {
            k[5:]: np.asarray(v, dtype=np.float64).reshape(())
            if np.size(v) == 1
            else np.asarray(v, float)
            for k, v in arrays.items()
            if k.startswith("goal/")
        }
        reference = float(np.asarray(arrays.get("reference", math.nan)).reshape(()))
        return cls(
            np.asarray(arrays["qpos"], float), np.asarray(arrays["qvel"], float), goal, reference
        )


def capture_start(env: gym.Env, seed: int, hand_qpos: Array | None = None) -> FixedStart:
    """Reset once with ``seed`` and record the start state and goal.

    With ``hand_qpos`` (n_hand,) [rad] the hand starts there instead of the task's reset pose
    (the object keeps the task's start); the state recorded is the one the robot reached.
    """
    env.reset(seed=seed)
    base = env.unwrapped
    if hand_qpos is not None:
        hand_qpos = check_hand_qpos(hand_qpos, base.task)
        qpos = base.data.qpos.copy()
        qpos[base.task.hand_qpos] = hand_qpos
        env.reset(seed=seed, options={"qpos": qpos, "qvel": np.zeros_like(base.data.qvel)})
    goal = {k: np.array(v, dtype=np.float64) for k, v in getattr(base, "goal", {}).items()}
    return FixedStart(base.data.qpos.copy(), base.data.qvel.copy(), goal)


def check_hand_qpos(hand_qpos: Any, task: Any) -> Array:
    """``hand_qpos`` (n_hand,) [rad] as an array, or ConfigError naming what is wrong: the count
    (one angle per hand joint, action order), NaN/inf, an angle outside its joint's range (e.g.
    degrees typed for rad)."""
    names = list(task.hand.joint_names)
    q = np.asarray(hand_qpos, dtype=np.float64).ravel()
    if q.shape != (len(names),):
        raise ConfigError(f"start_hand_qpos (--start-hand-qpos) has {q.size} values; the hand has "
                          f"{len(names)} joints, one angle each in rad: {', '.join(names)}")
    for k, name in enumerate(names):
        if not np.isfinite(q[k]):
            raise ConfigError(f"start_hand_qpos (--start-hand-qpos) {name}={q[k]} is not finite")
        low, high = float(task.hand_low[k]), float(task.hand_high[k])
        if not low - 1e-9 <= q[k] <= high + 1e-9:
            raise ConfigError(f"start_hand_qpos (--start-hand-qpos) {name}={q[k]:g} rad is "
                              f"outside the joint's range [{low:.4g}, {high:.4g}] rad"
                              + (" (degrees? write rad)" if abs(q[k]) > 2 * np.pi else ""))
    return q


def offset_start(env: gym.Env, start: FixedStart, offset: float) -> FixedStart:
    """``start`` with the object angle and the goal both turned by ``offset`` [rad] (e.g. to
    record a demonstration from a slightly different valve position than the fixed start)."""
    task = env.unwrapped.task
    qpos = start.qpos.copy()
    qpos[task.obj_qpos] += offset
    goal = {**start.goal, "angle": np.asarray(float(start.goal["angle"]) + offset)}
    return dataclasses.replace(start, qpos=qpos, goal=goal)


def controller_state(env: gym.Env, last_action: Array | None) -> Array:
    """The controller's state: ``state_vector()`` and, if given, the last applied action."""
    x = np.asarray(env.unwrapped.state_vector(), dtype=np.float64)
    return x if last_action is None else np.concatenate([x, last_action])


def hold_action(env: gym.Env, start: FixedStart) -> Array:
    """Normalised action (dU,) whose joint goals are the start pose of the hand."""
    from lowcostdex.sim.envs import goal_to_action

    task = env.unwrapped.task
    return goal_to_action(start.qpos[task.hand_qpos], task.hand_low, task.hand_high)


@dataclass(frozen=True)
class Episode:
    """One episode of a TVLG controller.

    Attributes:
      X: (H+1, dX) controller states x_0..x_H.
      U: (H+1, dU) commanded actions (the last one is not executed).
      rewards: (H,) env rewards.
      successes: (H,) ``info["success"]`` after each step.
      final_error: ``info["goal_error"]`` after the last step (nan if absent).
      robot_seconds: robot time [s]: steps x control period plus reported reset/pause time.
    """

    X: Array
    U: Array
    rewards: Array
    successes: NDArray[np.bool_]
    final_error: float
    robot_seconds: float

    def success(self, mode: str) -> bool:
        return bool(self.successes[-1]) if mode == "final" else bool(self.successes.any())


def run_episode(
    env: gym.Env,
    controller: LinearGaussianController,
    start: FixedStart,
    job: RolloutJob,
    include_last_action: bool,
    hold: Array,
    smooth_noise: float,
) -> Episode:
    """Run ``controller`` for one episode from ``start``; noise-free if ``job.deterministic``.

    An episode that terminates early is padded with its last state (an absorbing state).
    """
    T, dU = controller.T, controller.dU
    noise = None if job.deterministic else exploration_noise(job.noise_rng(), T, dU, smooth_noise)
    _, info = env.reset(seed=job.env_seed(), options=start.reset_options())
    extra = float(info.get("reset_time", 0.0)) + float(info.get("thermal_pause_time", 0.0))
    last = hold.copy() if include_last_action else None
    X, U = np.zeros((T, controller.dX)), np.zeros((T, dU))
    rewards, successes = [], []
    done, error = False, math.nan
    for t in range(T):
        X[t] = controller_state(env, last) if not done else X[t - 1]
        U[t] = controller.act(t, X[t], None if noise is None else noise[t])
        if t == T - 1 or done:
            continue
        applied = np.clip(U[t], -1.0, 1.0)
        _, reward, terminated, truncated, info = env.step(applied.astype(np.float32))
        rewards.append(float(reward))
        successes.append(bool(info.get("success", False)))
        error = float(info.get("goal_error", math.nan))
        last = applied if include_last_action else None
        done = bool(terminated or (truncated and t < T - 2))
    n = len(rewards)
    return Episode(
        X, U, np.asarray(rewards), np.asarray(successes, dtype=bool), error,
        n * control_period(env) + extra,
    )  # fmt: skip
