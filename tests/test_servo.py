"""The servo model: a Dynamixel position servo as a dcmotor, checked against its datasheet and
firmware arithmetic."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.sim import servo
from tests.conftest import hinge_servo_model


def test_static_stiffness_matches_firmware_arithmetic():
    # K_P = P/128 PWM units per tick; duty per rad = 651.9 ticks/rad * 6.25 / 885 at P = 800.
    for name, expected in (("XM430-W210", 13.8), ("XM430-W350", 18.9)):
        p = servo.dcmotor_params(servo.motor_spec(name), servo.ServoGains(position_p=800))
        assert p.kp == pytest.approx(expected, rel=0.01)
        assert p.kd == pytest.approx(p.motorconst**2 / p.resistance)
        assert p.vmax == pytest.approx(12.0)


def test_motor_constants_reproduce_datasheet():
    m = servo.motor_spec("XM430-W350")
    assert m.motorconst * 12.0 / m.resistance == pytest.approx(4.1)  # stall torque [N m]
    assert 12.0 / m.motorconst == pytest.approx(46 * 2 * math.pi / 60)  # no-load speed


def _step_response(model, goal, steps):
    d = mujoco.MjData(model)
    d.ctrl[0] = goal
    qs, vs = [], []
    for _ in range(steps):
        mujoco.mj_step(model, d)
        qs.append(d.qpos[0])
        vs.append(d.qvel[0])
    return np.array(qs), np.array(vs), d


@pytest.mark.parametrize("motor", ["XM430-W210", "XM430-W350", "XH430-W350"])
def test_large_step_is_voltage_limited_at_no_load_speed(motor):
    model = hinge_servo_model(motor, thermal=False)
    q, v, _ = _step_response(model, 2.0, 400)
    spec = servo.motor_spec(motor)
    assert v.max() == pytest.approx(spec.no_load_speed, rel=0.03)
    assert q[-1] == pytest.approx(2.0, abs=2e-3)


def test_pwm_limit_halves_the_speed_plateau():
    m = servo.motor_spec("XM430-W350")
    full = hinge_servo_model(gains=servo.ServoGains(pwm_limit=885), thermal=False)
    half = hinge_servo_model(gains=servo.ServoGains(pwm_limit=442), thermal=False)
    v_full = _step_response(full, 2.0, 200)[1].max()
    v_half = _step_response(half, 2.0, 200)[1].max()
    assert v_half / v_full == pytest.approx(442 / 885, rel=0.03)
    assert v_full == pytest.approx(m.no_load_speed, rel=0.03)


@pytest.mark.parametrize("p_gain", [200, 800])
def test_small_step_is_first_order_with_back_emf_damping(p_gain):
    # Unsaturated and with little inertia the servo is first order: c qdot = kp (u - q) with
    # c = K^2/R (back-EMF damping), so the half-rise time is ln 2 * c / kp.
    model = hinge_servo_model(gains=servo.ServoGains(position_p=p_gain), thermal=False)
    p = servo.dcmotor_params(servo.motor_spec("XM430-W350"), servo.ServoGains(position_p=p_gain))
    q = _step_response(model, 0.02, 400)[0]
    t_half = (np.argmax(q > 0.01) + 1) * model.opt.timestep
    assert t_half == pytest.approx(math.log(2) * p.kd / p.kp, rel=0.1)


def test_torque_off_is_free_wheeling():
    model = hinge_servo_model(thermal=False)
    d = mujoco.MjData(model)
    servo.set_torque_enabled(model, [0], False)
    d.ctrl[0] = 1.0
    d.qvel[0] = 2.0
    mujoco.mj_step(model, d, nstep=10)
    assert d.actuator_force[0] == 0.0
    assert d.qvel[0] == pytest.approx(2.0, rel=1e-6)  # no back-EMF braking, no drive
    servo.set_torque_enabled(model, [0], True)
    mujoco.mj_step(model, d, nstep=10)
    assert d.actuator_force[0] != 0.0


def test_stalled_servo_heats_toward_i2r_equilibrium():
    model = hinge_servo_model(thermal=True)
    # lock the joint: a huge armature makes it effectively immovable over the test
    model.dof_armature[0] = 1e6
    d = mujoco.MjData(model)
    d.ctrl[0] = 1.0  # error >> saturation: full voltage, stall current
    mujoco.mj_step(model, d, nstep=4000)  # 10 s
    m = servo.motor_spec("XM430-W350")
    temp = servo.winding_temperature(model, d)[0]
    cur = servo.motor_current(model, d)[0]
    assert cur == pytest.approx(12.0 / m.resistance, rel=0.15)  # stall current (R warms up)
    assert temp > m.thermal.ambient + 1.0
    equilibrium = m.thermal.ambient + cur**2 * m.resistance * m.thermal.resistance
    assert temp < equilibrium


def test_unknown_motor_lists_choices():
    with pytest.raises(ConfigError, match="XM430-W350"):
        servo.motor_spec("XM999")


def test_gains_validated():
    with pytest.raises(ConfigError):
        servo.ServoGains(pwm_limit=900)
    with pytest.raises(ConfigError):
        servo.ServoGains(position_p=-1)


def test_act_layout_with_a_rate_limited_setpoint():
    # Profile Velocity compiles a dcmotor slew state; it comes first in act, before the
    # integrator and the winding temperature (each read back from what it must hold)
    gains = servo.ServoGains(position_p=400, position_i=100, profile_velocity=100)
    m = hinge_servo_model("XL330-M288", gains, thermal=True)
    lay = servo.dcmotor_act_layout(m)[0]
    assert m.na == 3 and lay[servo.ACT_SLEW] == 0
    d = mujoco.MjData(m)
    d.ctrl[0] = 1.0
    for _ in range(100):
        mujoco.mj_step(m, d)
    slew = 100 * servo.motor_spec("XL330-M288").velocity_unit  # [rad/s]
    assert d.act[lay[servo.ACT_SLEW]] == pytest.approx(100 * m.opt.timestep * slew, rel=0.02)
    assert 0 < d.act[lay[servo.ACT_INTEGRATOR]] < 0.5  # integral of a sub-rad error over 0.25 s
    assert d.act[lay[servo.ACT_THERMAL]] > 0  # the winding warms
    assert servo.winding_temperature(m, d, servo.dcmotor_act_layout(m))[0] == pytest.approx(
        servo.winding_temperature(m, d)[0])
