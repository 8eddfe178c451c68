"""Clocks and the control-rate timer.

A ``Clock`` tells monotonic time and sleeps. ``RealClock`` is the host's; an emulated robot
brings a virtual clock whose ``sleep`` advances the emulated physics, so a control loop written
against ``Clock`` runs unchanged (and deterministically, faster than real time) on the emulator.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

from lowcostdex.errors import ConfigError


class Clock(Protocol):
    """Monotonic time [s] and sleep."""

    def now(self) -> float:
        """Monotonic time [s]."""

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` [s] pass (no-op for seconds <= 0)."""


class RealClock:
    """The host's monotonic clock."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class BusClock:
    """A bus's own clock as a ``Clock``: ``MotorBus.clock()`` and ``MotorBus.sleep()``.

    Waiting through the bus matters: an emulated bus advances its virtual time, and a real one
    keeps its fail-safes (the Dynamixel bus watchdog) fed while the host waits.
    """

    def __init__(self, bus) -> None:
        self.bus = bus

    def now(self) -> float:
        return self.bus.clock()

    def sleep(self, seconds: float) -> None:
        self.bus.sleep(seconds)


@dataclass
class RateStats:
    """Control-loop timing counters.

    Attributes:
      ticks: periods waited for.
      overruns: periods whose work took longer than the period.
      max_lateness: largest overrun [s].
    """

    ticks: int = 0
    overruns: int = 0
    max_lateness: float = 0.0


class Rate:
    """Keeps a loop at a fixed period on a monotonic clock.

    ``wait()`` sleeps until the next tick. When the work since the last tick took longer than
    the period, the overrun is counted and the schedule re-anchors at now (no burst of catch-up
    steps). ``restart()`` re-anchors after a blocking move (reset, pause).

    Args:
      period: control period [s].
      clock: the clock to use.
      tolerance: lateness [s] below which a tick is not counted as an overrun (OS jitter).
    """

    def __init__(self, period: float, clock: Clock, tolerance: float = 1e-3):
        if not period > 0:
            raise ConfigError(f"control period must be > 0, got {period}")
        self.period = period
        self.clock = clock
        self.tolerance = tolerance
        self.stats = RateStats()
        self._next = clock.now() + period

    def restart(self) -> None:
        """Start a new schedule: the next tick is one period from now."""
        self._next = self.clock.now() + self.period

    def wait(self) -> float:
        """Sleep until the next tick; returns the lateness [s] (0 when on time)."""
        now = self.clock.now()
        self.stats.ticks += 1
        late = now - self._next
        if late > self.tolerance:
            self.stats.overruns += 1
            self.stats.max_lateness = max(self.stats.max_lateness, late)
            self._next = now + self.period
            return late
        self.clock.sleep(self._next - now)
        self._next += self.period
        return 0.0
