"""Auto-reset procedures with verification: bounded, measured, and never blocking on a human.

Every procedure is a sequence of stages; each stage is a blocking move through the Robot's safety
gate (limits, motion bound, guards), verified per joint against a tolerance. A failed stage is
retried up to ``max_retries`` times, with a disentangle before each retry; when the retries are
spent the procedure raises ``ResetFailed`` naming the joints and their errors. There is no
``input()`` and no unbounded loop: a jammed valve or a broken finger ends in an exception after a
known, bounded time.

This module holds what every procedure shares: ``ResetConfig``, ``ResetFailed``, the
reports, ``move`` and ``verified_move`` (one stage), and ROBEL's disentangle. The procedures:
``reset_dclaw.DClawReset`` (the D'Claw), ``reset_robel.RobelReset`` (ROBEL's sequence, the
baseline), ``reset_allegro.AllegroReset`` (the Allegro and its valve), ``reset_flip.FlipBlockReset``
(the flip task's block).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.errors import ConfigError, LowcostdexError, check_fields, keyword_hints
from lowcostdex.hardware.robot.robot import Robot
from lowcostdex.sim.envs.task import wrap_angle


class ResetFailed(LowcostdexError, RuntimeError):
    """An auto-reset did not reach its target within its retries.

    Attributes:
      stage: the stage that failed last.
      errors: joint name -> final error of the joints outside tolerance [rad, or ``unit``].
      attempts: attempts made.
    """

    def __init__(self, stage: str, errors: dict[str, float], attempts: int, detail: str = "",
                 unit: str = "rad"):
        self.stage, self.errors, self.attempts = stage, dict(errors), attempts
        if unit == "rad":
            listed = ", ".join(f"{k} off by {math.degrees(v):.1f} deg" for k, v in errors.items())
        else:
            listed = ", ".join(f"{k} off by {v:.3f} {unit}" for k, v in errors.items())
        super().__init__(f"reset failed at stage '{stage}' after {attempts} attempt(s): "
                         f"{listed or 'no joint data'}{'; ' + detail if detail else ''}")


@keyword_hints
@dataclass(frozen=True)
class ResetConfig:
    """Reset tolerances, bounds and poses.

    Attributes:
      tolerance: per-joint verification tolerance for fingers [rad] (ROBEL: 5 deg).
      valve_tolerance: verification tolerance for the valve [rad].
      precision: the final finger move and the valve move go on until every joint is this
        close (or stalls), so episodes start reproducibly well inside the tolerance [rad].
      max_retries: attempts after the first one.
      move_timeout: bound on one finger move [s].
      valve_timeout: bound on the valve move [s] (ROBEL: 10 s).
      stall_time: a move ends early when no joint moved more than ``stall_motion`` in this
        window [s].
      stall_motion: [rad].
      settle: rest after a move before verifying [s].
      limp_rest: how long limp fingers hang (disentangle, recovery of joints found outside
        their limits) [s].
      recovery_passes: retract passes while middle joints are outside their limits.
      swing: disentangle swings the top joints to this fraction of their limit.
      corrections: passes that move a joint's goal by the error it still has (an integral
        correction for soft joints that sag under gravity: the Allegro's torque-driven PD;
        goals stay inside the limits). The D'Claw's stiff servos need none.
    """

    tolerance: float = math.radians(5.0)
    valve_tolerance: float = math.radians(3.0)
    precision: float = 0.01
    max_retries: int = 3
    move_timeout: float = 3.0
    valve_timeout: float = 10.0
    stall_time: float = 0.5
    stall_motion: float = math.radians(0.5)
    settle: float = 0.2
    limp_rest: float = 0.75
    recovery_passes: int = 3
    swing: float = 0.9
    corrections: int = 3

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first
        for name in ("tolerance", "valve_tolerance", "precision", "move_timeout", "valve_timeout",
                     "stall_time", "stall_motion"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"ResetConfig.{name} must be > 0")
        if self.max_retries < 0 or self.settle < 0 or self.limp_rest < 0:
            raise ConfigError("ResetConfig: max_retries, settle, limp_rest must be >= 0")
        if self.recovery_passes < 1:
            raise ConfigError("ResetConfig.recovery_passes must be >= 1")
        if self.corrections < 0:
            raise ConfigError("ResetConfig.corrections must be >= 0")


@dataclass
class MoveResult:
    """Outcome of one blocking move.

    Attributes:
      joints: joint names moved.
      errors: final |present - target| per joint [rad] (wrapped for angles that wrap).
      reached: every joint within tolerance.
      stalled: ended because nothing moved.
      duration: [s].
    """

    joints: tuple[str, ...]
    errors: np.ndarray
    reached: bool
    stalled: bool
    duration: float

    def outside(self, tolerance: float) -> dict[str, float]:
        pairs = zip(self.joints, self.errors, strict=True)
        return {n: float(e) for n, e in pairs if not e < tolerance}


@dataclass
class StageResult:
    """One verified stage: name, duration [s], largest error [rad], ok."""

    name: str
    duration: float
    max_error: float
    ok: bool


@dataclass
class ResetReport:
    """A finished reset.

    Attributes:
      success: every stage verified.
      attempts: attempts used (1 = no retry).
      duration: wall (or virtual) time of the whole reset [s].
      stages: every stage run, in order.
      pause: seconds spent in a thermal pause first.
    """

    success: bool
    attempts: int
    duration: float
    stages: list[StageResult] = field(default_factory=list)
    pause: float = 0.0


def move(robot: Robot, target: np.ndarray, joints: Sequence[str], *, tolerance: float,
         timeout: float, stall_time: float, stall_motion: float, wrap: bool = False,
         precision: float | None = None) -> MoveResult:
    """Drive ``joints`` to ``target`` (n,) [rad] through the Robot's safety gate, one control
    period at a time, until every joint is within ``precision`` (default ``tolerance``),
    nothing moved for ``stall_time``, or ``timeout`` passed; ``reached`` means within
    ``tolerance``. Torque must be on for the joints to move."""
    stop = tolerance if precision is None else min(precision, tolerance)
    joints = tuple(joints)
    idx = robot.index(joints)
    target = np.asarray(target, float)
    start = robot.clock.now()
    window = max(1, int(round(stall_time / robot.config.control_period)))
    history: list[np.ndarray] = [robot.present[idx]]
    robot.rate.restart()
    stalled = False
    while True:
        err = joint_error(robot.present[idx], target, wrap)
        if np.all(err < stop):
            break
        if robot.clock.now() - start >= timeout:
            break
        robot.step(target, joints)
        history.append(robot.present[idx])
        if len(history) > window:
            moved = np.max(np.abs(history[-1] - history[-1 - window]))
            if moved < stall_motion:
                stalled = True
                break
    err = joint_error(robot.present[idx], target, wrap)
    return MoveResult(joints, err, bool(np.all(err < tolerance)), stalled,
                      robot.clock.now() - start)


def joint_error(present: np.ndarray, target: np.ndarray, wrap: bool) -> np.ndarray:
    d = present - target
    if wrap:
        d = wrap_angle(d)
    return np.where(np.isfinite(d), np.abs(d), np.inf)


def verified_move(robot: Robot, config: ResetConfig, target: np.ndarray, joints: Sequence[str],
                  name: str, stages: list[StageResult], timeout: float | None = None,
                  tolerance: float | None = None, wrap: bool = False, final: bool = False
                  ) -> MoveResult:
    """One reset stage: ``move`` (bounded by ``timeout``, default ``config.move_timeout``), rest
    ``config.settle``, verify every joint against ``tolerance`` (default ``config.tolerance``)
    [rad]; ``final`` moves run to ``config.precision``. Appends the stage to ``stages``."""
    cfg, r = config, robot
    tol = cfg.tolerance if tolerance is None else tolerance
    res = move(r, target, joints, tolerance=tol,
               timeout=cfg.move_timeout if timeout is None else timeout,
               stall_time=cfg.stall_time, stall_motion=cfg.stall_motion, wrap=wrap,
               precision=cfg.precision if final else None)
    if cfg.settle > 0:
        r.rest(cfg.settle)
        res.errors = joint_error(r.present[r.index(joints)], np.asarray(target, float), wrap)
        res.reached = bool(np.all(res.errors < tol))
    stages.append(StageResult(name, res.duration, float(np.max(res.errors)), res.reached))
    return res


def robel_disentangle(r: Robot, target: dict[str, float], parts: dict[str, tuple[str, ...]]
                      ) -> None:
    """ROBEL's disentangle: all off 0.75 s; tops to pi/4 (clipped to their limits here), then
    middles, then bottoms to the pose, 0.75 s each, the joints already moved held."""
    r.torque(False, r.action_joints)
    r.rest(0.75)
    tops = r.index(parts["top"])
    swung = {n: float(min(math.pi / 4, r.high[i])) for n, i in zip(parts["top"], tops, strict=True)}
    for group, goal in (("top", swung), ("middle", target), ("bottom", target)):
        r.enable(parts[group])
        end = r.clock.now() + 0.75
        r.rate.restart()
        while r.clock.now() < end - 1e-9:
            r.step(np.array([goal[j] for j in parts[group]]), parts[group])
