"""Hand specs: joint names, motor ids, motor models, safety limits and calibration, as data.

The MJCF builders (``lowcostdex.sim.models``), the envs, the drivers and the emulators all read
these specs, so a joint has one name, one id and one limit everywhere.

Calibration convention (invertible, per joint)::

    q_joint = sign * scale * q_motor + offset       q_motor = ticks * 2 pi / ticks_per_rev [rad]

so ROBEL's D'Claw map (scale 1, offsets -pi/2 on top joints, -pi elsewhere) puts sim zero at raw
tick 1024 (top) and 2048 (middle, bottom).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

from lowcostdex.errors import ConfigError, check_choice


@dataclass(frozen=True)
class Calibration:
    """Motor-to-joint map ``q_joint = sign * scale * q_motor + offset`` (radians)."""

    offset: float = 0.0
    sign: int = 1
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.sign not in (-1, 1):
            raise ConfigError(f"calibration sign must be +1 or -1, got {self.sign}")
        if not self.scale > 0:
            raise ConfigError(f"calibration scale must be > 0, got {self.scale}")

    def to_joint(self, q_motor: float) -> float:
        """Motor angle [rad] -> joint angle [rad]."""
        return self.sign * self.scale * q_motor + self.offset

    def to_motor(self, q_joint: float) -> float:
        """Joint angle [rad] -> motor angle [rad]."""
        return (q_joint - self.offset) / (self.sign * self.scale)

    def rate_to_joint(self, v_motor: float) -> float:
        """Motor velocity [rad/s] -> joint velocity [rad/s]."""
        return self.sign * self.scale * v_motor


@dataclass(frozen=True)
class JointSpec:
    """One actuated joint.

    Attributes:
      name: joint (and actuator) name in the MJCF model.
      motor_id: bus id (Dynamixel id, or Allegro joint index).
      low, high: safety/action limits [rad]; commands are clipped to them.
      max_velocity: per-step motion bound [rad/s]; a command moves at most this times the control
        period from the present position.
      calibration: motor-to-joint map.
    """

    name: str
    motor_id: int
    low: float
    high: float
    max_velocity: float = 2.0 * math.pi / 3.0
    calibration: Calibration = Calibration()

    def __post_init__(self) -> None:
        if not self.low < self.high:
            raise ConfigError(f"joint {self.name}: low {self.low} must be < high {self.high}")


@dataclass(frozen=True)
class HandSpec:
    """A hand: its actuated joints, motor model, and auxiliary motors (e.g. the valve motor).

    Attributes:
      name: "dclaw", "allegro", "bench".
      motor: servo model name (a key of ``lowcostdex.sim.servo.MOTORS``) or "allegro".
      joints: finger joints in action order.
      aux_joints: motors that are not part of the action (D'Claw valve motor, id 50).
    """

    name: str
    motor: str
    joints: tuple[JointSpec, ...]
    aux_joints: tuple[JointSpec, ...] = ()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def motor_ids(self) -> tuple[int, ...]:
        return tuple(j.motor_id for j in self.joints)

    @property
    def all_joints(self) -> tuple[JointSpec, ...]:
        return self.joints + self.aux_joints

    def joint(self, name: str) -> JointSpec:
        for j in self.all_joints:
            if j.name == name:
                return j
        check_choice("joint", name, [j.name for j in self.all_joints])
        raise AssertionError  # unreachable

    def with_motor(self, motor: str) -> HandSpec:
        return dataclasses.replace(self, motor=motor)

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2)

    @classmethod
    def from_json(cls, text: str) -> HandSpec:
        raw = json.loads(text)

        def joint(d: dict) -> JointSpec:
            return JointSpec(**{**d, "calibration": Calibration(**d.get("calibration", {}))})

        return cls(
            name=raw["name"],
            motor=raw["motor"],
            joints=tuple(joint(j) for j in raw["joints"]),
            aux_joints=tuple(joint(j) for j in raw.get("aux_joints", ())),
        )

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> HandSpec:
        return cls.from_json(Path(path).read_text())


DCLAW_FINGERS = ("ff", "mf", "th")
DCLAW_PARTS = ("top", "middle", "bottom")
# ROBEL's action/safety limits (01-hardware.md section 1.1) and calibration offsets.
_DCLAW_LIMITS = {"top": 0.48, "middle": math.pi / 3, "bottom": math.pi / 2}
_DCLAW_OFFSETS = {"top": -math.pi / 2, "middle": -math.pi, "bottom": -math.pi}


def dclaw_spec(motor: str = "XH430-W350") -> HandSpec:
    """The D'Claw: three fingers (ids 10-12, 20-22, 30-32) and the valve motor (id 50)."""
    joints = tuple(
        JointSpec(
            name=f"{finger}_{part}",
            motor_id=10 * (f + 1) + p,
            low=-_DCLAW_LIMITS[part],
            high=_DCLAW_LIMITS[part],
            calibration=Calibration(offset=_DCLAW_OFFSETS[part]),
        )
        for f, finger in enumerate(DCLAW_FINGERS)
        for p, part in enumerate(DCLAW_PARTS)
    )
    valve = JointSpec("valve", 50, -math.pi, math.pi, max_velocity=2.0,
                      calibration=Calibration(offset=-math.pi))
    return HandSpec("dclaw", motor, joints, (valve,))


# Allegro v4 right hand joint limits [rad] (published URDF, allegro_hand_description).
_ALLEGRO_FINGER_LIMITS = ((-0.47, 0.47), (-0.196, 1.61), (-0.174, 1.709), (-0.227, 1.618))
_ALLEGRO_THUMB_LIMITS = ((0.263, 1.396), (-0.105, 1.163), (-0.189, 1.644), (-0.162, 1.719))
ALLEGRO_FINGERS = ("index", "middle", "ring", "thumb")


def allegro_spec() -> HandSpec:
    """The Allegro hand v4: 16 torque-driven joints (CAN), index = 4 * finger + joint."""
    joints = []
    for f, finger in enumerate(ALLEGRO_FINGERS):
        limits = _ALLEGRO_THUMB_LIMITS if finger == "thumb" else _ALLEGRO_FINGER_LIMITS
        for k, (low, high) in enumerate(limits):
            joints.append(JointSpec(f"{finger}_{k}", 4 * f + k, low, high, max_velocity=math.pi))
    return HandSpec("allegro", "allegro", tuple(joints))


def bench_spec(motor: str = "XL330-M288", motor_id: int = 1) -> HandSpec:
    """A single servo on a pendulum test bench (as in BAM's logs); joint 0 is the middle of the
    servo's turn (tick 2048), so the joint range maps inside position mode's 0..4095."""
    return HandSpec("bench", motor, (JointSpec("bench", motor_id, -math.pi, math.pi,
                                               max_velocity=10.0,
                                               calibration=Calibration(offset=-math.pi)),))


HANDS = {"dclaw": dclaw_spec, "allegro": allegro_spec, "bench": bench_spec}


def hand_spec(name: str) -> HandSpec:
    """The default spec of a named hand; the error lists the known hands."""
    check_choice("hand", name, HANDS)
    return HANDS[name]()
