"""Auto-reset procedures with verification: bounded, measured, and never blocking on a human.

Every procedure is a sequence of stages; each stage is a blocking move through the Robot's safety
gate (limits, motion bound, guards), verified per joint against a tolerance. A failed stage is
retried up to ``max_retries`` times, with a disentangle before each retry; when the retries are
spent the procedure raises ``ResetFailed`` naming the joints and their errors. There is no
``input()`` and no unbounded loop: a jammed valve or a broken finger ends in an exception after a
known, bounded time.

D'Claw (``DClawReset``), ROBEL's sequence (01-hardware.md section 1.6) as the baseline, improved:

  0. rest first if the thermal guard asked for a pause; reboot motors with latched errors;
  1. retract: middle joints to their reset angle with top and bottom joints limp, so the
     fingers unfold away from each other and from the object without fighting contacts;
  2. top joints to their reset angle (middle held);
  3. bottom joints to their reset angle; verify all nine joints (ROBEL: 5 deg);
  4. valve (motor id 50): drive to the episode's start angle, verify, then release (torque off
     for the episode so the fingers turn it freely).

  Before a retry, disentangle: every finger limp for a moment (gravity opens tangles), then the
  fingers are reset one at a time while the others stay limp, so no two fingers can push against
  each other. ROBEL instead moves all fingers together through fixed poses and, after three
  failures, blocks on ``input()``.

``FlipBlockReset`` re-centres the block of the flip task with a three-finger squeeze and
reorients it with an optional policy (e.g. the learned flip policy: two 180 deg flips about the
same axis restore the start orientation), verified against the block pose an object tracker
reports.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.errors import ConfigError, LowcostdexError
from lowcostdex.hardware.robot import Robot
from lowcostdex.sim.envs.task import wrap_angle

log = logging.getLogger(__name__)


class ResetFailed(LowcostdexError, RuntimeError):
    """An auto-reset did not reach its target within its retries.

    Attributes:
      stage: the stage that failed last.
      errors: joint name -> final error [rad] of the joints outside tolerance.
      attempts: attempts made.
    """

    def __init__(self, stage: str, errors: dict[str, float], attempts: int, detail: str = ""):
        self.stage, self.errors, self.attempts = stage, dict(errors), attempts
        listed = ", ".join(f"{k} off by {math.degrees(v):.1f} deg" for k, v in errors.items())
        super().__init__(f"reset failed at stage '{stage}' after {attempts} attempt(s): "
                         f"{listed or 'no joint data'}{'; ' + detail if detail else ''}")


@dataclass(frozen=True)
class ResetConfig:
    """Reset tolerances, bounds and poses.

    Attributes:
      tolerance: per-joint verification tolerance for fingers [rad] (ROBEL: 5 deg).
      valve_tolerance: verification tolerance for the valve [rad].
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
    """

    tolerance: float = math.radians(5.0)
    valve_tolerance: float = math.radians(3.0)
    max_retries: int = 3
    move_timeout: float = 3.0
    valve_timeout: float = 10.0
    stall_time: float = 0.5
    stall_motion: float = math.radians(0.5)
    settle: float = 0.2
    limp_rest: float = 0.75
    recovery_passes: int = 3
    swing: float = 0.9

    def __post_init__(self) -> None:
        for name in ("tolerance", "valve_tolerance", "move_timeout", "valve_timeout",
                     "stall_time", "stall_motion"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"ResetConfig.{name} must be > 0")
        if self.max_retries < 0 or self.settle < 0 or self.limp_rest < 0:
            raise ConfigError("ResetConfig: max_retries, settle, limp_rest must be >= 0")
        if self.recovery_passes < 1:
            raise ConfigError("ResetConfig.recovery_passes must be >= 1")


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
        return {n: float(e) for n, e in zip(self.joints, self.errors) if not e < tolerance}


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
         timeout: float, stall_time: float, stall_motion: float, wrap: bool = False
         ) -> MoveResult:
    """Drive ``joints`` to ``target`` (n,) [rad] through the Robot's safety gate, one control
    period at a time, until every joint is within ``tolerance``, nothing moved for
    ``stall_time``, or ``timeout`` passed. Torque must be on for the joints to move."""
    joints = tuple(joints)
    idx = robot.index(joints)
    target = np.asarray(target, float)
    start = robot.clock.now()
    window = max(1, int(round(stall_time / robot.config.control_period)))
    history: list[np.ndarray] = [robot.present[idx]]
    robot.rate.restart()
    stalled = False
    while True:
        err = _error(robot.present[idx], target, wrap)
        if np.all(err < tolerance):
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
    err = _error(robot.present[idx], target, wrap)
    return MoveResult(joints, err, bool(np.all(err < tolerance)), stalled,
                      robot.clock.now() - start)


def _error(present: np.ndarray, target: np.ndarray, wrap: bool) -> np.ndarray:
    d = present - target
    if wrap:
        d = wrap_angle(d)
    return np.where(np.isfinite(d), np.abs(d), np.inf)


class DClawReset:
    """Staged, verified reset of the D'Claw fingers and (optionally) the valve.

    Args:
      robot: a connected Robot for a D'Claw spec (joints ``<finger>_<top|middle|bottom>``).
      config: tolerances and bounds.
      valve: name of the valve joint (None: no object motor, e.g. the flip-block station).
    """

    def __init__(self, robot: Robot, config: ResetConfig = ResetConfig(),
                 valve: str | None = "valve"):
        self.robot = robot
        self.config = config
        self.valve = valve
        names = robot.action_joints
        self.fingers = tuple(dict.fromkeys(n.split("_")[0] for n in names))
        self.parts = {p: tuple(n for n in names if n.endswith("_" + p))
                      for p in ("top", "middle", "bottom")}
        if not all(self.parts.values()):
            raise ConfigError("DClawReset needs <finger>_top/_middle/_bottom joints, got "
                              f"{names}")
        if valve is not None and valve not in robot.joint_names:
            raise ConfigError(f"valve joint {valve!r} not in the robot's joints "
                              f"{robot.joint_names}")

    # -- public ---------------------------------------------------------------------------------
    def __call__(self, finger_target: np.ndarray, valve_target: float | None = None
                 ) -> ResetReport:
        """Reset the fingers to ``finger_target`` (9,) [rad, action order] and the valve to
        ``valve_target`` [rad] (skipped when None); the valve is released afterwards.

        Raises:
          ResetFailed: a stage did not verify within ``max_retries`` retries.
        """
        r, cfg = self.robot, self.config
        start = r.clock.now()
        pause = r.pause_if_hot()
        r.recover_faults()
        target = dict(zip(r.action_joints, np.asarray(finger_target, float)))
        stages: list[StageResult] = []
        failed_stage, errors = "", {}
        attempts = 0
        for attempt in range(cfg.max_retries + 1):
            attempts = attempt + 1
            r.metrics.reset_attempts += 1
            if attempt > 0:
                stages.append(self._disentangle(target, attempt))
            ok, stage, errors = self._fingers(target, stages, staged=attempt == 0)
            if not ok:
                failed_stage = stage
                continue
            if self.valve is not None and valve_target is not None:
                ok, errors = self._valve(float(valve_target), stages)
                if not ok:
                    failed_stage = "valve"
                    continue
            duration = r.clock.now() - start
            r.metrics.resets += 1
            r.metrics.reset_time += duration
            r.rate.restart()
            return ResetReport(True, attempts, duration, stages,
                               pause.duration if pause else 0.0)
        r.metrics.reset_failures += 1
        r.metrics.reset_time += r.clock.now() - start
        if self.valve is not None:
            r.torque(False, [self.valve])
        raise ResetFailed(failed_stage, errors, attempts)

    # -- stages ---------------------------------------------------------------------------------
    def _move(self, target: dict[str, float], joints: Sequence[str], name: str,
              stages: list[StageResult], timeout: float | None = None,
              tolerance: float | None = None, wrap: bool = False) -> MoveResult:
        cfg, r = self.config, self.robot
        tol = cfg.tolerance if tolerance is None else tolerance
        res = move(r, np.array([target[j] for j in joints]), joints, tolerance=tol,
                   timeout=cfg.move_timeout if timeout is None else timeout,
                   stall_time=cfg.stall_time, stall_motion=cfg.stall_motion, wrap=wrap)
        if cfg.settle > 0:
            r.rest(cfg.settle)
            idx = r.index(joints)
            res.errors = _error(r.present[idx], np.array([target[j] for j in joints]), wrap)
            res.reached = bool(np.all(res.errors < tol))
        stages.append(StageResult(name, res.duration, float(np.max(res.errors)), res.reached))
        return res

    def _fingers(self, target: dict[str, float], stages: list[StageResult], staged: bool
                 ) -> tuple[bool, str, dict[str, float]]:
        """Retract, top joints, then all joints; verify. Returns (ok, stage, errors)."""
        r, p = self.robot, self.parts
        fingers = list(r.action_joints)
        if staged:
            self._retract(target, stages)
            r.enable(p["top"])
            self._move(target, p["top"], "top", stages)
        limp = r.enable(fingers)
        res = self._move(target, fingers, "fingers", stages)
        bad = res.outside(self.config.tolerance)
        if limp:
            self.limp = limp
            log.info("reset: %s outside their limits, left limp", ", ".join(limp))
        return not bad, "fingers", bad

    def _retract(self, target: dict[str, float], stages: list[StageResult]) -> None:
        """Middle joints to their targets with the top and bottom joints limp, so the fingers
        unfold away from each other and the object and limp joints hang back inside their
        limits. A middle joint outside its limits refuses torque; it hangs while the others
        retract, and is retried (``recovery_passes`` passes)."""
        r, p, cfg = self.robot, self.parts, self.config
        r.torque(False, p["top"] + p["bottom"])
        for _ in range(cfg.recovery_passes):
            limp = r.enable(p["middle"])
            active = [m for m in p["middle"] if m not in limp]
            if active:
                self._move(target, active, "retract", stages)
            if not limp:
                return
            r.rest(cfg.limp_rest)

    def _disentangle(self, target: dict[str, float], attempt: int) -> StageResult:
        """Free tangled fingers before retry ``attempt`` (1, 2, ...).

        Every retry starts limp (contact forces relax). Retries 1 and 2 swing all top joints
        to one side, then the other (``swing`` x their limit, middle and bottom joints limp so
        the fingers rotate freely), and retract the middle joints with the tops held there:
        fingers hooked side by side come apart when both turn the same way (ROBEL turns the
        tops to pi/4 on every retry). Later retries reset one finger at a time while the others
        hang limp, with escape moves for a finger whose tip is hooked (``_free_finger``).
        """
        r, cfg, p = self.robot, self.config, self.parts
        start = r.clock.now()
        r.torque(False, r.action_joints)
        r.rest(cfg.limp_rest)
        sub: list[StageResult] = []
        if attempt <= 2:
            side = 1.0 if attempt == 1 else -1.0
            tops = r.index(p["top"])
            swung = dict(target)
            swung.update({n: side * cfg.swing * (r.high[i] if side > 0 else -r.low[i])
                          for n, i in zip(p["top"], tops)})
            r.enable(p["top"])
            self._move(swung, p["top"], f"swing_{'+' if side > 0 else '-'}", sub)
            r.enable(p["middle"])
            self._move(target, p["middle"], "retract", sub)
        else:
            for finger in self.fingers:
                self._free_finger(finger, target, sub)
        worst = max((s.max_error for s in sub), default=0.0)
        return StageResult(f"disentangle_{attempt}", r.clock.now() - start, worst,
                           all(s.ok for s in sub))

    def _free_finger(self, finger: str, target: dict[str, float], sub: list[StageResult]
                     ) -> None:
        """Reset one finger while the others hang limp; if its middle joint cannot retract
        (the tip is hooked behind another finger or a spoke), try escape moves first:
        straighten the bottom joint, curl further in, swing the top joint either way."""
        r, cfg = self.robot, self.config
        joints = tuple(n for n in r.action_joints if n.split("_")[0] == finger)
        top, middle, bottom = (f"{finger}_{p}" for p in ("top", "middle", "bottom"))
        idx = dict(zip(joints, r.index(joints)))
        r.enable(joints)
        for escape in ("none", "straighten", "curl", "swing+", "swing-"):
            if escape != "none":
                pose = {j: float(r.present[idx[j]]) for j in joints}
                if escape == "straighten":
                    pose[bottom] = 0.0
                elif escape == "curl":
                    pose[middle] = float(r.high[idx[middle]])
                    pose[bottom] = 0.0
                else:
                    sign = 1.0 if escape == "swing+" else -1.0
                    pose[top] = cfg.swing * (r.high[idx[top]] if sign > 0 else r.low[idx[top]])
                self._move(pose, joints, f"{finger}_{escape}", sub)
            res = self._move(target, (middle,), f"{finger}_retract", sub)
            if res.reached:
                break
        self._move(target, joints, finger, sub)
        r.torque(False, joints)

    def _valve(self, angle: float, stages: list[StageResult]) -> tuple[bool, dict[str, float]]:
        r, cfg = self.robot, self.config
        v = self.valve
        r.torque(True, [v])
        res = self._move({v: angle}, [v], "valve", stages, timeout=cfg.valve_timeout,
                         tolerance=cfg.valve_tolerance, wrap=True)
        r.torque(False, [v])  # released for the episode
        return res.reached, res.outside(cfg.valve_tolerance)


# ------------------------------------------------------------------------------------------------
# Flip block

BlockPose = tuple[np.ndarray, np.ndarray]  # position (3,) [m], quaternion (4,) (w, x, y, z)
Tracker = Callable[[], BlockPose]


@dataclass(frozen=True)
class FlipResetConfig:
    """Flip-block reset bounds.

    Attributes:
      position_tolerance: block centre distance to the start position [m].
      angle_tolerance: orientation error [rad].
      squeeze: tip-to-block-centre radius the squeeze closes to [m].
      max_retries: attempts after the first.
    """

    position_tolerance: float = 0.015
    angle_tolerance: float = 0.4
    squeeze: float = 0.035
    max_retries: int = 2
