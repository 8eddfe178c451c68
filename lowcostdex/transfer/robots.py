"""The transfer loop's robots: the user's D'Claw on a serial port (``PortRobot``) or emulated hidden
robots (``HiddenRobotTarget``; ``HiddenRobotEnv`` builds the on_robot condition's environment).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class PortRobot:
    """The user's D'Claw on a serial port (real, or an emulated one behind a pty).

    Attributes:
      latency_ms: the USB latency timer the driver's timeouts assume when it cannot read it
        from sysfs [ms] (a pty; None: the driver's default, 1 ms). Every bus the loop opens on
        the port (identification, on_robot training, evaluation) gets it.
    """

    port: str
    name: str = "robot"
    motor: str = "XH430-W350"
    latency_ms: float | None = None

    def env_kwargs(self) -> dict[str, Any]:
        return {"backend": "hardware", **self.bus_kwargs()}

    def bus_kwargs(self) -> dict[str, Any]:
        """The ``port``, ``motor`` (and ``latency_ms``) of every connection to the robot."""
        extra = {} if self.latency_ms is None else {"latency_ms": self.latency_ms}
        return {"port": self.port, "motor": self.motor, **extra}

    def identification_port(self, seed: int) -> str:
        return self.port

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "port": self.port, "motor": self.motor,
                "latency_ms": self.latency_ms}


class HiddenRobotTarget:
    """A hidden robot as a loop target (its identification port is its station without the
    valve, a fresh emulated chain)."""

    latency_ms = None  # the emulated port answers in bus time

    def __init__(self, robot: Any) -> None:
        self.robot = robot
        self.name = robot.name
        self.motor = robot.motor

    def env_kwargs(self) -> dict[str, Any]:
        return self.robot.env_kwargs()

    def identification_port(self, seed: int) -> Any:
        return self.robot.chain("none", rng=np.random.default_rng(seed)).port()

    def to_dict(self) -> dict[str, Any]:
        return self.robot.to_dict()


def make_robots(n: int, robot_seed: int = 0, port: str | None = None,
                latency_ms: float | None = None) -> list[Any]:
    """The loop's robots: the one on ``port`` (``latency_ms``: see ``PortRobot``), or ``n``
    hidden robots drawn from ``robot_seed``."""
    if port is not None:
        return [PortRobot(port, latency_ms=latency_ms)]
    from lowcostdex.hardware.emulated.hidden_robots import hidden_robots

    return [HiddenRobotTarget(r) for r in hidden_robots(n, seed=robot_seed)]


@dataclass(frozen=True)
class HiddenRobotEnv:
    """``gym.make`` of the task on a hidden robot (picklable, rebuilt from its seed): the
    on_robot condition's environment; the robot's definition stays out of the run's config."""

    env_id: str
    task_kwargs: tuple[tuple[str, Any], ...]
    robot_seed: int
    robot_name: str

    def __call__(self) -> Any:
        import gymnasium as gym

        import lowcostdex.sim  # noqa: F401  (registers the ids)
        from lowcostdex.hardware.emulated.hidden_robots import hidden_robot

        robot = hidden_robot(self.robot_seed, self.robot_name)
        return gym.make(self.env_id, **dict(self.task_kwargs), **robot.env_kwargs())
