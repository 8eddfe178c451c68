"""One flip-block episode driven by a virtual teacher (its goals turned into the env's actions),
shared by the flip teachers' tests: the truth they read is the env's own ``info`` at the end."""
from __future__ import annotations

import numpy as np

from lowcostdex.sim.envs import goal_to_action


def run_teacher(env, seed: int, teacher, noise: float = 0.0,
                rng: np.random.Generator | None = None) -> dict:
    """Reset ``env`` at ``seed``, let ``teacher`` drive it to the end; with ``rng`` given, each
    action gets uniform noise in +-``noise`` (action units) and is clipped to [-1, 1] (the
    demonstrations' executed-action noise). Returns the last step's ``info``."""
    u = env.unwrapped
    env.reset(seed=seed)
    teacher.reset(u)
    done, info = False, {}
    while not done:
        goals = teacher(u.backend.observed_qpos(), u.goal)
        a = goal_to_action(goals, u.task.hand_low, u.task.hand_high)
        if rng is not None:
            a = np.clip(a + rng.uniform(-noise, noise, a.shape), -1.0, 1.0)
        _, _, term, trunc, info = env.step(a.astype(np.float32))
        done = term or trunc
    return info
