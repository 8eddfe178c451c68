"""The goal ramp added to DAPG's training reward (``main_job.shaping``). The truth is the valve's
own state read from MuJoCo (the valve joint's angle against the episode's goal, wrapped by hand
here), the ramp's formula written out with numbers, and the task's success flag, which the
shaping must leave alone."""

from __future__ import annotations

import math

import numpy as np
import pytest

import lowcostdex.sim  # noqa: F401  (registers the ids)
from lowcostdex.algos.samplers import EnvFactory
from lowcostdex.errors import ConfigError
from lowcostdex.main_job.shaping import GoalRamp, GoalRampReward, ShapedEnvFactory

ENV = "lowcostdex/DClawTurnValve-v0"


def test_the_ramp_by_hand():
    ramp = GoalRamp(weight=50.0, radius=0.2)
    assert ramp.reward(0.0) == 50.0
    assert ramp.reward(0.05) == pytest.approx(37.5)   # 50 * (1 - 0.05 / 0.2)
    assert ramp.reward(-0.15) == pytest.approx(12.5)  # the sign does not matter
    assert ramp.reward(0.2) == 0.0
    assert ramp.reward(3.0) == 0.0                     # never negative


@pytest.mark.parametrize("kw", [{"weight": 0.0}, {"radius": -0.1}, {"weight": math.nan}])
def test_bad_settings_are_refused(kw):
    with pytest.raises(ConfigError):
        GoalRamp(**kw)


def _wrapped_angle(x: float) -> float:
    return (x + math.pi) % (2 * math.pi) - math.pi


def test_the_wrapper_adds_the_ramp_of_the_valves_true_error_and_leaves_success_alone():
    # goals within 0.3 rad of the start, so the episodes run inside and outside the ramp
    kw = {"backend": "sim", "goal_offset": 0.0, "goal_range": 0.3}
    plain = EnvFactory(ENV, kw)()
    shaped = ShapedEnvFactory(EnvFactory(ENV, kw), GoalRamp(weight=50.0, radius=0.2))()
    assert isinstance(shaped, GoalRampReward)
    rng = np.random.default_rng(3)
    added, successes = [], []
    for seed in range(8):
        plain.reset(seed=seed)
        shaped.reset(seed=seed)
        env = shaped.unwrapped
        for _ in range(3):
            a = (0.3 * rng.uniform(-1, 1, size=plain.action_space.shape)).astype(
                plain.action_space.dtype)
            _, r0, _, _, i0 = plain.step(a)
            _, r1, _, _, i1 = shaped.step(a)
            # the valve's error from MuJoCo's state and the goal the episode drew
            err = _wrapped_angle(float(env.goal["angle"])
                                 - float(env.data.qpos[env.task.obj_qpos]))
            assert float(i1["goal_error"]) == pytest.approx(err, abs=1e-9)
            expected = 50.0 * max(0.0, 1.0 - abs(err) / 0.2)
            assert r1 - r0 == pytest.approx(expected, abs=1e-9)
            assert i1["reward_goal_ramp"] == pytest.approx(expected, abs=1e-9)
            assert i1["success"] == i0["success"]
            added.append(r1 - r0)
            successes.append(bool(i1["success"]))
    plain.close()
    shaped.close()
    # both sides of the ramp's edge and of the tolerance were visited
    assert min(added) == 0.0 and max(added) > 25.0, added
    assert any(successes) and not all(successes)
