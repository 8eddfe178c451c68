"""Env backends for the Allegro hand: the emulated hand (python-can ``virtual``) and a real one.

The same path as the D'Claw's (``backend.RobotBackend``): a ``Robot`` (safety gate, thermal
guard, step timing) on an ``AllegroBus`` (the real python-can driver and its host-side PD), an
auto-reset at every ``reset`` (``reset_allegro.AllegroReset``: thermal pause first, the 16 joints driven
to the reset pose and verified, bounded retries, then ``ResetFailed``), and the mirror ``MjData``
the task reads. The Allegro's joints are soft and torque-driven, so the Robot rate-limits goals
from the previous goal (``RobotConfig(motion_reference="goal")``, the default here).

The valve is not motorized, so neither backend can turn it with a motor:

* ``EmulatedAllegroBackend``: the emulator stands in for a person (or a motorized valve) and puts
  the valve at the episode's start angle by writing its MuJoCo state; the valve angle the task
  observes is read from the emulator's physics, standing in for an encoder on the valve.
* ``AllegroHardwareBackend``: the valve angle must come from ``tracker`` (a callable reading an
  encoder or motion capture; ConfigError without one). ``place_valve`` (a motorized valve, or a
  function that asks a person) puts it at the start angle, verified with ``tracker``; without
  it the valve stays where the last episode left it and the episode starts from there.

    env = gym.make("lowcostdex/AllegroTurnValve-v0", backend="emulated")
    env = gym.make("lowcostdex/AllegroTurnValve-v0", backend="hardware", channel="can0",
                   tracker=read_valve_encoder)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.hands import HandSpec, as_hand_spec
from lowcostdex.hardware.robot.backend import (
    EpisodeReset,
    ObjectSensor,
    RobotBackend,
    as_effects,
    as_settings,
    check_start_qpos,
    resolve_callable,
    task_robot_config,
)
from lowcostdex.hardware.robot.reset import ResetConfig
from lowcostdex.hardware.robot.reset_allegro import AllegroReset, PlaceValve, ValveAngle
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.sim.effects import AppliedEffect

ALLEGRO_ROBOT = RobotConfig(motion_reference="goal")
"""Default Robot settings for the Allegro: rate-limit goals, not positions (soft joints)."""


def allegro_reset(task: Any, config: ResetConfig | None = None,
                  place_valve: PlaceValve | None = None, valve_angle: ValveAngle | None = None
                  ) -> Callable[[Robot], EpisodeReset]:
    """The Allegro valve task's episode reset: ``AllegroReset`` (``config`` default
    ``ResetConfig()``) to the start qpos's joints, the valve placed at its start angle when
    ``place_valve`` is given."""

    def make(robot: Robot) -> EpisodeReset:
        reset = AllegroReset(robot, config or ResetConfig(), place_valve, valve_angle)
        return lambda q: reset(q[task.hand_qpos], float(q[task.obj_qpos]))

    return make


def valve_sensor(task: Any, valve_angle: ValveAngle) -> ObjectSensor:
    """The valve angle from ``valve_angle`` into the mirror."""
    return ObjectSensor(np.array([task.obj_qpos]), lambda: np.array([float(valve_angle())]))


def _check_task(task: Any, who: str) -> None:
    if task is None:
        raise ConfigError(f"{who} needs the task")
    if task.hand.name != "allegro":
        raise ConfigError(f"{who} runs Allegro tasks, not {task.hand.name} tasks; "
                          "gym.make(..., backend=...) picks the hand's backend "
                          "(lowcostdex.sim.envs.backend.BACKENDS)")
    if task.object_joint != "valve":
        raise ConfigError(f"{who} runs the valve task (object joint 'valve'), got "
                          f"{task.object_joint!r}")


class EmulatedAllegroBackend(RobotBackend):
    """The task on an emulated Allegro behind python-can's ``virtual`` interface, in lock-step
    virtual time (``allegro_emulator.emulated_allegro``): deterministic, faster than real time.

    Args:
      model, task, rng: as every backend (``cls(model, task=task, rng=rng, **kwargs)``); the
        emulator simulates a copy of ``model`` with its position actuators off.
      effects: servo effects on the emulated hand's physics (``AppliedEffect``s or their
        ``to_dict()`` mappings; default none).
      robot_config: Robot settings (default ``ALLEGRO_ROBOT``; the control period is the task's).
      reset_config: auto-reset settings (default ``ResetConfig()``).
      start_qpos: the emulated hand's state when it powers up (nq,) (default the model's qpos0).
      bus_kwargs: more ``AllegroBus`` options (gains, period_ms, ...) and ``thermal``
        (``allegro_emulator.AllegroThermal``).
    """

    def __init__(self, model: mujoco.MjModel, task: Any = None,
                 rng: np.random.Generator | None = None,
                 effects: Sequence[AppliedEffect | dict] = (),
                 robot_config: RobotConfig | None = None,
                 reset_config: ResetConfig | None = None,
                 start_qpos: np.ndarray | None = None, **bus_kwargs: Any):
        from lowcostdex.hardware.allegro.emulator import emulated_allegro

        _check_task(task, "EmulatedAllegroBackend")
        self.effects = as_effects(effects)
        start_qpos = check_start_qpos(start_qpos, model)
        if reset_config is not None:
            reset_config = as_settings(ResetConfig, reset_config, "reset_config")
        bus, self.emulator, self.clock = emulated_allegro(
            model, effects=self.effects, rng=rng if rng is not None else np.random.default_rng(0),
            hand=task.hand, **bus_kwargs)
        plant = self.emulator.plant
        if start_qpos is not None:
            plant.data.qpos[:] = start_qpos
            mujoco.mj_forward(plant.model, plant.data)
        self._valve_adr, self._valve_dof = task.obj_qpos, task.obj_dof  # plant: model's layout
        config = task_robot_config(robot_config, task, model, ALLEGRO_ROBOT)
        robot = Robot(task.hand, bus, config)
        super().__init__(model, task, robot,
                         allegro_reset(task, reset_config, self.place_valve, self.valve_angle),
                         valve_sensor(task, self.valve_angle))

    def valve_angle(self) -> float:
        """The emulated valve's angle [rad] (its physics; an encoder on a real valve)."""
        return float(self.emulator.plant.data.qpos[self._valve_adr])

    def place_valve(self, angle: float) -> None:
        """Put the emulated valve at ``angle`` [rad], at rest: the emulator standing in for a
        person or a motorized valve (the Allegro cannot be asked to do it)."""
        plant = self.emulator.plant
        plant.data.qpos[self._valve_adr] = angle
        plant.data.qvel[self._valve_dof] = 0.0
        mujoco.mj_forward(plant.model, plant.data)

    def telemetry(self) -> dict[str, Any]:
        out = super().telemetry()
        out["bus_time"] = self.clock.now()
        return out

    def close(self) -> None:
        super().close()
        self.emulator.close()


class AllegroHardwareBackend(RobotBackend):
    """The task on a real Allegro v4 on a CAN bus.

    Args:
      model, task, rng: as every backend.
      channel: CAN channel, e.g. "can0" (socketcan, a PEAK PCAN-USB on Linux).
      interface: python-can interface name.
      tracker: () -> the valve angle [rad], unwrapped (an encoder on the valve or motion
        capture), or its import path "package.module:function" (JSON configs); required: the
        Allegro does not sense the valve.
      place_valve: (angle [rad]) -> None, puts the valve at the episode's start angle (a motorized
        valve, or a function that asks a person and returns when done); default: not placed.
      hand: hand spec (default the task's): a ``HandSpec``, the path of its JSON or the JSON's
        dict (``lowcostdex.hands.as_hand_spec``).
      robot_config: Robot settings (default ``ALLEGRO_ROBOT``).
      reset_config: auto-reset settings (default ``ResetConfig()``).
      bus_kwargs: more ``AllegroBus`` options (gains, device_id, ...).
    """

    def __init__(self, model: mujoco.MjModel, task: Any = None,
                 rng: np.random.Generator | None = None, *, channel: str | None = None,
                 interface: str = "socketcan", tracker: ValveAngle | None = None,
                 place_valve: PlaceValve | None = None, hand: HandSpec | None = None,
                 robot_config: RobotConfig | None = None,
                 reset_config: ResetConfig | None = None, **bus_kwargs: Any):
        from lowcostdex.hardware.allegro.driver import AllegroBus

        _check_task(task, "AllegroHardwareBackend")
        if channel is None:
            raise ConfigError("the Allegro on hardware needs channel=... (e.g. 'can0') and, if "
                              "not socketcan, interface=...")
        tracker = resolve_callable(tracker, "tracker")
        place_valve = resolve_callable(place_valve, "place_valve")
        if tracker is None:
            raise ConfigError("the Allegro valve task on hardware needs tracker=... (a function "
                              "returning the valve angle [rad], unwrapped, from an encoder or "
                              "motion capture): the hand does not sense the valve")
        hand = task.hand if hand is None else as_hand_spec(hand, "allegro")
        bus = AllegroBus(interface=interface, channel=channel, hand=hand, **bus_kwargs)
        robot = Robot(hand, bus, task_robot_config(robot_config, task, model, ALLEGRO_ROBOT))
        super().__init__(model, task, robot,
                         allegro_reset(task, reset_config, place_valve, tracker),
                         valve_sensor(task, tracker))
