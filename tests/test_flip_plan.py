"""The planned flip teacher (``lowcostdex.teachers.flip_plan``): from the starts a robot's reset
leaves, it flips the block where the scripted teacher alone does not; the truth is the env's own
success check (orientation within ``FlipConfig.success_angle`` of the goal at the episode's
end), not the teacher's prediction."""

from __future__ import annotations

import pathlib
import sys

import gymnasium as gym
import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.sim.registry import register_envs
from lowcostdex.teachers import TEACHERS
from lowcostdex.teachers.flip import FlipBlockTeacher
from lowcostdex.teachers.flip_plan import FlipPlanConfig, PlannedFlipTeacher

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from flip_episode import run_teacher  # noqa: E402

ENV = "lowcostdex/DClawFlipBlock-v0"
SEEDS = range(50_000, 50_020)  # the benchmark's held-out starts (bench/npg_dapg.py)


@pytest.fixture(scope="module", autouse=True)
def _register():
    register_envs()


def episode(env, seed, teacher):
    """One noise-free episode driven by ``teacher``: the env's success and orientation error at
    its end."""
    info = run_teacher(env, seed, teacher)
    return bool(info["success"]), float(info["goal_error"])


def test_planned_teacher_flips_from_the_resets_starts():
    env = gym.make(ENV)
    planned, scripted = PlannedFlipTeacher(), FlipBlockTeacher()
    wins, script_wins, agreed = 0, 0, 0
    for seed in SEEDS:
        ok, _ = episode(env, seed, planned)
        wins += ok
        script_wins += episode(env, seed, scripted)[0]
        # the prediction it chose by is what the env then did (noise-free, same model)
        agreed += planned.predicted[planned.choice][0] == ok
    env.close()
    # measured 2026-11-27: planned 20 of 20, scripted alone 15 of 20 (seeds 50000-50039:
    # 39 and 27 of 40); the bar of issue 15 item 1 is 85 %
    assert wins >= 18, wins
    assert wins > script_wins, (wins, script_wins)
    assert agreed == len(SEEDS)


def test_planned_teacher_is_registered_and_checks_its_config():
    assert TEACHERS["PlannedFlipTeacher"] is PlannedFlipTeacher
    with pytest.raises(ConfigError, match="non-empty"):
        FlipPlanConfig(variants=())
    with pytest.raises(ConfigError, match="horizon"):
        FlipPlanConfig(horizon=0)
    with pytest.raises(ConfigError, match="FlipPlanConfig"):
        PlannedFlipTeacher(config={"horizon": 10})
    with pytest.raises(ConfigError, match="reset"):
        PlannedFlipTeacher()(np.zeros(16), None)
    with pytest.raises(ConfigError, match="flip-block"):
        PlannedFlipTeacher().reset(gym.make("lowcostdex/DClawTurnValve-v0"))


def test_planned_teacher_records_flip_demonstrations_on_the_emulated_robot(tmp_path):
    """Through the kinesthetic recorder (``record-demos --port emulated``'s path): the planner
    predicts with its own simulation of the env's task, the emulated D'Claw's limp fingers
    follow its goals, and the recorded episode flips the block by the env's own check."""
    from lowcostdex.demonstrations.file import read_episodes
    from lowcostdex.demonstrations.kinesthetic import (
        FIRM_HAND,
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
    )

    env = gym.make(ENV, backend="emulated")
    u = env.unwrapped
    response, _ = identify_servo_response(env, episodes=1, seed=5)
    planner = PlannedFlipTeacher()
    teacher = VirtualTeacher(u.backend.chain, u.task, solver=planner, config=FIRM_HAND)
    path = tmp_path / "flip.h5"
    stats = KinestheticRecorder(env, path, ENV, teacher=teacher, response=response).record(
        6, seed=0, successes=1)
    env.close()
    # measured 2026-11-27: 7 of 10 recorded episodes flip (FlipBlockTeacher: 6 of 10)
    assert stats.successes == 1 and stats.episodes <= 6
    assert planner.choice is not None and planner._sim_of is u.task  # planned on the env's task
    assert read_episodes(path)[-1].success[-1]
