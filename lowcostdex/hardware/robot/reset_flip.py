"""``FlipBlockReset`` re-centres the block of the flip task with a three-finger squeeze and
reorients it with an optional policy (e.g. the learned flip policy: two 180 deg flips about the
same axis restore the start orientation), verified against the block pose an object tracker
reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lowcostdex.errors import ConfigError, keyword_hints
from lowcostdex.hardware.robot.reset import ResetConfig, ResetFailed, ResetReport, StageResult, move
from lowcostdex.hardware.robot.reset_dclaw import DClawReset
from lowcostdex.hardware.robot.robot import Robot
from lowcostdex.sim.envs.task import wrap_angle

BlockPose = tuple[np.ndarray, np.ndarray]  # position (3,) [m], quaternion (4,) (w, x, y, z)
Tracker = Callable[[], BlockPose]
Reorient = Callable[[Robot, Tracker, np.ndarray], None]
"""(robot, tracker, start quaternion (4,)) -> None: turn the block back to its start orientation
(e.g. the learned flip policy run once more: two 180 deg flips about one axis are the identity)."""


@keyword_hints
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
        from lowcostdex.hands import DCLAW_FINGERS
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
