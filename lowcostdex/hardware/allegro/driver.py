"""Allegro Hand v4 driver: a ``MotorBus`` over python-can with a host-side joint PD.

The v4 hand is torque-driven: it streams joint positions every period (3 ms = 333 Hz) and the
host answers each complete set of four FINGER_POSE frames with four SET_TORQUE frames. This
driver runs that loop: ``tau = kp (goal - q) - kd qdot`` per joint (qdot filtered from the
position stream), clamped per joint, sent as PWM (``allegro_can``) with the torque constant of
the hand's version read from HAND_INFO (1200 PWM counts per N m on a v4 hand, 800 on a v3 hand;
other versions are refused at connect). Joint temperatures are asked for with remote (RTR)
requests, as the reference drivers do (a v4 hand answers them whatever its streaming periods). ``write_goal_positions``
only changes the PD goal, so the Robot above (limits, thermal guard, resets) treats the Allegro
like a position-servo hand.

Two ways to run the loop:
  * ``threaded=True`` (hardware): a background thread blocks on the CAN bus and answers every
    pose set as it arrives;
  * ``threaded=False`` (emulation, tests): the caller pumps ``poll()``; a virtual clock
    (``allegro_emulator.LockstepClock``) does it once per emulated period, deterministically.

Units: joint angles [rad] (the Allegro reports joint angles, so motor angle == joint angle and
the hand spec's calibration is the identity), velocities [rad/s], torques [N m], temperatures
[deg C]. MotorState.current is NaN (the hand does not report current); the commanded torque of
each joint is in ``MotorState.extra["torque"]``.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import can
import numpy as np

from lowcostdex.errors import ConfigError, check_bool, check_number
from lowcostdex.hands import HandSpec, allegro_spec
from lowcostdex.hardware.allegro import protocol as proto
from lowcostdex.hardware.bus import BusError, CommandError, MotorBus, MotorState
from lowcostdex.hardware.timing import Clock, RealClock


class TemperatureSensorWarning(UserWarning):
    """A joint's TEMPERATURE byte is a sensor fault (>= 0x80): that joint reads NaN."""


@dataclass(frozen=True)
class AllegroGains:
    """Host-side PD gains: one value for every joint, or 16 values; None = the gains the
    simulated hand uses (``sim.models.allegro.AllegroPD()``: 600 / 1000 PWM counts per rad,
    15 / 30 per rad/s, over 1200 counts per N m, a two-set simplification of the v4 ROS PD
    controller's compiled-in fallback). ``AllegroGains.ros_launch()`` = the gains that
    controller is launched with (its gains_pd.yaml: 4000 counts per rad, 150-300 per rad/s),
    4-6.7x stiffer; ``AllegroGains.ros_fallback()`` = its compiled-in fallback exactly.

    Attributes:
      kp: stiffness [N m/rad].
      kd: damping [N m s/rad].
      velocity_filter: weight of the newest finite-difference velocity in the low-pass
        estimate, in (0, 1] (1 = no filtering).
      max_torque: extra clamp on |tau| [N m] below the firmware PWM clamps.
    """

    kp: float | tuple[float, ...] | None = None
    kd: float | tuple[float, ...] | None = None
    velocity_filter: float = 0.3
    max_torque: float = 0.7

    def __post_init__(self) -> None:
        kp, kd = self.arrays()
        for name, arr in (("kp", kp), ("kd", kd)):
            if np.any(arr < 0) or not np.all(np.isfinite(arr)):
                raise ConfigError(f"AllegroGains.{name} must be finite and >= 0")
        if not 0 < self.velocity_filter <= 1:
            raise ConfigError("AllegroGains.velocity_filter must be in (0, 1]")
        if not self.max_torque > 0:
            raise ConfigError("AllegroGains.max_torque must be > 0")

    @classmethod
    def ros_launch(cls, **kwargs) -> AllegroGains:
        """The gains the v4 ROS package launches its PD controller with (``AllegroPD.ros_launch``)."""
        from lowcostdex.sim.models.allegro import AllegroPD

        kp, kd = _pd_arrays(AllegroPD.ros_launch())
        return cls(kp=tuple(kp), kd=tuple(kd), **kwargs)

    @classmethod
    def ros_fallback(cls, **kwargs) -> AllegroGains:
        """That controller's compiled-in fallback gains (``AllegroPD.ros_fallback``)."""
        from lowcostdex.sim.models.allegro import AllegroPD

        kp, kd = _pd_arrays(AllegroPD.ros_fallback())
        return cls(kp=tuple(kp), kd=tuple(kd), **kwargs)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(kp (16,), kd (16,))."""
        n = proto.N_JOINTS
        default_kp, default_kd = _default_pd()
        kp = default_kp if self.kp is None else np.broadcast_to(np.asarray(self.kp, float), (n,))
        kd = default_kd if self.kd is None else np.broadcast_to(np.asarray(self.kd, float), (n,))
        return np.array(kp, float), np.array(kd, float)


def _default_pd() -> tuple[np.ndarray, np.ndarray]:
    from lowcostdex.sim.models.allegro import AllegroPD

    return _pd_arrays(AllegroPD())


def _pd_arrays(pd) -> tuple[np.ndarray, np.ndarray]:
    """(kp (16,), kd (16,)) of an ``AllegroPD`` in joint order."""
    from lowcostdex.hands import ALLEGRO_FINGERS

    gains = [pd.gains(f, k) for f in ALLEGRO_FINGERS for k in range(proto.JOINTS_PER_FINGER)]
    return np.array([g[0] for g in gains]), np.array([g[1] for g in gains])


def pd_torque(goal: np.ndarray, q: np.ndarray, qdot: np.ndarray, kp: np.ndarray, kd: np.ndarray,
              max_torque: float) -> np.ndarray:
    """Joint PD torque (16,) [N m] = clip(kp (goal - q) - kd qdot, +-max_torque)."""
    return np.clip(kp * (goal - q) - kd * qdot, -max_torque, max_torque)



def check_can_channel(channel: str, interface: str = "socketcan") -> None:
    """Raise BusError unless ``channel`` can be a SocketCAN interface on this machine: Linux
    lists the network interfaces (CAN ones too) in /sys/class/net. Other interfaces (pcan,
    kvaser, ...) are left to python-can. Nothing is opened."""
    import os
    import sys

    if interface != "socketcan":
        return
    if not sys.platform.startswith("linux"):
        raise BusError(f"CAN channel {channel!r}: SocketCAN needs Linux; on this system give "
                       "the adapter's python-can interface (e.g. interface='pcan')")
    if "/" in str(channel) or str(channel).startswith("tty"):  # not an interface name
        raise BusError(f"CAN channel {channel!r} is a device path, not a CAN network interface "
                       "(e.g. can0; `ip link` lists them); a serial device such as "
                       "/dev/ttyUSB0 is a D'Claw's Dynamixel bus, not the Allegro's")
    if not os.path.exists(os.path.join("/sys/class/net", str(channel))):
        raise BusError(f"CAN channel {channel!r}: no such network interface on this machine "
                       "(`ip link` lists them); plug in the CAN adapter and bring it up: "
                       f"sudo ip link set {channel} up type can bitrate 1000000")


def open_can_bus(interface: str, channel: str) -> can.BusABC:
    """``can.Bus`` at the Allegro's 1 Mbit/s; a channel that cannot be opened is a BusError
    naming it and the fix (python-can raises a bare OSError, e.g. errno 97 on a kernel without
    SocketCAN)."""
    check_can_channel(channel, interface)
    try:
        return can.Bus(interface=interface, channel=channel, bitrate=1_000_000)
    except (OSError, can.CanError) as exc:
        raise BusError(f"cannot open CAN channel {channel!r} ({interface}): {exc}; is the "
                       f"interface up? sudo ip link set {channel} up type can bitrate 1000000"
                       ) from exc

def _check_settings(device_id: object, period_ms: object, temperature_period_ms: object,
                    stale_after: object, timeout: object) -> None:
    """``AllegroBus``'s numbers, before any bus opens (before: device_id 2.5 and period_ms 2.5
    failed at connect in a bit operation / struct.pack, a negative temperature period turned the
    thermal guard blind, a NaN or negative stale_after read every joint invalid)."""
    check_number("Allegro device_id (the hand's 2-bit CAN id)", device_id, 0, 3, integer=True)
    check_number("period_ms (pose streaming period, ms)", period_ms, 1, 100, integer=True)
    check_number("temperature_period_ms (0: no temperatures, the thermal guard blind)",
                 temperature_period_ms, 0, 60_000, integer=True)
    check_number("stale_after [s]", stale_after, 0, low_open=True)
    check_number("timeout [s]", timeout, 0, low_open=True)


class AllegroBus(MotorBus):
    """The Allegro v4 on a CAN bus.

    Args:
      can_bus: an open python-can bus (e.g. ``can.Bus(interface="virtual", channel=...)``);
        None opens ``can.Bus(interface=interface, channel=channel, bitrate=1_000_000)`` on
        connect.
      interface, channel: used when ``can_bus`` is None (default socketcan ``can0``).
      hand: the hand spec (16 joints; ``motor_id`` = joint index 0..15).
      gains: PD gains.
      device_id: the hand's 2-bit CAN id.
      period_ms: pose streaming period requested from the hand [ms] (3 = 333 Hz).
      temperature_period_ms: interval of the temperature requests (RTR) [ms] (0: none; the
        temperatures then stay NaN and the thermal guard is blind).
      threaded: run the PD loop in a background thread (hardware) or in ``poll()``.
      clock: time source (a virtual clock when emulated); default the host's.
      stale_after: a joint whose last pose frame is older than this [s] reads invalid.
      timeout: bound on waiting for the hand's replies during connect [s].
      own_bus: shut ``can_bus`` down on disconnect (default: only a bus this driver opened).
    """

    def __init__(self, can_bus: can.BusABC | None = None, *, interface: str = "socketcan",
                 channel: str = "can0", hand: HandSpec | None = None,
                 gains: AllegroGains = AllegroGains(), device_id: int = 0, period_ms: int = 3,
                 temperature_period_ms: int = 100, threaded: bool = True,
                 clock: Clock | None = None, stale_after: float = 0.05, timeout: float = 1.0,
                 own_bus: bool | None = None):
        self.hand = hand or allegro_spec()
        if len(self.hand.joints) != proto.N_JOINTS:
            raise ConfigError(f"the Allegro has {proto.N_JOINTS} joints, spec has "
                              f"{len(self.hand.joints)}")
        self.ids = tuple(j.motor_id for j in self.hand.joints)
        if sorted(self.ids) != list(range(proto.N_JOINTS)):
            raise ConfigError("Allegro motor ids must be the joint indices 0..15")
        _check_settings(device_id, period_ms, temperature_period_ms, stale_after, timeout)
        check_bool("threaded", threaded)
        self._bus = can_bus
        self._given = can_bus is not None  # not reopened by connect() after a shutdown
        self._closed = False
        self._own_bus = can_bus is None if own_bus is None else own_bus
        self._interface, self._channel = interface, channel
        self.gains = gains
        self._kp, self._kd = gains.arrays()
        self.device_id = device_id
        self.period = period_ms * 1e-3
        self._period_ms = period_ms
        self._temperature_ms = temperature_period_ms
        self.threaded = threaded
        self._clock: Clock = clock or RealClock()
        self.stale_after = stale_after
        self.timeout = timeout
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected = False
        n = proto.N_JOINTS
        self._q = np.full(n, np.nan)
        self._qdot = np.zeros(n)
        self._stamp = np.full(n, -np.inf)  # clock time of each joint's last pose [s]
        self._fresh = np.zeros(proto.N_FINGERS, bool)  # fingers received since last PD cycle
        self._temperature = np.full(n, np.nan)
        self._temperature_raw = np.full(n, -1)  # last TEMPERATURE byte per joint (-1: none yet)
        self._goal = np.zeros(n)
        self._enabled = np.zeros(n, bool)
        self._tau = np.zeros(n)
        self._info: proto.HandInfo | None = None
        self._scale, self._pwm_max = proto.TORQUE_TO_PWM, proto.PWM_MAX  # set from HAND_INFO
        self._temperature_every = (max(1, round(temperature_period_ms / period_ms))
                                   if temperature_period_ms > 0 else 0)  # PD cycles
        self.cycles = 0  # PD cycles run
        self.bad_frames = 0  # frames with an unexpected length

    # -- lifecycle ------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        """Open the bus, query the hand (its version sets the torque constant), start the pose
        stream, wait for the first pose set and the first temperatures.

        Raises:
          ConfigError: the hand's hardware version is not one the driver knows (3 or 4).
          BusError: the hand does not answer within ``timeout``.
        """
        if self._connected:
            return
        if self._bus is None and self._closed and self._given:  # shut down at disconnect()
            raise BusError("this AllegroBus was given its CAN bus (an emulated hand's virtual "
                           "channel) and shut it down at disconnect(); make a new one "
                           "(emulated_allegro(), or gym.make for an env)")
        if self._bus is None:
            self._bus = open_can_bus(self._interface, self._channel)
        self._drain()
        self._send(proto.message(proto.SYSTEM_OFF, device_id=self.device_id))
        self._send(proto.message(proto.HAND_INFO, device_id=self.device_id, remote=True))
        self._wait(lambda: self._info is not None, "no HAND_INFO reply from the Allegro")
        self._scale, self._pwm_max = proto.torque_scale(self._info.major_version)
        self._send(proto.period_message(self._period_ms, 0, 0, self.device_id))
        if self._temperature_every:
            self.request_temperatures()
        self._wait(lambda: bool(np.all(np.isfinite(self._q))),
                   "no pose stream from the Allegro")
        if self._temperature_every:
            self._wait(lambda: bool(np.all(self._temperature_raw >= 0)),
                       "no TEMPERATURE replies from the Allegro")
            faults = self.temperature_faults
            if faults:
                warnings.warn(TemperatureSensorWarning(
                    "Allegro temperature sensor fault: "
                    + ", ".join(f"{self.hand.joints[j].name} reads 0x{b:02X}"
                                for j, b in faults.items())
                    + " (a byte >= 0x80 is not a temperature); these joints read NaN, so the "
                    "thermal guard cannot see them and a thermal pause cannot end; only the "
                    "hand's own high-temperature fault bit covers them"), stacklevel=2)
        with self._lock:
            self._goal = self._q.copy()
        self._connected = True
        if self.threaded:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="allegro-pd", daemon=True)
            self._thread.start()

    def disconnect(self) -> None:
        """Zero torques, servo off, stop streaming, close the bus (idempotent, best effort)."""
        if self._bus is None:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None
        with self._lock:
            self._enabled[:] = False
            self._tau[:] = 0.0
        try:
            for f in range(proto.N_FINGERS):
                self._send(proto.torque_message(f, np.zeros(4, int), self.device_id))
            self._send(proto.message(proto.SYSTEM_OFF, device_id=self.device_id))
            self._send(proto.period_message(0, 0, 0, self.device_id))
        except BusError:
            pass
        if self._own_bus:
            self._bus.shutdown()
            self._bus = None
        self._connected = False
        self._closed = True

    # -- MotorBus -------------------------------------------------------------------------------
    def read_state(self) -> MotorState:
        """Latest joint positions [rad], filtered velocities [rad/s], temperatures [deg C]."""
        self._check_connected()
        if not self.threaded:
            self.poll()
        now = self._clock.now()
        with self._lock:
            valid = (now - self._stamp) <= self.stale_after
            q = np.where(valid, self._q, np.nan)
            v = np.where(valid, self._qdot, np.nan)
            temp = self._temperature.copy()
            sensor_fault = self._temperature_raw >= proto.TEMPERATURE_SENSOR_FAULT
            tau = self._tau.copy()
            status = self._info.status if self._info else -1
        errors = np.full(proto.N_JOINTS, 0 if status >= 0 else -1, int)
        if status > 0 and status & proto.STATUS_HIGH_TEMPERATURE:
            errors[:] = proto.STATUS_HIGH_TEMPERATURE
        n = proto.N_JOINTS
        return MotorState(position=q, velocity=v, current=np.full(n, np.nan),
                          voltage=np.full(n, np.nan), temperature=temp, valid=valid,
                          hardware_error=errors, timestamp=now, extra={"torque": tau},
                          temperature_fault=sensor_fault)

    def write_goal_positions(self, positions: np.ndarray, ids: Sequence[int] | None = None
                             ) -> None:
        """Set PD goals [rad] for ``ids`` (default all); takes effect at the next pose set."""
        self._check_connected()
        idx = self._index(ids)
        pos = np.asarray(positions, float) if positions is not None else np.zeros(0)
        if pos.shape != (len(idx),):  # before: numpy's "cannot reshape array of size 3"
            raise CommandError(f"{pos.size} goals for {len(idx)} joints (ids "
                               f"{', '.join(map(str, np.asarray(self.ids)[idx]))}); nothing sent")
        if not np.all(np.isfinite(pos)):
            raise CommandError(f"goal positions must be finite, got {pos}; nothing sent")
        with self._lock:
            self._goal[idx] = pos

    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> None:
        """PD on/off per joint; turning on first sets goal := present. Servo on while any is."""
        check_bool("enabled", enabled)  # "no" or "false" (a config string) turned the PD on
        self._check_connected()
        idx = self._index(ids)
        with self._lock:
            if enabled:
                self._goal[idx] = np.where(np.isfinite(self._q[idx]), self._q[idx],
                                           self._goal[idx])
            self._enabled[idx] = enabled
            if not enabled:
                self._tau[idx] = 0.0
            any_on = bool(np.any(self._enabled))
        self._send(proto.message(proto.SYSTEM_ON if any_on else proto.SYSTEM_OFF,
                                 device_id=self.device_id))

    def clock(self) -> float:
        """Bus time [s]: the virtual clock when emulated, else the host's monotonic clock."""
        return self._clock.now()

    def sleep(self, seconds: float) -> None:
        """Wait [s]; on the lock-step virtual clock this runs the emulated hand and the PD."""
        self._clock.sleep(seconds)

    def torque_enabled(self) -> np.ndarray:
        """Per-joint PD enable flags (16,)."""
        with self._lock:
            return self._enabled.copy()

    def hand_info(self) -> proto.HandInfo | None:
        """The last HAND_INFO reply."""
        return self._info

    def request_info(self) -> None:
        """Ask the hand for HAND_INFO (status bits); the reply is handled by the loop."""
        self._send(proto.message(proto.HAND_INFO, device_id=self.device_id, remote=True))

    @property
    def temperature_faults(self) -> dict[int, int]:
        """Joints whose last TEMPERATURE byte is a sensor fault (joint index -> the byte); they
        read NaN (``protocol.temperatures_celsius``)."""
        with self._lock:
            raw = self._temperature_raw.copy()
        return {int(j): int(raw[j])
                for j in np.flatnonzero(raw >= proto.TEMPERATURE_SENSOR_FAULT)}

    def request_temperatures(self) -> None:
        """Ask the hand for the four fingers' TEMPERATURE frames (remote requests); the replies
        are handled by the loop."""
        for f in range(proto.N_FINGERS):
            self._send(proto.message(proto.TEMPERATURE + f, device_id=self.device_id,
                                     remote=True))

    @property
    def torque_constant(self) -> float:
        """PWM counts per N m of the connected hand's version (1200 v4, 800 v3)."""
        return self._scale

    # -- the loop -------------------------------------------------------------------------------
    def poll(self) -> int:
        """Handle every pending frame without blocking; returns the PD cycles run."""
        before = self.cycles
        while True:
            msg = self._bus.recv(timeout=0.0)
            if msg is None:
                break
            self._handle(msg)
        return self.cycles - before

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(timeout=0.05)
            except can.CanError:
                continue
            if msg is not None:
                self._handle(msg)

    def _handle(self, msg: can.Message) -> None:
        cmd, dev = proto.split_id(msg.arbitration_id)
        if dev != self.device_id or msg.is_remote_frame:
            return
        if proto.FINGER_POSE <= cmd < proto.FINGER_POSE + proto.N_FINGERS:
            if len(msg.data) != 8:
                self.bad_frames += 1
                return
            self._on_pose(cmd - proto.FINGER_POSE, proto.unpack4(msg.data))
        elif proto.TEMPERATURE <= cmd < proto.TEMPERATURE + proto.N_FINGERS:
            if len(msg.data) != 4:
                self.bad_frames += 1
                return
            f = cmd - proto.TEMPERATURE
            raw = proto.unpack_temperatures(msg.data)
            with self._lock:
                self._temperature_raw[4 * f:4 * f + 4] = raw
                self._temperature[4 * f:4 * f + 4] = proto.temperatures_celsius(raw)
        elif cmd == proto.HAND_INFO and len(msg.data) >= 7:
            self._info = proto.HandInfo.unpack(msg.data)

    def _on_pose(self, finger: int, raw: tuple[int, ...]) -> None:
        sl = slice(4 * finger, 4 * finger + 4)
        q = proto.raw_to_radians(np.array(raw))
        now = self._clock.now()
        alpha = self.gains.velocity_filter
        with self._lock:
            prev = self._q[sl]
            if np.all(np.isfinite(prev)):
                v = (q - prev) / self.period
                self._qdot[sl] = (1 - alpha) * self._qdot[sl] + alpha * v
            self._q[sl] = q
            self._stamp[sl] = now
            self._fresh[finger] = True
            complete = bool(np.all(self._fresh))
        if complete and self._connected:
            self._control_cycle()
        elif complete:
            self._fresh[:] = False

    def _control_cycle(self) -> None:
        with self._lock:
            self._fresh[:] = False
            tau = pd_torque(self._goal, self._q, self._qdot, self._kp, self._kd,
                            self.gains.max_torque)
            tau = np.where(self._enabled, tau, 0.0)
            self._tau = tau
        pwm = proto.torque_to_pwm(tau, self._scale, self._pwm_max)
        for f in range(proto.N_FINGERS):
            self._send(proto.torque_message(f, pwm[4 * f:4 * f + 4], self.device_id))
        self.cycles += 1
        if self.cycles % 100 == 0:
            self.request_info()
        if self._temperature_every and self.cycles % self._temperature_every == 0:
            self.request_temperatures()

    # -- helpers --------------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> None:
        try:
            self._bus.send(msg, timeout=0.01)
        except can.CanError as exc:
            raise BusError(f"CAN send failed: {exc}") from exc

    def _drain(self) -> None:
        while self._bus.recv(timeout=0.0) is not None:
            pass

    def _wait(self, done, what: str) -> None:
        start = self._clock.now()
        while not done():
            if self._clock.now() - start > self.timeout:
                raise BusError(f"{what} within {self.timeout} s")
            if self.threaded:
                msg = self._bus.recv(timeout=self.period)
                if msg is not None:
                    self._handle(msg)
            else:
                self._clock.sleep(self.period)
                self.poll()

    def _index(self, ids: Sequence[int] | None) -> np.ndarray:
        if ids is None:
            return np.arange(proto.N_JOINTS)
        bad = [i for i in ids if i not in self.ids]
        if bad:
            raise ConfigError(f"unknown Allegro joint ids {bad}; valid: 0..15")
        return np.array([self.ids.index(i) for i in ids], dtype=int)

    def _check_connected(self) -> None:
        if not self._connected:
            if getattr(self, "_closed", False):  # used after close: the env's or the Robot's
                raise BusError("the Allegro's CAN bus was closed (by Robot.close() or "
                               "env.close()); make a new env with gym.make (or a new "
                               "AllegroBus)")
            raise BusError("AllegroBus is not connected; call connect() or use `with`")
