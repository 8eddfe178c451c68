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
     fingers unfold away from each other and from the object without fighting contacts (a
     middle joint outside its limits hangs and is retried);
  2. all nine joints to their reset angles, run to a 0.01 rad precision and verified per joint
     (ROBEL: 5 deg);
  3. valve (motor id 50): drive to the episode's start angle, verify (ROBEL does not), then
     release (torque off for the episode so the fingers turn it freely).

  Each retry starts with a different disentangle: ROBEL's (tops to one side, then middles, then
  bottoms), the opposite swing, then one finger at a time with escape moves for a hooked tip
  while the others hang limp. ROBEL repeats its one disentangle and, after three failures,
  blocks on ``input()``. ``RobelReset`` reproduces ROBEL's sequence (bounded) as the baseline;
  ``bench/reset.py`` compares the two on the same seeded tangles.

``AllegroReset`` drives the Allegro's 16 joints to the reset pose (with integral corrections
for joints sagging under their soft PD), verified, bounded retries, and places its unmotorized
valve through a callback (the emulator's physics, a motorized valve or a person).

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
from lowcostdex.hardware.robot.robot import Robot
from lowcostdex.sim.envs.task import wrap_angle

log = logging.getLogger(__name__)


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
        err = _error(robot.present[idx], target, wrap)
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
    err = _error(robot.present[idx], target, wrap)
    return MoveResult(joints, err, bool(np.all(err < tolerance)), stalled,
                      robot.clock.now() - start)


def _error(present: np.ndarray, target: np.ndarray, wrap: bool) -> np.ndarray:
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
        res.errors = _error(r.present[r.index(joints)], np.asarray(target, float), wrap)
        res.reached = bool(np.all(res.errors < tol))
    stages.append(StageResult(name, res.duration, float(np.max(res.errors)), res.reached))
    return res


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
        target = dict(zip(r.action_joints, np.asarray(finger_target, float), strict=True))
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
              tolerance: float | None = None, wrap: bool = False, final: bool = False
              ) -> MoveResult:
        return verified_move(self.robot, self.config, np.array([target[j] for j in joints]),
                             joints, name, stages, timeout=timeout, tolerance=tolerance,
                             wrap=wrap, final=final)

    def _fingers(self, target: dict[str, float], stages: list[StageResult], staged: bool
                 ) -> tuple[bool, str, dict[str, float]]:
        """Retract, top joints, then all joints; verify. Returns (ok, stage, errors)."""
        r = self.robot
        fingers = list(r.action_joints)
        if staged:
            self._retract(target, stages)
        limp = r.enable(fingers)
        res = self._move(target, fingers, "fingers", stages, final=True)
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

        Every retry starts limp (contact forces relax). Retry 1 is ROBEL's disentangle (tops to
        pi/4, clipped to their limits, then middles, then bottoms); retry 2 swings the tops the
        other way (``swing`` x their lower limit, middles and bottoms limp) and retracts the
        middles with the tops held there: fingers hooked side by side come apart when both turn
        the same way. Later retries reset one finger at a time while the others hang limp, with
        escape moves for a finger whose tip is hooked (``_free_finger``).
        """
        r, cfg, p = self.robot, self.config, self.parts
        start = r.clock.now()
        r.torque(False, r.action_joints)
        r.rest(cfg.limp_rest)
        sub: list[StageResult] = []
        if attempt == 1:
            robel_disentangle(r, target, p)
        elif attempt == 2:
            tops = r.index(p["top"])
            swung = dict(target)
            swung.update({n: cfg.swing * r.low[i] for n, i in zip(p["top"], tops, strict=True)})
            r.enable(p["top"])
            self._move(swung, p["top"], "swing_-", sub)
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
        idx = dict(zip(joints, r.index(joints), strict=True))
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
                         tolerance=cfg.valve_tolerance, wrap=True, final=True)
        r.torque(False, [v])  # released for the episode
        return res.reached, res.outside(cfg.valve_tolerance)


class RobelReset:
    """ROBEL's D'Claw reset, reproduced as the baseline ``DClawReset`` is measured against
    (google-research/robel ``dclaw/scripted_reset.py``, 01-hardware.md section 1.6), bounded:
    after ``max_retries`` failed retries it raises ResetFailed where ROBEL blocks on
    ``input()``, and it moves through the same Robot safety gate.

    Sequence: top and bottom joints off, claw pose commanded (middles move) while the valve is
    driven to its start angle; at least 1 s; all joints on and a blocking move (ROBEL's wait:
    every joint within 1 deg, or under 1 deg of motion over two 0.25 s polls, or 3 s); check
    5 deg; on failure disentangle (``robel_disentangle``) and retry; release the valve.
    """

    def __init__(self, robot: Robot, config: ResetConfig = ResetConfig(),
                 valve: str | None = "valve"):
        self.robot, self.config, self.valve = robot, config, valve
        self.parts = _parts(robot.action_joints)

    def __call__(self, finger_target: np.ndarray, valve_target: float | None = None
                 ) -> ResetReport:
        r, cfg, p = self.robot, self.config, self.parts
        start = r.clock.now()
        target = dict(zip(r.action_joints, np.asarray(finger_target, float), strict=True))
        fingers = list(r.action_joints)
        r.torque(False, p["top"] + p["bottom"])
        r.enable(p["middle"])
        joints = list(p["middle"])
        if self.valve is not None and valve_target is not None:
            r.torque(True, [self.valve])
            target[self.valve] = float(valve_target)
            joints.append(self.valve)
        _robel_wait(r, target, joints, timeout=10.0, wrap=self.valve in joints)
        r.rest(max(0.0, 1.0 - (r.clock.now() - start)))
        errors: dict[str, float] = {}
        for attempt in range(cfg.max_retries + 1):
            r.metrics.reset_attempts += 1
            r.enable(fingers)
            _robel_wait(r, target, fingers, timeout=3.0)
            idx = r.index(fingers)
            err = np.abs(r.present[idx] - np.array([target[n] for n in fingers]))
            pairs = zip(fingers, err, strict=True)
            errors = {n: float(e) for n, e in pairs if not e < cfg.tolerance}
            if not errors:
                if self.valve is not None:
                    r.torque(False, [self.valve])
                duration = r.clock.now() - start
                r.metrics.resets += 1
                r.metrics.reset_time += duration
                return ResetReport(True, attempt + 1, duration)
            if attempt < cfg.max_retries:
                robel_disentangle(r, target, self.parts)
        if self.valve is not None:
            r.torque(False, [self.valve])
        r.metrics.reset_failures += 1
        r.metrics.reset_time += r.clock.now() - start
        raise ResetFailed("fingers", errors, cfg.max_retries + 1, "ROBEL would block on input()")


def _parts(names: Sequence[str]) -> dict[str, tuple[str, ...]]:
    return {p: tuple(n for n in names if n.endswith("_" + p)) for p in ("top", "middle", "bottom")}


def _robel_wait(r: Robot, target: dict[str, float], joints: Sequence[str], timeout: float,
                wrap: bool = False) -> None:
    """ROBEL's blocking wait: within 1 deg, stalled (< 1 deg over two polls), or timeout."""
    move(r, np.array([target[j] for j in joints]), joints, tolerance=math.radians(1.0),
         timeout=timeout, stall_time=0.5, stall_motion=math.radians(1.0), wrap=wrap)


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


# ------------------------------------------------------------------------------------------------
# Allegro

PlaceValve = Callable[[float], None]
"""(start angle [rad]) -> None: put an unmotorized valve at its episode's start angle (the
emulator writes its physics; on hardware a motorized valve or a person)."""
ValveAngle = Callable[[], float]
"""() -> the valve's angle [rad], unwrapped (an encoder or tracker; the emulator's physics)."""


class AllegroReset:
    """Verified reset of the Allegro's 16 joints; optional placement of its valve.

      0. rest first if the thermal guard asked for a pause;
      1. every joint torque on and driven to its target through the Robot's gate, run to
         ``precision`` or until it stalls; the soft PD sags under the fingers' weight (about
         8 deg at joint 1 with the default gains), so up to ``corrections`` more moves shift
         each goal by the error left; verified per joint against ``tolerance``; on failure
         every joint hangs limp for ``limp_rest`` (contact forces relax) and the move is
         retried, ``max_retries`` times;
      2. valve (not motorized): ``place_valve(angle)``, then verified with ``valve_angle``
         against ``valve_tolerance`` (retried like the joints). Without ``place_valve`` the valve
         stays where it is and the episode starts from the angle the env reads.

    When the retries are spent the hand is left limp and ``ResetFailed`` names the joints.

    Args:
      robot: a connected Robot for the Allegro spec.
      config: tolerances and bounds.
      place_valve: puts the valve at a start angle (None: not placed).
      valve_angle: reads the valve angle, to verify the placement.
    """

    def __init__(self, robot: Robot, config: ResetConfig = ResetConfig(),
                 place_valve: PlaceValve | None = None, valve_angle: ValveAngle | None = None):
        if place_valve is not None and valve_angle is None:
            raise ConfigError("AllegroReset: placing the valve needs valve_angle=... to verify it")
        self.robot, self.config = robot, config
        self.place_valve, self.valve_angle = place_valve, valve_angle

    def __call__(self, hand_target: np.ndarray, valve_target: float | None = None
                 ) -> ResetReport:
        """Reset the joints to ``hand_target`` (16,) [rad, action order] and place the valve at
        ``valve_target`` [rad] (skipped when None or without ``place_valve``).

        Raises:
          ResetFailed: the joints or the valve did not verify within ``max_retries`` retries.
        """
        r, cfg = self.robot, self.config
        start = r.clock.now()
        pause = r.pause_if_hot()
        joints = r.action_joints
        target = np.asarray(hand_target, float)
        stages: list[StageResult] = []
        failed_stage, errors = "", {}
        for attempt in range(cfg.max_retries + 1):
            r.metrics.reset_attempts += 1
            if attempt > 0:
                r.torque(False, joints)
                r.rest(cfg.limp_rest)
            r.torque(True, joints)
            failed_stage, errors = "joints", self._joints(target, stages)
            if not errors and valve_target is not None and self.place_valve is not None:
                failed_stage, errors = "valve", self._valve(float(valve_target), stages)
            if not errors:
                duration = r.clock.now() - start
                r.metrics.resets += 1
                r.metrics.reset_time += duration
                r.rate.restart()
                return ResetReport(True, attempt + 1, duration, stages,
                                   pause.duration if pause else 0.0)
        r.torque(False, joints)  # never keep pushing against a jam
        r.metrics.reset_failures += 1
        r.metrics.reset_time += r.clock.now() - start
        raise ResetFailed(failed_stage, errors, cfg.max_retries + 1)

    def _joints(self, target: np.ndarray, stages: list[StageResult]) -> dict[str, float]:
        """Move to ``target``, then up to ``corrections`` times move again with each goal
        shifted by the joint's remaining error; verify against ``target``. Returns the joints
        outside tolerance."""
        r, cfg = self.robot, self.config
        joints = r.action_joints
        idx = r.index(joints)
        goal = target.copy()
        for k in range(cfg.corrections + 1):
            verified_move(r, cfg, goal, joints, "joints" if k == 0 else f"correction_{k}",
                          stages, final=True)
            err = r.present[idx] - target
            if np.all(np.abs(err) < cfg.precision):
                break
            goal = np.clip(goal - err, r.low[idx], r.high[idx])
        errors = _error(r.present[idx], target, False)
        stages[-1].max_error = float(np.max(errors))
        stages[-1].ok = bool(np.all(errors < cfg.tolerance))
        return {n: float(e) for n, e in zip(joints, errors, strict=True)
                if not e < cfg.tolerance}

    def _valve(self, angle: float, stages: list[StageResult]) -> dict[str, float]:
        t0 = self.robot.clock.now()
        self.place_valve(angle)
        err = abs(float(self.valve_angle()) - angle)
        err = err if math.isfinite(err) else math.inf
        ok = err < self.config.valve_tolerance
        stages.append(StageResult("valve", self.robot.clock.now() - t0, err, ok))
        return {} if ok else {"valve": err}


# ------------------------------------------------------------------------------------------------
# Flip block

BlockPose = tuple[np.ndarray, np.ndarray]  # position (3,) [m], quaternion (4,) (w, x, y, z)
Tracker = Callable[[], BlockPose]
Reorient = Callable[[Robot, Tracker, np.ndarray], None]
"""(robot, tracker, start quaternion (4,)) -> None: turn the block back to its start orientation
(e.g. the learned flip policy run once more: two 180 deg flips about one axis are the identity)."""


@dataclass(frozen=True)
class FlipResetConfig:
    """Flip-block reset: the three-finger squeeze and its verification.

    Attributes:
      position_tolerance: block centre (x, y) distance to its start position [m].
      angle_tolerance: tilt of the block's up axis from its start orientation [rad]; beyond it
        the wrong face is up.
      yaw_tolerance: yaw error about the vertical [rad], corrected by turning the closed tips.
      max_turn: largest yaw correction per squeeze [rad].
      open_radius: tip-centre radius about the block target while opening and lowering [m].
      squeeze_radius: tip-centre radius the squeeze closes to [m] (block half edge + tip).
      squeeze_height: tip-centre height above the block centre while squeezing [m].
      clear_height: tip-centre height above the block centre while moving over it [m].
      twist: the tip triangle turns by +-this between squeezes, so a block the first squeeze
        left in a corner is caught by the next [rad].
      tolerance: joint tolerance of the squeeze moves [rad].
      max_squeezes: squeezes per reset.
    """

    position_tolerance: float = 0.015
    angle_tolerance: float = 0.4
    yaw_tolerance: float = 0.2
    max_turn: float = 0.8
    open_radius: float = 0.075
    squeeze_radius: float = 0.037
    squeeze_height: float = -0.005
    clear_height: float = 0.03
    twist: float = 0.35
    tolerance: float = 0.03
    max_squeezes: int = 5

    def __post_init__(self) -> None:
        if not 0 < self.squeeze_radius < self.open_radius:
            raise ConfigError("FlipResetConfig: need 0 < squeeze_radius < open_radius")
        if self.max_squeezes < 1 or not self.position_tolerance > 0:
            raise ConfigError("FlipResetConfig: max_squeezes >= 1, position_tolerance > 0")


class FlipBlockReset:
    """Reset of the flip task: fingers (staged, verified), then the block re-centred by
    three-finger squeezes and its orientation checked, all against an object tracker.

    Args:
      robot: a connected D'Claw Robot (no valve motor).
      model: the task's model (finger kinematics for the squeeze).
      tracker: the block's pose (motion capture on hardware; the emulator's physics).
      config: squeeze and verification settings.
      reset_config: finger reset settings.
      reorient: policy that restores the start orientation; without one a wrong orientation
        ends in ResetFailed (a person turns the block over).
    """

    def __init__(self, robot: Robot, model, tracker: Tracker,
                 config: FlipResetConfig = FlipResetConfig(),
                 reset_config: ResetConfig = ResetConfig(), reorient: Reorient | None = None):
        from lowcostdex.hardware.hands import DCLAW_FINGERS
        from lowcostdex.sim.kinematics import FingerGeometry

        self.robot, self.tracker, self.config, self.reorient = robot, tracker, config, reorient
        self.fingers = DClawReset(robot, reset_config, valve=None)
        self.geometry = [FingerGeometry.from_model(model, f) for f in DCLAW_FINGERS]
        idx = robot.index()
        self.low = robot.low[idx].reshape(3, 3)
        self.high = robot.high[idx].reshape(3, 3)

    def __call__(self, finger_target: np.ndarray, block_pos: np.ndarray,
                 block_quat: np.ndarray) -> ResetReport:
        """Reset fingers to ``finger_target`` (9,) and the block to ``block_pos`` (3,) [m],
        ``block_quat`` (4,).

        Squeezes (each closing the tips around the block, turning it by its yaw error, opening)
        repeat until the block is within ``position_tolerance`` and ``yaw_tolerance``.

        Raises:
          ResetFailed: stage "block_orientation" (wrong face up, no ``reorient``) or
            "block_position" (not re-centred and aligned after ``max_squeezes`` squeezes).
        """
        r, cfg = self.robot, self.config
        start = r.clock.now()
        self._before = (r.metrics.resets, r.metrics.reset_time)
        report = self.fingers(finger_target)
        target = np.asarray(block_pos, float)
        quat = np.asarray(block_quat, float)
        if self._tilt(quat) > cfg.angle_tolerance:
            if self.reorient is None:
                return self._fail("block_orientation", {"block": self._tilt(quat)},
                                  report.attempts, "the wrong face is up and no reorient "
                                  "policy is set; turn the block over by hand", start)
            self.reorient(r, self.tracker, quat)
            report = self.fingers(finger_target)
            if self._tilt(quat) > cfg.angle_tolerance:
                return self._fail("block_orientation", {"block": self._tilt(quat)},
                                  report.attempts, "the reorient policy did not restore the "
                                  "face up", start)
        squeezes = 0
        while (self._offset(target) > cfg.position_tolerance
               or abs(self._yaw(quat)) > cfg.yaw_tolerance):
            if squeezes >= cfg.max_squeezes:
                errors = {"block position": self._offset(target)}
                return self._fail("block_position", errors, squeezes,
                                  f"yaw off by {math.degrees(self._yaw(quat)):.1f} deg after "
                                  f"{squeezes} squeezes", start, unit="m")
            twist = (0.0, cfg.twist, -cfg.twist)[squeezes % 3]
            turn = float(np.clip(-self._yaw(quat), -cfg.max_turn, cfg.max_turn))
            report.stages.append(self._squeeze(target, twist, turn))
            squeezes += 1
        if squeezes:
            self.fingers(finger_target)
        report.duration = r.clock.now() - start
        report.attempts += squeezes
        r.metrics.resets = self._before[0] + 1  # one reset, however many finger resets inside
        r.metrics.reset_time = self._before[1] + report.duration
        return report

    # -- pieces -----------------------------------------------------------------------------------
    def _offset(self, target: np.ndarray) -> float:
        return float(np.linalg.norm(self.tracker()[0][:2] - target[:2]))

    def _tips(self, center: np.ndarray, radius: float, height: float, twist: float
              ) -> np.ndarray:
        """Joint goals (9,) putting the three tips on a circle about ``center``."""
        goals = []
        for i, f in enumerate(self.geometry):
            d = f.forward(np.zeros(3))[:2] - center[:2]
            phi = math.atan2(d[1], d[0]) + twist
            p = center + np.array([radius * math.cos(phi), radius * math.sin(phi), height])
            goals.append(f.inverse(p, self.low[i], self.high[i]))
        return np.concatenate(goals)

    def _tilt(self, quat: np.ndarray) -> float:
        """Angle between the block's up axis and its up axis at ``quat`` [rad] (yaw ignored)."""
        from lowcostdex.sim.envs.dclaw_tasks import quat_rotate

        up = np.array([[0.0, 0.0, 1.0]])
        z = quat_rotate(self.tracker()[1], up)[0]
        z0 = quat_rotate(np.asarray(quat, float), up)[0]
        return float(np.arccos(np.clip(np.dot(z, z0), -1.0, 1.0)))

    def _yaw(self, quat: np.ndarray) -> float:
        """Block yaw relative to ``quat`` about the vertical [rad] (tilt ignored)."""
        from lowcostdex.sim.envs.dclaw_tasks import quat_rotate

        x = quat_rotate(self.tracker()[1], np.array([[1.0, 0.0, 0.0]]))[0]
        x0 = quat_rotate(np.asarray(quat, float), np.array([[1.0, 0.0, 0.0]]))[0]
        return float(wrap_angle(math.atan2(x[1], x[0]) - math.atan2(x0[1], x0[0])))

    def _squeeze(self, target: np.ndarray, twist: float, turn: float = 0.0) -> StageResult:
        """Over the block where the tracker sees it, down around it, close to
        ``squeeze_radius``, carry it (closed) to ``target`` while turning it by ``turn`` [rad]
        (yaw correction), open, up."""
        r, cfg = self.robot, self.config
        start = r.clock.now()
        names = r.action_joints
        r.enable(names)
        seen = np.array([*self.tracker()[0][:2], target[2]])
        mid = 0.5 * (seen + target)
        o, c = cfg.open_radius, cfg.squeeze_radius
        lo, hi = cfg.squeeze_height, cfg.clear_height
        waypoints = ((seen, o, hi, twist), (seen, o, lo, twist), (seen, c, lo, twist),
                     (mid, c, lo, twist + 0.5 * turn), (target, c, lo, twist + turn),
                     (target, o, lo, twist + turn), (target, o, hi, twist + turn))
        worst = 0.0
        for center, radius, height, alpha in waypoints:
            res = move(r, self._tips(center, radius, height, alpha), names,
                       tolerance=cfg.tolerance, timeout=self.fingers.config.move_timeout,
                       stall_time=self.fingers.config.stall_time,
                       stall_motion=self.fingers.config.stall_motion)
            worst = max(worst, float(np.max(res.errors)))
        return StageResult("squeeze", r.clock.now() - start, worst,
                           self._offset(target) <= cfg.position_tolerance)

    def _fail(self, stage: str, errors: dict[str, float], attempts: int, detail: str,
              start: float, unit: str = "rad") -> ResetReport:
        r = self.robot
        r.metrics.reset_failures += 1
        r.metrics.resets = self._before[0]
        r.metrics.reset_time = self._before[1] + r.clock.now() - start
        raise ResetFailed(stage, errors, attempts, detail, unit)
