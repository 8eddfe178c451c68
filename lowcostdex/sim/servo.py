"""The one servo model: a Dynamixel-style position servo as a MuJoCo ``dcmotor`` actuator.

A Dynamixel X-series servo in position mode runs a firmware PID in device units whose output is a
PWM duty (limit 885 = 100 %) applied to the supply voltage; the DC motor then obeys

    v = V_s * clip(duty, +-PWM_limit/885)         (terminal voltage)      [V]
    i = (v - K * qdot) / R                        (back-EMF, no inductance) [A]
    tau = K * i                                   (output-side constants)  [N m]

with K and R referred to the output shaft (gear included). MuJoCo 4's ``dcmotor`` with
``input="pos"`` runs ``tau_cmd = kp (u - q) - kd qdot`` and drives ``v = (R/K) tau_cmd + K qdot``,
clamped at ``Vmax``. Choosing ``kd = K^2 / R`` cancels its back-EMF compensation, so

    v = (R/K) kp (u - q)   clamped at Vmax  ==  the firmware's P path, saturation included,

which is why the servo is exact, native (``mj_step(nstep=40)`` with no Python per substep) and
batchable: every gain lives in ``actuator_gainprm`` and ``mujoco.batch`` can expand it per sim.
The thermal sub-model (winding temperature state, R rising 0.39 %/K) and LuGre friction are the
dcmotor's own. Torque off (free-wheeling H-bridge) is ``forcerange = [0, 0]``.

Motor specs are data (``MOTORS``), not code: a D'Claw may carry XH430 or XM430 servos.

Units: SI inside (rad, rad/s, N m, A, V, deg C); device units (ticks, PWM, gain registers) only in
``ServoGains`` and the conversions below.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.motors import MOTORS as MOTORS  # the motor data lives in lowcostdex.motors
from lowcostdex.motors import TWO_PI as TWO_PI
from lowcostdex.motors import MotorSpec as MotorSpec
from lowcostdex.motors import ServoGains as ServoGains
from lowcostdex.motors import ThermalSpec as ThermalSpec
from lowcostdex.motors import motor_spec as motor_spec

# Layout of a compiled dcmotor's parameter arrays (verified against mujoco 4.0.0).
USER_SUPPLY_VOLTAGE = 0  # actuator_user column holding the servo's nominal supply [V]
GAIN_R, GAIN_K, GAIN_TEMPCOEF, GAIN_TREF, GAIN_KP, GAIN_KI, GAIN_KD, GAIN_VMAX = range(8)
DYN_TE, DYN_RTH, DYN_CTH, DYN_TAMB = 0, 2, 3, 4  # DYN_TE: electrical time constant L/R [s]
DYN_LUGRE_STIFFNESS, DYN_LUGRE_DAMPING, DYN_SLEWMAX, DYN_IMAX = 5, 6, 7, 8
BIAS_LUGRE_COULOMB, BIAS_LUGRE_STATIC, BIAS_LUGRE_STRIBECK = 3, 4, 5
DCMOTOR_INPUT_POS = 1  # MjsActuator.ctrlspec bit for input="pos" (vel 2, ff 4, voltage 8)




@dataclass(frozen=True)
class DcmotorParams:
    """Everything a dcmotor actuator needs, in SI units (output side)."""

    resistance: float
    motorconst: float
    kp: float
    ki: float
    kd: float
    vmax: float
    slewmax: float
    armature: float
    thermal: ThermalSpec
    supply_voltage: float

    def controller(self) -> list[float]:
        return [self.kp, self.ki, self.kd, self.slewmax, 0.0, self.vmax]

    def thermal_attr(self) -> list[float]:
        t = self.thermal
        return [t.resistance, t.capacitance, 0.0, t.tempcoef, t.ambient, t.ambient]


def dcmotor_params(motor: MotorSpec, gains: ServoGains = ServoGains()) -> DcmotorParams:
    """Map a motor and its control-table gains to dcmotor parameters.

    The voltage gains of the firmware (V per rad of error) become torque gains by K/R, and
    ``kd`` gains K^2/R to cancel the dcmotor controller's back-EMF compensation (module doc).
    """
    vs = motor.voltage if gains.supply_voltage is None else gains.supply_voltage
    k, r = motor.motorconst, motor.resistance
    to_torque = k / r
    kp = vs * motor.error_gain * gains.position_p * to_torque
    ki = vs * motor.i_error_gain * gains.position_i * to_torque
    kd = k * k / r + vs * motor.d_error_gain * gains.position_d * to_torque
    vmax = vs * gains.pwm_limit / motor.pwm_max
    slew = gains.profile_velocity * motor.velocity_unit
    return DcmotorParams(r, k, kp, ki, kd, vmax, slew, motor.armature, motor.thermal, vs)


def add_servo(
    spec: mujoco.MjSpec,
    joint: str,
    motor: MotorSpec,
    gains: ServoGains = ServoGains(),
    *,
    name: str | None = None,
    ctrlrange: tuple[float, float] | None = None,
    thermal: bool = True,
) -> mujoco.MjsActuator:
    """Add a position-mode servo driving ``joint`` to ``spec`` as a dcmotor actuator.

    The motor's reflected rotor inertia is added to the joint's armature.

    Args:
      spec: the model being built.
      joint: name of the hinge the servo drives.
      motor: the servo model.
      gains: control-table gains in device units.
      name: actuator name (default: the joint's name).
      ctrlrange: goal-position range [rad]; None leaves ctrl unlimited.
      thermal: include the winding thermal state (one activation per servo).
    """
    p = dcmotor_params(motor, gains)
    j = spec.joint(joint)
    j.armature = j.armature + p.armature
    act = spec.add_actuator()
    act.name = name or joint
    act.target = joint
    act.trntype = mujoco.mjtTrn.mjTRN_JOINT
    act.set_to_dcmotor(
        resistance=p.resistance,
        motorconst=[p.motorconst, p.motorconst],
        controller=p.controller(),
        thermal=p.thermal_attr() if thermal else [0.0] * 6,
        ctrlspec=DCMOTOR_INPUT_POS,
    )
    act.userdata = [p.supply_voltage]
    if ctrlrange is not None:
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = list(ctrlrange)
    return act


def servo_actuator_ids(model: mujoco.MjModel) -> np.ndarray:
    """Indices of the dcmotor actuators in ``model``."""
    return np.flatnonzero(model.actuator_gaintype == mujoco.mjtGain.mjGAIN_DCMOTOR)


def motor_current(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Winding current of every actuator [A] (tau / K; 0 for non-dcmotor actuators)."""
    k = model.actuator_gainprm[:, GAIN_K]
    with np.errstate(divide="ignore", invalid="ignore"):
        cur = np.where(k > 0, data.actuator_force / np.where(k > 0, k, 1.0), 0.0)
    return cur


ACT_CURRENT, ACT_INTEGRATOR, ACT_THERMAL, ACT_LUGRE, ACT_SLEW = range(5)
KI_MIN = 1e-12  # smallest ki written at run time to a dcmotor compiled with an integrator state


def dcmotor_act_layout(model: mujoco.MjModel) -> np.ndarray:
    """Activation index of each dcmotor state, shape (nu, 5), -1 where absent.

    Columns (``ACT_*``): armature current (inductance), PID integrator (compiled with ki > 0),
    winding temperature rise (thermal), LuGre bristle deflection, and the rate-limited setpoint
    (compiled with slewmax > 0). Order in ``act``: setpoint, then current, integrator, thermal,
    LuGre (setpoint before integrator before thermal verified against mujoco 4.0.0). The
    integrator exists when the actuator was *compiled* with ki > 0, whatever ki holds at run
    time, so it is inferred from the activation count.
    """
    dyn = model.actuator_dynprm
    adr = model.actuator_actadr
    dc = (model.actuator_gaintype == mujoco.mjtGain.mjGAIN_DCMOTOR) & (adr >= 0)
    cur, th, lu = dyn[:, DYN_TE] > 0, dyn[:, DYN_CTH] > 0, dyn[:, DYN_LUGRE_STIFFNESS] > 0
    slew = dyn[:, DYN_SLEWMAX] > 0
    integ = (model.actuator_actnum - cur - th - lu - slew) == 1
    out = np.full((model.nu, 5), -1, dtype=int)
    k = adr.copy()
    for col, has in ((ACT_SLEW, slew), (ACT_CURRENT, cur), (ACT_INTEGRATOR, integ),
                     (ACT_THERMAL, th), (ACT_LUGRE, lu)):
        sel = dc & has
        out[sel, col] = k[sel]
        k += has
    return out


def winding_temperature(model: mujoco.MjModel, data: mujoco.MjData,
                        layout: np.ndarray | None = None) -> np.ndarray:
    """Winding temperature of every actuator [deg C]; ambient when it has no thermal state.

    dcmotor's thermal activation is the rise over ambient; ``dcmotor_act_layout`` locates it (it
    follows the integrator state when the servo was compiled with an I gain). Pass that layout
    to skip recomputing it in a loop.
    """
    dyn = model.actuator_dynprm
    temp = dyn[:, DYN_TAMB].copy()
    if layout is not None:
        idx = layout[:, ACT_THERMAL]
    else:  # thermal state = actadr + (current state) + (integrator state)
        adr, th = model.actuator_actadr, dyn[:, DYN_CTH] > 0
        if not np.any(th):
            return temp
        before = model.actuator_actnum - th - (dyn[:, DYN_LUGRE_STIFFNESS] > 0)
        idx = np.where(th & (adr >= 0), adr + before, -1)
    has = idx >= 0
    temp[has] += data.act[idx[has]]
    return temp


def set_torque_enabled(model: mujoco.MjModel, actuators: np.ndarray | list[int], enabled: bool,
                       limits: np.ndarray | None = None) -> None:
    """Torque on/off for servos: off is a free-wheeling bridge, i.e. zero actuator force.

    Args:
      model: the model to edit in place.
      actuators: actuator indices.
      enabled: True restores ``limits`` (or unlimited), False clamps the force to [0, 0].
      limits: (n, 2) force ranges to restore when enabling; None means unlimited.
    """
    idx = np.asarray(actuators, dtype=int)
    if enabled:
        if limits is None:
            model.actuator_forcelimited[idx] = 0
            model.actuator_forcerange[idx] = 0.0
        else:
            model.actuator_forcerange[idx] = limits
            model.actuator_forcelimited[idx] = np.any(limits != 0, axis=-1)
    else:
        model.actuator_forcelimited[idx] = 1
        model.actuator_forcerange[idx] = 0.0
