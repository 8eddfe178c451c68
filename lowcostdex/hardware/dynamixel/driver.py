"""DynamixelBus: the ``MotorBus`` for Dynamixel X-series servos, on dynamixel_sdk (Protocol 2.0).

Construction::

    bus = DynamixelBus.from_hand(dclaw_spec(), "/dev/ttyUSB0")        # real U2D2
    bus = DynamixelBus.from_hand(chain.hand, chain.port())            # in-process emulator
    bus = DynamixelBus.from_hand(chain.hand, server.path)             # emulator on a pty
    with bus:                                   # connect(); torque off on exit and on errors
        bus.set_torque(True)                    # goal := present first, watchdog armed
        state = bus.read_state()                # one sync read of 126..146 for every motor
        bus.write_goal_positions(goals)         # one sync write of Goal Position

Units: SI at the interface (``bus.MotorBus``): motor angle = ticks * 2 pi / 4096 with tick 0 =
0 rad, rad/s, A (per-model current LSB from ``lowcostdex.sim.servo``), V, deg C. Device units
exist only at the wire, with two's-complement decoding of every signed register.

Start-up (``connect``): open the port at the configured baud rate; read the USB latency timer
from sysfs, warn when it is above 1 ms and size the status timeouts from it; ping every id and
check its Model Number (one error listing every missing or mismatched id); torque off; Return
Delay Time := 0, Operating Mode := position, Min/Max Position Limit := the configured limits
(EEPROM, written only when different, so the motors refuse out-of-range goals even if the host
misbehaves); Position P/I/D Gain and PWM Limit written if configured, then read back into
``bus.gains`` (the numbers a simulation of this robot should use; a ``GainMismatchWarning`` when
they are not the motor model's factory gains, which the simulation assumes by default); Bus
Watchdog cleared; latched hardware errors reported by name; Fast Sync Read probed.

Bus Watchdog (98) exists from firmware v38 (e-Manual, "Bus Watchdog(98, Available from Firmware
v38)"): the firmware version is read at connect, the watchdog is never written to older motors,
and a ``WatchdogUnavailableWarning`` names them (they keep their last goal if the host dies).

Per control step: ``read_state`` is one sync read (fast sync read when the firmware answers it)
of the 21-byte block Present Current .. Present Temperature (27 bytes from Realtime Tick after the
first lost reply); ``write_goal_positions`` is one sync
write, clipped to the position limits first.

Errors: every status error byte is decoded. The alert bit means a latched hardware error, not a
failed instruction: the data is used and Hardware Error Status (70) is read and reported by name
(``MotorState.hardware_error``, ``bus.faults``). A missing or corrupt reply makes that motor
invalid in this read (NaN, ``valid`` False) - never the previous value. Protocol 2.0 status
packets carry no sequence number, so a *late* reply to an earlier request looks fresh; three
defences: after any failed transaction the driver waits ``settle_ms`` (default 10 ms) before the
next one, so late bytes arrive and are flushed by the SDK's ``clearPort``; a transaction that
consumed other status packets than it asked for (more, or of another length), or left bytes
waiting, is discarded whole; and from the first lost reply of a block read on, the block is read
with the motor's Realtime Tick in front (27 bytes instead of 21), so a reply later than the
timeout plus ``settle_ms`` that lands in the slot of a lost one is refused by its length or its
tick (``transactions``). Missing motors are retried once (``read_retries``), motors that timed
out last (so a dead motor does not take the replies after it along). After ``max_invalid_reads``
consecutive invalid reads of a motor, ``read_state`` raises ``BusError``. Unicast reads/writes retry
``retries`` times, then raise. ``reboot`` clears a latched error.

Lifecycle: torque off on ``disconnect`` (context-manager exit, also on exceptions), on SIGINT /
SIGTERM (then the previous handler runs) and at interpreter exit. If the host dies without any of
these (SIGKILL, power loss of the PC), the Bus Watchdog armed at torque-on stops the motors.

Where the parts live: settings, counters, errors and warnings in ``config``; register access, sync
reads and the late-reply defences in ``transactions``; torque on (goal := a fresh read per
motor) and confirmed torque off in ``torque_on``; the torque-off hooks in ``shutdown``;
``scan`` in ``scan``. This module keeps the bus: connect, read_state, goals, torque, faults.
It is over 600 lines because it is one class whose methods share one state (control-table
addresses, position limits, validity streaks, the fault cache, the torque set); the parts that
need none of it live in the modules above.

Why one module (over ~600 lines; issue 16 asks for the reason here): the bus's session state (port,
packet handler, id map, cached registers, torque and watchdog state) is shared by every public
method; its transactions, scan and shutdown already live beside it (``transactions``, ``scan``,
``shutdown``, ``config``).
"""

from __future__ import annotations

import logging
import math
import os
import warnings
from collections.abc import Sequence

import numpy as np
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from lowcostdex.errors import ConfigError, check_bool
from lowcostdex.hands import HandSpec
from lowcostdex.hardware import bus as _bus
from lowcostdex.hardware.bus import BusError, CommandError, MotorBus, MotorState
from lowcostdex.hardware.dynamixel import transport
from lowcostdex.hardware.dynamixel.config import (
    BusStats,
    DynamixelConfig,
    GainMismatchWarning,
    LatencyWarning,
    WatchdogUnavailableWarning,
)
from lowcostdex.hardware.dynamixel.control_table import (
    ControlTable,
    Reg,
    check_same_layout,
    load_control_table,
    model_name,
)
from lowcostdex.hardware.dynamixel.protocol import ALERT, hardware_error_names
from lowcostdex.hardware.dynamixel.shutdown import register as _register
from lowcostdex.hardware.dynamixel.shutdown import unregister as _unregister
from lowcostdex.hardware.dynamixel.torque_on import (
    arm_watchdog,
    disable_confirmed,
    enable_holding,
    hold_goal,
    torque_on_attempts,
)
from lowcostdex.hardware.dynamixel.transactions import BLOCK, TICK_BLOCK, SdkTransactions
from lowcostdex.motion import goal_write_time
from lowcostdex.sim.servo import ServoGains, motor_spec

log = logging.getLogger(__name__)

TWO_PI = 2.0 * math.pi
_LAYOUT = BLOCK + (Reg.GOAL_POSITION, Reg.TORQUE_ENABLE, Reg.BUS_WATCHDOG,
                   Reg.HARDWARE_ERROR_STATUS, Reg.MIN_POSITION_LIMIT, Reg.MAX_POSITION_LIMIT)
_FAULT_POLL = 0.5  # [s] re-read Hardware Error Status at most this often while an alert persists
_GOAL_PARAM = np.dtype([("id", "u1"), ("goal", "<i4")])  # one SYNC_WRITE slot of Goal Position
WATCHDOG_MIN_FIRMWARE = 38  # e-Manual: "Bus Watchdog(98, Available from Firmware v38)"
_GAIN_REGS = (Reg.POSITION_P_GAIN, Reg.POSITION_I_GAIN, Reg.POSITION_D_GAIN)


class DynamixelBus(SdkTransactions, MotorBus):
    """Dynamixel X-series motors on one serial line (see the module docstring).

    Args:
      port: device path (a U2D2 tty, a pty path) or a ``transport.DxlPort`` (e.g.
        ``EmulatedChain.port()``).
      config: driver settings.
    """

    def __init__(self, port: str | transport.DxlPort, config: DynamixelConfig):
        if isinstance(port, str):
            port = transport.DxlPort(port, config.latency_ms)
        elif not isinstance(port, transport.DxlPort):
            kind = "a plain PortHandler" if isinstance(port, PortHandler) else type(port).__name__
            raise ConfigError(f"port must be a path or a transport.DxlPort, got {kind}")
        self.config = config
        self.ids = tuple(config.ids)
        self.port = port
        self.ph = PacketHandler(2.0)
        self.tables: dict[int, ControlTable] = {
            i: load_control_table(m) for i, m in zip(self.ids, config.models, strict=True)}
        check_same_layout(self.tables, _LAYOUT)
        t = self.tables[self.ids[0]]
        self._addr = {r: t[r].address for r in _LAYOUT}
        self._set_block(TICK_BLOCK if config.realtime_tick else BLOCK)
        specs = [motor_spec(m) for m in config.models]
        self._tpr = np.array([s.ticks_per_rev for s in specs], float)
        self._current_unit = np.array([s.current_unit for s in specs])
        self._velocity_unit = np.array([s.velocity_unit for s in specs])
        self._index = {i: k for k, i in enumerate(self.ids)}
        self._lo = np.zeros(len(self.ids), np.int64)
        self._hi = np.full(len(self.ids), 4095, np.int64)
        self._streak = np.zeros(len(self.ids), int)
        self._silent: set[int] = set()  # ids that timed out in their last read: read them last
        # id -> (sample time, Realtime Tick, trusted) of its last reply (transactions._stale)
        self._ticks: dict[int, tuple[float, int, bool]] = {}
        self._unanswered: set[int] = set()  # ids a tick read got no accepted reply from since
        self._untrusted = 0  # replies kept as untrusted tick references so far
        self._hw_cache: dict[int, tuple[int, float]] = {}
        self.faults: dict[int, tuple[str, ...]] = {}
        self.firmware: dict[int, int] = {}
        self.gains: dict[int, ServoGains] = {}  # read at connect: Position P/I/D, PWM Limit
        self._no_watchdog: set[int] = set()  # ids whose firmware has no Bus Watchdog
        self.stats = BusStats()
        self.fast_read = False
        self._dirty = False
        self._sample_time = 0.0  # bus clock when the last sync read request went out [s]
        self._silence = 0.0
        self._connected = False
        self._torque_ids: set[int] = set()
        self.watchdog_tripped: set[int] = set()
        self._last_tx = -math.inf
        self._all = np.arange(len(self.ids))
        self.sysfs = transport.SYSFS_USB_SERIAL

    @classmethod
    def from_hand(cls, hand: HandSpec, port: str | transport.DxlPort, **overrides
                  ) -> DynamixelBus:
        """A bus for every motor of ``hand`` (joints then auxiliary motors), with position limits
        from the joint limits through each joint's calibration. ``overrides`` are
        ``DynamixelConfig`` fields."""
        joints = hand.all_joints
        limits = []
        for j in joints:
            a, b = sorted((j.calibration.to_motor(j.low), j.calibration.to_motor(j.high)))
            limits.append((a, b))
        kwargs = dict(ids=tuple(j.motor_id for j in joints), models=(hand.motor,) * len(joints),
                      position_limits=tuple(limits))
        kwargs.update(overrides)
        return cls(port, DynamixelConfig(**kwargs))

    # -- lifecycle -------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        if self._connected:
            return
        self.port.baudrate = self.config.baudrate
        try:
            opened = self.port.openPort()
        except Exception as exc:  # pyserial raises SerialException/OSError subclasses
            raise BusError(f"cannot open {self.port.getPortName()}: {exc}") from exc
        if not opened:
            raise BusError(f"cannot open {self.port.getPortName()} at {self.config.baudrate} bps")
        try:
            self._check_latency()
            self._handshake()
            self._configure()
            self._probe_fast_read()
        except BaseException:
            self._close_port()
            raise
        self._connected = True
        self.stats = BusStats()
        if self.config.handle_signals:
            _register(self)

    def disconnect(self) -> None:
        if not self._connected:
            self._close_port()
            return
        try:
            if self.config.torque_off_on_close:
                self._torque_off_best_effort()
        finally:
            self._connected = False
            self._closed = True
            _unregister(self)
            self._close_port()

    def _close_port(self) -> None:
        if self.port.is_open:
            self.port.is_using = False
            self.port.closePort()

    def clock(self) -> float:
        return self.port.now()

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` on the bus clock; while torque may be on with the watchdog armed, the
        motors are read every half watchdog period so the watchdog does not trip."""
        wd = self.config.watchdog_ms / 1000.0
        if not self._connected or wd <= 0:
            self.port.sleep(seconds)
            return
        end = self.clock() + seconds
        while (left := end - self.clock()) > 0:
            self.port.sleep(min(left, wd / 2))
            if end - self.clock() > 0:
                self._read_block(self.ids, fast=self.fast_read)

    # -- start-up ----------------------------------------------------------------------------------
    def _check_latency(self) -> None:
        if self.port.is_emulated:
            return
        path = self.port.getPortName()
        value = transport.usb_latency_timer(path, self.sysfs)
        if value is None:
            log.info("%s is not a USB-serial adapter; assuming latency %.1f ms", path,
                     self.config.latency_ms)
            return
        self.port.latency_ms = max(float(value), 1.0)
        if value > 1:
            tty = os.path.basename(os.path.realpath(path))
            where = self.sysfs / tty / "latency_timer"
            warnings.warn(f"USB latency timer of {path} is {value} ms; "
                          + transport.LATENCY_ADVICE.format(path=where), LatencyWarning,
                          stacklevel=3)

    def _handshake(self) -> None:
        found = {i: self.ping(i) for i in self.ids}
        rows = []
        for i, expected in zip(self.ids, self.config.models, strict=True):
            got = found[i]
            if got is None:
                rows.append(f"  {i:>3}  {expected:<12} no reply")
            elif model_name(got[0]) != expected:
                rows.append(f"  {i:>3}  {expected:<12} found {model_name(got[0])} ({got[0]})")
        if rows:
            raise BusError("motor check failed on " + self.port.getPortName() + " at "
                           + f"{self.config.baudrate} bps:\n   id  expected     problem\n"
                           + "\n".join(rows))
        self.firmware = {i: found[i][1] if found[i][1] >= 0
                         else self.read_register(i, Reg.FIRMWARE_VERSION) for i in self.ids}
        self._no_watchdog = {i for i, fw in self.firmware.items()
                             if fw < WATCHDOG_MIN_FIRMWARE}
        if self._no_watchdog and self.config.watchdog_ms:
            old = ", ".join(f"{i} (v{self.firmware[i]})" for i in sorted(self._no_watchdog))
            warnings.warn(f"motors {old} have firmware older than v{WATCHDOG_MIN_FIRMWARE}, "
                          "which has no Bus Watchdog: they will not stop by themselves if this "
                          "host dies with torque on. Update their firmware (DYNAMIXEL Wizard 2.0, "
                          "Firmware Update) to get the watchdog.", WatchdogUnavailableWarning,
                          stacklevel=3)

    def _watchdog_ids(self, ids: Sequence[int]) -> tuple[int, ...]:
        """The ids among ``ids`` whose firmware has a Bus Watchdog."""
        return tuple(i for i in ids if i not in self._no_watchdog)

    def _configure(self) -> None:
        cfg = self.config
        for k, i in enumerate(self.ids):
            self.write_register(i, Reg.TORQUE_ENABLE, 0)
            self._ensure(i, Reg.RETURN_DELAY_TIME, cfg.return_delay)
            self._ensure(i, Reg.OPERATING_MODE, cfg.operating_mode)
            if cfg.position_limits is not None:
                lo, hi = self._limit_ticks(k, *cfg.position_limits[k])
                if self.read_register(i, Reg.MIN_POSITION_LIMIT) > hi:
                    self._ensure(i, Reg.MAX_POSITION_LIMIT, hi)
                    self._ensure(i, Reg.MIN_POSITION_LIMIT, lo)
                else:
                    self._ensure(i, Reg.MIN_POSITION_LIMIT, lo)
                    self._ensure(i, Reg.MAX_POSITION_LIMIT, hi)
            if cfg.position_gains is not None:
                for reg, value in zip(_GAIN_REGS, cfg.position_gains, strict=True):
                    self._ensure(i, reg, int(value))
            p, i_gain, d = (self.read_register(i, r) for r in _GAIN_REGS)
            self.gains[i] = ServoGains(position_p=p, position_i=i_gain, position_d=d,
                                       pwm_limit=self.read_register(i, Reg.PWM_LIMIT))
            if i not in self._no_watchdog:
                self.write_register(i, Reg.BUS_WATCHDOG, 0)  # clears a watchdog error, too
            if cfg.operating_mode == 3:
                self._lo[k] = self.read_register(i, Reg.MIN_POSITION_LIMIT)
                self._hi[k] = self.read_register(i, Reg.MAX_POSITION_LIMIT)
            else:
                self._lo[k], self._hi[k] = -1_048_575, 1_048_575
            bits = self.read_register(i, Reg.HARDWARE_ERROR_STATUS)
            self._note_hardware_error(i, bits)
        self._check_gains()

    def _check_gains(self) -> None:
        """Warn when motors run other gains than their model's factory gains (the simulation's
        default), naming the motors and both sets."""
        rows = []
        for i, model in zip(self.ids, self.config.models, strict=True):
            f, g = motor_spec(model).factory_gains(), self.gains[i]
            if (g.position_p, g.position_i, g.position_d) != (
                    f.position_p, f.position_i, f.position_d):
                rows.append(f"{i}: {g.position_p}/{g.position_i}/{g.position_d} (factory "
                            f"{f.position_p}/{f.position_i}/{f.position_d})")
        if rows:
            warnings.warn("Position P/I/D gains differ from the motor model's factory gains "
                          "that the simulation uses by default: " + "; ".join(rows)
                          + ". Simulate with bus.gains, or set DynamixelConfig.position_gains.",
                          GainMismatchWarning, stacklevel=3)

    def _limit_ticks(self, k: int, lo: float, hi: float) -> tuple[int, int]:
        tpr = self._tpr[k]
        a, b = math.ceil(lo * tpr / TWO_PI - 1e-9), math.floor(hi * tpr / TWO_PI + 1e-9)
        if self.config.operating_mode == 3:
            if a < -1 or b > tpr:
                raise ConfigError(f"motor {self.ids[k]}: position limits [{lo:.3f}, {hi:.3f}] "
                                  f"rad leave one turn; use operating_mode=4")
            a, b = max(a, 0), min(b, int(tpr) - 1)
        return a, b

    def _ensure(self, motor_id: int, reg: Reg, value: int) -> None:
        """Write an (EEPROM) item only if it differs: EEPROM has a limited number of writes."""
        if self.read_register(motor_id, reg) != value:
            self.write_register(motor_id, reg, value)

    def _probe_fast_read(self) -> None:
        mode = self.config.fast_read
        self.fast_read = mode == "on"
        if mode == "auto":
            valid, _, _ = self._read_block(self.ids, fast=True)
            self.fast_read = all(valid.values())
            self._dirty = False
        log.info("fast sync read %s", "on" if self.fast_read else "off")

    # -- per control step ---------------------------------------------------------------------------
    def read_state(self) -> MotorState:
        """One sync read of every motor's present block; invalid motors are NaN, never stale."""
        self._require_connected()
        self._check_watchdog_gap()
        # motors that timed out last time go last, so a dead one does not take the others along
        order = self.ids if not self._silent else tuple(
            sorted(self.ids, key=lambda i: i in self._silent))
        valid, err, raw = self._read_block(order, fast=self.fast_read)
        sampled = self._sample_time
        times = dict.fromkeys(order, sampled)  # a motor read in a retry was sampled then
        attempts, confirm = 0, True
        while attempts < self.config.read_retries:
            missing = [i for i in order if not valid[i]]
            if not missing:
                break
            self.stats.retries += 1
            silent, untrusted = len(self._silent), self._untrusted
            fresh = sorted(missing, key=lambda i: i in self._silent)
            v2, e2, r2 = self._read_block(tuple(fresh), fast=False)
            for i in fresh:
                if v2[i]:
                    valid[i], err[i], raw[i] = True, e2[i], r2[i]
                    times[i] = self._sample_time
            # a retry that found a new silent motor is free (it is read last next time);
            # bounded, since that can happen at most once per motor; so is one retry that kept
            # replies as new tick references (transactions._stale): the next confirms them
            free = len(self._silent) != silent
            if not free and confirm and self._untrusted != untrusted:
                free, confirm = True, False
            attempts += not free
        state = self._decode(valid, err, raw, sampled)
        state.sample_time = np.fromiter((times[i] for i in self.ids), float, len(self.ids))
        return state

    def goal_delay(self, n: int) -> float:
        """Upper bound [s] from now until a goal sync write for ``n`` motors reaches them: the
        settle wait still owed after a failed transaction, the packet's wire time (14 + 5 n
        bytes, 8N1) and one USB frame (1 ms) for the adapter to put it on the wire."""
        settle = self.config.settle_ms / 1000.0 if self._dirty else 0.0
        return settle + goal_write_time(n, self.config.baudrate)

    def _decode(self, valid: dict[int, bool], err: dict[int, int], raw: dict[int, bytes],
                t: float) -> MotorState:
        """Device units -> SI for every motor; NaN where invalid."""
        ids = self.ids
        all_ok = len(raw) == len(ids) and all(valid.values())
        if all_ok:
            ok = np.ones(len(ids), bool)
            rec = np.frombuffer(b"".join([raw[i] for i in ids]), self._dtype)
            status = np.fromiter((err[i] for i in ids), int, len(ids))
        else:
            ok = np.fromiter((valid[i] for i in ids), bool, len(ids))
            blank = bytes(self._block_len)
            rec = np.frombuffer(b"".join([raw[i] if valid[i] else blank for i in ids]),
                                self._dtype)
            status = np.fromiter((err[i] if valid[i] else -1 for i in ids), int, len(ids))
        rad = TWO_PI / self._tpr

        def field(reg: Reg, scale: np.ndarray | float) -> np.ndarray:
            out = rec[reg.name] * scale
            return out if all_ok else np.where(ok, out, np.nan)

        hw = np.where(ok, 0, -1)
        if np.any((status >= 0) & (status & ALERT != 0)) or self._hw_cache:
            for k, i in enumerate(ids):
                if ok[k]:
                    hw[k] = self._alert_bits(i, err[i])
        self._track_validity(ok, all_ok)
        return MotorState(
            position=field(Reg.PRESENT_POSITION, rad),
            velocity=field(Reg.PRESENT_VELOCITY, self._velocity_unit),
            current=field(Reg.PRESENT_CURRENT, self._current_unit),
            voltage=field(Reg.PRESENT_INPUT_VOLTAGE, 0.1),
            temperature=field(Reg.PRESENT_TEMPERATURE, 1.0),
            valid=ok, hardware_error=hw, timestamp=t,
            extra={"status_error": status,
                   "position_trajectory": field(Reg.POSITION_TRAJECTORY, rad)})

    def write_goal_positions(self, positions: np.ndarray, ids: Sequence[int] | None = None
                             ) -> np.ndarray:
        """Send goal positions [rad] in one sync write, clipped to the position limits.

        Returns the goals actually sent [rad]. Raises CommandError (nothing sent) on a wrong
        length or a non-finite value.
        """
        self._require_connected()
        ids = self.ids if ids is None else tuple(ids)
        self._check_watchdog_gap()
        stopped = self.watchdog_tripped.intersection(ids)
        if stopped:
            raise _bus.WatchdogTripped(sorted(stopped), self._silence)
        q = np.asarray(positions, dtype=float).reshape(-1)
        if q.shape[0] != len(ids):
            raise CommandError(f"{q.shape[0]} goals for {len(ids)} motors")
        if not np.all(np.isfinite(q)):
            bad = [i for i, v in zip(ids, q, strict=True) if not np.isfinite(v)]
            raise CommandError(f"non-finite goal for motors {bad}; nothing sent")
        if ids is self.ids:
            k = self._all
        else:
            try:
                k = np.array([self._index[i] for i in ids])
            except KeyError as exc:
                raise CommandError(f"motor {exc.args[0]} is not on this bus {self.ids}") from None
        ticks = np.clip(np.rint(q * self._tpr[k] / TWO_PI), self._lo[k], self._hi[k])
        param = np.empty(len(ids), _GOAL_PARAM)  # [id, goal (int32 LE)] per motor
        param["id"] = ids
        param["goal"] = ticks
        data = list(param.tobytes())
        self._begin()
        result = self.ph.syncWriteTxOnly(self.port, self._addr[Reg.GOAL_POSITION], 4, data,
                                         len(data))
        self.stats.transactions += 1
        if result != COMM_SUCCESS:
            self._dirty = True
            raise BusError(f"goal sync write failed: {self.ph.getTxRxResult(result)}")
        return ticks * TWO_PI / self._tpr[k]

    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> None:
        """Torque on/off. On: Goal Position := present (within one turn in position mode), torque
        on, Bus Watchdog armed. Raises PositionOutOfLimits (before any torque is on) when a motor
        sits outside its limits, MotorFault when a motor refuses because of a latched hardware
        error (reboot it)."""
        check_bool("enabled", enabled)  # "no" or "false" (a config string) turned torque on
        self._require_connected()
        ids = self.ids if ids is None else tuple(ids)
        absent = [i for i in ids if i not in self._index]
        if absent:  # before: 4 read attempts, then "no status packet"
            raise CommandError(f"motor {absent[0]} is not on this bus {self.ids}")
        if not enabled:
            failed = disable_confirmed(self, ids)
            if failed:
                raise BusError("torque off failed for " + "; ".join(failed))
            return
        tries = torque_on_attempts(self)  # a lossy bus is ridden out here, not by the caller
        present = self._present_ticks(ids, attempts=tries)
        for i in ids:  # every motor inside its limits before any torque is on
            hold_goal(self, i, present[i])
        for i in ids:
            if i not in self._no_watchdog:
                self.write_register(i, Reg.BUS_WATCHDOG, 0, tries=tries)
        for i in ids:  # each goal from a read just before it (torque_on)
            enable_holding(self, i)
            self._torque_ids.add(i)
            self.watchdog_tripped.discard(i)
        arm_watchdog(self, ids)

    def reboot(self, motor_id: int) -> None:
        """REBOOT a motor (clears latched hardware errors; torque is off afterwards) and wait
        until it answers again."""
        self._require_connected()
        def op():
            result, err = self.ph.reboot(self.port, motor_id)
            return (None, err), result, err

        self._unicast(motor_id, "reboot", op, 1)
        deadline = self.clock() + self.config.reboot_timeout
        while self.clock() < deadline:
            self.port.sleep(0.02)
            if self.ping(motor_id, retries=0) is not None:
                self._ticks.pop(motor_id, None)  # its Realtime Tick starts again
                self._hw_cache.pop(motor_id, None)
                self.faults.pop(motor_id, None)
                return
        raise BusError(f"motor {motor_id} did not answer within {self.config.reboot_timeout} s "
                       "after REBOOT")

    # -- transactions (the rest: transactions.SdkTransactions) ------------------------------
    def _check_watchdog_gap(self) -> None:
        """After a silence longer than the watchdog period, ask the motors with torque on whether
        their watchdog tripped (Bus Watchdog reads -1); they then ignore goal sync writes."""
        period = self.config.watchdog_ms / 1000.0
        silence = self.clock() - self._last_tx
        if period <= 0 or not self._torque_ids or silence < 0.9 * period:
            return
        self._silence = silence  # the gap that may have tripped them (WatchdogTripped says it)
        for i in sorted(self._watchdog_ids(self._torque_ids)):
            try:
                if self.read_register(i, Reg.BUS_WATCHDOG) == -1:
                    self.watchdog_tripped.add(i)
            except BusError:
                pass
        if self.watchdog_tripped:
            log.warning("bus watchdog stopped motors %s after %.0f ms of silence",
                        sorted(self.watchdog_tripped), 1000 * self._silence)

    def _present_ticks(self, ids: tuple[int, ...], attempts: int | None = None
                       ) -> dict[int, int]:
        """Present Position [ticks] of ``ids``, with bounded retries (``attempts``, default
        ``config.retries`` + 1; raises BusError, at once when no motor answered the first
        ``config.retries`` + 1); a late reply is refused by its Realtime Tick here too (torque-on
        checks the limits on this)."""
        out: dict[int, int] = {}
        attempts = self.config.retries + 1 if attempts is None else attempts
        for attempt in range(attempts):
            if not out and attempt == self.config.retries + 1:
                break  # not one reply: the bus is gone, not lossy
            todo = tuple(i for i in ids if i not in out)
            if not todo:
                break
            # retries one motor at a time: in a sync read, one lost reply voids the others
            for group in [todo] if attempt == 0 else [(i,) for i in todo]:
                valid, _, raw = self._read_block(group, fast=False)
                for i in group:
                    if valid[i]:
                        out[i] = self._position_ticks(raw[i])
        missing = [i for i in ids if i not in out]
        if missing:
            said = ("no motor answered: is the hand powered and its cable plugged in?"
                    if not out else f"no valid reply in {attempts} attempts")
            raise BusError(f"cannot read the present position of motors {missing} ({said})")
        return out

    def _position_ticks(self, raw: bytes) -> int:
        """Present Position [ticks] in a present block."""
        return int(np.frombuffer(raw, self._dtype)[Reg.PRESENT_POSITION.name][0])

    # -- faults ----------------------------------------------------------------------------------
    def _note_alert(self, motor_id: int, err: int) -> None:
        if err & ALERT and motor_id not in self._hw_cache:
            self._hw_cache[motor_id] = (-1, -math.inf)
        elif not err & ALERT:
            self._hw_cache.pop(motor_id, None)
            self.faults.pop(motor_id, None)

    def _alert_bits(self, motor_id: int, err: int) -> int:
        """Hardware Error Status of a motor whose reply carried ``err`` (0 without alert)."""
        if not err & ALERT:
            self._hw_cache.pop(motor_id, None)
            self.faults.pop(motor_id, None)
            return 0
        bits, when = self._hw_cache.get(motor_id, (-1, -math.inf))
        if bits < 0 or self.clock() - when > _FAULT_POLL:
            value = self._try_read(motor_id, self._addr[Reg.HARDWARE_ERROR_STATUS], 1)
            if value is not None:
                self._note_hardware_error(motor_id, value)
                bits = value
        return bits

    def _note_hardware_error(self, motor_id: int, bits: int) -> None:
        self._hw_cache[motor_id] = (bits, self.clock())
        if bits:
            names = hardware_error_names(bits)
            if self.faults.get(motor_id) != names:
                log.warning("motor %d: hardware error %s", motor_id, ", ".join(names))
            self.faults[motor_id] = names
        else:
            self.faults.pop(motor_id, None)

    def _track_validity(self, ok: np.ndarray, all_ok: bool = False) -> None:
        if all_ok:
            self._streak[:] = 0
            return
        self._streak = np.where(ok, 0, self._streak + 1)
        bad = np.flatnonzero(~ok)
        self.stats.invalid += len(bad)
        for k in bad:
            i = self.ids[k]
            self.stats.by_motor_invalid[i] = self.stats.by_motor_invalid.get(i, 0) + 1
        limit = self.config.max_invalid_reads
        if limit is not None and np.any(self._streak >= limit):
            dead = [self.ids[k] for k in np.flatnonzero(self._streak >= limit)]
            raise BusError(f"motors {dead} gave no valid reply in {limit} consecutive reads")

    def _require_connected(self) -> None:
        if not self._connected:
            if getattr(self, "_closed", False):  # used after close: the env's or the Robot's
                raise BusError(f"the bus on {self.port.getPortName()} was closed (by "
                               "Robot.close() or env.close()); make a new env with gym.make, "
                               "or connect() the Robot again")
            raise BusError("bus is not connected (call connect() or use it as a context manager)")

    # -- torque-off paths ----------------------------------------------------------------------------
    def _torque_off_best_effort(self) -> None:
        """Broadcast torque off (one packet reaches every motor), then confirm each motor."""
        self.emergency_torque_off()
        for i in self.ids:
            if self.port.gone:  # one line, not one per motor: the watchdog stops them
                log.warning("torque off not sent: the port stopped working (the motors' Bus "
                            "Watchdog stops them)")
                return
            try:
                self.write_register(i, Reg.TORQUE_ENABLE, 0)
            except BusError as exc:
                log.warning("torque off of motor %d not confirmed: %s", i, exc)

    def emergency_torque_off(self) -> None:
        """One SYNC_WRITE of Torque Enable = 0 to every motor; no status, safe in a handler."""
        if not self.port.is_open or self.port.gone:
            return
        self.port.is_using = False
        addr = self._addr[Reg.TORQUE_ENABLE]
        params = [b for i in self.ids for b in (i, 0)]
        try:
            self.ph.syncWriteTxOnly(self.port, addr, 1, params, len(params))
        except Exception as exc:  # a dying port must not mask the original problem
            log.warning("emergency torque off failed: %s", exc)
        self.port.is_using = False
