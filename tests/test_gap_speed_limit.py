"""velocity_limit on actuators without a back-EMF model: a motor's torque-speed line on the
force range of a plain position (or motor) actuator (issue 11 item 4, redteam3 srv_vlimit15).

Truth from physics written out here: a horizontal wheel (no gravity) with joint damping b driven
by a saturated servo whose motor delivers at most F (1 - w / w0) forward at speed w (a DC motor
at full voltage: torque (V - K w) K / R = stall (1 - w / w0)). Its speed settles where that
torque equals the damping torque: F (1 - w / w0) = b w, so w* = F w0 / (F + b w0). Without the
line the force range alone gives w* = F / b.
"""

from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import BatchPlant, Plant

_WHEEL = """
<mujoco><option timestep="0.001" gravity="0 0 0"/>
  <worldbody><body><joint name="j" axis="0 0 1" damping="{b}" armature="0.002"/>
    <geom type="cylinder" size="0.03 0.01" mass="0.05"/></body></worldbody>
  <actuator>{act}</actuator>
</mujoco>"""
F, B = 1.0, 0.1  # N m force limit, N m s/rad damping


def _model(act: str, b: float = B) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(_WHEEL.format(b=b, act=act))


def _plateau(plant, goal=1e4, steps=4000):
    """Speed after driving far toward ``goal`` for ``steps`` physics steps [rad/s]."""
    plant.reset()
    for _ in range(steps):
        plant.step(np.full(np.shape(plant.ctrl), goal), 1)
    return np.asarray(plant.qvel)[..., 0]


POS = f'<position joint="j" kp="50" kv="0.2" forcelimited="true" forcerange="{-F} {F}"/>'


@pytest.mark.parametrize("w0", [0.5, 1.5, 6.0])
def test_speed_plateau_of_a_position_actuator_on_a_torque_speed_line(w0):
    p = Plant(_model(POS), [AppliedEffect("velocity_limit", ("j",), {"speed": w0})])
    assert float(_plateau(p)) == pytest.approx(F * w0 / (F + B * w0), rel=0.01)
    # backwards: the same line mirrored
    assert float(_plateau(p, goal=-1e4)) == pytest.approx(-F * w0 / (F + B * w0), rel=0.01)


def test_null_speed_is_the_nominal_model_and_batches_carry_their_own_speeds():
    m = _model(POS)
    nominal = float(_plateau(Plant(m)))
    assert nominal == pytest.approx(F / B, rel=0.01)
    assert float(_plateau(Plant(m, [AppliedEffect("velocity_limit", ("j",))]))) == nominal
    bp = BatchPlant(m, 3, [[AppliedEffect("velocity_limit", ("j",), {"speed": s})]
                           for s in (math.inf, 1.5, 4.0)], nthread=1)
    got = _plateau(bp)
    np.testing.assert_allclose(got, [F / B, F * 1.5 / (F + B * 1.5), F * 4 / (F + B * 4)],
                               rtol=0.01)
    # the nominal force range is restored in the model between steps' rewrites
    np.testing.assert_array_equal(bp._static_forcerange[:, 0], [[-F, F]] * 3)


def test_beyond_the_no_load_speed_the_motor_brakes_and_torque_off_stays_off():
    # spun at 3 rad/s by its initial state with a 1 rad/s line: the force is -F (upper limit
    # F (1 - 3) clipped to the lower -F), as a motor driven above its no-load speed
    p = Plant(_model(POS, b=0.0), [AppliedEffect("velocity_limit", ("j",), {"speed": 1.0})])
    p.reset(qvel=np.array([3.0]), ctrl=np.array([1e4]))
    p.step(np.array([1e4]), 1)
    assert float(p.actuator_force[0]) == pytest.approx(-F)
    p.set_torque_enabled([0], False)
    p.step(np.array([1e4]), 1)
    assert float(p.actuator_force[0]) == 0.0


def test_a_motor_actuator_follows_the_same_line_and_an_unlimited_one_is_untouched():
    mot = f'<motor joint="j" gear="1" forcelimited="true" forcerange="{-F} {F}" ctrlrange="-5 5"/>'
    p = Plant(_model(mot), [AppliedEffect("velocity_limit", ("j",), {"speed": 2.0})])
    p.reset()
    for _ in range(4000):
        p.step(np.array([5.0]), 1)   # commands 5 N m, clipped to the line
    assert float(p.qvel[0]) == pytest.approx(F * 2.0 / (F + B * 2.0), rel=0.01)
    free = '<position joint="j" kp="2" kv="0.2"/>'
    a = _plateau(Plant(_model(free)), goal=3.0, steps=3000)
    b = _plateau(Plant(_model(free), [AppliedEffect("velocity_limit", ("j",), {"speed": 1.0})]),
                 goal=3.0, steps=3000)
    assert float(a) == float(b)


def test_the_fit_frees_speed_on_position_actuators_and_scale_on_dcmotors():
    ctx_pos = fitmod.Context(dt=0.002, peak_force=np.array([1.0]), stall=np.array([np.inf]),
                             damping=np.array([0.1]))
    ctx_dc = fitmod.Context(dt=0.002, peak_force=np.array([1.0]), stall=np.array([3.0]),
                            damping=np.array([0.1]))
    pos = fitmod.Structure.build(("velocity_limit",), ("j",), ctx_pos)
    dc = fitmod.Structure.build(("velocity_limit",), ("j",), ctx_dc)
    assert [f.param for f in pos.free] == ["speed"]
    assert [f.param for f in dc.free] == ["scale"]
    f = pos.free[0]
    assert f.log and f.lo <= 0.5 and f.hi >= 10.0  # real sizes: 0.5-10 rad/s
    e = pos.to_effects(np.array([1.5]))[-1]
    assert e.values["speed"][0] == 1.5 and e.values["scale"][0] == 1.0


def test_a_velocity_limit_at_its_infinite_null_round_trips_through_json():
    e = AppliedEffect("velocity_limit", ("j",), {"scale": 1.3})
    d = json.loads(json.dumps(e.to_dict(), allow_nan=False))
    back = AppliedEffect.from_dict(d)
    assert back.values["scale"][0] == 1.3 and math.isinf(back.values["speed"][0])


# ------------------------------------------------------------ Stribeck breakaway, true stiction
# Physics: a wheel (inertia I, no damping, no gravity) under a constant motor torque tau. Dry
# friction with breakaway Fs = Fc + static at rest and sliding level Fc: for tau < Fs it stays
# at rest (true stiction: no creep); for tau > Fs it breaks away and, once fast (v >> the
# Stribeck velocity), accelerates at (tau - Fc) / I.
_FREE = """
<mujoco><option timestep="0.002" gravity="0 0 0"/>
  <worldbody><body><joint name="j" axis="0 0 1" armature="0.002"/>
    <geom type="cylinder" size="0.03 0.01" mass="0.05"/></body></worldbody>
  <actuator><motor joint="j" gear="1" ctrlrange="-5 5"/></actuator>
</mujoco>"""
FC, FS_EXTRA, VS = 0.08, 0.12, 0.05


def _push(effects, tau, steps):
    m = mujoco.MjModel.from_xml_string(_FREE)
    p = Plant(m, effects)
    p.reset(ctrl=np.array([tau]))
    out = []
    for _ in range(steps):
        p.step(np.array([tau]), 1)
        out.append((float(p.qpos[0]), float(p.qvel[0])))
    return m, np.array(out)


def test_stribeck_holds_below_the_breakaway_without_creep_and_slides_at_coulomb_above():
    e = [AppliedEffect("stribeck_friction", ("j",),
                       {"coulomb": FC, "static": FS_EXTRA, "velocity": VS})]
    _, held = _push(e, 0.9 * (FC + FS_EXTRA), 500)       # 1 s at 90 % of the breakaway
    assert np.abs(held[:, 0]).max() < 1e-3                  # sticks: under a mrad in 1 s
    m, slid = _push(e, 1.2 * (FC + FS_EXTRA), 500)
    inertia = float(m.dof_armature[0] + m.body_inertia[1, 2])
    v = slid[:, 1]
    fast = np.flatnonzero(v > 20 * VS)
    acc = np.diff(v[fast]) / 0.002
    assert np.median(acc) == pytest.approx((1.2 * (FC + FS_EXTRA) - FC) / inertia, rel=0.03)
    # at the default (soft) friction constraint the same level creeps: what the stiff one fixes
    _, soft = _push([AppliedEffect("coulomb_friction", ("j",), {"frictionloss": FC + FS_EXTRA})],
                    0.9 * (FC + FS_EXTRA), 500)
    assert np.abs(soft[:, 0]).max() > 10 * np.abs(held[:, 0]).max()


def test_stribeck_null_is_the_nominal_model_and_stiffens_only_its_joints():
    m = mujoco.MjModel.from_xml_string(_FREE)
    null = Plant(m, [AppliedEffect("stribeck_friction", ("j",))])
    np.testing.assert_array_equal(null.model.dof_solref, m.dof_solref)
    np.testing.assert_array_equal(null.model.dof_solimp, m.dof_solimp)
    on = Plant(m, [AppliedEffect("stribeck_friction", ("j",), {"coulomb": 0.05})])
    assert on.model.dof_solimp[0, 0] == pytest.approx(0.999)
    assert m.dof_solimp[0, 0] != pytest.approx(0.999)


# ------------------------------------------------------------ backlash read across the play
# Physics written out: a massless motor body on hinge j (armature, damping) carrying a hanging
# 0.3 kg link on a play hinge limited to +-w/2. The servo's position loop reads the OUTPUT
# shaft (motor + play): torque = kp (goal - (q + p)) - kv (qd + pd), applied to the motor only
# (a plain ``motor`` actuator driven from Python every step, as a firmware would).
_PLAY_OUT = """
<mujoco><compiler angle="radian"/><option timestep="0.002"/>
  <worldbody><body name="motor"><joint name="j" axis="1 0 0" damping="0.1" armature="0.01"/>
    <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>
    <body name="link"><joint name="play" axis="1 0 0" limited="true" range="-0.02 0.02"
                             solreflimit="0.004 1"/>
      <geom type="sphere" pos="0 0 -0.1" size="0.01" mass="0.3"/></body></body></worldbody>
  <actuator><motor joint="j" gear="1"/></actuator>
</mujoco>"""
_ARM = """
<mujoco><option timestep="0.002"/>
  <worldbody><body><joint name="j" axis="1 0 0" damping="0.1" armature="0.01"/>
    <geom type="sphere" pos="0 0 -0.1" size="0.01" mass="0.3"/></body></worldbody>
  <actuator><position joint="j" kp="4" kv="0.3"/></actuator>
</mujoco>"""


def test_backlash_read_on_the_output_shaft_matches_a_loop_closed_across_the_play():
    from lowcostdex.sim.plant import prepare_spec

    kp, kv, q0 = 4.0, 0.3, 0.3
    ref_m = mujoco.MjModel.from_xml_string(_PLAY_OUT)
    ref = mujoco.MjData(ref_m)
    ref.qpos[:] = [q0 + 0.02, -0.02]
    mujoco.mj_forward(ref_m, ref)
    spec = mujoco.MjSpec.from_string(_ARM)
    eff = [AppliedEffect("backlash", ("j",), {"width": 0.04, "sensor": 1.0})]
    prepare_spec(spec, eff, hidden_dofs=True)
    p = Plant(spec.compile(), eff)
    p.reset(qpos=np.r_[q0, 0.0], ctrl=np.array([q0]))
    goals = np.r_[np.full(300, q0), q0 + 0.6 * np.sign(np.sin(np.arange(900) * 0.02))]
    err = []
    for g in goals:
        link, rate = ref.qpos[0] + ref.qpos[1], ref.qvel[0] + ref.qvel[1]
        ref.ctrl[0] = kp * (g - link) - kv * rate
        mujoco.mj_step(ref_m, ref)
        p.step(np.array([g]), 1)
        err.append(float(p.measured_qpos()[0]) - (ref.qpos[0] + ref.qpos[1]))
    assert np.max(np.abs(err)) < 5e-4
    # held at rest the OUTPUT sits where its own gravity balances the loop: kp (goal - link) =
    # m g l sin(link), wherever the play leans (a motor-side loop is off by half the play)
    for _ in range(1500):
        p.step(np.array([q0]), 1)
    link = float(p.measured_qpos()[0])
    assert kp * (q0 - link) == pytest.approx(0.3 * 9.81 * 0.1 * np.sin(link), rel=0.02)
    motor_side = Plant(spec.compile(), [AppliedEffect("backlash", ("j",), {"width": 0.04})])
    motor_side.reset(qpos=np.r_[q0, 0.0], ctrl=np.array([q0]))
    for _ in range(1500):
        motor_side.step(np.array([q0]), 1)
    assert float(motor_side.measured_qpos()[0]) == pytest.approx(link - 0.02, abs=2e-3)
