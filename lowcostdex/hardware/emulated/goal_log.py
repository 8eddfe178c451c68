"""The device side's record of what reached the motors: every accepted goal (``GoalLog``) and each
Goal Position audited against the motor's true position (``GoalAudit``)."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.hardware.dynamixel.control_table import Reg


@dataclass
class GoalLog:
    """Every goal register write a motor accepted: bus time [s], motor id, register, value."""

    time: list[float] = field(default_factory=list)
    motor_id: list[int] = field(default_factory=list)
    reg: list[str] = field(default_factory=list)
    value: list[int] = field(default_factory=list)

    def append(self, t: float, motor_id: int, reg: Reg, value: int) -> None:
        self.time.append(t)
        self.motor_id.append(motor_id)
        self.reg.append(reg.value)
        self.value.append(value)

    def __len__(self) -> int:
        return len(self.time)

    def positions(self, motor_id: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(times [s], Goal Position values [ticks]) accepted by ``motor_id`` (default all)."""
        sel = [k for k, (r, m) in enumerate(zip(self.reg, self.motor_id, strict=True))
               if r == Reg.GOAL_POSITION.value and (motor_id is None or m == motor_id)]
        return (np.array([self.time[k] for k in sel]), np.array([self.value[k] for k in sel]))


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
