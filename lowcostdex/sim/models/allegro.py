"""The Allegro Hand v4 (right) from primitives, palm up under a valve (BAIR's Allegro valve task).

Kinematics follow the right hand of ``allegro_hand_description`` (Wonik/SimLab's URDF, the frames
also used by MuJoCo Menagerie's ``wonik_allegro``), in the palm frame: fingers point along +z,
they flex towards +x (the palm's front), the index finger is at +y and the thumb sits low on the
+y side.

  finger (index, middle, ring)    base at (0, +-0.0435, -0.001542) rolled -+5 deg about x
                                  (middle at (0, 0, 0.0007), not rolled);
    joint 0  about z (along the finger), at the base        range -0.47 .. 0.47
    joint 1  about y, 0.0164 further                        range -0.196 .. 1.61
    joint 2  about y, 0.054 further (proximal link)         range -0.174 .. 1.709
    joint 3  about y, 0.0384 further (medial link)          range -0.227 .. 1.618
    tip      capsule r 0.012, half-length 0.01 at 0.019 on the distal link (end at 0.041)
  thumb   base at (-0.0182, 0.019333, -0.045987), quat (0.477714, -0.521334, -0.521334, -0.477714)
    joint 0  about -x                                       range 0.263 .. 1.396
    joint 1  about z, at (-0.027, 0.005, 0.0399)            range -0.105 .. 1.163
    joint 2  about y, 0.0177 further                        range -0.189 .. 1.644
    joint 3  about y, 0.0514 further                        range -0.162 .. 1.719
    tip      capsule r 0.012, half-length 0.008 at 0.035 on the distal link (end at 0.055)
  palm    box, half sizes (0.0204, 0.0565, 0.0475) centred at (-0.0093, 0, -0.0475).

Joint ranges are the hand spec's (``lowcostdex.hands.allegro_spec``, the same URDF). Link
masses are the URDF's for the fingers (0.0119, 0.065, 0.0355, 0.0096 kg, tip 0.0168 kg); the
thumb's (0.0176, 0.0119, 0.038, 0.0388 kg) are approximate. Links collide as capsules; the hand is
fixed (mounted), so the palm carries no free mass.

Actuation. The v4 hand is torque-driven: the host runs a joint PD at 333 Hz and sends
``pwm = tau * 1200`` clamped per joint (``TORQUE_LIMITS`` = PWM clamp / 1200: roll 375, near 675,
middle 450, far 285; thumb 525, 405, 270, 270 counts; simlabrobotics/allegro_hand_ros_v4 driver).
In simulation every joint has a ``position`` actuator (kp, kv) with that force range: the host PD
integrated at the physics step (2.5 ms, ~400 Hz instead of 333 Hz).

Gains. The v4 ROS package's PD controller (simlabrobotics/allegro_hand_ros_v4 @b19b18e,
allegro_hand_controllers/src/allegro_node_pd.cpp) takes ``k_p`` / ``k_d`` in PWM counts per rad
and per rad/s (its torque is ``(k_p err - k_d qdot) / 1200`` N m, sent at 1200 counts per N m).
Its launch file (allegro_hand_controllers/launch/allegro_hand.launch) always loads
``gains_pd.yaml``: kp 4000 on every joint (3.33 N m/rad), kd 150 (200 for joint 1, 300 for thumb
joint 0), ``AllegroPD.ros_launch()``; the node's compiled-in fallback, used only without the
yaml, is kp 600 (1000 for the finger distal joints and thumb joints 0-2, 600 for the thumb
distal joint), kd 15 (20 for joint 1, 30 for thumb joint 0), ``AllegroPD.ros_fallback()`` (the
launch file's default controller, ``grasp``, is libBHand's, gains not published). The
``AllegroPD`` defaults are neither: they are the fallback simplified to two sets, kp 600 / 1000
and kd 15 / 30 (0.5 / 0.83 N m/rad, 0.0125 / 0.025 N m s/rad; the second set on the distal and
thumb joints), so they differ from it on thumb_3's kp (1000, not 600) and on kd of joint 1 of
index/middle/ring (15, not 20), of the four distal joints (30, not 15) and of thumb joints 1-2
(30, not 20). The valve teacher was tuned on them: with the exact fallback its fixed-valve first
success moves from step 65 to 85 and the random valve succeeds in 5 of seeds 0-5 instead of 6;
with the launch gains (4-6.7x stiffer) step 96 and 5 of 6 (bench/RESULTS.md, 2026-11-26).
Joint damping, dry friction and reflected motor inertia are not published: ``AllegroPD`` carries
plausible values [uncertain].

Station "valve": a 3-spoke valve on a free (unlimited) vertical hinge above the palm, so turning
it 360 deg is an unwrapped angle of 2 pi. Names: joints and actuators are the hand spec's
(``index_0`` ... ``thumb_3``); the valve hinge is ``valve``; fingertip sites are ``<finger>_tip``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice
from lowcostdex.hands import ALLEGRO_FINGERS, HandSpec, allegro_spec
from lowcostdex.sim.models.common import GROUP_COLLISION, add_floor, new_spec, visual_only

ALLEGRO_STATIONS = ("valve", "none")
TORQUE_TO_PWM = 1200.0  # v4 torque constant [PWM counts per N m]
_PWM_LIMITS = {"finger": (375, 675, 450, 285), "thumb": (525, 405, 270, 270)}
TORQUE_LIMITS = {k: tuple(p / TORQUE_TO_PWM for p in v) for k, v in _PWM_LIMITS.items()}  # [N m]
# Host PD gains of the v4 ROS PD controller, joints j00..j33 (index, middle, ring, thumb) [PWM
# counts per rad, per rad/s]: the compiled-in fallback (allegro_node_pd.cpp) and the launched
# gains_pd.yaml (simlabrobotics/allegro_hand_ros_v4 @b19b18e). The three fingers share one set.
ROS_FALLBACK_KP = (600.0, 600.0, 600.0, 1000.0) * 3 + (1000.0, 1000.0, 1000.0, 600.0)
ROS_FALLBACK_KD = (15.0, 20.0, 15.0, 15.0) * 3 + (30.0, 20.0, 20.0, 15.0)
ROS_LAUNCH_KP = (4000.0,) * 16
ROS_LAUNCH_KD = (150.0, 200.0, 150.0, 150.0) * 3 + (300.0, 200.0, 200.0, 150.0)

# Palm pose in the world: palm normal (+x) up, fingers (+z) along world +x, palm +y to world -y.
PALM_POS = (0.0, 0.0, 0.1)  # [m] finger-base line
_PALM_QUAT = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))  # (w, x, y, z): pi about (x + z)

_FINGER_BASES = {  # palm-frame base position and roll about x [rad]
    "index": ((0.0, 0.0435, -0.001542), -math.radians(5)),
    "middle": ((0.0, 0.0, 0.0007), 0.0),
    "ring": ((0.0, -0.0435, -0.001542), math.radians(5)),
}
_FINGER_LINKS = (0.0164, 0.054, 0.0384)  # joint 0 -> 1 -> 2 -> 3 distances along z [m]
_FINGER_TIP = (0.012, 0.01, 0.019)  # capsule radius, half-length, centre along z [m]
_FINGER_MASSES = (0.0119, 0.065, 0.0355, 0.0096 + 0.0168)  # [kg] links 0..3 (+ tip)
_THUMB_BASE = ((-0.0182, 0.019333, -0.045987), (0.477714, -0.521334, -0.521334, -0.477714))
_THUMB_J1 = (-0.027, 0.005, 0.0399)  # joint 0 -> joint 1 offset [m]
_THUMB_LINKS = (0.0177, 0.0514)  # joint 1 -> 2 -> 3 distances along z [m]
_THUMB_TIP = (0.012, 0.008, 0.035)
_THUMB_MASSES = (0.0176, 0.0119, 0.038, 0.0388)  # [kg] approximate
_LINK_RADIUS = 0.0115  # [m] collision capsule radius of the proximal and medial links


def _per_finger(counts: tuple[float, ...]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """16 PWM-count gains j00..j33 -> (fingers' 4, thumb's 4) in SI (over 1200 counts per N m);
    the three fingers must share one set."""
    si = tuple(c / TORQUE_TO_PWM for c in counts)
    if not si[0:4] == si[4:8] == si[8:12]:
        raise ConfigError("the Allegro's three fingers share one set of gains")
    return si[0:4], si[12:16]


@dataclass(frozen=True)
class AllegroPD:
    """Joint PD of the torque-driven hand and the joints' passive dynamics (all 16 joints).

    Attributes:
      kp: stiffness [N m/rad] of joints 0-3, (fingers (index, middle, ring), thumb).
      kd: damping [N m s/rad], same layout.
      damping: passive joint viscous damping [N m s/rad] [uncertain].
      frictionloss: passive joint dry friction [N m] [uncertain].
      armature: reflected motor inertia [kg m^2] [uncertain].
      torque_scale: multiplies the firmware torque limits (1 = the v4 driver's PWM clamps).
    """

    kp: tuple[tuple[float, ...], tuple[float, ...]] = (
        (600 / TORQUE_TO_PWM,) * 3 + (1000 / TORQUE_TO_PWM,), (1000 / TORQUE_TO_PWM,) * 4)
    kd: tuple[tuple[float, ...], tuple[float, ...]] = (
        (15 / TORQUE_TO_PWM,) * 3 + (30 / TORQUE_TO_PWM,), (30 / TORQUE_TO_PWM,) * 4)
    damping: float = 0.01
    frictionloss: float = 0.005
    armature: float = 2e-4
    torque_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("kp", "kd"):
            value = getattr(self, name)
            if (len(value) != 2 or any(len(v) != 4 for v in value)
                    or min(min(v) for v in value) < 0):
                raise ConfigError(f"AllegroPD.{name} must be two 4-tuples (fingers, thumb) >= 0")
        for name in ("damping", "frictionloss", "armature"):
            if getattr(self, name) < 0:
                raise ConfigError(f"AllegroPD.{name} must be >= 0")
        if not self.torque_scale > 0:
            raise ConfigError("AllegroPD.torque_scale must be > 0")

    @classmethod
    def ros_fallback(cls, **kwargs) -> AllegroPD:
        """The v4 ROS PD controller's compiled-in gains (used when gains_pd.yaml is not loaded)."""
        return cls(kp=_per_finger(ROS_FALLBACK_KP), kd=_per_finger(ROS_FALLBACK_KD), **kwargs)

    @classmethod
    def ros_launch(cls, **kwargs) -> AllegroPD:
        """The gains the v4 ROS package launches its PD controller with (gains_pd.yaml)."""
        return cls(kp=_per_finger(ROS_LAUNCH_KP), kd=_per_finger(ROS_LAUNCH_KD), **kwargs)

    def gains(self, finger: str, joint: int) -> tuple[float, float]:
        """(kp, kd) of one joint (0-3) of a finger."""
        i = 1 if finger == "thumb" else 0
        return self.kp[i][joint], self.kd[i][joint]


@dataclass(frozen=True)
class AllegroValve:
    """The valve above the palm.

    Attributes:
      center: (x, y) of the hinge axis in the world [m] (the palm's finger-base line is x = 0).
      height: spoke axis height above the palm's finger-base line [m].
      spokes: number of spokes.
      spoke_length: hub-to-spoke-end distance (capsule end) [m].
      spoke_radius: capsule radius [m].
      damping: hinge damping [N m s/rad]; frictionloss: hinge dry friction [N m].
      friction: sliding friction of the valve geoms.
    """

    center: tuple[float, float] = (0.06, 0.0)
    height: float = 0.08
    spokes: int = 3
    spoke_length: float = 0.075
    spoke_radius: float = 0.01
    damping: float = 0.02
    frictionloss: float = 0.005
    friction: float = 1.0

    def __post_init__(self) -> None:
        if self.spokes < 2:
            raise ConfigError("AllegroValve.spokes must be >= 2")
        if not self.spoke_length > 2 * self.spoke_radius:
            raise ConfigError("AllegroValve.spoke_length must exceed the spoke diameter")


def build_allegro(station: str = "valve", hand: HandSpec | None = None,
                  pd: AllegroPD | None = None, valve: AllegroValve | None = None,
                  fingers: Sequence[str] = ALLEGRO_FINGERS) -> mujoco.MjSpec:
    """Build the palm-up Allegro scene as an MjSpec (compile with ``spec.compile()``).

    Args:
      station: one of ALLEGRO_STATIONS.
      hand: the hand spec (joint names and ranges); default ``allegro_spec()``.
      pd: joint PD gains, torque limits and passive joint dynamics (default ``AllegroPD()``).
      valve: valve geometry (station "valve"; default ``AllegroValve()``).
      fingers: the fingers to build (a subset of ``ALLEGRO_FINGERS``, in any order; default all
        four). A model of the fingers an identification log moved is what ``lowcostdex gap
        analyze`` replays (the log commands only those actuators).
    """
    check_choice("Allegro station", station, ALLEGRO_STATIONS)
    hand = hand or allegro_spec()
    pd = pd or AllegroPD()
    valve = valve or AllegroValve()
    if len(hand.joints) != 16:
        raise ConfigError(f"the Allegro has 16 joints, the spec has {len(hand.joints)}")
    if isinstance(fingers, str) or not fingers:
        raise ConfigError(f"fingers must be a non-empty sequence of {', '.join(ALLEGRO_FINGERS)}"
                          f"; got {fingers!r}")
    for f in fingers:
        check_choice("Allegro finger", f, ALLEGRO_FINGERS)
    if len(set(fingers)) != len(fingers):
        raise ConfigError(f"fingers lists a finger twice: {list(fingers)}")
    built = tuple(f for f in ALLEGRO_FINGERS if f in fingers)
    spec = new_spec(f"allegro_{station}")
    spec.option.noslip_iterations = 0  # position actuators; no servo holding against friction
    add_floor(spec)
    spec.worldbody.add_camera(name="front", pos=[0.07, -0.35, 0.3],
                              xyaxes=[1, 0, 0, 0, 0.55, 0.83])
    palm = spec.worldbody.add_body(name="palm", pos=list(PALM_POS), quat=list(_PALM_QUAT))
    palm.add_geom(name="palm_geom", type=mujoco.mjtGeom.mjGEOM_BOX,
                  size=[0.0204, 0.0565, 0.0475], pos=[-0.0093, 0, -0.0475],
                  rgba=[0.2, 0.2, 0.2, 1], group=GROUP_COLLISION)
    joints = {f: [j for j in hand.joints if j.name.startswith(f + "_")] for f in ALLEGRO_FINGERS}
    for finger in built:
        if finger == "thumb":
            _add_thumb(palm, joints[finger], pd)
        else:
            _add_finger(palm, finger, joints[finger], pd)
    for finger in built:
        limits = TORQUE_LIMITS["thumb" if finger == "thumb" else "finger"]
        for k, j in enumerate(joints[finger]):
            kp, kd = pd.gains(finger, k)
            act = spec.add_actuator()
            act.name = j.name
            act.target = j.name
            act.trntype = mujoco.mjtTrn.mjTRN_JOINT
            act.set_to_position(kp=kp, kv=kd)
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.ctrlrange = [j.low, j.high]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            tau = limits[k] * pd.torque_scale
            act.forcerange = [-tau, tau]
    # The palm and the first links of the fingers overlap at the knuckles.
    for finger in built:
        spec.add_exclude(bodyname1="palm", bodyname2=f"{finger}_link0")
    if "thumb" in built:
        spec.add_exclude(bodyname1="palm", bodyname2="thumb_link1")
    if station == "valve":
        _add_valve(spec, valve)
    return spec


def _hinge(body: mujoco.MjsBody, joint, axis: tuple[float, float, float], pd: AllegroPD) -> None:
    j = body.add_joint(name=joint.name, type=mujoco.mjtJoint.mjJNT_HINGE, axis=list(axis))
    j.range = [joint.low, joint.high]
    j.limited = mujoco.mjtLimited.mjLIMITED_TRUE
    j.damping[0] = pd.damping
    j.frictionloss = pd.frictionloss
    j.armature = pd.armature


def _capsule(body: mujoco.MjsBody, length: float, mass: float, radius: float = _LINK_RADIUS,
             name: str | None = None, center: float | None = None,
             rgba: tuple[float, ...] = (0.2, 0.2, 0.2, 1.0)) -> mujoco.MjsGeom:
    """A capsule along the body's z axis from 0 to ``length`` (or centred at ``center``)."""
    half = max(length / 2 - radius, 1e-4) if center is None else length
    z = length / 2 if center is None else center
    geom = body.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[radius, half, 0],
                         pos=[0, 0, z], mass=mass, rgba=list(rgba), group=GROUP_COLLISION)
    if name:
        geom.name = name
    return geom


def _add_finger(palm: mujoco.MjsBody, finger: str, joints, pd: AllegroPD) -> None:
    (pos, roll) = _FINGER_BASES[finger]
    quat = [math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0]
    body = palm.add_body(name=f"{finger}_link0", pos=list(pos), quat=quat)
    _hinge(body, joints[0], (0, 0, 1), pd)
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.0098, 0.01375, 0.0082],
                  pos=[0, 0, 0.0082], mass=_FINGER_MASSES[0], rgba=[0.2, 0.2, 0.2, 1],
                  group=GROUP_COLLISION)
    for k, length in enumerate(_FINGER_LINKS):
        body = body.add_body(name=f"{finger}_link{k + 1}", pos=[0, 0, length])
        _hinge(body, joints[k + 1], (0, 1, 0), pd)
        if k < 2:
            _capsule(body, _FINGER_LINKS[k + 1], _FINGER_MASSES[k + 1])
    r, half, z = _FINGER_TIP
    _capsule(body, half, _FINGER_MASSES[3], radius=r, name=f"{finger}_tip_geom", center=z,
             rgba=(0.9, 0.9, 0.9, 1.0))
    body.add_site(name=f"{finger}_tip", pos=[0, 0, z + half + r], size=[0.004, 0, 0])


def _add_thumb(palm: mujoco.MjsBody, joints, pd: AllegroPD) -> None:
    pos, quat = _THUMB_BASE
    body = palm.add_body(name="thumb_link0", pos=list(pos), quat=list(quat))
    _hinge(body, joints[0], (-1, 0, 0), pd)
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.0179, 0.017, 0.02275],
                  pos=[-0.0179, 0.009, 0.0145], mass=_THUMB_MASSES[0], rgba=[0.2, 0.2, 0.2, 1],
                  group=GROUP_COLLISION)
    body = body.add_body(name="thumb_link1", pos=list(_THUMB_J1))
    _hinge(body, joints[1], (0, 0, 1), pd)
    _capsule(body, _THUMB_LINKS[0], _THUMB_MASSES[1])
    body = body.add_body(name="thumb_link2", pos=[0, 0, _THUMB_LINKS[0]])
    _hinge(body, joints[2], (0, 1, 0), pd)
    _capsule(body, _THUMB_LINKS[1], _THUMB_MASSES[2])
    body = body.add_body(name="thumb_link3", pos=[0, 0, _THUMB_LINKS[1]])
    _hinge(body, joints[3], (0, 1, 0), pd)
    r, half, z = _THUMB_TIP
    _capsule(body, half, _THUMB_MASSES[3], radius=r, name="thumb_tip_geom", center=z,
             rgba=(0.9, 0.9, 0.9, 1.0))
    body.add_site(name="thumb_tip", pos=[0, 0, z + half + r], size=[0.004, 0, 0])


def _add_valve(spec: mujoco.MjSpec, v: AllegroValve) -> None:
    """A spoked valve hanging from a post beside the hand, turning about the vertical."""
    top = PALM_POS[2] + v.height
    post = spec.worldbody.add_body(name="valve_mount", pos=[v.center[0], v.center[1], top])
    post.add_geom(name="valve_post", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                  size=[0.006, 0.05, 0], pos=[0, 0, 0.07], rgba=[0.5, 0.5, 0.5, 1],
                  group=GROUP_COLLISION)
    body = post.add_body(name="valve_body")
    j = body.add_joint(name="valve", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
    j.damping[0] = v.damping
    j.frictionloss = v.frictionloss
    j.armature = 1e-4
    j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
    contact = dict(friction=[v.friction, 0.005, 0.0001], group=GROUP_COLLISION)
    body.add_geom(name="valve_hub", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                  size=[0.015, 0.012, 0], pos=[0, 0, 0.0], mass=0.02,
                  rgba=[0.8, 0.5, 0.2, 1], **contact)
    half = (v.spoke_length - v.spoke_radius) / 2
    for k in range(v.spokes):
        a = 2 * math.pi * k / v.spokes
        c = half + 0.0
        body.add_geom(name=f"valve_spoke{k}", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                      size=[v.spoke_radius, half, 0],
                      pos=[c * math.cos(a), c * math.sin(a), 0.0],
                      quat=_radial_quat(a), mass=0.01,
                      rgba=[0.2, 0.6, 0.9, 1] if k else [0.9, 0.3, 0.2, 1], **contact)
    target = spec.worldbody.add_body(name="target", mocap=True, pos=[v.center[0], v.center[1],
                                                                     top + 0.13])
    visual_only(target.add_geom(type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=[0.004, 0.04, 0],
                                pos=[0.04, 0, 0], quat=_radial_quat(0.0),
                                rgba=[0.1, 0.9, 0.1, 0.6]))


def _radial_quat(angle: float) -> list[float]:
    """Orientation of a horizontal capsule pointing radially at ``angle`` [rad] about z."""
    out = np.zeros(4)
    qz = np.array([math.cos(angle / 2), 0, 0, math.sin(angle / 2)])
    qy = np.array([math.cos(math.pi / 4), 0, math.sin(math.pi / 4), 0])
    mujoco.mju_mulQuat(out, qz, qy)
    return out.tolist()
