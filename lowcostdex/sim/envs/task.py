"""Task interface: what a hand env observes, rewards and counts as success.

Tasks are written against plain arrays with optional leading batch dimensions (qpos (..., nq),
qvel (..., nv)), so one task serves the single env and the batched vector env alike, and the robot
side (sim, emulated bus, hardware) is swappable behind ``Backend``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_bool, check_number
from lowcostdex.hands import HandSpec

Goal = dict[str, np.ndarray]


def check_settings(config: object, bounds: dict[str, tuple]) -> None:
    """Validate a task config's numbers at construction: each named field must be a finite
    number in its closed interval ``(low, high, unit)`` (``(low, high, unit, "open")``: open at
    ``low``, as ``TOLERANCE``). An angle beyond its bound names the
    unit, so 180 for a 180 deg offset is refused as degrees rather than run as 180 rad.

    Raises:
      ConfigError naming the config, the field, the value and the interval.
    """
    kind = type(config).__name__
    for name, (low, high, unit, *open_low) in bounds.items():
        value = getattr(config, name)
        try:
            check_number(f"{kind}.{name}", value, low, high, low_open=bool(open_low))
        except ConfigError as e:
            big = isinstance(value, (int, float)) and abs(value) > high
            hint = {"rad": " (an angle in rad, not degrees)",
                    "rad/s": " (in rad/s, not deg/s)"}.get(unit, "") if big else ""
            raise ConfigError(f"{e} [{unit}]{hint}") from None


# a success tolerance [rad] in (0, pi]: success is |error| < it, which 0 never is
TOLERANCE = (0.0, math.pi, "rad", "open")
VALVE_BOUNDS = {"init_range": (0.0, math.pi, "rad"),
                "goal_offset": (-4 * math.pi, 4 * math.pi, "rad"),
                "goal_range": (0.0, math.pi, "rad"), "success_tol": TOLERANCE,
                "pose_noise": (0.0, 1.0, "rad")}
"""Bounds of the valve tasks' settings (D'Claw and Allegro; ``check_settings``): ranges up to
half a turn either way, offsets up to two turns, a start-pose noise std up to 1 rad."""
VALVE_GOAL = {"angle": (-6 * math.pi, 6 * math.pi, "rad"), "start": (-6 * math.pi, 6 * math.pi, "rad"),
              "speed": (-2 * math.pi, 2 * math.pi, "rad/s")}
"""Bounds of a valve task's goal given to ``env.reset(options={"goal": ...})`` (``Task.goal_bounds``):
the farthest goal the settings reach, init_range + |goal_offset| + goal_range = pi + 4 pi + pi, and
``ScrewConfig``'s speed bound (a goal in degrees, 400 for 400 deg, was taken as 400 rad)."""


def check_flag(config: object, name: str) -> None:
    """A config's bool field must be True or False (a string "false" is truthy)."""
    check_bool(f"{type(config).__name__}.{name}", getattr(config, name))


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """Wrap angles [rad] to [-pi, pi)."""
    return (np.asarray(x) + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class TaskSpec:
    """Timing of a task.

    Attributes:
      frame_skip: physics substeps per control step.
      episode_steps: control steps per episode (truncation).
    """

    frame_skip: int = 40
    episode_steps: int = 40

    def __post_init__(self) -> None:  # (Plant.step_unchecked takes frame_skip as its count)
        check_number("TaskSpec.frame_skip (physics substeps)", self.frame_skip, 1, integer=True)
        check_number("TaskSpec.episode_steps", self.episode_steps, 1, integer=True)


class Task(ABC):
    """A task on a hand: model, initial state distribution, observation, reward terms, success."""

    hand: HandSpec
    timing: TaskSpec
    #: actuators released (torque off) during episodes, e.g. the D'Claw's valve motor.
    passive_actuators: tuple[str, ...] = ()
    #: bounds (low, high, unit) of goal keys a reset option may give (``VALVE_GOAL``)
    goal_bounds: dict[str, tuple[float, float, str]] = {}
    object_joint: str | None = None
    """A one-DOF object joint (e.g. "valve"): ``bind`` sets ``obj_qpos`` and ``obj_dof``."""

    @abstractmethod
    def build_spec(self) -> mujoco.MjSpec:
        """The task's MJCF scene (uncompiled)."""

    def bind(self, model: mujoco.MjModel) -> None:
        """Resolve names to indices in the compiled model."""
        self.model = model
        self.hand_qpos = np.array([model.jnt_qposadr[model.joint(n).id]
                                   for n in self.hand.joint_names])
        self.hand_dof = np.array([model.jnt_dofadr[model.joint(n).id]
                                  for n in self.hand.joint_names])
        self.hand_act = np.array([model.actuator(n).id for n in self.hand.joint_names])
        self.hand_low = np.array([j.low for j in self.hand.joints])
        self.hand_high = np.array([j.high for j in self.hand.joints])
        self.passive_act = np.array([model.actuator(n).id for n in self.passive_actuators],
                                    dtype=int)
        if self.object_joint is not None:
            joint = model.joint(self.object_joint)
            self.obj_qpos = int(model.jnt_qposadr[joint.id])
            self.obj_dof = int(model.jnt_dofadr[joint.id])

    @abstractmethod
    def initial_state(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, Goal]:
        """Sample (qpos (nq,), qvel (nv,), goal) for a new episode."""

    @abstractmethod
    def observation(self, qpos: np.ndarray, qvel: np.ndarray, goal: Goal,
                    last_action: np.ndarray) -> np.ndarray:
        """Observation (..., obs_dim) from state arrays (..., nq), (..., nv)."""

    @property
    @abstractmethod
    def obs_dim(self) -> int:
        """Observation length."""

    @abstractmethod
    def reward_terms(self, qpos: np.ndarray, qvel: np.ndarray, goal: Goal,
                     action: np.ndarray) -> dict[str, np.ndarray]:
        """Named reward terms (each (...)); the reward is their sum."""

    @abstractmethod
    def success(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        """Success flag (...)."""

    def terminated(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        """True where the episode reached a terminal state (default: never; time limits truncate)."""
        return np.zeros(np.shape(qpos)[:-1], dtype=bool)

    def goal_error(self, qpos: np.ndarray, goal: Goal) -> np.ndarray:
        """Scalar goal error (...) reported in info (task-specific unit)."""
        return np.zeros(np.shape(qpos)[:-1])

    def start_goal(self, qpos: np.ndarray, goal: Goal) -> Goal:
        """The episode's goal given the state the robot actually starts in (qpos (nq,)).

        Called after the backend's reset; a robot's auto-reset may not reproduce the sampled
        initial state exactly (e.g. the flip block's goal is relative to its start pose).
        Default: the sampled goal.
        """
        return goal

    def advance_goal(self, goal: Goal, step: int) -> Goal:
        """Goal after ``step`` control steps (moving targets, e.g. the screw); default fixed."""
        return goal

    def aux_ctrl(self, qpos: np.ndarray) -> np.ndarray:
        """Goals (..., n_aux) for actuators outside the action (e.g. the valve motor: hold)."""
        return np.zeros(np.shape(qpos)[:-1] + (self.model.nu - len(self.hand_act),))

    def goal_marker(self, goal: Goal) -> tuple[np.ndarray, np.ndarray] | None:
        """(pos, quat) of the mocap goal marker, if the scene has one."""
        return None
