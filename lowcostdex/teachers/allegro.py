"""The Allegro valve teacher: index, middle and ring turn the valve above the palm-up hand, each
pushing a spoke along its own arc about the valve axis and returning above the spokes (the
stroke of :class:`~lowcostdex.teachers.valve.ValveTurnTeacher` on four-joint
fingers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, keyword_hints
from lowcostdex.sim.envs.task import Goal, wrap_angle
from lowcostdex.sim.kinematics import AllegroFingerGeometry
from lowcostdex.teachers.binding import bound_task, check_call
from lowcostdex.teachers.valve import (
    LOWER,
    PUSH,
    RETURN,
    RISE,
    _angle,
    _spoke_names,
)

ALLEGRO_PUSHERS = ("index", "middle", "ring")


@keyword_hints
@dataclass(frozen=True)
class AllegroTeacherConfig:
    """Strokes of the Allegro valve teacher (lengths [m], angles [rad]).

    Attributes:
      radius: radius of the circle about the valve axis the tips push and return on.
      push_drop: tip-sphere centre below the spoke axis while pushing.
      return_drop: tip-sphere centre below the spoke axis while returning (under the spokes).
      arcs: per finger, the arc of the circle (world angle about the valve axis, from +x) it
        pushes along; together they cover every spoke position (the middle finger takes the
        front, over its fingertip; index and ring the sides).
      couplings: distal/medial joint ratios the inverse kinematics tries, nearest pose first.
      approach_gap: extra angle between tip and spoke when the tip comes up behind it.
      sweep_speed: largest lead of a pushing tip over its spoke per control step.
      travel_speed: largest tip travel per control step while returning.
      error_gain: lead = min(sweep_speed, error_gain * valve error).
      hold_tolerance: valve error below which pushing stops.
      rise_min: valve error below which a finger comes up only if no other finger is pushing.
      angle_tolerance: tip angle from its target that counts as arrived.
      height_tolerance: tip height from its target [m] that ends a rise or a descent.
      gravity_compensation: add gravity torque / kp to the goals for the hand's soft PD (on
        when the teacher's goals drive the servos); off when the goals are targets of the
        emulator's virtual teacher (``VirtualTeacher``), which holds its own pose.
    """

    radius: float = 0.05
    push_drop: float = 0.003
    return_drop: float = 0.03
    arcs: tuple[tuple[str, float, float], ...] = (
        ("index", math.radians(-155), math.radians(-35)),
        ("middle", math.radians(-35), math.radians(35)),
        ("ring", math.radians(35), math.radians(155)),
    )
    couplings: tuple[float, ...] = (1.0, 0.5, 0.0)
    approach_gap: float = math.radians(8)
    sweep_speed: float = math.radians(30)
    travel_speed: float = math.radians(50)
    error_gain: float = 0.8
    hold_tolerance: float = 0.02
    rise_min: float = 0.25
    angle_tolerance: float = math.radians(5)
    height_tolerance: float = 0.006
    gravity_compensation: bool = True

    def __post_init__(self) -> None:
        for name in ("radius", "return_drop", "sweep_speed", "travel_speed", "error_gain",
                     "hold_tolerance", "angle_tolerance", "height_tolerance"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"AllegroTeacherConfig.{name} must be > 0")
        if sorted(f for f, _, _ in self.arcs) != sorted(ALLEGRO_PUSHERS):
            raise ConfigError(f"AllegroTeacherConfig.arcs needs one arc per finger of "
                              f"{ALLEGRO_PUSHERS}")
        for f, lo, hi in self.arcs:
            if not lo < hi:
                raise ConfigError(f"AllegroTeacherConfig.arcs: {f} arc needs low < high")


class AllegroValveTeacher:
    """Closed-loop valve turning (360 deg and more) with the palm-up Allegro (``allegro_tasks``).

    Index, middle and ring fingertips work on a circle about the valve axis, each on its own
    arc: a finger waits under the spokes at the start of its arc, comes up behind the next spoke
    that enters it, pushes it along the arc (leading it by at most ``sweep_speed``), drops under
    the spokes at the end of its arc and travels back. The arcs cover the whole circle, so some
    finger always has a spoke (a relay), and the valve turns without a pause. The thumb holds the
    pose it has at the first call. The hand's joint PD is soft (v4 defaults, 0.5 N m/rad), so the
    joint goals carry the gravity torque / kp, as a host-side gravity compensation would.

    ``reset(task)`` (or a ``HandEnv``), then ``teacher(qpos, goal)`` -> joint goals (16,) [rad].
    The goal angle is unwrapped; the teacher turns the valve in the positive sense.
    """

    def __init__(self, config: AllegroTeacherConfig = AllegroTeacherConfig()):
        self.config = config

    def reset(self, task_or_env, goal: Goal | None = None) -> None:
        """Bind to a task's model and forget the previous episode (``goal`` is unused)."""
        task = bound_task(task_or_env, type(self).__name__, "allegro",
                          "the Allegro's valve tasks", joint="valve")
        model = task.model
        c = self.config
        self._nq = model.nq
        self.model, self.data = model, mujoco.MjData(model)
        self.hand_qpos, self.hand_dof, self.hand_act = task.hand_qpos, task.hand_dof, task.hand_act
        self.low, self.high = task.hand_low, task.hand_high
        self.valve_qpos = int(model.jnt_qposadr[model.joint("valve").id])
        names = [j.name for j in task.hand.joints]
        self.fingers = {f: AllegroFingerGeometry.from_model(model, f) for f in ALLEGRO_PUSHERS}
        self.slices = {f: np.array([names.index(f"{f}_{k}") for k in range(4)])
                       for f in ALLEGRO_PUSHERS}
        mujoco.mj_kinematics(model, self.data)
        self.center = self.data.xpos[model.body("valve_body").id].copy()
        spokes = [model.geom(name) for name in _spoke_names(model)]
        self.spoke_angles = np.array([_angle(self.data.geom_xpos[g.id] - self.center)
                                      for g in spokes])
        spoke_z = float(self.data.geom_xpos[spokes[0].id][2])
        tip_radius = float(model.geom("index_tip_geom").size[0])
        self.contact_angle = math.asin(min((tip_radius + float(spokes[0].size[0])) / c.radius,
                                           1.0))
        self.push_z = spoke_z - c.push_drop
        self.low_z = spoke_z - c.return_drop
        self.arcs = {f: (lo, hi) for f, lo, hi in c.arcs}
        self.state = {f: RETURN for f in ALLEGRO_PUSHERS}  # RETURN, RISE, PUSH, LOWER
        self.command: dict[str, list[float]] = {}  # finger -> [angle from arc centre, height]
        self.held = {f: False for f in ALLEGRO_PUSHERS}
        self.goals: np.ndarray | None = None

    def tips(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Tip-sphere centres (3,) [m] of the pushing fingers for hand joint angles q (16,)."""
        return {f: g.forward(q[self.slices[f]]) for f, g in self.fingers.items()}

    def __call__(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        c = self.config
        qpos = check_call(self, qpos, goal, ("angle",))
        q = qpos[self.hand_qpos]
        if self.goals is None:
            self.goals = q.copy()  # the thumb keeps this pose
        theta = float(qpos[self.valve_qpos])
        err = float(goal["angle"]) - theta
        hold = err < c.hold_tolerance
        lead = min(c.sweep_speed, c.error_gain * max(err, 0.0))
        spokes = self.spoke_angles + theta
        pushing = sum(s == PUSH for s in self.state.values())
        for f, tip in self.tips(q).items():
            lo, hi = self.arcs[f]
            mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            rel = tip - self.center
            a = float(wrap_angle(math.atan2(rel[1], rel[0]) - mid))  # tip angle on the arc
            z = float(tip[2])
            cmd = self.command.setdefault(f, [float(np.clip(a, -half, half)), self.low_z])
            spoke = wrap_angle(spokes - mid)
            self.state[f] = self._finger(f, a, z, cmd, spoke, half, hold, lead,
                                         err > c.rise_min or pushing == 0)
            point = self.center + np.array([c.radius * math.cos(cmd[0] + mid),
                                            c.radius * math.sin(cmd[0] + mid), 0.0])
            point[2] = cmd[1]
            self.goals[self.slices[f]] = self._inverse(f, point)
        if not self.config.gravity_compensation:
            return np.clip(self.goals, self.low, self.high)
        return self._gravity_compensated(qpos, self.goals)

    def _finger(self, f: str, a: float, z: float, cmd: list[float], spoke: np.ndarray,
                half: float, hold: bool, lead: float, may_rise: bool) -> str:
        """Advance one finger's stroke; updates ``cmd`` in place; returns its new state."""
        c = self.config
        state = self.state[f]
        if state == PUSH:
            k = int(np.argmin(np.abs(wrap_angle(spoke - (a + self.contact_angle)))))
            behind = float(spoke[k]) - self.contact_angle
            if not hold:
                cmd[0] = min(behind + lead, half)
                self.held[f] = False
            elif not self.held[f]:  # stop pressing: back off the spoke a little
                cmd[0] = min(a, behind) - math.radians(3)
                self.held[f] = True
            if a >= half - c.angle_tolerance and not hold:
                state = LOWER
        if state == RISE and hold:
            state = LOWER
        if state == LOWER:
            cmd[1] = self.low_z
            if z <= self.low_z + c.height_tolerance:
                state = RETURN
        if state == RETURN:
            cmd[1] = self.low_z
            start = spoke - self.contact_angle - c.approach_gap
            ok = (start >= -half) & (start <= half - 3 * c.angle_tolerance)
            target = float(np.min(start[ok])) if np.any(ok) else -half
            cmd[0] += float(np.clip(target - cmd[0], -c.travel_speed, c.travel_speed))
            arrived = np.any(ok) and abs(target - a) < c.angle_tolerance
            if arrived and not hold and may_rise:
                state = RISE
        if state == RISE:
            cmd[1] = self.push_z
            if z >= self.push_z - c.height_tolerance:
                state = PUSH
        return state

    def _inverse(self, f: str, point: np.ndarray) -> np.ndarray:
        """Joints of finger f reaching ``point``: reachable solutions first, then the nearest."""
        idx = self.slices[f]
        best = None
        for k in self.config.couplings:
            q = self.fingers[f].inverse(point, self.low[idx], self.high[idx], k)
            miss = np.linalg.norm(self.fingers[f].forward(q) - point) > 1e-4
            score = (miss, float(np.max(np.abs(q - self.goals[idx]))))
            if best is None or score < best[0]:
                best = (score, q)
        return best[1]

    def _gravity_compensated(self, qpos: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """Goals shifted by gravity torque / kp, so the soft PD holds the pose it is given."""
        d = self.data
        d.qpos[:] = qpos
        d.qvel[:] = 0.0
        mujoco.mj_forward(self.model, d)
        kp = self.model.actuator_gainprm[self.hand_act, 0]
        return np.clip(goals + d.qfrc_bias[self.hand_dof] / kp, self.low, self.high)
