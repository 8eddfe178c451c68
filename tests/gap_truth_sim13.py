"""A thirteenth independent truth simulator for the gap analysis: a user's low-cost UNDERACTUATED,
TENDON-driven finger, one servo pulling a cable that flexes three joints, the distal one coupled
to the middle one (issue 11; gap-sim17, session 28).

Written with mujoco, numpy and the stdlib only (and the sets' one grader, tests/redteam_grade.py),
importing nothing from lowcostdex (no effect, plant, servo or gap code). The twelve earlier sets
drive every joint through its own actuator; here no actuator acts on a joint.

The rig (``model_xml``, the user's MJCF): a finger lying along +x, three hinges about -y (positive
angles lift it, against gravity): ``mcp`` (proximal phalanx 45 mm, 30 g), ``pip`` (30 mm, 20 g),
``dip`` (25 mm, 15 g). Each joint has a return spring (``stiffness`` 0.10 / 0.056 / 0.03 N m/rad,
``springref`` -0.3 / -0.3 / -0.24 rad: pre-tensioned, so the springs always extend the finger),
``damping`` 0.01 / 0.006 / 0.003 N m s/rad and ``frictionloss`` 0.002 / 0.0015 / 0.001 N m.
``dip`` follows ``pip`` through an ``<equality><joint>`` (dip = 0.8 pip, a linkage). The flexor
cable runs over pulleys of 8 mm (mcp) and 6 mm (pip): the user writes it as a fixed tendon
``flex`` (coef 0.008, 0.006: its length in m of cable) with ``armature`` 0.2 kg and ``damping``
100 N s/m (the servo's rotor, 2e-5 kg m^2, and its 0.01 N m s/rad, seen through the 10 mm horn:
J / R^2, b / R^2), and the servo as ``<position tendon="flex" gear="100" kp="3"
forcerange="-0.5 0.5">``: gear 1 / R, so the goal is the servo's angle in rad (100 x metres of
cable) and kp, the force range are the servo's (N m/rad, N m at the horn).

The truth runs at 0.25 ms (the user's model at 2 ms). The servo is a horn joint of its own
(armature 2e-5 kg m^2, damping 0.01 N m s/rad) driven by a ``motor`` whose torque is the servo's
law computed here every step: tau = clip(gain kp (u - s), -tau_max, tau_max), u the goal that
has arrived, s the servo's own reading of its horn. The cable is a fixed tendon ``cable`` (0.008
mcp + 0.006 pip - 0.010 horn) limited to >= 0: it pulls (the tendon's limit holds it taut) but
never pushes (slack when the finger is flexed past the horn's reel; the springs keep it taut in
every log here). The host loop (100 Hz, +-10 % jitter) reads the three joints' magnetic encoders
(4096 ticks a turn, 0.4 mrad of noise) and writes the servo's goal right after. Logged as
docs/gap_analysis.md says: CSV ``time`` [s], ``goal:flex`` [rad, the servo's angle],
``qpos:mcp``, ``qpos:pip``, ``qpos:dip`` [rad]; no velocity column.

Hidden effects (``Effect.kind``), each written here from its physics:

- ``latency``: every goal reaches the servo ``value`` s after its row (``latency``, on flex).
- ``backlash``: a play of full width ``value`` rad (at the horn) between the servo's output
  shaft (its armature, damping, torque, its own encoder) and the horn the cable winds on (a worn
  spline): two joints held by a fixed tendon's limit (``backlash`` on flex).
- ``gain``: the servo's kp is ``value`` times the model's (``gain_error`` on flex).
- ``offset``: the mcp encoder reads q + ``value`` (a magnet glued off its zero); springs,
  gravity and the cable see the true angle (``position_offset`` on mcp).
- ``friction``: the pip joint's dry friction is ``value`` N m more than the model's (a tight
  pin), MuJoCo's ``frictionloss`` (``coulomb_friction`` on pip).
- ``mass``: the distal phalanx weighs ``value`` times the model's (a fingertip pad and sensor
  the user did not weigh; ``mass_error`` on dip).
- ``stretch`` (OUTSIDE the catalogue): the cable is elastic, ``value`` N/m (a nylon line): no
  limit holds it, a spring that only pulls (MuJoCo's tendon ``stiffness`` with a dead band
  ``springlength`` 0..1 m) carries the tension; the finger lags and sags under the springs'
  load, more the harder it is flexed.

The LINKAGE rig (``linkage_xml``, ``simulate_linkage``; ``Case.rig`` "linkage finger", cases
``link_*``): the same finger without springs, a servo on the mcp and one on the pip (the user's
``<position kp="2" / "1" forcerange="-0.5 0.5" / "-0.3 0.3">`` on joints with ``armature``
5e-4 / 3e-4 kg m^2, ``damping`` 0.02 / 0.01 N m s/rad, ``frictionloss`` 0.005 / 0.003 / 0.001 N
m), the dip on the pip through the same joint equality (an Inspire-like linkage finger). The
truth drives ``motor`` actuators with each servo's law on its own reading; the log has
``goal:mcp``, ``goal:pip`` and the three joints. Effects there: ``latency`` on both servos,
``backlash``, ``gain`` on the pip servo (a play between its rotor and the pip link), ``mount``
(the pip servo reads and holds q + ``value``: ``mounting_offset``; only the dip's encoder
through the linkage and gravity see it), ``friction`` on the pip, ``mass`` of the distal
phalanx (a joint without an actuator), a pair, and ``curve`` (OUTSIDE the catalogue: the
four-bar's dip = 0.8 pip + ``value`` pip^2 where the user's MJCF has the straight line).

``write_case`` writes what a user brings (``model.xml``, ``logs/log<i>.csv``) and ``truth.json``
(``causes`` as catalogue names, ``expected_params``; ``outside`` for the stretch); ``score``
grades a report with ``redteam_grade.grade`` and ``FAMILIES``.
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
JOINTS = ("mcp", "pip", "dip")
ACT = "flex"
LENGTH = {"mcp": 0.045, "pip": 0.030, "dip": 0.025}        # m
MASS = {"mcp": 0.030, "pip": 0.020, "dip": 0.015}          # kg
STIFF = {"mcp": 0.10, "pip": 0.056, "dip": 0.03}           # N m/rad
SPRINGREF = {"mcp": -0.3, "pip": -0.3, "dip": -0.24}       # rad
DAMPING = {"mcp": 0.003, "pip": 0.002, "dip": 0.001}        # N m s/rad
FRICTION = {"mcp": 0.002, "pip": 0.0015, "dip": 0.001}     # N m
ARM = {"mcp": 0.008, "pip": 0.006}                         # m, the cable's pulley radii
COUPLE = 0.8                       # dip = COUPLE x pip
HORN = 0.010                       # m, the servo horn's radius
KP, TMAX = 3.0, 0.5                # N m/rad, N m at the horn
ROTOR_J, ROTOR_B = 2e-5, 0.005     # kg m^2, N m s/rad at the horn
HORN_J = 2e-6                      # kg m^2: the horn's own share of ROTOR_J (beyond a play)
LSB = 2 * math.pi / 4096           # rad per count
NOISE = 4e-4                       # rad before quantisation
GOALS = (0.3, 1.5)                 # rad of servo angle: the host's range (joints off limits)
SOLREF, STIFF_IMP = "0.001 1", "0.999 0.9999 0.001"   # the cable's and the play's limits
LINK_SOLREF, LINK_SOLIMP = "0.005 1", "0.9999 0.9999 0.001"   # the dip-pip linkage (both)

# the LINKAGE rig: the same finger, a servo on the mcp and one on the pip (position actuators
# on their joints), no springs; the dip follows the pip through the same joint equality
SERVOS = ("mcp", "pip")
LKP = {"mcp": 2.0, "pip": 1.0}             # N m/rad
LTMAX = {"mcp": 0.5, "pip": 0.3}           # N m
LARM = {"mcp": 5e-4, "pip": 3e-4}          # kg m^2, the servos' rotors
LDAMP = {"mcp": 0.02, "pip": 0.01}         # N m s/rad
LFRIC = {"mcp": 0.005, "pip": 0.003, "dip": 0.001}   # N m
LGOALS = {"mcp": (0.0, 1.2), "pip": (0.0, 1.3)}       # rad

KINDS = ("latency", "backlash", "gain", "offset", "mount", "friction", "mass", "stretch",
         "curve")
CATALOGUE = {"latency": "latency", "backlash": "backlash", "gain": "gain_error",
             "offset": "position_offset", "mount": "mounting_offset",
             "friction": "coulomb_friction", "mass": "mass_error"}
PARAM = {"latency": "delay", "backlash": "width", "gain": "scale", "offset": "offset",
         "mount": "offset", "friction": "frictionloss", "mass": "scale"}
WHERE = {"latency": ACT, "backlash": ACT, "gain": ACT, "offset": "mcp", "friction": "pip",
         "mass": "dip", "stretch": ACT, "mount": "pip", "curve": "dip"}   # unless ``on`` says
FAMILIES = (
    {"gain_error", "latency", "inertia_error", "mass_error", "viscous_damping"},
    {"velocity_limit", "torque_limit", "gain_error"},
    {"coulomb_friction", "stribeck_friction", "gearbox_friction", "load_dependent_friction",
     "backlash", "deadband"},
    {"position_offset", "mounting_offset", "mass_error", "sensor_scale"},
)


@dataclasses.dataclass(frozen=True)
class Effect:
    """Hidden effect ``kind`` of size ``value`` (s, rad, 1, rad, rad, N m, 1, N/m, 1/rad) on the
    joints ``on`` (default ``WHERE[kind]``; on the tendon rig the servo's effects act on the
    actuator ``flex``)."""

    kind: str
    value: float
    on: tuple[str, ...] = ()

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {', '.join(KINDS)}")

    @property
    def joints(self) -> tuple[str, ...]:
        return self.on or (WHERE[self.kind],)


@dataclasses.dataclass(frozen=True)
class Case:
    """Hidden ``effects``; logs of ``durations`` s; ``seed`` for targets, jitter, noise."""

    name: str
    effects: tuple[Effect, ...] = ()
    durations: tuple[float, ...] = (6.0, 6.0, 6.0, 6.0)
    seed: int = 0
    note: str = ""
    rig: str = "tendon finger"
    rate: float = RATE
    qvel: bool = False

    def get(self, kind: str, joint: str | None = None) -> float | None:
        return next((e.value for e in self.effects
                     if e.kind == kind and (joint is None or joint in e.joints)), None)

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects if e.kind in CATALOGUE}

    @property
    def outside(self) -> bool:
        return any(e.kind not in CATALOGUE for e in self.effects)


def _link(j: str, inner: str, pos: str, case: Case, truth: bool) -> str:
    """Body of joint ``j`` at ``pos`` holding ``inner`` (the next link)."""
    fric = FRICTION[j] + ((case.get("friction") or 0.0) if truth and j == "pip" else 0.0)
    mass = MASS[j] * ((case.get("mass") or 1.0) if truth and j == "dip" else 1.0)
    ln = LENGTH[j]
    hi = {"mcp": 1.5, "pip": 1.7, "dip": 1.4}[j]
    inertia = mass * ln ** 2 / 12
    return (f'<body name="{j}_link" pos="{pos}">'
            f'<joint name="{j}" type="hinge" axis="0 -1 0" range="-0.2 {hi}" limited="true" '
            f'stiffness="{STIFF[j]}" springref="{SPRINGREF[j]}" damping="{DAMPING[j]}" '
            f'frictionloss="{fric:.6g}"/>'
            f'<geom type="capsule" fromto="0 0 0 {ln} 0 0" size="0.008" mass="0" '
            f'contype="0" conaffinity="0"/>'
            f'<inertial pos="{ln / 2} 0 0" mass="{mass:.6g}" '
            f'diaginertia="{0.2 * inertia:.4g} {inertia:.4g} {inertia:.4g}"/>{inner}</body>')


def model_xml(case: Case | None = None, timestep: float = MODEL_DT, truth: bool = False) -> str:
    """The user's MJCF (``truth`` False: the servo a ``position`` actuator on the tendon ``flex``)
    or the truth's (a horn joint driven by a ``motor`` whose torque ``simulate`` computes, the
    cable a one-sided tendon to it, a play beside the horn, the hidden friction and mass)."""
    case = case or Case("nominal")
    dip = _link("dip", "", f"{LENGTH['pip']} 0 0", case, truth)
    pip = _link("pip", dip, f"{LENGTH['mcp']} 0 0", case, truth)
    finger = _link("mcp", pip, "0 0 0.1", case, truth)
    couple = (f'<equality><joint joint1="dip" joint2="pip" polycoef="0 {COUPLE} 0 0 0" '
              f'solref="{LINK_SOLREF}" solimp="{LINK_SOLIMP}"/></equality>')
    if not truth:
        tendon = (f'<tendon><fixed name="{ACT}" armature="{ROTOR_J / HORN ** 2:.6g}" '
                  f'damping="{ROTOR_B / HORN ** 2:.6g}"><joint joint="mcp" coef="{ARM["mcp"]}"/>'
                  f'<joint joint="pip" coef="{ARM["pip"]}"/></fixed></tendon>')
        act = (f'<actuator><position name="{ACT}" tendon="{ACT}" gear="{1 / HORN:.6g}" kp="{KP}" '
               f'ctrlrange="0 1.8" forcerange="0 {TMAX}"/></actuator>')
        servo = ""
    else:
        play = case.get("backlash")
        stretch = case.get("stretch")
        rotor = (f'<joint name="rotor" type="hinge" axis="1 0 0" '
                 f'armature="{ROTOR_J - (HORN_J if play else 0.0):.6g}" damping="{ROTOR_B}"/>')
        horn = f'<joint name="horn" type="hinge" axis="1 0 0" armature="{HORN_J}"/>'
        sliver = '<inertial pos="0 0 0" mass="1e-4" diaginertia="1e-9 1e-9 1e-9"/>'
        if play is None:
            servo = f'<body name="horn" pos="0.2 0 0">{rotor}{sliver}</body>'
            wound = "rotor"
        else:
            servo = (f'<body name="rotor" pos="0.2 0 0">{rotor}{sliver}</body>'
                     f'<body name="horn" pos="0.2 0 0">{horn}{sliver}</body>')
            wound = "horn"
        cable_attr = (f'stiffness="{stretch}" springlength="0 1"' if stretch else
                      f'limited="true" range="0 1" solreflimit="{SOLREF}" solimplimit="{STIFF_IMP}"')
        tendons = (f'<fixed name="cable" {cable_attr}><joint joint="mcp" coef="{ARM["mcp"]}"/>'
                   f'<joint joint="pip" coef="{ARM["pip"]}"/>'
                   f'<joint joint="{wound}" coef="{-HORN}"/></fixed>')
        if play is not None:
            tendons += (f'<fixed name="play" limited="true" range="{-play / 2:.6g} '
                        f'{play / 2:.6g}" solreflimit="{SOLREF}" solimplimit="{STIFF_IMP}"><joint joint="horn" coef="1"/>'
                        f'<joint joint="rotor" coef="-1"/></fixed>')
        tendon = f"<tendon>{tendons}</tendon>"
        act = f'<actuator><motor name="{ACT}" joint="rotor" ctrlrange="{-TMAX} {TMAX}"/></actuator>'
    return f"""<mujoco model="tendon_finger">
  <compiler angle="radian"/>
  <option timestep="{timestep}" gravity="0 0 -9.81"/>
  <worldbody>
    {finger}
    {servo}
  </worldbody>
  {couple}
  {tendon}
  {act}
</mujoco>
"""


def host_times(duration: float, rng: np.random.Generator) -> np.ndarray:
    """The host loop's cycle times [s] from -SETTLE to ``duration``, 100 Hz +-10 % jitter."""
    n = int((duration + SETTLE) * RATE * 1.2) + 2
    t = np.concatenate([[0.0], np.cumsum((1.0 + rng.uniform(-0.1, 0.1, n)) / RATE)]) - SETTLE
    return t[t <= duration]


def targets(t: np.ndarray, rng: np.random.Generator,
            span: tuple[float, float] = GOALS) -> np.ndarray:
    """The host's servo goals [rad] at times ``t``: levels in ``span`` held 0.4-1.0 s, reached
    by a 0.15-0.6 s ramp (a grasp closing and opening; the host ramps its goals so that the
    springs return the finger as fast as the horn lets the cable out)."""
    edges = np.concatenate([[t[0]], np.cumsum(rng.uniform(0.4, 1.0, int(t[-1] / 0.4) + 3))])
    n = len(edges)
    levels = rng.uniform(*span, n)
    ramps = rng.uniform(0.15, 0.6, n)
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n - 1)
    prev = levels[np.maximum(k - 1, 0)]
    frac = np.where(ramps[k] > 0, np.clip((t - edges[k]) / np.maximum(ramps[k], 1e-9), 0, 1), 1)
    out = prev + (levels[k] - prev) * frac
    out[t < 0] = levels[0]
    return out


def servo_torque(goal: float, reading: float, gain: float = 1.0) -> float:
    """The servo's torque at the horn [N m]: clip(gain kp (goal - reading), -tau_max, tau_max)."""
    return float(np.clip(gain * KP * (goal - reading), -TMAX, TMAX))


def rest_state(m: mujoco.MjModel, d: mujoco.MjData, goal: float, seconds: float = 1.5) -> None:
    """Put the truth at rest holding ``goal`` (the finger at the servo's static balance): the
    horn at the goal, the finger hanging on the cable, damped ``seconds`` with the servo law."""
    rot = m.jnt_qposadr[m.joint("rotor").id]
    d.qpos[:] = 0.0
    d.qpos[rot] = goal
    if m.njnt > 4:   # a play: the horn its own joint
        d.qpos[m.jnt_qposadr[m.joint("horn").id]] = goal
    share = HORN * goal / (ARM["mcp"] + ARM["pip"])
    for j in ("mcp", "pip"):
        d.qpos[m.jnt_qposadr[m.joint(j).id]] = share
    d.qpos[m.jnt_qposadr[m.joint("dip").id]] = COUPLE * share
    mujoco.mj_forward(m, d)


def simulate(case: Case, t: np.ndarray, goal: np.ndarray, rng: np.random.Generator,
             true_state: bool = False) -> dict[str, np.ndarray]:
    """Run the truth under the host loop's cycles ``t`` [s] writing ``goal`` (each written right
    after its read; the first SETTLE s of ``t`` < 0 let it come to rest). Returns
    {"qpos:<j>": the logged readings, "goal:flex"} per cycle, with ``true_state`` also
    "true:<j>", "rotor" (the servo's shaft) and "horn" (where the cable winds)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case, TRUTH_DT, truth=True))
    d = mujoco.MjData(m)
    adr = {j: m.jnt_qposadr[m.joint(j).id] for j in JOINTS}
    rot = m.jnt_qposadr[m.joint("rotor").id]
    horn = m.jnt_qposadr[m.joint("horn").id] if case.get("backlash") else rot
    gain = case.get("gain") or 1.0
    lat = case.get("latency") or 0.0
    rest_state(m, d, goal[0])
    arrive = t + lat
    n_steps = int(math.ceil((t[-1] - t[0]) / TRUTH_DT)) + 1
    read_step = np.round((t - t[0]) / TRUTH_DT).astype(int)
    arrived = np.searchsorted(arrive, t[0] + np.arange(n_steps) * TRUTH_DT, side="right") - 1
    res = {f"true:{j}": np.zeros(len(t)) for j in JOINTS}
    res["rotor"], res["horn"] = np.zeros(len(t)), np.zeros(len(t))
    k = 0
    for i in range(n_steps):
        while k < len(t) and read_step[k] == i:
            for j in JOINTS:
                res[f"true:{j}"][k] = d.qpos[adr[j]]
            res["rotor"][k], res["horn"][k] = d.qpos[rot], d.qpos[horn]
            k += 1
        d.ctrl[0] = servo_torque(goal[max(arrived[i], 0)], d.qpos[rot], gain)
        mujoco.mj_step(m, d)
    off = case.get("offset") or 0.0
    for j in JOINTS:
        noisy = res[f"true:{j}"] + (off if j == "mcp" else 0.0) + rng.normal(0.0, NOISE, len(t))
        res[f"qpos:{j}"] = np.round(noisy / LSB) * LSB
    res[f"goal:{ACT}"] = goal
    if not true_state:
        res = {key: v for key, v in res.items() if key.startswith(("qpos:", "goal:"))}
    return res


def _linkage_joint(j: str, case: Case, truth: bool, rotor: bool) -> str:
    """Joint ``j`` of the linkage rig: on the servo's side (``rotor``) its armature and damping,
    on the link its friction; both when there is no play."""
    hi = {"mcp": 1.5, "pip": 1.7, "dip": 1.4}[j.removesuffix("_rotor")]
    attrs = f'name="{j}" type="hinge" axis="0 -1 0" range="-0.2 {hi}" limited="true"'
    base = j.removesuffix("_rotor")
    if base in SERVOS and rotor:
        attrs += f' armature="{LARM[base]}" damping="{LDAMP[base]}"'
    if j == base:
        fric = LFRIC[j] + ((case.get("friction", j) or 0.0) if truth else 0.0)
        attrs += f' frictionloss="{fric:.6g}"'
    return f"<joint {attrs}/>"


def linkage_xml(case: Case | None = None, timestep: float = MODEL_DT, truth: bool = False) -> str:
    """The linkage rig's MJCF: the user's (``truth`` False: ``position`` actuators on mcp and pip,
    the dip on the pip through ``dip = 0.8 pip``) or the truth's (``motor`` actuators whose torque
    ``simulate_linkage`` computes, a rotor joint and a tendon's play where the case hides a
    backlash, the hidden friction and mass, a four-bar's curve ``dip = 0.8 pip + c pip^2``)."""
    case = case or Case("nominal", rig="linkage finger")
    play = {j: (case.get("backlash", j) if truth else None) for j in SERVOS}
    curve = (case.get("curve") or 0.0) if truth else 0.0

    def link(j: str, inner: str, pos: str) -> str:
        mass = MASS[j] * ((case.get("mass", j) or 1.0) if truth else 1.0)
        ln = LENGTH[j]
        inertia = mass * ln ** 2 / 12
        geoms = (f'<geom type="capsule" fromto="0 0 0 {ln} 0 0" size="0.008" mass="0" '
                 f'contype="0" conaffinity="0"/><inertial pos="{ln / 2} 0 0" mass="{mass:.6g}" '
                 f'diaginertia="{0.2 * inertia:.4g} {inertia:.4g} {inertia:.4g}"/>')
        if j not in SERVOS or play[j] is None:
            joint = _linkage_joint(j, case, truth, rotor=True)
            return f'<body name="{j}_link" pos="{pos}">{joint}{geoms}{inner}</body>'
        rotor = _linkage_joint(j + "_rotor", case, truth, rotor=True)
        joint = _linkage_joint(j, case, truth, rotor=False)
        return (f'<body name="{j}_rotor" pos="{pos}">{rotor}<inertial pos="0 0 0" mass="1e-4" '
                f'diaginertia="1e-8 1e-8 1e-8"/></body>'
                f'<body name="{j}_link" pos="{pos}">{joint}{geoms}{inner}</body>')

    finger = link("mcp", link("pip", link("dip", "", f"{LENGTH['pip']} 0 0"),
                              f"{LENGTH['mcp']} 0 0"), "0 0 0.1")
    couple = (f'<equality><joint joint1="dip" joint2="pip" polycoef="0 {COUPLE} {curve:.6g} 0 0" '
              f'solref="{LINK_SOLREF}" solimp="{LINK_SOLIMP}"/></equality>')
    tendons = "".join(
        f'<fixed name="{j}_play" limited="true" range="{-play[j] / 2:.6g} {play[j] / 2:.6g}" '
        f'solreflimit="{SOLREF}" solimplimit="{STIFF_IMP}"><joint joint="{j}" coef="1"/>'
        f'<joint joint="{j}_rotor" coef="-1"/></fixed>' for j in SERVOS if play[j] is not None)
    if truth:
        acts = "".join(f'<motor name="{j}" joint="{j if play[j] is None else j + "_rotor"}" '
                       f'ctrlrange="{-LTMAX[j]} {LTMAX[j]}"/>' for j in SERVOS)
    else:
        acts = "".join(f'<position name="{j}" joint="{j}" kp="{LKP[j]}" ctrlrange="-0.2 1.5" '
                       f'forcerange="{-LTMAX[j]} {LTMAX[j]}"/>' for j in SERVOS)
    return f"""<mujoco model="linkage_finger">
  <compiler angle="radian"/>
  <option timestep="{timestep}" gravity="0 0 -9.81"/>
  <worldbody>
    {finger}
  </worldbody>
  {couple}
  <tendon>{tendons}</tendon>
  <actuator>{acts}</actuator>
</mujoco>
"""


def simulate_linkage(case: Case, t: np.ndarray, goals: dict[str, np.ndarray],
                     rng: np.random.Generator, true_state: bool = False) -> dict[str, np.ndarray]:
    """The linkage rig's truth under the host loop's cycles ``t`` [s] writing ``goals`` (one per
    servo). Each servo: tau = clip(gain kp (u - s), -tau_max, tau_max), s its own reading of its
    rotor (+ a ``mount`` offset; the log reads the same sensor); the dip's encoder reads the dip.
    Returns {"qpos:<j>", "goal:<servo>"} per cycle, with ``true_state`` also "true:<j>" and
    "rotor:<servo>"."""
    m = mujoco.MjModel.from_xml_string(linkage_xml(case, TRUTH_DT, truth=True))
    d = mujoco.MjData(m)
    adr = {j: m.jnt_qposadr[m.joint(j).id] for j in JOINTS}
    rot = {j: m.jnt_qposadr[m.joint(j + "_rotor").id] if case.get("backlash", j) else adr[j]
           for j in SERVOS}
    act = {j: m.actuator(j).id for j in SERVOS}
    gain = {j: case.get("gain", j) or 1.0 for j in SERVOS}
    off = {j: case.get("mount", j) or 0.0 for j in SERVOS}
    lat = case.get("latency") or 0.0
    for j in SERVOS:
        d.qpos[adr[j]] = d.qpos[rot[j]] = goals[j][0] - off[j]
    pip = d.qpos[adr["pip"]]
    d.qpos[adr["dip"]] = COUPLE * pip + (case.get("curve") or 0.0) * pip ** 2
    arrive = t + lat
    n_steps = int(math.ceil((t[-1] - t[0]) / TRUTH_DT)) + 1
    read_step = np.round((t - t[0]) / TRUTH_DT).astype(int)
    arrived = np.searchsorted(arrive, t[0] + np.arange(n_steps) * TRUTH_DT, side="right") - 1
    res = {f"true:{j}": np.zeros(len(t)) for j in JOINTS}
    res |= {f"rotor:{j}": np.zeros(len(t)) for j in SERVOS}
    k = 0
    for i in range(n_steps):
        while k < len(t) and read_step[k] == i:
            for j in JOINTS:
                res[f"true:{j}"][k] = d.qpos[adr[j]]
            for j in SERVOS:
                res[f"rotor:{j}"][k] = d.qpos[rot[j]]
            k += 1
        g = max(arrived[i], 0)
        for j in SERVOS:
            tau = gain[j] * LKP[j] * (goals[j][g] - d.qpos[rot[j]] - off[j])
            d.ctrl[act[j]] = float(np.clip(tau, -LTMAX[j], LTMAX[j]))
        mujoco.mj_step(m, d)
    for j in JOINTS:
        noisy = res[f"true:{j}"] + off.get(j, 0.0) + (case.get("offset", j) or 0.0) \
            + rng.normal(0.0, NOISE, len(t))
        res[f"qpos:{j}"] = np.round(noisy / LSB) * LSB
    for j in SERVOS:
        res[f"goal:{j}"] = goals[j]
    if not true_state:
        res = {key: v for key, v in res.items() if key.startswith(("qpos:", "goal:"))}
    return res


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml``, ``logs/log<i>.csv`` (seconds from 0, radians) and ``truth.json`` into
    ``folder``. Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    linkage = case.rig == "linkage finger"
    (folder / "model.xml").write_text(linkage_xml() if linkage else model_xml())
    rng = np.random.default_rng(case.seed)
    acts = SERVOS if linkage else (ACT,)
    names = ["time"] + [f"goal:{a}" for a in acts] + [f"qpos:{j}" for j in JOINTS]
    for i, dur in enumerate(case.durations):
        t = host_times(dur, rng)
        if linkage:
            goals = {j: targets(t, rng, LGOALS[j]) for j in SERVOS}
            cols = simulate_linkage(case, t, goals, rng)
        else:
            cols = simulate(case, t, targets(t, rng), rng)
        keep = t >= 0.0
        data = np.column_stack([t[keep]] + [cols[n][keep] for n in names[1:]])
        np.savetxt(folder / "logs" / f"log{i}.csv", data, delimiter=",", header=",".join(names),
                   comments="", fmt=["%.5f"] + ["%.7g"] * (len(names) - 1))
    truth = {"case": case.name, "causes": sorted(case.causes),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case)}
    if case.outside:
        truth["outside"] = True
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": [str(folder / "logs")], "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Each catalogue effect's parameter where it acts (the servo's effects on the actuator
    ``flex``, in rad at the horn, s, or a factor)."""
    return [dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=j, value=e.value)
            for e in case.effects if e.kind in CATALOGUE for j in e.joints]


def score(report: dict, truth: dict) -> dict:
    """``redteam_grade.grade`` of ``report`` against ``truth`` with this set's FAMILIES."""
    return redteam_grade.grade(report, truth, FAMILIES)


def magnitudes(seed: int = 13) -> dict[str, float]:
    """The hidden effects' sizes, drawn once from a seeded generator over real-world ranges:
    20-50 ms of latency, a horn play of 40-100 mrad (0.4-1 mm of cable), a kp x0.5-0.7 or
    x1.5-2, an mcp encoder 60-120 mrad off either way, 0.01-0.03 N m more on the pip pin (5-15
    times the model's), a distal phalanx 1.8-2.5 times as heavy, a cable of 10-30 kN/m (0.7-2
    mm at 20 N); on the linkage rig a pip servo mounted 60-120 mrad off either way and a four-bar's
    curve of 0.1-0.3 /rad (0.1-0.3 rad at a pip of 1 rad). The servo's effects take the same
    sizes on both rigs."""
    r = np.random.default_rng(seed)
    return {
        "latency": round(r.uniform(0.020, 0.050), 4),
        "backlash": round(r.uniform(0.04, 0.10), 4),
        "gain": round(float(r.uniform(0.5, 0.7) if r.uniform() < 0.5 else r.uniform(1.5, 2.0)), 3),
        "offset": round(float(r.choice([-1.0, 1.0]) * r.uniform(0.06, 0.12)), 4),
        "friction": round(r.uniform(0.01, 0.03), 4),
        "mass": round(r.uniform(1.8, 2.5), 3),
        "stretch": round(r.uniform(10000.0, 30000.0), -2),
        "mount": round(float(r.choice([-1.0, 1.0]) * r.uniform(0.06, 0.12)), 4),
        "curve": round(r.uniform(0.1, 0.3), 3),
    }


MAG = magnitudes()
E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_a", (), seed=1301, note="no hidden effect"),
    Case("clean_b", (), seed=1302, note="no hidden effect, other goals"),
    Case("latency", (E("latency", MAG["latency"]),), seed=1303,
         note="the goal reaches the servo late"),
    Case("backlash", (E("backlash", MAG["backlash"]),), seed=1304,
         note="a play between the servo's shaft and the horn the cable winds on"),
    Case("offset", (E("offset", MAG["offset"]),), seed=1305,
         note="the mcp encoder's zero off"),
    Case("gain", (E("gain", MAG["gain"]),), seed=1306, note="the servo's kp off the model's"),
    Case("friction", (E("friction", MAG["friction"]),), seed=1307,
         note="dry friction added on the pip pin"),
    Case("mass", (E("mass", MAG["mass"]),), seed=1308,
         note="the distal phalanx heavier (a fingertip pad)"),
    Case("latency_friction", (E("latency", MAG["latency"]), E("friction", MAG["friction"])),
         seed=1309, note="the pair: a late goal and a tight pip pin"),
    Case("stretch", (E("stretch", MAG["stretch"]),), seed=1310,
         note="OUTSIDE the catalogue: an elastic cable"),
) + tuple(Case(name, effects, seed=seed, note=note, rig="linkage finger") for name, effects,
          seed, note in (
    ("link_clean", (), 1321, "the linkage rig: no hidden effect"),
    ("link_latency", (E("latency", MAG["latency"], SERVOS),), 1322,
     "the goals reach both servos late"),
    ("link_backlash", (E("backlash", MAG["backlash"], ("pip",)),), 1323,
     "a play between the pip servo and its link (the dip's linkage on the link)"),
    ("link_gain", (E("gain", MAG["gain"], ("pip",)),), 1324, "the pip servo's kp off"),
    ("link_mount", (E("mount", MAG["mount"], ("pip",)),), 1325,
     "the pip servo mounted off its zero: it reads and holds q + offset; only the dip's "
     "encoder (through the linkage) and gravity see it"),
    ("link_friction", (E("friction", MAG["friction"], ("pip",)),), 1326,
     "dry friction added on the pip pin"),
    ("link_mass", (E("mass", MAG["mass"], ("dip",)),), 1327,
     "the distal phalanx heavier; its joint has no actuator of its own"),
    ("link_latency_friction", (E("latency", MAG["latency"], SERVOS),
                               E("friction", MAG["friction"], ("pip",))), 1328,
     "the pair: late goals and a tight pip pin"),
    ("link_curve", (E("curve", MAG["curve"]),), 1329,
     "OUTSIDE the catalogue: the linkage's four-bar curve, dip = 0.8 pip + c pip^2, where the "
     "user's MJCF has the straight line"),
))
CASE_BY_NAME = {c.name: c for c in CASES}
