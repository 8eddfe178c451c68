"""Scripted teachers: closed-loop solving motions that map the present state to joint goals.

A teacher is deterministic and draws no random numbers. It reads the full ``qpos`` of the task's
model (hand joints and object) and returns joint goals [rad] for the hand joints in action order,
so it can drive a ``HandEnv`` (``goal_to_action``), serve as the physics sanity test, and act as the
"virtual teacher" that moves the fingers of an emulated hand while demonstrations are recorded.

``ValveTurnTeacher`` turns the D'Claw valve as a relay: each finger runs its own stroke (wait
lifted above the spokes, come down behind the first spoke ahead of its tip, push it along a circle
about the valve axis with the side of the tip, rise, travel back), planned from the measured valve
angle with analytic inverse kinematics. A finger comes down while no finger pushes, or, while
another pushes, behind a spoke that has just come into its reach (``early_window``: it lands as
that stroke ends). Either way the spoke stands still or turns away from where the tip lands, so
an open-loop playback of a recorded demonstration, whose valve lags the original by a few
degrees, lands behind the same spoke. On a valve with dry friction (the foam valve, which stops
when let go) every finger that can reach a spoke joins the stroke that finishes the turn
(``share_last``). The first stroke is one finger's when the spoke ahead leaves the fingers less than ``solo_stroke``
(ROBEL's spoke phase: spokes midway between the fingers), else all three push together. The
tips push low on the spokes (``push_height``): the contact normal is then closer to horizontal,
so a servo that yields under load (the playback) loses less of the stroke by riding up the spoke.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, keyword_hints
from lowcostdex.hands import DCLAW_FINGERS
from lowcostdex.sim.envs.task import Goal, wrap_angle
from lowcostdex.sim.kinematics import FingerGeometry
from lowcostdex.teachers.binding import bound_task, check_call

RETURN, PUSH, RISE, LOWER, WAIT = "return", "push", "rise", "lower", "wait"



# ------------------------------------------------------------------------------------------------
# Valve turning


@keyword_hints
@dataclass(frozen=True)
class ValveTeacherConfig:
    """Strokes of the valve-turning teacher (lengths [m], angles [rad]).

    Angles are tip angles about the valve axis from the finger's own direction, counted in the
    turning direction (a stroke runs from negative to positive).

    Attributes:
      push_radius: radius of the fingertip circle about the valve axis.
      push_height: tip-sphere centre above the spoke axis while pushing.
      wait_radius: radius of the circle the tips travel and wait on, above the spokes.
      wait_height: tip-sphere centre above the spoke axis there (clear of a neighbour's pushing
        tip passing below).
      reach: a stroke ends at this tip angle (lowered at ``reset`` to what every finger
        reaches on the push circle); strokes start no further back than -reach.
      wait_angle: where a finger waits for the next spoke (at -wait_angle): a little behind
        where the furthest-back stroke starts, so the tip may come down behind a spoke as soon as
        the spoke comes into reach (a spoke less than a contact angle ahead of a waiting tip is
        not pushed from behind by it).
      approach_gap: angle between the tip and the spoke's contact position when the tip comes
        down behind it.
      min_stroke: a finger comes down only behind a spoke it can push at least this far.
      solo_stroke: the first stroke is made by one finger if it would be shorter than this (the
        other two wait for the next spoke and push it further), else by all three.
      clearance: a finger does not come down within this angle (about the valve axis) of
        another finger's pushing or rising tip.
      early_window: while another finger pushes, a waiting finger comes down only behind a
        spoke that has just come into reach (its stroke starts within this angle of -reach),
        so it lands as the pushing finger's stroke ends instead of after it; the valve turns
        away from where it lands, so a playback whose valve lags still lands behind the spoke.
      share_last: on a valve with dry friction (it stops when let go: the foam valve), every
        waiting finger that can reach a spoke joins the stroke that finishes the turn, so no
        single servo carries the last, slowest part alone. Applied only where the valve hinge has
        dry friction (``dof_frictionloss`` > 0, read from the model at ``reset``): on a valve that
        coasts (the valve, the screw) extra fingers overshoot in the playbacks.
      sweep_speed: largest lead of the tip command over the spoke's contact position per
        control step; error_gain: lead = min(sweep_speed, error_gain * |valve error|).
      max_lead: largest lead of the tip command over the measured tip.
      travel_speed: largest travel of a waiting tip's command per control step.
      reach_tolerance: a stroke ends when the measured tip is this close to ``reach``.
      hold_tolerance: |valve error| below which the fingers hold still.
      reverse_tolerance: overshoot beyond which the fingers go round to push back.
      settle_tolerance: height [m] above the push height that ends a descent.
      rise_clearance: a rising tip starts to wait (and may travel) once this far [m] above the
        spoke tops; travel_clearance: a waiting tip travels only this far above them (tips
        that travelled 4 mm above the push height in a playback dragged a spoke back).
      hold_backoff: when the valve reaches the goal a pushing tip steps back this much, so it
        stops pressing on the spoke.
      flip_margin: the turning direction chosen at the first call (the short way; +1 at exactly
        180 deg) is kept until the wrapped error passes pi - flip_margin the other way.
    """

    push_radius: float = 0.065
    push_height: float = 0.022
    wait_radius: float = 0.085
    wait_height: float = 0.05
    reach: float = math.radians(75)
    wait_angle: float = math.radians(64)
    approach_gap: float = math.radians(8)
    min_stroke: float = math.radians(20)
    solo_stroke: float = math.radians(90)
    clearance: float = math.radians(35)
    sweep_speed: float = math.radians(24)
    error_gain: float = 0.8
    max_lead: float = math.radians(35)
    travel_speed: float = math.radians(40)
    reach_tolerance: float = math.radians(4)
    hold_tolerance: float = 0.02
    reverse_tolerance: float = 0.08
    settle_tolerance: float = 0.004
    rise_clearance: float = 0.006
    travel_clearance: float = 0.008
    hold_backoff: float = math.radians(2)
    flip_margin: float = 0.5
    early_window: float = math.radians(8)
    share_last: bool = True

    def __post_init__(self) -> None:
        if not (self.rise_clearance >= 0 and self.travel_clearance >= 0):
            raise ConfigError("ValveTeacherConfig.rise_clearance and travel_clearance must be >= 0")
        for name in ("push_radius", "wait_radius", "reach", "sweep_speed", "travel_speed",
                     "max_lead", "error_gain", "hold_tolerance", "settle_tolerance"):
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

    A relay: every finger runs its own stroke (``wait`` above the spokes at -wait_angle,
    ``lower`` behind the first spoke ahead of its tip, ``push`` it to ``reach``, ``rise``, back to
    ``wait``). One finger starts; the next comes down behind the spoke reaching it as the pushing
    finger ends its stroke, so one finger pushes while the others return and the valve keeps
    turning. Everything is planned from the measured valve angle and spoke
    directions, so it works at any spoke phase (the fingers and spokes share the 3-fold symmetry:
    every finger sees the spokes at the same angles in its own frame).
    """

    def __init__(self, config: ValveTeacherConfig = ValveTeacherConfig()):
        self.config = config

    def reset(self, task_or_env, goal: Goal | None = None) -> None:
        """Bind to a task's model and forget the previous episode (``goal`` is unused)."""
        task = bound_task(task_or_env, type(self).__name__, "dclaw",
                          "the D'Claw's valve, foam-valve and screw tasks", joint="valve")
        model = task.model
        c = self.config
        self._nq = model.nq
        self.hand_qpos = task.hand_qpos
        self.low, self.high = task.hand_low.reshape(3, 3), task.hand_high.reshape(3, 3)
        valve = model.joint("valve")
        self.valve_qpos = int(model.jnt_qposadr[valve.id])
        self.share_last = c.share_last and float(model.dof_frictionloss[valve.dofadr[0]]) > 0
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
        self.wait_z = spoke_z + c.wait_height
        self.clear_z = spoke_z + spoke_radius + tip_radius + 0.002  # above the spoke tops
        lift = max(c.rise_clearance, c.travel_clearance)
        if not self.wait_z > self.clear_z + lift:
            raise ConfigError(f"wait_height {c.wait_height} must put the tips above the "
                              f"spokes (> {self.clear_z + lift - spoke_z:.3f} m)")
        self.reach = min(c.reach, self._reachable(c.push_radius, self.push_z))
        if not max(c.wait_angle, self.reach) <= self._reachable(c.wait_radius, self.wait_z):
            raise ConfigError("wait_radius/wait_height: the fingers cannot reach the wait circle")
        self.state = [WAIT] * 3
        self.command: np.ndarray | None = None  # per finger: tip angle [rad], radius, height [m]
        self.direction = 0.0  # turning direction (+1 / -1; 0 before the first call)
        self._held = [False] * 3
        self._started = False  # a stroke has started since the first call or the last reversal
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
        qpos = check_call(self, qpos, goal, ("angle",))
        q = qpos[self.hand_qpos]
        err = self.error(qpos, goal)
        tips_alpha, _, tips_z = self.tip_polar(q)
        if self.command is None:
            self.command = np.stack([tips_alpha, np.full(3, c.push_radius), tips_z], axis=1)
        s = math.copysign(1.0, err)
        if self.direction == 0.0:
            self.direction = s
        elif s != self.direction and abs(err) > c.reverse_tolerance:  # go round, push back
            self.direction = s
            self.state = [RISE if st in (PUSH, LOWER) else st for st in self.state]
            self._started = False
        s = self.direction
        hold = abs(err) < c.hold_tolerance or math.copysign(1.0, err) != s
        lead = min(c.sweep_speed, c.error_gain * abs(err))
        spokes = s * self.spoke_rel(float(qpos[self.valve_qpos]))  # in the turning direction
        u_tips = s * tips_alpha
        # a finger comes down only while no finger pushes (the valve stands still, so where
        # the tip lands does not depend on timing); the first stroke is one finger's if it is short
        handover = not any(st in (PUSH, LOWER) for st in self.state)
        starts = 3 if self._started else self._first_group(spokes)
        for i in range(3):
            u, z, cmd = float(u_tips[i]), float(tips_z[i]), self.command[i]
            if self.state[i] == PUSH:
                self._push(i, u, cmd, spokes, hold, lead)
            if self.state[i] == RISE:
                cmd[1:] = c.wait_radius, self.wait_z
                if z >= self.clear_z + c.rise_clearance:
                    self.state[i] = WAIT
            if self.state[i] == WAIT:
                start = None
                if starts > 0 and not hold:
                    start = self._start(i, u, spokes, self.finger_angles + tips_alpha)
                    if start is not None and not handover and not self._joins(start, err):
                        start = None
                if start is not None:
                    starts -= 1
                    self._started = True
                    self.state[i] = LOWER
                    cmd[0] = s * start
                else:
                    cmd[1:] = c.wait_radius, self.wait_z
                    if z >= self.clear_z + c.travel_clearance:  # travel only above the spokes
                        cmd[0] = s * (s * cmd[0] + float(np.clip(-c.wait_angle - s * cmd[0],
                                                                 -c.travel_speed, c.travel_speed)))
            if self.state[i] == LOWER:
                # behind the spoke it came down for (the spoke may move meanwhile)
                behind = spokes - self.contact_angle - c.approach_gap
                k = int(np.argmin(np.abs(wrap_angle(behind - s * cmd[0]))))
                cmd[:] = s * max(float(behind[k]), -self.reach), c.push_radius, self.push_z
                if z <= self.push_z + c.settle_tolerance:
                    self.state[i] = PUSH
        return np.concatenate([f.inverse(self._circle_point(i, *self.command[i]), self.low[i],
                                         self.high[i]) for i, f in enumerate(self.fingers)])

    def _joins(self, start: float, err: float) -> bool:
        """Whether a finger may come down at ``start`` [rad] while another finger pushes: behind
        a spoke just come into reach (``early_window``), or (``share_last``) for a stroke that
        finishes the turn (the error [rad] is covered before the tip reaches ``reach``)."""
        c = self.config
        if start <= -self.reach + c.early_window:
            return True
        return self.share_last and (start + c.approach_gap + abs(err)
                                    <= self.reach - c.reach_tolerance)

    def _first_group(self, spokes: np.ndarray) -> int:
        """How many fingers start the first stroke: all three if the spoke ahead leaves them a
        stroke of ``solo_stroke`` or more, else one (the other two take the next, longer one)."""
        c = self.config
        d = wrap_angle(spokes + c.wait_angle)
        start = spokes - self.contact_angle - c.approach_gap
        stroke = self.reach - (spokes - self.contact_angle)
        ok = (start >= -self.reach) & (d > -self.contact_angle)
        return 3 if np.any(ok & (stroke >= c.solo_stroke)) else 1

    def _push(self, i: int, u: float, cmd: np.ndarray, spokes: np.ndarray, hold: bool,
              lead: float) -> None:
        """Lead the spoke ahead of tip i by ``lead`` (up to ``reach``); rise at the end."""
        c, s = self.config, self.direction
        k = int(np.argmin(np.abs(wrap_angle(spokes - (u + self.contact_angle)))))
        contact = float(spokes[k]) - self.contact_angle
        cmd[1:] = c.push_radius, self.push_z
        if hold:
            if not self._held[i]:  # stop pressing: back the tip off the spoke a little
                cmd[0] = s * (min(u, contact) - c.hold_backoff)
                self._held[i] = True
            return
        self._held[i] = False
        cmd[0] = s * min(max(contact, u) + lead, self.reach, u + c.max_lead)
        if u >= self.reach - c.reach_tolerance:
            self.state[i] = RISE

    def _start(self, i: int, u: float, spokes: np.ndarray, world_tips: np.ndarray
               ) -> float | None:
        """Where waiting finger i comes down (tip angle in the turning direction), or None.

        Behind the first spoke ahead of its tip (a spoke less than a contact angle behind the
        tip is still under it: wait for it to pass; a spoke less than a contact angle ahead is
        pushed from behind only by a tip that does not have to move back across it), if the stroke left is at least
        ``min_stroke`` and no other pushing or rising tip (``world_tips``: world angles about the
        valve axis [rad]) is within ``clearance``.
        """
        c = self.config
        d = wrap_angle(spokes - u)
        k = int(np.argmin(np.where(d > -self.contact_angle, d, np.inf)))
        start = float(spokes[k]) - self.contact_angle - c.approach_gap
        # behind its tip only if the tip is behind the spoke's contact position already (it
        # then moves away from the spoke while it comes down)
        if start < -self.reach or (start < u - c.reach_tolerance and d[k] < self.contact_angle):
            return None
        if self.reach - (start + c.approach_gap) < c.min_stroke:
            return None
        point = self.finger_angles[i] + self.direction * start  # world angle of the descent
        for j in range(3):
            if (j != i and self.state[j] in (PUSH, RISE)
                    and abs(wrap_angle(world_tips[j] - point)) < c.clearance):
                return None
        return start


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
