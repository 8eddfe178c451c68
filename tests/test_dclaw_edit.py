"""``model_edit=``: a fitted D'Claw geometry / valve edit (``sim.models.dclaw_edit.DClawEdit``)
reaches the model every D'Claw task compiles. Truth: the nominal compiled model read with plain
MuJoCo, the tilt's rotation from scipy, the scalings written out in this test."""

import json

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import lowcostdex.sim  # noqa: F401
from lowcostdex.errors import ConfigError
from lowcostdex.sim.models.dclaw_edit import DClawEdit

EDIT = {"base_tilt": {"th": [-0.10, 0.017]}, "link_length": {"ff": 1.02, "mf": 0.98},
        "valve_frictionloss": 0.004, "valve_damping": 1.3, "valve_inertia": 0.8}


def _model(**kw):
    env = gym.make("lowcostdex/DClawTurnValve-v0", **kw)
    model = env.unwrapped.model
    env.close()
    return model


def test_the_edit_tilts_the_base_scales_the_links_and_changes_the_valve():
    m0, m1 = _model(), _model(model_edit=json.loads(json.dumps(EDIT)))  # as a run's config
    body = lambda m, n: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
    # the tilt: the base's quat times the rotation vector (ax, ay, 0), in the base's own frame
    b = body(m0, "th_base")
    r = Rotation.from_quat(m0.body_quat[b], scalar_first=True) * Rotation.from_rotvec(
        [-0.10, 0.017, 0.0])
    q = r.as_quat(scalar_first=True)
    assert np.allclose(m1.body_quat[b], q, atol=1e-9) or np.allclose(m1.body_quat[b], -q,
                                                                     atol=1e-9)
    for f in ("ff", "mf"):  # untilted bases keep their frame
        assert np.allclose(m1.body_quat[body(m0, f"{f}_base")], m0.body_quat[body(m0, f"{f}_base")])
    # link lengths: joint-to-joint and joint-to-tip distances scaled; th untouched
    for f, factor in (("ff", 1.02), ("mf", 0.98), ("th", 1.0)):
        for link in (f"{f}_link1", f"{f}_link2"):
            assert np.allclose(m1.body_pos[body(m0, link)], factor * m0.body_pos[body(m0, link)])
        tip = body(m0, f"{f}_link2")
        geoms = np.flatnonzero(m0.geom_bodyid == tip)
        assert geoms.size and np.allclose(m1.geom_pos[geoms], factor * m0.geom_pos[geoms])
    # the valve hinge and its body
    j = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_JOINT, "valve")
    dof = m0.jnt_dofadr[j]
    assert m1.dof_frictionloss[dof] == pytest.approx(m0.dof_frictionloss[dof] + 0.004)
    assert m1.dof_damping[dof] == pytest.approx(1.3 * m0.dof_damping[dof])
    assert m1.dof_armature[dof] == pytest.approx(0.8 * m0.dof_armature[dof])
    vb = body(m0, "valve_body")
    assert m1.body_mass[vb] == pytest.approx(0.8 * m0.body_mass[vb])
    # and the physics sees it: the thumb's tip sits elsewhere at the same joint angles
    d0, d1 = mujoco.MjData(m0), mujoco.MjData(m1)
    mujoco.mj_forward(m0, d0)
    mujoco.mj_forward(m1, d1)
    th_tip = body(m0, "th_link2")
    assert np.linalg.norm(d1.xpos[th_tip] - d0.xpos[th_tip]) > 1e-3


def test_no_edit_and_the_identity_edit_leave_the_model_alone():
    m0, m1 = _model(), _model(model_edit=DClawEdit())
    for name in ("body_pos", "body_quat", "body_mass", "geom_pos", "dof_frictionloss",
                 "dof_damping", "dof_armature"):
        assert np.array_equal(getattr(m0, name), getattr(m1, name)), name


def test_the_edit_round_trips_as_json():
    e = DClawEdit.from_dict(EDIT)
    assert DClawEdit.from_dict(json.loads(json.dumps(e.to_dict()))) == e


@pytest.mark.parametrize("bad, words", [
    ({"base_tilt": {"rf": [0.0, 0.0]}}, "ff"),
    ({"base_tilt": {"th": [0.0]}}, "2 finite angles"),
    ({"base_tilt": {"th": [float("nan"), 0.0]}}, "2 finite angles"),
    ({"link_length": {"ff": 0.0}}, "[0.5, 2]"),
    ({"valve_frictionloss": -0.01}, ">= 0"),
    ({"valve_damping": 0.0}, "> 0"),
    ({"valve_inertia": float("inf")}, "> 0"),
    ({"tilt": {}}, "unknown keys ['tilt']"),
])
def test_a_bad_edit_is_refused_naming_what_is_wrong(bad, words):
    with pytest.raises(ConfigError, match=None) as e:
        _model(model_edit=bad)
    assert words in str(e.value)


def test_a_bad_edit_type_is_refused():
    with pytest.raises(ConfigError, match="to_dict"):
        _model(model_edit=[1, 2])
