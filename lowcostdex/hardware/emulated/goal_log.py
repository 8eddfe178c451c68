"""The device side's record of what reached the motors: every accepted goal (``GoalLog``), each
Goal Position audited against the motor's true position (``GoalAudit``), and the bounded logs an
emulator keeps over an hours-long run (``hardware.ringlog.RingLog``: the chain's events and
replies, their sizes here)."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.hardware.dynamixel.control_table import Reg

GOAL_LOG_CAPACITY = 1 << 20
"""Goal writes ``GoalLog`` keeps by default: about 3 h of a D'Claw at 10 Hz (9 goals a step),
19 MB; older entries are dropped (the audit keeps its own counts in constant memory)."""


EVENTS_KEPT = 10_000
"""Chain events (``EmulatedChain.events``) kept, the newest: watchdog trips, reboots, hardware
errors, physics lag (~230 bytes each measured with tracemalloc: ~2.3 MB when full)."""

REPLIES_KEPT = 1 << 16
"""Status replies ``EmulatedChain.reply_log`` keeps (``record_replies``), the newest: the last
11 min of a D'Claw read at 10 Hz (10 replies a step); ~170 bytes each (tracemalloc), ~11 MB."""


class GoalLog:
    """The goal register writes the motors accepted, newest ``capacity`` kept: bus time [s],
    motor id, register, value. A ring buffer, so a run of days holds the same memory as one
    of hours (``total`` counts every write, ``dropped`` those no longer kept).

    ``time``, ``motor_id``, ``value`` (arrays) and ``reg`` (register names) are in the order
    the writes arrived, oldest kept first.
    """

    def __init__(self, capacity: int = GOAL_LOG_CAPACITY):
        if capacity < 1:
            raise ValueError(f"GoalLog capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.total = 0
        size = min(self.capacity, 1024)  # grows by doubling up to the capacity
        self._t = np.empty(size)
        self._id = np.empty(size, np.int16)
        self._reg = np.empty(size, np.int8)
        self._value = np.empty(size, np.int64)
        self._names: list[str] = []  # register names, indexed by the codes in _reg

    def append(self, t: float, motor_id: int, reg: Reg, value: int) -> None:
        k = self.total % self.capacity
        if k >= len(self._t):  # still growing
            size = min(2 * len(self._t), self.capacity)
            self._t, self._id, self._reg, self._value = (
                np.resize(a, size) for a in (self._t, self._id, self._reg, self._value))
        if reg.value not in self._names:
            self._names.append(reg.value)
        self._t[k], self._id[k], self._value[k] = t, motor_id, value
        self._reg[k] = self._names.index(reg.value)
        self.total += 1

    def __len__(self) -> int:
        return min(self.total, self.capacity)

    @property
    def dropped(self) -> int:
        """Writes no longer kept (the oldest)."""
        return self.total - len(self)

    @property
    def nbytes(self) -> int:
        """Memory the kept entries take [bytes] (bounded by the capacity)."""
        return sum(a.nbytes for a in (self._t, self._id, self._reg, self._value))

    def _ordered(self, a: np.ndarray) -> np.ndarray:
        n = len(self)
        if self.total <= self.capacity:
            return a[:n].copy()
        k = self.total % self.capacity
        return np.concatenate([a[k:], a[:k]])

    @property
    def time(self) -> np.ndarray:
        return self._ordered(self._t)

    @property
    def motor_id(self) -> np.ndarray:
        return self._ordered(self._id).astype(int)

    @property
    def value(self) -> np.ndarray:
        return self._ordered(self._value)

    @property
    def reg(self) -> list[str]:
        return [self._names[c] for c in self._ordered(self._reg)]

    def positions(self, motor_id: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(times [s], Goal Position values [ticks]) accepted by ``motor_id`` (default all)."""
        if Reg.GOAL_POSITION.value not in self._names:
            return np.array([]), np.array([], np.int64)
        sel = self._ordered(self._reg) == self._names.index(Reg.GOAL_POSITION.value)
        if motor_id is not None:
            sel &= self._ordered(self._id) == motor_id
        return self.time[sel], self.value[sel]


@dataclass
class GoalAudit:
    """Device-side audit of every Goal Position a motor accepted, in constant memory.

    Each goal [rad, joint, true mounting] is compared with the motor's *true* joint position
    (the physics' qpos, before any encoder effect) at two moments:

    * when the motor last sampled its Present Position for a read (the reading a host that
      bounds goals around fresh positions computed this goal from): the ``read lead``;
    * when the goal arrived (the motor may have moved since that sample): the ``lead``.

    Per motor it keeps the count, the largest of both leads, the longest time from the sample
    to the goal, the extreme goals, and counts of goals beyond the bounds set with ``watch``;
    ``recent`` keeps the last receipts. (The lead at receipt exceeds the read lead by what the
    motor moved between the sample and the goal's arrival: a few ms on a clean bus, tens of ms
    when the host retried a read.)

    Attributes:
      count: goals accepted per motor id.
      max_lead: largest |goal - true position at receipt| per motor id [rad].
      max_read_lead: largest |goal - true position at the last sample| per motor id [rad].
      max_age: longest time from the last sample to a goal's receipt per motor id [s].
      low, high: smallest and largest goal per motor id [rad, joint].
      lead_violations: goals whose read lead exceeded the watched motion bound, per motor id.
      arrival_excess: largest lead at receipt beyond the watched motion bound (and limit
        allowance), per watched motor id [rad]: what the motor moved between sample and goal.
      limit_violations: goals outside the watched joint limits, per motor id.
      recent: the last receipts (bus time [s], motor id, goal, true position at receipt, true
        position at the last sample [rad], time since that sample [s]).
    """

    count: dict[int, int] = field(default_factory=dict)
    max_lead: dict[int, float] = field(default_factory=dict)
    max_read_lead: dict[int, float] = field(default_factory=dict)
    max_age: dict[int, float] = field(default_factory=dict)
    low: dict[int, float] = field(default_factory=dict)
    high: dict[int, float] = field(default_factory=dict)
    lead_violations: dict[int, int] = field(default_factory=dict)
    limit_violations: dict[int, int] = field(default_factory=dict)
    arrival_excess: dict[int, float] = field(default_factory=dict)
    recent: deque[tuple[float, int, float, float, float, float]] = field(
        default_factory=lambda: deque(maxlen=1024))
    _bounds: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    _sample: dict[int, tuple[float, float]] = field(default_factory=dict)

    def watch(self, motor_id: int, max_step: float, low: float = -math.inf,
              high: float = math.inf) -> None:
        """From now on count goals of ``motor_id`` outside ``[low, high]`` [rad, joint], or
        leading the true position at the last sample by more than ``max_step`` [rad] (plus, for
        a joint sampled outside ``[low, high]``, its distance from them: the limits win over
        the motion bound, its goal is the nearest limit)."""
        self._bounds[motor_id] = (max_step, low, high)
        self.lead_violations.setdefault(motor_id, 0)
        self.limit_violations.setdefault(motor_id, 0)
        self.arrival_excess.setdefault(motor_id, -math.inf)

    def sampled(self, t: float, motor_id: int, true: float) -> None:
        """The motor sampled its Present Position at bus time ``t`` [s]; true position [rad]."""
        self._sample[motor_id] = (t, true)

    def record(self, t: float, motor_id: int, goal: float, true: float) -> None:
        """One accepted goal [rad] at bus time ``t`` [s] and the true joint position [rad]."""
        t_read, at_read = self._sample.get(motor_id, (t, true))
        lead, read_lead, age = abs(goal - true), abs(goal - at_read), t - t_read
        self.count[motor_id] = self.count.get(motor_id, 0) + 1
        self.max_lead[motor_id] = max(self.max_lead.get(motor_id, 0.0), lead)
        self.max_read_lead[motor_id] = max(self.max_read_lead.get(motor_id, 0.0), read_lead)
        self.max_age[motor_id] = max(self.max_age.get(motor_id, 0.0), age)
        self.low[motor_id] = min(self.low.get(motor_id, math.inf), goal)
        self.high[motor_id] = max(self.high.get(motor_id, -math.inf), goal)
        self.recent.append((t, motor_id, goal, true, at_read, age))
        bound = self._bounds.get(motor_id)
        if bound is not None:
            max_step, low, high = bound
            outside = max(low - at_read, at_read - high, 0.0)
            self.lead_violations[motor_id] += read_lead > max_step + outside
            self.arrival_excess[motor_id] = max(self.arrival_excess[motor_id],
                                                lead - max_step - outside)
            self.limit_violations[motor_id] += not low <= goal <= high

    @property
    def violations(self) -> int:
        """Goals beyond a watched bound (motion or limits), all motors."""
        return sum(self.lead_violations.values()) + sum(self.limit_violations.values())
