"""Careless calls, session 28 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

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


def _plant(batch: int = 0):
    from lowcostdex.sim.plant import BatchPlant, Plant

    model = mujoco.MjModel.from_xml_string(_TWO)
    return BatchPlant(model, batch, nthread=1) if batch else Plant(model)


_WHAT = "goals of the 2 actuators"


@pytest.mark.parametrize("goal,said", [
    (np.array([0.3]), r"goal of shape \(1,\) must have shape \(2,\): " + _WHAT),
    (0.3, r"goal of shape \(\) must have shape \(2,\): " + _WHAT),
    (np.zeros(3), r"goal of shape \(3,\) must have shape \(2,\): " + _WHAT),
    (np.zeros((2, 2)), r"goal of shape \(2, 2\) must have shape \(2,\): " + _WHAT),
    (np.array([np.nan, 0.0]), r"goal holds nan: must be finite numbers, " + _WHAT),
    (np.array([0.0, -np.inf]), r"goal holds -inf: must be finite numbers, " + _WHAT),
    (np.array([0.0, 1e12]), r"goal holds 1e\+12: must be at most 1e\+10 in size, " + _WHAT),
    (["0.1", "0.2"], r"goal holds '0.1', not numbers: " + _WHAT),
])
def test_a_plant_step_refuses_a_goal_it_would_broadcast_or_mujoco_would_zero(goal, said):
    # before: a (1,) or scalar goal drove both actuators to one angle without a word; a NaN,
    # inf or 1e12 goal made MuJoCo zero every control of the step (a printed warning only);
    # text goals a numpy error
    plant = _plant()
    with pytest.raises(ConfigError, match=said + r": positions \[rad\]"):
        plant.step(goal, 2)
    assert plant.time == 0.0 and not plant.ctrl.any()


@pytest.mark.parametrize("nstep", [0, -3, 2.5, "3", True, None])
def test_a_plant_step_refuses_a_count_of_substeps_that_is_no_count(nstep):
    # before: 0 and -3 stepped nothing without a word, 2.5 and "3" ended in MuJoCo's binding
    # error, True stepped once
    plant = _plant()
    with pytest.raises(ConfigError, match=rf"nstep \(physics substeps\)={nstep!r} must be an "
                                          r"integer in \[1, inf\)"):
        plant.step(np.zeros(2), nstep)
    assert plant.time == 0.0


def test_a_plant_step_with_good_arguments_is_unchanged():
    # the checks let every good call through: numpy counts, lists, a batch's (nu,) and
    # (nsim, nu) goals, and the numbers are those of plain MuJoCo's own position servo
    plant = _plant()
    plant.step([0.1, 0.2], np.int64(3))
    model = mujoco.MjModel.from_xml_string(_TWO)
    data = mujoco.MjData(model)
    data.ctrl[:] = [0.1, 0.2]
    mujoco.mj_step(model, data, nstep=3)
    np.testing.assert_array_equal(plant.qpos, data.qpos)
    batch = _plant(3)
    batch.step(np.array([0.1, 0.2]), 3)
    batch.step(np.zeros((3, 2)), 1)
    with pytest.raises(ConfigError, match=r"shape \(2,\) or \(3, 2\): goals of the 2 actuators "
                                          r"\(per simulation\)"):
        batch.step(np.zeros((2, 2)), 1)


@pytest.mark.parametrize("state,said", [
    (dict(qpos=0.3), r"qpos of shape \(\) must have shape \(2,\)"),
    (dict(qpos=[0.3]), r"qpos of shape \(1,\) must have shape \(2,\)"),
    (dict(qvel=[0.0, np.nan]), r"qvel holds nan: must be finite numbers"),
    (dict(ctrl=np.zeros(3)), r"ctrl of shape \(3,\) must have shape \(2,\)"),
])
def test_a_plant_reset_refuses_a_state_of_another_shape_or_not_finite(state, said):
    # before: a scalar or (1,) qpos was broadcast to every joint; a NaN qvel made MuJoCo reset
    # the simulation at the next step with a printed warning
    with pytest.raises(ConfigError, match=said):
        _plant().reset(**state)
    with pytest.raises(ConfigError, match=r"qpos of shape \(2,\) must have shape \(3, 2\)"):
        _plant(3).reset(qpos=np.zeros(2))  # (before: each simulation given one number)


def test_the_same_log_twice_from_python_is_refused_naming_it(tmp_path):
    # before: load_dataset([a, a]) read and fitted the log twice (the CLI uses it once with a
    # note); a folder and a file in it, or two spellings of one path, too
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.logs import LogError, Trajectory, write_log

    (tmp_path / "m.xml").write_text(_TWO)
    t = np.arange(200) * 0.01
    goal = np.stack([0.2 * np.sin(t), 0.1 * np.cos(t)], axis=1)
    log = write_log(tmp_path / "a.csv", Trajectory("a", t, goal, goal.copy(), ("a", "b"),
                                                   ("a", "b")))
    model = tmp_path / "m.xml"
    assert len(load_dataset([log], model=model).trajectories) == 1
    with pytest.raises(LogError, match=r"a.csv: the same log given twice; each log is fitted "
                                       r"once: give it once"):
        load_dataset([log, log], model=model)
    with pytest.raises(LogError, match=r"the same log given twice \(as .*a.csv and as "
                                       r".*sub/\.\./a.csv\)"):
        (tmp_path / "sub").mkdir()
        load_dataset([tmp_path, tmp_path / "sub" / ".." / "a.csv"], model=model)

