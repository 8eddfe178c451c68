"""``AllegroReset`` drives the Allegro's 16 joints to the reset pose (with integral corrections
for joints sagging under their soft PD), verified, bounded retries, and places its unmotorized
valve through a callback (the emulator's physics, a motorized valve or a person).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.hardware.robot.reset import (
    ResetConfig,
    ResetFailed,
    ResetReport,
    StageResult,
    joint_error,
    verified_move,
)
from lowcostdex.hardware.robot.robot import Robot

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
        errors = joint_error(r.present[idx], target, False)
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
