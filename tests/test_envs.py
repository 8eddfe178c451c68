"""Contract tests for every registered env: gymnasium's checker, determinism under a seed,
reward == sum of named terms, termination vs truncation, and the batched vector env equals a loop
of single envs."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import lowcostdex  # noqa: F401
from lowcostdex.errors import ConfigError
from lowcostdex.sim.envs import action_to_goal, goal_to_action
from lowcostdex.sim.registry import env_ids
from lowcostdex.sim.vector import make_vec

IDS = env_ids()


def rollout(env, seed, steps, action_seed=0):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(action_seed)
    out = [obs]
    rewards = []
    for _ in range(steps):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        out.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return np.array(out), np.array(rewards)


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_checker(env_id):
    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_determinism_under_seed_and_reward_is_sum_of_terms(env_id):
    env = gym.make(env_id)
    o1, r1 = rollout(env, 3, 10)
    o2, r2 = rollout(env, 3, 10)
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(r1, r2)
    env.reset(seed=1)
    _, reward, _, _, info = env.step(env.action_space.sample())
    terms = [v for k, v in info.items() if k.startswith("reward_")]
    assert len(terms) >= 2
    assert reward == pytest.approx(sum(terms), abs=1e-9)
    assert isinstance(info["success"], bool)
    env.close()


def test_episode_is_truncated_not_terminated_at_the_time_limit():
    env = gym.make("lowcostdex/DClawTurnValve-v0")
    env.reset(seed=0)
    for _ in range(40):
        _, _, term, trunc, _ = env.step(np.zeros(9))
        assert not term
    assert trunc


def test_dropped_block_terminates():
    env = gym.make("lowcostdex/DClawFlipBlock-v0")
    env.reset(seed=0)
    u = env.unwrapped
    qpos = u.data.qpos.copy()
    qpos[u.task.block_pos] = [0.25, 0.0, 0.03]  # off the platform, falling
    env.reset(seed=0, options={"qpos": qpos})
    term = False
    for _ in range(10):
        _, _, term, trunc, _ = env.step(np.zeros(9))
        if term:
            break
    assert term


def test_actions_map_to_limits_with_a_motion_bound():
    low, high = np.array([-1.0, -0.5]), np.array([1.0, 0.5])
    present = np.zeros(2)
    goal = action_to_goal(np.array([1.0, -1.0]), low, high, present, np.array([0.2, 2.0]))
    np.testing.assert_allclose(goal, [0.2, -0.5])
    np.testing.assert_allclose(goal_to_action(np.array([1.0, 0.0]), low, high), [1.0, 0.0])


def test_nan_action_is_rejected():
    env = gym.make("lowcostdex/DClawTurnValve-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.full(9, np.nan))


def test_unknown_backend_lists_choices():
    with pytest.raises(ConfigError, match="emulated"):
        gym.make("lowcostdex/DClawTurnValve-v0", backend="robot")


def test_randomized_dynamics_differ_between_episodes():
    env = gym.make("lowcostdex/DClawTurnValveRandomDynamics-v0")
    env.reset(seed=0)
    g1 = env.unwrapped.backend.plant.model.actuator_gainprm[:, 4].copy()
    env.reset()
    g2 = env.unwrapped.backend.plant.model.actuator_gainprm[:, 4].copy()
    assert not np.allclose(g1, g2)


@pytest.mark.parametrize("env_id,kwargs", [
    ("lowcostdex/DClawTurnValve-v0", {}),
    ("lowcostdex/DClawTurnValve-v0", {"randomize": ("gain_error", "latency", "backlash",
                                                    "coulomb_friction", "mass_error")}),
    ("lowcostdex/DClawScrewRandom-v0", {}),
    ("lowcostdex/DClawFlipBlock-v0", {}),
    ("lowcostdex/DClawFlipBlockQuaternion-v0", {}),  # PPO's batched flip, quaternion variant
])
def test_vector_env_equals_a_loop_of_single_envs(env_id, kwargs):
    n = 3
    vec = make_vec(env_id, n, nthread=1, **kwargs)
    singles = [gym.make(env_id, **kwargs) for _ in range(n)]
    vobs, _ = vec.reset(seed=11)
    sobs = [e.reset(seed=11 + i)[0] for i, e in enumerate(singles)]
    np.testing.assert_allclose(vobs, np.stack(sobs), atol=1e-6)
    rng = np.random.default_rng(0)
    horizon = vec.task.timing.episode_steps
    ended = [False] * n
    for _ in range(horizon + 3):
        a = rng.uniform(-1, 1, (n, 9))
        vobs, vrew, vterm, vtrunc, vinfo = vec.step(a)
        for i, e in enumerate(singles):
            if ended[i]:  # NEXT_STEP autoreset: the step after an episode's end resets it
                o, r, term, trunc = e.reset()[0], 0.0, False, False
            else:
                o, r, term, trunc, info = e.step(a[i])
                assert bool(vinfo["success"][i]) == info["success"]
            ended[i] = term or trunc
            np.testing.assert_allclose(vobs[i], o, atol=1e-6)
            assert vrew[i] == pytest.approx(r, abs=1e-9)
            assert bool(vtrunc[i]) == trunc and bool(vterm[i]) == term


def test_flip_goal_is_relative_to_the_start_pose():
    env = gym.make("lowcostdex/DClawFlipBlock-v0")
    env.reset(seed=0)
    u = env.unwrapped
    assert u.task.orientation_error(u.data.qpos, u.goal) == pytest.approx(np.pi)
    qpos = u.data.qpos.copy()
    assert tuple(u.task.config.flip_axis) == (0.0, 1.0, 0.0)
    qpos[u.task.block_quat] = [0.0, 0.0, 1.0, 0.0]  # start upside down (flipped about y)
    env.reset(seed=0, options={"qpos": qpos})
    assert u.task.orientation_error(u.data.qpos, u.goal) == pytest.approx(np.pi, abs=1e-3)
    # the goal is the upright block again: 180 deg about the flip axis from upside down
    assert abs(abs(u.goal["quat"][0]) - 1.0) < 1e-6


def _flip_start(seed, **config):
    from lowcostdex.sim.envs.dclaw_tasks import FlipConfig

    env = gym.make("lowcostdex/DClawFlipBlock-v0")
    u = env.unwrapped
    if config:
        u.task.config = FlipConfig(**config)
    env.reset(seed=seed)
    q = u.data.qpos.copy()
    hand, pos, quat = q[u.task.hand_qpos], q[u.task.block_pos], q[u.task.block_quat]
    env.close()
    return hand, pos, quat


def test_flip_start_noise_is_seeded_and_sized_by_the_robot_reset():
    from lowcostdex.hardware.robot.reset import ResetConfig
    from lowcostdex.hardware.robot.reset_flip import FlipResetConfig
    from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE, FlipConfig

    c = FlipConfig()
    # the start noise stays inside what the robot's reset accepts as a start
    assert 0 < c.position_radius <= FlipResetConfig().position_tolerance
    assert 0 < c.joint_range <= ResetConfig().precision
    assert 0 < c.yaw_range
    a, b, a2 = _flip_start(3), _flip_start(4), _flip_start(3)
    for x, y in zip(a, a2, strict=True):
        np.testing.assert_array_equal(x, y)  # one seed, one start
    for x, y in zip(a, b, strict=True):
        assert np.max(np.abs(x - y)) > 1e-4  # two seeds: fingers, position, orientation differ
    rest = np.array([0.0, 0.0, 0.1 + 0.025])  # table top 0.1 m + half the 50 mm block
    yaws, radii = [], []
    for seed in range(40):
        hand, pos, quat = _flip_start(seed)
        assert np.max(np.abs(hand - RESET_POSE)) <= c.joint_range
        assert pos[2] == pytest.approx(rest[2])  # resting on the table
        radii.append(np.linalg.norm(pos[:2]))
        # upright, turned about the vertical only: q = (cos(yaw/2), 0, 0, sin(yaw/2))
        assert quat[1] == 0.0 and quat[2] == 0.0
        yaws.append(2.0 * math.atan2(quat[3], quat[0]))
    assert max(radii) <= c.position_radius and max(np.abs(yaws)) <= c.yaw_range
    # spread over the ranges: 40 uniform draws reach beyond half of each (P(miss) < 1e-11)
    assert max(radii) > 0.5 * c.position_radius and max(np.abs(yaws)) > 0.5 * c.yaw_range
    # with the noise off every seed starts at the one resting pose
    for seed in (3, 4):
        hand, pos, quat = _flip_start(seed, position_radius=0.0, yaw_range=0.0, joint_range=0.0)
        np.testing.assert_array_equal(hand, RESET_POSE)
        np.testing.assert_allclose(pos, rest, atol=1e-12)
        np.testing.assert_array_equal(quat, [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ConfigError, match="yaw_range"):
        FlipConfig(yaw_range=-0.1)


def _about_y(angle):
    return np.array([math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0])


def test_flip_rewards_charge_position_alike_and_orientation_on_one_scale():
    """Keypoint and quaternion flip rewards: the same position term, and orientation terms
    that agree at 0 and 180 deg, computed here from the cube's geometry."""
    from lowcostdex.sim.envs.dclaw_tasks import FlipConfig

    terms = {}
    for rep in ("keypoints", "quaternion"):
        env = gym.make("lowcostdex/DClawFlipBlock-v0")
        u = env.unwrapped
        u.task.config = FlipConfig(representation=rep)
        env.reset(seed=0)
        q0, v0 = u.data.qpos.copy(), u.data.qvel.copy()
        goal = {"pos": np.array([0.0, 0.0, 0.125]), "quat": _about_y(math.pi)}
        rows = []
        for shift, angle in (([0.03, 0.0, 0.0], 0.0), ([0.0, -0.04, 0.0], math.pi),
                             ([0.0, 0.0, 0.0], math.pi / 2)):
            q = q0.copy()
            q[u.task.block_pos] = goal["pos"] + shift
            q[u.task.block_quat] = _about_y(angle)  # angle from upright; the goal is pi
            rows.append(q)
        batch = np.stack(rows)
        t = u.task.reward_terms(batch, np.stack([v0] * 3), goal, np.zeros(9))
        for i, q in enumerate(rows):  # one state at a time gives the batch's rows
            one = u.task.reward_terms(q, v0, goal, np.zeros(9))
            for k in one:
                assert np.asarray(one[k]) == pytest.approx(np.asarray(t[k])[i], abs=1e-12)
        terms[rep] = t
        env.close()
    orient = {"keypoints": terms["keypoints"]["keypoint_distance"],
              "quaternion": terms["quaternion"]["orientation"]}
    for rep in ("keypoints", "quaternion"):
        # position: -20 per metre from the goal's centre, whatever the orientation
        np.testing.assert_allclose(terms[rep]["position"], [-0.6, -0.8, 0.0], atol=1e-12)
    # upright block, goal upside down: every corner (sqrt(2) h from the y axis, h half the
    # 50 mm block) is 2 sqrt(2) h away after the 180 deg turn about y, and the angle is pi;
    # both terms cost pi (the keypoints' scale is set by it)
    assert orient["keypoints"][0] == pytest.approx(-math.pi, abs=1e-9)
    assert orient["quaternion"][0] == pytest.approx(-math.pi, abs=1e-9)
    # at the goal's orientation, 40 mm away: no orientation cost at all (the old keypoint
    # reward charged the travel here too)
    assert orient["keypoints"][1] == pytest.approx(0.0, abs=1e-9)
    assert orient["quaternion"][1] == pytest.approx(0.0, abs=1e-9)
    # 90 deg short: each corner's chord over 90 deg is sqrt(2) x sqrt(2) h = 2 h, so the
    # keypoint term is -pi / (2 sqrt(2) h) x 2 h = -pi / sqrt(2); the angle term -pi / 2
    assert orient["keypoints"][2] == pytest.approx(-math.pi / math.sqrt(2.0), abs=1e-9)
    assert orient["quaternion"][2] == pytest.approx(-math.pi / 2, abs=1e-9)


def test_a_wrong_action_shape_is_named_with_the_joints():
    env = gym.make("lowcostdex/DClawTurnValve-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(5,\); this env takes \(9,\).*ff_top"):
        env.step(np.zeros(5, np.float32))
    env.close()
