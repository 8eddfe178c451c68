"""``deadband``: a servo's position-loop deadband, checked against statics written out here and a
plain-MuJoCo servo whose law is written in this file (force = kp sign(e) max(|e| - w, 0) - kv
qdot, e = goal - q, every physics step), on a position actuator, a torque-driven motor and a
dcmotor servo (the XL330 bench); a batch equals single runs; a null width is the nominal model.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.gap.results import GapConfig
from lowcostdex.sim import servo
from lowcostdex.sim.effects import CAUSES, EFFECTS, OPT_IN, AppliedEffect, Targets, effect
from lowcostdex.sim.models.bench import BenchConfig, build_bench
from lowcostdex.sim.plant import BatchPlant, Plant

KP, KV = 2.0, 0.05


def hinge(actuator: str, damping: float = 0.1, gravity: bool = False, dt: float = 0.001) -> str:
    """One hinge (about y) with a 0.1 kg point-like mass 0.1 m out along x, and its actuator."""
    g = "0 0 -9.81" if gravity else "0 0 0"
    return (f'<mujoco><option timestep="{dt}" gravity="{g}" integrator="implicitfast"/>'
            '<worldbody><body name="arm"><joint name="j" axis="0 1 0" armature="0.01" '
            f'damping="{damping}"/><geom type="sphere" size="0.01" pos="0.1 0 0" mass="0.1"/>'
            f'</body></worldbody><actuator>{actuator}</actuator></mujoco>')


def position(**kw) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(
        hinge(f'<position name="a" joint="j" kp="{KP}" kv="{KV}"/>', **kw))


def band(width: float, joint: str = "j") -> list[AppliedEffect]:
    return [AppliedEffect("deadband", (joint,), {"width": np.array([width])})]


def test_deadband_is_a_cause_an_analysis_fits_when_asked():
    # opt-in (``OPT_IN``): a user names it with --candidates; a default analysis offers it only
    # where its data gate shows a band (``gap.offer``, tests/test_gap_offer.py)
    assert "deadband" in EFFECTS and "deadband" in CAUSES and "deadband" in OPT_IN
    assert GapConfig(candidates=("deadband", "coulomb_friction")).candidates == (
        "deadband", "coulomb_friction")


def hold(plant, goal: float, seconds: float, q0: float = 0.0, load: float = 0.0):
    plant.reset(qpos=np.array([q0]), ctrl=np.array([goal]))
    plant.data.qfrc_applied[0] = load
    dt = plant.model.opt.timestep
    for _ in range(round(seconds / dt)):
        plant.step(np.array([goal]), 1)
    return plant


@pytest.mark.parametrize("load", [0.03, -0.03, 0.005])
def test_a_held_joint_under_a_constant_load_rests_width_plus_load_over_kp_from_its_goal(load):
    # statics: at rest the servo's force kp sign(e) max(|e| - w, 0) balances the load L, so the
    # joint sits at q = goal + sign(L) (w + |L| / kp); without the band at goal + L / kp (a small
    # load first drifts across the band: 20 mrad at L / damping = 4.8 mrad/s)
    w, goal = 0.02, 0.1
    p = hold(Plant(position(damping=1.0), band(w)), goal, 15.0, q0=goal, load=load)
    assert abs(p.qvel[0]) < 1e-6
    assert p.qpos[0] == pytest.approx(goal + math.copysign(w + abs(load) / KP, load), abs=2e-5)
    p0 = hold(Plant(position(damping=1.0)), goal, 6.0, q0=goal, load=load)
    assert p0.qpos[0] == pytest.approx(goal + load / KP, abs=2e-5)


def test_inside_the_band_an_unloaded_joint_stays_where_it_is_left_outside_it_returns_to_the_edge():
    w = 0.02
    # 15 mrad off its goal, at rest, no load: no force, it does not move (a servo without the
    # band pulls it back)
    p = hold(Plant(position(damping=1.0), band(w)), 0.0, 2.0, q0=0.015)
    assert p.qpos[0] == pytest.approx(0.015, abs=1e-9)
    assert abs(hold(Plant(position(damping=1.0)), 0.0, 2.0, q0=0.015).qpos[0]) < 1e-3
    # 50 mrad off, overdamped (damping 1.05 N m s/rad on kp 2, armature 0.011 kg m^2): it creeps
    # back to the band's edge, e -> w, and stops there
    p = hold(Plant(position(damping=1.0), band(w)), 0.0, 8.0, q0=0.05)
    assert p.qpos[0] == pytest.approx(w, abs=1e-5)


def truth(goals: np.ndarray, w: float, dt: float = 0.001) -> np.ndarray:
    """Plain MuJoCo: the pendulum on a ``motor`` whose torque this loop computes every step from
    the servo law with the band (kp sign(e) max(|e| - w, 0) - kv qdot); goals per step."""
    m = mujoco.MjModel.from_xml_string(hinge('<motor name="a" joint="j"/>', gravity=True, dt=dt))
    d = mujoco.MjData(m)
    out = np.empty(len(goals))
    for k, g in enumerate(goals):
        e = g - d.qpos[0]
        d.ctrl[0] = KP * np.sign(e) * max(abs(e) - w, 0.0) - KV * d.qvel[0]
        mujoco.mj_step(m, d)
        out[k] = d.qpos[0]
    return out


def test_a_position_servo_with_the_band_tracks_as_the_law_written_here():
    t = np.arange(3000) * 0.001
    goals = 0.3 * np.sin(2 * math.pi * 0.7 * t) + 0.2 * (t > 1.5)
    w = 0.03
    m = position(gravity=True)
    plant = Plant(m, band(w))
    plant.reset(qpos=np.zeros(1), ctrl=goals[:1])
    got = np.empty(len(goals))
    for k, g in enumerate(goals):
        plant.step(np.array([g]), 1)
        got[k] = plant.qpos[0]
    want = truth(goals, w)
    nominal = truth(goals, 0.0)
    err = np.sqrt(np.mean((got - want) ** 2))
    assert err < 1e-3, err  # kv implicit here, explicit in the truth: ~1e-4
    assert np.sqrt(np.mean((nominal - want) ** 2)) > 20 * err  # the band shows


def test_a_torque_driven_motor_loses_the_band_from_its_command():
    m = mujoco.MjModel.from_xml_string(hinge('<motor name="a" joint="j" ctrlrange="-1 1"/>'))
    p = Plant(m, band(0.01))
    for c, want in ((0.3, 0.29), (0.005, 0.0), (-0.3, -0.29), (-0.01, 0.0)):
        p.reset()
        p.step(np.array([c]), 1)
        assert p.actuator_force[0] == pytest.approx(want, abs=1e-12)


def test_a_motor_with_the_band_steps_as_plain_mujoco_on_the_banded_command():
    # the band acts on a motor's command alone: no per-physics-step hook (``live_on``), so a
    # control period of 5 physics steps is plain MuJoCo stepped 5 at once on sign(c) max(|c| -
    # w, 0), bit for bit (a position servo's band is live: its bias follows the error each step)
    m = mujoco.MjModel.from_xml_string(hinge('<motor name="a" joint="j" ctrlrange="-1 1"/>',
                                             gravity=True))
    p = Plant(m, band(0.01))
    d = mujoco.MjData(m)
    p.reset(qpos=np.array([0.2]))
    d.qpos[0] = 0.2
    mujoco.mj_forward(m, d)
    for c in 0.05 * np.sin(np.arange(200) * 0.05):
        p.step(np.array([c]), 5)
        d.ctrl[0] = math.copysign(max(abs(c) - 0.01, 0.0), c)
        mujoco.mj_step(m, d, nstep=5)
        assert p.qpos[0] == d.qpos[0] and p.qvel[0] == d.qvel[0]
    db = effect("deadband")
    width = {"width": np.array([0.01])}
    assert not db.live_on(p, Targets.resolve(m, ("j",)), width)
    pos = Plant(position(), band(0.01))
    assert db.live_on(pos, Targets.resolve(pos.model, ("j",)), width)
    assert not db.live_on(pos, Targets.resolve(pos.model, ("j",)), {"width": np.zeros(1)})


def test_a_batch_equals_single_runs_and_a_null_width_is_the_nominal_model():
    m = position(gravity=True)
    widths = (0.0, 0.02, 0.05)
    goals = 0.3 * np.sin(np.arange(800) * 0.01)
    bp = BatchPlant(m, len(widths), [band(w) for w in widths], nthread=1)
    bp.reset(qpos=np.zeros((3, 1)), ctrl=np.zeros((3, 1)))
    singles = [Plant(m, band(w)) for w in widths] + [Plant(m)]
    for p in singles:
        p.reset(qpos=np.zeros(1), ctrl=np.zeros(1))
    for g in goals:
        bp.step(np.full((3, 1), g), 1)
        for p in singles:
            p.step(np.array([g]), 1)
    for i, p in enumerate(singles[:3]):
        np.testing.assert_allclose(bp.qpos[i], p.qpos, atol=1e-12)
    np.testing.assert_array_equal(singles[0].qpos, singles[3].qpos)


MASS, LENGTH, SUPPLY, G = 0.49, 0.1, 7.4, 9.81  # Rhoban's XL330 bench (ref 07)


def test_a_dcmotor_servo_holds_its_load_width_beyond_the_p_law():
    # the XL330 bench with gravity: at rest the firmware P law on the error beyond the band
    # balances the arm, m g l sin q = kp (goal - q - w), kp the compiled torque per rad (its
    # controller kp: R/K x kp x e volts give K/R x that x ... = kp e N m at rest); solved here by
    # bisection, and the nominal servo (w = 0) the same way
    m = build_bench(BenchConfig(mass=MASS, length=LENGTH, supply=SUPPLY, damping=0.05,
                                gains=servo.ServoGains(position_p=400))).compile()
    joint = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, 0)
    kp = float(m.actuator_gainprm[0, servo.GAIN_KP])
    goal = 1.0

    def rest(w: float) -> float:
        lo, hi = 0.0, goal
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if MASS * G * LENGTH * math.sin(mid) < kp * (goal - mid - w):
                lo = mid
            else:
                hi = mid
        return lo

    for w in (0.0, 0.04):
        p = Plant(m, band(w, joint))
        p.reset(qpos=np.array([rest(w)]))
        for _ in range(4000):
            p.step(np.array([goal]), 1)
        assert abs(p.qvel[0]) < 1e-4
        assert p.qpos[0] == pytest.approx(rest(w), abs=2e-3), w
    assert rest(0.0) - rest(0.04) > 0.02
