"""Effects on a TENDON-driven finger (issue 11; gap-tendon, session 29): the servo of
``tests/gap_truth_sim13.py``'s tendon finger is a ``position`` actuator on a fixed tendon over
the mcp and pip (gear 1 / horn radius: its length is the servo's angle). The servo's effects
(latency, gain_error, torque_limit) act on that actuator's own coordinate, once, whichever of its
joints carries the value; the joints' effects on the joints. The truth of each check is plain
MuJoCo: the user's MJCF with the effect written into it by hand (the delay, kp or force range of
the actuator), stepped with the same goals."""

from __future__ import annotations

import pathlib
import sys

import mujoco
import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim13 as sim  # noqa: E402

JOINTS = ("mcp", "pip")


def _goals(n: int) -> np.ndarray:
    """A flexing then releasing servo goal [rad of servo angle], one per physics step."""
    t = np.arange(n) * sim.MODEL_DT
    return 0.9 + 0.5 * np.sin(2 * np.pi * 1.5 * t)


def _plain(xml: str, goals: np.ndarray) -> np.ndarray:
    """qpos after each step of the user's model in plain MuJoCo (finger at rest, goal 0.9)."""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    out = []
    for g in goals:
        d.ctrl[0] = g
        mujoco.mj_step(m, d)
        out.append(d.qpos.copy())
    return np.array(out)


def _with_effect(name: str, values: dict, goals: np.ndarray) -> np.ndarray:
    from lowcostdex.sim.effects import AppliedEffect
    from lowcostdex.sim.plant import Plant, compile_with_effects

    spec = mujoco.MjSpec.from_string(sim.model_xml())
    eff = AppliedEffect(name, JOINTS, values)
    p = Plant(compile_with_effects(spec, [(name, JOINTS)]), [eff])
    out = []
    for g in goals:
        p.step(np.array([g]), 1)
        out.append(p.qpos.copy())
    return np.array(out)


@pytest.mark.parametrize("name, values, edit", [
    # kp x1.6 on the servo: gain and bias (-kp) scale together (MuJoCo's position shortcut)
    ("gain_error", {"scale": np.array([1.6, 1.0])}, ('kp="3.0"', 'kp="4.8"')),
    # a 0.3 N m limit at the horn: the actuator's own force range (not divided by its gear)
    ("torque_limit", {"torque": np.array([0.3, np.inf])}, ('forcerange="0 0.5"',
                                                           'forcerange="0 0.3"')),
    # the goal 30 ms late: MuJoCo's own actuator delay, linear between samples
    ("latency", {"delay": np.array([0.03, 0.0])}, ('ctrlrange="0 1.8"',
                                                   'ctrlrange="0 1.8" delay="0.03" nsample="40" '
                                                   'interp="linear"')),
])
def test_a_tendon_servos_effect_acts_on_its_actuator_as_written_in_the_mjcf(name, values, edit):
    """The effect placed on the tendon's joints (mcp carries the value, pip the null: the fit
    frees it on the first joint only) replays as the user's MJCF with the effect written into
    its actuator by hand. Before gap-tendon, Targets.resolve refused the joints (no joint
    actuator) and a joint-keyed write would have let pip's null win on the shared actuator."""
    goals = _goals(400)
    xml = sim.model_xml()
    assert edit[0] in xml
    want = _plain(xml.replace(edit[0], edit[1]), goals)
    got = _with_effect(name, values, goals)
    assert np.abs(got - want).max() < 1e-9
    assert np.abs(_plain(xml, goals) - want).max() > 1e-3  # the effect moves the finger


def test_a_tendon_finger_is_analysed_on_its_servo_and_joints(tmp_path):
    """Its measured joints over the cable are effect joints (the dip, on the linkage, is not),
    the servo's effects are keyed by the actuator ``flex``, the effects not yet supported there
    are refused by name with the reason; the linkage twin as before."""
    from lowcostdex.errors import ConfigError
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.offer import ON_TENDON, available_candidates

    files = sim.write_case(sim.Case("t", (), (1.0,), 3), tmp_path / "t")
    ds = load_dataset(files["logs"], model=files["model"])
    assert ds.effect_joints == JOINTS
    assert "joint 'mcp' is driven through tendon flex" in " ".join(ds.notes)
    assert set(available_candidates(ds, None)) <= set(ON_TENDON)
    assert {"latency", "gain_error", "coulomb_friction", "mass_error"} <= set(
        available_candidates(ds, None))
    with pytest.raises(ConfigError, match="backlash: not analysed .*a play at the horn"):
        available_candidates(ds, ["latency", "backlash"])
    files = sim.write_case(sim.Case("l", (), (1.0,), 3, rig="linkage finger"), tmp_path / "l")
    ds = load_dataset(files["logs"], model=files["model"])
    assert ds.effect_joints == JOINTS and "backlash" in available_candidates(ds, ["backlash"])


def test_a_shared_servos_parameters_are_free_once_and_reported_on_the_actuator():
    """A fit frees the servo's delay on its first joint only (a second free scalar on the same
    actuator would be a dead column); the report keys it by the actuator ``flex``; the joints'
    friction stays per joint."""
    from lowcostdex.gap import fit as fitmod
    from lowcostdex.gap.results import Cause, servo_keyed
    from lowcostdex.sim.effects import Targets

    m = mujoco.MjModel.from_xml_string(sim.model_xml())
    t = Targets.resolve(m, JOINTS)
    assert t.actuators.tolist() == [0, 0] and t.owners.tolist() == [0]
    ctx = fitmod.Context(dt=0.002, peak_force=np.array([0.4, 0.4]),
                         damping=np.zeros(2), **fitmod.servo_facts(m, t.actuators))
    s = fitmod.Structure.build(("latency", "coulomb_friction"), JOINTS, ctx)
    assert [(f.effect, f.param, f.joint) for f in s.free] == [
        ("latency", "delay", 0), ("coulomb_friction", "frictionloss", 0),
        ("coulomb_friction", "frictionloss", 1)]
    c = Cause("latency", JOINTS, {"delay": {"value": [0.031, 0.0], "interval": [
        [0.03, 0.032], [0.0, 0.0]], "unit": "s"}})
    k = servo_keyed(c, m, t)
    assert k.joints == ("flex",) and k.params["delay"]["value"] == [0.031]
    assert k.params["delay"]["interval"] == [[0.03, 0.032]] and k.params["delay"]["unit"] == "s"
    f = Cause("coulomb_friction", JOINTS, {"frictionloss": {"value": [0.0, 0.02]}})
    assert servo_keyed(f, m, t) is f


def test_a_shared_servos_latency_survives_a_goal_shift(tmp_path):
    """The analysis checks a latency again with every goal a fraction of a step later
    (``goal_shift``: the goals queued on the grid, the native delay off): the tendon's servo
    keeps its first joint's delay there, so 30 ms + a 0.5 ms shift replays as 30.5 ms (before,
    pip's null overwrote mcp's delay on the shared column and the shifted replay had none: the
    sim13 latency case was refused as 'not robust', 0 % gain with goals shifted)."""
    from lowcostdex.gap.dataset import episodes, load_dataset
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.sim.effects import AppliedEffect

    files = sim.write_case(sim.Case("t", (), (1.5,), 5), tmp_path / "t")
    ds = load_dataset(files["logs"], model=files["model"])
    rep = Replayer(ds, ["latency"], nthread=1)
    eps = episodes(ds)

    def lat(d):
        return [AppliedEffect("latency", JOINTS, {"delay": np.array([d, 0.0])})]

    (shifted,), _ = rep.run(eps, [lat(0.03)], goal_shift=0.0005)
    late, none = rep.run(eps, [lat(0.0305), []])[0]
    assert np.abs(shifted[0] - late[0]).max() < 1e-9
    assert np.abs(late[0] - none[0]).max() > 5e-3  # 30 ms moves the finger
