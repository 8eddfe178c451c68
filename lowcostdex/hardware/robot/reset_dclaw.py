"""D'Claw (``DClawReset``), ROBEL's sequence (01-hardware.md section 1.6) as the baseline, improved:

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
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.hardware.robot.reset import (
    MoveResult,
    ResetConfig,
    ResetFailed,
    ResetReport,
    StageResult,
    robel_disentangle,
    verified_move,
)
from lowcostdex.hardware.robot.robot import Robot

log = logging.getLogger(__name__)


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
