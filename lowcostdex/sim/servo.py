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

import dataclasses
import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice

TWO_PI = 2.0 * math.pi

# Layout of a compiled dcmotor's parameter arrays (verified against mujoco 4.0.0).
USER_SUPPLY_VOLTAGE = 0  # actuator_user column holding the servo's nominal supply [V]
GAIN_R, GAIN_K, GAIN_TEMPCOEF, GAIN_TREF, GAIN_KP, GAIN_KI, GAIN_KD, GAIN_VMAX = range(8)
DYN_TE, DYN_RTH, DYN_CTH, DYN_TAMB = 0, 2, 3, 4  # DYN_TE: electrical time constant L/R [s]
DYN_LUGRE_STIFFNESS, DYN_LUGRE_DAMPING, DYN_SLEWMAX, DYN_IMAX = 5, 6, 7, 8
BIAS_LUGRE_COULOMB, BIAS_LUGRE_STATIC, BIAS_LUGRE_STRIBECK = 3, 4, 5
DCMOTOR_INPUT_POS = 1  # MjsActuator.ctrlspec bit for input="pos" (vel 2, ff 4, voltage 8)


@dataclass(frozen=True)
class ThermalSpec:
    """Single-node winding thermal model (dcmotor ``thermal``).

    Attributes:
      resistance: winding-to-ambient thermal resistance [K/W].
      capacitance: winding heat capacity [J/K].
      tempcoef: copper resistance coefficient [1/K].
      ambient: ambient temperature [deg C].
      limit: firmware shutdown temperature (Temperature Limit, address 31) [deg C].
    """

    resistance: float = 12.0
    capacitance: float = 8.0
    tempcoef: float = 0.0039
    ambient: float = 25.0
    limit: float = 80.0


@dataclass(frozen=True)
class MotorSpec:
    """Physical and device-unit facts of one servo model at its nominal supply.

    Attributes:
      name: model name as ROBOTIS writes it, e.g. "XM430-W350".
      model_number: value of the Model Number register (Dynamixel address 0, Feetech address 3;
        0 where the vendor publishes none).
      voltage: nominal supply voltage [V].
      stall_torque: output stall torque at ``voltage`` [N m].
      no_load_speed: output no-load speed at ``voltage`` [rad/s].
      gear_ratio: gearbox ratio (documentation; constants are output-side).
      armature: rotor inertia reflected to the output [kg m^2].
      error_gain: PWM duty (fraction of full scale) per rad of position error per unit of the
        Position P Gain register. ROBOTIS documents K_P = P/128 in PWM units per tick.
      d_error_gain: duty per (rad/s) per unit of Position D Gain (approximate: K_D = D/16 per tick
        per 1 ms firmware cycle).
      i_error_gain: duty per (rad s) per unit of Position I Gain (K_I = I/65536 per tick per ms).
      current_unit: Present/Goal Current LSB [A].
      velocity_unit: Present Velocity LSB [rad/s] (0.229 rpm).
      ticks_per_rev: encoder resolution [ticks/rev].
      pwm_max: PWM register full scale (885 = 100 % duty on X-series).
      default_p, default_i, default_d: factory Position P / I / D Gain (e-Manual control
        table; the emulated firmware boots with them and the simulated servo uses them).
      thermal: winding thermal model.
      backlash: manufacturer backlash [rad] (documentation / DR prior).
      max_duty: firmware duty ceiling as a fraction of full scale (BAM's ``max_pwm``); the
        default PWM Limit of a bench or hand built for this motor is ``max_duty * pwm_max``.
    """

    name: str
    model_number: int
    voltage: float
    stall_torque: float
    no_load_speed: float
    gear_ratio: float
    armature: float
    current_unit: float = 2.69e-3
    velocity_unit: float = 0.229 * TWO_PI / 60.0
    ticks_per_rev: int = 4096
    pwm_max: int = 885
    default_p: int = 800
    default_i: int = 0
    default_d: int = 0
    error_gain: float = field(default=float("nan"))
    d_error_gain: float = field(default=float("nan"))
    i_error_gain: float = field(default=float("nan"))
    thermal: ThermalSpec = ThermalSpec()
    backlash: float = math.radians(0.25)
    max_duty: float = 1.0

    def __post_init__(self) -> None:
        for name in ("voltage", "stall_torque", "no_load_speed", "gear_ratio"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"MotorSpec {self.name}: {name} must be > 0")
        if not 0 < self.max_duty <= 1:
            raise ConfigError(f"MotorSpec {self.name}: max_duty must be in (0, 1]")
        tpr = self.ticks_per_rad
        if math.isnan(self.error_gain):
            object.__setattr__(self, "error_gain", tpr / (128.0 * self.pwm_max))
        if math.isnan(self.d_error_gain):
            object.__setattr__(self, "d_error_gain", tpr * 1e-3 / (16.0 * self.pwm_max))
        if math.isnan(self.i_error_gain):
            object.__setattr__(self, "i_error_gain", tpr * 1e3 / (65536.0 * self.pwm_max))

    def factory_gains(self) -> ServoGains:
        """The factory Position P/I/D gains as ``ServoGains`` (other settings at defaults)."""
        return ServoGains(position_p=self.default_p, position_i=self.default_i,
                          position_d=self.default_d)

    @property
    def ticks_per_rad(self) -> float:
        return self.ticks_per_rev / TWO_PI

    @property
    def motorconst(self) -> float:
        """Output-side torque/back-EMF constant K [N m/A = V s/rad]."""
        return self.voltage / self.no_load_speed

    @property
    def resistance(self) -> float:
        """Terminal resistance R [Ohm] such that stall torque = K V / R."""
        return self.motorconst * self.voltage / self.stall_torque


_X430_THERMAL = ThermalSpec(resistance=12.0, capacitance=8.0)

MOTORS: dict[str, MotorSpec] = {
    m.name: m
    for m in (
        # ROBOTIS e-Manual figures at 12 V (05-dynamixel-protocol.md section 4). Current units
        # and factory gains from each model's control table (checked against the e-Manual in
        # tests/test_vendor_units.py): 2.69 mA for XM430 and XH430-W, 1.34 mA for XH430-V;
        # Position P 900 on the XH430-W, 800 on the others.
        MotorSpec("XM430-W210", 1030, 12.0, 3.0, 77 * TWO_PI / 60, 212.6, 0.0012),
        MotorSpec("XM430-W350", 1020, 12.0, 4.1, 46 * TWO_PI / 60, 353.5, 0.0030),
        MotorSpec("XH430-W210", 1010, 12.0, 2.5, 50 * TWO_PI / 60, 212.6, 0.0012,
                  default_p=900),
        MotorSpec("XH430-W350", 1000, 12.0, 3.4, 30 * TWO_PI / 60, 353.5, 0.0030,
                  default_p=900),
        MotorSpec("XH430-V210", 1050, 24.0, 2.6, 52 * TWO_PI / 60, 212.6, 0.0012,
                  current_unit=1.34e-3),
        MotorSpec("XH430-V350", 1040, 24.0, 3.3, 31 * TWO_PI / 60, 353.5, 0.0030,
                  current_unit=1.34e-3),
        # XL330: 5 V class, plastic gears; BAM found the effective P divisor to be 256.
        MotorSpec("XL330-M288", 1200, 5.0, 0.52, 103 * TWO_PI / 60, 288.4, 0.0003,
                  current_unit=1.0e-3, default_p=400,
                  error_gain=(4096 / TWO_PI) / (256.0 * 885),
                  thermal=ThermalSpec(resistance=18.0, capacitance=3.0, limit=70.0)),
        MotorSpec("XL330-M077", 1190, 5.0, 0.215, 383 * TWO_PI / 60, 77.5, 0.0001,
                  current_unit=1.0e-3, default_p=400, default_i=400,
                  error_gain=(4096 / TWO_PI) / (256.0 * 885),
                  thermal=ThermalSpec(resistance=18.0, capacitance=3.0, limit=70.0)),
        # MX-64/MX-106 with Protocol 2.0 firmware (Model Number 311/321, the tables dynamixel-sdk
        # ships): e-Manual mx-64-2 / mx-106-2 pages, 12 V rows; current 3.36 mA per count,
        # factory Position P 850, the P2 gain law K_P = P/128 (error_gain from pwm_max, as the
        # X series). Armature: Menagerie dynamixel_2r's fitted 0.005 [uncertain: a prior].
        MotorSpec("MX-64", 311, 12.0, 6.0, 63 * TWO_PI / 60, 200.0, 0.005,
                  current_unit=3.36e-3, default_p=850),
        MotorSpec("MX-106", 321, 12.0, 8.4, 45 * TWO_PI / 60, 225.0, 0.005,
                  current_unit=3.36e-3, default_p=850),
        # The same motors with Protocol 1.0 firmware (Model Number 310/320), as on BAM's MX
        # benches: P Gain register 28 (factory 32), Present Speed 0.114 rpm per count
        # (e-Manual mx-64 page). BAM measured the P path with an oscilloscope at 15 V: duty =
        # 0.158 per (P unit * rad), ceiling 0.9625 (07-measured-data.md section 4). At the
        # factory gains both firmwares give nearly the same stiffness: 32 * 0.158 = 5.06 duty/rad
        # vs 850 * 4096 / (2 pi 128 885) = 4.89 duty/rad. The P1 Current register (68) reads
        # 4.5 mA * (value - 2048); current_unit holds the 4.5 mA (the offset is not modelled).
        MotorSpec("MX-64(1.0)", 310, 12.0, 6.0, 63 * TWO_PI / 60, 200.0, 0.005,
                  current_unit=4.5e-3, velocity_unit=0.114 * TWO_PI / 60.0, default_p=32,
                  error_gain=0.158, max_duty=0.9625),
        MotorSpec("MX-106(1.0)", 320, 12.0, 8.4, 45 * TWO_PI / 60, 225.0, 0.005,
                  current_unit=4.5e-3, velocity_unit=0.114 * TWO_PI / 60.0, default_p=32,
                  error_gain=0.158, max_duty=0.9625),
        # Feetech STS series (memory table: position 4096 steps per turn, Present Speed in
        # steps/s, Present Current 6.5 mA, voltage 0.1 V, temperature 1 deg C; P coefficient
        # factory 32). STS3250: Model Number 2825 (lerobot's table, read from the motor);
        # 50 kg cm (4.9 N m) stall, 0.133 s/60 deg at 12 V (vendor sheet as quoted by
        # robonine.com). No error_gain has been measured: BAM's STS3215 value 0.166 and its 0.97
        # ceiling are used [uncertain]. Gear ratio and armature [uncertain].
        MotorSpec("STS3250", 2825, 12.0, 4.9, (math.pi / 3) / 0.133, 345.0, 0.003,
                  current_unit=6.5e-3, velocity_unit=TWO_PI / 4096, default_p=32,
                  error_gain=0.166, max_duty=0.97, thermal=ThermalSpec(limit=70.0),
                  backlash=math.radians(0.5)),
        # Feetech STS3032 (6 V class): no datasheet and no published Model Number (0 = unknown).
        # Stall torque and no-load speed come from BAM's STS3215-model fit to the STS3032 bench
        # logs (kt 0.483 N m/A, R 3.29 Ohm at 6 V -> 0.88 N m, 12.4 rad/s;
        # 08-bam-reference-errors.md section 4), armature likewise (0.00103). error_gain/ceiling
        # as STS3215 [all uncertain].
        MotorSpec("STS3032", 0, 6.0, 0.88, 6.0 / 0.483, 345.0, 0.00103,
                  current_unit=6.5e-3, velocity_unit=TWO_PI / 4096, default_p=32,
                  error_gain=0.166, max_duty=0.97, thermal=ThermalSpec(limit=70.0),
                  backlash=math.radians(0.5)),
    )
}


def motor_spec(name: str) -> MotorSpec:
    """Look up a motor by name; the error lists the known models."""
    check_choice("motor model", name, MOTORS)
    return MOTORS[name]


@dataclass(frozen=True)
class ServoGains:
    """Firmware settings in device units (control-table values).

    Attributes:
      position_p / position_i / position_d: Position P/I/D Gain registers (84/82/80).
      pwm_limit: PWM Limit register (36), 0..885.
      profile_velocity: Profile Velocity register (112) [0.229 rpm]; 0 = unlimited.
      supply_voltage: supply [V]; None = the motor's nominal voltage.
    """

    position_p: int = 800
    position_i: int = 0
    position_d: int = 0
    pwm_limit: int = 885
    profile_velocity: int = 0
    supply_voltage: float | None = None

    def __post_init__(self) -> None:
        for name in ("position_p", "position_i", "position_d"):
            if not 0 <= getattr(self, name) <= 16383:
                raise ConfigError(f"{name}={getattr(self, name)} outside the register range 0..16383")
        if not 0 <= self.pwm_limit <= 885:
            raise ConfigError(f"pwm_limit={self.pwm_limit} outside 0..885")
        if self.profile_velocity < 0:
            raise ConfigError("profile_velocity must be >= 0")

    def replace(self, **changes: float) -> ServoGains:
        return dataclasses.replace(self, **changes)


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
