"""Hand specs: joint names, motor ids, motor models, safety limits and calibration, as data.

The MJCF builders (``lowcostdex.sim.models``), the envs, the drivers and the emulators all read
these specs, so a joint has one name, one id and one limit everywhere.

Calibration convention (invertible, per joint)::

    q_joint = sign * scale * q_motor + offset       q_motor = ticks * 2 pi / ticks_per_rev [rad]

so ROBEL's D'Claw map (scale 1, offsets -pi/2 on top joints, -pi elsewhere) puts sim zero at raw
tick 1024 (top) and 2048 (middle, bottom).

Specs are checked where they are built or loaded (ConfigError naming the joint, field and value;
``HandSpec.load`` adds the file): finite limits and calibration, ``max_velocity`` within what
the motor can turn, one motor id per joint, and on Dynamixel hands every joint's limits inside
the motor's one turn of position mode, on a hand named "dclaw" its finger joints' limits inside
ROBEL's D'Claw joint ranges (``DCLAW_RANGES``, the mechanical stops the D'Claw model has: a
Robot built from a spec never meets a model); on the Allegro (CAN) its 16 joints in action order on
joint slots 0..15, limits inside the published URDF ranges (the mechanical stops: the Allegro
model takes its ranges from the spec, so the model cannot tell) and inside the position the
hand reports (int16 counts of 333.3/65536 deg). ``check_model_ranges`` checks the limits against
a model's joint ranges (the mechanical stops) where a spec meets its model; ``as_hand_spec``
takes a spec given as an object, a JSON file or a JSON dict (an env keyword from a config).
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
from dataclasses import dataclass
from pathlib import Path

from lowcostdex.errors import ConfigError, InputError, LowcostdexError, check_choice, did_you_mean
from lowcostdex.motors import MOTORS, motor_spec

MAX_JOINT_SPEED = 50.0
"""Largest plausible ``max_velocity`` of any joint [rad/s]: above every servo listed in
``lowcostdex.motors`` (the fastest, XL330-M077, turns 383 rpm = 40 rad/s no-load)."""
_ONE_TURN = 2.0 * math.pi  # position mode: one turn of the motor, ticks 0 .. ticks_per_rev - 1


def _finite(what: str, value: float) -> None:
    try:
        ok = math.isfinite(value)
    except TypeError:
        ok = False
    if not ok:
        raise ConfigError(f"{what} must be a finite number, got {value!r}")


def _as_python(spec: object, **kinds: type) -> None:
    """Store ``spec``'s checked numeric fields as Python numbers: a numpy number (an offset
    from ``np.mean`` of readings) passes every check but not ``json`` (``HandSpec.save``)."""
    for field, kind in kinds.items():
        object.__setattr__(spec, field, kind(getattr(spec, field)))


@dataclass(frozen=True)
class Calibration:
    """Motor-to-joint map ``q_joint = sign * scale * q_motor + offset`` (radians)."""

    offset: float = 0.0
    sign: int = 1
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.sign not in (-1, 1):
            raise ConfigError(f"calibration sign must be +1 or -1, got {self.sign!r}")
        _finite("calibration offset", self.offset)
        _finite("calibration scale", self.scale)
        if not self.scale > 0:
            raise ConfigError(f"calibration scale must be > 0, got {self.scale}")
        _as_python(self, offset=float, sign=int, scale=float)

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
        if not isinstance(self.name, str) or not self.name:
            raise ConfigError(f"a joint's name must be a non-empty string, got {self.name!r}")
        if (isinstance(self.motor_id, bool) or not isinstance(self.motor_id, numbers.Integral)
                or not 0 <= self.motor_id <= 252):
            raise ConfigError(f"joint {self.name}: motor_id must be an integer bus id in "
                              f"[0, 252], got {self.motor_id!r}")
        for name in ("low", "high", "max_velocity"):
            _finite(f"joint {self.name}: {name}", getattr(self, name))
        if not self.low < self.high:
            raise ConfigError(f"joint {self.name}: low {self.low} must be < high {self.high}")
        if not 0 < self.max_velocity <= MAX_JOINT_SPEED:
            raise ConfigError(f"joint {self.name}: max_velocity {self.max_velocity} rad/s is "
                              f"outside (0, {MAX_JOINT_SPEED}]; it bounds each step's motion")
        if not isinstance(self.calibration, Calibration):
            raise ConfigError(f"joint {self.name}: calibration must be a Calibration, got "
                              f"{self.calibration!r}")
        _as_python(self, motor_id=int, low=float, high=float, max_velocity=float)


@dataclass(frozen=True)
class HandSpec:
    """A hand: its actuated joints, motor model, and auxiliary motors (e.g. the valve motor).

    Attributes:
      name: "dclaw", "allegro", "bench".
      motor: servo model name (a key of ``lowcostdex.motors.MOTORS``) or "allegro".
      joints: finger joints in action order.
      aux_joints: motors that are not part of the action (D'Claw valve motor, id 50).
    """

    name: str
    motor: str
    joints: tuple[JointSpec, ...]
    aux_joints: tuple[JointSpec, ...] = ()

    def __post_init__(self) -> None:
        if not self.joints:
            raise ConfigError(f"hand {self.name}: no joints")
        seen: dict[int, str] = {}
        names: set[str] = set()
        for j in self.all_joints:
            if j.motor_id in seen:
                raise ConfigError(f"hand {self.name}: joints {seen[j.motor_id]} and {j.name} are "
                                  f"both on motor id {j.motor_id}; every joint needs its own "
                                  "motor")
            if j.name in names:
                raise ConfigError(f"hand {self.name}: joint name {j.name} appears twice")
            seen[j.motor_id] = j.name
            names.add(j.name)
        if self.motor == "allegro":  # the Allegro's joints are torque-driven, no servo table
            self._check_allegro()
        else:
            if self.motor not in MOTORS:
                raise ConfigError(f"hand {self.name}: unknown motor model {self.motor!r}; valid "
                                  f"choices: {', '.join(MOTORS)} (or 'allegro')"
                                  + did_you_mean(self.motor, MOTORS))
            self._check_motor_range(MOTORS[self.motor])
        if self.name == "dclaw":
            self._check_dclaw()

    def _check_dclaw(self) -> None:
        """The D'Claw's finger joints (``<finger>_<part>``) inside ``DCLAW_RANGES``."""
        for j in self.joints:
            part = j.name.partition("_")[2]
            if part not in DCLAW_RANGES:
                continue
            lo, hi = DCLAW_RANGES[part]
            if j.low < lo or j.high > hi:
                degrees = _in_degrees(j.low, j.high, lo, hi)
                raise ConfigError(f"joint {j.name}: limits [{j.low}, {j.high}] rad leave the "
                                  f"D'Claw's joint range [{lo}, {hi}] rad (ROBEL's D'Claw model: "
                                  f"the mechanical stops){degrees}; type limits inside it, e.g. "
                                  + (degrees.split("they are ")[1].rstrip(")") if degrees else
                                     f"low={max(j.low, lo)}, high={min(j.high, hi)}"))

    def _check_allegro(self) -> None:
        """The Allegro v4's 16 joints in action order on CAN joint slots 0..15, no auxiliary
        motors, limits inside the published URDF range of each joint and inside the position
        the hand reports. (No servo table gives its joints' top speed: ``max_velocity`` has the
        general bound ``MAX_JOINT_SPEED``.)"""
        names = tuple(ALLEGRO_RANGES)
        if self.aux_joints:
            aux = ", ".join(j.name for j in self.aux_joints)
            raise ConfigError(f"hand {self.name}: aux_joints {aux}: the Allegro has no motors "
                              "beside its 16 joints on CAN; leave aux_joints empty")
        if self.joint_names != names:
            raise ConfigError(f"hand {self.name}: joints {', '.join(self.joint_names)} are not "
                              f"the Allegro's {len(names)} in action order: {', '.join(names)}")
        for j in self.joints:
            if not 0 <= j.motor_id < len(names):
                raise ConfigError(f"joint {j.name}: motor_id {j.motor_id} is not an Allegro joint "
                                  f"slot (0..{len(names) - 1}: 4 x finger + joint, as the hand's "
                                  "CAN frames carry them)")
            lo, hi = ALLEGRO_RANGES[j.name]
            if j.low < lo or j.high > hi:
                raise ConfigError(f"joint {j.name}: limits [{j.low}, {j.high}] rad leave the "
                                  f"Allegro's joint range [{lo}, {hi}] rad (published URDF: the "
                                  f"mechanical stops){_in_degrees(j.low, j.high, lo, hi)}")
            c = j.calibration
            a, b = sorted((c.to_motor(j.low), c.to_motor(j.high)))
            if a < -ALLEGRO_POSITION_RANGE or b > ALLEGRO_POSITION_RANGE:
                raise ConfigError(f"joint {j.name}: limits [{j.low}, {j.high}] rad are hand "
                                  f"readings [{a:.4f}, {b:.4f}] rad, outside what the hand "
                                  f"reports (+-{ALLEGRO_POSITION_RANGE:.4f} rad, int16 counts); "
                                  "check the calibration offset")

    def _check_motor_range(self, motor) -> None:
        """Limits inside the motor's one turn of position mode; max_velocity within the joint
        speed the motor reaches unloaded."""
        tick = _ONE_TURN / motor.ticks_per_rev
        for j in self.all_joints:
            c = j.calibration
            a, b = sorted((c.to_motor(j.low), c.to_motor(j.high)))
            if b - a > _ONE_TURN + 1e-9:
                raise ConfigError(f"joint {j.name}: limits [{j.low}, {j.high}] rad span "
                                  f"{b - a:.3f} rad of motor {j.motor_id}, more than its one "
                                  f"turn ({_ONE_TURN:.4f} rad) in position mode"
                                  + _in_degrees(j.low, j.high, -_ONE_TURN / 2, _ONE_TURN / 2))
            if b - a < _ONE_TURN - 1e-9 and (a < -tick or b > _ONE_TURN + tick):
                raise ConfigError(f"joint {j.name}: limits [{j.low}, {j.high}] rad are motor "
                                  f"{j.motor_id} angles [{a:.4f}, {b:.4f}] rad, outside its "
                                  f"range [0, {_ONE_TURN:.4f}] (ticks 0..{motor.ticks_per_rev - 1});"
                                  " check the limits and the calibration offset")
            top = motor.no_load_speed * c.scale
            if j.max_velocity > top:
                raise ConfigError(f"joint {j.name}: max_velocity {j.max_velocity} rad/s is "
                                  f"faster than a {motor.name} turns it unloaded ({top:.3f} "
                                  "rad/s)")

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
        _known_keys("the spec", raw, cls)

        def joint(d: dict) -> JointSpec:
            _known_keys(f"joint {d.get('name', '?')}" if isinstance(d, dict) else "a joint", d,
                        JointSpec)
            _known_keys(f"joint {d.get('name', '?')}: calibration", d.get("calibration", {}),
                        Calibration)
            return JointSpec(**{**d, "calibration": Calibration(**d.get("calibration", {}))})

        for key in ("joints", "aux_joints"):  # else "'NoneType' object is not iterable", or a
            if not isinstance(raw.get(key, []), list):  # dict's keys taken for its joints
                raise ConfigError(f"the spec's {key!r} must be a JSON list of joint objects "
                                  f"([] for none), got {type(raw[key]).__name__}")
        return cls(
            name=raw["name"],
            motor=raw["motor"],
            joints=tuple(joint(j) for j in raw["joints"]),
            aux_joints=tuple(joint(j) for j in raw.get("aux_joints", ())),
        )

    def save(self, path: str | Path) -> None:
        """Write the spec as JSON to ``path`` (a leading ``~`` is the home folder)."""
        from lowcostdex.outdir import user_path

        out = user_path(path)
        if out.is_dir():
            raise InputError(f"{path} is a folder; give a file name, e.g. {out / 'hand.json'}")
        out.write_text(self.to_json())

    @classmethod
    def load(cls, path: str | Path) -> HandSpec:
        """The spec in a JSON file (a leading ``~`` is the home folder); InputError naming the
        file and what is wrong with it."""
        from lowcostdex.outdir import user_path

        try:
            text = user_path(path).read_text()
        except OSError as exc:
            raise InputError(f"{path}: cannot read it ({exc.strerror}); give the path of a "
                             "hand spec JSON (one HandSpec.save or `lowcostdex calibrate` "
                             "wrote)") from None
        try:
            return cls.from_json(text)
        except ConfigError as exc:
            raise InputError(f"{path}: {exc}") from None
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            yaml = str(path).lower().endswith((".yaml", ".yml")) or text.lstrip().startswith(
                ("name:", "motor:", "joints:", "---"))
            hint = (" - it reads as YAML; a hand spec is JSON (HandSpec.save writes one): "
                    "HandSpec.from_json(json.dumps(yaml.safe_load(text))).save('hand.json')"
                    if yaml else "")
            raise InputError(f"{path}: not a hand spec JSON ({type(exc).__name__}: {exc}){hint}"
                             ) from None


def _in_degrees(low: float, high: float, lo: float, hi: float) -> str:
    """The hint for limits typed in degrees: beyond 2 pi, and inside [lo, hi] read as degrees
    ('' otherwise)."""
    rl, rh = math.radians(low), math.radians(high)
    if max(abs(low), abs(high)) > _ONE_TURN and lo <= rl and rh <= hi:
        return f" (degrees? in rad they are low={rl:.4g}, high={rh:.4g})"
    return ""


def _known_keys(where: str, raw: object, cls: type) -> None:
    """ConfigError for an object that is not a JSON object or has a key ``cls`` does not know
    (a misspelt field would otherwise be ignored or fail deep inside)."""
    fields = [f.name for f in dataclasses.fields(cls)]
    if not isinstance(raw, dict):
        raise ConfigError(f"{where} must be a JSON object with keys {', '.join(fields)}; got "
                          f"{type(raw).__name__}")
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; valid keys: {', '.join(fields)}")
    required = [f.name for f in dataclasses.fields(cls)
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    missing = [k for k in required if k not in raw]
    if missing:  # else a TypeError/KeyError that names neither the joint nor the file's key
        raise ConfigError(f"{where}: missing key {missing[0]!r}; required keys: "
                          f"{', '.join(required)}")


def check_model_ranges(hand: HandSpec, model) -> None:
    """Raise ConfigError unless every joint's limits lie inside its range in ``model`` (an
    ``mujoco.MjModel``; the mechanical stops), for the joints the model has and limits."""
    names = {model.joint(i).name for i in range(model.njnt)}
    for j in hand.all_joints:
        if j.name not in names or not model.jnt_limited[model.joint(j.name).id]:
            continue
        lo, hi = (float(x) for x in model.jnt_range[model.joint(j.name).id])
        if j.low < lo or j.high > hi:
            raise ConfigError(f"joint {j.name}: limits [{j.low}, {j.high}] rad leave the "
                              f"model's joint range [{lo}, {hi}] rad (the mechanical stops)")


DCLAW_FINGERS = ("ff", "mf", "th")
DCLAW_PARTS = ("top", "middle", "bottom")
# ROBEL's D'Claw joint ranges [rad] (its MJCF: the mechanical stops; wider than the action limits)
DCLAW_RANGES = {"top": (-0.5, 1.35), "middle": (-2.0, 2.0), "bottom": (-2.0, 2.0)}
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
ALLEGRO_RANGES = {f"{finger}_{k}": lim for finger in ALLEGRO_FINGERS for k, lim in enumerate(
    _ALLEGRO_THUMB_LIMITS if finger == "thumb" else _ALLEGRO_FINGER_LIMITS)}
"""Joint name -> (low, high) [rad] of the Allegro v4 right hand in action order."""
ALLEGRO_POSITION_UNIT = math.radians(333.3 / 65536.0)
"""[rad] per count of a FINGER_POSE position (``deg = raw * 333.3 / 65536``, v4 C++ driver)."""
ALLEGRO_POSITION_RANGE = 32768 * ALLEGRO_POSITION_UNIT
"""[rad] the largest position an int16 FINGER_POSE count carries (2.909 rad)."""


def allegro_spec() -> HandSpec:
    """The Allegro hand v4: 16 torque-driven joints (CAN), index = 4 * finger + joint."""
    joints = [JointSpec(name, i, low, high, max_velocity=math.pi)
              for i, (name, (low, high)) in enumerate(ALLEGRO_RANGES.items())]
    return HandSpec("allegro", "allegro", tuple(joints))


def bench_spec(motor: str = "XL330-M288", motor_id: int = 1) -> HandSpec:
    """A single servo on a pendulum test bench (as in BAM's logs); joint 0 is the middle of the
    servo's turn (tick 2048), so the joint range maps inside position mode's 0..4095; the speed
    bound is 10 rad/s or the motor's no-load speed if slower."""
    top = min(10.0, motor_spec(motor).no_load_speed)
    return HandSpec("bench", motor, (JointSpec("bench", motor_id, -math.pi, math.pi,
                                               max_velocity=top,
                                               calibration=Calibration(offset=-math.pi)),))


HANDS = {"dclaw": dclaw_spec, "allegro": allegro_spec, "bench": bench_spec}


def hand_spec(name: str) -> HandSpec:
    """The default spec of a named hand; the error lists the known hands."""
    check_choice("hand", name, HANDS)
    return HANDS[name]()


def as_hand_spec(value: object, hand: str) -> HandSpec:
    """A hand spec given to a backend as ``hand=``: a ``HandSpec``, the path of a spec JSON, or
    the JSON's dict (an env keyword from a JSON config); it must be a ``hand`` spec.

    Raises:
      ConfigError / InputError: another type, a file or dict that is not a valid spec, or a
        spec of another hand.
    """
    if isinstance(value, HandSpec):
        spec = value
    elif isinstance(value, (str, Path)):
        try:
            spec = HandSpec.load(value)
        except InputError as exc:
            raise InputError(f"hand={exc}") from None
    elif isinstance(value, dict):
        try:
            spec = HandSpec.from_json(json.dumps(value))
        except ConfigError as exc:
            raise ConfigError(f"hand=: {exc}") from None
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise ConfigError(f"hand=: not a hand spec ({type(exc).__name__}: {exc})") from None
    else:
        raise ConfigError(f"hand= must be a HandSpec, the path of a hand spec JSON or its dict; "
                          f"got {type(value).__name__}")
    if spec.name != hand:
        raise ConfigError(f"hand=: a {spec.name!r} hand spec given for the {hand!r} hand")
    return spec


def load_spec(path: str):
    """``HandSpec.load`` for a command's ``--spec`` option: a one-line InputError for a file that
    is not a hand spec."""
    try:
        return HandSpec.load(path)
    except InputError as exc:  # names the file and the field; say which option gave it
        raise InputError(f"--spec {exc}") from None
    except (LowcostdexError, OSError):
        raise
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise InputError(f"--spec {path}: not a hand spec JSON ({type(exc).__name__}: {exc})"
                         ) from None
