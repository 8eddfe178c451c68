"""Reset trials: tangle the D'Claw the way exploration does, run the auto-reset, measure.

``tangle`` drives the fingers (through the Robot's safety gate, so only to goals a policy could
send) through random segments aimed at each other and at the object: top joints at their
extremes (toward a neighbour), middle joints inward. Half of the time the motors then go limp
and the fingers settle where contacts leave them, as after a thermal pause or a power cut.
``reset_trials`` repeats tangle + reset and reports the success rate and the reset times; the
``lowcostdex reset-test`` command and the tests use it on the emulated or the real D'Claw.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lowcostdex.hardware.robot.reset import ResetFailed
from lowcostdex.hardware.robot.reset_dclaw import DClawReset
from lowcostdex.hardware.robot.reset_robel import RobelReset
from lowcostdex.hardware.robot.robot import Robot


def tangle(robot: Robot, rng: np.random.Generator, segments: int = 5,
           steps_per_segment: int = 6, limp_probability: float = 0.5) -> None:
    """Drive the action joints of a D'Claw into a random tangle (seeded by ``rng``)."""
    names = robot.action_joints
    idx = robot.index(names)
    low, high = robot.low[idx], robot.high[idx]
    parts = np.array([n.split("_")[-1] for n in names])
    robot.enable(names)
    for _ in range(segments):
        goal = rng.uniform(low, high)
        top, mid, bot = parts == "top", parts == "middle", parts == "bottom"
        goal[top] = np.where(rng.random(int(top.sum())) < 0.5, low[top], high[top])
        goal[mid] = rng.uniform(0.0, high[mid])
        goal[bot] = rng.uniform(-0.5, high[bot])
        for _ in range(steps_per_segment):
            robot.step(goal, names)
    if rng.random() < limp_probability:
        robot.torque(False, names)
        robot.rest(0.5)


@dataclass
class TrialStats:
    """Outcome of ``reset_trials``.

    Attributes:
      trials: resets attempted.
      successes: resets that verified.
      times: duration of every successful reset [s] (robot clock).
      attempts: attempts used per successful reset.
      failures: the ResetFailed messages.
    """

    trials: int = 0
    successes: int = 0
    times: list[float] = field(default_factory=list)
    attempts: list[int] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return self.successes / self.trials if self.trials else float("nan")

    def summary(self) -> dict[str, float]:
        t = np.array(self.times) if self.times else np.array([np.nan])
        return {"trials": self.trials, "successes": self.successes,
                "success_rate": self.success_rate, "time_mean": float(np.mean(t)),
                "time_median": float(np.median(t)), "time_max": float(np.max(t)),
                "retried": int(np.sum(np.array(self.attempts) > 1)) if self.attempts else 0}


def reset_trials(robot: Robot, reset: DClawReset | RobelReset, target: np.ndarray, n: int,
                 rng: np.random.Generator, valve_range: float = np.pi / 3,
                 on_trial: Callable[[int, bool, float], None] | None = None,
                 tangler: Callable[[Robot, np.random.Generator], None] = tangle) -> TrialStats:
    """``n`` times: ``tangler`` (default ``tangle``), then reset to ``target`` (9,) [rad] and a
    random valve angle in +-``valve_range`` [rad]. A failed reset is counted and the next trial
    goes on."""
    stats = TrialStats()
    for k in range(n):
        tangler(robot, rng)
        valve = float(rng.uniform(-valve_range, valve_range)) if reset.valve else None
        stats.trials += 1
        try:
            report = reset(target, valve)
        except ResetFailed as exc:
            stats.failures.append(str(exc))
            ok, duration = False, float("nan")
        else:
            stats.successes += 1
            stats.times.append(report.duration)
            stats.attempts.append(report.attempts)
            ok, duration = True, report.duration
        if on_trial is not None:
            on_trial(k, ok, duration)
    return stats
