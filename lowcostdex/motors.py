"""Servo models as data: the vendor's numbers for each motor (``MOTORS``, ``motor_spec``).

Stall torque, no-load speed and voltage from the datasheets, the control table's units and
factory gains, the firmware's thermal limit. Core data: the hand specs (``lowcostdex.hands``), the
servo model (``lowcostdex.sim.servo``), the drivers and the emulators all read it; sources are in
the comments beside each entry and checked in tests/test_vendor_units.py.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.errors import ConfigError, check_choice

TWO_PI = 2.0 * math.pi


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
      goal_speed: [rad/s] the rate at which the firmware moves its internal goal toward a
        written goal when no speed is written (0: the goal acts at once). Dynamixel: 0 (Profile
        Velocity 0 = no profile). Feetech STS: the Running Speed register (46) boots at the
        factory maximum and 0 there also means the maximum (STS3215: ``STS_GOAL_SPEED``; 0
        where the servo's logs move faster than any goal they hold).
      backdriven: (Coulomb [N m], viscous [N m s/rad]) of the gear train back-driven by its load
        with the torque off (``backdriven_friction``), or None: not known. Identification uses
        it when no training log has the torque off (``gap.identify_logs.backdriven_plan``).
      release: [s] how long the servo still holds its load after a torque-off command (0: not
        measured). The replay of logs lets go that long after the first sample logged with
        the torque off when no training log has a torque-off swing to measure it on
        (``gap.torque_off.release_delay``, ``gap.bam_measure.resample``).
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
    goal_speed: float = 0.0
    backdriven: tuple[float, float] | None = None
    release: float = 0.0

    def __post_init__(self) -> None:
        for name in ("voltage", "stall_torque", "no_load_speed", "gear_ratio"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"MotorSpec {self.name}: {name} must be > 0")
        if not 0 < self.max_duty <= 1:
            raise ConfigError(f"MotorSpec {self.name}: max_duty must be in (0, 1]")
        if not (math.isfinite(self.goal_speed) and self.goal_speed >= 0):
            raise ConfigError(f"MotorSpec {self.name}: goal_speed must be >= 0 rad/s (0: none)")
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

    def winding_heating(self, current: np.ndarray | float, temperature: np.ndarray | float
                        ) -> np.ndarray:
        """Rate of change of the winding temperature [K/s] at ``current`` [A] and winding
        ``temperature`` [deg C]: the single-node model of the simulation's dcmotor ``thermal``
        (``thermal``), C dT/dt = I^2 R (1 + tempcoef (T - ambient)) - (T - ambient) / R_th."""
        t = self.thermal
        rise = np.asarray(temperature, float) - t.ambient
        power = np.square(current) * self.resistance * (1.0 + t.tempcoef * rise)
        return (power - rise / t.resistance) / t.capacitance


KGF_CM = 9.80665e-2
"""N m per kgf cm (Feetech rates torque in kg cm)."""

STS_GOAL_SPEED = 3400 * TWO_PI / 4096
"""[rad/s] the Feetech STS firmware's goal slew at its factory Running Speed: 3400 steps/s (5.22
rad/s). Feetech's STS memory table (ftservo/ftservo-wiki docs/en/reference/parameter/
memory-sts.md @9522ce19): Running Speed (address 46) "initial value: factory default maximum
speed ... 0 means the maximum speed", Acceleration (41) 0 = the maximum acceleration; the goal
position (42) is approached at that speed (the firmware's current goal is readable at 67).
3400 steps/s is the STS3215's maximum as BAM models it (Rhoban/bam bam/feetech/actuator.py
``default_max_velocity``; 08-bam-reference-errors.md section 4); ``goal_slew`` fits a factor on
it. Not the STS3032's or STS3250's: their measured logs (BAM's recorders, Running Speed never
written) track the goal at up to 11.9 rad/s (STS3032, kp 32, sin_time_square, above 5.5 rad/s
for 0.2 s at a time) and 8.6 rad/s (STS3250), and BAM's STS3032 fits put the clamp at 16.8-29.7
rad/s, above every goal speed in those logs (14 rad/s): no slew is modelled for them."""

_X430_THERMAL = ThermalSpec(resistance=12.0, capacitance=8.0)
MX64_BACKDRIVEN = (0.0904, 0.0117)
MX106_BACKDRIVEN = (0.1035, 0.0352)

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
        # backdriven: BAM's published XL330 M1 Coulomb + viscous (Rhoban/bam params/xl330/m1.json
        # @11bb7ec, branch nolift_xl330, fitted with lift_and_drop left out: friction_base 0.0182,
        # friction_viscous 0.0059; Rhoban/bam main @1b5a1ce has 0.0128 + 0.0037: Rhoban's lift
        # fold 46.0 mrad with it, 40.9 with these, BAM M3 52.2, gap-real16), one law for the
        # torque on and off; the Rhoban XL330 swings alone say 0.0053 + 0.0095 (gap.torque_off.
        # swing_fit, gap-real12). release: the median over Rhoban's four lift_and_drop logs
        # (1.2-12.6 ms; gap.torque_off.release_delay, gap-real21).
        MotorSpec("XL330-M288", 1200, 5.0, 0.52, 103 * TWO_PI / 60, 288.4, 0.0003,
                  current_unit=1.0e-3, default_p=400,
                  error_gain=(4096 / TWO_PI) / (256.0 * 885), backdriven=(0.0182, 0.0059),
                  release=0.0045,
                  thermal=ThermalSpec(resistance=18.0, capacitance=3.0, limit=70.0)),
        MotorSpec("XL330-M077", 1190, 5.0, 0.215, 383 * TWO_PI / 60, 77.5, 0.0001,
                  current_unit=1.0e-3, default_p=400, default_i=400,
                  error_gain=(4096 / TWO_PI) / (256.0 * 885),
                  thermal=ThermalSpec(resistance=18.0, capacitance=3.0, limit=70.0)),
        # MX-64/MX-106 with Protocol 2.0 firmware (Model Number 311/321, the tables dynamixel-sdk
        # ships): e-Manual mx-64-2 / mx-106-2 pages, 12 V rows; current 3.36 mA per count,
        # factory Position P 850, the P2 gain law K_P = P/128 (error_gain from pwm_max, as the
        # X series). Armature: Menagerie dynamixel_2r's fitted 0.005 [uncertain: a prior].
        # backdriven (both firmwares): BAM's published M1 Coulomb + viscous (Rhoban/bam@1b5a1ce
        # params/mx64/m1.json 0.0904 + 0.0117, mx106/m1.json 0.1035 + 0.0352), one law for the
        # torque on and off. Rhoban's passive fall of an MX (data/friction_1.json, model not
        # recorded, torque off) follows MX-106's at 22 mrad (rest -1.858 rad, measured -1.833)
        # and not MX-64's (284 mrad): MX-64's is unchecked on a torque-off log (gap-real16).
        MotorSpec("MX-64", 311, 12.0, 6.0, 63 * TWO_PI / 60, 200.0, 0.005,
                  current_unit=3.36e-3, default_p=850, backdriven=MX64_BACKDRIVEN),
        MotorSpec("MX-106", 321, 12.0, 8.4, 45 * TWO_PI / 60, 225.0, 0.005,
                  current_unit=3.36e-3, default_p=850, backdriven=MX106_BACKDRIVEN),
        # MX-28 with Protocol 2.0 firmware: e-Manual mx-28-2 page (Model Number 30, 2.5 N m and
        # 55 rpm at 12 V, 193:1, Temperature Limit 80, Position P/I/D 850/0/0, Velocity 0.229
        # rpm). It has no current register (Present Load, 0.1 % of the maximum, where the X and
        # MX-64/106 tables have Present Current), so current_unit is NaN and the Dynamixel
        # driver refuses it on the bus; the spec serves the simulation. Armature [uncertain:
        # the XM430-W210's, a motor of the same class].
        MotorSpec("MX-28", 30, 12.0, 2.5, 55 * TWO_PI / 60, 193.0, 0.0012,
                  current_unit=float("nan"), default_p=850),
        # The same motors with Protocol 1.0 firmware (Model Number 310/320), as on BAM's MX
        # benches: P Gain register 28 (factory 32), Present Speed 0.114 rpm per count
        # (e-Manual mx-64 page). BAM measured the P path with an oscilloscope at 15 V: duty =
        # 0.158 per (P unit * rad), ceiling 0.9625 (07-measured-data.md section 4). At the
        # factory gains both firmwares give nearly the same stiffness: 32 * 0.158 = 5.06 duty/rad
        # vs 850 * 4096 / (2 pi 128 885) = 4.89 duty/rad. The P1 Current register (68) reads
        # 4.5 mA * (value - 2048); current_unit holds the 4.5 mA (the offset is not modelled).
        MotorSpec("MX-64(1.0)", 310, 12.0, 6.0, 63 * TWO_PI / 60, 200.0, 0.005,
                  current_unit=4.5e-3, velocity_unit=0.114 * TWO_PI / 60.0, default_p=32,
                  error_gain=0.158, max_duty=0.9625, backdriven=MX64_BACKDRIVEN),
        MotorSpec("MX-106(1.0)", 320, 12.0, 8.4, 45 * TWO_PI / 60, 225.0, 0.005,
                  current_unit=4.5e-3, velocity_unit=0.114 * TWO_PI / 60.0, default_p=32,
                  error_gain=0.158, max_duty=0.9625, backdriven=MX106_BACKDRIVEN),
        # Feetech STS series. Feetech's STS memory table (ftservo/ftservo-wiki
        # docs/en/reference/parameter/memory-sts.md @9522ce19): position 4096 steps per turn,
        # Present Speed in 0.0146 rpm = 1 step/s (Phase bit 2), Present Current 6.5 mA, voltage
        # 0.1 V, temperature 1 deg C, Maximum Temperature Limit (13) initial value 70 deg C, I
        # coefficient 0. P and D are left to the model there; lerobot's SO-100 configure() gives
        # the STS3215's factory values "P_Coefficient ... (Default is 32)", "I_Coefficient and
        # D_Coefficient to default value 0 and 32". The D scale in duty is unpublished and BAM's
        # STS3215 error_gain (0.166, fitted at the factory gains) absorbs D's effect, so the
        # model applies none (d_error_gain 0). Gear ratios and armatures [uncertain].
        # STS3215 (LeRobot SO-100/SO-101, 7.4 V, 1/345 C001): Model Number 777 (lerobot's
        # table); Feetech's ST-3215-C001 spec at 6 V: stall 19.5 kg cm, 0.238 s/60 deg;
        # armature BAM's published sts3215 7.4 V M1 fit (0.0284) [a fit, not a datasheet value];
        # backdriven: the same file's Coulomb 0.0524 + viscous 0.0591 (Rhoban/bam@1b5a1ce
        # params/feetech_sts3215_7_4V/m1.json), unchecked on a torque-off log (none held here).
        MotorSpec("STS3215", 777, 6.0, 19.5 * KGF_CM, (math.pi / 3) / 0.238, 345.0, 0.0284,
                  current_unit=6.5e-3, velocity_unit=TWO_PI / 4096, default_p=32, default_d=32,
                  error_gain=0.166, d_error_gain=0.0, max_duty=0.97, goal_speed=STS_GOAL_SPEED,
                  backdriven=(0.0524, 0.0591),
                  thermal=ThermalSpec(limit=70.0), backlash=math.radians(0.5)),
        # STS3250: Model Number 2825 (lerobot's table, read from the motor); 50 kg cm (4.9 N m)
        # stall, 0.133 s/60 deg at 12 V (vendor sheet as quoted by robonine.com). No error_gain
        # has been measured: BAM's STS3215 value 0.166 and its 0.97 ceiling are used [uncertain].
        MotorSpec("STS3250", 2825, 12.0, 4.9, (math.pi / 3) / 0.133, 345.0, 0.003,
                  current_unit=6.5e-3, velocity_unit=TWO_PI / 4096, default_p=32, default_d=32,
                  error_gain=0.166, d_error_gain=0.0, max_duty=0.97,
                  thermal=ThermalSpec(limit=70.0), backlash=math.radians(0.5)),
        # Feetech STS3032 (6 V class): no datasheet and no published Model Number (0 = unknown).
        # Stall torque and no-load speed come from BAM's STS3215-model fit to the STS3032 bench
        # logs (kt 0.483 N m/A, R 3.29 Ohm at 6 V -> 0.88 N m, 12.4 rad/s;
        # 08-bam-reference-errors.md section 4), armature likewise (0.00103). error_gain/ceiling
        # as STS3215 [all uncertain]. backdriven: the STS3032 M1 Coulomb + viscous the logs'
        # authors published (qua-robotics/bam params/feetech_sts3032_6_0V/m1.json @4bd252b,
        # main: friction_base 0.00540, friction_viscous 0.00159; fitted on their 144 logs, the
        # 72 shared ones among them), one law for the torque on and off; the 18 shared torque-off
        # swings alone say 0.00528 + 0.00167 (gap.torque_off.swing_fit). Its lift_and_drop fold
        # (no torque-off log in training) 204.2 -> 188.8 mrad with it (BAM's M1 34.3; gap-real16),
        # 46.9 with it as the joint's whole back-driven friction (gap-real17). release: the
        # median over the 18 shared lift_and_drop logs (3.0-10.8 ms; gap.torque_off.
        # release_delay, gap-real21), the same logs the lift_and_drop fold holds out.
        MotorSpec("STS3032", 0, 6.0, 0.88, 6.0 / 0.483, 345.0, 0.00103,
                  current_unit=6.5e-3, velocity_unit=TWO_PI / 4096, default_p=32, default_d=32,
                  error_gain=0.166, d_error_gain=0.0, max_duty=0.97, backdriven=(0.0054, 0.00159),
                  release=0.0053,
                  thermal=ThermalSpec(limit=70.0), backlash=math.radians(0.5)),
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
      profile_velocity: the goal speed register in the motor's velocity unit: Dynamixel
        Profile Velocity (112) [0.229 rpm]; Feetech Running Speed (46) [step/s]; 0 = the
        motor's own (``MotorSpec.goal_speed``: unlimited on Dynamixel, the factory maximum on
        Feetech).
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
