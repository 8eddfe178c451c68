"""The motor-bus interface: one small ABC that the Dynamixel bus (real or emulated) and the Allegro
CAN bus implement, so the Robot (safety, thermal guard, resets) is written once.

A bus speaks *motor* units in SI: motor angle [rad] = raw encoder ticks * 2 pi / ticks_per_rev
(tick 0 = 0 rad), velocity [rad/s], current [A], voltage [V], temperature [deg C]. Joint
calibration (``hands.Calibration``) is applied above the bus, by the Robot.

A read never returns stale values as fresh: every field comes with a per-motor ``valid`` flag, and
invalid entries are NaN.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.errors import LowcostdexError


class BusError(LowcostdexError, IOError):
    """Communication failed (no status packet, corrupt reply, port error) after bounded retries."""


class CommandError(LowcostdexError, ValueError):
    """A command was rejected before anything was sent (non-finite goal, wrong length, ...)."""


class WatchdogTripped(BusError):
    """Motors stopped by their bus watchdog (the host was silent too long); they refuse goals
    until ``set_torque(True, ids)`` re-arms them from their present position. Any bus whose
    motors stop themselves on a silent host raises it (the Dynamixel Bus Watchdog today), so
    the Robot's backend resumes after it without knowing the bus."""

    def __init__(self, motor_ids: Sequence[int], silence: float):
        self.motor_ids = tuple(motor_ids)
        super().__init__(f"motors {list(self.motor_ids)} were stopped by their bus watchdog after "
                         f"{silence * 1000:.0f} ms without a packet; call set_torque(True) to "
                         "resume from where they stopped")


class MotorFault(LowcostdexError, RuntimeError):
    """A motor reported a hardware error (overheating, overload, voltage, encoder, shock)."""

    def __init__(self, motor_id: int, flags: Sequence[str], message: str = ""):
        self.motor_id = motor_id
        self.flags = tuple(flags)
        super().__init__(message or f"motor {motor_id}: hardware error {', '.join(flags)}")


@dataclass
class MotorState:
    """One bus read of every motor, arrays aligned with ``MotorBus.ids``.

    Attributes:
      position: motor angle [rad].
      velocity: [rad/s].
      current: winding current [A].
      voltage: input voltage [V].
      temperature: [deg C].
      valid: True where the motor answered with a correct packet in this read.
      hardware_error: Hardware Error Status bits (0 = none), -1 where unknown.
      timestamp: host monotonic time the values were sampled [s] (for a sync read: when the
        request went out, not when the last reply came back).
      sample_time: per motor, when its values were sampled [s] (a motor answering only a
        retried read was sampled later than ``timestamp``); None: all at ``timestamp``.
      temperature_fault: per motor, its temperature sensor reported a fault in this read (the
        temperature is NaN: e.g. an Allegro byte >= 0x80); None: no bus-reported faults.
    """

    position: np.ndarray
    velocity: np.ndarray
    current: np.ndarray
    voltage: np.ndarray
    temperature: np.ndarray
    valid: np.ndarray
    hardware_error: np.ndarray
    timestamp: float = 0.0
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    sample_time: np.ndarray | None = None
    temperature_fault: np.ndarray | None = None

    @classmethod
    def invalid(cls, n: int, timestamp: float = 0.0) -> MotorState:
        nan = np.full(n, np.nan)
        return cls(nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy(),
                   np.zeros(n, bool), np.full(n, -1, int), timestamp)


class MotorBus(abc.ABC):
    """A chain of motors addressed by id.

    Implementations: ``DynamixelBus`` (dynamixel_sdk on a serial port, a pty, or the in-process
    emulator) and ``AllegroBus`` (python-can). Use as a context manager: leaving the block turns
    torque off and closes the port, also on exceptions.
    """

    ids: tuple[int, ...]

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the port, check the motors (ping, model numbers) and configure them."""

    @abc.abstractmethod
    def disconnect(self) -> None:
        """Torque off (best effort) and close the port. Idempotent."""

    @abc.abstractmethod
    def read_state(self) -> MotorState:
        """Read every motor's state in one bus transaction."""

    @abc.abstractmethod
    def write_goal_positions(self, positions: np.ndarray, ids: Sequence[int] | None = None
                             ) -> None:
        """Send goal positions [rad] (motor angles) in one transaction."""

    @abc.abstractmethod
    def set_torque(self, enabled: bool, ids: Sequence[int] | None = None) -> None:
        """Torque on/off for ``ids`` (default all). Turning on first sets goal := present."""

    def goal_delay(self, n: int) -> float:
        """Upper bound [s] on the time from now until goals for ``n`` motors written now take
        effect in the motors (pending bus waits plus the write's transmission); 0 if unknown."""
        return 0.0

    def reboot(self, motor_id: int) -> None:
        """Clear a latched hardware error by rebooting the motor (torque is off afterwards)."""
        raise NotImplementedError

    def clock(self) -> float:
        """The bus's time [s]: monotonic wall time, or bus time on an emulated virtual clock."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Wait on the bus's clock [s]; implementations keep hardware fail-safes (e.g. a bus
        watchdog) fed while waiting."""
        if seconds > 0:
            time.sleep(seconds)

    @property
    def connected(self) -> bool:
        return False

    def __enter__(self) -> MotorBus:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()
