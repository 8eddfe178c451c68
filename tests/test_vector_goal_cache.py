"""The vector env stacks its copies' goals once per step (and after a reset), not in each of
``step``, ``_infos`` and ``_obs``: what it returns must not change by a bit.

The truth is the env with the cache defeated (``_goal`` restacking the per-copy goal dicts on
every call, the code before the cache), run side by side on the same actions, through
auto-resets, on a fixed goal (the valve), a moving goal (the screw: ``advance_goal`` moves it
every step) and a goal set from the start pose (the flip).
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.sim import vector
from lowcostdex.sim.vector import make_vec


def _uncached(env: vector.HandVectorEnv) -> vector.HandVectorEnv:
    """``env`` with its goal restacked from the per-copy dicts at every use."""
    env._goal = lambda: {k: np.stack([np.asarray(g[k], float) for g in env._goals])
                         for k in env._goals[0]}
    return env


@pytest.mark.parametrize("env_id", ["lowcostdex/DClawTurnValve-v0",
                                    "lowcostdex/DClawScrewRandom-v0",
                                    "lowcostdex/DClawFlipBlockQuaternion-v0"])
def test_cached_goals_leave_every_output_unchanged(env_id):
    n = 4
    cached = make_vec(env_id, n, nthread=1)
    plain = _uncached(make_vec(env_id, n, nthread=1))
    try:
        horizon = cached.episode_steps
        o1, i1 = cached.reset(seed=[3, 5, 7, 9])
        o2, i2 = plain.reset(seed=[3, 5, 7, 9])
        assert o1.tobytes() == o2.tobytes()
        rng = np.random.default_rng(0)
        resets = 0
        # past two episode ends: every copy is auto-reset (NEXT_STEP) at least once
        for _ in range(2 * horizon + 3):
            a = rng.uniform(-1, 1, (n, cached.single_action_space.shape[0]))
            out1, out2 = cached.step(a), plain.step(a)
            for x, y in zip(out1[:4], out2[:4], strict=True):  # obs, reward, terminated, truncated
                assert np.asarray(x).dtype == np.asarray(y).dtype
                assert np.asarray(x).tobytes() == np.asarray(y).tobytes()
            assert out1[4].keys() == out2[4].keys()
            for key in out1[4]:
                assert np.asarray(out1[4][key]).tobytes() == np.asarray(out2[4][key]).tobytes(), key
            resets += int(np.sum(out1[2] | out1[3]))
        assert resets >= n
    finally:
        cached.close()
        plain.close()


def test_a_moving_goal_is_restacked_every_step():
    """The screw's goal angle advances each step: the cached stack follows it (the values the
    task's own ``advance_goal`` gives for each copy's step count)."""
    env = make_vec("lowcostdex/DClawScrewRandom-v0", 2, nthread=1)
    try:
        env.reset(seed=0)
        start = env._goal()["angle"].copy()
        for _ in range(3):
            env.step(np.zeros((2, env.single_action_space.shape[0])))
        goals = [env.task.advance_goal(g, 3) for g in env._goals]
        np.testing.assert_array_equal(env._goal()["angle"], [g["angle"] for g in goals])
        assert np.all(env._goal()["angle"] != start)
    finally:
        env.close()


def test_stacked_goals_are_read_only():
    """A task function writing into the shared stack would change later steps' goals."""
    env = make_vec("lowcostdex/DClawTurnValve-v0", 2, nthread=1)
    try:
        env.reset(seed=0)
        goal = env._goal()
        for v in goal.values():
            with pytest.raises(ValueError):
                v[...] = 0.0
    finally:
        env.close()
