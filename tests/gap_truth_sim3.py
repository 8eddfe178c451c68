"""A third independently written truth simulator for the gap analysis (issue 11 item 4).

Written from first principles with mujoco and numpy only, importing nothing from lowcostdex, and
without reading the analyzer, its effect catalogue, plant, servo or the two earlier truth
simulators. What it covers that they do not:

- ``finger``: a D'Claw-like 3-joint finger hanging from a plate (``abd`` abduction about x, then
  ``prox`` and ``dist`` flexion about y; links 85 g / 55 mm, 85 g / 68 mm, 50 g / 65 mm, rotor
  armature 0.8 g m^2 per joint, joint damping 0.01 N m s/rad), driven by plain MJCF ``position``
  actuators (kp 3 N m/rad, kv 0.08 N m s/rad, forcerange +-1.5 N m). An effect sits on ONE joint
  (the others clean) or on two different joints.
- ``servo``: a one-joint servo bench (a 150 g arm, centre of mass 60 mm below a horizontal axis,
  armature 2 g m^2) whose truth is a ``motor`` actuator driven by the servo's OWN firmware: a P-D
  law at 1 kHz in integer encoder ticks (4096 per turn), D on the measured tick difference per
  cycle, output an integer PWM duty (885 full scale) times the stall torque 1.5 N m. The user's
  model of it is the obvious one: a ``position`` actuator with the firmware's kp, kv and force
  range converted to SI.

Effects are written here from their physics: latency (the goal reaches the servo late, continuous
time), backlash (a play joint between the rotor and the link; on the finger the servo's encoder
reads the rotor side, on the servo bench it reads the OUTPUT shaft and the firmware closes its
loop there), a reading offset (the log reads q + offset, the servo holds the true goal), a
mounting offset (the servo reads and holds q + offset), a P-gain error (kp scaled, kv kept), an
armature (rotor inertia) error, a link mass error (mass and inertia of one link), Coulomb friction
near the stall torque, Stribeck friction (breakaway above Coulomb, decaying with speed),
direction-dependent Coulomb friction, and a motor torque-speed line (no torque left at 1-2 rad/s).
Frictions are MuJoCo's frictionloss constraint (true stiction), its level set every truth step
from the joint's speed or the direction it is pushed. Truth physics at 0.25 ms; the user's model
at MuJoCo's default 2 ms.

Logs: the project's CSV format (docs/gap_analysis.md): ``time``, ``goal_time`` (the goal's bus
packet arrives 2.6 ms after the read), ``goal:<actuator>`` (integer ticks, written in rad),
``qpos:<joint>`` (encoder ticks of 2 pi / 4096 plus read noise), optionally ``qvel:<joint>``
(0.229 rpm units). 100 Hz or 50 Hz, optionally jittered. ``score`` grades a report.json.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import pathlib

import mujoco
import numpy as np

TRUTH_DT = 0.00025          # s, truth physics step
TICK = 2 * np.pi / 4096     # rad per encoder tick
VEL_UNIT = 0.229 * 2 * np.pi / 60   # rad/s per Dynamixel velocity unit
BUS_DELAY = 0.0026          # s, read -> goal packet on the bus (goal_time - time)
GRAVITY = 9.81

# finger (D'Claw-like); per link: (joint, axis, length m, mass kg)
FINGER_LINKS = (("abd", "1 0 0", 0.055, 0.085), ("prox", "0 1 0", 0.068, 0.085),
                ("dist", "0 1 0", 0.065, 0.050))
FINGER_KP, FINGER_KV, FINGER_TMAX = 3.0, 0.08, 1.5     # N m/rad, N m s/rad, N m
ARMATURE = 0.0008          # kg m^2 per finger joint
JOINT_DAMPING = 0.01       # N m s/rad (nominal, in both models)
FINGER_CENTRE = {"abd": (0.0, 0.35), "prox": (0.5, 0.6), "dist": (0.5, 0.6)}  # centre, half range

# servo bench: firmware gains in device units, converted to SI for the user's model
SERVO_TMAX = 1.5           # N m stall torque (PWM 885)
PWM_MAX = 885
KP_DEV, KD_DEV = 348, 724  # P: pwm = KP * e_ticks / 128; D: pwm = KD * dticks_per_ms / 16
SERVO_KP = KP_DEV / 128 * SERVO_TMAX / PWM_MAX / TICK            # N m/rad  (~3.0)
SERVO_KV = KD_DEV / 16 * SERVO_TMAX / PWM_MAX / TICK * 1e-3      # N m s/rad (~0.05)
SERVO_ARM = (0.150, 0.060)  # kg, m (point-ish mass below the axis)
SERVO_ARMATURE = 0.002     # kg m^2

ACT = {j: f"servo_{j}" for j, *_ in FINGER_LINKS}
# MuJoCo's frictionloss is a soft constraint: with the default solref/solimp a joint held below
# its friction level creeps at v = F R / b (~0.04 rad/s at 0.1 N m on the servo bench). The
# truth's frictions are true stiction: the stiffest reference the 0.25 ms step allows and an
# impedance near 1 (creep ~1e-5 rad/s).
STIFF_FRICTION = ' solreffriction="0.0005 1" solimpfriction="0.999 0.9999 0.001"'

# catalogue names an effect may be confused with (named instead: "family")
FAMILY = {
    "latency": set(),
    "backlash": set(),
    "position_offset": {"mounting_offset"},
    "mounting_offset": {"position_offset"},
    "gain_error": {"motor_strength"},
    "inertia_error": {"mass_error"},
    "mass_error": {"inertia_error"},
    "coulomb_friction": {"stribeck_friction", "gearbox_friction", "load_dependent_friction"},
    "stribeck_friction": {"coulomb_friction", "gearbox_friction", "load_dependent_friction"},
    "velocity_limit": {"viscous_damping", "motor_strength", "torque_limit"},
}


@dataclasses.dataclass(frozen=True)
class Effect:
    """One hidden effect. ``kind`` is this simulator's own name; ``joints`` where it acts
    (finger joint names, or ``q`` on the servo bench); ``value`` its size in SI units
    (latency s, backlash full play rad, offsets rad, factors 1, Coulomb N m, velocity rad/s);
    ``extra`` more numbers (Stribeck: static N m and velocity rad/s; direction: the torque
    for negative speeds)."""
    kind: str
    joints: tuple[str, ...]
    value: float
    extra: tuple[float, ...] = ()

    @property
    def catalogue(self) -> str:
        return {"latency": "latency", "backlash": "backlash", "offset_read": "position_offset",
                "offset_mount": "mounting_offset", "gain": "gain_error",
                "armature": "inertia_error", "mass": "mass_error",
                "coulomb": "coulomb_friction", "stribeck": "stribeck_friction",
                "dirfric": "coulomb_friction", "vlimit": "velocity_limit"}[self.kind]

    def truth_params(self) -> dict:
        """Catalogue parameters comparable with this effect's value (documented meaning
        only; documented by gap-cands 2026-11-26: the velocity limit's ``speed`` is the no-load
        speed of a torque-speed line; stribeck_friction's ``coulomb`` the sliding level,
        ``static`` the breakaway above it, ``velocity`` the Stribeck speed)."""
        return {"latency": {"delay": self.value}, "backlash": {"width": self.value},
                "offset_read": {"offset": self.value}, "offset_mount": {"offset": self.value},
                "gain": {"scale": self.value}, "armature": {"scale": self.value},
                "mass": {"scale": self.value}, "coulomb": {"frictionloss": self.value},
                "vlimit": {"speed": self.value},
                "stribeck": {"coulomb": self.value, "static": self.extra[0] - self.value,
                             "velocity": self.extra[1]} if self.kind == "stribeck" else {},
                }.get(self.kind, {})


@dataclasses.dataclass(frozen=True)
class Case:
    name: str
    rig: str                                 # "finger" | "servo"
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0                      # Hz, nominal log rate
    jitter: float = 0.0                      # s, each row interval + U(0, jitter)
    qvel: bool = True
    noise: float = 0.0005                    # rad, read noise (before quantisation)
    durations: tuple[float, ...] = (12.0, 12.0, 12.0)
    seed: int = 0
    note: str = ""

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(j for j, *_ in FINGER_LINKS) if self.rig == "finger" else ("q",)

    @property
    def causes(self) -> set[str]:
        return {e.catalogue for e in self.effects}

    def on(self, kind: str, joint: str) -> Effect | None:
        for e in self.effects:
            if e.kind == kind and joint in e.joints:
                return e
        return None


# ---------------------------------------------------------------- models

def _rod(mass: float, length: float, scale: float = 1.0) -> str:
    """Inertial of a uniform rod hanging along -z from its body frame (mass scaled)."""
    m = mass * scale
    i_perp = m * length ** 2 / 12
    i_ax = m * 0.012 ** 2 / 2
    return (f'<inertial pos="0 0 {-length / 2:.6g}" mass="{m:.6g}" '
            f'diaginertia="{i_perp:.6g} {i_perp:.6g} {i_ax:.6g}"/>')


def finger_xml(case: Case | None = None, truth: bool = False) -> str:
    """MJCF of the finger: the user's nominal model (``truth=False``: 2 ms, position actuators)
    or the truth model of ``case`` (0.25 ms, effects built in: play joints, scaled kp,
    armature and link mass)."""
    case = case or Case("nominal", "finger")
    step = TRUTH_DT if truth else 0.002
    body_open, closes = [], 0
    for i, (j, axis, length, mass) in enumerate(FINGER_LINKS):
        arm = ARMATURE
        mscale = 1.0
        play = None
        if truth:
            if (e := case.on("armature", j)):
                arm *= e.value
            if (e := case.on("mass", j)):
                mscale = e.value
            if (e := case.on("backlash", j)):
                play = e.value
        pos = "0 0 0" if i == 0 else f"0 0 {-FINGER_LINKS[i - 1][2]:.6g}"
        joint = (f'<joint name="{j}" type="hinge" axis="{axis}" armature="{arm:.6g}" '
                 f'damping="{JOINT_DAMPING}"{STIFF_FRICTION if truth else ""}/>')
        geom = (f'<geom type="capsule" fromto="0 0 0 0 0 {-length:.6g}" size="0.01" '
                f'contype="0" conaffinity="0" mass="0"/>')
        if play is None:
            body_open.append(f'<body name="link_{j}" pos="{pos}">{joint}'
                             f'{_rod(mass, length, mscale)}{geom}')
            closes += 1
        else:   # rotor (the servo's output as its encoder sees it) -> play -> link
            h = play / 2
            body_open.append(
                f'<body name="rotor_{j}" pos="{pos}">{joint}'
                f'<inertial pos="0 0 0" mass="0.001" diaginertia="1e-8 1e-8 1e-8"/>'
                f'<body name="link_{j}" pos="0 0 0"><joint name="{j}_play" type="hinge" '
                f'axis="{axis}" range="{-h:.6g} {h:.6g}" limited="true" '
                f'solreflimit="0.0005 1" solimplimit="0.99 0.999 0.0001"/>'
                f'{_rod(mass, length, mscale)}{geom}')
            closes += 2
    acts = []
    for j, *_ in FINGER_LINKS:
        kp = FINGER_KP
        if truth and (e := case.on("gain", j)):
            kp *= e.value
        acts.append(f'<position name="{ACT[j]}" joint="{j}" kp="{kp:.6g}" kv="{FINGER_KV}" '
                    f'forcerange="{-FINGER_TMAX} {FINGER_TMAX}"/>')
    return (f'<mujoco model="finger3">\n<compiler angle="radian"/>\n<option timestep="{step}" integrator="implicitfast"/>\n'
            f'<worldbody><body name="plate" pos="0 0 0.4">'
            + "".join(body_open) + "</body>" * closes
            + "</body></worldbody>\n<actuator>" + "".join(acts) + "</actuator>\n</mujoco>\n")


def servo_xml(case: Case | None = None, truth: bool = False) -> str:
    """MJCF of the servo bench. User's model: joint ``q`` with a ``position`` actuator ``servo``
    (the firmware's gains in SI). Truth: a ``motor`` actuator on the rotor, driven by
    ``Firmware``; with backlash a play joint ``q_play`` between rotor and arm."""
    case = case or Case("nominal", "servo")
    step = TRUTH_DT if truth else 0.002
    m, arm_l = SERVO_ARM
    arm = SERVO_ARMATURE
    if truth and (e := case.on("armature", "q")):
        arm *= e.value
    ms = case.on("mass", "q").value if truth and case.on("mass", "q") else 1.0
    inertial = (f'<inertial pos="0 0 {-arm_l}" mass="{m * ms:.6g}" '
                f'diaginertia="{2e-5 * ms:.6g} {2e-5 * ms:.6g} {1e-6 * ms:.6g}"/>')
    geom = f'<geom type="capsule" fromto="0 0 0 0 0 {-arm_l}" size="0.008" contype="0" conaffinity="0" mass="0"/>'
    joint = (f'<joint name="q" type="hinge" axis="1 0 0" armature="{arm:.6g}" '
             f'damping="{JOINT_DAMPING}"{STIFF_FRICTION if truth else ""}/>')
    if not truth:
        body = f'<body name="arm" pos="0 0 0.3">{joint}{inertial}{geom}</body>'
        act = (f'<position name="servo" joint="q" kp="{SERVO_KP:.6g}" kv="{SERVO_KV:.6g}" '
               f'forcerange="{-SERVO_TMAX} {SERVO_TMAX}"/>')
    else:
        bl = case.on("backlash", "q")
        if bl is None:
            body = f'<body name="arm" pos="0 0 0.3">{joint}{inertial}{geom}</body>'
        else:
            h = bl.value / 2
            body = (f'<body name="rotor" pos="0 0 0.3">{joint}'
                    f'<inertial pos="0 0 0" mass="0.001" diaginertia="1e-8 1e-8 1e-8"/>'
                    f'<body name="arm"><joint name="q_play" type="hinge" axis="1 0 0" '
                    f'range="{-h:.6g} {h:.6g}" limited="true" solreflimit="0.0005 1" '
                    f'solimplimit="0.99 0.999 0.0001"/>{inertial}{geom}</body></body>')
        act = (f'<motor name="servo" joint="q" ctrlrange="{-SERVO_TMAX} {SERVO_TMAX}" '
               f'ctrllimited="true"/>')
    return (f'<mujoco model="servo3">\n<compiler angle="radian"/>\n<option timestep="{step}" integrator="implicitfast"/>\n'
            f'<worldbody>{body}</worldbody>\n<actuator>{act}</actuator>\n</mujoco>\n')


class Firmware:
    """The servo's own position loop, run every 1 ms on integer ticks:
    pwm = KP * e / 128 - KD * (p_k - p_{k-1}) / 16 (integer division toward zero), clipped
    to +-885, torque = pwm / 885 * stall torque; ``kp_scale`` multiplies KP (a gain error)."""

    def __init__(self, kp_scale: float = 1.0):
        self.kp = int(round(KP_DEV * kp_scale))
        self.kd = KD_DEV
        self.prev: int | None = None

    def torque(self, goal_ticks: int, pos_ticks: int) -> float:
        prev = pos_ticks if self.prev is None else self.prev
        self.prev = pos_ticks
        p = int(self.kp * (goal_ticks - pos_ticks) / 128)
        d = int(self.kd * (pos_ticks - prev) / 16)
        pwm = max(-PWM_MAX, min(PWM_MAX, p - d))
        return pwm / PWM_MAX * SERVO_TMAX


# ---------------------------------------------------------------- goals and logs

def row_times(case: Case, duration: float, rng: np.random.Generator) -> np.ndarray:
    dt = 1.0 / case.rate
    if case.jitter <= 0:
        return np.arange(0.0, duration, dt)
    gaps = dt + rng.uniform(0.0, case.jitter, int(duration / dt) + 2)
    t = np.concatenate([[0.0], np.cumsum(gaps)])
    return t[t < duration]


def goal_signal(t: np.ndarray, centre: float, half: float, style: int,
                rng: np.random.Generator) -> np.ndarray:
    """Goals (rad) at the row times ``t``: style 0 steps and holds, 1 sines and a chirp,
    2 a mix (steps, ramps, a sine). Quantised to ticks (the host writes ticks)."""
    g = np.full(t.shape, centre)
    s = 0.0
    end = t[-1] + 1e-9
    while s < end:
        kind = ("step", "step", "ramp")[rng.integers(3)] if style == 0 else (
            ("sine", "chirp")[rng.integers(2)] if style == 1 else
            ("step", "ramp", "sine")[rng.integers(3)])
        dur = rng.uniform(0.5, 1.3) if kind == "step" else rng.uniform(1.5, 3.5)
        m = (t >= s) & (t < s + dur)
        tau = t[m] - s
        if kind == "step":
            g[m] = centre + rng.uniform(-half, half)
        elif kind == "ramp":
            a, b = rng.uniform(-half, half, 2)
            g[m] = centre + a + (b - a) * tau / dur
        elif kind == "sine":
            amp, f = rng.uniform(0.3, 1.0) * half, rng.uniform(0.3, 1.5)
            g[m] = centre + amp * np.sin(2 * np.pi * f * tau)
        else:
            f0, f1, amp = 0.2, 2.5, rng.uniform(0.3, 0.7) * half
            g[m] = centre + amp * np.sin(2 * np.pi * (f0 * tau + (f1 - f0) * tau ** 2 / (2 * dur)))
        s += dur
    g[t < 0.3] = g[np.searchsorted(t, 0.3)] if np.any(t >= 0.3) else g[0]  # start on a hold
    return np.round(g / TICK) * TICK


@dataclasses.dataclass
class Run:
    """One simulated log: row times, goals (rad, per actuator), readings (what the log holds)
    and the truth at every truth step (time, logged joints' true angle and speed)."""
    t: np.ndarray
    goals: np.ndarray        # rows x joints
    qpos: np.ndarray         # rows x joints (logged: offsets, noise, ticks)
    qvel: np.ndarray         # rows x joints (logged velocity units)
    t_truth: np.ndarray
    q_truth: np.ndarray      # steps x joints, the reading side's true angle (no offset)
    v_truth: np.ndarray
    extra: dict


def _friction_level(e: Effect, v: float, push: float) -> float:
    """Friction torque level (N m) of a friction effect at speed ``v`` (rad/s) when pushed by
    the non-friction torque ``push`` (N m, decides the direction at rest)."""
    if e.kind == "coulomb":
        return e.value
    if e.kind == "stribeck":
        fs, vs = e.extra
        return e.value + (fs - e.value) * np.exp(-(v / vs) ** 2)
    if e.kind == "dirfric":
        d = v if abs(v) > 1e-3 else push
        return e.value if d >= 0 else e.extra[0]
    raise ValueError(e.kind)


def simulate(case: Case, goals: np.ndarray, t: np.ndarray, settle: float = 1.0,
             record_every: int = 1) -> dict:
    """Run the truth physics of ``case`` for goals ``goals`` (rows x joints, rad, in the
    servo's reading frame) written at row times ``t`` (s). Returns the truth at every step
    (from time 0, after ``settle`` s holding the first goal): ``t``, ``q`` and ``v`` of the
    reading side, ``q_link`` (after any play), ``torque`` (servo rig: firmware torque)."""
    xml = finger_xml(case, truth=True) if case.rig == "finger" else servo_xml(case, truth=True)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    joints = case.joints
    jq = [model.jnt_qposadr[model.joint(j).id] for j in joints]
    jv = [model.jnt_dofadr[model.joint(j).id] for j in joints]
    play = {}
    for j in joints:
        pid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{j}_play")
        if pid >= 0:
            play[j] = model.jnt_qposadr[pid]
    off_mount = np.array([e.value if (e := case.on("offset_mount", j)) else 0.0 for j in joints])
    lat = np.array([e.value if (e := case.on("latency", j)) else 0.0 for j in joints])
    fric = [(model.jnt_dofadr[model.joint(j).id], e) for j in joints
            for e in case.effects if e.kind in ("coulomb", "stribeck", "dirfric") and j in e.joints]
    vlim = case.on("vlimit", "q")
    gain = case.on("gain", "q")
    fw = Firmware(gain.value if gain else 1.0) if case.rig == "servo" else None
    n_settle = int(round(settle / TRUTH_DT))
    n = int(np.ceil((t[-1] + 0.05) / TRUTH_DT))
    # goal index in force at each truth step, per joint (continuous-time arrival)
    steps_t = (np.arange(n_settle + n) - n_settle) * TRUTH_DT
    idx = np.stack([np.searchsorted(t + BUS_DELAY + lat[k], steps_t, side="right") - 1
                    for k in range(len(joints))], axis=1)
    idx = np.maximum(idx, 0)
    # the servo holds its reading (q + mounting offset) at the goal: true target = goal - off
    target = goals[idx, np.arange(len(joints))] - off_mount
    # initial state: the first goal
    for k in range(len(joints)):
        data.qpos[jq[k]] = target[0, k]
    mujoco.mj_forward(model, data)
    nrec = (n + record_every - 1) // record_every
    out_q = np.empty((nrec, len(joints)))
    out_v = np.empty((nrec, len(joints)))
    out_link = np.empty((nrec, len(joints)))
    out_tau = np.zeros(nrec)
    tau = 0.0
    r = 0
    for i in range(n_settle + n):
        if case.rig == "finger":
            data.ctrl[:] = target[i]
        elif i % 4 == 0:   # firmware at 1 kHz on integer ticks of the output reading
            q_read = data.qpos[jq[0]] + (data.qpos[play["q"]] if "q" in play else 0.0) + off_mount[0]
            tau = fw.torque(int(round((target[i, 0] + off_mount[0]) / TICK)),
                            int(round(q_read / TICK)))
            if vlim is not None:   # motor torque-speed line: no torque left at vlim.value
                v = data.qvel[jv[0]]
                tau = min(max(tau, -SERVO_TMAX * (1 + v / vlim.value)),
                          SERVO_TMAX * (1 - v / vlim.value))
                tau = min(max(tau, -SERVO_TMAX), SERVO_TMAX)
            data.ctrl[0] = tau
        for dof, e in fric:   # forces of the previous step (0.25 ms old) give the push
            push = data.qfrc_actuator[dof] + data.qfrc_passive[dof] - data.qfrc_bias[dof]
            model.dof_frictionloss[dof] = _friction_level(e, data.qvel[dof], push)
        mujoco.mj_step(model, data)
        if i >= n_settle and (i - n_settle) % record_every == 0:
            for k, j in enumerate(joints):
                out_q[r, k] = data.qpos[jq[k]]
                out_v[r, k] = data.qvel[jv[k]]
                out_link[r, k] = data.qpos[jq[k]] + (data.qpos[play[j]] if j in play else 0.0)
            out_tau[r] = tau
            r += 1
    q_read = out_link if case.rig == "servo" else out_q   # servo bench: output-shaft encoder
    v_read = out_v.copy()
    if case.rig == "servo" and "q" in play:
        v_read[:, 0] = np.gradient(out_link[:, 0], TRUTH_DT * record_every)
    return {"t": np.arange(nrec) * TRUTH_DT * record_every, "q": q_read, "v": v_read,
            "q_motor": out_q, "q_link": out_link, "torque": out_tau, "target": target[n_settle::record_every]}


def make_run(case: Case, duration: float, style: int, rng: np.random.Generator) -> Run:
    t = row_times(case, duration, rng)
    joints = case.joints
    goals = np.empty((len(t), len(joints)))
    for k, j in enumerate(joints):
        c, h = FINGER_CENTRE[j] if case.rig == "finger" else (0.0, 1.0)
        goals[:, k] = goal_signal(t, c, h, style, rng)
    tr = simulate(case, goals, t)
    i = np.minimum(np.round(t / TRUTH_DT).astype(int), len(tr["t"]) - 1)
    off = np.array([(e.value if (e := case.on("offset_read", j)) else 0.0)
                    + (e.value if (e := case.on("offset_mount", j)) else 0.0) for j in joints])
    reading = tr["q"][i] + off + rng.normal(0.0, case.noise, (len(t), len(joints)))
    qpos = np.round(reading / TICK) * TICK
    vel = tr["v"][i] + rng.normal(0.0, 0.02, (len(t), len(joints)))
    qvel = np.round(vel / VEL_UNIT) * VEL_UNIT
    return Run(t, goals, qpos, qvel, tr["t"], tr["q"], tr["v"], tr)


def write_log(case: Case, run: Run, path: pathlib.Path) -> None:
    joints = case.joints
    acts = [ACT[j] for j in joints] if case.rig == "finger" else ["servo"]
    cols = (["time", "goal_time"] + [f"goal:{a}" for a in acts] + [f"qpos:{j}" for j in joints]
            + ([f"qvel:{j}" for j in joints] if case.qvel else []))
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        for r in range(len(run.t)):
            row = [f"{run.t[r]:.6f}", f"{run.t[r] + BUS_DELAY:.6f}"]
            row += [f"{x:.9g}" for x in run.goals[r]] + [f"{x:.9g}" for x in run.qpos[r]]
            if case.qvel:
                row += [f"{x:.9g}" for x in run.qvel[r]]
            w.writerow(row)


def truth_dict(case: Case) -> dict:
    return {"case": case.name, "rig": case.rig, "note": case.note,
            "causes": [{"effect": e.catalogue, "kind": e.kind, "joints": list(e.joints),
                        "value": e.value, "extra": list(e.extra),
                        "params": e.truth_params()} for e in case.effects]}


def write_case(case: Case, folder: pathlib.Path) -> dict:
    """Write ``model.xml`` (the user's nominal model), ``log<i>.csv`` and ``truth.json`` into
    ``folder``; returns their paths."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(finger_xml() if case.rig == "finger" else servo_xml())
    rng = np.random.default_rng(case.seed)
    logs = []
    for i, dur in enumerate(case.durations):
        run = make_run(case, dur, i % 3, rng)
        p = folder / f"log{i}.csv"
        write_log(case, run, p)
        logs.append(str(p))
    (folder / "truth.json").write_text(json.dumps(truth_dict(case), indent=1))
    return {"model": str(folder / "model.xml"), "logs": logs,
            "truth": json.loads((folder / "truth.json").read_text())}


def nominal_replay(case: Case, run: Run, dt: float = TRUTH_DT) -> np.ndarray:
    """The user's nominal model (plain mujoco, at ``dt``) driven by ``run``'s goals as the log
    says (held from ``goal_time``), started on the first goal after 1 s at rest: its joint
    angles at the row times (rows x joints)."""
    model = mujoco.MjModel.from_xml_string(finger_xml() if case.rig == "finger" else servo_xml())
    model.opt.timestep = dt
    data = mujoco.MjData(model)
    data.qpos[:] = run.goals[0]
    n0 = int(round(1.0 / dt))
    steps = (np.arange(n0 + int(np.ceil((run.t[-1] + 0.05) / dt))) - n0) * dt
    idx = np.maximum(np.searchsorted(run.t + BUS_DELAY, steps, side="right") - 1, 0)
    out = np.empty((len(steps), model.nq))
    for i in range(len(steps)):
        data.ctrl[:] = run.goals[idx[i]]
        mujoco.mj_step(model, data)
        out[i] = data.qpos
    return out[np.minimum(n0 + np.round(run.t / dt).astype(int), len(out) - 1)]


def effect_size(case: Case) -> dict:
    """How visible the hidden effects are in the case's first log: per joint RMS and max of
    (logged reading - the user's nominal model replayed in plain mujoco), rad. A clean case
    gives the floor (noise, ticks, the servo firmware's discretisation)."""
    run = make_run(case, case.durations[0], 0, np.random.default_rng(case.seed))
    err = run.qpos - nominal_replay(case, run)
    return {"rms": np.sqrt((err ** 2).mean(0)).tolist(), "max": np.abs(err).max(0).tolist()}


# ---------------------------------------------------------------- scoring

# a parameter's "no effect" value (documented units: scale factors 1, sizes 0)
# "creep" 1: coulomb_friction's own null, the model's friction constraint unchanged (gap-fric,
# session 8: its new shape parameter; without it every Coulomb joint counted as named)
NEUTRAL = {"scale": 1.0, "delay": 0.0, "width": 0.0, "offset": 0.0, "frictionloss": 0.0,
           "damping": 0.0, "mu": 0.0, "creep": 1.0, "asymmetry": 0.0, "static": 0.0,
           "coulomb": 0.0}


# shape parameters with no "no effect" value of their own: a Stribeck velocity shapes a level
# coulomb + static exp(-(v / velocity)^2) that is zero whatever it is once coulomb = static = 0
SHAPE = {"stribeck_friction": {"velocity"}}


def _no_effect_here(cause: dict, k: int) -> bool:
    """A cause listed on its k-th joint whose every parameter's 95 % interval there holds its
    "no effect" value (a per-joint effect fitted on every joint, significant on some); shape
    parameters (``SHAPE``) do not count when every other one holds its null."""
    shape = SHAPE.get(cause.get("effect"), set())
    ps = {n: p for n, p in cause.get("params", {}).items() if n not in shape}
    return bool(ps) and all(n in NEUTRAL and p["interval"][k][0] <= NEUTRAL[n] <= p["interval"][k][1]
                            for n, p in ps.items())


def score(report: dict, truth: dict) -> dict:
    """Grade a report.json against ``truth`` (``truth_dict``). Pairs (effect, joint):
    exact = the hidden pairs named and nothing else; extra = the hidden pairs named plus
    others; family = each hidden pair named or a confusable neighbour on that joint and
    nothing unrelated; miss = a hidden pair neither named nor a neighbour; clean/false for
    cases without effects. Parameters whose meaning is documented are checked against
    their 95 % interval. A cause is named on a joint unless every parameter's interval there
    holds its no-effect value (listed as ``idle``: fitted on every joint, not significant)."""
    named, idle = set(), set()
    for c in report.get("causes", []):
        for k, j in enumerate(c["joints"]):
            (idle if _no_effect_here(c, k) else named).add((c["effect"], j))
    hidden = {(c["effect"], j) for c in truth["causes"] for j in c["joints"]}
    names = sorted({f"{e}[{j}]" for e, j in named})
    extra = {"idle": sorted(f"{e}[{j}]" for e, j in idle)}
    if not hidden:
        return {"result": "clean" if not named else "false", "named": names, "params": [],
                **extra}
    fam = {(f, j) for e, j in hidden for f in FAMILY.get(e, set())}
    if hidden <= named:
        result = "exact" if named == hidden else "extra"
    elif all(p in named or any((f, p[1]) in named for f in FAMILY.get(p[0], ())) for p in hidden):
        result = "family" if named <= hidden | fam else "extra_family"
    else:
        result = "miss"
    params = []
    for c in truth["causes"]:
        for pname, tv in c["params"].items():
            for j in c["joints"]:
                for rc in report.get("causes", []):
                    if rc["effect"] == c["effect"] and j in rc["joints"] and pname in rc["params"]:
                        k = rc["joints"].index(j)
                        p = rc["params"][pname]
                        lo, hi = p["interval"][k]
                        params.append({"effect": c["effect"], "param": pname, "joint": j,
                                       "truth": tv, "value": p["value"][k],
                                       "interval": [lo, hi], "inside": bool(lo <= tv <= hi)})
    return {"result": result, "named": names, "params": params, **extra}


# ---------------------------------------------------------------- cases (priority order)

def _f(kind, joints, value, *extra):
    return Effect(kind, tuple(joints.split(",")), value, tuple(extra))


CASES = (
    Case("fin_latency60_prox", "finger", (_f("latency", "prox", 0.060),)),
    Case("srv_stribeck", "servo", (_f("stribeck", "q", 0.08, 0.20, 0.05),),
         note="Coulomb 0.08, breakaway 0.20 N m, Stribeck speed 0.05 rad/s"),
    Case("fin_gain035_abd_50hz_posonly", "finger", (_f("gain", "abd", 0.35),), rate=50.0,
         qvel=False),
    Case("fin_clean_noisy", "finger", (), noise=0.006, note="read noise 6 mrad (4 ticks)"),
    Case("srv_backlash_output", "servo", (_f("backlash", "q", 0.05),),
         note="play 0.05 rad in the gearbox, encoder and loop on the output shaft"),
    Case("fin_backlash080_dist", "finger", (_f("backlash", "dist", 0.08),),
         note="play 0.08 rad between rotor and link, encoder on the rotor side"),
    Case("srv_coulomb_stall_50hz", "servo", (_f("coulomb", "q", 1.2),), rate=50.0,
         note="Coulomb 1.2 N m = 80 % of the 1.5 N m stall torque"),
    Case("fin_clean_jitter_posonly", "finger", (), jitter=0.020, qvel=False,
         note="row interval 10 ms + U(0, 20) ms"),
    Case("fin_offset_read015_prox_50hz_posonly", "finger", (_f("offset_read", "prox", 0.15),),
         rate=50.0, qvel=False),
    Case("fin_mass25_dist", "finger", (_f("mass", "dist", 2.5),)),
    Case("srv_vlimit15", "servo", (_f("vlimit", "q", 1.5),),
         note="torque-speed line: no torque left at 1.5 rad/s"),
    Case("srv_gain25_posonly", "servo", (_f("gain", "q", 2.5),), qvel=False),
    Case("fin_armature04_prox", "finger", (_f("armature", "prox", 0.4),)),
    Case("srv_dirfric_50hz", "servo", (_f("dirfric", "q", 0.15, 0.05),), rate=50.0,
         note="Coulomb 0.15 N m for positive speeds, 0.05 for negative"),
    Case("fin_pair_latency080_abd_backlash050_prox", "finger",
         (_f("latency", "abd", 0.080), _f("backlash", "prox", 0.05))),
    Case("fin_mount_offset020_prox", "finger", (_f("offset_mount", "prox", 0.20),)),
    Case("fin_latency040_all_50hz_posonly", "finger", (_f("latency", "abd,prox,dist", 0.040),),
         rate=50.0, qvel=False),
    Case("fin_pair_gain25_prox_mass04_dist", "finger",
         (_f("gain", "prox", 2.5), _f("mass", "dist", 0.4))),
    Case("fin_stribeck_prox", "finger", (_f("stribeck", "prox", 0.05, 0.12, 0.05),),
         note="Coulomb 0.05, breakaway 0.12 N m, Stribeck speed 0.05 rad/s"),
    Case("srv_latency080", "servo", (_f("latency", "q", 0.080),)),
    Case("srv_clean", "servo", (), note="the firmware's own 1 kHz integer loop only"),
    Case("fin_armature25_abd", "finger", (_f("armature", "abd", 2.5),)),
    Case("fin_offset_read010_dist", "finger", (_f("offset_read", "dist", 0.10),)),
    Case("srv_vlimit10_latency040", "servo", (_f("vlimit", "q", 1.0), _f("latency", "q", 0.04))),
    # gap-fric (session 8): dry friction at 60 % of a plain position actuator's forcerange
    Case("fin_coulomb090_dist", "finger", (_f("coulomb", "dist", 0.9),),
         note="Coulomb 0.9 N m = 60 % of the 1.5 N m forcerange, stiff (sticks)"),
)
CASE_BY_NAME = {c.name: c for c in CASES}
