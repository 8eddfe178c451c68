"""What every teacher checks where a user hands it an env or a state: the task it is bound to
(the right hand and scene, a gymnasium-wrapped env taken too) and, at each call, a bound
teacher, the full ``qpos`` of that model and a goal with the keys the teacher reads. A wrong
env gives one ConfigError naming the teacher, the tasks it solves and what it got, instead of a
KeyError or reshape error from inside the geometry."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lowcostdex.errors import ConfigError


def bound_task(task_or_env: Any, teacher: str, hand: str, solves: str,
               joint: str | None = None, attributes: Sequence[str] = ()) -> Any:
    """The task of ``task_or_env`` (a bound Task, a HandEnv or a wrapped one), checked to be on
    ``hand`` with the scene joint ``joint`` and the task ``attributes`` the teacher uses.

    Raises:
      ConfigError naming ``teacher``, what it ``solves`` and what it was given.
    """
    obj = getattr(task_or_env, "unwrapped", task_or_env)  # gym.make's wrappers
    task = getattr(obj, "task", obj)
    model = getattr(task, "model", None)
    hand_name = getattr(getattr(task, "hand", None), "name", None)
    ok = model is not None and hand_name == hand and all(hasattr(task, a) for a in attributes)
    if ok and joint is not None:
        ok = joint in {model.joint(i).name for i in range(model.njnt)}
    if not ok:
        got = type(task).__name__ + (f" on the {hand_name} hand" if hand_name else "")
        if model is None and hand_name is not None:
            got += " (not bound to a model yet: pass the env, or a task after env creation)"
        raise ConfigError(f"{teacher} solves {solves}; got {got}")
    return task


def check_call(teacher: Any, qpos: Any, goal: Mapping[str, Any] | None,
               keys: Sequence[str]) -> np.ndarray:
    """``qpos`` as a float array after checking that ``teacher`` was reset, that ``qpos`` is the
    bound model's full state (nq,) and that ``goal`` holds ``keys``."""
    name = type(teacher).__name__
    nq = getattr(teacher, "_nq", None)
    if nq is None:
        raise ConfigError(f"{name}: call reset(env) at the start of an episode first")
    q = np.asarray(qpos, dtype=float)
    if q.shape != (nq,):
        raise ValueError(f"{name}: qpos has shape {q.shape}; the bound model's full state is "
                         f"({nq},) (env.unwrapped.data.qpos)")
    missing = [k for k in keys if not goal or k not in goal]
    if missing:
        raise ValueError(f"{name}: the goal lacks {', '.join(missing)} (pass the env's goal, "
                         "env.unwrapped.goal)")
    return q
