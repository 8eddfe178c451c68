"""Scripted teachers: closed-loop solving motions that map the present state to joint goals.

A teacher is deterministic and draws no random numbers. It reads the full ``qpos`` of the task's
model (hand joints and object) and returns joint goals [rad] for the hand joints in action order,
so it can drive a ``HandEnv`` (``goal_to_action``), serve as the physics sanity test, and act as the
"virtual teacher" that moves the fingers of an emulated hand while demonstrations are recorded.

``ValveTurnTeacher`` turns the D'Claw valve: every fingertip is placed, with analytic inverse
kinematics, on a circle about the valve axis a little above the spoke axis, behind the spoke it
is going to push; it then sweeps along the circle, pushing the spoke with the side of its tip,
until the valve reaches the goal (the sweep speed falls with the remaining error) or the tip leaves
its reach; then it lifts above the spokes, travels back behind the next spoke, lowers and pushes
again. The three fingers and the three spokes share the hand's 3-fold symmetry, so all fingers
run the same stroke in their own frames, 120 deg apart, and never meet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.hands import DCLAW_FINGERS
from lowcostdex.sim.envs.task import Goal, wrap_angle
from lowcostdex.sim.kinematics import FingerGeometry

RETURN, PUSH, RISE, LOWER = "return", "push", "rise", "lower"


# ------------------------------------------------------------------------------------------------
# Valve turning


@dataclass(frozen=True)
class ValveTeacherConfig:
    """Stroke of the valve-turning teacher (lengths [m], angles [rad]).

    Attributes:
      push_radius: radius of the fingertip circle about the valve axis.
      push_height: tip-sphere centre above the spoke axis while pushing.
      return_radius: radius of the circle the tips return along, above the spokes.
      return_height: tip-sphere centre above the spoke axis while returning.
      reach: largest tip angle from the finger's own direction (either side); lowered at
        ``reset`` to what the finger reaches on the push circle.
      approach_gap: extra angular gap between tip and spoke when the tip comes down.
      sweep_speed: largest tip advance along the circle per control step while pushing.
      travel_speed: largest tip travel along the circle per control step while returning.
      reach_tolerance: a stroke ends when the measured tip is this close to its reach.
      error_gain: tip advance per step = min(sweep_speed, error_gain * |valve error| - lag).
      hold_tolerance: |valve error| below which the fingers hold still.
      reverse_tolerance: overshoot beyond which the fingers go round to push back.
      settle_tolerance: distance [m] from the push circle that ends a return.
      hold_backoff: when the valve reaches the goal the tip steps back this much from where it
        is, so it stops pressing on the spoke.
      lift_start: a return travels only once the tip is this far [m] above the push height.
      replan_angle: a return re-plans its stroke when the valve has turned this much since.
      flip_margin: the turning direction chosen at the first call (the short way; +1 at exactly
        180 deg) is kept until the wrapped error passes pi - flip_margin the other way.
    """

    push_radius: float = 0.065
    push_height: float = 0.027
    return_radius: float = 0.08
    return_height: float = 0.038
    reach: float = math.radians(75)
    approach_gap: float = math.radians(10)
    sweep_speed: float = math.radians(24)
    travel_speed: float = math.radians(35)
    reach_tolerance: float = math.radians(4)
    error_gain: float = 0.8
    hold_tolerance: float = 0.02
    reverse_tolerance: float = 0.08
    settle_tolerance: float = 0.004
    flip_margin: float = 0.5
    hold_backoff: float = math.radians(2)
    lift_start: float = 0.004
    replan_angle: float = math.radians(4)

    def __post_init__(self) -> None:
        for name in ("push_radius", "reach", "sweep_speed", "travel_speed", "error_gain",
                     "hold_tolerance", "settle_tolerance"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"ValveTeacherConfig.{name} must be > 0, got {getattr(self, name)}")
        if not self.reverse_tolerance >= self.hold_tolerance:
            raise ConfigError("ValveTeacherConfig.reverse_tolerance must be >= hold_tolerance")


class ValveTurnTeacher:
    """Closed-loop valve turning on the D'Claw (valve, foam valve and screw stations).

    Call ``reset(task)`` (a bound task, or anything with ``.task``, e.g. a ``HandEnv``) at the
    start of an episode, then ``teacher(qpos, goal)`` every control step with the full ``qpos``
    (nq,) and the goal dict (``goal["angle"]`` [rad]); it returns joint goals (9,) [rad] in the
    hand's action order. The error is wrapped to [-pi, pi) as the task does.

    Two phases: ``return`` brings the tips to the start of a stroke (lifted above the spokes
    only while crossing one) and ``push`` sweeps them along the push circle.
    """

    def __init__(self, config: ValveTeacherConfig = ValveTeacherConfig()):
        self.config = config

    def reset(self, task_or_env, goal: Goal | None = None) -> None:
        """Bind to a task's model and forget the previous episode (``goal`` is unused)."""
        task = getattr(task_or_env, "task", task_or_env)
        model = task.model
        c = self.config
        self.hand_qpos = task.hand_qpos
        self.low, self.high = task.hand_low.reshape(3, 3), task.hand_high.reshape(3, 3)
        self.valve_qpos = int(model.jnt_qposadr[model.joint("valve").id])
        self.fingers = [FingerGeometry.from_model(model, f) for f in DCLAW_FINGERS]
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        self.center = data.xpos[model.body("valve_body").id].copy()
        spokes = [model.geom(name) for name in _spoke_names(model)]
        # Spoke directions at valve angle 0 (world angles [rad]), measured from the model.
        self.spoke_angles = np.array([_angle(data.geom_xpos[g.id] - self.center) for g in spokes])
        spoke_z = float(data.geom_xpos[spokes[0].id][2])
        spoke_radius = float(spokes[0].size[0])
        tip_radius = self.fingers[0].tip_radius
        # Each finger's own direction: its straight tip seen from the valve axis.
        self.finger_angles = np.array([_angle(f.forward(np.zeros(3)) - self.center)
                                       for f in self.fingers])
        # Angle between tip and spoke axis when they touch at push height.
        side = math.sqrt(max((spoke_radius + tip_radius) ** 2 - c.push_height**2, 0.0))
        self.contact_angle = math.asin(min(side / c.push_radius, 1.0))
        self.push_z = spoke_z + c.push_height
        self.return_z = spoke_z + c.return_height
        self.clear_z = spoke_z + spoke_radius + tip_radius + 0.002  # above the spoke tops
        if not self.return_z > self.clear_z:
            raise ConfigError(f"return_height {c.return_height} must put the tips above the "
                              f"spokes (> {self.clear_z - spoke_z:.3f} m)")
        self.reach = min(c.reach, self._reachable(c.push_radius, self.push_z),
                         self._reachable(c.return_radius, self.return_z))
        self.phase = RETURN
        self.alpha = math.nan  # commanded tip angle from each finger's direction [rad]
        self.z = math.nan  # commanded tip-centre height [m]
        self.radius = c.push_radius
        self.direction = 0.0  # direction of the current stroke (+1 / -1; 0 before the first)
        self.target_alpha = math.nan
        self._crossing = np.zeros(0)  # spokes between the tip and the stroke start [rad]
        self._way = 0.0  # direction of travel to the stroke start
        self._lifting = False
        self._holding = False
        self._plan_theta = math.nan
        self._commit: float | None = None

    def _reachable(self, radius: float, z: float) -> float:
        """Largest tip angle [rad] every finger reaches on the circle (radius, z), by bisection."""
        lo, hi = 0.0, math.pi / 2
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            ok = all(self._reaches(i, a, radius, z) for i in range(3) for a in (mid, -mid))
            lo, hi = (mid, hi) if ok else (lo, mid)
        return lo

    def _reaches(self, i: int, alpha: float, radius: float, z: float) -> bool:
        p = self._circle_point(i, alpha, radius, z)
        q = self.fingers[i].inverse(p, self.low[i], self.high[i])
        return bool(np.linalg.norm(self.fingers[i].forward(q) - p) < 1e-4)

    def _circle_point(self, i: int, alpha: float, radius: float, z: float) -> np.ndarray:
        phi = self.finger_angles[i] + alpha
        return np.array([self.center[0] + radius * math.cos(phi),
                         self.center[1] + radius * math.sin(phi), z])

    # -- geometry --------------------------------------------------------------------------------
    def tips(self, q: np.ndarray) -> np.ndarray:
        """Tip-sphere centres (3, 3) [m] for hand joint angles q (9,) [rad]."""
        q = np.asarray(q, float).reshape(3, 3)
        return np.stack([f.forward(q[i]) for i, f in enumerate(self.fingers)])

    def tip_polar(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tips (3,) each: angle from the finger's direction [rad], radius [m], height [m]."""
        rel = self.tips(q) - self.center
        alpha = wrap_angle(np.arctan2(rel[:, 1], rel[:, 0]) - self.finger_angles)
        return alpha, np.hypot(rel[:, 0], rel[:, 1]), rel[:, 2] + self.center[2]

    def joint_goals(self, alpha: float, radius: float, z: float) -> np.ndarray:
        """Joint goals (9,) [rad] putting every tip at (alpha, radius, z) in its own frame."""
        return np.concatenate([f.inverse(self._circle_point(i, alpha, radius, z), self.low[i],
                                         self.high[i]) for i, f in enumerate(self.fingers)])

    def spoke_rel(self, theta: float) -> np.ndarray:
        """Spoke angles seen from the fingers' direction (the same for every finger) [rad]."""
        return wrap_angle(self.spoke_angles + theta - self.finger_angles[0])

    # -- policy ----------------------------------------------------------------------------------
    def error(self, qpos: np.ndarray, goal: Goal) -> float:
        """Valve error [rad], wrapped, without flipping the committed turning direction."""
        err = float(wrap_angle(float(goal["angle"]) - float(qpos[self.valve_qpos])))
        if self._commit is None:
            self._commit = math.copysign(1.0, err) if abs(abs(err) - math.pi) > 1e-3 else 1.0
        limit = math.pi - self.config.flip_margin
        if self._commit > 0 and err < -limit:
            err += 2 * math.pi
        elif self._commit < 0 and err > limit:
            err -= 2 * math.pi
        return err

    def __call__(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        c = self.config
        q = np.asarray(qpos, float)[self.hand_qpos]
        theta = float(qpos[self.valve_qpos])
        err = self.error(qpos, goal)
        tips_alpha, _, tips_z = self.tip_polar(q)
        alpha = float(np.mean(tips_alpha))
        if math.isnan(self.alpha):
            self.alpha, self.z = alpha, float(np.mean(tips_z))
        s = math.copysign(1.0, err)
        if self.phase == PUSH:
            reverse = s != self.direction and abs(err) > c.reverse_tolerance
            if abs(err) < c.hold_tolerance or (s != self.direction and not reverse):
                if not self._holding:  # stop pressing: back the tip off the spoke a little
                    self.alpha = alpha - self.direction * c.hold_backoff
                    self._holding = True
                return self.joint_goals(self.alpha, self.radius, self.z)
            self._holding = False
            if reverse or s * alpha >= self.reach - c.reach_tolerance:
                self.phase = RETURN
                self.direction = 0.0
            else:
                # The tip still owes the lag between command and measurement: that much of the
                # error will be pushed off without a new command.
                owed = max(s * (self.alpha - alpha), 0.0)
                step = min(c.sweep_speed, max(c.error_gain * abs(err) - owed, 0.0))
                self.alpha = float(np.clip(self.alpha + s * step, -self.reach, self.reach))
        if self.phase == RETURN:
            moved = abs(float(wrap_angle(theta - self._plan_theta))) > c.replan_angle
            if self.direction == 0.0 or moved:  # (a spoke knocked on the way moves the start)
                self._plan_stroke(theta, alpha, s)
            self._return_step(tips_alpha, tips_z)
        return self.joint_goals(self.alpha, self.radius, self.z)

    def _plan_stroke(self, theta: float, alpha: float, s: float) -> None:
        """Pick the spoke to push in direction s (the tip starts behind it) and the spokes the
        tip crosses on its way there."""
        c = self.config
        spokes = self.spoke_rel(theta)
        behind = spokes - s * (self.contact_angle + c.approach_gap)
        ok = np.abs(behind) <= self.reach
        # the candidate furthest back gives the longest stroke
        self.target_alpha = (float(behind[ok][np.argmin(s * behind[ok])]) if np.any(ok)
                             else -s * self.reach)
        lo, hi = sorted((alpha, self.target_alpha))
        self._crossing = spokes[(spokes > lo - self.contact_angle) & (spokes < hi)]
        self._way = math.copysign(1.0, self.target_alpha - alpha)
        self.direction = s
        self.alpha = alpha  # drop the push lead: no more pressing on the spoke
        self._lifting = True
        self._plan_theta = theta

    def _return_step(self, tips_alpha: np.ndarray, tips_z: np.ndarray) -> None:
        """Travel over the spokes in the way to the stroke start, then down to the push circle.

        The tips travel at the return height; they enter a spoke's zone only once the lowest is
        above the spoke tops, and come down as soon as the last has passed the last spoke in
        the way. Tips are judged one by one (worst case), not by their mean.
        """
        c = self.config
        low, high = float(np.min(tips_z)), float(np.max(tips_z))
        if self._lifting:  # first up off the spoke just pushed, so as not to drag it back
            self.radius, self.z = c.return_radius, self.return_z
            if low < self.push_z + c.lift_start:
                return
            self._lifting = False
        way, half = self._way, self.contact_angle + 0.5 * c.approach_gap
        ahead, behind = float(np.max(way * tips_alpha)), float(np.min(way * tips_alpha))
        # spokes every tip has passed are behind them for good
        self._crossing = self._crossing[behind - way * self._crossing < half]
        new_alpha = self.alpha + float(np.clip(self.target_alpha - self.alpha,
                                               -c.travel_speed, c.travel_speed))
        if low < self.clear_z:  # not above the spokes yet: do not enter a spoke's zone
            for spoke in self._crossing:
                near = way * (spoke - way * half)  # in the travel direction's coordinate
                if ahead > near:  # a tip is beside the spoke already: hold until lifted
                    new_alpha = self.alpha
                elif way * new_alpha > near:
                    new_alpha = way * near
        self.alpha = new_alpha
        if self._crossing.size:
            self.radius, self.z = c.return_radius, self.return_z
            return
        self.radius, self.z = c.push_radius, self.push_z
        arrived = abs(self.target_alpha - float(np.mean(tips_alpha))) < c.approach_gap
        if arrived and high <= self.push_z + c.settle_tolerance:
            self.phase = PUSH


def _spoke_names(model: mujoco.MjModel) -> list[str]:
    names = []
    while mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"valve_spoke{len(names)}") >= 0:
        names.append(f"valve_spoke{len(names)}")
    return names


def _angle(v: np.ndarray) -> float:
    return math.atan2(float(v[1]), float(v[0]))


class ScrewTrackTeacher(ValveTurnTeacher):
    """``ValveTurnTeacher`` for the screw: aims ``lead`` seconds ahead of the moving goal.

    The goal angle moves at ``goal["speed"]`` [rad/s]; pushing to where it will be covers part of
    the time the tips spend returning between strokes, when the valve stands still.
    """

    def __init__(self, config: ValveTeacherConfig = ValveTeacherConfig(), lead: float = 0.3):
        super().__init__(config)
        if lead < 0:
            raise ConfigError(f"ScrewTrackTeacher lead must be >= 0 [s], got {lead}")
        self.lead = lead

    def error(self, qpos: np.ndarray, goal: Goal) -> float:
        ahead = {**goal, "angle": goal["angle"] + goal.get("speed", 0.0) * self.lead}
        return super().error(qpos, ahead)
