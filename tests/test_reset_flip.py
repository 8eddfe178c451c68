"""Flip-task reset on the emulated D'Claw: the block re-centred and aligned by three-finger
squeezes against the tracker (here the emulator's physics), checked on the device side; a block
with the wrong face up ends in a bounded ResetFailed unless a reorient policy is set."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

from lowcostdex.hardware.robot.reset import ResetFailed
from lowcostdex.sim.registry import register_envs

ENV = "lowcostdex/DClawFlipBlock-v0"


@pytest.fixture(scope="module", autouse=True)
def _register():
    register_envs()


def place_block(chain, xy, yaw=0.0):
    """Put the block (upright) at (x, y) [m] turned by ``yaw`` [rad] about the vertical."""
    m, d = chain.plant.model, chain.plant.data
    adr = m.jnt_qposadr[m.joint("block").id]
    d.qpos[adr:adr + 2] = xy
    d.qpos[adr + 3:adr + 7] = [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]
    d.qvel[:] = 0
    mujoco.mj_forward(m, d)
    return adr


def test_displaced_and_turned_block_is_recentred_and_aligned():
    env = gym.make(ENV, backend="emulated")
    env.reset(seed=0)
    backend = env.unwrapped.backend
    chain = backend.chain
    rng = np.random.default_rng(5)
    for seed in range(3):
        adr = place_block(chain, rng.uniform(-0.04, 0.04, 2), yaw=rng.uniform(-1, 1))
        env.reset(seed=seed)
        d = chain.plant.data
        assert np.linalg.norm(d.qpos[adr:adr + 2]) < 0.015  # device side: the true block
        _, _, _, _, info = env.step(np.zeros(9, np.float32))
        assert not info["success"] and info["goal_error"] > 2.5  # start orientation, not goal
    assert backend.robot.metrics.resets == 4 and backend.robot.metrics.reset_failures == 0
    env.close()


def test_block_with_the_wrong_face_up_fails_clearly_or_uses_the_reorient_policy():
    # without a reorientation and without the emulator's virtual person (both on by default)
    env = gym.make(ENV, backend="emulated", reorient=None, virtual_person=False)
    env.reset(seed=0)
    chain = env.unwrapped.backend.chain
    m, d = chain.plant.model, chain.plant.data
    adr = m.jnt_qposadr[m.joint("block").id]
    d.qpos[adr + 3:adr + 7] = [0.0, 1.0, 0.0, 0.0]  # flipped: 180 deg about x
    mujoco.mj_forward(m, d)
    t0 = chain.now
    with pytest.raises(ResetFailed, match="wrong face is up.*turn the block over by hand"):
        env.reset(seed=1)
    assert chain.now - t0 < 60.0
    env.close()

    calls = []

    def person_turns_it_over(robot, tracker, quat):  # stands in for a learned flip policy
        calls.append(tracker()[1].copy())
        d.qpos[adr + 3:adr + 7] = quat
        mujoco.mj_forward(m, d)

    env = gym.make(ENV, backend="emulated", reorient=person_turns_it_over, virtual_person=False)
    env.reset(seed=0)
    chain = env.unwrapped.backend.chain
    m, d = chain.plant.model, chain.plant.data
    d.qpos[adr + 3:adr + 7] = [0.0, 1.0, 0.0, 0.0]
    mujoco.mj_forward(m, d)
    env.reset(seed=1)
    assert len(calls) == 1 and abs(calls[0][1]) > 0.99
    env.close()
