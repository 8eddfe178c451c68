"""bench/flip_markov.py's ``MarkovFlipTeacher`` (issue 15 item 1): its action is a function of
the present state alone (a fresh teacher handed any state of an episode commands what the
running one does; the package's ``FlipBlockTeacher`` does not), and it flips the block."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from lowcostdex.sim.envs import goal_to_action
from lowcostdex.sim.registry import register_envs
from lowcostdex.teachers.flip import FlipBlockTeacher

sys.path.insert(0, str(Path(__file__).parent))
from bench_script import script_module  # noqa: E402

ENV = "lowcostdex/DClawFlipBlock-v0"
SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "flip_markov.py"


@pytest.fixture(scope="module")
def bench():
    register_envs()
    yield from script_module(SCRIPT, "flip_markov")


def fresh_vs_running(make, seed: int, steps: int) -> list[bool]:
    """Per step of an episode driven by one running teacher: does a fresh teacher, reset and
    handed only this step's state and goal, command the same joint goals?"""
    env = gym.make(ENV)
    u = env.unwrapped
    env.reset(seed=seed)
    running = make()
    running.reset(u)
    same = []
    for _ in range(steps):
        qpos = u.backend.observed_qpos()
        goals = running(qpos, u.goal)
        fresh = make()
        fresh.reset(u)
        same.append(bool(np.array_equal(fresh(qpos, u.goal), goals)))
        env.step(goal_to_action(goals, u.task.hand_low, u.task.hand_high).astype(np.float32))
    env.close()
    return same


def test_the_markov_teacher_acts_on_the_present_state_alone(bench):
    # through push, lift, carry, push and hold (seed 1: carry at steps 16-25, done at 32)
    assert all(fresh_vs_running(bench.MarkovFlipTeacher, seed=1, steps=40))
    # the package's teacher keeps stages and counters: the same check tells them apart
    assert not all(fresh_vs_running(FlipBlockTeacher, seed=1, steps=40))


def test_the_markov_teacher_flips_the_block(bench):
    env = gym.make(ENV)
    u = env.unwrapped
    teacher = bench.MarkovFlipTeacher()
    assert bench.run_teacher(env, teacher, seed=1)
    assert teacher.done and teacher.rolls == 2
    assert u.task.tilt(u.data.qpos) > math.pi - 0.4  # upside down
    env.close()
