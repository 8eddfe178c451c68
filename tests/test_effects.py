"""Effects: each named effect changes the servo's behaviour with its known signature; null values
change nothing; a batch with per-simulation values equals single simulations."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.sim import servo
from lowcostdex.sim.effects import (
    CAUSES,
    EFFECTS,
    AppliedEffect,
    DomainRandomization,
    effect,
)
from lowcostdex.sim.plant import BatchPlant, Plant, prepare_spec
from tests.conftest import hinge_spec

MOTOR = servo.motor_spec("XM430-W350")
DT = 0.0025


def make_plant(effects=(), p_gain=800, gravity=False, batch=None):
    spec = hinge_spec(gravity)
    servo.add_servo(spec, "j", MOTOR, servo.ServoGains(position_p=p_gain), thermal=False)
    prepare_spec(spec, effects)
    model = spec.compile()
    if batch:
        return BatchPlant(model, batch, effects, nthread=1)
    return Plant(model, effects)


def run(plant, goals, nstep=4, channels=None):
    """Hold each goal for nstep substeps; return the true joint angle after each hold."""
    plant.reset()
    out = []
    for g in goals:
        plant.step(np.atleast_1d(g), nstep, channels=channels)
        out.append(float(plant.qpos[0]))
    return np.array(out)


STEPS = np.r_[np.zeros(5), np.full(60, 0.4), np.full(60, -0.3), np.full(60, 0.1)]


def E(name, **values):
    return AppliedEffect(name, ("j",), values)


def test_catalogue_has_the_canonical_causes():
    assert set(CAUSES) <= set(EFFECTS)
    for name in CAUSES:
        cls = effect(name)
        for p in cls.params:
            assert p.low <= p.initial <= p.high


@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_null_values_change_nothing(name):
    cls = effect(name)
    base = run(make_plant(), STEPS)
    chans = {"temperature": np.array([60.0]), "voltage": np.array([10.0])}
    nulls = {p.name: p.null for p in cls.params}
    got = run(make_plant([E(name, **nulls)]), STEPS, channels=chans)
    np.testing.assert_allclose(got, base, atol=1e-12)


def test_latency_delays_the_response_by_the_delay():
    base = run(make_plant(), STEPS, nstep=1)
    late = run(make_plant([E("latency", delay=0.02)]), STEPS, nstep=1)
    onset = lambda q: np.argmax(np.abs(q - q[0]) > 1e-4)  # noqa: E731
    assert (onset(late) - onset(base)) * DT == pytest.approx(0.02, abs=DT)


def test_coulomb_friction_stops_short_by_f_over_kp():
    kp = servo.dcmotor_params(MOTOR, servo.ServoGains(position_p=100)).kp
    f = 0.1
    q = run(make_plant([E("coulomb_friction", frictionloss=f)], p_gain=100), [0.3] * 200)
    assert 0.3 - q[-1] == pytest.approx(f / kp, rel=0.1)


def test_backlash_without_its_play_hinge_is_a_dead_band_of_its_width():
    # the massless-motor limit (a model without hidden dofs: the emulator, env backends)
    w = 0.03
    p = make_plant([E("backlash", width=w)])
    q = run(p, np.r_[np.full(50, 0.2), np.full(50, 0.0)])
    base = run(make_plant(), np.r_[np.full(50, 0.2), np.full(50, 0.0)])
    # after the reversal the servo stops short by the half width on each side
    assert q[49] == pytest.approx(base[49] - w / 2, abs=2e-3)
    assert q[-1] == pytest.approx(base[-1] + w / 2, abs=2e-3)


_PLAY_REF = """
<mujoco><compiler angle="radian"/><option timestep="0.002"/>
  <worldbody><body name="motor"><joint name="j" axis="1 0 0" damping="0.1" armature="0.01"/>
    <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>
    <body name="link"><joint name="play" axis="1 0 0" limited="true" range="-0.02 0.02"
                             solreflimit="0.004 1"/>
      <geom type="sphere" pos="0 0 -0.1" size="0.01" mass="0.3"/></body></body></worldbody>
  <actuator><position joint="j" kp="4" kv="0.3"/></actuator>
</mujoco>"""


def test_backlash_matches_a_motor_body_and_a_play_hinged_link_written_out():
    # The physics written out in plain MJCF: a (massless) motor body carrying the rotor's
    # armature, the joint's damping and the servo; the hanging link on a hinge limited to
    # +-width/2. The plant's play hinge must reproduce its link angle, including the free
    # swings across the play on fast reversals, and rest on the lower stop under gravity.
    import mujoco

    ref_m = mujoco.MjModel.from_xml_string(_PLAY_REF)
    ref = mujoco.MjData(ref_m)
    spec = mujoco.MjSpec.from_string(_ARM.format(act='<position joint="j" kp="4" kv="0.3"/>'))
    eff = [E("backlash", width=0.04)]
    prepare_spec(spec, eff, hidden_dofs=True)
    p = Plant(spec.compile(), eff)
    q0 = 0.3
    ref.qpos[:] = [q0 + 0.02, -0.02]  # at rest the link hangs on the lower stop
    ref.ctrl[:] = q0
    mujoco.mj_forward(ref_m, ref)
    p.reset(qpos=np.r_[q0, 0.0], ctrl=np.array([q0]))
    goals = np.r_[np.full(300, q0), q0 + 0.6 * np.sign(np.sin(np.arange(900) * 0.02))]
    err = []
    for g in goals:
        ref.ctrl[:] = g
        mujoco.mj_step(ref_m, ref)
        p.step(np.array([g]), 1)
        err.append(float(p.measured_qpos()[0]) - (ref.qpos[0] + ref.qpos[1]))
    assert np.max(np.abs(err)) < 2e-4
    # at rest (a hold after the swings) the link hangs on the lower stop, 20 mrad below the motor
    for _ in range(500):
        p.step(np.array([q0]), 1)
    assert float(p.measured_qpos()[0] - p.qpos[0]) == pytest.approx(-0.02, abs=1e-4)


def test_reset_puts_a_hanging_link_on_its_lower_stop_keeping_the_reading():
    import mujoco

    spec = mujoco.MjSpec.from_string(_ARM.format(act='<position joint="j" kp="4" kv="0.3"/>'))
    eff = [E("backlash", width=0.04)]
    prepare_spec(spec, eff, hidden_dofs=True)
    p = Plant(spec.compile(), eff)
    for q in (0.5, -0.5):
        p.reset(qpos=np.r_[q, 0.0], ctrl=np.array([q]))
        # gravity pulls the link towards 0: it leans on the stop on that side
        assert float(p.measured_qpos()[0]) == pytest.approx(q)
        assert float(p.qpos[1]) == pytest.approx(-0.02 * np.sign(q))


def test_play_hinges_only_with_hidden_dofs_and_a_null_play_is_the_nominal_model():
    import mujoco

    act = '<position joint="j" kp="4" kv="0.3"/>'
    eff = [E("backlash", width=0.0)]
    plain = prepare_spec(mujoco.MjSpec.from_string(_ARM.format(act=act)), eff).compile()
    assert plain.nq == 1  # the qpos layout is kept (the emulator shares it with its task)
    hinged = prepare_spec(mujoco.MjSpec.from_string(_ARM.format(act=act)), eff,
                          hidden_dofs=True).compile()
    assert hinged.nq == 2
    ref = Plant(mujoco.MjModel.from_xml_string(_ARM.format(act=act)))
    p = Plant(hinged, eff)
    for plant in (ref, p):
        plant.reset(qpos=np.r_[0.3, np.zeros(plant.model.nq - 1)], ctrl=np.array([0.3]))
    for g in np.r_[np.full(100, 0.3), np.full(200, -0.5), np.full(200, 0.8)]:
        ref.step(np.array([g]), 1)
        p.step(np.array([g]), 1)
        assert float(p.measured_qpos()[0]) == pytest.approx(float(ref.qpos[0]), abs=1e-9)


def test_stribeck_breakaway_holds_small_steps():
    kp = servo.dcmotor_params(MOTOR, servo.ServoGains(position_p=100)).kp
    small = 0.5 * 0.05 / kp  # command error below breakaway / kp
    stuck = run(make_plant([E("stribeck_friction", static=0.05, velocity=0.1)], p_gain=100),
                [small] * 200)
    free = run(make_plant(p_gain=100), [small] * 200)
    assert abs(stuck[-1]) < 0.1 * small
    assert free[-1] == pytest.approx(small, rel=0.05)


def test_load_dependent_friction_grows_with_gravity_load():
    q0 = run(make_plant(gravity=True, p_gain=200), [0.0] * 100)
    q1 = run(make_plant([E("load_dependent_friction", mu=0.3)], gravity=True, p_gain=200),
             np.r_[np.full(60, 0.5), np.full(100, 0.0)])
    q2 = run(make_plant(gravity=True, p_gain=200), np.r_[np.full(60, 0.5), np.full(100, 0.0)])
    # the friction budget keeps the loaded joint further from its goal than without the effect
    assert abs(q1[-1]) > abs(q2[-1]) + 1e-3
    assert np.isfinite(q0).all()


def test_viscous_damping_and_gain_error_scale_the_time_constant():
    def t_half(plant):
        q = run(plant, [0.02] * 400, nstep=1)
        return (np.argmax(q > 0.01) + 1) * DT

    p = servo.dcmotor_params(MOTOR, servo.ServoGains(position_p=800))
    base = t_half(make_plant())
    assert t_half(make_plant([E("gain_error", scale=0.5)])) == pytest.approx(2 * base, rel=0.08)
    extra = 0.5 * p.kd
    assert t_half(make_plant([E("viscous_damping", damping=extra)])) == pytest.approx(
        1.5 * base, rel=0.08)


def test_torque_limit_caps_the_actuator_force():
    p = make_plant([E("torque_limit", torque=0.5)])
    p.reset()
    peak = 0.0
    for _ in range(100):
        p.step(np.array([1.0]), 1)
        peak = max(peak, abs(float(p.actuator_force[0])))
    assert peak == pytest.approx(0.5, rel=1e-6)


def _peak_speed(plant, channels=None):
    plant.reset()
    v = 0.0
    for _ in range(200):
        plant.step(np.array([2.0]), 1, channels=channels)
        v = max(v, float(plant.qvel[0]))
    return v


def test_velocity_limit_and_voltage_sag_scale_the_speed_plateau():
    base = _peak_speed(make_plant())
    assert base == pytest.approx(MOTOR.no_load_speed, rel=0.03)
    assert _peak_speed(make_plant([E("velocity_limit", scale=0.6)])) == pytest.approx(
        0.6 * base, rel=0.03)
    sag = make_plant([E("voltage_sag", weight=1.0)])
    assert _peak_speed(sag, {"voltage": np.array([9.0])}) == pytest.approx(0.75 * base, rel=0.03)


def test_thermal_derating_slows_a_hot_servo():
    hot = make_plant([E("thermal_derating", tempcoef=0.004)])
    cold_v = _peak_speed(hot, {"temperature": np.array([25.0])})
    hot_v = _peak_speed(hot, {"temperature": np.array([75.0])})
    # stall torque falls by 1/(1 + 0.004 * 50); no-load speed is unchanged, so the plateau
    # (voltage-limited) stays while the torque-limited acceleration drops
    assert hot_v == pytest.approx(cold_v, rel=0.03)
    # at stall (joint held still) the torque falls exactly by 1 + a (T - T_ref)
    hot.model.dof_armature[0] = 1e9
    torques = []
    for temp in (75.0, 25.0):
        hot.reset()
        hot.step(np.array([2.0]), 1, channels={"temperature": np.array([temp])})
        torques.append(float(hot.actuator_force[0]))
    assert torques[0] == pytest.approx(torques[1] / 1.2, rel=1e-3)


def test_exogenous_effects_require_their_channel():
    p = make_plant([E("thermal_derating", tempcoef=0.004)])
    with pytest.raises(ConfigError, match="temperature"):
        p.step(np.array([0.1]), 1)


def test_inertia_and_mass_errors_scale_model_fields():
    p = make_plant([E("inertia_error", scale=2.0), E("mass_error", scale=1.5)])
    nominal = make_plant()
    assert p.model.dof_armature[0] == pytest.approx(2 * nominal.model.dof_armature[0])
    body = nominal.model.jnt_bodyid[0]
    assert p.model.body_mass[body] == pytest.approx(1.5 * nominal.model.body_mass[body])


def test_observation_effects(rng):
    p = make_plant([E("position_offset", offset=0.05)])
    p.reset()
    assert p.measured_qpos()[0] - p.qpos[0] == pytest.approx(0.05)
    q = make_plant([E("quantization", ticks=4096)])
    q.reset(qpos=np.array([0.123456]))
    step = 2 * math.pi / 4096
    assert q.measured_qpos()[0] / step == pytest.approx(round(0.123456 / step))


def test_batch_with_per_sim_values_equals_single_plants():
    widths = [0.0, 0.02, 0.05]
    effs = [[E("backlash", width=w), E("latency", delay=0.01 * (i + 1)),
             E("coulomb_friction", frictionloss=0.02 * i)] for i, w in enumerate(widths)]
    bp = make_plant(effs[0], batch=3)
    bp.set_effects(effs)
    bp.reset()
    singles = [make_plant(e) for e in effs]
    for s in singles:
        s.reset()
    for g in STEPS:
        bp.step(np.full((3, 1), g), 4)
        for s in singles:
            s.step(np.array([g]), 4)
    np.testing.assert_array_equal(bp.qpos[:, 0], [s.qpos[0] for s in singles])


def test_applied_effect_json_round_trip_and_validation():
    e = AppliedEffect("backlash", ("a", "b"), {"width": [0.01, 0.02]})
    back = AppliedEffect.from_dict(json.loads(json.dumps(e.to_dict())))
    assert back.name == "backlash" and back.joints == ("a", "b")
    np.testing.assert_allclose(back.values["width"], [0.01, 0.02])
    with pytest.raises(ConfigError, match="coulomb_friction"):
        AppliedEffect("friction", ("a",))
    with pytest.raises(ConfigError, match="width"):
        AppliedEffect("backlash", ("a",), {"play": 0.1})


def test_domain_randomization_is_seeded_and_in_range():
    dr = DomainRandomization(("gain_error", "latency"), ("a", "b", "c"))
    s1 = dr.sample(np.random.default_rng(7))
    s2 = dr.sample(np.random.default_rng(7))
    for a, b in zip(s1, s2, strict=True):
        for k in a.values:
            np.testing.assert_array_equal(a.values[k], b.values[k])
            lo, hi = effect(a.name).param(k).dr
            assert np.all((lo <= a.values[k]) & (a.values[k] <= hi))
    narrowed = DomainRandomization(("gain_error",), ("a",), {"gain_error": {"scale": (0.9, 0.91)}})
    v = narrowed.sample(np.random.default_rng(0))[0].values["scale"]
    assert 0.9 <= v[0] <= 0.91


def test_domain_randomization_ranges_per_joint_and_json_round_trip():
    import json

    fixed = [0.01, 0.02, 0.03]
    dr = DomainRandomization(("latency", "backlash"), ("a", "b", "c"),
                             {"latency": {"delay": (fixed, fixed)},
                              "backlash": {"width": ([0.0, 0.01, 0.02], [0.001, 0.011, 0.021])}})
    back = DomainRandomization.from_dict(json.loads(json.dumps(dr.to_dict())))
    for d in (dr, back):
        lat, bl = d.sample(np.random.default_rng(3))
        np.testing.assert_array_equal(lat.values["delay"], fixed)  # low == high: held fixed
        w = bl.values["width"]
        assert np.all((np.array([0.0, 0.01, 0.02]) <= w) & (w <= [0.001, 0.011, 0.021]))
    with pytest.raises(ConfigError, match="one value per joint"):
        DomainRandomization(("latency",), ("a", "b"), {"latency": {"delay": ([0.0] * 3, 0.1)}})
    with pytest.raises(ConfigError, match="above high"):
        DomainRandomization(("latency",), ("a",), {"latency": {"delay": (0.02, 0.01)}})


def test_an_env_takes_a_randomization_mapping_with_per_joint_values():
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the ids)
    from lowcostdex.hands import dclaw_spec

    joints = dclaw_spec().joint_names
    delay = np.linspace(0.0, 0.02, len(joints))
    dr = DomainRandomization(("latency",), joints, {"latency": {"delay": (delay, delay)}})
    env = gym.make("lowcostdex/DClawTurnValve-v0", randomize=dr.to_dict())
    env.reset(seed=0)
    model = env.unwrapped.backend.plant.model
    acts = [model.actuator(j).id for j in joints]
    np.testing.assert_allclose(model.actuator_delay[acts], delay)
    env.close()


def test_latency_without_prepared_history_is_refused():
    spec = hinge_spec()
    servo.add_servo(spec, "j", MOTOR)
    with pytest.raises(ConfigError, match="prepare_spec"):
        Plant(spec.compile(), [E("latency", delay=0.02)])


# ------------------------------------------------------------------------------------------------
# standard MJCF actuators (issue 11): each effect means the same physical thing on each

_ARM = """
<mujoco><option timestep="0.002"/>
  <worldbody><body><joint name="j" axis="1 0 0" damping="0.1" armature="0.01"/>
    <geom type="sphere" pos="0 0 -0.1" size="0.01" mass="0.3"/></body></worldbody>
  <actuator>{act}</actuator>
</mujoco>"""


def _standard(act: str, effects=(), batch=None):
    import mujoco

    model = mujoco.MjModel.from_xml_string(_ARM.format(act=act))
    if batch:
        return BatchPlant(model, batch, effects, nthread=1)
    return Plant(model, effects)


def _hold(plant, goal, steps=1500):
    plant.reset()
    for _ in range(steps):
        plant.step(np.atleast_1d(goal), 1)
    return float(np.asarray(plant.qpos).ravel()[0])


def test_gain_error_scales_the_stiffness_of_a_position_actuator():
    # hanging 0.3 kg at 0.1 m held at 0.5 rad by kp = 4 N m/rad: it sags by
    # m g l sin(q) / kp (small sag), so a kp twice as stiff sags half as much
    pos = '<position joint="j" kp="4" kv="0.3"/>'
    sag = 0.5 - _hold(_standard(pos), 0.5)
    expect = 0.3 * 9.81 * 0.1 * math.sin(0.5 - sag) / 4
    assert sag == pytest.approx(expect, rel=0.02)
    sag2 = 0.5 - _hold(_standard(pos, [E("gain_error", scale=2.0)]), 0.5)
    assert sag2 == pytest.approx(0.3 * 9.81 * 0.1 * math.sin(0.5 - sag2) / 8, rel=0.02)
    # the same in a batch with per-simulation values
    bp = _standard(pos, [[E("gain_error", scale=2.0)], [E("gain_error", scale=0.5)]], batch=2)
    bp.reset()
    for _ in range(1500):
        bp.step(np.full((2, 1), 0.5), 1)
    assert 0.5 - bp.qpos[0, 0] == pytest.approx(sag2, rel=1e-6)
    assert bp.model.actuator_gainprm[0, 0] == 4.0  # the nominal copy is untouched


def test_gain_error_on_velocity_and_motor_actuators_and_velocity_limit_only_on_dcmotors():
    import mujoco

    vel = _standard('<velocity joint="j" kv="0.5"/>', [E("gain_error", scale=3.0)])
    assert vel.model.actuator_gainprm[0, 0] == pytest.approx(1.5)
    assert vel.model.actuator_biasprm[0, 2] == pytest.approx(-1.5)
    mot = _standard('<motor joint="j" gear="1"/>', [E("gain_error", scale=0.5)])
    assert mot.model.actuator_gainprm[0, 0] == pytest.approx(0.5)
    pos = _standard('<position joint="j" kp="4" kv="0.3"/>', [E("velocity_limit", scale=0.5)])
    ref = mujoco.MjModel.from_xml_string(_ARM.format(act='<position joint="j" kp="4" kv="0.3"/>'))
    np.testing.assert_array_equal(pos.model.actuator_gainprm, ref.actuator_gainprm)
    np.testing.assert_array_equal(pos.model.actuator_biasprm, ref.actuator_biasprm)


def test_torque_limit_on_a_force_limited_position_actuator():
    # null (inf): the nominal +-3 N m range stays (a batch column without the effect must not
    # lose its force); a finite limit narrows it, never widens it
    act = '<position joint="j" kp="40" forcelimited="true" forcerange="-3 3"/>'
    for effects in ([], [E("torque_limit", torque=math.inf)]):
        p = _standard(act, effects)
        np.testing.assert_array_equal(p.model.actuator_forcerange[0], [-3, 3])
        assert p.model.actuator_forcelimited[0] == 1
        p.reset()
        p.step(np.array([1.0]), 1)
        assert float(p.actuator_force[0]) == pytest.approx(3.0)
    assert _standard(act, [E("torque_limit", torque=1.0)]).model.actuator_forcerange[0, 1] == 1.0
    assert _standard(act, [E("torque_limit", torque=9.0)]).model.actuator_forcerange[0, 1] == 3.0
    bp = _standard(act, [[E("torque_limit", torque=math.inf)], [E("torque_limit", torque=1.0)]],
                   batch=2)
    bp.reset()
    bp.step(np.ones((2, 1)), 1)
    np.testing.assert_allclose(bp.actuator_force[:, 0], [3.0, 1.0])
