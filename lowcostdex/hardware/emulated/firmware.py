"""Emulated Dynamixel X-series firmware: one motor's control table and what the firmware does with it.

A ``MotorFirmware`` owns the control-table memory of one motor (layout from the SDK's ``.model``
file, defaults and access rules from ``control_table``) and implements the device side of every
instruction on it: READ / WRITE with the firmware's checks (access, EEPROM lock while torque is
on, data length, range, position limits), REG_WRITE / ACTION, REBOOT, FACTORY_RESET. Packet
framing and the instruction dispatch across a chain of motors live in ``emulator``; the physics
lives behind the ``Drive`` protocol (implemented on a ``lowcostdex.sim.plant.Plant`` by
``drive.PlantDrive``).

What the firmware model does every physics step (``tick``):

- position controller: the Position P/I/D Gain and PWM Limit registers become the servo model's
  dcmotor gains through ``lowcostdex.sim.servo.dcmotor_params`` (written on every change); Profile
  Velocity / Profile Acceleration drive a trapezoidal trajectory generator whose output (the
  Position Trajectory register) is the setpoint of that controller, as on the real firmware;
- thermal: at the Temperature Limit (31) the Overheating bit of Hardware Error Status (70) is set;
  every status packet then carries the alert bit; if Shutdown (63) selects the bit, torque drops
  and stays off until REBOOT (torque-on writes fail with Result Fail);
- input voltage outside the Min/Max Voltage Limits sets the Input Voltage bit (same latch rule);
- Bus Watchdog (98): with torque on, no instruction for longer than value x 20 ms stops the motor
  (it holds its present position), the register reads -1 and Goal writes get Data Range Error
  until 0 is written.

Present Position follows the e-Manual: continuous over turns while torque is off, reset into one
turn (0..4095) when torque turns on in Position Control Mode, when switching to that mode and at
reboot; Homing Offset (20) is added.

Not emulated (stored, no effect): velocity/current/PWM operating modes (writes of Operating Mode
other than 3 and 4 get Data Range Error), Current Limit outside those modes, Drive Mode bits,
Secondary ID, indirect addressing (the indirect area is plain RAM).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lowcostdex.errors import check_choice
from lowcostdex.hands import Calibration
from lowcostdex.hardware.dynamixel.control_table import (
    DEPENDENT,
    EEPROM_END,
    GOALS,
    READ_ONLY,
    SIGNED,
    ControlTable,
    Reg,
    factory_defaults,
    load_control_table,
    value_range,
)
from lowcostdex.hardware.dynamixel.protocol import (
    ErrorNumber,
    HardwareError,
    hardware_error_names,
    le_bytes,
    to_signed,
)
from lowcostdex.sim.servo import MotorSpec, ServoGains, motor_spec

E = ErrorNumber
POSITION_MODE, EXTENDED_POSITION_MODE = 3, 4
EMULATED_MODES = (POSITION_MODE, EXTENDED_POSITION_MODE)
WATCHDOG_UNIT = 0.020  # [s] per Bus Watchdog LSB
RDT_UNIT = 2e-6  # [s] per Return Delay Time LSB
PROFILE_ACC_UNIT = 214.577 / 3600.0  # [rev/s^2] per Profile Acceleration LSB
PRESENT_START, PRESENT_END = 120, 147  # Realtime Tick .. Present Temperature
_PRESENT = struct.Struct("<HBBhhiiiiHB")  # packed layout of 120..146
_FACTORY_RESET = {0xFF: "all", 0x01: "all but ID", 0x02: "all but ID and baud rate"}
_UNCACHED = frozenset({Reg.GOAL_POSITION, Reg.GOAL_PWM, Reg.GOAL_CURRENT, Reg.GOAL_VELOCITY,
                       Reg.LED, Reg.POSITION_P_GAIN, Reg.POSITION_I_GAIN, Reg.POSITION_D_GAIN,
                       Reg.VELOCITY_P_GAIN, Reg.VELOCITY_I_GAIN})  # writes that need no _cache()


@dataclass(frozen=True)
class FirmwareOptions:
    """Behaviour of the emulated firmware that differs between versions or is a choice.

    Attributes:
      firmware_version: Firmware Version register (6).
      fast_read: answer FAST_SYNC_READ / FAST_BULK_READ (firmware support is version dependent).
      factory_reset: "refuse" (Result Fail, nothing changes) or "reset" (defaults, then reboot).
      reboot_time: the motor is silent this long after REBOOT [s].
    """

    firmware_version: int = 52
    fast_read: bool = True
    factory_reset: str = "refuse"
    reboot_time: float = 0.05

    def __post_init__(self) -> None:
        check_choice("factory_reset behaviour", self.factory_reset, ("refuse", "reset"))


class DriveState(Protocol):
    """Physics readings of every emulated servo, arrays indexed by the motor's drive index.

    Attributes:
      q: joint angle [rad]; qd: joint velocity [rad/s]; current: winding current [A] (joint sign);
      duty: PWM duty, -1..1 (joint sign, 0 with torque off); temperature: winding [deg C];
      voltage: supply at the motor [V].
      step: physics step counter of the readings.
    """

    q: np.ndarray
    qd: np.ndarray
    current: np.ndarray
    duty: np.ndarray
    temperature: np.ndarray
    voltage: np.ndarray
    step: int  # physics step these readings belong to


class Drive(Protocol):
    """The physics behind the firmware (``drive.PlantDrive``), indexed by drive index."""

    def set_torque(self, index: int, enabled: bool) -> None: ...

    def set_gains(self, index: int, gains: ServoGains) -> None: ...

    def set_goal(self, index: int, q: float, after: float = 0.0) -> None:
        """The setpoint becomes ``q`` [rad] ``after`` (0..1) of the way into the coming step."""

    def state(self) -> DriveState: ...


class Sink(Protocol):
    """Where a motor reports to its chain (goal log, events, id changes)."""

    def on_goal(self, motor_id: int, reg: Reg, value: int) -> None: ...

    def on_sample(self, motor_id: int) -> None:
        """The motor answered a read of its Present Position (sampled it now)."""

    def on_event(self, motor_id: int, kind: str, detail: str) -> None: ...

    def on_id_change(self, old: int, new: int) -> None: ...


class MotorFirmware:
    """One emulated Dynamixel: control table + firmware behaviour on a ``Drive``.

    Args:
      motor_id: initial ID register value.
      model: model name (one of ``control_table.SUPPORTED_MODELS``).
      index: this servo's index in the drive.
      calibration: how the motor shaft maps to the simulated joint (the *true* mounting).
      drive: the physics.
      sink: receives accepted goals, events and id changes.
      clock: current bus time [s].
      options: firmware options.
      baud_code: Baud Rate register value at power-on.
    """

    def __init__(self, motor_id: int, model: str, index: int, calibration: Calibration,
                 drive: Drive, sink: Sink, clock: Callable[[], float],
                 options: FirmwareOptions | None = None, baud_code: int = 3):
        self.table: ControlTable = load_control_table(model)
        self.model = model
        self.spec: MotorSpec = motor_spec(model)
        self.defaults = factory_defaults(model)
        self.index = index
        self.calibration = calibration
        self.drive, self.sink, self.clock = drive, sink, clock
        self.options = options or FirmwareOptions()
        self.mem = bytearray(self.table.size)
        self._where = {it.reg: (it.address, it.end, it.reg in SIGNED)
                       for it in self.table.items.values() if it.reg is not None}
        self._goal_address = self.table.address(Reg.GOAL_POSITION)
        self._position_address = self.table.address(Reg.PRESENT_POSITION)
        self._ticks_per_rad = self.spec.ticks_per_rev / (2 * math.pi)
        self.hardware_error = 0
        self.watchdog_error = False
        self.stuck_temperature: float | None = None  # a stuck sensor's reading [deg C]
        self.registered: tuple[int, bytes] | None = None
        self.turn_offset = 0.0  # [ticks] encoder = shaft ticks + turn_offset
        self.setpoint = 0.0  # profile output [encoder ticks]
        self.setpoint_velocity = 0.0  # [ticks/s]
        self.target = 0.0  # goal [encoder ticks]
        self._target_time = -math.inf  # bus time [s] the goal arrived
        self._goal_sent = math.nan  # setpoint last handed to the drive
        self.offline_until = -math.inf
        self.last_rx = 0.0
        self.srl_rx = 2  # Status Return Level when the instruction being answered arrived
        self._present_time, self._present_step = -1.0, -1
        self._load_defaults(keep=())
        self.mem[self.table.address(Reg.ID)] = motor_id
        self.mem[self.table.address(Reg.BAUD_RATE)] = baud_code
        self._power_on()

    # -- registers -------------------------------------------------------------------------------
    def get(self, reg: Reg) -> int:
        """Register value (signed items decoded)."""
        a, b, signed = self._where[reg]
        return int.from_bytes(self.mem[a:b], "little", signed=signed)

    def _set(self, reg: Reg, value: int) -> None:
        a, b, _ = self._where[reg]
        self.mem[a:b] = le_bytes(value, b - a)

    @property
    def id(self) -> int:
        return self.mem[7]

    def _load_defaults(self, keep: tuple[Reg, ...]) -> None:
        kept = {r: self.get(r) for r in keep}
        for reg, value in self.defaults.items():
            if reg in self.table:
                self._set(reg, value)
        self._set(Reg.MODEL_NUMBER, self.table.model_number)
        self._set(Reg.FIRMWARE_VERSION, self.options.firmware_version)
        for r, v in kept.items():
            self._set(r, v)
        self._cache()

    def _cache(self) -> None:
        """Hot register values as attributes (refreshed after every write)."""
        g = self.get
        self.torque_on = g(Reg.TORQUE_ENABLE) == 1
        self.mode = g(Reg.OPERATING_MODE)
        self.return_delay = g(Reg.RETURN_DELAY_TIME) * RDT_UNIT
        self.status_return_level = g(Reg.STATUS_RETURN_LEVEL)
        self.watchdog_period = 0.0 if self.watchdog_error else g(Reg.BUS_WATCHDOG) * WATCHDOG_UNIT
        self.shutdown_mask = g(Reg.SHUTDOWN)
        self.temperature_limit = g(Reg.TEMPERATURE_LIMIT)
        self.voltage_limits = (0.1 * g(Reg.MIN_VOLTAGE_LIMIT), 0.1 * g(Reg.MAX_VOLTAGE_LIMIT))
        self.position_limits = (g(Reg.MIN_POSITION_LIMIT), g(Reg.MAX_POSITION_LIMIT))
        self.homing = g(Reg.HOMING_OFFSET)
        self.moving_threshold = g(Reg.MOVING_THRESHOLD)
        self.pwm_limit = g(Reg.PWM_LIMIT)
        tpr = self.spec.ticks_per_rev
        pv, pa = g(Reg.PROFILE_VELOCITY), g(Reg.PROFILE_ACCELERATION)
        self.profile_velocity = pv * self.spec.velocity_unit * self._ticks_per_rad if pv else math.inf
        self.profile_acceleration = pa * PROFILE_ACC_UNIT * tpr if pa else math.inf
        self.baudrate_code = g(Reg.BAUD_RATE)

    # -- conversions between the shaft, the encoder register and the joint ----------------------
    def _encoder(self, q_joint: float) -> float:
        """Continuous encoder count [ticks] of a joint angle (homing offset not included)."""
        return self.calibration.to_motor(q_joint) * self._ticks_per_rad + self.turn_offset

    def _joint(self, encoder: float) -> float:
        return self.calibration.to_joint((encoder - self.turn_offset) / self._ticks_per_rad)

    def position_to_joint(self, value: int) -> float:
        """Joint angle [rad] (true mounting) of a Goal/Present Position register value [ticks]."""
        return self._joint(value - self.homing)

    def _wrap_one_turn(self, q_joint: float) -> None:
        """Re-express the present position within one turn (0..4095), as the firmware does."""
        present = self._encoder(q_joint) + self.homing
        tpr = self.spec.ticks_per_rev
        self.turn_offset += math.floor(round(present) / tpr) * -tpr

    # -- instructions ----------------------------------------------------------------------------
    def read(self, address: int, length: int, state: DriveState) -> tuple[int, bytes]:
        """READ: (error number, data)."""
        end = address + length
        if length < 1 or end > self.table.size:
            return E.ACCESS, b""
        if address < PRESENT_END and end > PRESENT_START:
            self.refresh_present(state)
            if address <= self._position_address and end >= self._position_address + 4:
                self.sink.on_sample(self.id)
        return E.NONE, bytes(self.mem[address:end])

    def write(self, address: int, data: bytes, state: DriveState) -> int:
        """WRITE: all-or-nothing; returns the error number."""
        if address == self._goal_address and len(data) == 4:
            return self._write_goal(data)
        values, err = self._decode_write(address, data)
        if err:
            return err
        err = self._check_values(values)
        if err:
            return err
        old_id = self.id
        self.mem[address:address + len(data)] = data
        if not _UNCACHED.issuperset(values):
            self._cache()
        for reg, value in values.items():
            self._after_write(reg, value, state)
        if self.id != old_id:
            self.sink.on_id_change(old_id, self.id)
        return E.NONE

    def _write_goal(self, data: bytes) -> int:
        """The common case of ``write``: Goal Position alone (same checks, no generic walk)."""
        value = int.from_bytes(data, "little", signed=True)
        if self.watchdog_error:
            return E.DATA_RANGE
        if self.mode == POSITION_MODE:
            lo, hi = self.position_limits
            if not lo <= value <= hi:
                return E.DATA_LIMIT
        elif not -1_048_575 <= value <= 1_048_575:
            return E.DATA_RANGE
        self.mem[self._goal_address:self._goal_address + 4] = data
        self.target = float(value - self.homing)
        self._target_time = self.clock()
        self.sink.on_goal(self.id, Reg.GOAL_POSITION, value)
        return E.NONE

    def reg_write(self, address: int, data: bytes) -> int:
        """REG_WRITE: checked now, applied on ACTION."""
        values, err = self._decode_write(address, data)
        if not err:
            err = self._check_values(values)
        if err:
            return err
        self.registered = (address, bytes(data))
        self._set(Reg.REGISTERED_INSTRUCTION, 1)
        return E.NONE

    def action(self, state: DriveState) -> int:
        """ACTION: execute the registered write (Instruction Error if there is none)."""
        if self.registered is None:
            return E.INSTRUCTION
        address, data = self.registered
        self.registered = None
        self._set(Reg.REGISTERED_INSTRUCTION, 0)
        return self.write(address, data, state)

    def reboot(self) -> None:
        """REBOOT: RAM to defaults, errors cleared, torque off, silent for ``reboot_time``."""
        eeprom = bytes(self.mem[:EEPROM_END])
        self._load_defaults(keep=())
        self.mem[:EEPROM_END] = eeprom
        self._cache()
        self.hardware_error = 0
        self.watchdog_error = False
        self.registered = None
        self._power_on()
        self.offline_until = self.clock() + self.options.reboot_time
        self.sink.on_event(self.id, "reboot", "")

    def factory_reset(self, option: int) -> int:
        """FACTORY_RESET per ``options.factory_reset``; returns the error number."""
        if self.options.factory_reset == "refuse" or option not in _FACTORY_RESET:
            return E.RESULT_FAIL
        if self.torque_on:
            return E.RESULT_FAIL
        keep = {0xFF: (), 0x01: (Reg.ID,), 0x02: (Reg.ID, Reg.BAUD_RATE)}[option]
        old = self.id
        self._load_defaults(keep=keep)
        self.reboot()
        if self.id != old:
            self.sink.on_id_change(old, self.id)
        return E.NONE

    def ping_data(self) -> bytes:
        """PING reply parameters: model number (2 bytes), firmware version."""
        return le_bytes(self.table.model_number, 2) + bytes((self.options.firmware_version,))

    @property
    def error_byte(self) -> int:
        """Alert bit of status packets (0x80 while a hardware error is latched)."""
        return 0x80 if self.hardware_error else 0

    def online(self, now: float) -> bool:
        return now >= self.offline_until

    # -- write checks ------------------------------------------------------------------------------
    def _decode_write(self, address: int, data: bytes) -> tuple[dict[Reg, int], int]:
        end = address + len(data)
        if not data or end > self.table.size:
            return {}, E.ACCESS
        values: dict[Reg, int] = {}
        pos = address
        while pos < end:
            it = self.table.item_at(pos)
            if it is None:
                if pos >= self.table.raw_start:
                    pos += 1
                    continue
                return {}, E.ACCESS  # a reserved gap, or the middle of an item
            if it.end > end:
                return {}, E.DATA_LENGTH
            reg = it.reg
            if reg is not None:
                if reg in READ_ONLY:
                    return {}, E.ACCESS
                if it.address < EEPROM_END and self.torque_on:
                    return {}, E.ACCESS
                raw = int.from_bytes(data[pos - address:it.end - address], "little")
                values[reg] = to_signed(raw, it.size) if reg in SIGNED else raw
            pos = it.end
        return values, E.NONE

    def _check_values(self, values: dict[Reg, int]) -> int:
        merged = values
        if not DEPENDENT.isdisjoint(values):
            limits = (Reg.PWM_LIMIT, Reg.CURRENT_LIMIT, Reg.VELOCITY_LIMIT)
            merged = {**{r: self.get(r) for r in limits}, **values}
        for reg, v in values.items():
            rng = value_range(reg, merged, self.model)
            if rng is not None and not rng[0] <= v <= rng[1]:
                return E.DATA_RANGE
            if reg in GOALS and self.watchdog_error:
                return E.DATA_RANGE
            if reg == Reg.OPERATING_MODE and v not in EMULATED_MODES:
                return E.DATA_RANGE
            if reg == Reg.BUS_WATCHDOG and self.watchdog_error and v != 0:
                return E.DATA_RANGE
            if reg == Reg.TORQUE_ENABLE and v == 1 and self.hardware_error & self.shutdown_mask:
                return E.RESULT_FAIL
            if reg == Reg.GOAL_POSITION:
                mode = values.get(Reg.OPERATING_MODE, self.mode)
                if mode == POSITION_MODE:
                    lo, hi = self.position_limits
                    if not lo <= v <= hi:
                        return E.DATA_LIMIT
                elif not -1_048_575 <= v <= 1_048_575:
                    return E.DATA_RANGE
        return E.NONE

    def _after_write(self, reg: Reg, value: int, state: DriveState) -> None:
        if reg == Reg.TORQUE_ENABLE:
            self._torque(value == 1, state)
        elif reg in (Reg.POSITION_P_GAIN, Reg.POSITION_I_GAIN, Reg.POSITION_D_GAIN, Reg.PWM_LIMIT):
            self._push_gains()
        elif reg == Reg.GOAL_POSITION:
            self.target = float(value - self.homing)
            self._target_time = self.clock()
            self.sink.on_goal(self.id, reg, value)
        elif reg in GOALS:
            self.sink.on_goal(self.id, reg, value)
        elif reg == Reg.OPERATING_MODE and value == POSITION_MODE:
            self._wrap_one_turn(float(state.q[self.index]))
        elif reg == Reg.BUS_WATCHDOG:
            if value == 0 and self.watchdog_error:
                self.watchdog_error = False
                self._cache()
            self.last_rx = self.clock()

    def _torque(self, on: bool, state: DriveState) -> None:
        q = float(state.q[self.index])
        if on:
            if self.mode == POSITION_MODE:
                self._wrap_one_turn(q)
            self.target = float(self.get(Reg.GOAL_POSITION) - self.homing)
            self.setpoint = self._encoder(q)
            self.setpoint_velocity = 0.0
            self.last_rx = self.clock()
            self._push_gains()
            self.drive.set_goal(self.index, q)
            self._goal_sent = math.nan
        self.drive.set_torque(self.index, on)

    def _push_gains(self) -> None:
        g = self.get
        gains = ServoGains(position_p=g(Reg.POSITION_P_GAIN), position_i=g(Reg.POSITION_I_GAIN),
                           position_d=g(Reg.POSITION_D_GAIN), pwm_limit=g(Reg.PWM_LIMIT))
        self.drive.set_gains(self.index, gains)

    def _power_on(self) -> None:
        """Boot: present position within one turn, Goal Position := present, torque off."""
        state = self.drive.state()
        q = float(state.q[self.index])
        self._wrap_one_turn(q)
        present = round(self._encoder(q) + self.homing)
        self._set(Reg.GOAL_POSITION, present)
        self.target = self.setpoint = float(present - self.homing)
        self.setpoint_velocity = 0.0
        self._set(Reg.HARDWARE_ERROR_STATUS, 0)
        self._cache()
        self._push_gains()
        self.drive.set_torque(self.index, False)
        self._present_step = -1

    def sensed_temperature(self, state: DriveState) -> float:
        """What the motor's temperature sensor reads [deg C]: the winding's, or the value a
        stuck sensor stays at (``stuck_temperature``, a fault to inject); the firmware's own
        overheating shutdown sees only this."""
        if self.stuck_temperature is not None:
            return self.stuck_temperature
        return float(state.temperature[self.index])

    # -- per physics step ------------------------------------------------------------------------
    def tick(self, now: float, dt: float, state: DriveState) -> None:
        """One firmware cycle before the physics step from ``now`` to ``now + dt`` [s]: safety
        checks, then the profile setpoint; a goal that arrived during the step acts from its
        arrival (``Drive.set_goal``'s ``after``), not from the step's start."""
        k = self.index
        if self.sensed_temperature(state) >= self.temperature_limit:  # the firmware's sensor
            self.raise_hardware_error(HardwareError.OVERHEATING, state)
        lo, hi = self.voltage_limits
        if not lo <= state.voltage[k] <= hi:
            self.raise_hardware_error(HardwareError.INPUT_VOLTAGE, state)
        if not self.torque_on:
            return
        self.check_watchdog(now, state)
        if self.setpoint != self.target or self.setpoint_velocity:
            self._profile(dt)
        if self.setpoint != self._goal_sent:
            self._goal_sent = self.setpoint
            after = min(max((self._target_time - now) / dt, 0.0), 1.0)
            self.drive.set_goal(k, self._joint(self.setpoint), after)

    def check_watchdog(self, now: float, state: DriveState) -> None:
        """Bus watchdog: stop (and latch the error) after ``watchdog_period`` without an
        instruction, at bus time ``now`` [s]."""
        if self.torque_on and self.watchdog_period > 0 and now - self.last_rx > self.watchdog_period:
            self._trip_watchdog(state, now - self.last_rx)

    def _profile(self, dt: float) -> None:
        e = self.target - self.setpoint
        vmax, amax = self.profile_velocity, self.profile_acceleration
        if math.isinf(vmax) and math.isinf(amax):
            self.setpoint, self.setpoint_velocity = self.target, 0.0
            return
        v = self.setpoint_velocity
        stop = math.sqrt(2.0 * amax * abs(e)) if math.isfinite(amax) else math.inf
        v_des = math.copysign(min(vmax, stop), e)
        dv = v_des - v
        if math.isfinite(amax):
            dv = max(-amax * dt, min(amax * dt, dv))
        v += dv
        step = v * dt
        if abs(step) >= abs(e) or abs(e) < 0.5 and abs(v) * dt < 0.5:
            self.setpoint, self.setpoint_velocity = self.target, 0.0
        else:
            self.setpoint += step
            self.setpoint_velocity = v

    def _trip_watchdog(self, state: DriveState, silence: float) -> None:
        self.watchdog_error = True
        self.mem[self.table.address(Reg.BUS_WATCHDOG)] = 0xFF
        self._cache()
        stop = self._encoder(float(state.q[self.index]))
        self.target = self.setpoint = stop
        self.setpoint_velocity = 0.0
        self.sink.on_event(self.id, "watchdog",
                           f"stopped at {round(stop + self.homing)} after {silence:.6f} s silent")

    def raise_hardware_error(self, bits: int, state: DriveState | None = None) -> None:
        """Latch hardware error ``bits``; torque drops if Shutdown selects one of them."""
        new = bits & ~self.hardware_error
        if not new:
            return
        self.hardware_error |= bits
        self._set(Reg.HARDWARE_ERROR_STATUS, self.hardware_error)
        names = ", ".join(hardware_error_names(new))
        self.sink.on_event(self.id, "hardware_error", names)
        if self.hardware_error & self.shutdown_mask and self.torque_on:
            self._set(Reg.TORQUE_ENABLE, 0)
            self._cache()
            self.drive.set_torque(self.index, False)
            self.sink.on_event(self.id, "shutdown", names)

    # -- present values ----------------------------------------------------------------------------
    def refresh_present(self, state: DriveState) -> None:
        """Write Realtime Tick .. Present Temperature from the physics (quantized to ticks)."""
        now = self.clock()
        if now == self._present_time and state.step == self._present_step:
            return
        self._present_time, self._present_step = now, state.step
        k, spec, cal = self.index, self.spec, self.calibration
        direction = cal.sign * cal.scale
        position = round((state.q[k] - cal.offset) / direction * self._ticks_per_rad
                         + self.turn_offset + self.homing)
        velocity = round(state.qd[k] / direction / spec.velocity_unit)
        current = round(state.current[k] * cal.sign / spec.current_unit)
        pwm = 0
        if self.torque_on:
            pwm = round(state.duty[k] * cal.sign * spec.pwm_max)
            pwm = max(-self.pwm_limit, min(self.pwm_limit, pwm))
        traj_v = round(self.setpoint_velocity / self._ticks_per_rad / spec.velocity_unit)
        traj_p = round(self.setpoint + self.homing)
        moving = abs(velocity) > self.moving_threshold
        in_position = abs(self.target + self.homing - position) <= self.moving_threshold
        status = int(in_position) | (int(self.setpoint != self.target) << 1)
        volt = round(state.voltage[k] * 10)
        temp = round(self.sensed_temperature(state))
        fields = (int(now * 1000) % 32768, int(moving), status, pwm, current, velocity, position,
                  traj_v, traj_p, volt, temp)
        try:
            _PRESENT.pack_into(self.mem, PRESENT_START, *fields)
        except struct.error:  # a value beyond its register: saturate like the firmware's clamp
            bits = (16, 8, 8, 16, 16, 32, 32, 32, 32, 16, 8)
            signed = (False, False, False, True, True, True, True, True, True, False, False)
            _PRESENT.pack_into(self.mem, PRESENT_START, *(
                _clamp(v, b, s) for v, b, s in zip(fields, bits, signed, strict=True)))


def _clamp(value: int, bits: int, signed: bool) -> int:
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    return max(lo, min(hi, value))
