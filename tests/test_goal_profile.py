"""``goal_profile`` (a Dynamixel's Profile Velocity / Profile Acceleration on the goal) against a
trapezoid written out here, on every actuator kind that takes a position goal (gap-profile16).

The hand numbers: a 1 rad step at 2 rad/s and 10 rad/s^2 accelerates for v / a = 0.2 s (0.2 rad),
cruises 0.6 rad at 2 rad/s (0.3 s) and brakes 0.2 s: it reaches the goal at v / a + d / v = 0.7 s.
At 2 rad/s with acceleration 0 (a rectangle) it reaches it at 0.5 s."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.sim import servo
from lowcostdex.sim.effects import CAUSES, EFFECTS, AppliedEffect, Targets, effect
from lowcostdex.sim.effects.profile import GoalProfile, profile_step
from lowcostdex.sim.plant import BatchPlant, Plant

DT = 0.001   # physics step [s]


def trapezoid(t: np.ndarray, d: float = 1.0, v: float = 2.0, a: float = 10.0) -> np.ndarray:
    """The setpoint of a d rad move from 0 at t = 0 (d >= v^2 / a: a trapezoid), written out."""
    ta, tc = v / a, d / v - v / a          # accelerating, cruising [s]
    t_end = 2 * ta + tc
    return np.where(t < ta, 0.5 * a * t ** 2,
                    np.where(t < ta + tc, 0.5 * a * ta ** 2 + v * (t - ta),
                             np.where(t < t_end, d - 0.5 * a * (t_end - t) ** 2, d)))


def test_a_1_rad_step_at_2_rad_s_and_10_rad_s2_arrives_at_0_7_s():
    p, w, k = np.zeros(1), np.zeros(1), 0
    dt = 1e-4
    ts, ps = [], []
    while k < 9000:
        p, w = profile_step(p, w, np.ones(1), np.array([2.0]), np.array([10.0]), dt)
        k += 1
        ts.append(k * dt)
        ps.append(p[0])
    ts, ps = np.array(ts), np.array(ps)
    np.testing.assert_allclose(ps, trapezoid(ts), atol=2e-4)
    # it brakes at 10 rad/s^2 into 0.7 s: 1 mrad short of the goal at 0.7 - sqrt(2e-3 / 10)
    near = ts[np.argmax(ps >= 1.0 - 1e-3)]
    assert near == pytest.approx(0.7 - math.sqrt(2e-3 / 10.0), abs=0.002)
    assert ps[ts < 0.69].max() < 1.0 and ps[ts >= 0.7].min() == 1.0  # there at 0.7 s
    assert np.all(np.diff(ps) >= -1e-12) and ps.max() <= 1.0  # no overshoot


def test_a_rectangle_without_acceleration_and_no_profile_without_velocity():
    p, w = np.zeros(1), np.zeros(1)
    t = 0.0
    while p[0] < 1.0 and t < 2.0:
        p, w = profile_step(p, w, np.ones(1), np.array([2.0]), np.array([0.0]), 1e-3)
        t += 1e-3
    assert t == pytest.approx(0.5, abs=1.5e-3)
    for off in (0.0, math.inf):  # the register's 0 and the catalogue's null: no profile
        p, w = profile_step(np.zeros(1), np.zeros(1), np.ones(1), np.array([off]),
                            np.array([10.0]), 1e-3)
        assert p[0] == 1.0 and w[0] == 0.0


def _model(kind: str) -> mujoco.MjModel:
    """A horizontal hinge (no gravity) with inertia 0.01 kg m^2 driven by one servo ``kind``:
    a position actuator, a general actuator written as one, or the project's dcmotor servo."""
    spec = mujoco.MjSpec()
    spec.option.timestep = DT
    spec.option.gravity = [0, 0, 0]
    b = spec.worldbody.add_body(name="link")
    b.add_joint(name="j", axis=[0, 0, 1], damping=0.0)
    b.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.01], mass=0.0)
    b.mass, b.ipos, b.inertia, b.explicitinertial = 0.1, [0, 0, 0], [0.01, 0.01, 0.01], True
    if kind == "dcmotor":
        servo.add_servo(spec, "j", servo.motor_spec("XM430-W350"), thermal=False)
        return spec.compile()
    a = spec.add_actuator(name="j", target="j", trntype=mujoco.mjtTrn.mjTRN_JOINT)
    if kind == "position":
        a.set_to_position(kp=50.0, kv=2.0)
    else:  # general: force = kp ctrl - kp q - kv qdot
        a.gaintype, a.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        a.gainprm[0], a.biasprm[:3] = 50.0, [0.0, -50.0, -2.0]
    return spec.compile()


@pytest.mark.parametrize("kind", ["position", "general", "dcmotor"])
def test_every_position_goal_actuator_receives_the_trapezoid(kind):
    """A 1 rad goal step held from t = 0, control steps of 10 ms: what the servo receives over
    each step is the written-out trapezoid's mean over it (within 1 mrad: the profile's own
    steps), and the joint follows it to the goal; with no profile it receives the goal."""
    model = _model(kind)
    nstep = 10
    prof = AppliedEffect("goal_profile", ("j",), {"velocity": 2.0, "acceleration": 10.0})
    plant = Plant(model, [prof])
    plant.reset()
    ctrl, q = [], []
    for _ in range(150):
        plant.step(np.ones(1), nstep)
        ctrl.append(float(plant.ctrl[0]))
        q.append(float(plant.qpos[0]))
    t0 = np.arange(150) * nstep * DT
    fine = np.linspace(0, nstep * DT, 21)
    want = np.array([trapezoid(s + fine).mean() for s in t0])
    np.testing.assert_allclose(ctrl, want, atol=1e-3)
    assert abs(q[-1] - 1.0) < 0.01 and q[30] < 0.6  # still on its way at 0.3 s (0.4 rad)
    bare = Plant(model, [])
    bare.reset()
    bare.step(np.ones(1), nstep)
    assert bare.ctrl[0] == 1.0


def test_a_batch_carries_one_profile_per_simulation_and_a_reset_restarts_it():
    """Two simulations, 2 rad/s and off: at 0.25 s the first receives ~0.5 rad (rectangle), the
    second the goal; resetting only the first restarts its profile from the goal it holds."""
    model = _model("position")
    prof = [[AppliedEffect("goal_profile", ("j",), {"velocity": 2.0})],
            [AppliedEffect("goal_profile", ("j",), {"velocity": math.inf})]]
    plant = BatchPlant(model, 2, prof, nthread=1)
    plant.reset()
    for _ in range(25):
        plant.step(np.ones((2, 1)), 10)
    assert plant.ctrl[0, 0] == pytest.approx(0.49, abs=2e-3)  # mean over 0.24-0.25 s
    assert plant.ctrl[1, 0] == 1.0
    for _ in range(40):
        plant.step(np.ones((2, 1)), 10)
    plant.reset(ctrl=np.zeros((1, 1)) + 1.0, sims=np.array([0]))
    plant.step(np.full((2, 1), -1.0), 10)  # a new goal: 2 rad away, from the held 1.0
    assert plant.ctrl[0, 0] == pytest.approx(1.0 - 2.0 * 0.005, abs=1e-6)


def test_a_restart_mid_move_starts_the_profile_at_the_moving_joint():
    """A replay window that starts while the joint moves (faster than ``MOVING``): the profile
    starts at the joint's angle and speed (clipped to the profile velocity), not at the goal."""
    model = _model("position")
    targets = Targets.resolve(model, ("j",))
    v = {"velocity": np.array([2.0]), "acceleration": np.array([math.inf])}
    state = {"setpoint": np.array([1.0]), "dt": 0.01, "qpos": np.array([0.3]),
             "qvel": np.array([5.0])}
    got = GoalProfile.command(targets, v, np.array([1.0]), state, np.random.default_rng(0))
    assert got[0] == pytest.approx(0.3 + 0.5 * 0.02)
    assert state["position"][0] == pytest.approx(0.32) and state["speed"][0] == 2.0
    state = {"setpoint": np.array([1.0]), "dt": 0.01, "qpos": np.array([0.97]),
             "qvel": np.array([0.0])}  # at rest: the profile arrived at the held setpoint
    got = GoalProfile.command(targets, v, np.array([1.0]), state, np.random.default_rng(0))
    assert got[0] == 1.0


def test_the_catalogue_offers_it_with_wide_bounds_and_a_flagged_floor():
    """A cause with null inf (off; the register's 0 is off too), bounds 0.5-50 rad/s searched in
    log space; a fit on the 0.5 floor is flagged (it may widen to the hard limit 0.1), one on
    the 50 top is "as little profile as the search expresses" (toward the null), not flagged."""
    assert "goal_profile" in CAUSES and EFFECTS["goal_profile"] is GoalProfile
    vel = effect("goal_profile").param("velocity")
    assert (vel.null, vel.low, vel.high, vel.hard) == (math.inf, 0.5, 50.0, (0.1, 500.0))
    assert effect("goal_profile").param("acceleration").null == math.inf
    ctx = fitmod.Context(dt=0.002, peak_force=np.ones(1), stall=np.full(1, np.inf),
                         damping=np.zeros(1))
    st = fitmod.Structure.build(("goal_profile",), ("j",), ctx)
    assert [(f.param, f.log) for f in st.free] == [("velocity", True), ("acceleration", True)]
    lo, hi = st.u_bounds()
    floor = np.array([lo[0], 0.5 * (lo[1] + hi[1])])
    top = np.array([hi[0], hi[1]])
    assert fitmod.at_bounds(st, floor) == [(0, "lower")]
    assert fitmod.at_bounds(st, top) == []
