"""The robot side of an env, swappable: pure MuJoCo, an emulated robot, or hardware.

An env owns a compiled model and an ``MjData`` that its task reads (the "mirror"). A backend
brings the robot to an initial state, holds joint goals for one control period, and leaves the
resulting state in the mirror. ``SimBackend`` steps the mirror itself through a ``Plant`` (the
shared servo/effect engine); the emulated and hardware backends (``lowcostdex.hardware``) drive a
bus and copy what the encoders report into the mirror, as ROBEL does.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import ClosedError, check_choice
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import Plant


class Backend(ABC):
    """Interface between an env and a robot.

    Attributes:
      model: the env's compiled model.
      data: the mirror the task reads (qpos/qvel are the robot's state after each call).
    """

    model: mujoco.MjModel
    data: mujoco.MjData
    #: True when the backend runs in real time on a physical or emulated robot.
    real_time: bool = False

    @abstractmethod
    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Bring the robot to (qpos (nq,), qvel (nv,)) or as close as it can (auto-reset)."""

    @abstractmethod
    def apply(self, goal: np.ndarray, nstep: int) -> None:
        """Hold goal positions (nu,) [rad] for one control period of ``nstep`` substeps."""

    def observed_qpos(self) -> np.ndarray:
        """qpos as the robot's encoders report it (nq,); default the mirror's qpos."""
        return self.data.qpos

    def set_effects(self, effects: Sequence[AppliedEffect]) -> None:
        """Domain randomization: apply effect values for the next episode (sim only)."""
        if effects:
            raise NotImplementedError(f"{type(self).__name__} cannot randomize dynamics")

    def telemetry(self) -> dict[str, Any]:
        """Extra readings for ``info`` (currents [A], temperatures [deg C], resets, pauses)."""
        return {}

    def close(self) -> None:  # noqa: B027 (optional: a backend without a robot has nothing to release)
        """Release the robot (torque off, port closed)."""


class SimBackend(Backend):
    """Pure MuJoCo: the mirror is the simulation, stepped by a ``Plant``."""

    def __init__(self, model: mujoco.MjModel, task: Any = None,
                 rng: np.random.Generator | None = None):
        self.plant = Plant(model, rng=rng)
        self.model = self.plant.model
        self.data = self.plant.data
        self.closed = False
        if task is not None and len(task.passive_act):
            self.plant.set_torque_enabled(task.passive_act, False)

    def _check_open(self, call: str) -> None:
        # as the robot backends refuse a closed bus (before: a closed sim env kept stepping)
        if self.closed:
            raise ClosedError(f"{call}() on a simulation that was closed (by env.close()); "
                              "make a new env with gym.make")

    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        self._check_open("reset")
        self.plant.reset(qpos, qvel)

    def apply(self, goal: np.ndarray, nstep: int) -> None:
        self._check_open("step")
        self.plant.step_unchecked(goal, nstep)  # the env's goal: from its checked action

    def close(self) -> None:
        self.closed = True

    def set_effects(self, effects: Sequence[AppliedEffect]) -> None:
        self.plant.set_effects(effects)

    def observed_qpos(self) -> np.ndarray:
        return self.plant.measured_qpos()

    def telemetry(self) -> dict[str, Any]:
        from lowcostdex.sim import servo

        return {"current": servo.motor_current(self.model, self.data),
                "temperature": servo.winding_temperature(self.model, self.data)}


# Backends outside lowcostdex.sim are named by "module:Class" and imported on first use; robot
# backends are per hand (the hand spec's name). Every backend is constructed as
# ``cls(model, task=task, rng=rng, **backend_kwargs)``.
BACKENDS: dict[str, str | dict[str, str]] = {
    "sim": "lowcostdex.sim.envs.backend:SimBackend",
    "emulated": {"dclaw": "lowcostdex.hardware.robot.backend:EmulatedBackend",
                 "allegro": "lowcostdex.hardware.robot.allegro_backend:EmulatedAllegroBackend"},
    "hardware": {"dclaw": "lowcostdex.hardware.robot.backend:HardwareBackend",
                 "allegro": "lowcostdex.hardware.robot.allegro_backend:AllegroHardwareBackend"},
}


def backend_class(name: str, hand: str | None = None) -> type[Backend]:
    """Resolve a backend name (and, for robot backends, the hand's name: "dclaw", "allegro")
    to its class; the errors list the valid names."""
    check_choice("backend", name, BACKENDS)
    entry = BACKENDS[name]
    if isinstance(entry, dict):
        check_choice(f"hand for backend {name!r}", hand, entry)
        entry = entry[hand]
    module, cls = entry.split(":")
    return getattr(importlib.import_module(module), cls)
