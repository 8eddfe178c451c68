"""``supply_resistance``: a resistance ahead of a dcmotor servo's H-bridge, checked against the
motor's equations written out here (bridge voltage V - r d i, the winding sees d (V - r d i), so
i (R + r d^2) = d V - K w) on a pendulum and a spinning rotor; batched values equal single runs;
a torque-off servo stays limp."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.sim import servo
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.models.bench import BenchConfig, build_bench
from lowcostdex.sim.plant import BatchPlant, Plant

MASS, LENGTH, SUPPLY, G = 0.49, 0.1, 7.4, 9.81  # Rhoban's XL330 bench (ref 07), g as in MuJoCo


def bench(p_gain=400, gravity=True, damping=0.05):
    m = build_bench(BenchConfig(mass=MASS, length=LENGTH, supply=SUPPLY, damping=damping,
                                gains=servo.ServoGains(position_p=p_gain))).compile()
    if not gravity:
        m.opt.gravity[:] = 0.0
    joint = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, 0)
    return m, joint


def settle(plant, goal, steps):
    plant.reset()
    for _ in range(steps):
        plant.step(np.atleast_1d(goal), 1)
    return plant


def sr(joint, r):
    return [AppliedEffect("supply_resistance", (joint,), {"resistance": np.array([r])})]


def motor(m):
    """(R, K, duty per rad of error) of the compiled XL330 servo, from its datasheet numbers
    (e-Manual XL330-M288-T: 0.52 N m stall and 103 rev/min no load at 5.0 V; BAM's firmware
    duty per (P unit x rad) (4096 / 2 pi) / (256 x 885), reference 08) -- checked against
    what the model compiled."""
    k = 5.0 / (103 * 2 * math.pi / 60)
    r = 5.0 * k / 0.52
    np.testing.assert_allclose(m.actuator_gainprm[0, servo.GAIN_R], r, rtol=1e-6)
    np.testing.assert_allclose(m.actuator_gainprm[0, servo.GAIN_K], k, rtol=1e-6)
    return r, k, (4096 / (2 * math.pi)) / (256 * 885)


@pytest.mark.parametrize("r_s", [3.0, 5.0])
def test_full_duty_stall_holds_the_load_the_bridge_drop_allows(r_s):
    # goal far above: the firmware duty is 1; at rest i = V / (R + r), the arm stops where
    # m g l sin q = K V / (R + r) (no friction; the damping acts only while it moves)
    m, j = bench(p_gain=800)
    res, k, _ = motor(m)
    p = settle(Plant(m, sr(j, r_s)), 2.5, 3000)
    want = math.asin(k * SUPPLY / (res + r_s) / (MASS * G * LENGTH))
    assert abs(p.qvel[0]) < 1e-4
    assert p.qpos[0] == pytest.approx(want, abs=2e-3)


def test_part_duty_hold_solves_the_p_law_with_the_drop():
    # a goal the servo holds below saturation: duty d = e_g kp (goal - q) < 1 and
    # m g l sin q = K d V / (R + r d^2) at rest; solved here by bisection on q
    m, j = bench(p_gain=200)
    res, k, eg = motor(m)
    r_s, goal, kp = 5.0, 1.5, 200

    def gap(q):
        d = eg * kp * (goal - q)
        return MASS * G * LENGTH * math.sin(q) - k * d * SUPPLY / (res + r_s * d * d)

    lo, hi = 0.0, goal
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if gap(mid) < 0 else (lo, mid)
    d_eq = eg * kp * (goal - lo)
    assert 0.2 < d_eq < 0.9  # a part duty: the d^2 law, not the stall end
    p = settle(Plant(m, sr(j, r_s)), goal, 4000)
    base = settle(Plant(m), goal, 4000)
    assert p.qpos[0] == pytest.approx(lo, abs=2e-3)
    assert base.qpos[0] - p.qpos[0] > 0.05  # the drop is visible at this duty (0.76 -> 0.66)


def test_spinning_rotor_terminal_speed_has_the_drop_in_its_current():
    # no gravity, viscous damping b, goal far ahead (d = 1): b w = K (V - K w) / (R + r), so
    # w = K V / (b (R + r) + K^2); without the resistance K V / (b R + K^2)
    b, r_s = 0.05, 3.0
    m, j = bench(p_gain=800, gravity=False, damping=b)
    res, k, _ = motor(m)
    p = Plant(m, sr(j, r_s))
    p.reset()
    for _ in range(800):  # 2 s: the speed settles in ~0.1 s; the goal stays ahead
        p.step(np.array([p.qpos[0] + 10.0]), 1)
    assert p.qvel[0] == pytest.approx(k * SUPPLY / (b * (res + r_s) + k * k), rel=2e-3)
    assert k * SUPPLY / (b * res + k * k) - p.qvel[0] > 1.0  # far from the no-drop speed


def test_batch_values_equal_single_runs_and_torque_off_is_limp():
    m, j = bench(p_gain=800)
    vals = [0.0, 2.0, 4.0]
    bp = BatchPlant(m, len(vals), sr(j, vals[1]), nthread=1)
    bp.set_effects([sr(j, v) for v in vals])
    bp.reset()
    for _ in range(400):
        bp.step(np.full((len(vals), 1), 2.5), 1)
    for i, v in enumerate(vals):
        one = settle(Plant(m, sr(j, v) if v else []), 2.5, 400)
        np.testing.assert_allclose(bp.qpos[i], one.qpos, atol=1e-9)
    # torque off: no drive whatever the resistance (the arm swings back to hanging)
    p = Plant(m, sr(j, 4.0))
    p.reset()
    p.qpos[0] = 0.8
    mujoco.mj_forward(p.model, p.data)
    p.set_torque_enabled([0], False)
    for _ in range(4000):
        p.step(np.array([2.5]), 1)
    assert abs(p.qpos[0]) < 0.02


@pytest.mark.parametrize("period", [0.0, 0.005, 0.01])
def test_a_sagging_supply_lasts_the_control_period_under_a_servo_period(period):
    """A servo compiled for a 5.0 V supply is the truth for the 7.4 V servo whose measured
    supply reads 5.0 V (voltage_sag, weight 1), also when the firmware samples its law every
    ``period`` (session 20: each servo update restored the unsagged firmware gains until the next
    control step: 0.106 rad apart at a 2-step period, nearly the 0.133 of no sag at all)."""
    def run(supply, effects, channels):
        m = build_bench(BenchConfig(mass=MASS, length=LENGTH, supply=supply, damping=0.05,
                                    gains=servo.ServoGains(position_p=400))).compile()
        p = Plant(m, effects(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, 0)),
                  servo_period=period)
        p.reset()
        out = []
        for k in range(100):
            p.step(np.array([0.8 if k > 10 else 0.0]), 10, channels=channels)
            out.append(p.qpos[0])
        return np.array(out)

    truth = run(5.0, lambda j: [], None)
    sag = run(SUPPLY, lambda j: [AppliedEffect("voltage_sag", (j,), {"weight": np.array([1.0])})],
              {"voltage": np.array([5.0])})
    unsagged = run(SUPPLY, lambda j: [], None)
    assert np.max(np.abs(sag - truth)) < 1e-9
    assert np.max(np.abs(unsagged - truth)) > 0.05  # the sag matters at this load
