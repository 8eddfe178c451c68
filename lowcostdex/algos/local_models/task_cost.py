"""The TVLG trainer's cost on the valve/screw tasks: the object's target angle, the quadratic task
cost around the start, the demonstrations' hand reference."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.costs import ActionCost, StateCost, SumCost
from lowcostdex.algos.local_models.episodes import FixedStart
from lowcostdex.algos.local_models.train_config import TaskCostConfig
from lowcostdex.errors import ConfigError

Array = NDArray[np.float64]
HALF_TURN_TOLERANCE = 0.25
"""Goals within this angle [rad] of a half turn from the start are reached turning positively."""


def object_target(theta0: float, goal: float, reference: float = math.nan) -> float:
    """The copy goal + 2 pi n [rad] the cost pulls the object angle to.

    Nearest to ``reference`` when it is finite; otherwise nearest to the start angle ``theta0``,
    except that a goal within HALF_TURN_TOLERANCE of a half turn is taken in the positive
    direction (a measured start angle a hair off zero must not flip a 180 deg goal).
    """
    if math.isfinite(reference):
        return reference + (goal - reference + math.pi) % (2 * math.pi) - math.pi
    d = (goal - theta0 + math.pi) % (2 * math.pi) - math.pi  # [-pi, pi)
    if d < -math.pi + HALF_TURN_TOLERANCE:
        d += 2 * math.pi
    return theta0 + d


def task_cost(
    env: gym.Env,
    start: FixedStart,
    hold: Array,
    cfg: TaskCostConfig,
    T: int,
    dX: int,
    demo_actions: Array | None = None,
) -> SumCost:
    """Quadratic cost of a goal-angle task over T steps, for states of size dX.

    The object target is the goal angle unwrapped by :func:`object_target` (for a moving goal,
    one target per step from ``task.advance_goal``, unwrapped continuously). The hand is kept near
    its start pose and the action near the one holding it; when ``cfg.hand_reference`` is "demo",
    near the demonstrated joint targets (:func:`demo_hand_reference`) and the mean demonstrated
    action instead.

    Args:
      demo_actions: (M, T, dU) demonstrated actions (NaN where an episode has ended), needed when
        ``cfg.hand_reference`` is "demo".

    Raises:
      ConfigError: if the task has no goal angle, or the demonstration is missing or misshaped.
    """
    base = env.unwrapped
    task = base.task
    if "angle" not in start.goal or not hasattr(task, "obj_qpos"):
        raise ConfigError(
            f"tvlg needs a goal-angle task (valve or screw); {env.spec.id if env.spec else env} has "
            f"goal keys {sorted(start.goal)}"
        )
    n_hand = len(task.hand_qpos)
    obj = 2 * n_hand  # state_vector: hand qpos, hand qvel, object qpos, object qvel
    goals = np.unwrap([float(task.advance_goal(start.goal, t)["angle"]) for t in range(T)])
    target = np.tile(np.concatenate([start.qpos[task.hand_qpos], np.zeros(dX - n_hand)]), (T, 1))
    action_target = hold
    if cfg.hand_reference == "demo":
        if demo_actions is None or demo_actions.shape[1:] != (T, len(hold)):
            raise ConfigError(
                f"cost hand_reference 'demo' needs demonstrated actions (M, T={T}, {len(hold)}), "
                f"got {None if demo_actions is None else demo_actions.shape}"
            )
        target[:, :n_hand] = demo_hand_reference(env, start, demo_actions)
        action_target = np.nanmean(np.clip(demo_actions, -1.0, 1.0), axis=0)
    target[:, obj] = (
        goals
        + object_target(float(start.qpos[task.obj_qpos]), goals[0], start.reference)
        - goals[0]
    )
    w_obj = np.zeros(dX)
    w_obj[obj] = 1.0
    w_hand = np.zeros(dX)
    w_hand[:n_hand] = cfg.pose_weight
    w_hand[n_hand : 2 * n_hand] = cfg.velocity_weight
    w_hand[obj + 1] = cfg.velocity_weight  # object velocity
    terms = [
        StateCost(target, w_hand, final_multiplier=cfg.final_multiplier),
        StateCost(
            target, w_obj, l2=cfg.object_weight, l1=cfg.object_l1, alpha=1e-2, ramp=cfg.ramp,
            final_multiplier=cfg.final_multiplier, final_steps=min(cfg.final_steps, T),
        ),
        ActionCost(cfg.action_weight * np.ones(len(hold)), target=action_target),
    ]  # fmt: skip
    return SumCost(terms)


def demo_hand_reference(env: gym.Env, start: FixedStart, demo_actions: Array) -> Array:
    """Hand joint reference (T, n_hand) [rad] from demonstrated actions (M, T, dU).

    The start pose at t = 0, then the joint targets of the mean demonstrated action of the step
    before (servos reach their targets within a control period unless a contact stops them).
    Steps no demonstration reaches (NaN) repeat the last reference.
    """
    task = env.unwrapped.task
    mean = np.nanmean(np.clip(demo_actions, -1.0, 1.0), axis=0)  # (T, dU)
    mid, half = 0.5 * (task.hand_high + task.hand_low), 0.5 * (task.hand_high - task.hand_low)
    ref = np.empty((mean.shape[0], len(task.hand_qpos)))
    ref[0] = start.qpos[task.hand_qpos]
    ref[1:] = mid + half * mean[:-1]
    for t in range(1, ref.shape[0]):
        if not np.all(np.isfinite(ref[t])):
            ref[t] = ref[t - 1]
    return ref
