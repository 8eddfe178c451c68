"""The D'Claw from primitives, with its stations (valve, foam valve, screw, flip block).

Geometry, joint axes, ranges and masses follow ROBEL's D'Claw (01-hardware.md section 1.9): a
base plate at z = 0.335 m flipped so the fingers point down, three 3-joint fingers at 120 deg,
each link a servo box, the distal link a capsule fingertip. Servos are ``lowcostdex.sim.servo``
dcmotor actuators parameterized by the motor model of the hand spec (XH430 or XM430).

Deviation from ROBEL (which has no block station): the flip block rests on a 0.1 m high table so
its centre (z = 0.125 m) sits at fingertip height. With the block on a 0.05 m platform (top face
at z = 0.1 m) the fingertips, which reach z ~ 0.115 m only when bent inwards over the block,
could not get beside it: over 20000 random finger poses the closest any finger geom came was
1.3 mm. On the table the tips reach the side faces between z 0.115 and 0.15 m and can roll the
block over an edge. The table (0.4 m square) is wider than the fingers can push the block, so
the block never falls off between resets.

The valve differs from ROBEL's "valve3" (docs/hardware.md, "Where the D'Claw model differs from
ROBEL's"; tests/test_dclaw_valve_reference.py computes ROBEL's side from its typed geometry):

- Spoke phase: ROBEL's (spokes at 0, 120, 240 deg at valve angle 0, the angle its motor-50
  calibration reports, which this project copies), midway between the fingers. Until 2026-11-26
  ours sat at -90, 30, 150 deg, where the three-finger valve teacher needed two strokes; at
  ROBEL's phase it needed three and failed under randomized dynamics, so
  ``ValveTurnTeacher`` (teachers/valve.py) became a relay.
- Spoke/hub friction 1.0 (ROBEL 0.2): taken for rubber-coated spokes, not measured. The old
  three-finger teacher needed it (randomized dynamics 0/20 at 0.2); the relay teacher does not
  (20/20 at both, and its emulated playbacks are better at 0.2), but at 0.2 the Robot's fault
  soak (tests/test_robot_faults.py) no longer drives th_middle to its limit, and every recorded
  valve-task number was measured at 1.0: kept until those are re-measured (bench/RESULTS.md,
  "Valve contact friction at ROBEL's 0.2").
- Inertia about the hinge 4.1e-3 kg m^2, ROBEL's 2.0e-3 (+107 %): ROBEL's valve is solid at
  water density (0.48 kg, 1.0e-3) plus armature 1e-3; ours is printed parts (0.09 kg, 1.5e-4) plus
  armature 1e-3 plus the valve servo's reflected rotor inertia (3e-3, ``servo.add_servo``): the
  released XH430 under the valve is back-driven through its gearbox, which ROBEL leaves out.

Names: joints and actuators are the hand spec's (``ff_top`` ... ``th_bottom``); the valve hinge is
``valve`` with servo ``valve`` (motor id 50, torque off during episodes); the block is ``block``.
Fingertip sites are ``<finger>_tip``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice
from lowcostdex.hands import DCLAW_FINGERS, DCLAW_PARTS, DCLAW_RANGES, HandSpec, dclaw_spec
from lowcostdex.sim import servo
from lowcostdex.sim.models.common import (
    GROUP_COLLISION,
    add_floor,
    new_spec,
    quat_euler,
    visual_only,
)

MOUNT_Z = 0.335  # [m] base-plate height in the station scenes (ROBEL)
# Finger base positions in the flipped claw frame and yaw [rad] (FF, MF, TH).
_FINGER_BASES = {
    "ff": ((0.03, -0.052, 0.003), 0.52),
    "mf": ((0.03, 0.052, 0.003), 2.6),
    "th": ((-0.06, 0.0, 0.003), -1.57),
}
_MOTOR_BOX = (0.0175, 0.015, 0.024)  # half sizes [m] of an XH/XM430 body along the finger
_MOTOR_MASS = 0.093 + 0.012  # servo plus its printed plates [kg]
# ROBEL's fingertip friction. MuJoCo takes the larger friction of two touching geoms, so contacts
# with the valve (friction 1.0, rubber-coated spokes) and the block use the object's value.
_TIP_FRICTION = (0.2, 0.005, 0.0001)
_JOINT_RANGE = DCLAW_RANGES  # MJCF joint ranges [rad] (wider than the env's action limits)

STATIONS = ("valve", "foam_valve", "screw", "block", "none")


@dataclass(frozen=True)
class ValveGeometry:
    """A spoked valve on a hinge (ROBEL "valve3").

    Attributes:
      spokes: number of spokes.
      spoke_radius, spoke_half_length: capsule size [m].
      spoke_center: radius of the spoke centres [m].
      damping: hinge damping [N m s/rad]; frictionloss: hinge dry friction [N m].
      friction: geom sliding friction; solref: contact softness (foam: compliant).
      limited: a hinge range of +-2 pi (ROBEL's). Off by default: a valve on a servo turns
        freely, and a range lets a valve that overshot 180 deg end up parked against it, out of
        reach of the valve motor's reset.
      spoke_phase: world direction of spoke 0 about the valve axis at valve angle 0 [rad, from
        +x]; the others follow every 2 pi / spokes. ROBEL's: 0.
    """

    spokes: int = 3
    spoke_radius: float = 0.021
    spoke_half_length: float = 0.035
    spoke_center: float = 0.038
    damping: float = 0.1
    frictionloss: float = 0.0
    friction: float = 1.0
    solref: tuple[float, float] = (0.02, 1.0)
    solimp: tuple[float, float, float] = (0.9, 0.95, 0.001)
    limited: bool = False
    spoke_phase: float = 0.0


VALVE = ValveGeometry()
FOAM_VALVE = ValveGeometry(damping=0.2, frictionloss=0.03, friction=1.2, solref=(0.04, 1.0),
                           solimp=(0.5, 0.9, 0.01))
SCREW = ValveGeometry()


def build_dclaw(
    station: str = "valve",
    hand: HandSpec | None = None,
    gains: servo.ServoGains | None = None,
    *,
    thermal: bool = True,
    fingers: tuple[str, ...] = DCLAW_FINGERS,
) -> mujoco.MjSpec:
    """Build the D'Claw scene as an MjSpec (compile with ``spec.compile()``).

    Args:
      station: one of STATIONS.
      hand: hand spec (joint names, motor model); default ``dclaw_spec()`` (XH430-W350).
      gains: firmware gains of every servo (default: the motor's factory P/I/D gains).
      thermal: model winding temperature (one activation state per servo).
      fingers: fingers to build (a subset of DCLAW_FINGERS, e.g. ("ff",) for a single-finger
        test model with station "none"); the hand's other joints and servos are left out.
    """
    check_choice("D'Claw station", station, STATIONS)
    for f in fingers:
        check_choice("D'Claw finger", f, DCLAW_FINGERS)
    hand = hand or dclaw_spec()
    dclaw = tuple(f"{f}_{p}" for f in DCLAW_FINGERS for p in DCLAW_PARTS)
    if tuple(hand.joint_names) != dclaw:
        raise ConfigError(f"hand {hand.name}: joints {', '.join(hand.joint_names) or '(none)'} are "
                          f"not the D'Claw's {len(dclaw)} in action order: {', '.join(dclaw)}")
    motor = servo.motor_spec(hand.motor)
    gains = gains or motor.factory_gains()
    spec = new_spec(f"dclaw_{station}")
    add_floor(spec)
    spec.worldbody.add_camera(name="front", pos=[0.0, -0.45, 0.35], xyaxes=[1, 0, 0, 0, 0.6, 0.8])
    claw = spec.worldbody.add_body(name="claw", pos=[0, 0, MOUNT_Z], quat=quat_euler(x=math.pi))
    claw.add_geom(name="base_plate", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.075, 0.004, 0],
                  mass=0.11, rgba=[0.3, 0.3, 0.3, 1], group=GROUP_COLLISION)
    names = iter(hand.joint_names)
    built = []
    for finger in DCLAW_FINGERS:
        finger_joints = [next(names) for _ in range(3)]
        if finger in fingers:
            _add_finger(claw, finger, finger_joints)
            built += finger_joints
    for j in (j for j in hand.joints if j.name in built):
        servo.add_servo(spec, j.name, motor, gains, ctrlrange=_JOINT_RANGE[j.name.split("_")[1]],
                        thermal=thermal)
    if station in ("valve", "foam_valve", "screw"):
        geom = {"valve": VALVE, "foam_valve": FOAM_VALVE, "screw": SCREW}[station]
        _add_valve(spec, geom)
        # The valve motor (id 50) sits under the valve; episodes run with its torque off.
        servo.add_servo(spec, "valve", motor, gains, thermal=thermal)
    elif station == "block":
        _add_block(spec)
    return spec


def _add_finger(claw: mujoco.MjsBody, finger: str, joints: list[str]) -> None:
    pos, yaw = _FINGER_BASES[finger]
    base = claw.add_body(name=f"{finger}_base", pos=list(pos), quat=quat_euler(z=yaw))
    base.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.024, 0.0175, 0.015],
                  pos=[0.012, 0, 0.014], mass=_MOTOR_MASS, rgba=[0.15, 0.15, 0.15, 1],
                  group=GROUP_COLLISION)
    top = base.add_body(name=f"{finger}_link0", pos=[0, 0, 0.01425], quat=quat_euler(z=math.pi))
    _hinge(top, joints[0], (0, 1, 0), _JOINT_RANGE["top"])
    top.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(_MOTOR_BOX), pos=[0, 0, 0.056],
                 mass=_MOTOR_MASS, rgba=[0.15, 0.15, 0.15, 1], group=GROUP_COLLISION)
    mid = top.add_body(name=f"{finger}_link1", pos=[0, 0, 0.0675])
    _hinge(mid, joints[1], (1, 0, 0), _JOINT_RANGE["middle"])
    mid.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(_MOTOR_BOX), pos=[0, 0, 0.056],
                 mass=_MOTOR_MASS, rgba=[0.2, 0.2, 0.2, 1], group=GROUP_COLLISION)
    tip = mid.add_body(name=f"{finger}_link2", pos=[0, 0, 0.068])
    _hinge(tip, joints[2], (1, 0, 0), _JOINT_RANGE["bottom"])
    tip.add_geom(name=f"{finger}_tip_geom", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                 size=[0.011, 0.02, 0], pos=[0, 0, 0.053], mass=0.018 + 0.012,
                 friction=list(_TIP_FRICTION), rgba=[0.9, 0.9, 0.9, 1], group=GROUP_COLLISION)
    tip.add_site(name=f"{finger}_tip", pos=[0, 0, 0.076], size=[0.005, 0, 0])


def _hinge(body: mujoco.MjsBody, name: str, axis: tuple[float, float, float],
           rng: tuple[float, float]) -> None:
    j = body.add_joint(name=name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis))
    j.range = list(rng)
    j.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    j.damping[0] = 0.02  # gear viscous friction; back-EMF damping comes from the servo
    j.armature = 0.0     # the servo adds its reflected rotor inertia


def _add_valve(spec: mujoco.MjSpec, g: ValveGeometry) -> None:
    station = spec.worldbody.add_body(name="valve_station", pos=[0, 0, 0.0001])
    station.add_geom(name="valve_motor_box", type=mujoco.mjtGeom.mjGEOM_BOX,
                     size=[0.01425, 0.02325, 0.017], pos=[0, 0, 0.027], mass=0.082,
                     rgba=[0.15, 0.15, 0.15, 1], group=GROUP_COLLISION)
    valve = station.add_body(name="valve_body", pos=[0, 0, 0.048])
    j = valve.add_joint(name="valve", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
    j.damping[0] = g.damping
    j.frictionloss = g.frictionloss
    j.armature = 0.001
    if g.limited:
        j.range = [-2 * math.pi, 2 * math.pi]
        j.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    else:
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    contact = dict(friction=[g.friction, 0.005, 0.0001], solref=list(g.solref),
                   solimp=[*g.solimp, 0.5, 2.0], group=GROUP_COLLISION)
    valve.add_geom(name="valve_hub", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.02, 0.0275, 0],
                   pos=[0, 0, 0.027], mass=0.03, rgba=[0.8, 0.5, 0.2, 1], **contact)
    for k in range(g.spokes):
        a = g.spoke_phase + 2 * math.pi * k / g.spokes
        c = g.spoke_center
        valve.add_geom(
            name=f"valve_spoke{k}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            size=[g.spoke_radius, g.spoke_half_length, 0],
            pos=[c * math.cos(a), c * math.sin(a), 0.054],
            quat=_radial_quat(a),
            mass=0.02, rgba=[0.2, 0.6, 0.9, 1] if k else [0.9, 0.3, 0.2, 1], **contact)
    # Goal marker: a mocap arrow the env turns to the goal angle.
    target = spec.worldbody.add_body(name="target", mocap=True, pos=[0, 0, 0.16])
    visual_only(target.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.004, 0.04, 0],
                                pos=[0.04, 0, 0], quat=quat_euler(y=math.pi / 2),
                                rgba=[0.1, 0.9, 0.1, 0.6]))


def _radial_quat(angle: float) -> list[float]:
    """Orientation of a horizontal capsule pointing radially at ``angle`` [rad] about z."""
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, np.array(quat_euler(z=angle)), np.array(quat_euler(y=math.pi / 2)))
    return out.tolist()


BLOCK_HALF = 0.025  # [m] half edge of the flip block
TABLE_HEIGHT = 0.1  # [m] top of the table the block rests on (module doc: fingertip reach)
# [m] wider than the fingers can push the block (tips reach ~0.15 m from the axis), so the block
# never falls off and needs no pick-up between episodes
TABLE_HALF_WIDTH = 0.2
BLOCK_CENTER = (0.0, 0.0, TABLE_HEIGHT + BLOCK_HALF)  # [m] resting position on the table


def _add_block(spec: mujoco.MjSpec) -> None:
    spec.worldbody.add_geom(name="platform", type=mujoco.mjtGeom.mjGEOM_BOX,
                            size=[TABLE_HALF_WIDTH, TABLE_HALF_WIDTH, TABLE_HEIGHT / 2],
                            pos=[0, 0, TABLE_HEIGHT / 2],
                            rgba=[0.5, 0.4, 0.3, 1],
                            friction=[0.6, 0.005, 0.0001], group=GROUP_COLLISION)
    block = spec.worldbody.add_body(name="block", pos=list(BLOCK_CENTER))
    block.add_freejoint(name="block")
    h = BLOCK_HALF
    block.add_geom(name="block_geom", type=mujoco.mjtGeom.mjGEOM_BOX, size=[h, h, h], mass=0.05,
                   friction=[1.0, 0.005, 0.0001], rgba=[0.9, 0.7, 0.2, 1], group=GROUP_COLLISION)
    # A coloured face marks "up" so a flip is visible.
    visual_only(block.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[h * 0.8, h * 0.8, 0.001],
                               pos=[0, 0, h], rgba=[0.8, 0.1, 0.1, 1]))
    for k in range(8):
        sx, sy, sz = (1 if k & 1 else -1), (1 if k & 2 else -1), (1 if k & 4 else -1)
        block.add_site(name=f"block_corner{k}", pos=[sx * h, sy * h, sz * h], size=[0.003, 0, 0])
