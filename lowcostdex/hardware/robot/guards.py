"""Thermal and current guards: keep motors out of their firmware shutdowns during long training.

Neither guard talks to the bus; the Robot feeds them every read and acts on their verdicts.

Thermal guard (hysteresis; three thresholds set as margins below the firmware limit) [deg C]::

    resume  <  warn  <  critical  <  limit (firmware shutdown, e.g. 80 on X430 servos)

* at ``warn`` a pause is requested: at the next episode boundary the Robot lets the motors rest
  (torque off, or a low-effort hold) until every motor reads below ``resume``;
* at ``critical`` the hot motor is relaxed at once, mid-episode (torque off), so it never
  reaches the firmware limit even if an episode is long or the load extreme.

A motor whose temperature sensor is faulty (the bus says so: an Allegro byte >= 0x80 reads NaN)
is flagged (``sensor_fault``, kept for the session) and left out of the cool-down test while its
reading is faulty: it can never read "cool", and a pause waiting for it would never end.

A stuck sensor says nothing: its reading stays flat while the current heats the winding. With
the motor's thermal model (``servo.MotorSpec.winding_heating``, the simulation's dcmotor
model) the guard integrates the temperature the measured current makes from the reading at
which it last changed; when the model has risen ``stuck_rise`` K and the reading has not moved
by a whole degree, the sensor is stuck (``stuck``, flagged in ``sensor_fault``): the guard cannot
see that motor any more, so it is relaxed at once and at every later read, and a pause is
requested (the pause leaves it out of the cool-down test).

Current guard: a motor drawing more than ``limit`` for ``window`` consecutive reads is
overloaded; for ``relax_steps`` control steps its goal may only lead its present position by
``relaxed_step``, which bounds the position error and hence the current the firmware's P path
drives (a software version of Current Limit that does not latch like the firmware's overload
shutdown).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lowcostdex.errors import ConfigError, check_choice, check_fields, keyword_hints

PAUSE_MODES = ("torque_off", "hold")


@keyword_hints
@dataclass(frozen=True)
class ThermalConfig:
    """Thermal guard thresholds, as margins below the firmware shutdown temperature.

    Attributes:
      warn_margin: pause at the next episode boundary when a motor reaches limit - this [K].
      resume_margin: end the pause when every motor is below limit - this [K].
      critical_margin: relax a motor at once when it reaches limit - this [K].
      limit: firmware shutdown temperature [deg C]; None = the motor spec's (80 deg C for X430
        servos: warn 65, resume 50, critical 73).
      pause_mode: "torque_off" (motors limp, coolest) or "hold" (torque on, goal := present).
      poll_interval: temperature read interval while paused [s].
      max_pause: a pause longer than this raises ThermalTimeout (a fan or sensor is broken) [s].
      stuck_rise: the model's rise over a flat reading that makes a stuck sensor [K]
        (readings are whole degrees; 5 K leaves room for a model 5x too hot).
    """

    warn_margin: float = 15.0
    resume_margin: float = 30.0
    critical_margin: float = 7.0
    limit: float | None = None
    pause_mode: str = "torque_off"
    poll_interval: float = 1.0
    max_pause: float = 3600.0
    stuck_rise: float = 5.0

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first
        check_choice("thermal pause mode", self.pause_mode, PAUSE_MODES)
        if not self.stuck_rise > 1.0:
            raise ConfigError("ThermalConfig.stuck_rise must be > 1 K (readings are whole "
                              f"degrees), got {self.stuck_rise}")
        if not self.resume_margin > self.warn_margin > self.critical_margin >= 0:
            raise ConfigError("ThermalConfig: need resume_margin > warn_margin > "
                              f"critical_margin >= 0, got {self.resume_margin}, "
                              f"{self.warn_margin}, {self.critical_margin}")
        if not self.poll_interval > 0 or not self.max_pause > 0:
            raise ConfigError("ThermalConfig: poll_interval and max_pause must be > 0")


@keyword_hints
@dataclass(frozen=True)
class CurrentConfig:
    """Current (overload) guard.

    Attributes:
      limit: sustained current threshold [A]; None = ``fraction`` x the motor's stall current.
      fraction: see ``limit``.
      window: consecutive reads above the limit that make an overload.
      relaxed_step: largest goal lead over the present position of an overloaded motor [rad].
      relax_steps: control steps an overload relaxation lasts.
    """

    limit: float | None = None
    fraction: float = 0.6
    window: int = 5
    relaxed_step: float = 0.02
    relax_steps: int = 20

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first
        if self.limit is not None and not self.limit > 0:
            raise ConfigError("CurrentConfig.limit must be > 0")
        if not 0 < self.fraction <= 1:
            raise ConfigError("CurrentConfig.fraction must be in (0, 1]")
        if self.window < 1 or self.relax_steps < 1 or not self.relaxed_step > 0:
            raise ConfigError("CurrentConfig: window, relax_steps >= 1 and relaxed_step > 0")


@dataclass
class PauseRecord:
    """One thermal pause.

    Attributes:
      start: clock time the pause began [s].
      duration: [s].
      peak: hottest motor temperature when it began [deg C].
      hottest: name of that motor's joint.
      end_max: hottest temperature when it ended [deg C].
    """

    start: float
    duration: float
    peak: float
    hottest: str
    end_max: float


@dataclass
class ThermalGuard:
    """Tracks temperatures; decides pauses (between episodes) and immediate relaxations.

    Args:
      config: thresholds.
      limit: firmware shutdown temperature [deg C] (config.limit or the motor's).
      names: joint names aligned with the temperature arrays.
      motor: the motors' spec (``sim.servo.MotorSpec``) whose thermal model checks for stuck
        sensors; None (the Allegro: no current reading, no spec): no check.
    """

    config: ThermalConfig
    limit: float
    names: tuple[str, ...]
    motor: Any = None
    pause_pending: bool = False
    max_seen: np.ndarray = field(init=False)
    relaxed: np.ndarray = field(init=False)
    pauses: list[PauseRecord] = field(default_factory=list)
    relaxations: int = 0
    warnings: int = 0

    def __post_init__(self) -> None:
        self.max_seen = np.full(len(self.names), -np.inf)
        self.relaxed = np.zeros(len(self.names), bool)
        n = len(self.names)
        self.sensor_fault = np.zeros(n, bool)  # ever flagged (n,) bool
        self.stuck = np.zeros(n, bool)  # flat reading while the model heated (n,) bool
        self._faulty = np.zeros(n, bool)  # faulty in the last read
        self._flat = np.full(n, np.nan)  # reading since it last changed [deg C]
        self._model = np.full(n, np.nan)  # model temperature since then [deg C]
        self._time = np.nan  # time of the last read [s]

    @property
    def warn(self) -> float:
        """Temperature that requests a pause [deg C]."""
        return self.limit - self.config.warn_margin

    @property
    def resume(self) -> float:
        """Temperature below which a pause ends [deg C]."""
        return self.limit - self.config.resume_margin

    @property
    def critical(self) -> float:
        """Temperature at which a motor is relaxed mid-episode [deg C]."""
        return self.limit - self.config.critical_margin

    def update(self, temperature: np.ndarray, sensor_fault: np.ndarray | None = None,
               current: np.ndarray | None = None, time: float | None = None) -> np.ndarray:
        """Feed one read (n,) [deg C] (NaN = unknown), the motors whose sensor reported a
        fault in it (n,) bool, the winding currents (n,) [A] and the read's time [s]; returns
        the motors to relax now (n,) bool (newly critical or stuck ones; already relaxed motors
        are not repeated)."""
        t = np.asarray(temperature, float)
        if sensor_fault is not None:
            self._faulty = np.asarray(sensor_fault, bool).copy()
            self.sensor_fault |= self._faulty
        if self.motor is not None and current is not None and time is not None:
            self._check_stuck(t, np.asarray(current, float), float(time))
        known = np.isfinite(t)
        self.max_seen = np.where(known, np.maximum(self.max_seen, t), self.max_seen)
        if np.any(known & (t >= self.warn)) and not self.pause_pending:
            self.pause_pending = True
            self.warnings += 1
        hot = ((known & (t >= self.critical)) | self.stuck) & ~self.relaxed
        if np.any(hot):
            self.relaxed |= hot
            self.relaxations += int(np.sum(hot))
            self.pause_pending = True
        return hot

    def cooled(self, temperature: np.ndarray) -> bool:
        """True when every motor reads (validly) below ``resume``, leaving out the motors whose
        sensor reported a fault in the last read (``update``): their reading is no temperature
        (they stay flagged in ``sensor_fault``)."""
        t = np.asarray(temperature, float)[~(self._faulty | self.stuck)]
        return bool(np.all(np.isfinite(t)) and np.all(t < self.resume))

    def _check_stuck(self, t: np.ndarray, current: np.ndarray, now: float) -> None:
        """Integrate the thermal model since each reading last changed; flag ``stuck``."""
        dt = now - self._time if np.isfinite(self._time) else 0.0
        self._time = now
        if dt > 0:  # explicit Euler: reads come every 0.1-1 s, the winding's constant is ~100 s
            amps = np.where(np.isfinite(current), current, 0.0)  # unknown: no heat (no verdict)
            self._model += dt * self.motor.winding_heating(amps, self._model)
        moved = ~(np.abs(t - self._flat) < 1.0)  # a whole degree, or the first / a NaN read
        self._flat = np.where(moved, t, self._flat)
        self._model = np.where(moved, t, self._model)
        new = ~moved & (self._model - self._flat >= self.config.stuck_rise) & ~self.stuck
        if np.any(new):
            self.stuck |= new
            self.sensor_fault |= new

    def end_pause(self, record: PauseRecord) -> None:
        self.pauses.append(record)
        self.pause_pending = False
        self.relaxed[:] = False


@dataclass
class CurrentGuard:
    """Counts consecutive over-current reads per motor and holds relaxations.

    Args:
      config: thresholds.
      limit: sustained current threshold per motor (n,) [A].
    """

    config: CurrentConfig
    limit: np.ndarray
    over: np.ndarray = field(init=False)
    remaining: np.ndarray = field(init=False)
    events: int = 0

    def __post_init__(self) -> None:
        n = len(self.limit)
        self.over = np.zeros(n, int)
        self.remaining = np.zeros(n, int)

    def update(self, current: np.ndarray) -> np.ndarray:
        """Feed one read (n,) [A] (NaN = unknown); returns newly overloaded motors (n,) bool."""
        c = np.abs(np.asarray(current, float))
        above = np.isfinite(c) & (c > self.limit)
        self.over = np.where(above, self.over + 1, 0)
        new = (self.over >= self.config.window) & (self.remaining == 0)
        if np.any(new):
            self.events += int(np.sum(new))
            self.remaining[new] = self.config.relax_steps
        return new

    @property
    def relaxed(self) -> np.ndarray:
        """Motors whose goal lead is bounded now (n,) bool."""
        return self.remaining > 0

    def tick(self) -> None:
        """One control step passed."""
        self.remaining = np.maximum(self.remaining - 1, 0)
