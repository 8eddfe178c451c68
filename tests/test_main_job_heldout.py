"""The main job's paired held-out comparison does not depend on evaluation order (issue 13).

Checked from the device side: the emulated D'Claw's own physics (the plant's joint angles and
its motors' winding temperatures, read from the emulator behind the bus, not from the env's
observations) at the start and at the end of every episode. On one robot a policy's episodes
start differently after another policy ran (the reset leaves the fingers where their backlash
and friction stop them, the windings are warmer: physical, a real robot does it too); with
``evaluate(fresh=True)`` a policy's episodes are bit-identical whether or not another policy
ran before it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from lowcostdex.algos.configs import PolicyConfig
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.algos.samplers import HELDOUT_STREAM, EnvFactory, make_jobs
from lowcostdex.main_job.heldout import UniformActions, evaluate, uniform_actions
from lowcostdex.main_job.setup import TASKS, Context

EPISODES = 2


def device_logging_factory(logs: list[list[dict[str, np.ndarray]]]):
    """Builds the main job's emulated robot env and records, for every env it builds (one list
    per env in ``logs``), the emulator's physics at each episode start (after the auto-reset)
    and end (before the next reset, or at close)."""
    make = EnvFactory(TASKS["valve-target"].env_id, Context(out=Path(".")).env_kwargs())

    def factory():
        env = make()
        backend = env.unwrapped.backend
        log: list[dict[str, np.ndarray]] = []
        logs.append(log)

        def device(when: str) -> dict[str, np.ndarray]:
            plant = backend.chain.plant
            return {"when": when, "qpos": plant.data.qpos.copy(), "qvel": plant.data.qvel.copy(),
                    "temperature": np.array(backend.chain.drive.state().temperature)}

        reset, close = backend.reset, backend.close

        def logged_reset(qpos, qvel):
            if log:
                log.append(device("end"))
            reset(qpos, qvel)
            log.append(device("start"))

        def logged_close():
            log.append(device("end"))
            close()

        backend.reset, backend.close = logged_reset, logged_close
        return env

    return factory


@pytest.fixture(scope="module")
def runs():
    x = GaussianMLPPolicy(30, 9, PolicyConfig(hidden_sizes=(16,)),
                          torch.Generator().manual_seed(5)).snapshot()
    jobs = make_jobs(0, HELDOUT_STREAM, 0, EPISODES, deterministic=True)
    out = {}
    for case, policies, fresh in (
            ("alone", {"x": x}, True),
            ("after_y_fresh", {"y": uniform_actions(np.random.default_rng(1)), "x": x}, True),
            ("after_y_shared", {"y": uniform_actions(np.random.default_rng(1)), "x": x}, False)):
        logs: list = []
        paths = evaluate(device_logging_factory(logs), policies, jobs, fresh=fresh)
        out[case] = (paths, logs)
    return out


def x_device_log(case, runs):
    paths, logs = runs[case]
    if case == "after_y_shared":  # one env: y's episodes, then x's
        assert len(logs) == 1
        return logs[0][2 * EPISODES:]
    return logs[-1]


def test_the_policy_obs_size_fits_the_task(runs):
    paths, _ = runs["alone"]
    assert paths["x"][0].observations.shape[1] == 30 and paths["x"][0].actions.shape[1] == 9


def test_a_policy_runs_the_same_on_a_fresh_robot_whatever_ran_before(runs):
    alone, after = x_device_log("alone", runs), x_device_log("after_y_fresh", runs)
    assert len(alone) == len(after) == 2 * EPISODES
    for a, b in zip(alone, after, strict=True):
        assert a["when"] == b["when"]
        for key in ("qpos", "qvel", "temperature"):
            np.testing.assert_array_equal(a[key], b[key])
    pa, pb = runs["alone"][0]["x"], runs["after_y_fresh"][0]["x"]
    for ta, tb in zip(pa, pb, strict=True):
        np.testing.assert_array_equal(ta.actions, tb.actions)
        assert ta.final_goal_error == tb.final_goal_error


def test_on_one_robot_the_state_carries_over_from_the_policy_before(runs):
    # why evaluate(fresh=True) exists: the same first episode of x starts elsewhere and warmer
    # after y's episodes on the same robot (the plant's state, not the env's reading of it)
    alone, shared = x_device_log("alone", runs), x_device_log("after_y_shared", runs)
    first_alone, first_shared = alone[0], shared[0]
    assert first_alone["when"] == first_shared["when"] == "start"
    assert np.max(np.abs(first_alone["qpos"] - first_shared["qpos"])) > 1e-3  # [rad]
    assert np.all(first_shared["temperature"] > first_alone["temperature"])
    # y's episodes really ran on that robot before x: twice as many episodes logged
    assert len(runs["after_y_shared"][1][0]) == 4 * EPISODES


def test_uniform_actions_cover_the_action_space_and_are_seeded():
    low, high = -np.ones(9), np.ones(9)
    a = UniformActions(low, high, np.random.default_rng(3))
    b = UniformActions(low, high, np.random.default_rng(3))
    draws = np.array([a.act(np.zeros(30)) for _ in range(2000)])
    np.testing.assert_array_equal(draws[0], b.act(np.zeros(30)))
    assert a.act_dim == 9
    assert np.all(draws >= -1) and np.all(draws <= 1)
    # uniform on [-1, 1]: mean 0, variance 1/3 (2000 draws: standard error ~0.013 per joint)
    assert np.all(np.abs(draws.mean(0)) < 0.06)
    assert np.all(np.abs(draws.var(0) - 1 / 3) < 0.04)
