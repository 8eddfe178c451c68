"""Careless calls, session 29 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError

_TWO = """<mujoco><option timestep="0.002"/><worldbody>
<body><joint name="a" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body>
<body pos="0 1 0"><joint name="b" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="a" joint="a" kp="2"/><position name="b" joint="b" kp="2"/></actuator>
</mujoco>"""


def _trajectory(t: np.ndarray, name: str = "arm"):
    from lowcostdex.gap.trajectory import Trajectory

    goal = np.stack([0.2 * np.sin(t), 0.1 * np.cos(t)], axis=1)
    return Trajectory(name, t, goal, goal.copy(), ("a", "b"), ("a", "b"))


# -- leftovers of session 28 ------------------------------------------------------------------

@pytest.mark.parametrize("edit,said", [
    (lambda t: t[::-1].copy(), r"time\[1\]=1\.98 is before time\[0\]=1\.99"),
    (lambda t: np.concatenate([t[:100], t[100:][::-1]]), r"time\[101\]=1\.98 is before "
                                                          r"time\[100\]=1\.99"),
    (lambda t: np.where(np.arange(len(t)) == 7, t[6], t), r"time\[7\]=0\.06 repeats time\[6\]"),
    (lambda t: np.where(np.arange(len(t)) == 3, np.nan, t), r"time\[3\] is nan: sample times "
                                                            r"\[s\] must be finite"),
])
@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_write_log_refuses_times_that_do_not_increase(edit, said, suffix, tmp_path):
    # before: written without a word (the reader sorts a little disorder with a note, refuses
    # the rest): the file written is not the trajectory given
    from lowcostdex.gap.logs import LogError, write_log

    tr = _trajectory(edit(np.arange(200) * 0.01))
    with pytest.raises(LogError, match=r"Trajectory 'arm': " + said if "nan" in said else
                       r"Trajectory 'arm': time must be strictly increasing \[s\], but " + said):
        write_log(tmp_path / f"arm{suffix}", tr)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("kwargs,said", [
    ({"events_kept": 0}, "EmulatedChain events_kept=0"),
    ({"replies_kept": 1.5}, "EmulatedChain replies_kept=1.5"),
    ({"events_kept": "100"}, "EmulatedChain events_kept='100'"),
])
def test_an_emulated_chain_names_a_bad_count_of_entries_kept(kwargs, said):
    # before: events_kept=0 gave RingLog's "RingLog needs maxlen >= 1", not naming the option;
    # replies_kept=1.5 was taken (and kept 1 reply); "100" a TypeError
    from lowcostdex.hardware.emulated.chain import emulated_bench

    with pytest.raises(ConfigError, match=said + r" must be an integer in \[1, inf\)"):
        emulated_bench(**kwargs)


def test_a_replayer_refuses_what_is_no_dataset_or_a_goal_it_cannot_replay():
    # before: Replayer(None) raised AttributeError ('NoneType' object has no attribute
    # 'trajectories'); a NaN goal of a Dataset built in Python was refused by the plant at the
    # first step, without naming the trajectory (the replay now steps its plant unchecked)
    from lowcostdex.gap.dataset import Dataset
    from lowcostdex.gap.replay import Replayer

    for ds in (None, "logs/arm.csv"):
        with pytest.raises(ConfigError, match=r"Replayer\(ds\) replays a lowcostdex.gap.Dataset "
                                              r"\(from load_dataset\), not "):
            Replayer(ds)
    tr = _trajectory(np.arange(200) * 0.01)
    tr.goal[50, 1] = np.nan
    with pytest.raises(ConfigError, match=r"trajectory 'arm': goal holds nan: must be finite "
                                          r"numbers, goals of the actuators a, b"):
        Replayer(Dataset({"model": _TWO}, [tr]))


@pytest.mark.parametrize("env_id,goal,said", [
    ("lowcostdex/DClawTurnValve-v0", {"angle": 400.0},
     r"goal\['angle'\]=400.0 is outside \[-18.85, 18.85\] rad, the farthest this task's settings "
     r"reach; in rad, not deg \(400 deg is 6.981 rad\)"),
    ("lowcostdex/DClawTurnValve-v0", {"angle": -90},
     r"goal\['angle'\]=-90 is outside \[-18.85, 18.85\] rad"),
    ("lowcostdex/DClawScrew-v0", {"angle": 0.0, "start": 0.0, "speed": 30.0},
     r"goal\['speed'\]=30.0 is outside \[-6.283, 6.283\] rad/s, the farthest this task's "
     r"settings reach; in rad/s, not deg/s \(30 deg/s is 0.5236 rad/s\)"),
])
def test_a_valve_reset_goal_in_degrees_is_refused(env_id, goal, said):
    # before: taken (a goal of 400 rad: 64 turns); the configs' goal_offset had a bound (+-4 pi)
    # but a goal given at reset none
    import gymnasium as gym

    import lowcostdex  # noqa: F401

    env = gym.make(env_id)
    try:
        with pytest.raises(ValueError, match=r"reset option " + said):
            env.reset(seed=0, options={"goal": goal})
        fine = {k: 6 * math.pi if k == "angle" else 0.5 for k in goal}  # at the bound: taken
        env.reset(seed=0, options={"goal": fine})
        assert float(env.unwrapped._goal["angle"]) == fine["angle"]
    finally:
        env.close()


@pytest.mark.parametrize("kwargs,said", [
    ({"frame_skip": 0}, r"TaskSpec.frame_skip \(physics substeps\)=0"),
    ({"frame_skip": 2.5}, r"TaskSpec.frame_skip \(physics substeps\)=2.5"),
    ({"episode_steps": -1}, r"TaskSpec.episode_steps=-1"),
])
def test_a_task_timing_that_is_no_count_is_refused_where_made(kwargs, said):
    # before: taken; a frame_skip of 0 was refused by Plant.step at the first env step (the env
    # now steps its plant unchecked), 2.5 likewise; episode_steps=-1 truncated every step
    from lowcostdex.sim.envs.task import TaskSpec

    with pytest.raises(ConfigError, match=said + r" must be an integer in \[1, inf\)"):
        TaskSpec(**kwargs)


def test_the_unchecked_step_is_the_checked_step_to_the_bit():
    # the replay's and envs' path: Plant.step_unchecked (did not exist before); the physics of
    # a plain MuJoCo position servo, stepped beside it, and Plant.step give the same bits
    from lowcostdex.sim.plant import BatchPlant, Plant

    model = mujoco.MjModel.from_xml_string(_TWO)
    rng = np.random.default_rng(3)
    goals = rng.uniform(-0.5, 0.5, (30, 2))
    data = mujoco.MjData(model)
    checked, unchecked = Plant(model), Plant(model)
    for g in goals:
        data.ctrl[:] = g
        mujoco.mj_step(model, data, nstep=3)
        checked.step(g, 3)
        unchecked.step_unchecked(g, 3)
        assert np.array_equal(unchecked.qpos, data.qpos)
        assert np.array_equal(checked.qpos, data.qpos)
    a, b = BatchPlant(model, 3, nthread=1), BatchPlant(model, 3, nthread=1)
    for g in goals:
        a.step(np.stack([g, -g, 0 * g]), 2)
        b.step_unchecked(np.stack([g, -g, 0 * g]), 2)
    assert np.array_equal(a.qpos, b.qpos) and np.array_equal(a.qvel, b.qvel)


def test_env_steps_skip_the_goal_check_the_public_step_keeps(monkeypatch):
    # before: every env step (and replay step) paid Plant.step's argument check (2-4 us a call,
    # 10-20 % of a one-substep step); their goals come from checked actions and logs
    import gymnasium as gym

    import lowcostdex  # noqa: F401
    from lowcostdex.sim import plant as plant_module
    from lowcostdex.sim.vector import make_vec

    calls = []
    real = plant_module.check_finite_array
    monkeypatch.setattr(plant_module, "check_finite_array",
                        lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    env = gym.make("lowcostdex/DClawTurnValve-v0")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    vec = make_vec("lowcostdex/DClawTurnValve-v0", num_envs=2, nthread=1)
    vec.reset(seed=0)
    vec.step(np.zeros(vec.action_space.shape))
    assert "goal" not in calls and calls  # (reset still checks its qpos and qvel)
    with pytest.raises(ConfigError, match=r"goal of shape \(1,\)"):
        env.unwrapped.backend.plant.step(np.zeros(1), 1)  # the public call: still checked
    env.close()
    vec.close()
