"""The Dynamixel driver's settings (``DynamixelConfig``), its counters, and the errors and warnings
it raises."""

from __future__ import annotations

from dataclasses import dataclass, field

from lowcostdex.errors import ConfigError, check_bool, check_choice, check_number, keyword_hints
from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.bus import WatchdogTripped as WatchdogTripped  # its home is hardware.bus
from lowcostdex.hardware.dynamixel.control_table import Reg, load_control_table, value_range
from lowcostdex.hardware.dynamixel.protocol import BAUD_CODES, status_error_text

SDK_BAUDRATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
                 1_000_000, 1_152_000, 2_000_000, 2_500_000, 3_000_000, 3_500_000, 4_000_000)


def model_baudrates(model: str) -> tuple[int, ...] | None:
    """The bit rates [bit/s] a protocol-2.0 ``model``'s Baud Rate register offers (X-series
    codes ``protocol.BAUD_CODES`` over its Range column), None for protocol-1.0 firmware (its
    register is a divisor, not these codes)."""
    if "(1.0)" in model:
        return None
    lo, hi = value_range(Reg.BAUD_RATE, {}, model)
    return tuple(BAUD_CODES[c] for c in range(lo, hi + 1))


class LatencyWarning(UserWarning):
    """The USB-serial latency timer is above 1 ms (the loop will run far slower than the wire)."""


class GainMismatchWarning(UserWarning):
    """The motors' Position P/I/D gains are not their model's factory gains, which the
    simulation uses unless told otherwise."""


class WatchdogUnavailableWarning(UserWarning):
    """Motors with firmware older than v38 have no Bus Watchdog: nothing stops them if the host
    dies with torque on."""


class InstructionError(BusError):
    """A motor answered with an instruction error (access, range, limit, ...)."""

    def __init__(self, motor_id: int, what: str, error: int):
        self.motor_id, self.error = motor_id, error
        super().__init__(f"motor {motor_id}: {what}: {status_error_text(error)}")


class PositionOutOfLimits(BusError):
    """Torque-on refused: the motor sits outside its position limits (moved by hand?)."""


@keyword_hints
@dataclass(frozen=True)
class DynamixelConfig:
    """Driver settings.

    Attributes:
      ids: motor ids in the order of every array the bus returns or takes.
      models: expected model name per id (``ControlTable`` names, e.g. "XH430-W350").
      baudrate: bit rate [bit/s] (the SDK accepts up to 4 Mbps).
      latency_ms: USB latency timer assumed when sysfs cannot tell [ms].
      return_delay: Return Delay Time written at connect [2 us units] (0: answer at once).
      watchdog_ms: Bus Watchdog armed while torque is on [ms], multiple of 20, <= 2540; 0 = off.
      position_limits: (low, high) motor angle [rad] per id, written to Min/Max Position Limit
        and used to clip goals; None keeps the limits stored in the motors.
      operating_mode: Operating Mode written at connect (3 position, 4 extended position).
      position_gains: (P, I, D) written to Position P/I/D Gain at connect (when different);
        None keeps the motors' own gains. Either way they are read back into ``bus.gains``.
      fast_read: "auto" (probe), "on" or "off" for Fast Sync Read.
      read_retries: extra sync reads of the motors missing from a read.
      retries: extra attempts of a failed unicast read/write/ping.
      settle_ms: wait after a failed transaction before the next one [ms].
      realtime_tick: read Realtime Tick (address 120) with the block from the start. Without it
        the driver reads the 21-byte block until the first reply of a block read is lost, then
        switches to the 27-byte block with Realtime Tick for good (a late reply to an earlier
        request is refused by its length or its tick; Protocol 2.0 has no sequence number), so
        a clean bus keeps the timing the simulation's motion bound assumes
        (``motion.PRESENT_BLOCK_BYTES``; fast read of 10 motors at 1 Mbit/s 2.58 ms, 3.18 ms
        with the tick).
      max_invalid_reads: consecutive invalid reads of one motor before BusError; None = never.
      torque_off_on_close: turn torque off in ``disconnect``.
      handle_signals: turn torque off on SIGINT/SIGTERM (main thread only) and at exit.
      reboot_timeout: how long ``reboot`` waits for the motor to answer again [s].
    """

    ids: tuple[int, ...]
    models: tuple[str, ...]
    baudrate: int = 1_000_000
    latency_ms: float = 1.0
    return_delay: int = 0
    watchdog_ms: int = 100
    position_limits: tuple[tuple[float, float], ...] | None = None
    operating_mode: int = 3
    position_gains: tuple[int, int, int] | None = None
    fast_read: str = "auto"
    read_retries: int = 1
    retries: int = 3
    settle_ms: float = 10.0
    realtime_tick: bool = False
    max_invalid_reads: int | None = 50
    torque_off_on_close: bool = True
    handle_signals: bool = True
    reboot_timeout: float = 2.0

    def __post_init__(self) -> None:
        # types first: "false" for a flag is truthy (torque_off_on_close="no" would leave the
        # motors powered at close), NaN passes every comparison below
        for name in ("realtime_tick", "torque_off_on_close", "handle_signals"):
            check_bool(name, getattr(self, name))
        for name in ("latency_ms", "settle_ms", "reboot_timeout"):
            check_number(f"{name}", getattr(self, name), 0)
        for name in ("baudrate", "return_delay", "watchdog_ms", "read_retries", "retries"):
            check_number(name, getattr(self, name), 0, integer=True)
        check_number("max_invalid_reads", self.max_invalid_reads, 0, integer=True, none_ok=True)
        if not self.ids or len(set(self.ids)) != len(self.ids):
            raise ConfigError(f"ids must be unique and non-empty, got {self.ids}")
        if any(not 0 <= i <= 252 for i in self.ids):
            raise ConfigError(f"ids must be in 0..252, got {self.ids}")
        if len(self.models) != len(self.ids):
            raise ConfigError(f"{len(self.models)} models for {len(self.ids)} ids")
        for m in set(self.models):
            load_control_table(m)
        check_choice("baud rate", self.baudrate, SDK_BAUDRATES)
        for m in sorted(set(self.models)):  # a rate the servos cannot be set to: "no reply" x N
            rates = model_baudrates(m)
            if rates is not None and self.baudrate not in rates:
                raise ConfigError(
                    f"baud rate {self.baudrate}: a {m} cannot be set to it (its Baud Rate "
                    f"register offers {', '.join(map(str, rates))} bps); give one of those "
                    "(the factory rate: 57600; `lowcostdex scan` finds the motors' rate)")
        check_choice("fast_read", self.fast_read, ("auto", "on", "off"))
        check_choice("operating mode", self.operating_mode, (3, 4))
        if self.watchdog_ms % 20 or not 0 <= self.watchdog_ms <= 2540:
            raise ConfigError(f"watchdog_ms={self.watchdog_ms}: a multiple of 20 in 0..2540")
        if not 0 <= self.return_delay <= 254:
            raise ConfigError(f"return_delay={self.return_delay} outside 0..254")
        if self.position_gains is not None and (
                len(self.position_gains) != 3
                or not all(0 <= int(g) <= 16383 for g in self.position_gains)):
            raise ConfigError(f"position_gains={self.position_gains}: (P, I, D), each 0..16383")
        if self.latency_ms <= 0 or self.settle_ms < 0 or self.read_retries < 0 or self.retries < 0:
            raise ConfigError("latency_ms must be > 0; settle_ms, read_retries, retries >= 0")
        if self.position_limits is not None:
            if len(self.position_limits) != len(self.ids):
                raise ConfigError(f"{len(self.position_limits)} limits for {len(self.ids)} ids")
            for i, (lo, hi) in zip(self.ids, self.position_limits, strict=True):
                if not lo < hi:
                    raise ConfigError(f"motor {i}: position limit low {lo} must be < high {hi}")


@dataclass
class BusStats:
    """Counters since connect."""

    transactions: int = 0
    reads: int = 0
    invalid: int = 0  # motor-reads returned invalid
    timeouts: int = 0
    corrupt: int = 0
    contaminated: int = 0
    retries: int = 0
    stale: int = 0  # replies refused because their Realtime Tick had not advanced
    by_motor_invalid: dict[int, int] = field(default_factory=dict)
