"""Hidden robots: emulated D'Claws that differ from the nominal model, for measuring transfer.

A ``HiddenRobot`` is drawn from a seed (``hidden_robot``, ``hidden_robots``) and stands in for a
real D'Claw in the transfer table (``lowcostdex transfer``): policies trained in simulation are
evaluated on it through the emulated bus, and the gap analysis identifies it from logs recorded
on it. It differs from the nominal model in three ways:

1. **Catalogue effects** (``lowcostdex.sim.effects``) at realistic sizes, a mix of 3-5 of
   latency, backlash, Coulomb / Stribeck / load-dependent friction, encoder offset, gain and
   inertia errors per robot (``HIDDEN_EFFECTS``); each finger has or lacks each effect and every
   joint draws its own value.
2. **MJCF perturbations no effect names** (``ModelPerturbation``): link masses (+-8 %) and link
   lengths (+-3 %) per finger, one finger base mounted 2-4 deg rotated about a horizontal axis,
   the valve's dry friction, damping and inertia changed.
3. **Firmware imperfections** (``FirmwareImperfection``), per servo: a PWM deadband of the
   position loop (the driver puts out nothing while the P term's PWM is below 10-30 of 885
   units: 1.4-4.3 ticks of error at the factory P gain) and a magnetic encoder's once-per-turn
   nonlinearity (0.25-0.7 deg amplitude). The servo closes its loop on its own encoder, so the
   nonlinearity also moves where a goal puts the joint. Since session 21 the deadband is
   nameable: the catalogue's ``deadband`` (``lowcostdex.sim.effects.deadband``) holds the same
   band, its P term on the error beyond the band where this firmware passes the whole error
   once outside it (they differ by at most kp x width of force at the band's edge). The
   encoder nonlinearity and the geometry of item 2 (link lengths, the tilted finger base) stay
   outside the catalogue.

Identifying such a robot is therefore not a lookup of the analyzer's own catalogue: parts of it
can only be approximated by catalogue effects, and the valve is never seen by the finger logs.

The training side never reads these definitions (an import-linter contract keeps
``lowcostdex.algos`` and ``lowcostdex.sim`` from importing this module); only the evaluation and
the identification recordings do.

    robots = hidden_robots(3, seed=0)
    env = gym.make("lowcostdex/DClawTurnValveRandom-v0", **robots[0].env_kwargs())
    chain = robots[0].chain("none")        # the same robot without its valve station
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.hands import DCLAW_FINGERS, HandSpec, dclaw_spec
from lowcostdex.sim import servo
from lowcostdex.sim.effects import AppliedEffect, effect

# Realistic sizes of the catalogue effects a hidden robot may carry: effect -> parameter ->
# (low, high) magnitude; "sign" parameters are drawn with a random sign. Inside each parameter's
# plausible D'Claw range (``Param.dr``), away from the null so an effect is there when drawn.
HIDDEN_EFFECTS: dict[str, dict[str, tuple[float, float]]] = {
    "latency": {"delay": (0.006, 0.025)},                       # [s]
    "backlash": {"width": (0.004, 0.017)},                      # [rad] 0.25-1 deg
    "coulomb_friction": {"frictionloss": (0.02, 0.08)},        # [N m]
    "stribeck_friction": {"static": (0.02, 0.06), "velocity": (0.05, 0.3)},
    "load_dependent_friction": {"mu": (0.03, 0.12)},
    "position_offset": {"offset": (0.005, 0.025)},              # [rad], random sign
    "gain_error": {"scale": (0.1, 0.3)},                        # |scale - 1|, random sign
    "inertia_error": {"scale": (0.15, 0.3)},                    # |scale - 1|, random sign
}
_SIGNED = {("position_offset", "offset")}
_AROUND_ONE = {("gain_error", "scale"), ("inertia_error", "scale")}
N_EFFECTS = (3, 5)  # effects per robot (inclusive)
FINGER_PRESENCE = 0.7  # probability that a finger carries each of its robot's effects
LINK_MASS = 0.08  # relative +- range of each link's mass
LINK_LENGTH = 0.03  # relative +- range of each finger's link lengths
BASE_TILT = (math.radians(2.0), math.radians(4.0))  # [rad] one finger base's mounting error
VALVE_FRICTION = (0.005, 0.02)  # [N m] added dry friction of the valve hinge
VALVE_DAMPING = (0.6, 1.6)  # factor on the valve hinge damping
VALVE_INERTIA = (0.7, 1.5)  # factor on the valve's masses, inertias and armature
PWM_DEADBAND = (10.0, 30.0)  # [PWM units of 885] position-loop deadband
ENCODER_ERROR = (math.radians(0.25), math.radians(0.7))  # [rad] encoder nonlinearity amplitude


@dataclass(frozen=True)
class ModelPerturbation:
    """How a hidden robot's body differs from the nominal MJCF (``apply`` edits a D'Claw spec).

    Attributes:
      link_mass: body name -> mass factor (every geom of the body; inertia follows).
      link_length: finger -> factor on the distances between its joints and to its tip.
      base_tilt: finger -> (axis (x, y, 0) in the base frame, angle [rad]) of its mounting error.
      valve_frictionloss: added dry friction of the valve hinge [N m].
      valve_damping: factor on the valve hinge damping.
      valve_inertia: factor on the valve's geom masses and its hinge armature.
    """

    link_mass: dict[str, float] = field(default_factory=dict)
    link_length: dict[str, float] = field(default_factory=dict)
    base_tilt: dict[str, tuple[tuple[float, float, float], float]] = field(default_factory=dict)
    valve_frictionloss: float = 0.0
    valve_damping: float = 1.0
    valve_inertia: float = 1.0

    def apply(self, spec: mujoco.MjSpec) -> None:
        """Edit a D'Claw spec (``sim.models.dclaw.build_dclaw``) in place; parts the spec lacks
        (fingers not built, no valve station) are skipped."""
        bodies = {b.name: b for b in spec.worldbody.find_all(mujoco.mjtObj.mjOBJ_BODY)}
        for name, factor in self.link_mass.items():
            if name in bodies:
                for g in bodies[name].geoms:
                    g.mass = g.mass * factor
        for finger, factor in self.link_length.items():
            for link in (f"{finger}_link1", f"{finger}_link2"):
                if link in bodies:
                    bodies[link].pos = np.asarray(bodies[link].pos) * factor
            tip = bodies.get(f"{finger}_link2")
            if tip is not None:
                for item in (*tip.geoms, *tip.sites):
                    item.pos = np.asarray(item.pos) * factor
        for finger, (axis, angle) in self.base_tilt.items():
            base = bodies.get(f"{finger}_base")
            if base is not None:
                tilt = np.array([math.cos(angle / 2), *(math.sin(angle / 2) * np.asarray(axis))])
                quat = np.zeros(4)
                mujoco.mju_mulQuat(quat, np.asarray(base.quat, float), tilt)
                base.quat = quat
        if "valve_body" in bodies:
            joint = spec.joint("valve")
            joint.frictionloss = joint.frictionloss + self.valve_frictionloss
            joint.damping[0] = joint.damping[0] * self.valve_damping
            joint.armature = joint.armature * self.valve_inertia
            for g in bodies["valve_body"].geoms:
                g.mass = g.mass * self.valve_inertia

    def to_dict(self) -> dict[str, Any]:
        return {"link_mass": dict(self.link_mass), "link_length": dict(self.link_length),
                "base_tilt": {f: {"axis": list(a), "angle_deg": math.degrees(t)}
                              for f, (a, t) in self.base_tilt.items()},
                "valve_frictionloss": self.valve_frictionloss,
                "valve_damping": self.valve_damping, "valve_inertia": self.valve_inertia}


@dataclass(frozen=True)
class FirmwareImperfection:
    """Servo firmware behaviour of a hidden robot beyond its catalogue effects (the deadband is
    nameable as the catalogue's ``deadband`` since session 21; the encoder error is not).

    Per servo (joint name): the encoder reads ``q + amplitude sin(q + phase)`` (a magnetic
    encoder's once-per-turn error; the D'Claw's joints turn 1:1 with their horns), and the
    position loop has a deadband: the firmware's loop acts on the error between its setpoint
    and that reading, and puts out nothing while |error| < ``deadband``. Joints not listed are
    ideal. Implements ``drive.Imperfection``.

    Attributes:
      deadband: joint -> position-error deadband [rad] (the PWM deadband over the P gain).
      amplitude: joint -> encoder error amplitude [rad].
      phase: joint -> encoder error phase [rad].
    """

    deadband: dict[str, float] = field(default_factory=dict)
    amplitude: dict[str, float] = field(default_factory=dict)
    phase: dict[str, float] = field(default_factory=dict)

    def bind(self, joints: Sequence[str]) -> _BoundFirmware:
        """The imperfection of the servos driving ``joints`` (in that order)."""
        return _BoundFirmware(np.array([self.deadband.get(j, 0.0) for j in joints]),
                              np.array([self.amplitude.get(j, 0.0) for j in joints]),
                              np.array([self.phase.get(j, 0.0) for j in joints]))

    def to_dict(self) -> dict[str, Any]:
        return {"deadband_rad": dict(self.deadband), "encoder_amplitude_rad": dict(self.amplitude),
                "encoder_phase_rad": dict(self.phase)}


@dataclass(frozen=True)
class _BoundFirmware:
    deadband: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray

    def encoder(self, q: np.ndarray) -> np.ndarray:
        return q + self.amplitude * np.sin(q + self.phase)

    def command(self, goal: np.ndarray, q: np.ndarray) -> np.ndarray:
        error = goal - self.encoder(q)
        return q + np.where(np.abs(error) < self.deadband, 0.0, error)


def pwm_deadband_error(pwm: float, motor: str) -> float:
    """Position error [rad] at which the P term of ``motor``'s factory gains reaches ``pwm``
    [PWM units]: the X-series position loop puts out K_PP e = (P / 128) e PWM units for an
    error of e ticks (e-Manual, Position PID)."""
    spec = servo.motor_spec(motor)
    ticks = pwm / (spec.default_p / 128.0)
    return ticks * 2 * math.pi / spec.ticks_per_rev


@dataclass(frozen=True)
class HiddenRobot:
    """An emulated D'Claw that differs from the nominal model (module docstring).

    Attributes:
      name: label in tables.
      seed: the seed it was drawn from.
      effects: catalogue effects (one per effect name, per-joint values; null where a finger
        lacks it).
      model: MJCF perturbations.
      firmware: servo firmware imperfection.
      motor: servo model of the hand.
    """

    name: str
    seed: int
    effects: tuple[AppliedEffect, ...]
    model: ModelPerturbation
    firmware: FirmwareImperfection
    motor: str = "XH430-W350"

    def emulator_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``emulator.emulated_dclaw`` (and of the emulated env backend)
        that make an emulated D'Claw this robot."""
        return {"effects": list(self.effects), "modify_model": self.model.apply,
                "imperfection": self.firmware}

    def env_kwargs(self) -> dict[str, Any]:
        """``gym.make`` keyword arguments of a D'Claw task on this robot (emulated backend)."""
        return {"backend": "emulated", "motor": self.motor, **self.emulator_kwargs()}

    def chain(self, station: str = "valve", rng: np.random.Generator | None = None,
              **kwargs: Any) -> Any:
        """This robot as an ``emulator.EmulatedChain`` (``station``: "valve", "none", ...);
        ``kwargs`` as ``emulated_dclaw``."""
        from lowcostdex.hardware.emulated.chain import emulated_dclaw

        return emulated_dclaw(station, self.motor, rng=np.random.default_rng(self.seed) if rng is None else rng,
                              **self.emulator_kwargs(), **kwargs)

    def effect_truth(self) -> dict[str, dict[str, list[float]]]:
        """The catalogue part of the truth: effect -> parameter -> value per hand joint."""
        return {e.name: {p: v.tolist() for p, v in e.values.items()} for e in self.effects}

    def to_dict(self) -> dict[str, Any]:
        """A JSON description of everything that makes this robot differ (the truth)."""
        return {"name": self.name, "seed": self.seed, "motor": self.motor,
                "effects": [e.to_dict() for e in self.effects],
                "model": self.model.to_dict(), "firmware": self.firmware.to_dict()}


def _draw_effects(rng: np.random.Generator, hand: HandSpec) -> tuple[AppliedEffect, ...]:
    names = list(HIDDEN_EFFECTS)
    k = int(rng.integers(N_EFFECTS[0], N_EFFECTS[1] + 1))
    chosen = sorted(rng.choice(len(names), size=k, replace=False))
    joints = hand.joint_names
    fingers = [j.split("_")[0] for j in joints]
    out = []
    for i in chosen:
        name = names[i]
        cls = effect(name)
        present = rng.random(len(DCLAW_FINGERS)) < FINGER_PRESENCE
        if not present.any():
            present[int(rng.integers(len(DCLAW_FINGERS)))] = True
        on = np.array([present[DCLAW_FINGERS.index(f)] for f in fingers])
        values = {}
        for p, (lo, hi) in HIDDEN_EFFECTS[name].items():
            mag = rng.uniform(lo, hi, size=len(joints))
            if (name, p) in _SIGNED or (name, p) in _AROUND_ONE:
                mag = mag * rng.choice([-1.0, 1.0], size=len(joints))
            if (name, p) in _AROUND_ONE:
                mag = 1.0 + mag
            values[p] = np.where(on, mag, cls.param(p).null)
        out.append(AppliedEffect(name, joints, values))
    return tuple(out)


def _draw_model(rng: np.random.Generator) -> ModelPerturbation:
    mass = {f"{f}_link{k}": float(1.0 + rng.uniform(-LINK_MASS, LINK_MASS))
            for f in DCLAW_FINGERS for k in range(3)}
    length = {f: float(1.0 + rng.uniform(-LINK_LENGTH, LINK_LENGTH)) for f in DCLAW_FINGERS}
    finger = DCLAW_FINGERS[int(rng.integers(len(DCLAW_FINGERS)))]
    direction = rng.uniform(0, 2 * math.pi)
    axis = (math.cos(direction), math.sin(direction), 0.0)
    tilt = {finger: (axis, float(rng.uniform(*BASE_TILT)))}
    return ModelPerturbation(mass, length, tilt,
                             valve_frictionloss=float(rng.uniform(*VALVE_FRICTION)),
                             valve_damping=float(rng.uniform(*VALVE_DAMPING)),
                             valve_inertia=float(rng.uniform(*VALVE_INERTIA)))


def _draw_firmware(rng: np.random.Generator, hand: HandSpec) -> FirmwareImperfection:
    joints = [j.name for j in hand.all_joints]
    deadband = {j: pwm_deadband_error(float(rng.uniform(*PWM_DEADBAND)), hand.motor)
                for j in joints}
    amplitude = {j: float(rng.uniform(*ENCODER_ERROR)) for j in joints}
    phase = {j: float(rng.uniform(0, 2 * math.pi)) for j in joints}
    return FirmwareImperfection(deadband, amplitude, phase)


def hidden_robot(seed: int, name: str | None = None, motor: str = "XH430-W350") -> HiddenRobot:
    """Draw one hidden robot from ``seed`` (same seed, same robot)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"hidden robot seed must be an integer >= 0 (same seed, same robot), "
                          f"got {seed!r}")
    hand = dclaw_spec(motor)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0x41D,)))
    effects = _draw_effects(rng, hand)
    model = _draw_model(rng)
    firmware = _draw_firmware(rng, hand)
    return HiddenRobot(name or f"robot{seed}", seed, effects, model, firmware, motor)


def hidden_robots(n: int = 3, seed: int = 0, motor: str = "XH430-W350") -> list[HiddenRobot]:
    """``n`` hidden robots, ``hidden_robot(seed + k)`` named "A", "B", ..."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ConfigError(f"need an integer number of hidden robots >= 1, got n={n!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed={seed!r}: the hidden robots' seed must be an integer >= 0 "
                          "(robot k is hidden_robot(seed + k)); a Generator cannot name them")
    return [hidden_robot(seed + k, chr(ord("A") + k), motor) for k in range(n)]
