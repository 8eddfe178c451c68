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
A firmware that moves its internal goal toward a written goal at a bounded speed (Dynamixel's
Profile Velocity; a Feetech STS always, at its Running Speed: ``MotorSpec.goal_speed``) is the
dcmotor's ``slewmax``: the slewed goal is its first activation, which a reset puts at the goal the
servo holds (``goal_slew_states``), and the P law acts on it, the torque on or off.

Motor specs are data (``MOTORS``), not code: a D'Claw may carry XH430 or XM430 servos.

Units: SI inside (rad, rad/s, N m, A, V, deg C); device units (ticks, PWM, gain registers) only in
``ServoGains`` and the conversions below.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
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


def servo_supply_voltage(model: mujoco.MjModel) -> np.ndarray:
    """Nominal supply voltage of each actuator [V] (0 for non-servo actuators)."""
    if model.nuser_actuator < 1:
        return np.zeros(model.nu)
    return model.actuator_user[:, USER_SUPPLY_VOLTAGE].copy()




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
    # the firmware's goal slew: the speed written, else the motor's own (Feetech: its factory
    # maximum; Dynamixel: none). A dcmotor compiled with slewmax > 0 carries the slewed goal as
    # its first activation (``dcmotor_act_layout``; ``reset_goal_slew`` at a reset).
    slew = (gains.profile_velocity * motor.velocity_unit if gains.profile_velocity > 0
            else motor.goal_speed)
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


def dcmotor_mask(model: mujoco.MjModel, actuators: np.ndarray) -> np.ndarray:
    """(n,) bool: which of these actuators are dcmotors."""
    return model.actuator_gaintype[actuators] == int(mujoco.mjtGain.mjGAIN_DCMOTOR)


def stall_torque(model: mujoco.MjModel, actuators: np.ndarray) -> np.ndarray:
    """Stall torque K Vmax / R of dcmotor servos [N m] (inf for other actuators).

    A dcmotor written without a drive limit (``controller`` Vmax 0, MuJoCo's default) is not
    clamped: its torque kp (goal - q) grows with the error (12 N m from a 1.5 N m motor 3 rad
    off its goal). It has no stall torque: the top of its force range when it has one, else
    inf (the gap analysis then bounds dry friction by its hard limit, not at 0)."""
    g = model.actuator_gainprm[actuators]
    with np.errstate(divide="ignore", invalid="ignore"):
        st = g[:, GAIN_K] * g[:, GAIN_VMAX] / g[:, GAIN_R]
    top = np.abs(model.actuator_forcerange[actuators]).max(axis=-1)
    capped = (model.actuator_forcelimited[actuators] > 0) & (top > 0)
    st = np.where(g[:, GAIN_VMAX] > 0, st, np.where(capped, top, np.inf))
    return np.where(dcmotor_mask(model, actuators) & ~np.isnan(st), st, np.inf)


def motor_current(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """Winding current of every actuator [A] (tau / K; 0 for non-dcmotor actuators)."""
    k = model.actuator_gainprm[:, GAIN_K]
    with np.errstate(divide="ignore", invalid="ignore"):
        cur = np.where(k > 0, data.actuator_force / np.where(k > 0, k, 1.0), 0.0)
    return cur


MAX_SERVO_PERIOD = 0.1  # s; a servo's position loop runs at >= 10 Hz (Dynamixel, Feetech ~1 kHz)


class ServoClock:
    """A servo's update period: its position law sampled every period, its force held between.

    A Dynamixel or Feetech servo runs its firmware position loop at ~1 kHz and holds the PWM
    (so the torque) until the next cycle; a continuous actuator law is a stiffer servo (a gain
    fitted to a 1 kHz firmware's logs with the law continuous lands ~5 % high, gap-fric4's trace
    in tests/test_gap_redteam3.py). It applies to fixed-gain affine actuators on a joint with no
    activation (``position``, a ``general`` written so): at an update the force is

        f = gain * ctrl + bias0 + bias1 * length + bias2 * velocity

    (ctrl clamped to its range; length and velocity gear times the joint's) clipped by the force
    range in force then (torque enable, a torque-speed line), and held by pinning the actuator's
    force range to [f, f]: MuJoCo's implicit integrators drop the velocity derivative of a
    clamped force, so the held force is exactly a ``motor`` at ctrl f (checked in
    tests/test_servo_period.py). The period is rounded to a whole number of physics steps (one
    under half a step is the continuous law). Actuators with a native delay, ``dcmotor``s and
    filtered ``position``s keep the continuous law. Fields are read through the plant's
    protocol (``array``, ``qpos``, ``qvel``, ``ctrl``; arrays with a leading sim axis or not).
    """

    def __init__(self, model: mujoco.MjModel):
        m = model
        self.holdable = ((m.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
                         & (m.actuator_biastype == mujoco.mjtBias.mjBIAS_AFFINE)
                         & (m.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
                         & (m.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT))
        jid = m.actuator_trnid[:, 0]
        self.qadr = np.where(self.holdable, m.jnt_qposadr[jid], 0)
        self.dadr = np.where(self.holdable, m.jnt_dofadr[jid], 0)
        self.every = 0  # physics steps per update (0: continuous)
        self.phase = 0  # physics steps since the last update
        self.held: np.ndarray | None = None  # (..., nu) actuators whose force is held now
        self.force: np.ndarray | None = None

    def set_period(self, period: float, timestep: float) -> None:
        if not (np.isfinite(period) and 0.0 <= period <= MAX_SERVO_PERIOD):
            raise ConfigError(f"servo period must be in [0, {MAX_SERVO_PERIOD}] s, got {period}")
        self.every = int(round(period / timestep))
        self.release()

    def release(self) -> None:
        """Forget the held forces (the caller restored the ranges); update at the next step."""
        self.held, self.force, self.phase = None, None, 0

    def tick(self, n: int) -> None:
        if self.every:
            self.phase = (self.phase + n) % self.every

    def hold(self, plant) -> None:
        """An update: each holdable actuator's force from its law now, pinned."""
        fr, fl = plant.array("actuator_forcerange"), plant.array("actuator_forcelimited")
        gain, bias = plant.array("actuator_gainprm"), plant.array("actuator_biasprm")
        cr = plant.array("actuator_ctrlrange")
        ctrl = np.where(plant.array("actuator_ctrllimited") > 0,
                        np.clip(plant.ctrl, cr[..., 0], cr[..., 1]), plant.ctrl)
        gear = plant.array("actuator_gear")[..., 0]
        f = (gain[..., 0] * ctrl + bias[..., 0] + bias[..., 1] * gear * plant.qpos[..., self.qadr]
             + bias[..., 2] * gear * plant.qvel[..., self.dadr])
        f = np.where(fl > 0, np.clip(f, fr[..., 0], fr[..., 1]), f)
        self.held = self.holdable & (plant.array("actuator_delay") <= 0)
        self.force = f
        self.keep(plant)

    def keep(self, plant) -> None:
        """Between updates: pin the held forces again (after a rewrite of the ranges)."""
        if self.held is None:
            return
        fr, fl = plant.array("actuator_forcerange"), plant.array("actuator_forcelimited")
        fr[...] = np.where(self.held[..., None], self.force[..., None], fr)
        fl[...] = np.where(self.held, 1, fl)


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


def goal_slew_states(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The dcmotor servos whose goal is slewed (compiled with slewmax > 0) and the activation
    address of each one's slewed goal [rad]: (actuator ids, act addresses)."""
    col = dcmotor_act_layout(model)[:, ACT_SLEW]
    ids = np.flatnonzero(col >= 0)
    return ids, col[ids]


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
