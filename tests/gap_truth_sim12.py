"""A twelfth independent truth simulator for the gap analysis: a user's low-cost GRIPPER whose jaw
runs on a SLIDE (prismatic) joint in metres, with a finger on a hinge riding on the jaw, logged
while it closes on a clamped object and presses its fingertip on the table (issue 11; gap-sim15,
session 27).

Written with mujoco, numpy and the stdlib only (and the sets' one grader, tests/redteam_grade.py),
importing nothing from lowcostdex (no effect, plant, servo or gap code). The eleven earlier sets
have hinge joints only and no log in which the robot touches anything.

The rig (``model_xml``, the user's MJCF): ``grip`` is a horizontal slide along +x (no gravity
along it) moving a jaw carriage of 120 g; a linear servo or a rack drives it, written by the user
as ``<position kp="2500" forcerange="-40 40">`` (N/m, N) on a joint with ``armature`` 0.35 kg (the
rotor's reflected mass), ``damping`` 40 N s/m and ``frictionloss`` 1 N. The jaw's pad closes on a
block clamped in the user's fixture (a world geom in the MJCF) when ``grip`` reaches 35 mm.
``finger`` is a hinge about +y on the jaw, a 100 g finger whose centre of mass is 35 mm out
(positive angles lower it: gravity pulls toward +q, 34 mN m level); ``<position kp="3"
forcerange="-1 1">`` on ``armature`` 0.002 kg m^2, ``damping`` 0.05 N m s/rad, ``frictionloss``
0.01 N m. Its fingertip presses on the table top (also in the MJCF) from 0.680 rad on. Contacts
use ``solref`` 6 ms, ``solimp`` MuJoCo's default, in the user's model and in the truth alike: the
contact forces are modelled, not a hidden effect.

The truth runs at 0.25 ms (the user's model at 2 ms) and drives ``motor`` actuators with the
servos' law computed here every step: F = clip(gain kp (u - s), -F_max, F_max), u the goal that
has arrived, s the servo's own reading of its motor side. The user's host loop (100 Hz, +-10 %
jitter) reads both sensors and writes both goals right after: the slide through a 12-bit
potentiometer over 50 mm (12.2 um per count, 8 um of noise), the finger through a 4096-tick
encoder (0.4 mrad of noise). Logged as docs/gap_analysis.md says: CSV ``time`` [s], ``goal:grip``
[m], ``goal:finger`` [rad], ``qpos:grip`` [m], ``qpos:finger`` [rad]; no velocity column.

Hidden effects (``Effect.kind``), each written here from its physics, in the joint's own units:

- ``latency``: every goal reaches both servos ``value`` s after its row.
- ``backlash``: a play of full width ``value`` (m on the slide, rad on the hinge) between the
  servo's motor side (armature, damping, the servo's force, the servo's own sensor: a rack's
  pinion) and the output (the jaw or the finger: its mass, its friction, its contacts), written as
  two joints held by a fixed tendon's limit; the log reads the output (a linear encoder on the
  jaw, an encoder on the finger's axle).
- ``gain``: the servo's kp is ``value`` times the model's.
- ``offset``: the servo's sensor reads q + ``value`` (the rack engaged one tooth off, a horn one
  spline off) and the servo holds that reading at the goal; the log reads the same sensor
  (``mounting_offset``). On the slide nothing but the clamped block shows it.
- ``friction``: the output's dry friction is ``value`` (N, N m) more than the model's (a
  dry rail, a cable dragging), MuJoCo's ``frictionloss``.

``write_case`` writes what a user brings (``model.xml``, ``logs/log<i>.csv``) and ``truth.json``
(``causes`` as catalogue names, ``expected_params``); ``score`` grades a report with
``redteam_grade.grade`` and ``FAMILIES``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np
import redteam_grade  # the red-team sets' one grader (tests/, no project imports)

TRUTH_DT = 0.00025                 # s
MODEL_DT = 0.002                   # s
SETTLE = 1.0                       # s held at the first goal before the logger starts
RATE = 100.0                       # Hz, the host loop
JOINTS = ("grip", "finger")
KP = {"grip": 2500.0, "finger": 3.0}          # N/m, N m/rad
FMAX = {"grip": 40.0, "finger": 1.0}          # N, N m
ARMATURE = {"grip": 0.35, "finger": 0.002}    # kg, kg m^2
DAMPING = {"grip": 40.0, "finger": 0.05}      # N s/m, N m s/rad
FRICTION = {"grip": 1.0, "finger": 0.01}      # N, N m
JAW_MASS, FINGER_MASS, FINGER_COM, TIP = 0.12, 0.10, 0.035, 0.07   # kg, kg, m, m
HINGE_Z, TIP_R = 0.05, 0.006       # m: the finger's axle above the table top, the tip's radius
PAD_X, BLOCK_FACE = 0.025, 0.060   # m: the pad's face ahead of the jaw, the block's face
CONTACT_GRIP = BLOCK_FACE - PAD_X  # 0.035 m: the jaw position where the pad meets the block
CONTACT_FINGER = math.asin((HINGE_Z - TIP_R) / TIP)   # 0.680 rad: the tip meets the table
LSB = {"grip": 0.05 / 4096, "finger": 2 * math.pi / 4096}   # m, rad per count
NOISE = {"grip": 8e-6, "finger": 4e-4}                       # m, rad before quantisation
FREE = {"grip": (0.003, 0.030), "finger": (-0.45, 0.50)}     # host targets away from contact
PRESS = {"grip": (0.037, 0.043), "finger": (0.74, 0.95)}     # targets past the contact
SOLREF = "0.006 1"

KINDS = ("latency", "backlash", "gain", "offset", "friction")
CATALOGUE = {"latency": "latency", "backlash": "backlash", "gain": "gain_error",
             "offset": "mounting_offset", "friction": "coulomb_friction"}
PARAM = {"latency": "delay", "backlash": "width", "gain": "scale", "offset": "offset",
         "friction": "frictionloss"}
FAMILIES = (
    {"gain_error", "latency", "inertia_error", "mass_error", "viscous_damping"},
    {"velocity_limit", "torque_limit", "gain_error"},
    {"coulomb_friction", "stribeck_friction", "gearbox_friction", "load_dependent_friction",
     "backlash", "deadband"},
    {"position_offset", "mounting_offset", "mass_error", "sensor_scale"},
)


@dataclasses.dataclass(frozen=True)
class Effect:
    """Hidden effect ``kind`` of size ``value`` (the joint's units) on ``joint`` (latency:
    both servos)."""

    kind: str
    value: float
    joint: str = "grip"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {', '.join(KINDS)}")
        if self.joint not in JOINTS:
            raise ValueError(f"unknown joint {self.joint!r}; valid: {', '.join(JOINTS)}")

    @property
    def joints(self) -> tuple[str, ...]:
        return JOINTS if self.kind == "latency" else (self.joint,)


@dataclasses.dataclass(frozen=True)
class Case:
    """Hidden ``effects``; logs of ``durations`` s, 40 % of each log's goal levels pressing on
    the block and the table unless ``contact`` is False; ``seed`` for targets, jitter, noise."""

    name: str
    effects: tuple[Effect, ...] = ()
    durations: tuple[float, ...] = (6.0, 6.0, 6.0, 6.0)
    seed: int = 0
    contact: bool = True
    note: str = ""
    rig: str = "gripper"
    rate: float = RATE
    qvel: bool = False

    def get(self, kind: str, joint: str) -> float | None:
        return next((e.value for e in self.effects if e.kind == kind and joint in e.joints),
                    None)

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects}


def _joint(name: str, axis: str, rng_: str, *, friction: float, rotor: bool) -> str:
    """The joint ``name``: on the motor side (``rotor``) the armature and damping, on the output
    its friction; both when there is no play."""
    base = name.removesuffix("_rotor")
    kind = "slide" if base == "grip" else "hinge"
    attrs = f'name="{name}" type="{kind}" axis="{axis}" range="{rng_}" limited="true"'
    if rotor:
        attrs += f' armature="{ARMATURE[base]}" damping="{DAMPING[base]}"'
    if friction:
        attrs += f' frictionloss="{friction:.6g}"'
    return f"<joint {attrs}/>"


def _finger_geoms() -> str:
    return (f'<geom type="capsule" fromto="0 0 0 {TIP - 0.005} 0 0" size="0.005" contype="0" '
            f'conaffinity="0" mass="0"/>'
            f'<geom name="tip" type="sphere" pos="{TIP} 0 0" size="{TIP_R}" contype="2" '
            f'conaffinity="0" mass="0"/>'
            f'<inertial pos="{FINGER_COM} 0 0" mass="{FINGER_MASS}" '
            f'diaginertia="1e-6 4e-5 4e-5"/>')


def model_xml(case: Case | None = None, timestep: float = MODEL_DT, truth: bool = False) -> str:
    """The user's MJCF (``truth`` False: position actuators, one joint per servo) or the truth's
    (``motor`` actuators whose force ``simulate`` computes, a motor-side joint and a tendon's
    play where ``case`` hides a backlash, the extra friction)."""
    case = case or Case("nominal")
    play = {j: (case.get("backlash", j) if truth else None) for j in JOINTS}
    fric = {j: FRICTION[j] + ((case.get("friction", j) or 0.0) if truth else 0.0) for j in JOINTS}
    rng = {"grip": "-0.002 0.05", "finger": "-0.6 1.2"}
    axis = {"grip": "1 0 0", "finger": "0 1 0"}
    pad = ('<geom name="pad" type="box" pos="0.02 0.03 0" size="0.005 0.01 0.01" contype="1" '
           'conaffinity="0" mass="0"/>')

    def servo(j: str, inner: str, body_pos: str, own_mass: str) -> str:
        if play[j] is None:
            joint = _joint(j, axis[j], rng[j], friction=fric[j], rotor=True)
            return f'<body name="{j}_out" pos="{body_pos}">{joint}{own_mass}{inner}</body>'
        # the motor side: its own body (a sliver of mass), armature, damping; the output beside it
        rotor = _joint(j + "_rotor", axis[j], rng[j], friction=0.0, rotor=True)
        joint = _joint(j, axis[j], rng[j], friction=fric[j], rotor=False)
        return (f'<body name="{j}_rotor" pos="{body_pos}">{rotor}<inertial pos="0 0 0" '
                f'mass="1e-4" diaginertia="1e-8 1e-8 1e-8"/></body>'
                f'<body name="{j}_out" pos="{body_pos}">{joint}{own_mass}{inner}</body>')

    finger = servo("finger", _finger_geoms(), "0 0 0", "")
    jaw = servo("grip", pad + finger, f"0 0 {HINGE_Z}",
                f'<inertial pos="0 0 0" mass="{JAW_MASS}" diaginertia="1e-4 1e-4 1e-4"/>')
    tendons = "".join(
        f'<fixed name="{j}_play" limited="true" range="{-play[j] / 2:.6g} {play[j] / 2:.6g}" '
        f'solreflimit="0.001 1"><joint joint="{j}" coef="1"/>'
        f'<joint joint="{j}_rotor" coef="-1"/></fixed>'
        for j in JOINTS if play[j] is not None)
    if truth:
        acts = "".join(f'<motor name="{j}" joint="{j if play[j] is None else j + "_rotor"}" '
                       f'ctrlrange="{-FMAX[j]} {FMAX[j]}"/>' for j in JOINTS)
    else:
        lo = {"grip": "0 0.045", "finger": "-0.6 1.1"}
        acts = "".join(f'<position name="{j}" joint="{j}" kp="{KP[j]}" ctrlrange="{lo[j]}" '
                       f'forcerange="{-FMAX[j]} {FMAX[j]}"/>' for j in JOINTS)
    block_x = BLOCK_FACE + 0.01
    return f"""<mujoco model="gripper">
  <compiler angle="radian"/>
  <option timestep="{timestep}" gravity="0 0 -9.81"/>
  <default><geom solref="{SOLREF}" friction="0.6 0.005 0.0001"/></default>
  <worldbody>
    <geom name="table" type="box" pos="0.05 0 -0.01" size="0.2 0.1 0.01" contype="0"
          conaffinity="2"/>
    <geom name="block" type="box" pos="{block_x} 0.03 {HINGE_Z}" size="0.01 0.015 0.015"
          contype="0" conaffinity="1"/>
    {jaw}
  </worldbody>
  <tendon>{tendons}</tendon>
  <actuator>{acts}</actuator>
</mujoco>
"""


def host_times(duration: float, rng: np.random.Generator) -> np.ndarray:
    """The host loop's cycle times [s] from -SETTLE to ``duration``, 100 Hz +-10 % jitter."""
    n = int((duration + SETTLE) * RATE * 1.2) + 2
    t = np.concatenate([[0.0], np.cumsum((1.0 + rng.uniform(-0.1, 0.1, n)) / RATE)]) - SETTLE
    return t[t <= duration]


def targets(joint: str, press: bool, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The host's goals at times ``t``: levels held 0.4-1.0 s, reached by a step or a 0.2-0.5 s
    ramp, inside ``FREE``; with ``press``, 40 % of the levels past the contact (``PRESS``)."""
    edges = np.concatenate([[t[0]], np.cumsum(rng.uniform(0.4, 1.0, int(t[-1] / 0.4) + 3))])
    n = len(edges)
    levels = rng.uniform(*FREE[joint], n)
    if press:
        hit = rng.uniform(size=n) < 0.4
        hit[0] = False   # the log starts away from contact
        levels[hit] = rng.uniform(*PRESS[joint], int(hit.sum()))
    ramps = np.where(rng.uniform(size=n) < 0.5, 0.0, rng.uniform(0.2, 0.5, n))
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n - 1)
    prev = levels[np.maximum(k - 1, 0)]
    frac = np.where(ramps[k] > 0, np.clip((t - edges[k]) / np.maximum(ramps[k], 1e-9), 0, 1), 1)
    out = prev + (levels[k] - prev) * frac
    out[t < 0] = levels[0]
    return out


def servo_force(joint: str, goal: float, reading: float, gain: float = 1.0) -> float:
    """The servo's force [N or N m]: clip(gain kp (goal - reading), -F_max, F_max)."""
    return float(np.clip(gain * KP[joint] * (goal - reading), -FMAX[joint], FMAX[joint]))


def simulate(case: Case, t: np.ndarray, goals: dict[str, np.ndarray], rng: np.random.Generator,
             true_state: bool = False) -> dict[str, np.ndarray]:
    """Run the truth under the host loop's cycles ``t`` [s] writing ``goals`` (each written right
    after its read). Returns {"qpos:<j>": the logged readings, "goal:<j>"} per cycle, with
    ``true_state`` also "true:<j>" (the output) and "rotor:<j>" (the motor side)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case, TRUTH_DT, truth=True))
    d = mujoco.MjData(m)
    out_adr = {j: m.jnt_qposadr[m.joint(j).id] for j in JOINTS}
    rot_adr = {j: m.jnt_qposadr[m.joint(j + "_rotor").id] if case.get("backlash", j) else
               out_adr[j] for j in JOINTS}
    act = {j: m.actuator(j).id for j in JOINTS}
    gain = {j: case.get("gain", j) or 1.0 for j in JOINTS}
    off = {j: case.get("offset", j) or 0.0 for j in JOINTS}
    lat = case.get("latency", "grip") or 0.0
    # start at rest where the servo holds its first goal
    for j in JOINTS:
        q0 = goals[j][0] - off[j]
        d.qpos[out_adr[j]] = q0
        d.qpos[rot_adr[j]] = q0
    arrive = t + lat
    n_steps = int(math.ceil((t[-1] - t[0]) / TRUTH_DT)) + 1
    read_step = np.round((t - t[0]) / TRUTH_DT).astype(int)
    arrived = np.searchsorted(arrive, t[0] + np.arange(n_steps) * TRUTH_DT, side="right") - 1
    res = {f"{k}:{j}": np.zeros(len(t)) for k in ("qpos", "true", "rotor") for j in JOINTS}
    k = 0
    for i in range(n_steps):
        while k < len(t) and read_step[k] == i:
            for j in JOINTS:
                res[f"true:{j}"][k] = d.qpos[out_adr[j]]
                res[f"rotor:{j}"][k] = d.qpos[rot_adr[j]]
            k += 1
        g = max(arrived[i], 0)
        for j in JOINTS:
            d.ctrl[act[j]] = servo_force(j, goals[j][g], d.qpos[rot_adr[j]] + off[j], gain[j])
        mujoco.mj_step(m, d)
    for j in JOINTS:
        noisy = res[f"true:{j}"] + off[j] + rng.normal(0.0, NOISE[j], len(t))
        res[f"qpos:{j}"] = np.round(noisy / LSB[j]) * LSB[j]
        res[f"goal:{j}"] = goals[j]
    if not true_state:
        res = {key: v for key, v in res.items() if key.split(":")[0] in ("qpos", "goal")}
    return res


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml``, ``logs/log<i>.csv`` (seconds from 0, metres and radians; the logs
    press on the block and the table when ``case.contact``) and ``truth.json`` into
    ``folder``. Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml())
    rng = np.random.default_rng(case.seed)
    names = ["time"] + [f"{k}:{j}" for k in ("goal", "qpos") for j in JOINTS]
    for i, dur in enumerate(case.durations):
        t = host_times(dur, rng)
        cols = simulate(case, t, {j: targets(j, case.contact, t, rng) for j in JOINTS}, rng)
        keep = t >= 0.0
        data = np.column_stack([t[keep]] + [cols[n][keep] for n in names[1:]])
        np.savetxt(folder / "logs" / f"log{i}.csv", data, delimiter=",", header=",".join(names),
                   comments="", fmt=["%.5f"] + ["%.7g"] * (len(names) - 1))
    truth = {"case": case.name, "causes": sorted(case.causes),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": [str(folder / "logs")], "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Each hidden effect's catalogue parameter on its joint(s), in the joint's units."""
    return [dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=j, value=e.value)
            for e in case.effects for j in e.joints]


def score(report: dict, truth: dict) -> dict:
    """``redteam_grade.grade`` of ``report`` against ``truth`` with this set's FAMILIES."""
    return redteam_grade.grade(report, truth, FAMILIES)


def magnitudes(seed: int = 12) -> dict[str, float]:
    """The hidden effects' sizes, drawn once from a seeded generator over real-world ranges:
    a slide offset of 1.5-3 mm either way, a rack's play of 0.8-1.5 mm, 5-20 N of rail
    friction, a kp off by x0.5-0.7 or x1.5-2, 20-50 ms of latency, a finger offset of 0.06-0.12
    rad either way, 0.03-0.08 N m on the finger's axle, a finger play of 20-50 mrad."""
    r = np.random.default_rng(seed)
    sign = lambda: float(r.choice([-1.0, 1.0]))  # noqa: E731
    gain = lambda: float(r.uniform(0.5, 0.7) if r.uniform() < 0.5 else r.uniform(1.5, 2.0))  # noqa: E731
    return {
        "grip_offset": round(sign() * r.uniform(0.0015, 0.003), 5),
        "grip_backlash": round(r.uniform(0.0008, 0.0015), 5),
        "grip_friction": round(r.uniform(5.0, 20.0), 2),
        "grip_gain": round(gain(), 3),
        "latency": round(r.uniform(0.020, 0.050), 4),
        "finger_offset": round(sign() * r.uniform(0.06, 0.12), 4),
        "finger_friction": round(r.uniform(0.03, 0.08), 4),
        "finger_backlash": round(r.uniform(0.02, 0.05), 4),
        "finger_gain": round(gain(), 3),
    }


MAG = magnitudes()
E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_free", (), seed=1201, contact=False,
         note="no hidden effect, no contact"),
    Case("clean_contact", (), seed=1202,
         note="no hidden effect; the logs squeeze the block and press the table"),
    Case("grip_offset", (E("offset", MAG["grip_offset"], "grip"),), seed=1203,
         note="the slide's sensor zero off by mm: seen only where the jaw meets the block"),
    Case("grip_backlash", (E("backlash", MAG["grip_backlash"], "grip"),), seed=1204,
         note="a rack's play between the pinion (servo loop) and the jaw (logged)"),
    Case("grip_friction", (E("friction", MAG["grip_friction"], "grip"),), seed=1205,
         note="newtons of dry friction added on the jaw's rail"),
    Case("grip_gain", (E("gain", MAG["grip_gain"], "grip"),), seed=1206,
         note="the linear servo's kp off the model's"),
    Case("latency", (E("latency", MAG["latency"]),), seed=1207,
         note="goals reach both servos late"),
    Case("finger_offset", (E("offset", MAG["finger_offset"], "finger"),), seed=1208,
         note="the finger's encoder zero off (gravity and the table see the true angle)"),
    Case("finger_friction", (E("friction", MAG["finger_friction"], "finger"),), seed=1209,
         note="dry friction added on the finger's axle"),
    Case("finger_backlash", (E("backlash", MAG["finger_backlash"], "finger"),), seed=1210,
         note="a play between the finger's servo and the finger (logged on the finger)"),
    Case("grip_friction_finger_offset", (E("friction", MAG["grip_friction"], "grip"),
                                         E("offset", MAG["finger_offset"], "finger")),
         seed=1211, note="the pair: rail friction on the slide, the finger's zero off"),
)
CASE_BY_NAME = {c.name: c for c in CASES}
