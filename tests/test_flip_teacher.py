"""The flip teacher (``lowcostdex.teachers.flip``): it flips the block in simulation, holds up
under executed-action noise, counts its rolls from the goal; on the emulated D'Claw it records
flip demonstrations through the kinesthetic recorder and the robot's reset turns a flipped
block back (the teacher through the servos, else the emulator's person); the emulated Allegro's
fingers follow its virtual teacher too."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from scipy.stats import fisher_exact

from lowcostdex.demonstrations.file import read_episodes
from lowcostdex.demonstrations.kinesthetic import (
    FIRM_HAND,
    KinestheticRecorder,
    VirtualTeacher,
    identify_servo_response,
)
from lowcostdex.errors import ConfigError
from lowcostdex.sim.envs import goal_to_action
from lowcostdex.sim.registry import register_envs
from lowcostdex.teachers.allegro import AllegroTeacherConfig, AllegroValveTeacher
from lowcostdex.teachers.flip import FlipBlockTeacher, FlipTeacherConfig

ENV = "lowcostdex/DClawFlipBlock-v0"


@pytest.fixture(scope="module", autouse=True)
def _register():
    register_envs()


def flip(env, seed=0, noise=0.0, teacher=None, record=None):
    """One episode driven by the teacher with uniform executed-action noise; per-step infos
    (the executed actions appended to ``record``, if given)."""
    u = env.unwrapped
    env.reset(seed=seed)
    teacher = teacher or FlipBlockTeacher()
    teacher.reset(u)
    rng = np.random.default_rng(seed)
    infos, done = [], False
    while not done:
        goals = teacher(u.backend.observed_qpos(), u.goal)
        a = goal_to_action(goals, u.task.hand_low, u.task.hand_high)
        a = np.clip(a + rng.uniform(-noise, noise, a.shape), -1.0, 1.0)
        if record is not None:
            record.append(a)
        _, _, term, trunc, info = env.step(a.astype(np.float32))
        infos.append(info)
        done = term or trunc
    return infos, teacher


def test_teacher_flips_the_block_in_simulation():
    env = gym.make(ENV)
    u = env.unwrapped
    infos, teacher = flip(env)
    assert teacher.done and teacher.rolls == 2
    assert infos[-1]["success"] and infos[-1]["goal_error"] < 0.15
    first = next(i for i, info in enumerate(infos) if info["success"])
    assert first < 60  # with time to spare in the 80-step episode
    q = u.data.qpos
    # upside down now, and still on the table near where it started (in the reset's reach)
    assert u.task.tilt(q) > math.pi - 0.15
    assert np.linalg.norm(q[u.task.block_pos][:2]) < 0.06
    env.close()


def replay(env, seed, actions, noise):
    """The actions of a noise-free episode replayed open loop on the same start, with the same
    executed-action noise as ``flip``; its last info."""
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for a in actions:
        a = np.clip(a + rng.uniform(-noise, noise, a.shape), -1.0, 1.0)
        _, _, term, trunc, info = env.step(a.astype(np.float32))
        if term or trunc:
            break
    return info


def test_teacher_recovers_from_executed_action_noise():
    """Closed loop, the teacher recovers from executed-action noise that an open-loop replay of
    its own noise-free actions does not survive: success with noise 0.05 on 20 starts, teacher
    vs replay, one-sided Fisher exact test (scipy), p <= 0.05 (e.g. 5 of 20 vs 0 of 20)."""
    env = gym.make(ENV)
    teacher, replayed = [], []
    for seed in range(20):
        clean = []
        flip(env, seed, record=clean)
        replayed.append(bool(replay(env, seed, clean, 0.05)["success"]))
        teacher.append(bool(flip(env, seed, noise=0.05)[0][-1]["success"]))
    env.close()
    # measured 2026-11-26, the motion bound narrowed in flight (0.191 rad): teacher 6 of 20
    # (18 of 40), replay 0 of 20 (1 of 40); bound not narrowed (0.209): teacher 11 of 20 (22 of
    # 40). (Was: >= 4 of seeds 0-7, a threshold at the teacher's own rate: 5 of 8 unnarrowed,
    # 3 of 8 narrowed.)
    table = [[sum(teacher), 20 - sum(teacher)], [sum(replayed), 20 - sum(replayed)]]
    assert fisher_exact(table, alternative="greater").pvalue <= 0.05, (teacher, replayed)



def test_rolls_come_from_the_goal_and_the_teacher_is_deterministic():
    env = gym.make(ENV)
    u = env.unwrapped
    env.reset(seed=0)
    teacher = FlipBlockTeacher()
    teacher.reset(u)
    up = np.array([1.0, 0.0, 0.0, 0.0])
    about_y = lambda a: np.array([math.cos(a / 2), 0.0, math.sin(a / 2), 0.0])  # noqa: E731
    assert teacher.rolls_to(up, about_y(math.pi)) == 2
    assert teacher.rolls_to(about_y(math.pi), up) == 2  # upside down back to upright
    assert teacher.rolls_to(about_y(math.pi / 2), up) == 3  # one way round only
    assert teacher.rolls_to(about_y(-math.pi / 2), up) == 1
    assert teacher.rolls_to(up, up) == 0
    runs = []
    for _ in range(2):
        env.reset(seed=4)
        t = FlipBlockTeacher()
        t.reset(u)
        goals = []
        for _ in range(15):
            goals.append(t(u.data.qpos, u.goal))
            env.step(goal_to_action(goals[-1], u.task.hand_low, u.task.hand_high))
        runs.append(np.array(goals))
    np.testing.assert_array_equal(runs[0], runs[1])
    env.close()
    with pytest.raises(ConfigError, match="different fingers"):
        FlipTeacherConfig(pusher="ff")


def test_flip_demonstrations_on_the_emulated_robot(tmp_path):
    env = gym.make(ENV, backend="emulated")
    u = env.unwrapped
    chain = u.backend.chain
    adr = chain.plant.model.jnt_qposadr[chain.plant.model.joint("block").id]
    start = chain.plant.data.qpos[adr:adr + 3].copy()
    # the identification's random goals stay in the flip task's box, clear of the block
    response, _ = identify_servo_response(env, episodes=1, seed=5)
    assert np.linalg.norm(chain.plant.data.qpos[adr:adr + 2] - start[:2]) < 0.01
    teacher = VirtualTeacher(chain, u.task, solver=FlipBlockTeacher(), config=FIRM_HAND)
    path = tmp_path / "flip.h5"
    recorder = KinestheticRecorder(env, path, ENV, teacher=teacher, response=response)
    stats = recorder.record(6, seed=0, successes=1)
    assert stats.successes == 1 and stats.episodes <= 6
    episodes = read_episodes(path)
    assert len(episodes) == stats.episodes and episodes[-1].success[-1]
    # the next reset brings the flipped block back upright, on the robot's own account (the
    # teacher through the servos) or the emulator's person's
    env.reset(seed=99)
    assert u.task.tilt(chain.plant.data.qpos) < 0.4  # the emulator's model has the env's layout
    telemetry = u.backend.telemetry()
    assert telemetry["person_resets"] >= 0 and u.backend.robot.metrics.reset_failures >= 0
    env.close()


def test_virtual_person_restores_a_block_knocked_beyond_reach():
    env = gym.make(ENV, backend="emulated")
    u = env.unwrapped
    env.reset(seed=0)
    m, d = u.backend.chain.plant.model, u.backend.chain.plant.data
    adr = m.jnt_qposadr[m.joint("block").id]
    d.qpos[adr:adr + 3] = [0.0, 0.15, 0.125]  # beyond the squeezes' reach, on a side
    d.qpos[adr + 3:adr + 7] = [math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0]
    mujoco.mj_forward(m, d)
    env.reset(seed=1)
    assert np.linalg.norm(d.qpos[adr:adr + 2]) < 0.015
    assert u.backend.telemetry()["person_resets"] == 1
    env.close()


def test_allegro_virtual_teacher_turns_the_emulated_valve(tmp_path):
    env_id = "lowcostdex/AllegroTurnValve-v0"
    env = gym.make(env_id, backend="emulated")
    u = env.unwrapped
    teacher = VirtualTeacher(u.backend.emulator, u.task,
                             solver=AllegroValveTeacher(
                                 AllegroTeacherConfig(gravity_compensation=False)))
    recorder = KinestheticRecorder(env, tmp_path / "allegro.h5", env_id, teacher=teacher)
    demo = recorder.record_episode(0)
    env.close()
    # the limp fingers, moved by the virtual person's hand, turned the valve a full turn
    assert demo.success[-1] and demo.length == u.task.timing.episode_steps
    turned = demo.qpos[-1, u.task.obj_qpos] - demo.qpos[0, u.task.obj_qpos]
    assert turned > 1.5 * math.pi
