"""Effects real servos need on a pendulum bench (issue 11, real logs), each checked against the
bench physics written out here: a mounting offset between the servo's encoder and the joint, the
motor's torque per volt, and gear-train friction that keeps acting when the servo is back-driven
with the torque off."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.sim import servo
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig, build_bench
from lowcostdex.sim.plant import Plant

G = 9.81  # MuJoCo's default gravity [m/s^2]
MASS, LENGTH = 0.3, 0.1  # point load [kg] at [m]: gravity torque amplitude M g L = 0.294 N m
MGL = MASS * G * LENGTH


def E(name, **values):
    return AppliedEffect(name, (BENCH_JOINT,), values)


def bench(effects=(), p_gain=400, supply=5.0, timestep=0.001):
    cfg = BenchConfig(motor="XL330-M288", mass=MASS, length=LENGTH, timestep=timestep,
                      gains=servo.ServoGains(position_p=p_gain, supply_voltage=supply))
    return Plant(build_bench(cfg).compile(), effects), cfg


def hold(plant, goal, seconds, q0=0.0, qd0=0.0, torque=True):
    plant.reset(qpos=np.array([q0]), qvel=np.array([qd0]))
    if not torque:
        plant.set_torque_enabled([0], False)
    n = int(round(seconds / plant.model.opt.timestep))
    qs = np.empty(n)
    for k in range(n):
        plant.step(np.array([goal]), 1)
        qs[k] = plant.qpos[0]
    return qs


def test_mounting_offset_the_servo_holds_its_reading_gravity_acts_on_the_joint():
    off = 0.08
    p, _ = bench([E("mounting_offset", offset=off)], p_gain=2000)
    q = hold(p, 0.0, 2.0)
    # the servo holds its own reading (q + off) at the goal against gravity; the joint sits
    # near -off, where the bench's gravity torque -M g L sin(q) pushes back towards hanging
    reading = p.measured_qpos()[0]
    assert q[-1] == pytest.approx(reading - off, abs=1e-12)
    assert abs(reading) < 0.01 and q[-1] == pytest.approx(-off, abs=0.01)
    # torque off: the arm hangs at q = 0 and the encoder reads the offset
    q = hold(p, 0.0, 3.0, q0=0.0, torque=False)
    assert abs(q[-1]) < 1e-6 and p.measured_qpos()[0] == pytest.approx(off, abs=1e-6)


@pytest.mark.parametrize("scale", [1.0, 0.6])
def test_motor_strength_scales_the_stall_torque(scale):
    # a goal far above the arm saturates the drive voltage; at rest the servo delivers its
    # stall torque K Vmax / R (times the scale) and the arm settles where gravity equals it
    p, cfg = bench([E("motor_strength", scale=scale)], supply=2.0)
    m = cfg.motor_spec
    stall = m.motorconst * 2.0 / m.resistance * scale
    assert stall < MGL
    q = hold(p, math.pi, 4.0, q0=0.0)
    assert q[-1] == pytest.approx(math.asin(stall / MGL), abs=2e-3)


def _amplitude_after_half_swing(a0: float, mu: float) -> float:
    """Energy balance of a pendulum released from rest at a0 with dry friction mu |tau_g|:
    M g L (cos a1 - cos a0) = mu M g L ((1 - cos a0) + (1 - cos a1))."""
    return math.acos(1.0 - (1.0 - mu) / (1.0 + mu) * (1.0 - math.cos(a0)))


def _first_turn(q: np.ndarray) -> float:
    """|q| where the released arm first stops and turns back (after passing the bottom)."""
    dq = np.diff(q)
    k = int(np.argmax(dq[1:] * dq[:-1] < 0)) + 1
    return abs(q[k])


def test_gearbox_friction_acts_on_a_back_driven_gearbox_with_the_torque_off():
    a0, mu = 1.0, 0.15
    free = _first_turn(hold(bench()[0], 0.0, 2.0, q0=a0, torque=False))
    assert free == pytest.approx(a0, abs=0.01)  # frictionless bench: swings back to a0
    # the motor torque is zero with the torque off: friction on it alone changes nothing
    motor_only = hold(bench([E("load_dependent_friction", mu=0.3)])[0], 0.0, 2.0, q0=a0,
                      torque=False)
    assert _first_turn(motor_only) == pytest.approx(free, abs=1e-9)
    # the gears still carry the gravity torque: friction mu |tau_g| brakes the fall
    ext = hold(bench([E("gearbox_friction", mu=mu)])[0], 0.0, 2.0, q0=a0, torque=False)
    assert _first_turn(ext) == pytest.approx(_amplitude_after_half_swing(a0, mu), abs=0.01)


def test_gearbox_friction_holding_against_gravity_carries_both_torques():
    # at rest at q0 the servo pulls up with tau_m = 1.15 M g L sin(q0) against gravity: a net
    # 0.15 M g L sin(q0) upwards. The gears carry |tau_m - tau_ext| = 2.15 M g L sin(q0), so a
    # friction share mu = 0.1 (budget 0.215) holds the arm still; on the motor torque alone
    # (load_dependent_friction, budget 0.115) it moves
    mu, q0 = 0.1, 0.5
    p, cfg = bench([E("gearbox_friction", mu=mu)], p_gain=200)
    kp = servo.dcmotor_params(cfg.motor_spec, cfg.servo_gains()).kp
    goal = q0 + 1.15 * MGL * math.sin(q0) / kp
    assert np.max(np.abs(hold(p, goal, 1.0, q0=q0) - q0)) < 1e-4
    p, _ = bench([E("load_dependent_friction", mu=mu)], p_gain=200)
    assert hold(p, goal, 1.0, q0=q0)[-1] - q0 > 5e-3


def test_gearbox_friction_backdrive_share_scales_the_load_side_torque_only():
    # BAM's directional gearbox (M5): friction mu |tau_m - backdrive tau_ext|. With the torque
    # off only the load side drives the gears: the fall is braked as by a share mu backdrive
    a0, mu, r = 1.0, 0.3, 0.5
    ext = hold(bench([E("gearbox_friction", mu=mu, backdrive=r)])[0], 0.0, 2.0, q0=a0,
               torque=False)
    assert _first_turn(ext) == pytest.approx(_amplitude_after_half_swing(a0, mu * r), abs=0.01)


@pytest.mark.parametrize("r", [0.5, 0.2, 0.0])
def test_gearbox_friction_backdrive_share_sets_the_holding_budget(r):
    # at rest at q0 the servo pulls up with tau_m = 1.15 M g L sin(q0) against gravity
    # tau_ext = -M g L sin(q0): a net 0.15 M g L sin(q0) upwards, against a friction budget
    # mu (1.15 + r) M g L sin(q0). With mu = 0.1 it holds for r = 0.5 (0.165 > 0.15); for r =
    # 0.2 and 0 (0.135, 0.115) the arm slides up past the angle q1 where the drive has fallen
    # to the budget, kp (goal - q1) - M g L sin(q1) = mu (kp (goal - q1) + r M g L sin(q1)),
    # and stops before twice that distance (a released spring against dry friction)
    mu, q0 = 0.1, 0.5
    p, cfg = bench([E("gearbox_friction", mu=mu, backdrive=r)], p_gain=200)
    kp = servo.dcmotor_params(cfg.motor_spec, cfg.servo_gains()).kp
    goal = q0 + 1.15 * MGL * math.sin(q0) / kp
    q = hold(p, goal, 1.0, q0=q0)
    if r == 0.5:
        assert np.max(np.abs(q - q0)) < 1e-4
        return
    lo, hi = q0, goal  # bisection on the drive - budget balance
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        net = (kp * (goal - mid) - MGL * math.sin(mid)
               - mu * (kp * (goal - mid) + r * MGL * math.sin(mid)))
        lo, hi = (mid, hi) if net > 0 else (lo, mid)
    d = lo - q0
    assert d > 3e-3
    assert d < q[-1] - q0 < 2 * d


@pytest.mark.parametrize("alpha", [2.0, 8.0])
def test_gearbox_friction_stribeck_curvature(alpha):
    # BAM's Stribeck coefficient exp(-|v / v_s|^alpha): at v_s the breakaway share is down to
    # 1/e whatever alpha; at v_s / 2 it keeps exp(-0.5^alpha) (0.7788 for 2, 0.9961 for 8); the
    # gears carry |tau_m - tau_ext| = |0.2 - (-0.1)| = 0.3 N m
    from lowcostdex.sim.effects import GearboxFriction, Targets

    t = Targets(("j",), np.array([0]), np.array([0]), np.array([0]), np.array([1]))
    v = {"mu": np.array([0.1]), "static": np.array([0.4]), "velocity": np.array([0.8]),
         "backdrive": np.array([1.0]), "alpha": np.array([alpha])}
    force, ext = np.array([0.2]), np.array([-0.1])
    for qd, share in ((0.8, math.exp(-1.0)), (-0.4, {2.0: 0.7788008, 8.0: 0.9961014}[alpha]),
                      (0.0, 1.0)):
        got = GearboxFriction.friction(t, v, np.array([qd]), force, ext)[0]
        assert got == pytest.approx(0.3 * (0.1 + 0.4 * share), rel=1e-6)


# ------------------------------------------------------------------------------------------------
# backdriven_friction: the gear train's own friction law while the torque is off (issue 11)


def test_backdriven_friction_coulomb_brakes_the_released_arm_as_its_energy_balance_says():
    # released from rest at a0 with the torque off, a constant Coulomb torque c takes
    # c (a0 + a1) of the arm's potential energy by the first turn at -a1:
    # M g L (cos a1 - cos a0) = c (a0 + a1), solved here by bisection
    a0, c = 1.0, 0.03
    turn = _first_turn(hold(bench([E("backdriven_friction", coulomb=c)])[0], 0.0, 2.0, q0=a0,
                            torque=False))
    lo, hi = 0.0, a0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        left = MGL * (math.cos(mid) - math.cos(a0)) - c * (a0 + mid)
        lo, hi = (mid, hi) if left > 0 else (lo, mid)
    assert turn == pytest.approx(lo, abs=0.01)
    assert lo < a0 - 0.15  # the braking is large enough to tell


def test_backdriven_friction_coulomb_and_viscous_stop_a_coasting_rotor_where_the_ode_says():
    # a gravity-free hinge coasting at v0 with the torque off: I dv/dt = -(c + b v) (plus the
    # model's own joint damping d0 and dry friction f0, read from it), so
    # v(t) = (v0 + C/B) exp(-B t / I) - C/B (B = b + d0, C = c + f0), and it stops after
    # travelling (I / B) (v0 - (C / B) ln(1 + B v0 / C))
    import mujoco

    from tests.conftest import hinge_servo_model

    model = hinge_servo_model("XL330-M288", thermal=False)
    d = mujoco.MjData(model)
    mujoco.mj_forward(model, d)
    unit, col = np.zeros(model.nv), np.zeros(model.nv)
    unit[0] = 1.0
    mujoco.mj_mulM(model, d, col, unit)  # the joint's inertia, armature included [kg m^2]
    inertia = float(col[0])
    v0, c, b = 3.0, 0.004, 0.0005
    big_c, big_b = c + float(model.dof_frictionloss[0]), b + float(model.dof_damping[0])
    tau = inertia / big_b  # [s]
    stop = tau * math.log(1.0 + big_b * v0 / big_c)
    travel = tau * (v0 - big_c / big_b * math.log(1.0 + big_b * v0 / big_c))
    p = Plant(model, [AppliedEffect("backdriven_friction", ("j",),
                                    {"coulomb": c, "viscous": b})])
    p.reset(qpos=np.array([0.0]), qvel=np.array([v0]))
    p.set_torque_enabled([0], False)
    dt = model.opt.timestep
    n = int(round(1.5 * stop / dt))
    q = np.empty(n)
    for k in range(n):
        p.step(np.array([0.0]), 1)
        q[k] = p.qpos[0]
    assert q[-1] == pytest.approx(travel, rel=0.03)
    # halfway to the stop it has covered what the ODE says too
    k = int(round(0.5 * stop / dt)) - 1
    t = (k + 1) * dt
    half = (tau * (v0 + big_c / big_b) * (1.0 - math.exp(-t / tau)) - big_c / big_b * t)
    assert q[k] == pytest.approx(half, rel=0.03)
    # the viscous part shapes the stop: Coulomb alone would coast I v0^2 / (2 C) (0.74 rad)
    assert abs(q[-1] - inertia * v0 ** 2 / (2 * big_c)) > 0.1 * travel


def test_backdriven_friction_joint_share_drops_the_joints_own_friction_only_with_torque_off():
    # ``joint`` 0: the law is the back-driven joint's whole friction; the joint's own extra
    # Coulomb level and damping (coulomb_friction, viscous_damping: fitted with the torque on,
    # where a firmware D term or the drive can stand in for them) act only while the torque is
    # on. Truth: the bench without those effects (torque off) and with them (torque on).
    a0 = 1.0
    own = [E("coulomb_friction", frictionloss=0.02), E("viscous_damping", damping=0.005)]
    drop = E("backdriven_friction", coulomb=0.0, viscous=0.0, gear=1.0, joint=0.0)
    bare = hold(bench()[0], 0.0, 2.0, q0=a0, torque=False)
    p = bench(own + [drop])[0]
    off = hold(p, 0.0, 2.0, q0=a0, torque=False)
    np.testing.assert_allclose(off, bare, atol=1e-9)
    kept = hold(bench(own)[0], 0.0, 2.0, q0=a0, torque=False)
    assert _first_turn(kept) < _first_turn(bare) - 0.2  # the friction dropped is large
    # torque on again: the joint's own friction is back, exactly as without the law
    p.set_torque_enabled([0], True)
    np.testing.assert_allclose(hold(p, 0.3, 1.0), hold(bench(own)[0], 0.3, 1.0), atol=1e-12)
    # half the share: the first turn between the two, by the energy balance of the half level
    half = hold(bench(own + [E("backdriven_friction", coulomb=0.0, viscous=0.0, gear=1.0,
                                joint=0.5)])[0], 0.0, 2.0, q0=a0, torque=False)
    assert _first_turn(kept) < _first_turn(half) < _first_turn(bare)


def test_backdriven_friction_acts_only_with_the_torque_off_and_sets_the_gear_share_there():
    a0, mu = 1.0, 0.3
    law = E("backdriven_friction", coulomb=0.05, viscous=0.02, gear=0.0)
    # torque on: nothing changes (the servo's own laws hold the arm)
    base = hold(bench()[0], 0.3, 1.0, q0=0.0)
    on = hold(bench([law])[0], 0.3, 1.0, q0=0.0)
    np.testing.assert_allclose(on, base, atol=1e-12)
    # torque off, no Coulomb / viscous of its own: the share ``gear`` of the gear friction's
    # back-driven level mu |tau_g| is kept (1: as with the torque on; 0: none)
    for share, amp in ((0.0, a0), (0.5, _amplitude_after_half_swing(a0, mu * 0.5)),
                       (1.0, _amplitude_after_half_swing(a0, mu))):
        p = bench([E("gearbox_friction", mu=mu),
                   E("backdriven_friction", coulomb=0.0, viscous=0.0, gear=share)])[0]
        assert _first_turn(hold(p, 0.0, 2.0, q0=a0, torque=False)) == pytest.approx(amp,
                                                                                    abs=0.01)
