"""The palm-up Allegro valve task: env contract (gymnasium checker, determinism under a seed,
reward == sum of terms), the model's kinematics and actuation, and the unwrapped 360 deg goal."""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import lowcostdex  # noqa: F401  (registers the ids)
from lowcostdex.hands import allegro_spec
from lowcostdex.sim.envs import goal_to_action
from lowcostdex.sim.models.allegro import TORQUE_LIMITS, AllegroPD, build_allegro
from lowcostdex.sim.registry import env_ids

IDS = ["lowcostdex/AllegroTurnValve-v0", "lowcostdex/AllegroTurnValveRandom-v0"]


def test_ids_are_registered():
    assert set(IDS) <= set(env_ids())


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_checker(env_id):
    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_determinism_under_seed_and_reward_is_sum_of_terms(env_id):
    env = gym.make(env_id)

    def rollout(seed):
        obs, _ = env.reset(seed=seed)
        rng = np.random.default_rng(0)
        out, rewards = [obs], []
        for _ in range(15):
            obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 16))
            out.append(obs)
            rewards.append(r)
            terms = [v for k, v in info.items() if k.startswith("reward_")]
            assert len(terms) == 5
            assert r == pytest.approx(sum(terms), abs=1e-9)
        return np.array(out), np.array(rewards)

    o1, r1 = rollout(4)
    o2, r2 = rollout(4)
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(r1, r2)
    o3, _ = rollout(5)
    if env_id.endswith("Random-v0"):  # the start differs with the seed
        assert not np.allclose(o1[0], o3[0])
    env.close()


def test_goal_is_360_deg_and_the_error_is_not_wrapped():
    env = gym.make("lowcostdex/AllegroTurnValve-v0")
    u = env.unwrapped
    obs, info = env.reset(seed=0)
    assert info["goal_error"] == pytest.approx(2 * math.pi)
    assert obs[34] == pytest.approx(2 * math.pi)  # observation: q, v, cos, sin, error, action
    # the valve one turn round: cos/sin back where they started, the error is zero
    u.data.qpos[u.task.obj_qpos] = 2 * math.pi - 0.05
    mujoco.mj_forward(u.model, u.data)
    hold = goal_to_action(u.data.qpos[u.task.hand_qpos], u.task.hand_low, u.task.hand_high)
    _, reward, term, trunc, info = env.step(hold)
    assert info["success"] and abs(info["goal_error"]) < 0.1
    assert info["reward_bonus_big"] == 50.0
    assert not term and not trunc
    env.close()


def test_episode_is_truncated_at_100_steps():
    env = gym.make("lowcostdex/AllegroTurnValve-v0")
    env.reset(seed=0)
    for k in range(100):
        _, _, term, trunc, _ = env.step(np.zeros(16))
        assert not term
        assert trunc == (k == 99)
    env.close()


def test_model_joints_ranges_and_torque_limits_follow_the_v4_hand():
    hand = allegro_spec()
    model = build_allegro("valve").compile()
    assert model.nu == 16
    for j in hand.joints:
        jid = model.joint(j.name).id
        np.testing.assert_allclose(model.jnt_range[jid], [j.low, j.high])
        act = model.actuator(j.name)
        assert act.trnid[0] == jid
    # torque limits are the driver's PWM clamps / 1200, e.g. index "near" joint 675 counts
    np.testing.assert_allclose(model.actuator("index_1").forcerange, [-675 / 1200, 675 / 1200])
    np.testing.assert_allclose(model.actuator("thumb_3").forcerange,
                               [-TORQUE_LIMITS["thumb"][3], TORQUE_LIMITS["thumb"][3]])
    # the straight finger is 0.0164 + 0.054 + 0.0384 + 0.041 = 0.1498 m from joint 0 to its tip
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    length = np.linalg.norm(data.site("middle_tip").xpos - data.body("middle_link0").xpos)
    assert length == pytest.approx(0.0164 + 0.054 + 0.0384 + 0.041, abs=1e-6)
    # flexion (joint 1 > 0) lifts the fingertips off the palm-up hand
    z0 = data.site("middle_tip").xpos[2]
    data.qpos[model.jnt_qposadr[model.joint("middle_1").id]] = 1.0
    mujoco.mj_kinematics(model, data)
    assert data.site("middle_tip").xpos[2] > z0 + 0.08


def test_joint_pd_tracks_a_goal_and_saturates_at_the_torque_limit():
    pd = AllegroPD()
    env = gym.make("lowcostdex/AllegroTurnValve-v0")
    u = env.unwrapped
    env.reset(seed=0)
    goal = u.data.qpos[u.task.hand_qpos].copy()
    goal[5] = 0.8  # middle_1: flex by 0.8 rad (three 0.31 rad/step motion bounds)
    for _ in range(8):
        env.step(goal_to_action(goal, u.task.hand_low, u.task.hand_high))
    q = u.data.qpos[u.task.hand_qpos]
    v = u.data.qvel[u.task.hand_dof]
    # the soft default PD (0.5 N m/rad) sags under the finger's weight, but gets most of the way
    assert 0.5 < q[5] < 0.8
    kp, kd = pd.gains("middle", 1)
    mujoco.mj_forward(u.model, u.data)  # actuator forces at the present state
    assert u.data.actuator_force[5] == pytest.approx(kp * (0.8 - q[5]) - kd * v[5], rel=1e-6)
    # a goal far away saturates the torque at the v4 clamp
    u.data.qpos[u.task.hand_qpos[5]] = -0.19
    u.data.qvel[:] = 0.0
    u.data.ctrl[5] = 1.6  # kp * 1.79 rad = 0.9 N m > the 0.5625 N m clamp
    mujoco.mj_forward(u.model, u.data)
    assert abs(u.data.actuator_force[5]) == pytest.approx(TORQUE_LIMITS["finger"][1], rel=1e-6)
    assert pd.gains("middle", 1)[0] == pytest.approx(0.5)
    env.close()
