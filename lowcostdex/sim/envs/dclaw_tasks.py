"""D'Claw tasks: turn a valve (180 deg), turn a foam valve, track a screw, flip a block.

Task definitions follow ROBEL (01-hardware.md section 1.5): 10 Hz control (40 x 2.5 ms), reset pose
[0, -pi/3, pi/3] per finger, reward terms -5|err|, -||q - q_reset||, -||v[|v| > 0.5]||,
+10 (|err| < 0.25), +50 (|err| < 0.1); success |err| < 0.1 rad (turn) or 0.2 rad (screw).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice, keyword_hints
from lowcostdex.hands import HandSpec, dclaw_spec
from lowcostdex.sim import servo
from lowcostdex.sim.envs.task import (
    TOLERANCE,
    VALVE_BOUNDS,
    VALVE_GOAL,
    Goal,
    Task,
    TaskSpec,
    check_flag,
    check_settings,
    wrap_angle,
)
from lowcostdex.sim.models.common import quat_euler
from lowcostdex.sim.models.dclaw import BLOCK_CENTER, BLOCK_HALF, VALVE, build_dclaw
from lowcostdex.sim.models.dclaw_edit import DClawEdit, as_edit

RESET_POSE = np.tile([0.0, -math.pi / 3, math.pi / 3], 3)  # [rad] ROBEL turn/screw reset pose


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(np.square(x), axis=-1))


class DClawTask(Task):
    """Common D'Claw pieces: the scene, the hand observation, the pose and velocity penalties."""

    station: str = "none"

    def __init__(self, hand: HandSpec | None = None, gains: servo.ServoGains | None = None,
                 timing: TaskSpec = TaskSpec(),
                 model_edit: DClawEdit | Mapping[str, Any] | None = None):
        self.hand = hand or dclaw_spec()
        self.gains = gains
        self.timing = timing
        # a fitted geometry / valve edit (``sim.models.dclaw_edit``), applied on every build
        self.model_edit = as_edit(model_edit)

    def build_spec(self) -> mujoco.MjSpec:
        spec = build_dclaw(self.station, self.hand, self.gains)
        if self.model_edit is not None:
            self.model_edit.apply(spec)
        return spec

    def hand_state(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return qpos[..., self.hand_qpos], qvel[..., self.hand_dof]

    def posture_terms(self, qpos: np.ndarray, qvel: np.ndarray) -> dict[str, np.ndarray]:
        q, v = self.hand_state(qpos, qvel)
        fast = np.where(np.abs(v) >= 0.5, v, 0.0)
        return {"pose": -1.0 * _norm(q - RESET_POSE), "velocity": -1.0 * _norm(fast)}


@keyword_hints
@dataclass(frozen=True)
class TurnConfig:
    """Valve-turning goal distribution.

    Attributes:
      init_range: initial valve angle ~ U(-init_range, init_range) [rad] (0: fixed at 0).
      goal_offset: nominal goal relative to the initial angle [rad] (pi = 180 deg).
      goal_range: goal ~ init + goal_offset + U(-goal_range, goal_range) [rad].
      success_tol: |error| for success [rad].
      pose_noise: std of Gaussian noise on the initial finger pose [rad].
    """

    init_range: float = 0.0
    goal_offset: float = math.pi
    goal_range: float = 0.0
    success_tol: float = 0.1
    pose_noise: float = 0.0

    def __post_init__(self) -> None:
        check_settings(self, VALVE_BOUNDS)


class ValveTask(DClawTask):
    """Shared pieces of the valve tasks: observation, error, reward, the released valve motor.

    The valve motor (id 50) is torque-off during episodes, as ROBEL disengages it after the
    reset: ``passive_actuators`` names it, and every backend releases it (the sim backends switch
    its torque off in the plant; robots release it after their auto-reset). A torque-on servo
    whose goal follows the valve once per control step is not free: within each 0.1 s step it
    pulls the valve back to the step's starting angle (kp ~ 15.7 N m/rad plus back-EMF damping
    ~ 1.1 N m s/rad on an XH430-W350), which held a 0.1 N m turning torque to 0.05 rad in 1 s.
    """

    config: TurnConfig | ScrewConfig
    passive_actuators = ("valve",)
    object_joint = "valve"
    goal_bounds = VALVE_GOAL

    @property
    def obs_dim(self) -> int:
        return 9 + 9 + 2 + 1 + 9

    def error(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        return wrap_angle(goal["angle"] - qpos[..., self.obj_qpos])

    def observation(self, qpos, qvel, goal, last_action):
        q, v = self.hand_state(qpos, qvel)
        theta = qpos[..., self.obj_qpos]
        err = self.error(qpos, goal)[..., None]
        return np.concatenate([q, v, np.cos(theta)[..., None], np.sin(theta)[..., None], err,
                               last_action], axis=-1)

    def reward_terms(self, qpos, qvel, goal, action):
        err = np.abs(self.error(qpos, goal))
        terms = {"goal_error": -5.0 * err}
        terms.update(self.posture_terms(qpos, qvel))
        terms["bonus_small"] = 10.0 * (err < 0.25)
        terms["bonus_big"] = 50.0 * (err < 0.10)
        return terms

    def success(self, qpos, goal):
        return np.abs(self.error(qpos, goal)) < self.config.success_tol

    def goal_error(self, qpos, goal):
        return self.error(qpos, goal)

    def aux_ctrl(self, qpos):
        # The valve motor is released (torque off, see the class doc); its goal follows the valve.
        return qpos[..., [self.obj_qpos]]

    def goal_marker(self, goal):
        # the arrow points where spoke 0 will point when the valve is at the goal
        return (np.array([0.0, 0.0, 0.16]),
                np.array(quat_euler(z=float(goal["angle"]) + VALVE.spoke_phase)))


class TurnValve(ValveTask):
    """Turn the 3-spoke valve to a goal angle (default 180 deg from 0)."""

    station = "valve"

    def __init__(self, config: TurnConfig = TurnConfig(), *, foam: bool = False, **kw):
        super().__init__(**kw)
        self.config = config
        if foam:
            self.station = "foam_valve"

    def initial_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, Goal]:
        c = self.config
        qpos = np.zeros(self.model.nq)
        qpos[self.hand_qpos] = RESET_POSE + c.pose_noise * rng.normal(size=9)
        init = rng.uniform(-c.init_range, c.init_range) if c.init_range > 0 else 0.0
        goal = init + c.goal_offset + (rng.uniform(-c.goal_range, c.goal_range)
                                       if c.goal_range > 0 else 0.0)
        qpos[self.obj_qpos] = init
        return qpos, np.zeros(self.model.nv), {"angle": np.asarray(goal, float)}


@keyword_hints
@dataclass(frozen=True)
class ScrewConfig:
    """Screw tracking: the goal angle moves at ``speed`` rad/s from the initial angle.

    Attributes:
      speed: goal velocity [rad/s] (fixed variant) or the bound of U(-speed, speed) (random).
      random: sample initial angle U(-pi, pi) and speed U(-speed, speed) (ROBEL ScrewRandom).
      success_tol: |error| for success [rad].
    """

    speed: float = 0.5
    random: bool = False
    success_tol: float = 0.2

    def __post_init__(self) -> None:
        check_settings(self, {"speed": (-2 * math.pi, 2 * math.pi, "rad/s"),
                              "success_tol": TOLERANCE})
        check_flag(self, "random")


class Screw(ValveTask):
    """Keep the valve (continuous rotation) at a goal angle moving at constant speed."""

    station = "screw"

    def __init__(self, config: ScrewConfig = ScrewConfig(), **kw):
        kw.setdefault("timing", TaskSpec(frame_skip=40, episode_steps=80))
        super().__init__(**kw)
        self.config = config

    def initial_state(self, rng):
        c = self.config
        qpos = np.zeros(self.model.nq)
        qpos[self.hand_qpos] = RESET_POSE
        init = rng.uniform(-math.pi, math.pi) if c.random else 0.0
        speed = rng.uniform(-c.speed, c.speed) if c.random else c.speed
        qpos[self.obj_qpos] = init
        goal = {"angle": np.asarray(init, float), "start": np.asarray(init, float),
                "speed": np.asarray(speed, float)}
        return qpos, np.zeros(self.model.nv), goal

    def advance_goal(self, goal: Goal, step: int) -> Goal:
        period = self.timing.frame_skip * self.model.opt.timestep
        return {**goal, "angle": goal["start"] + goal["speed"] * period * step}


@keyword_hints
@dataclass(frozen=True)
class FlipConfig:
    """Block flipping.

    Attributes:
      representation: "keypoints" (observation: the 8 cube corners of the block and of the
        goal; reward: the corners' mean distance from the goal's about the block's centre) or
        "quaternion" (observation: position + orientation quaternion; reward: rotation
        angle). Both rewards have the same position term (-20 x distance [m] from the start
        centre), and the orientation terms have the same scale (``KEYPOINT_WEIGHT``: the flip
        costs pi in both), so the two differ only in how they measure the orientation.
        (Until 2026-11-26 the keypoint reward was -20 x the mean distance of the absolute
        corners, which mixes in the block's travel: a roll moves it by one edge. Along 17
        successful teacher flips it went from -1.41 at the start to -1.60 after the first
        roll and -1.16 at the flipped end: the whole flip was worth 0.25, against 1.87 for the
        quaternion reward's object terms and 1.81 for the present keypoint terms;
        bench/RESULTS.md.)
      flip_axis: horizontal axis the goal rotates the block about. Default y: a flip about y
        rolls the block along x, in the thumb's plane of flexion, which passes through the
        block's centre, so a push turns it without yawing it; about x the push comes from the
        first finger, whose plane is at 60 deg to the roll, and yawed the block 20-30 deg per
        roll (the flip teacher, ``FlipBlockTeacher``: final error 0.13-0.6 rad about x, 0.04
        rad about y; bench/RESULTS.md).
      success_angle: orientation error for success [rad].
      drop_height: block centre below this height [m] ends the episode (terminated).
      position_radius: the block's start centre is uniform in a disc of this radius [m] about
        its resting place on the table (``BLOCK_CENTER``).
      yaw_range: the block's start turn about the vertical ~ U(-yaw_range, yaw_range) [rad].
      joint_range: each finger joint starts at the reset pose + U(-joint_range, joint_range)
        [rad].

    The start noise is sized by the robot's episode reset: ``FlipBlockReset`` accepts a block
    within 15 mm of its start (``FlipResetConfig.position_tolerance``) and the finger reset
    ends with every joint within 0.01 rad (``ResetConfig.precision``). Measured on the emulated
    D'Claw (2026-11-26, 10 resets of a block displaced by up to 40 mm and 1 rad): the squeezes
    left it 1.8-19.3 mm from its start (median 8 mm) and turned by 0.015-0.16 rad (median
    0.05). All 0: one fixed start (every episode of a deterministic policy is then the same
    episode in the noise-free simulation).
    """

    representation: str = "keypoints"
    flip_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    success_angle: float = 0.4
    drop_height: float = 0.03
    position_radius: float = 0.015
    yaw_range: float = 0.15
    joint_range: float = 0.01

    def __post_init__(self) -> None:
        check_choice("block representation", self.representation, ("keypoints", "quaternion"))
        check_settings(self, {"success_angle": TOLERANCE,
                              "drop_height": (-1.0, 1.0, "m"),
                              "position_radius": (0.0, 0.1, "m"),
                              "yaw_range": (0.0, math.pi, "rad"),
                              "joint_range": (0.0, 1.0, "rad")})
        axis = np.asarray(self.flip_axis, dtype=float) if _numbers(self.flip_axis) else None
        if axis is None or axis.shape != (3,) or not np.all(np.isfinite(axis)) or not (
                np.linalg.norm(axis) > 0):
            raise ConfigError(f"FlipConfig.flip_axis={self.flip_axis!r} must be 3 finite numbers, "
                              "not all 0 (an axis, e.g. (0, 1, 0))")


def _numbers(x: object) -> bool:
    try:
        return np.asarray(x).dtype.kind in "iuf"
    except (TypeError, ValueError):
        return False


_CORNERS = np.array([[sx, sy, sz] for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)],
                    dtype=float) * BLOCK_HALF


KEYPOINT_WEIGHT = math.pi / (2.0 * math.sqrt(2.0) * BLOCK_HALF)
"""Weight [1/m] of the flip's keypoint term: the mean distance of the block's corners, about its
centre, from the goal's (-KEYPOINT_WEIGHT x distance). A 180 deg turn about a face axis moves
every corner by 2 sqrt(2) BLOCK_HALF, so the flip costs pi, as the quaternion reward's angle
term (-1 x angle [rad]) does."""


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., k, 3) by unit quaternions q (..., 4) (w, x, y, z)."""
    w = q[..., None, 0:1]
    u = q[..., None, 1:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation angle between unit quaternions (...) [rad]."""
    dot = np.abs(np.sum(q1 * q2, axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


class FlipBlock(DClawTask):
    """Flip a free block 180 deg about a horizontal axis (BAIR's D'Claw flipping task).

    The goal is relative to the pose the block starts in (``start_goal``): the same position,
    turned 180 deg about ``flip_axis`` (a world axis). A robot's reset therefore only has to put
    the block back on the table, with either face up.
    """

    station = "block"
    identification_limits = (np.array([-0.3, -1.05, 0.5] * 3), np.array([0.3, -0.7, 1.57] * 3))
    """Joint box [rad] (top, middle, bottom per finger) in which random goals keep the fingers
    bent outwards, clear of the block (``identify_servo_response``): full-range goals knock the
    block off its place (0.155 m away on the emulated D'Claw, beyond the reset's reach)."""

    def __init__(self, config: FlipConfig = FlipConfig(), **kw):
        kw.setdefault("timing", TaskSpec(frame_skip=40, episode_steps=80))
        super().__init__(**kw)
        self.config = config

    def bind(self, model: mujoco.MjModel) -> None:
        super().bind(model)
        adr = int(model.jnt_qposadr[model.joint("block").id])
        self.block_pos = np.arange(adr, adr + 3)
        self.block_quat = np.arange(adr + 3, adr + 7)
        axis = np.asarray(self.config.flip_axis, float)
        self.flip_quat = np.array([0.0, *(axis / np.linalg.norm(axis))])  # 180 deg about axis

    @property
    def obs_dim(self) -> int:
        pose = 24 if self.config.representation == "keypoints" else 7
        return 9 + 9 + 2 * pose + 9

    def keypoints(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """Cube corners (..., 8, 3) [m] of a block at pos (..., 3), quat (..., 4)."""
        return pos[..., None, :] + quat_rotate(quat, np.broadcast_to(_CORNERS, quat.shape[:-1]
                                                                     + _CORNERS.shape))

    @property
    def block_rest(self) -> tuple[np.ndarray, np.ndarray]:
        """The block's nominal start: resting upright at the table's centre, position (3,) [m]
        and quaternion (4,). A robot's reset aims here; ``initial_state`` adds the noise."""
        return np.array(BLOCK_CENTER, float), np.array([1.0, 0.0, 0.0, 0.0])

    def _pose(self, qpos):
        return qpos[..., self.block_pos], qpos[..., self.block_quat]

    def initial_state(self, rng):
        """Fingers at the reset pose and the block resting upright at the table's centre, each
        with the config's start noise drawn from ``rng`` (see ``FlipConfig``)."""
        c = self.config
        qpos = np.zeros(self.model.nq)
        qpos[self.hand_qpos] = RESET_POSE + rng.uniform(-c.joint_range, c.joint_range, 9)
        r = c.position_radius * math.sqrt(rng.uniform())  # uniform over the disc's area
        phi = rng.uniform(-math.pi, math.pi)
        rest, _ = self.block_rest
        qpos[self.block_pos] = rest + [r * math.cos(phi), r * math.sin(phi), 0.0]
        yaw = rng.uniform(-c.yaw_range, c.yaw_range)
        qpos[self.block_quat] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        return qpos, np.zeros(self.model.nv), self.start_goal(qpos, {})

    def start_goal(self, qpos: np.ndarray, goal: Goal) -> Goal:
        pos, quat = self._pose(qpos)
        target = np.zeros(4)
        mujoco.mju_mulQuat(target, self.flip_quat, np.asarray(quat, float))
        return {"pos": np.array(pos, float), "quat": target}

    def _rep(self, pos, quat):
        if self.config.representation == "keypoints":
            kp = self.keypoints(pos, quat)
            return kp.reshape(kp.shape[:-2] + (24,))
        return np.concatenate([pos, quat * np.sign(quat[..., :1] + 1e-12)], axis=-1)

    def observation(self, qpos, qvel, goal, last_action):
        q, v = self.hand_state(qpos, qvel)
        pos, quat = self._pose(qpos)
        lead = pos.shape[:-1]
        gpos = np.broadcast_to(goal["pos"], lead + (3,))
        gquat = np.broadcast_to(goal["quat"], lead + (4,))
        return np.concatenate([q, v, self._rep(pos, quat), self._rep(gpos, gquat), last_action],
                              axis=-1)

    def orientation_error(self, qpos, goal):
        _, quat = self._pose(qpos)
        return quat_angle(quat, goal["quat"])

    def reward_terms(self, qpos, qvel, goal, action):
        pos, quat = self._pose(qpos)
        terms = {"position": -20.0 * _norm(pos - goal["pos"])}
        if self.config.representation == "keypoints":
            corners = quat_rotate(quat, np.broadcast_to(_CORNERS, quat.shape[:-1] + (8, 3)))
            gquat = np.broadcast_to(goal["quat"], quat.shape)
            goal_corners = quat_rotate(gquat, np.broadcast_to(_CORNERS, gquat.shape[:-1] + (8, 3)))
            dist = np.mean(_norm(corners - goal_corners), axis=-1)
            terms["keypoint_distance"] = -KEYPOINT_WEIGHT * dist
        else:
            terms["orientation"] = -1.0 * self.orientation_error(qpos, goal)
        terms.update(self.posture_terms(qpos, qvel))
        terms["pose"] = 0.1 * terms["pose"]
        terms["bonus"] = 10.0 * self.success(qpos, goal)
        return terms

    def success(self, qpos, goal):
        return self.orientation_error(qpos, goal) < self.config.success_angle

    def tilt(self, qpos: np.ndarray) -> np.ndarray:
        """Angle (...) [rad] between the block's local z axis and the world's up: 0 upright,
        pi/2 on a side, pi upside down."""
        _, quat = self._pose(qpos)
        z = quat_rotate(quat, np.broadcast_to([0.0, 0.0, 1.0], quat.shape[:-1] + (1, 3)))
        return np.arccos(np.clip(z[..., 0, 2], -1.0, 1.0))

    def terminated(self, qpos, goal):
        return qpos[..., self.block_pos[2]] < self.config.drop_height

    def goal_error(self, qpos, goal):
        return self.orientation_error(qpos, goal)
