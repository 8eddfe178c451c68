"""ROBEL's D'Claw reset (``RobelReset``), reproduced and bounded: the baseline ``DClawReset`` is
measured against (``bench/reset.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from lowcostdex.hardware.robot.reset import (
    ResetConfig,
    ResetFailed,
    ResetReport,
    move,
    robel_disentangle,
)
from lowcostdex.hardware.robot.robot import Robot


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
