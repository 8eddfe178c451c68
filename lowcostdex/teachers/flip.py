"""The flip teacher: a closed-loop scripted flip of the D'Claw flip block (``FlipBlock``).

A 180 deg flip about a horizontal axis is two rolls over an edge. A roll moves the block by one
edge length (50 mm) in the roll direction d = axis x up, and two rolls in one go would take it
beyond the fingers' reach, so the teacher alternates: roll, carry the lying block back, roll.

- **Roll.** The pusher (the thumb for the default flip axis y: its plane of flexion contains d
  and the block's centre) comes over the block's back face (the face opposite d) and down behind
  it, then presses just below the face's top edge, aiming ``lead`` ahead of the block's measured
  roll about its front bottom edge; a yaw of the block steers the contact sideways against it.
  Past ``release`` the block falls on by itself and the pusher lifts off. A roll has landed when
  the block rests within ``settle_angle`` of the next multiple of 90 deg.
- **Carry.** Before a roll the block must start near ``home + roll_from`` along d (so that the
  last roll ends near home). If it is further along d, the two carriers (first and middle finger)
  push its front face low above the table, side by side, back against d, while the pusher trails
  above its back face so that it cannot roll back; the carriers push unequally against the
  block's yaw (a differential drive), so that the next roll starts square. The carry ends at
  its target, or where the block stops moving (the carriers' reach), once the yaw is small.

Everything is computed from the measured ``qpos`` (fingers and block pose) at every call, so the
same teacher drives the simulation (through ``goal_to_action``), the emulated D'Claw's limp
fingers (``lowcostdex.demonstrations.kinesthetic.VirtualTeacher``) and the robot's servos
(:class:`TeacherReorient`, the flip task's reorientation). The number of 90 deg rolls comes
from the goal's orientation (2 for the task's flip, 1-3 to restore a block lying on a side).
Deterministic; it draws no random numbers.

Measured (bench/RESULTS.md, "Flip teacher"): in simulation the noise-free flip succeeds in 20 of
20 episodes at step 47 of 80 (final error 0.04 rad); with +-0.05 executed-action noise 60-65 %;
on the emulated D'Claw through its servos 65 %, as the virtual teacher moving the limp fingers
about half of the episodes (the failures end yawed by 30-40 deg or with one roll only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, keyword_hints
from lowcostdex.hands import DCLAW_FINGERS
from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE, quat_rotate
from lowcostdex.sim.envs.task import Goal
from lowcostdex.sim.kinematics import FingerGeometry
from lowcostdex.sim.models.dclaw import BLOCK_HALF
from lowcostdex.teachers.binding import bound_task, check_call

UP = np.array([0.0, 0.0, 1.0])
ROLL, CARRY, DONE = "roll", "carry", "done"


def _conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.asarray(a, float), np.asarray(b, float))
    return out


@keyword_hints
@dataclass(frozen=True)
class FlipTeacherConfig:
    """Motions of the flip teacher (lengths [m], angles [rad]).

    Attributes:
      pusher: finger that rolls the block (its plane of flexion should contain d).
      carriers: the two fingers that push the lying block back between rolls.
      lead: the pusher aims this far ahead of the block's measured roll.
      below: contact point below the back face's top edge, along the face.
      gap: tip surface to the face when the tip comes down behind it.
      behind, clear: how far behind and above the top edge the tip comes over.
      release: roll within a 90 deg step past which the pusher lets go (the block falls on).
      settle_angle: |roll - 90 deg| within which a roll has landed.
      settle_motion: block motion per control step below which it rests.
      push_yaw_gain, push_yaw_max: sideways shift of the pusher's contact per rad of yaw, and
        its largest value.
      carry_step: block travel per step the carriers command.
      carry_low: the carriers' tip-centre height above the table.
      carry_push: how far inside the block's front face the carriers aim (a firmer push).
      carrier_spread: the carriers' offsets to either side along the axis.
      carry_yaw_gain: differential push per rad of yaw per m of offset.
      guard_high, guard_gap: the trailing pusher's height above the block centre and gap to it.
      carry_tol: distance to the carry target that ends a carry.
      yaw_tol, align_steps: at the carry's end, push on until |yaw| < yaw_tol, at most this
        many steps.
      home: (x, y) [m] where the last roll should end.
      roll_from: where a roll starts along d, from home (the last one then ends about half an
        edge past home); roll_from_tol: a block this much further along d is carried first.
    """

    pusher: str = "th"
    carriers: tuple[str, str] = ("ff", "mf")
    lead: float = math.radians(25)
    below: float = 0.010
    gap: float = 0.002
    behind: float = 0.012
    clear: float = 0.03
    release: float = math.radians(60)
    settle_angle: float = math.radians(20)
    settle_motion: float = 0.003
    push_yaw_gain: float = 0.04
    push_yaw_max: float = 0.016
    carry_step: float = 0.010
    carry_low: float = 0.013
    carry_push: float = 0.004
    carrier_spread: float = 0.02
    carry_yaw_gain: float = -2.0
    guard_high: float = 0.012
    guard_gap: float = 0.006
    carry_tol: float = 0.006
    yaw_tol: float = math.radians(8)
    align_steps: int = 6
    home: tuple[float, float] = (0.0, 0.0)
    roll_from: float = -0.025
    roll_from_tol: float = 0.03

    def __post_init__(self) -> None:
        names = (self.pusher, *self.carriers)
        for f in names:
            if f not in DCLAW_FINGERS:
                raise ConfigError(f"FlipTeacherConfig finger {f!r}; valid: {DCLAW_FINGERS}")
        if len(names) != 3 or len(set(names)) != 3:
            raise ConfigError("FlipTeacherConfig: the pusher and the two carriers must be the "
                              "three different fingers")
        for name in ("lead", "release", "settle_angle", "carry_step", "carry_tol", "yaw_tol"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"FlipTeacherConfig.{name} must be > 0")
        if not 0 < self.release < math.pi / 2:
            raise ConfigError("FlipTeacherConfig.release must be in (0, pi/2)")


class FlipBlockTeacher:
    """Closed-loop flip of the D'Claw flip block; see the module docstring.

    ``reset(task)`` (a bound ``FlipBlock`` task, or anything with ``.task``), then
    ``teacher(qpos, goal)`` with the full ``qpos`` (nq,) every control step -> joint goals (9,)
    [rad] in the hand's action order; ``done`` once the last roll has landed (it then holds).
    ``goal["quat"]`` (the task's goal) sets how many rolls; without it, two.
    """

    def __init__(self, config: FlipTeacherConfig = FlipTeacherConfig()):
        self.config = config

    def reset(self, task_or_env: Any, goal: Goal | None = None) -> None:
        """Bind to a task's model and forget the previous episode (``goal`` is unused)."""
        task = bound_task(task_or_env, type(self).__name__, "dclaw",
                          "the D'Claw's flip-block tasks", attributes=("block_pos", "block_quat"))
        c = self.config
        self._nq = task.model.nq
        self.hand_qpos = task.hand_qpos
        self.block_pos, self.block_quat = task.block_pos, task.block_quat
        self.low, self.high = task.hand_low.reshape(3, 3), task.hand_high.reshape(3, 3)
        self.fingers = [FingerGeometry.from_model(task.model, f) for f in DCLAW_FINGERS]
        self.pusher = DCLAW_FINGERS.index(c.pusher)
        self.carriers = [DCLAW_FINGERS.index(f) for f in c.carriers]
        axis = np.asarray(task.config.flip_axis, float)
        self.axis = axis / np.linalg.norm(axis)
        self.d = np.cross(self.axis, UP)
        self.d /= np.linalg.norm(self.d)
        self.h, self.r = BLOCK_HALF, self.fingers[0].tip_radius
        self.start_quat: np.ndarray | None = None
        self.rolls_needed = 2
        self.rolls = 0
        self.phase, self.stage = ROLL, "approach"
        self._prev: np.ndarray | None = None
        self._lift_from: np.ndarray | None = None
        self._hold: np.ndarray | None = None
        self._k = 0
        self._aligning = False
        self._stalled = 0

    @property
    def done(self) -> bool:
        return self.phase == DONE

    # -- measurements -----------------------------------------------------------------------
    def roll_angle(self, quat: np.ndarray) -> float:
        """The block's roll about the flip axis since the start [rad], in [-pi/2, 3 pi/2)."""
        u = quat_rotate(_mul(quat, _conj(self.start_quat)), UP[None])[0]
        phi = math.atan2(float(u @ self.d), float(u[2]))
        return phi + 2 * math.pi if phi < -math.pi / 2 else phi

    def yaw(self, quat: np.ndarray) -> float:
        """The block's turn about the vertical since the start [rad] (of its flip-axis edge)."""
        x = quat_rotate(_mul(quat, _conj(self.start_quat)), self.axis[None])[0]
        return math.atan2(float(x @ np.cross(UP, self.axis)), float(x @ self.axis))

    def rolls_to(self, quat: np.ndarray, goal_quat: np.ndarray) -> int:
        """90 deg rolls (in the roll direction) from ``quat`` to ``goal_quat``, 0-3."""
        rel = _mul(goal_quat, _conj(quat))
        angle = 2.0 * math.atan2(float(rel[1:] @ self.axis), float(rel[0]))
        return int(round((angle % (2 * math.pi)) / (math.pi / 2))) % 4

    def _roll_from(self) -> float:
        return float(np.array([*self.config.home, 0.0]) @ self.d) + self.config.roll_from

    def _ik(self, i: int, p: np.ndarray) -> np.ndarray:
        return self.fingers[i].inverse(p, self.low[i], self.high[i])

    def _corners(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        local = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
        return pos + quat_rotate(quat, local * self.h)

    def _finger(self, i: int) -> slice:
        return slice(3 * i, 3 * i + 3)

    # -- policy -----------------------------------------------------------------------------
    def __call__(self, qpos: np.ndarray, goal: Goal | None) -> np.ndarray:
        c = self.config
        qpos = check_call(self, qpos, goal, ())
        q = qpos[self.hand_qpos]
        pos, quat = qpos[self.block_pos], qpos[self.block_quat]
        if self.start_quat is None:
            self.start_quat = quat.copy()
            if goal and "quat" in goal:
                self.rolls_needed = self.rolls_to(quat, np.asarray(goal["quat"], float))
            if self.rolls_needed == 0:
                self.phase = DONE
        phi = self.roll_angle(quat)
        if self.rolls >= 2 and phi < 0:  # past 270 deg the roll angle wraps
            phi += 2 * math.pi
        moving = self._prev is not None and np.linalg.norm(pos - self._prev) > c.settle_motion
        self._prev = pos.copy()
        goals = np.tile(RESET_POSE[:3], 3)
        if (self.phase == ROLL and self.stage == "approach"
                and float(pos @ self.d) > self._roll_from() + c.roll_from_tol):
            self.phase, self.stage = CARRY, "place"
        if self.phase == ROLL:
            a = phi - self.rolls * math.pi / 2
            p = self._finger(self.pusher)
            if a > c.release or self.stage == "lift":
                if self.stage != "lift":
                    self.stage = "lift"
                    self._lift_from = self.fingers[self.pusher].forward(q[p])
                goals[p] = self._ik(self.pusher, self._lift_from + UP * 0.03 - self.d * 0.01)
                if abs(a - math.pi / 2) < c.settle_angle and not moving:
                    self.rolls += 1
                    self.stage = "approach"
                    if self.rolls >= self.rolls_needed:
                        self.phase = DONE
                elif a < c.release - math.radians(25) and not moving:  # fell back: again
                    self.stage = "approach"
            else:
                goals[p] = self._push(pos, quat, a)
        if self.phase == DONE:  # hold still, the pusher lifted off the block
            if self._hold is None:
                p = self._finger(self.pusher)
                self._hold = q.copy()
                tip = self.fingers[self.pusher].forward(q[p])
                self._hold[p] = self._ik(self.pusher, tip + UP * 0.03 - self.d * 0.01)
            return self._hold.copy()
        if self.phase == CARRY:
            carried = self._carry(pos, quat, moving)
            if carried is None:
                self.phase, self.stage = ROLL, "approach"
                goals[self._finger(self.pusher)] = self._push(
                    pos, quat, phi - self.rolls * math.pi / 2)
            else:
                goals = carried
        return goals

    def _push(self, pos: np.ndarray, quat: np.ndarray, a: float) -> np.ndarray:
        """The pusher's goals: over, behind and down, then leading the roll by ``lead``."""
        c, i = self.config, self.pusher
        w = self._corners(pos, quat)
        z = w[:, 2]
        top = w[np.argsort(-z)[:4]]
        back = top[np.argsort(top @ self.d)[:2]].mean(axis=0)  # the back face's top edge
        n = -self.d * math.cos(a) + UP * math.sin(a)  # the back face's outward normal
        down = -UP * math.cos(a) - self.d * math.sin(a)  # down the back face
        if self.stage == "approach":
            self.stage = "down"
            return self._ik(i, back + n * (self.r + c.behind) + UP * c.clear)
        if self.stage == "down":
            self.stage = "push"
            return self._ik(i, back + n * (self.r + c.gap) + down * c.below)
        low = w[np.argsort(z)[:4]]
        pivot = low[np.argsort(-(low @ self.d))[:2]].mean(axis=0)  # the front bottom edge
        steer = float(np.clip(c.push_yaw_gain * self.yaw(quat), -c.push_yaw_max,
                              c.push_yaw_max))
        rel = back + n * (self.r - 0.004) + down * c.below + self.axis * steer - pivot
        rs, rz = float(rel @ self.d), float(rel[2])
        ca, sa = math.cos(c.lead), math.sin(c.lead)  # the contact, turned on by ``lead``
        return self._ik(i, pivot + self.d * (ca * rs + sa * rz) + UP * (-sa * rs + ca * rz)
                        + self.axis * float(rel @ self.axis))

    def _carry(self, pos: np.ndarray, quat: np.ndarray, moving: bool) -> np.ndarray | None:
        """All fingers' goals while carrying the block back; None when the carry is over."""
        c = self.config
        h, r = self.h, self.r
        table = pos[2] - h
        s = float(pos @ self.d)
        lateral = pos - s * self.d
        lateral[2] = 0.0
        goals = np.tile(RESET_POSE[:3], 3)

        def front(ds: float, out: float) -> np.ndarray:
            return lateral + self.d * (s + ds + h + r + out) + UP * (table + c.carry_low)

        def back(ds: float, out: float) -> np.ndarray:
            return lateral + self.d * (s + ds - h - r - out) + UP * (pos[2] + c.guard_high)

        if self.stage == "place":
            if moving:
                return goals  # let it come to rest first
            self.stage, self._k, self._aligning, self._stalled = "descend", 0, False, 0
        if self.stage == "descend":
            self._k += 1
            lift = UP * (0.02 if self._k == 1 else 0.0)
            f, b = front(0, c.behind) + lift, back(0, c.behind) + lift
            if self._k >= 3:
                self.stage = "carry"
        elif self.stage == "carry":
            err = self._roll_from() - s
            self._stalled = self._stalled + 1 if not moving else 0
            if err > -c.carry_tol or (self._stalled >= 3 and err > -c.roll_from_tol):
                self._k = self._k + 1 if self._aligning else 1
                self._aligning = True
                if abs(self.yaw(quat)) < c.yaw_tol or self._k > c.align_steps:
                    self.stage, self._k = "release", 0
            step = max(err, -c.carry_step)
            f, b = front(step, -c.carry_push), back(step, c.guard_gap)
        if self.stage == "release":
            self._k += 1
            f, b = front(0, 0.02) + UP * 0.01, back(0, 0.01) + UP * 0.03
            if self._k > 2:
                return None
        yaw = self.yaw(quat) if self.stage == "carry" else 0.0
        for i in self.carriers:
            side = 1.0 if float((self.fingers[i].origin - pos) @ self.axis) > 0 else -1.0
            offset = side * c.carrier_spread
            goals[self._finger(i)] = self._ik(
                i, f + self.axis * offset - self.d * (c.carry_yaw_gain * yaw * offset))
        goals[self._finger(self.pusher)] = self._ik(self.pusher, b)
        return goals


class TeacherReorient:
    """The flip teacher as the flip task's reorientation on a robot
    (``FlipBlockReset(reorient=...)``): it rolls the block back to the start orientation
    through the robot's servos and safety gate, at most ``max_steps`` control steps.

    ``reorient(robot, tracker, quat)``: ``tracker()`` -> (position (3,), quaternion (4,)) of
    the block; ``quat`` the orientation to restore. The reset checks the result.

    Args:
      task: the bound flip task (its model's layout, the flip axis).
      config: the teacher's motions.
      max_steps: control steps before giving up.
    """

    def __init__(self, task: Any, config: FlipTeacherConfig = FlipTeacherConfig(),
                 max_steps: int = 120):
        self.task, self.config, self.max_steps = task, config, max_steps
        self.calls = 0

    def __call__(self, robot: Any, tracker: Any, quat: np.ndarray) -> None:
        t = self.task
        teacher = FlipBlockTeacher(self.config)
        teacher.reset(t)
        names = t.hand.joint_names
        idx = robot.index(names)
        robot.enable(names)
        qpos = np.zeros(t.model.nq)
        goal = {"quat": np.asarray(quat, float)}
        self.calls += 1
        for _ in range(self.max_steps):
            state = robot.read()
            qpos[t.hand_qpos] = state.position[idx]
            pos, q = tracker()
            qpos[t.block_pos], qpos[t.block_quat] = pos, q
            goals = teacher(qpos, goal)
            if teacher.done:
                return
            robot.step(goals, names)
