"""Env backends on a robot: the emulated D'Claw (in-process) and the real one (serial port).

Both run the same path: ``Robot`` (safety gate, thermal and current guards, step timing) on a
``DynamixelBus`` (the real dynamixel_sdk code path), an auto-reset procedure at every
``reset`` (thermal pause first, verified staged reset, valve driven to its start angle and
released), and a mirror ``MjData`` into which the encoders' readings are copied after every step,
as ROBEL does; the task computes observations and rewards from the mirror.

``EmulatedBackend`` puts an emulated D'Claw (``emulator.emulated_dclaw``: firmware, thermal
model, virtual clock) behind an in-process port. Its physics ``Plant`` carries servo effects the
nominal simulation lacks (``DEFAULT_EFFECTS``: a little latency, backlash and joint friction) so
that a sim-to-"real" gap exists to be found; pass ``effects=()`` for a nominal emulated robot.
A free object (the flip-task block) is read from the emulator's physics, standing in for the
motion-capture tracker a real setup needs (``HardwareBackend(tracker=...)``).

    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated")
    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="hardware", port="/dev/ttyUSB0")

``RobotBackend`` (the reset/step/mirror loop) is shared by every hand: the episode reset is
pluggable (``dclaw_reset`` here, ``allegro_backend.allegro_reset`` for the Allegro, whose backends
live in ``lowcostdex.hardware.robot.allegro_backend``), and so is the source of an object pose the
motors do not measure (``ObjectSensor``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_keys
from lowcostdex.hands import HandSpec, as_hand_spec, check_model_ranges
from lowcostdex.hardware.bus import MotorBus, WatchdogTripped
from lowcostdex.hardware.robot.reset import ResetConfig, ResetReport
from lowcostdex.hardware.robot.reset_dclaw import DClawReset
from lowcostdex.hardware.robot.reset_flip import FlipBlockReset, FlipResetConfig, Reorient
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.envs.backend import Backend

log = logging.getLogger(__name__)

EEPROM_MARGIN = 0.05  # [rad] EEPROM position limits beyond the mechanical range

Tracker = Callable[[], tuple[np.ndarray, np.ndarray]]
"""() -> (block position (3,) [m], quaternion (4,) (w, x, y, z)) in the env model's frame."""


def default_effects(joints: Sequence[str], latency: float = 0.004,
                    backlash: float = math.radians(0.4), friction: float = 0.02
                    ) -> list[AppliedEffect]:
    """A plausible set of servo effects for an emulated D'Claw (a gap to find): command
    ``latency`` [s], gear ``backlash`` [rad] and extra dry joint ``friction`` [N m] on every
    joint in ``joints``. Defaults small: 4 ms, 0.4 deg, 0.02 N m."""
    joints = tuple(joints)
    return [AppliedEffect("latency", joints, {"delay": latency}),
            AppliedEffect("backlash", joints, {"width": backlash}),
            AppliedEffect("coulomb_friction", joints, {"frictionloss": friction})]


def robot_hand(hand: HandSpec, model: mujoco.MjModel) -> HandSpec:
    """The hand spec restricted to auxiliary motors present in ``model`` (no valve motor on
    the block station)."""
    names = {model.actuator(i).name for i in range(model.nu)}
    return dataclasses.replace(hand, aux_joints=tuple(j for j in hand.aux_joints
                                                      if j.name in names))


EpisodeReset = Callable[[np.ndarray], ResetReport]
"""(the episode's start qpos (nq,), env model order) -> ResetReport: bring the robot (and the
object, where it can) there, verified; raises ``reset.ResetFailed``."""


@dataclass(frozen=True)
class ObjectSensor:
    """An object's pose from outside the robot's motors (motion capture, an encoder, or the
    emulator's physics standing in for them), copied into the mirror after every step.

    Attributes:
      qpos: indices into the env model's qpos that it fills (n,).
      read: () -> values (n,) [m, rad; quaternions (w, x, y, z)].
    """

    qpos: np.ndarray
    read: Callable[[], np.ndarray]


class RobotBackend(Backend):
    """A task on a Robot, with auto-reset and the encoder mirror.

    At every ``reset`` the backend runs the episode reset (thermal pause, verified reset), turns
    the action joints' torque on and mirrors the state; at every step it sends the goals, waits
    one control period and mirrors. The mirror takes the joints from the encoders, a motorized
    object joint (the D'Claw valve) from its encoder, and any other object pose from the
    ``sensor``; object velocities from a sensor are not measured and stay 0.

    Args:
      model: the env's compiled model (the mirror's).
      task: the bound task.
      robot: a Robot (not yet connected) for the task's hand.
      make_reset: builds the episode reset for the connected robot (``dclaw_reset``,
        ``allegro_backend.allegro_reset``).
      sensor: pose source of an object the robot does not drive (flip block, Allegro valve).
    """

    real_time = True

    def __init__(self, model: mujoco.MjModel, task: Any, robot: Robot,
                 make_reset: Callable[[Robot], EpisodeReset],
                 sensor: ObjectSensor | None = None):
        self.model = model
        self.data = mujoco.MjData(model)
        self.task = task
        self.robot = robot
        period = task.timing.frame_skip * model.opt.timestep
        if not math.isclose(period, robot.config.control_period, rel_tol=1e-9):
            raise ConfigError(f"task control period {period} s != robot control period "
                              f"{robot.config.control_period} s")
        self._act = robot.index(task.hand.joint_names)
        self._valve = robot.index(["valve"])[0] if "valve" in robot.joint_names else None
        self.sensor = sensor
        self.last_reset: ResetReport | None = None
        self.stale_steps = 0
        self.watchdog_stops = 0  # steps resumed after the Bus Watchdog stopped the motors
        self._episode_stops = 0
        robot.connect()
        self.episode_reset = make_reset(robot)

    # -- Backend --------------------------------------------------------------------------------
    def reset(self, qpos: np.ndarray, qvel: np.ndarray) -> None:
        """Thermal pause if due, verified auto-reset to ``qpos``, action joints torque on."""
        self.last_reset = self.episode_reset(np.asarray(qpos, float))
        self.robot.torque(True, self.task.hand.joint_names)
        self._episode_stops = 0
        self.data.qpos[:] = qpos
        self.data.qvel[:] = 0.0
        self._mirror(self.robot.read())
        self.robot.rate.restart()

    def apply(self, goal: np.ndarray, nstep: int) -> None:
        """Send the hand's goals (nu,) -> the action joints; wait one period; mirror."""
        frame_skip = self.task.timing.frame_skip
        if nstep != frame_skip:
            raise ConfigError(f"a robot steps whole control periods ({frame_skip} substeps), "
                              f"got nstep={nstep}")
        goal = np.asarray(goal)[self.task.hand_act]
        try:
            state = self.robot.step(goal, self.task.hand.joint_names)
        except WatchdogTripped as exc:
            self._resume_after_watchdog(exc)
            state = self.robot.step(goal, self.task.hand.joint_names)
        self._mirror(state)

    MAX_WATCHDOG_STOPS = 3
    """Watchdog stops one episode may resume from; one more is raised (the host cannot keep
    up with the control rate: a loaded machine, swapping, a debugger)."""

    def _resume_after_watchdog(self, exc: WatchdogTripped) -> None:
        """The host fell silent for longer than the Bus Watchdog (a stall of the training
        process) and the motors stopped where they were. Torque on again from there (goal :=
        present, watchdog re-armed) and let the step's goal go out; the per-step motion bound
        keeps it near where the motors stopped. Counted in telemetry (``watchdog_stops``). A
        motor the thermal guard relaxed stays limp until the pause (re-enabling it raised
        UnsafeCommand and ended the run)."""
        self._episode_stops += 1
        if self._episode_stops > self.MAX_WATCHDOG_STOPS:
            raise exc
        self.watchdog_stops += 1
        log.warning("%s; resuming from there (%d this episode)", exc, self._episode_stops)
        names = self.task.hand.joint_names
        relaxed = self.robot.thermal.relaxed[self.robot.index(names)]
        self.robot.torque(True, [n for n, r in zip(names, relaxed, strict=True) if not r])

    def passive_step(self) -> None:
        """Wait one control period without commanding (demonstrations), then mirror."""
        self.robot.wait()
        self._mirror(self.robot.read())

    def telemetry(self) -> dict[str, Any]:
        out = self.robot.telemetry()
        if self.last_reset is not None:
            out["last_reset_time"] = self.last_reset.duration
            out["last_reset_attempts"] = self.last_reset.attempts
        out["stale_steps"] = self.stale_steps
        out["watchdog_stops"] = self.watchdog_stops
        return out

    def close(self) -> None:
        self.robot.close()

    # -- mirror ---------------------------------------------------------------------------------
    def _mirror(self, state) -> None:
        """Copy encoder readings into the mirror (invalid readings keep the previous value)."""
        t, d = self.task, self.data
        if not np.all(state.valid):
            self.stale_steps += 1
        pos = np.where(state.valid, state.position, np.nan)
        vel = np.where(state.valid, state.velocity, np.nan)
        q, v = d.qpos, d.qvel
        q[t.hand_qpos] = np.where(np.isfinite(pos[self._act]), pos[self._act], q[t.hand_qpos])
        v[t.hand_dof] = np.where(np.isfinite(vel[self._act]), vel[self._act], v[t.hand_dof])
        if self._valve is not None:
            k = self._valve
            if np.isfinite(pos[k]):
                q[t.obj_qpos] = pos[k]
                v[t.obj_dof] = vel[k] if np.isfinite(vel[k]) else 0.0
        if self.sensor is not None:
            q[self.sensor.qpos] = self.sensor.read()
        mujoco.mj_forward(self.model, d)


def dclaw_reset(task: Any, model: mujoco.MjModel, config: ResetConfig | None = None,
                tracker: Tracker | None = None, flip_config: FlipResetConfig | None = None,
                reorient: Reorient | None = None) -> Callable[[Robot], EpisodeReset]:
    """The D'Claw's episode reset: ``FlipBlockReset`` when the task has a block and a tracker,
    else ``DClawReset`` (fingers, and the valve motor when the robot has one). ``config``,
    ``flip_config``: default ``ResetConfig()``, ``FlipResetConfig()``."""
    config = config or ResetConfig()
    flip_config = flip_config or FlipResetConfig()

    def make(robot: Robot) -> EpisodeReset:
        hand = task.hand_qpos
        if task.station == "block" and tracker is not None:
            block = _block_qpos(model)
            flip = FlipBlockReset(robot, model, tracker, flip_config, config, reorient)
            # The block goes back to its resting place, upright: the start noise the task
            # draws stands in (in simulation) for the scatter a robot's reset leaves by itself.
            rest = getattr(task, "block_rest", None)
            if rest is not None:
                pos, quat = rest
                return lambda q: flip(q[hand], pos, quat)
            return lambda q: flip(q[hand], q[block[:3]], q[block[3:]])
        valve = "valve" if "valve" in robot.joint_names else None
        fingers = DClawReset(robot, config, valve=valve)
        return lambda q: fingers(q[hand], float(q[task.obj_qpos]) if valve else None)

    return make


def _block_qpos(model: mujoco.MjModel) -> np.ndarray:
    adr = int(model.jnt_qposadr[model.joint("block").id])
    return np.arange(adr, adr + 7)


def resolve_callable(spec: Any, what: str) -> Any:
    """A callable given directly or as an import path ``"package.module:function"``.

    Import paths keep robot configurations JSON-serializable, e.g. a sensor in a training run's
    ``env_kwargs`` (``lowcostdex train ... --env-kwarg tracker=mylab.sensors:valve_angle``).

    Raises:
      ConfigError: a malformed path, a missing module or attribute, or not a callable.
    """
    if spec is None or callable(spec):
        return spec
    if not isinstance(spec, str) or spec.count(":") != 1:
        raise ConfigError(f"{what} must be a callable or 'package.module:function', got {spec!r}")
    import importlib

    module_name, attr = spec.split(":")
    try:
        fn = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"{what} {spec!r} cannot be imported: {exc}") from exc
    if not callable(fn):
        raise ConfigError(f"{what} {spec!r} is not callable")
    return fn


def block_sensor(model: mujoco.MjModel, tracker: Tracker) -> ObjectSensor:
    """The flip block's pose (position, quaternion) from ``tracker`` into the mirror."""
    return ObjectSensor(_block_qpos(model), lambda: np.concatenate(tracker()))


class EmulatedBackend(RobotBackend):
    """The task on an emulated D'Claw behind an in-process dynamixel_sdk port.

    Args:
      model, task, rng: as every backend (``cls(model, task=task, rng=rng, **kwargs)``).
      effects: servo effects of the emulated robot (default ``default_effects``), as
        ``AppliedEffect``s or their ``to_dict()`` mappings; ``()`` for a
        nominal one.
      faults: ``emulator.FaultConfig`` for the status packets (default none).
      robot_config: Robot settings (the control period is the task's).
      reset_config: auto-reset settings.
      flip_config, reorient: flip-task block reset (see ``dclaw_reset``); ``reorient="teacher"``
        (the default) is the flip teacher through the servos
        (``lowcostdex.teachers.flip.TeacherReorient``), None none (a block with the wrong
        face up then fails the reset).
      virtual_person: flip task only: when the block reset fails (the teacher did not turn the
        block back, or the block lies beyond the squeezes' reach), the emulator puts the block
        back at the episode's start pose, as the person a real setup needs would
        (``FlipBlockReset`` raises ``ResetFailed`` asking for one), and the reset runs again;
        counted as ``person_resets`` in the telemetry.
      start_qpos: the emulated robot's pose when it powers up (default the model's qpos0).
      chain_kwargs: more ``emulator.EmulatedChain`` options (baudrate, supply_resistance, ...).
    """

    def __init__(self, model: mujoco.MjModel, task: Any = None,
                 rng: np.random.Generator | None = None,
                 effects: Sequence[AppliedEffect] | None = None, faults: Any = None,
                 robot_config: RobotConfig | None = None,
                 reset_config: ResetConfig = ResetConfig(),
                 start_qpos: np.ndarray | None = None,
                 flip_config: FlipResetConfig = FlipResetConfig(),
                 reorient: Reorient | str | None = "teacher", virtual_person: bool = True,
                 **chain_kwargs: Any):
        from lowcostdex.hardware.emulated.chain import FaultConfig, emulated_dclaw

        if task is None:
            raise ConfigError("EmulatedBackend needs the task (it builds the task's station)")
        if task.hand.name != "dclaw":
            raise ConfigError(f"EmulatedBackend runs D'Claw tasks, not {task.hand.name} tasks; "
                              "gym.make(..., backend='emulated') picks the hand's backend "
                              "(lowcostdex.sim.envs.backend.BACKENDS)")
        rng = rng if rng is not None else np.random.default_rng(0)
        hand = robot_hand(task.hand, model)
        if effects is None:
            effects = default_effects(task.hand.joint_names)
        # JSON configs (training runs) carry effects as AppliedEffect.to_dict() mappings
        effects = as_effects(effects)
        reset_config = as_settings(ResetConfig, reset_config, "reset_config")
        flip_config = as_settings(FlipResetConfig, flip_config, "flip_config")
        start_qpos = check_start_qpos(start_qpos, model)
        self.chain = emulated_dclaw(task.station, hand=hand, effects=list(effects), rng=rng,
                                    qpos=start_qpos, faults=as_settings(  # a dict: JSON
                                        FaultConfig, faults or FaultConfig(), "faults"),
                                    **chain_kwargs)
        self.effects = list(effects)
        port = self.chain.port()
        bus = make_dynamixel_bus(hand, port, model)
        config = task_robot_config(robot_config, task, model)
        robot = Robot(hand, bus, config)
        tracker = self._physics_tracker() if task.station == "block" else None
        if reorient == "teacher":
            reorient = None
            if tracker is not None:
                from lowcostdex.teachers.flip import TeacherReorient

                reorient = TeacherReorient(task)
        super().__init__(model, task, robot,
                         dclaw_reset(task, model, reset_config, tracker, flip_config, reorient),
                         block_sensor(model, tracker) if tracker is not None else None)
        self.person_resets = 0
        if tracker is not None and virtual_person:
            self.episode_reset = self._with_virtual_person(self.episode_reset)

    def _with_virtual_person(self, reset: EpisodeReset) -> EpisodeReset:
        from lowcostdex.hardware.robot.reset import ResetFailed

        def with_person(qpos: np.ndarray) -> ResetReport:
            try:
                return reset(qpos)
            except ResetFailed as exc:
                if exc.stage not in ("block_orientation", "block_position"):
                    raise
                log.info("virtual person: %s; the block goes back to its start", exc)
                self.place_block(qpos)
                self.person_resets += 1
                return reset(qpos)

        return with_person

    def place_block(self, qpos: np.ndarray) -> None:
        """Put the emulated block at rest at its pose in ``qpos`` (the env model's layout): the
        emulator standing in for a person."""
        plant = self.chain.plant
        m, d = plant.model, plant.data
        block = _block_qpos(self.model)
        adr = int(m.jnt_qposadr[m.joint("block").id])
        dof = int(m.jnt_dofadr[m.joint("block").id])
        d.qpos[adr:adr + 7] = np.asarray(qpos, float)[block]
        d.qvel[dof:dof + 6] = 0.0
        mujoco.mj_forward(m, d)

    def _physics_tracker(self) -> Tracker:
        plant = self.chain.plant
        adr = int(plant.model.jnt_qposadr[plant.model.joint("block").id])

        def track() -> tuple[np.ndarray, np.ndarray]:
            q = plant.data.qpos
            return q[adr:adr + 3].copy(), q[adr + 3:adr + 7].copy()

        return track

    def telemetry(self) -> dict[str, Any]:
        out = super().telemetry()
        out["bus_time"] = self.chain.now
        if self.task.station == "block":
            out["person_resets"] = self.person_resets
        return out


class HardwareBackend(RobotBackend):
    """The task on a real D'Claw on a serial port (U2D2 or any dynamixel_sdk port).

    Args:
      model, task, rng: as every backend.
      port: serial device path, e.g. "/dev/ttyUSB0" (a pty from ``lowcostdex emulate`` works).
      baudrate: line rate [bit/s].
      hand: hand spec with this robot's calibration (default the task's): a ``HandSpec``, the
        path of its JSON or the JSON's dict (``lowcostdex.hands.as_hand_spec``).
      robot_config, reset_config: as ``EmulatedBackend``.
      tracker: block pose source for the flip task (motion capture), a callable or its import
        path "package.module:function"; required for that task.
      bus_kwargs: more ``DynamixelBus`` options.
    """

    def __init__(self, model: mujoco.MjModel, task: Any = None,
                 rng: np.random.Generator | None = None, *, port: str | None = None,
                 baudrate: int = 1_000_000, hand: HandSpec | None = None,
                 robot_config: RobotConfig | None = None,
                 reset_config: ResetConfig = ResetConfig(), tracker: Tracker | None = None,
                 flip_config: FlipResetConfig = FlipResetConfig(),
                 reorient: Reorient | None = None, **bus_kwargs: Any):
        if port is None and "channel" in bus_kwargs:
            raise ConfigError(f"channel={bus_kwargs['channel']!r} is the Allegro's CAN channel; "
                              "a D'Claw is on a serial port: port='/dev/ttyUSB0'")
        if task is None or port is None:
            raise ConfigError("HardwareBackend needs the task and port=... (e.g. /dev/ttyUSB0)")
        if port == "emulated":  # the CLI's spelling of the emulated robot, given to gym.make
            raise ConfigError("port='emulated' names no serial port: for the emulated D'Claw use "
                              "backend='emulated' (no port); for a real one port='/dev/ttyUSB0'")
        if task.hand.name != "dclaw":
            raise ConfigError(f"HardwareBackend drives a D'Claw on Dynamixels, not the "
                              f"{task.hand.name}; gym.make(..., backend='hardware') picks the "
                              "hand's backend (lowcostdex.sim.envs.backend.BACKENDS)")
        tracker = resolve_callable(tracker, "tracker")
        if task.station == "block" and tracker is None:
            raise ConfigError("the flip-block task on hardware needs tracker=... (a function "
                              "returning the block's position and quaternion)")
        reset_config = as_settings(ResetConfig, reset_config, "reset_config")
        flip_config = as_settings(FlipResetConfig, flip_config, "flip_config")
        hand = robot_hand(task.hand if hand is None else as_hand_spec(hand, "dclaw"), model)
        bus = make_dynamixel_bus(hand, port, model, baudrate=baudrate, **bus_kwargs)
        robot = Robot(hand, bus, task_robot_config(robot_config, task, model))
        super().__init__(model, task, robot,
                         dclaw_reset(task, model, reset_config, tracker, flip_config, reorient),
                         block_sensor(model, tracker) if task.station == "block" else None)


def task_robot_config(config: RobotConfig | None, task: Any, model: mujoco.MjModel,
                  default: RobotConfig | None = None) -> RobotConfig:
    """``config`` (or ``default``, or ``RobotConfig()``) with the task's control period."""
    period = task.timing.frame_skip * model.opt.timestep
    config = None if config is None else as_settings(RobotConfig, config, "robot_config")
    return dataclasses.replace(config or default or RobotConfig(), control_period=period)


def as_settings(cls: type, value: Any, name: str) -> Any:
    """``value`` as a ``cls`` settings dataclass (``RobotConfig``, ``ResetConfig``, ...): itself,
    or built from a mapping of its fields (a JSON run config's ``env_kwargs``; nested settings
    as mappings too). A misspelt key is refused listing the valid ones; any other type is
    refused naming ``name`` (``dataclasses.replace`` raised a TypeError on a dict)."""
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        check_keys(f"{cls.__name__} setting", value, [f.name for f in dataclasses.fields(cls)])
        defaults = cls()
        return cls(**{k: as_settings(type(getattr(defaults, k)), v, f"{name}.{k}")
                      if dataclasses.is_dataclass(getattr(defaults, k)) else v
                      for k, v in value.items()})
    raise ConfigError(f"{name}={value!r:.80} must be a {cls.__name__} (or a dict of its "
                      "settings)")


def as_effects(effects: Any) -> list[AppliedEffect]:
    """An emulated robot's ``effects``: a list of ``AppliedEffect``s or their ``to_dict()``
    mappings, or the path of a JSON file of them (``read_effects``: a list, or a gap report's
    extended/effects.json). One effect, an effect's name or a mapping is refused naming the form
    (iterating them read a name's letters or a dict's keys as effects)."""
    if isinstance(effects, (str, os.PathLike)) and str(effects).endswith(".json"):
        from lowcostdex.sim.effects.randomization import read_effects

        return read_effects(str(effects))
    if isinstance(effects, (str, bytes, Mapping, AppliedEffect)) or not isinstance(
            effects, Iterable):
        raise ConfigError(f"effects={effects!r:.80} must be a list of effects: AppliedEffect "
                          "objects or dicts with effect, joints and params (as in a gap "
                          "report's extended/effects.json); () for none")
    return [AppliedEffect.coerce(e) for e in effects]


def check_start_qpos(start_qpos: Any, model: mujoco.MjModel) -> np.ndarray | None:
    """An emulated robot's power-up pose: (nq,) finite numbers [rad, m], inside each limited
    hinge joint's range (a pose in degrees is named), or None."""
    if start_qpos is None:
        return None
    try:
        q = np.asarray(start_qpos, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"start_qpos={start_qpos!r:.80} must be numbers") from None
    joints = [model.joint(j).name for j in range(model.njnt)]
    if q.shape != (model.nq,):
        raise ConfigError(f"start_qpos has shape {q.shape}; this model's qpos is ({model.nq},): "
                          f"{', '.join(joints)} (every joint, the object's too)")
    if not np.all(np.isfinite(q)):
        raise ConfigError("start_qpos has NaN/inf entries")
    for j in range(model.njnt):
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE or not model.jnt_limited[j]:
            continue
        x, (lo, hi) = q[model.jnt_qposadr[j]], model.jnt_range[j]
        if not lo - 0.2 <= x <= hi + 0.2:
            raise ConfigError(f"start_qpos: joint {joints[j]} at {x:g} rad is outside its range "
                              f"[{lo:.3g}, {hi:.3g}] rad (degrees? give radians)")
    return q


def motor_limits(hand: HandSpec, model: mujoco.MjModel | None = None,
                 margin: float = EEPROM_MARGIN) -> tuple[tuple[float, float], ...]:
    """Min/Max Position Limits for the motors [rad, motor angle], joints then aux motors.

    The second safety layer, in the motors' EEPROM: the joint's mechanical range from the model
    plus ``margin`` [rad] (a joint resting on its stop must still accept torque), or, without
    a model, the policy limits widened by ``margin``. The Robot's gate keeps every goal inside
    the policy limits; the wider EEPROM range lets a joint that contacts pushed past its policy
    limit while limp be torqued and pulled back in, and still stops a runaway host at the
    mechanical stops. Joints spanning a full turn (the valve) keep their limits.

    Raises:
      ConfigError: a joint's limits leave the model's joint range (``check_model_ranges``).
    """
    if model is not None:
        check_model_ranges(hand, model)
    names = {model.joint(i).name for i in range(model.njnt)} if model is not None else set()
    out = []
    for j in hand.all_joints:
        lo, hi = j.low - margin, j.high + margin
        if j.name in names and model.jnt_limited[model.joint(j.name).id]:
            mech = model.jnt_range[model.joint(j.name).id]
            lo, hi = min(j.low, mech[0] - margin), max(j.high, mech[1] + margin)
        if hi - lo >= 2 * math.pi:
            lo, hi = j.low, j.high
        a, b = sorted((j.calibration.to_motor(lo), j.calibration.to_motor(hi)))
        out.append((max(a, 0.0), min(b, 2 * math.pi)))
    return tuple(out)


def make_dynamixel_bus(hand: HandSpec, port: Any, model: mujoco.MjModel | None = None,
                       **kwargs: Any) -> MotorBus:
    """The Dynamixel driver for ``hand`` on ``port`` (a device path or an emulated port), with
    EEPROM position limits from ``motor_limits`` unless ``position_limits`` is given."""
    from lowcostdex.hardware.dynamixel.driver import DynamixelBus

    kwargs.setdefault("position_limits", motor_limits(hand, model))
    return DynamixelBus.from_hand(hand, port, **kwargs)
