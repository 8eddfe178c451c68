"""The Robot: a hand spec plus a motor bus, with safety limits, guards, step timing and metrics.

Everything a long training run needs between a policy and the motors lives here, written once
for the D'Claw (Dynamixel) and the Allegro (CAN):

* joint units inside: the bus speaks motor angles, the Robot applies each joint's
  ``hands.Calibration`` both ways;
* every goal passes ``safety``: non-finite goals are rejected with nothing sent; goals are clipped
  to the joint limits and to a per-step motion bound (max_velocity x control period) around the
  present position; ``send`` returns what was actually sent;
* the bound acts on fresh state only: a goal is computed from the position read since the last
  goal went out; a joint whose read failed or was corrupt gets no new goal (it holds the one in
  force), counted in ``metrics.holds`` and flagged in ``telemetry()["held"]``;
* the bound holds where the goal arrives, not only where the position was sampled: the motor
  keeps moving between its sample and the goal's arrival (the read's replies, a retried read,
  the settle wait after a failed one, the host's own computing), so the bound is narrowed by
  ``motor_speed`` x that time (``RobotConfig.motor_speed``; ``lowcostdex.motion``, the rule the
  simulation's bound follows with a clean bus's time); a joint whose sample is so old that
  nothing is left holds;
* every read feeds the thermal and current guards (``guards``); critical motors are relaxed at
  once, and ``pause_if_hot`` rests the hand between episodes until it has cooled;
* ``step`` keeps the control rate on a monotonic clock (``timing.Rate``, overruns counted);
* ``metrics`` collects what a user wants to log after hours of training.

Use as a context manager: leaving the block turns torque off and closes the bus, also on
exceptions.

Why one module (over ~600 lines; issue 16 asks for the reason here): one control step (read ->
guards -> safety -> write -> timing) is a sequence over one Robot state; the safety limits, guards,
calibration, resets and trace already live beside it (``safety``, ``guards``, ``calibration``,
``reset*``, ``trace``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lowcostdex.errors import ConfigError, check_bool, check_choice, check_number, keyword_hints
from lowcostdex.hands import HandSpec, JointSpec
from lowcostdex.hardware.bus import BusError, MotorBus, MotorFault, MotorState
from lowcostdex.hardware.dynamixel.protocol import hardware_error_names
from lowcostdex.hardware.robot.guards import (
    CurrentConfig,
    CurrentGuard,
    PauseRecord,
    ThermalConfig,
    ThermalGuard,
)
from lowcostdex.hardware.robot.safety import UnsafeCommand, check_finite, check_units, clip_goal
from lowcostdex.hardware.timing import BusClock, Clock, Rate
from lowcostdex.motion import in_flight_step, joint_speeds
from lowcostdex.motors import MOTORS, MotorSpec

log = logging.getLogger(__name__)


class ThermalTimeout(BusError):
    """The motors did not cool below the resume threshold within ``max_pause``."""


@keyword_hints
@dataclass(frozen=True)
class RobotConfig:
    """Robot settings.

    Attributes:
      control_period: control step [s] (ROBEL's D'Claw turn task: 0.1).
      motion_scale: multiplies every joint's ``max_velocity`` for the per-step motion bound.
      motion_reference: what the motion bound is measured from: "present" (the present
        position; stiff position servos such as the D'Claw's) or "goal" (the previous goal, a
        rate limit for soft torque-driven joints such as the Allegro's host PD, whose position
        lags; the goal's lead over the present position is then bounded by ``max_lead`` steps).
      max_lead: see ``motion_reference`` [motion-bound steps].
      thermal: thermal guard thresholds.
      current: current guard thresholds.
      max_invalid_reads: consecutive reads a motor may miss before ``read`` raises BusError.
      max_reboots: reboots per motor per session when recovering from hardware errors.
      motor_speed: fastest a joint can move [rad/s, joint], by its own drive or pushed (contacts,
        the finger's swing); with ``motion_reference`` "present" the motion bound is narrowed by
        this times the time from the position's sample to the goal's arrival, so the goal leads
        the position *where it arrives* by at most the bound. None (the default):
        ``motion.motor_speed``, 1.5 x the hand's motor's no-load speed (``motors.MotorSpec``:
        XH430-W350 3.14 rad/s -> 4.71; the D'Claw's joints reached 4.06 rad/s in the emulated
        fault soak), 0 for the Allegro, whose motors have no spec; 0 turns the narrowing off.
        The simulation (``sim.envs.hand_env``) narrows its bound by the default speed and a
        clean bus's time (``motion.clean_in_flight``: 4.17 ms on the D'Claw, 9 % of its
        bound), so on a clean bus the robot and the policy's simulation apply the same bound
        (tests/test_backend_emulated.py checks that they agree).
    """

    control_period: float = 0.1
    motion_scale: float = 1.0
    motion_reference: str = "present"
    max_lead: float = 4.0
    thermal: ThermalConfig = ThermalConfig()
    current: CurrentConfig = CurrentConfig()
    max_invalid_reads: int = 5
    max_reboots: int = 2
    motor_speed: float | None = None

    def __post_init__(self) -> None:
        # finite numbers first: motion_scale=inf would lift the motion bound, control_period=100
        # (ms typed as s) would step once per 100 s; "0.1" would fail a comparison below
        check_number("RobotConfig.control_period [s]", self.control_period, 0, 1,
                     low_open=True)
        for name in ("motion_scale", "max_lead"):
            check_number(f"RobotConfig.{name}", getattr(self, name))
        for name in ("max_invalid_reads", "max_reboots"):
            check_number(f"RobotConfig.{name}", getattr(self, name), integer=True)
        if not self.control_period > 0:
            raise ConfigError("RobotConfig.control_period must be > 0")
        if not self.motion_scale > 0:
            raise ConfigError("RobotConfig.motion_scale must be > 0")
        check_choice("motion reference", self.motion_reference, ("present", "goal"))
        if not self.max_lead >= 1:
            raise ConfigError("RobotConfig.max_lead must be >= 1")
        if self.max_invalid_reads < 0 or self.max_reboots < 0:
            raise ConfigError("RobotConfig.max_invalid_reads and max_reboots must be >= 0")
        if self.motor_speed is not None and not 0 <= self.motor_speed < float("inf"):
            raise ConfigError(f"RobotConfig.motor_speed must be finite and >= 0 [rad/s], got "
                              f"{self.motor_speed}")


@dataclass
class RobotState:
    """One read in joint units, arrays aligned with ``Robot.joint_names``.

    Attributes:
      position: joint angles [rad] (NaN where invalid).
      velocity: [rad/s].
      current: [A] (NaN where the bus does not measure it).
      temperature: [deg C].
      voltage: [V].
      valid: fresh reading (n,) bool.
      hardware_error: Hardware Error Status bits (0 none, -1 unknown).
      time: clock time of the read [s].
      temperature_fault: the temperature sensor reported a fault (n,) bool (its temperature
        is NaN; ``MotorState.temperature_fault``).
    """

    position: np.ndarray
    velocity: np.ndarray
    current: np.ndarray
    temperature: np.ndarray
    voltage: np.ndarray
    valid: np.ndarray
    hardware_error: np.ndarray
    time: float
    temperature_fault: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


@dataclass
class RobotMetrics:
    """Counters and logs for long runs (``as_dict`` gives flat scalars for a metrics CSV).

    Attributes:
      steps: control steps.
      sent: goal writes.
      rejected: commands rejected (non-finite, bad shape).
      limit_clips / motion_clips: joint entries clipped by limits / by the motion bound.
      holds: joint entries not sent because their position was not read fresh (they hold).
      invalid_reads: motor readings missing or corrupt.
      faults: (time, joint, flags) of every hardware error seen.
      reboots: motor reboots.
      overloads: current-guard events.
      resets / reset_failures / reset_time / reset_attempts: auto-reset outcomes [s].
      pauses: thermal pauses (``PauseRecord``).
      thermal_relaxations: motors relaxed mid-episode at the critical temperature.
      max_temperature: hottest reading per joint [deg C].
    """

    steps: int = 0
    sent: int = 0
    rejected: int = 0
    limit_clips: int = 0
    motion_clips: int = 0
    holds: int = 0
    invalid_reads: int = 0
    faults: list[tuple[float, str, tuple[str, ...]]] = field(default_factory=list)
    reboots: int = 0
    overloads: int = 0
    resets: int = 0
    reset_failures: int = 0
    reset_attempts: int = 0
    reset_time: float = 0.0
    pauses: list[PauseRecord] = field(default_factory=list)
    thermal_relaxations: int = 0
    max_temperature: dict[str, float] = field(default_factory=dict)
    overruns: int = 0
    max_lateness: float = 0.0

    def as_dict(self) -> dict[str, float]:
        """Flat scalars for logging."""
        out: dict[str, float] = {
            k: float(getattr(self, k))
            for k in ("steps", "sent", "rejected", "limit_clips", "motion_clips", "holds",
                      "invalid_reads", "reboots", "overloads", "resets", "reset_failures",
                      "reset_attempts", "reset_time", "thermal_relaxations", "overruns",
                      "max_lateness")
        }
        out["faults"] = float(len(self.faults))
        out["pauses"] = float(len(self.pauses))
        out["pause_time"] = float(sum(p.duration for p in self.pauses))
        out["reset_success_rate"] = (self.resets / (self.resets + self.reset_failures)
                                     if self.resets + self.reset_failures else float("nan"))
        temps = [t for t in self.max_temperature.values() if np.isfinite(t)]
        out["max_temperature"] = max(temps) if temps else float("nan")
        return out


def motor_spec_of(hand: HandSpec) -> MotorSpec | None:
    """The hand's ``motors.MotorSpec`` (its thermal model), None for the Allegro."""
    return MOTORS.get(hand.motor)


def motor_limits(hand: HandSpec) -> tuple[float, float]:
    """(firmware temperature limit [deg C], stall current [A]) of the hand's motor model."""
    if hand.motor == "allegro":
        from lowcostdex.hardware.allegro.emulator import AllegroThermal

        return AllegroThermal().limit, float("inf")
    from lowcostdex.sim import servo

    m = servo.motor_spec(hand.motor)
    return m.thermal.limit, m.voltage / m.resistance


class Robot:
    """A hand on a bus.

    Args:
      hand: the hand spec (joints in action order, then auxiliary motors such as the valve).
      bus: a ``MotorBus`` whose ids include every joint's motor id.
      config: limits, guards, timing.
      clock: time source; default the bus's own (``MotorBus.clock``/``sleep``: virtual time on
        an emulated bus, the host's monotonic clock with fail-safes fed on a real one).
    """

    def __init__(self, hand: HandSpec, bus: MotorBus, config: RobotConfig = RobotConfig(),
                 clock: Clock | None = None):
        if not isinstance(config, RobotConfig):  # else an AttributeError deep in __init__
            raise ConfigError(f"config must be a RobotConfig, got {type(config).__name__}; "
                              "e.g. Robot(hand, bus, RobotConfig(control_period=0.1))"
                              + (" or RobotConfig(**settings)" if isinstance(config, dict)
                                 else ""))
        if not isinstance(hand, HandSpec):
            raise ConfigError(f"hand must be a HandSpec, got {type(hand).__name__}; load a JSON "
                              "spec with lowcostdex.hands.HandSpec.load(path), or "
                              "lowcostdex.hands.hand_spec('dclaw')")
        self.hand = hand
        self.bus = bus
        self.config = config
        self.clock: Clock = clock or BusClock(bus)
        self.joints: tuple[JointSpec, ...] = hand.all_joints
        self.joint_names = tuple(j.name for j in self.joints)
        self.action_joints = hand.joint_names
        missing = [j.motor_id for j in self.joints if j.motor_id not in bus.ids]
        if missing:
            raise ConfigError(f"bus has no motors {missing} for hand {hand.name}; "
                              f"bus ids: {list(bus.ids)}")
        self._bus_index = np.array([list(bus.ids).index(j.motor_id) for j in self.joints])
        self.low = np.array([j.low for j in self.joints])
        self.high = np.array([j.high for j in self.joints])
        self.max_step = (np.array([j.max_velocity for j in self.joints])
                         * config.control_period * config.motion_scale)
        self.speed = (joint_speeds(hand) if config.motor_speed is None
                      else np.full(len(self.joints), config.motor_speed))
        limit, stall = motor_limits(hand)
        limit = config.thermal.limit if config.thermal.limit is not None else limit
        self.thermal = ThermalGuard(config.thermal, limit, self.joint_names,
                                    motor_spec_of(hand))
        climit = config.current.limit if config.current.limit is not None else (
            config.current.fraction * stall)
        self.current_guard = CurrentGuard(config.current, np.full(len(self.joints), climit))
        self.rate = Rate(config.control_period, self.clock)
        self.metrics = RobotMetrics()
        self._present = np.full(len(self.joints), np.nan)
        self._fresh = np.zeros(len(self.joints), bool)  # read valid since the last goal sent
        self._sampled = np.full(len(self.joints), -np.inf)  # bus time of each valid position
        self.held = np.zeros(len(self.joints), bool)  # joints the last send held
        self._misses = np.zeros(len(self.joints), int)
        self._torque = np.zeros(len(self.joints), bool)
        self._reboots: dict[int, int] = {}
        self.last_state: RobotState | None = None
        self.last_sent = np.full(len(self.joints), np.nan)

    # -- lifecycle ------------------------------------------------------------------------------
    def connect(self) -> None:
        """Connect the bus (torque stays off) and take a first reading."""
        if not self.bus.connected:
            self.bus.connect()
        self.read()
        self.rate.restart()

    def close(self) -> None:
        """Torque off (best effort) and disconnect. Idempotent."""
        try:
            if self.bus.connected:
                self.bus.set_torque(False)
        except Exception as exc:  # the bus may be the reason we are closing
            log.warning("torque off on close failed: %s", exc)
        finally:
            self._torque[:] = False
            self.bus.disconnect()

    def __enter__(self) -> Robot:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- indexing -------------------------------------------------------------------------------
    def index(self, joints: Sequence[str] | None = None) -> np.ndarray:
        """Indices into ``joint_names`` of ``joints`` (default: the action joints; one name
        alone is that joint, not its letters)."""
        names = (self.action_joints if joints is None
                 else (joints,) if isinstance(joints, str) else tuple(joints))
        for n in names:
            check_choice("joint", n, self.joint_names)
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:  # two goals for one motor: which is sent depends on the order
            raise ConfigError(f"joint {', '.join(twice)} named twice in joints={list(names)}; "
                              "name each joint once")
        return np.array([self.joint_names.index(n) for n in names], dtype=int)

    def _ids(self, idx: np.ndarray) -> list[int]:
        return [self.joints[i].motor_id for i in idx]

    # -- reading --------------------------------------------------------------------------------
    def read(self) -> RobotState:
        """Read every motor, convert to joint units, feed the guards.

        Raises:
          BusError: a motor missed more than ``max_invalid_reads`` consecutive reads.
        """
        raw = self.bus.read_state()
        state = self._to_joint(raw)
        self._misses = np.where(state.valid, 0, self._misses + 1)
        self.metrics.invalid_reads += int(np.sum(~state.valid))
        self._present = np.where(state.valid, state.position, self._present)
        self._fresh = state.valid.copy()
        sampled = (raw.sample_time[self._bus_index] if raw.sample_time is not None
                   else np.full(len(self.joints), raw.timestamp))
        self._sampled = np.where(state.valid, sampled, self._sampled)
        if np.any(self._misses > self.config.max_invalid_reads):
            bad = [self.joint_names[i] for i in np.flatnonzero(
                self._misses > self.config.max_invalid_reads)]
            raise BusError(f"no valid reading from {', '.join(bad)} for "
                           f"{self.config.max_invalid_reads + 1} consecutive reads")
        self._record_faults(state)
        self._guard(state)
        self.last_state = state
        return state

    def _to_joint(self, raw: MotorState) -> RobotState:
        k = self._bus_index
        cal = [j.calibration for j in self.joints]
        pos = np.array([c.to_joint(p) for c, p in zip(cal, raw.position[k], strict=True)])
        vel = np.array([c.rate_to_joint(v) for c, v in zip(cal, raw.velocity[k], strict=True)])
        cur = np.array([c.sign * i for c, i in zip(cal, raw.current[k], strict=True)])
        valid = np.asarray(raw.valid[k], bool) & np.isfinite(pos)
        sensor = (np.zeros(len(k), bool) if raw.temperature_fault is None
                  else np.asarray(raw.temperature_fault, bool)[k])
        return RobotState(position=np.where(valid, pos, np.nan), velocity=vel, current=cur,
                          temperature=np.asarray(raw.temperature[k], float),
                          voltage=np.asarray(raw.voltage[k], float), valid=valid,
                          hardware_error=np.asarray(raw.hardware_error[k], int),
                          time=raw.timestamp, temperature_fault=sensor)

    def _record_faults(self, state: RobotState) -> None:
        for i in np.flatnonzero(state.hardware_error > 0):
            name = self.joint_names[i]
            bits = int(state.hardware_error[i])
            flags = hardware_error_names(bits)
            recent = [f for f in self.metrics.faults if f[1] == name]
            if not recent or recent[-1][2] != flags:
                self.metrics.faults.append((state.time, name, flags))
                log.warning("motor %s (%s): hardware error %s", self.joints[i].motor_id, name,
                            ", ".join(flags))

    def _guard(self, state: RobotState) -> None:
        for i, t in enumerate(state.temperature):
            if np.isfinite(t):
                name = self.joint_names[i]
                self.metrics.max_temperature[name] = max(
                    self.metrics.max_temperature.get(name, -np.inf), float(t))
        new = state.temperature_fault & ~self.thermal.sensor_fault
        if np.any(new):
            log.warning("temperature sensor fault: %s; left out of the thermal pause's "
                        "cool-down test while faulty", ", ".join(
                            self.joint_names[i] for i in np.flatnonzero(new)))
        stuck = self.thermal.stuck.copy()
        hot = self.thermal.update(state.temperature, state.temperature_fault, state.current,
                                  state.time)
        for i in np.flatnonzero(self.thermal.stuck & ~stuck):
            log.error("temperature sensor of %s stuck at %.0f deg C while its current heated "
                      "the winding by >= %.0f K (thermal model); the thermal guard cannot see "
                      "it, so it is kept relaxed: check the motor", self.joint_names[i],
                      state.temperature[i], self.thermal.config.stuck_rise)
        if np.any(hot):
            names = [self.joint_names[i] for i in np.flatnonzero(hot & ~self.thermal.stuck)]
            if names:
                log.warning("thermal guard: %s at >= %.1f deg C; torque off until the next "
                            "pause", ", ".join(names), self.thermal.critical)
            self.metrics.thermal_relaxations += int(np.sum(hot))
            self.torque(False, [self.joint_names[i] for i in np.flatnonzero(hot)])
        over = self.current_guard.update(state.current)
        if np.any(over):
            self.metrics.overloads += int(np.sum(over))
            log.info("current guard: %s overloaded; goal lead bounded for %d steps",
                        ", ".join(self.joint_names[i] for i in np.flatnonzero(over)),
                        self.config.current.relax_steps)

    @property
    def present(self) -> np.ndarray:
        """Last valid joint angles (n,) [rad] (NaN before any valid read)."""
        return self._present.copy()

    @property
    def faulted(self) -> list[str]:
        """Joints whose last read carried a hardware error."""
        if self.last_state is None:
            return []
        return [self.joint_names[i] for i in np.flatnonzero(self.last_state.hardware_error > 0)]

    # -- commanding -----------------------------------------------------------------------------
    def send(self, goal: np.ndarray, joints: Sequence[str] | None = None) -> np.ndarray:
        """Send joint goals [rad] for ``joints`` (default the action joints) after the safety
        gate; returns the goals in force afterwards (same shape).

        Each goal is bounded around the position read since the last goal went out (one read
        is taken here if a joint has none), the bound narrowed by what the joint may move
        before the goal arrives (``RobotConfig.motor_speed``); joints whose sample is too old
        to leave any room (the host stalled after the read) are read again first. A joint whose
        read failed or was corrupt, or whose sample still leaves no room, is held: no goal is
        sent to it, its previous goal stays in force (``held``, ``metrics.holds``).

        Raises:
          UnsafeCommand: non-finite entries, a wrong shape, or a joint never read validly
            (nothing is sent).
        """
        idx = self.index(joints)
        names = tuple(self.joint_names[i] for i in idx)
        try:
            g = check_finite(goal, names)
            check_units(g, self.low[idx], self.high[idx], names)
        except UnsafeCommand:
            self.metrics.rejected += 1
            raise
        if not np.all(self._fresh[idx]):
            self.read()
        present, fresh, max_step = self._gate_inputs(idx, names)
        if np.any(fresh & (max_step <= 0)):  # sampled too long ago (the host stalled): read now
            self.read()
            present, fresh, max_step = self._gate_inputs(idx, names)
        fresh = fresh & (max_step > 0)  # still nothing left (e.g. a retried read): hold
        relaxed = self.current_guard.relaxed[idx]
        max_step[relaxed] = np.minimum(max_step[relaxed], self.config.current.relaxed_step)
        if self.config.motion_reference == "goal":
            last = self.last_sent[idx]
            reference = np.where(np.isfinite(last), last, present)
            report = clip_goal(g, self.low[idx], self.high[idx], reference, max_step, present,
                               self.config.max_lead * max_step)
        else:
            report = clip_goal(g, self.low[idx], self.high[idx], present, max_step)
        self.held[:] = False
        self.held[idx] = ~fresh
        self.metrics.holds += int(np.sum(~fresh))
        self.metrics.limit_clips += int(np.sum(report.limit_clipped & fresh))
        self.metrics.motion_clips += int(np.sum(report.motion_clipped & fresh))
        if np.any(fresh):
            out = idx[fresh]
            motor = np.array([self.joints[i].calibration.to_motor(q)
                              for i, q in zip(out, report.goal[fresh], strict=True)])
            self.bus.write_goal_positions(motor, self._ids(out))
            self.metrics.sent += 1
            self.last_sent[out] = report.goal[fresh]
            self._fresh[out] = False
        if not np.all(fresh):
            log.debug("held %s: no fresh position read",
                      ", ".join(n for n, f in zip(names, fresh, strict=True) if not f))
        return np.where(fresh, report.goal, self.last_sent[idx])

    def _gate_inputs(self, idx: np.ndarray, names: tuple[str, ...]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(present positions, fresh flags, motion bound) of joints ``idx``: the bound narrowed
        by what each joint may move from its sample until the goal arrives."""
        present, fresh = self._present[idx], self._fresh[idx]
        if not np.all(np.isfinite(present)):
            self.metrics.rejected += 1
            missing = [n for n, p in zip(names, present, strict=True) if not np.isfinite(p)]
            raise UnsafeCommand(f"no valid present position for {missing}; nothing sent")
        max_step = self.max_step[idx].copy()
        if self.config.motion_reference == "present":
            arrival = self.bus.clock() + self.bus.goal_delay(int(np.sum(fresh)))
            max_step = in_flight_step(max_step, self.speed[idx], arrival - self._sampled[idx])
        return present, fresh, max_step

    def torque(self, enabled: bool, joints: Sequence[str] | None = None) -> None:
        """Torque on/off for ``joints`` (default: every joint, auxiliary motors included).

        Turning on writes goal := present first (the bus does), so nothing jumps.
        """
        check_bool("enabled", enabled)  # torque("off") would switch the motors on
        idx = np.arange(len(self.joints)) if joints is None else self.index(joints)
        if enabled:
            hot = idx[self.thermal.relaxed[idx]]
            if len(hot):
                raise UnsafeCommand(f"{[self.joint_names[i] for i in hot]} are relaxed by the "
                                    "thermal guard until the next pause; not enabling torque")
        self.bus.set_torque(enabled, self._ids(idx))
        self._torque[idx] = enabled
        self._fresh[idx] = False  # the motors hold (or sag) from here: the next goal reads first
        if enabled:
            self.last_sent[idx] = self._present[idx]

    def enable(self, joints: Sequence[str]) -> list[str]:
        """Torque on for ``joints`` where the motors accept it; returns the joints left limp
        because their motor refused (it sits outside its position limits)."""
        names = [joints] if isinstance(joints, str) else list(joints)  # as index(): one name
        try:
            self.torque(True, names)
            return []
        except BusError as exc:  # PositionOutOfLimits: find out which, one at a time
            log.info("torque on refused (%s); enabling joints one at a time", exc)
        limp = []
        for name in names:
            try:
                self.torque(True, [name])
            except BusError:
                limp.append(name)
        return limp

    @property
    def torque_enabled(self) -> np.ndarray:
        """Torque state as commanded by this Robot (n,) bool."""
        return self._torque.copy()

    def step(self, goal: np.ndarray, joints: Sequence[str] | None = None) -> RobotState:
        """One control step: send (safety gate), wait for the period, read.

        Returns the state read at the end of the period.
        """
        self.send(goal, joints)
        self.wait()
        return self.read()

    def wait(self) -> None:
        """Sleep until the next control tick; counts overruns."""
        self.rate.wait()
        self.current_guard.tick()
        self.metrics.steps += 1
        self.metrics.overruns = self.rate.stats.overruns
        self.metrics.max_lateness = self.rate.stats.max_lateness

    def rest(self, seconds: float) -> RobotState:
        """Let ``seconds`` pass without commanding, reading at the control period."""
        check_number("seconds", seconds, 0)
        end = self.clock.now() + seconds
        state = self.read()
        while self.clock.now() < end - 1e-9:
            self.clock.sleep(min(self.config.control_period, end - self.clock.now()))
            state = self.read()
        self.rate.restart()
        return state

    # -- thermal pause ---------------------------------------------------------------------------
    def pause_if_hot(self) -> PauseRecord | None:
        """At an episode boundary: if the thermal guard asked for a pause, rest until every motor
        is below the resume threshold (bounded by ``max_pause``). Returns the pause record.

        Raises:
          ThermalTimeout: the motors did not cool within ``max_pause``.
        """
        if not self.thermal.pause_pending:
            return None
        cfg = self.thermal.config
        state = self.read()
        start = self.clock.now()
        hottest = int(np.nanargmax(np.where(np.isfinite(state.temperature),
                                            state.temperature, -np.inf)))
        peak = float(state.temperature[hottest])
        log.warning("thermal pause: %s at %.1f deg C; resting until all < %.1f deg C%s",
                    self.joint_names[hottest], peak, self.thermal.resume,
                    "".join(f" (not {self.joint_names[i]}: sensor fault)"
                            for i in np.flatnonzero(state.temperature_fault)))
        enabled = self._torque.copy()
        if cfg.pause_mode == "torque_off":
            self.bus.set_torque(False)
            self._torque[:] = False
        else:
            self.send(self._present[self.index(self.joint_names)], self.joint_names)
        while not self.thermal.cooled(state.temperature):
            if self.clock.now() - start > cfg.max_pause:
                raise ThermalTimeout(f"motors still at {np.nanmax(state.temperature):.1f} deg C "
                                     f"after {cfg.max_pause:.0f} s pause (resume below "
                                     f"{self.thermal.resume} deg C)")
            self.clock.sleep(cfg.poll_interval)
            state = self.read()
        record = PauseRecord(start=start, duration=self.clock.now() - start, peak=peak,
                             hottest=self.joint_names[hottest],
                             end_max=float(np.nanmax(np.where(
                                 state.temperature_fault, np.nan, state.temperature))))
        self.thermal.end_pause(record)
        self.metrics.pauses.append(record)
        log.info("thermal pause over after %.0f s (max %.1f deg C)", record.duration,
                 record.end_max)
        if cfg.pause_mode == "torque_off" and np.any(enabled):
            self.torque(True, [self.joint_names[i] for i in np.flatnonzero(enabled)])
        self.rate.restart()
        return record

    # -- faults ---------------------------------------------------------------------------------
    def recover_faults(self) -> list[str]:
        """Reboot motors reporting hardware errors (bounded by ``max_reboots`` per motor).

        Returns the joints rebooted. Raises MotorFault when a motor is out of reboots.
        """
        state = self.read()
        rebooted = []
        for i in np.flatnonzero(state.hardware_error > 0):
            j = self.joints[i]
            n = self._reboots.get(j.motor_id, 0)
            flags = hardware_error_names(int(state.hardware_error[i]))
            if n >= self.config.max_reboots:
                raise MotorFault(j.motor_id, flags,
                                 f"motor {j.motor_id} ({j.name}): {', '.join(flags)} persists "
                                 f"after {n} reboots; check the hardware")
            self.bus.reboot(j.motor_id)
            self._reboots[j.motor_id] = n + 1
            self._torque[i] = False
            self.metrics.reboots += 1
            rebooted.append(j.name)
        if rebooted:
            self.read()
        return rebooted

    # -- telemetry ------------------------------------------------------------------------------
    def telemetry(self) -> dict[str, Any]:
        """Latest per-joint readings and the run's counters (for ``info`` and logs)."""
        s = self.last_state
        out: dict[str, Any] = dict(self.metrics.as_dict())
        if s is not None:
            out.update(current=s.current.copy(), temperature=s.temperature.copy(),
                       voltage=s.voltage.copy(), valid=s.valid.copy())
        out["held"] = self.held.copy()  # joints the last send held (no fresh position)
        out["pause_pending"] = self.thermal.pause_pending
        out["temperature_faults"] = self.thermal.sensor_fault.copy()  # flagged this session
        out["clock"] = self.clock.now()  # robot clock [s]: timestamps of recorded episodes
        return out
