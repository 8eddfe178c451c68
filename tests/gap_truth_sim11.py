"""An eleventh independent truth simulator for the gap analysis: a user's pan-tilt camera head on
two servos in VELOCITY mode, driven by the user's own python position loop, logged the way a
hobbyist logs (issue 11; gap-sim13, session 26).

Written with mujoco, numpy and the stdlib only (and the sets' one grader, tests/redteam_grade.py),
importing nothing from lowcostdex (no effect, plant, servo or gap code). The earlier sets drive
position servos (every rig), velocity actuators on a one-joint pendulum only (sim4) and torque
(``motor``) fingers; none has a multi-joint rig in velocity mode, where gravity loads one joint
and not the other, the servo's own loop is a velocity loop and the position loop is the host's.

The rig (``model_xml``): a pan-tilt head. ``pan`` turns about the vertical z axis (no gravity
torque) a yoke (60 g) carrying the tilt servo; ``tilt`` turns about the horizontal y axis, 45 mm
above the pan servo, a camera of 250 g whose centre of mass sits 60 mm in front of the tilt axis
(0.147 N m of gravity torque at level, pointing at +x). Each servo is an XL430-class Dynamixel in
velocity mode (Operating Mode 1): the user's model is ``<velocity kv="0.5" forcerange="-1.5 1.5">``
on a joint with ``armature`` 0.004 kg m^2, ``damping`` 0.05 N m s/rad and ``frictionloss`` 0.02
N m. The truth drives ``motor`` actuators with the firmware's law computed here every 0.25 ms
physics step (tau = clip(kv (u - w), -1.5, 1.5), w the velocity of the servo's output encoder);
the user's model runs MuJoCo's own velocity actuator at its 2 ms step.

The user's host loop (100 Hz, +-10 % jitter): read both encoders (4096 ticks per turn after 0.4
mrad of noise), command u = clip(KP_HOST (target - reading), +-VMAX) in Dynamixel velocity units
(0.229 rpm), written right after the read. A failed read (2 % of cycles) skips the whole cycle:
no row, no new command (the last one is held, as the log's zero-order hold says). The logger
writes ``time`` as integer milliseconds of the host's monotonic clock (``--time-unit ms``), angles
in degrees and the velocity goals in deg/s (``--units deg``), no velocity column; in the second
log the user paused the logger for 1.2 s while the loop kept running (a time stamp jump).

Hidden effects (``Effect.kind``), each written here from its physics:

- ``latency``: every command reaches its servo ``value`` s after its row (a USB latency timer
  and the bus).
- ``backlash``: a play of full width ``value`` rad between the servo's gear (the rotor: armature,
  damping, friction, the firmware's torque) and the output; the encoder sits on the output (as a
  Dynamixel's does) so the log reads the output and the firmware's velocity loop reads its rate
  across the play. Where the host holds the joint that loop hunts (a limit cycle: the rotor
  crosses the play, kicks the output, crosses back; 9 mrad RMS at a hold), as such servos do.
- ``gain``: the servo's velocity loop gain (Velocity P Gain) is ``value`` times the model's kv.
- ``offset``: the host reads q + ``value`` (a horn mounted one spline off); the servo and
  gravity see the true angle.
- ``mass``: the camera's mass and inertia are ``value`` times the model's (a heavier lens).
- ``armature``: the servo's reflected rotor inertia is ``value`` times the model's.
- ``friction``: the output's dry friction is ``value`` N m more than the model's (a stiff
  bearing, a cable dragging).
- ``speed``: the motor runs out of torque with speed: the torque available in the direction of
  motion falls linearly from 1.5 N m at rest to 0 at ``value`` rad/s (a low supply voltage),
  the full 1.5 N m against the motion.

``write_case`` writes what a user brings (``model.xml``, ``logs/log<i>.csv``) and
``truth.json`` (``causes`` as catalogue names, ``expected_params``); ``score`` grades a report
with ``redteam_grade.grade`` and ``FAMILIES``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np
import redteam_grade  # the red-team sets' one grader (tests/, no project imports)

TICK = 2 * math.pi / 4096          # rad per encoder tick
VUNIT = 0.229 * 2 * math.pi / 60   # rad/s per Dynamixel velocity unit
TRUTH_DT = 0.00025                 # s
MODEL_DT = 0.002                   # s
NOISE = 0.0004                     # rad, read noise before quantisation
SETTLE = 1.0                       # s held still before the first row
RATE = 100.0                       # Hz, the host loop
DROP = 0.02                        # share of host cycles whose read fails
KP_HOST, VMAX = 8.0, 4.0           # 1/s, rad/s: the host's position loop
KV, FORCE = 0.5, 1.5               # N m s/rad, N m: the servo's velocity loop
ARMATURE, DAMPING, FRICTION = 0.004, 0.05, 0.02
YOKE_MASS, CAM_MASS, CAM_X = 0.06, 0.25, 0.06   # kg, kg, m
JOINTS = ("pan", "tilt")
RANGE = {"pan": (-1.2, 1.2), "tilt": (-0.6, 0.9)}   # host targets [rad]

KINDS = ("latency", "backlash", "gain", "offset", "mass", "armature", "friction", "speed")
CATALOGUE = {"latency": "latency", "backlash": "backlash", "gain": "gain_error",
             "offset": "position_offset", "mass": "mass_error", "armature": "inertia_error",
             "friction": "coulomb_friction", "speed": "velocity_limit"}
PARAM = {"latency": "delay", "backlash": "width", "gain": "scale", "offset": "offset",
         "mass": "scale", "armature": "scale", "friction": "frictionloss", "speed": "speed"}
# Confusable neighbours, from the physics of a velocity-mode servo under a host P loop
# (decided before any run): a slower loop (gain) and a later command (latency) and more
# inertia (armature, mass) all lag the response; a speed limit and a weak loop both cap fast
# moves; dry friction and a play both make a band the host must push through; a reading offset
# and a heavier camera both shift the gravity-held tilt.
FAMILIES = (
    {"gain_error", "latency", "inertia_error", "mass_error", "viscous_damping"},
    {"velocity_limit", "torque_limit", "gain_error"},
    {"coulomb_friction", "stribeck_friction", "gearbox_friction", "load_dependent_friction",
     "backlash", "deadband"},
    {"position_offset", "mounting_offset", "mass_error", "sensor_scale"},
)


@dataclasses.dataclass(frozen=True)
class Effect:
    """Hidden effect ``kind`` of size ``value`` on ``joint`` (latency: both servos)."""

    kind: str
    value: float
    joint: str = "pan"

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
    """Hidden ``effects``; logs of ``durations`` s; ``seed`` for targets, jitter, drops, noise."""

    name: str
    effects: tuple[Effect, ...] = ()
    durations: tuple[float, ...] = (6.0, 6.0, 6.0)
    seed: int = 0
    note: str = ""
    rig: str = "pantilt"
    rate: float = RATE
    qvel: bool = False

    def get(self, kind: str, joint: str | None = None) -> float | None:
        return next((e.value for e in self.effects if e.kind == kind
                     and (joint is None or joint in e.joints)), None)

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects}

    @property
    def args(self) -> tuple[str, ...]:
        return ("--units", "deg", "--time-unit", "ms")


def _camera(mass_scale: float) -> str:
    m = CAM_MASS * mass_scale
    # a 90 x 60 x 60 mm box about its centre (its inertia), the centre 60 mm ahead of the axis
    ixx, iyy = m * (0.06 ** 2 + 0.06 ** 2) / 12, m * (0.09 ** 2 + 0.06 ** 2) / 12
    return (f'<inertial pos="{CAM_X} 0 0" mass="{m:.9g}" '
            f'diaginertia="{ixx:.6g} {iyy:.6g} {iyy:.6g}"/>'
            f'<geom type="box" pos="{CAM_X} 0 0" size="0.045 0.03 0.03" mass="0"/>')


def _yoke() -> str:
    return (f'<inertial pos="0 0 0.02" mass="{YOKE_MASS}" diaginertia="2e-5 2e-5 1e-5"/>'
            f'<geom type="box" pos="0 0 0.02" size="0.02 0.03 0.02" mass="0"/>')


def model_xml(case: Case | None = None, timestep: float = MODEL_DT) -> str:
    """The head's MJCF: the user's nominal model (``case`` None: ``velocity`` actuators named
    after their joints) or the truth for ``case`` (``motor`` actuators on the rotor joints the
    caller drives with the firmware's law; a play joint ``<j>_play`` after a backlash's rotor;
    the case's armature, friction and camera mass written in)."""
    def servo(j: str, play: bool) -> str:
        arm = ARMATURE * ((case.get("armature", j) or 1.0) if case else 1.0)
        fric = FRICTION + ((case.get("friction", j) or 0.0) if case else 0.0)
        # with a play the friction of the bearing sits on the output, the gear's on the rotor
        if play:
            return (f'armature="{arm:.9g}" damping="{DAMPING}" frictionloss="{FRICTION}"',
                    f'frictionloss="{fric - FRICTION:.9g}"')
        return (f'armature="{arm:.9g}" damping="{DAMPING}" frictionloss="{fric:.9g}"', "")

    def joint(j: str, axis: str, inner: str) -> str:
        w = case.get("backlash", j) if case else None
        rotor, out = servo(j, bool(w))
        if not w:
            return f'<joint name="{j}" axis="{axis}" {rotor}/>{inner}'
        return (f'<joint name="{j}_rotor" axis="{axis}" {rotor}/>'
                f'<geom type="cylinder" size="0.005 0.002" mass="0.001"/>'
                f'<body name="{j}_output"><joint name="{j}_play" axis="{axis}" limited="true" '
                f'range="{-w / 2:.9g} {w / 2:.9g}" solreflimit="0.0005 1" solimplimit="0.99 0.999 0.0005" {out}/>{inner}</body>')

    scale = (case.get("mass", "tilt") or 1.0) if case else 1.0
    tilt = f'<body name="camera" pos="0 0 0.045">{joint("tilt", "0 1 0", _camera(scale))}</body>'
    pan = f'<body name="yoke" pos="0 0 0.1">{joint("pan", "0 0 1", _yoke() + tilt)}</body>'
    if case is None:
        acts = "\n".join(f'<velocity name="{j}" joint="{j}" kv="{KV}" forcelimited="true" '
                         f'forcerange="{-FORCE} {FORCE}" ctrllimited="true" '
                         f'ctrlrange="-6.5 6.5"/>' for j in JOINTS)
    else:
        acts = "\n".join(f'<motor name="{j}" joint="{j}{"_rotor" if case.get("backlash", j) else ""}" '
                         f'ctrllimited="false"/>' for j in JOINTS)
    return (f'<mujoco model="pantilt">\n<compiler angle="radian"/>\n'
            f'<option timestep="{timestep:.9g}" integrator="implicitfast"/>\n'
            f'<default><geom contype="0" conaffinity="0"/></default>\n'
            f'<worldbody>\n{pan}\n</worldbody>\n<actuator>\n{acts}\n</actuator>\n</mujoco>\n')


def firmware_torque(u: float, w: float, gain: float = 1.0, speed: float | None = None) -> float:
    """The servo's velocity loop [N m]: kv gain (u - w) for command ``u`` and output rate ``w``
    [rad/s], clipped to the torque the motor has at ``w``: 1.5 N m against the motion, and with
    a no-load ``speed`` 1.5 (1 - |w| / speed) (not below 0) along it."""
    tau = gain * KV * (u - w)
    hi = lo = FORCE
    if speed is not None:
        along = FORCE * min(max(1.0 - abs(w) / speed, 0.0), 1.0)
        if w > 0:
            hi = along
        elif w < 0:
            lo = along
    return float(min(max(tau, -lo), hi))


def host_times(duration: float, rng: np.random.Generator) -> np.ndarray:
    """The host loop's cycle times [s]: from -SETTLE (the loop holding the first target before
    the logger starts at 0) to ``duration``, the period with +-10 % jitter."""
    n = int((duration + SETTLE) * RATE) + 2
    t = np.concatenate([[0.0], np.cumsum((1.0 + rng.uniform(-0.1, 0.1, n)) / RATE)]) - SETTLE
    return t[t <= duration]


def targets(joint: str, style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The host's targets [rad] at times ``t``: ``steps`` (held 0.5-1.3 s) or ``sine`` (a
    0.2-0.6 Hz sine plus a slower one) inside the joint's range."""
    lo, hi = RANGE[joint]
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    if style == "steps":
        edges = np.cumsum(rng.uniform(0.5, 1.3, int(t[-1] / 0.5) + 2))   # from t = 0
        levels = mid + half * rng.uniform(-0.95, 0.95, len(edges) + 1)
        return levels[np.searchsorted(edges, t, side="right")]
    f1, f2 = rng.uniform(0.2, 0.6), rng.uniform(0.05, 0.12)
    p1, p2 = rng.uniform(0, 2 * math.pi, 2)
    return mid + half * (0.6 * np.sin(2 * math.pi * f1 * t + p1)
                         + 0.3 * np.sin(2 * math.pi * f2 * t + p2))


def simulate(case: Case, t: np.ndarray, target: dict[str, np.ndarray],
             rng: np.random.Generator, drop: float = DROP, true_angles: bool = False
             ) -> dict[str, np.ndarray]:
    """Run the truth and the host loop over cycles ``t`` [s] (from the first) toward
    ``target`` [rad]. Returns
    per cycle ``ok`` (1: the read succeeded and a row exists), ``goal:<j>`` [rad/s] (the
    command written, quantised) and ``qpos:<j>`` [rad] (the host's reading; with ``true_angles``
    also ``true:<j>``, the output's angle, and ``rotor:<j>``, the gear's)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case, TRUTH_DT))
    d = mujoco.MjData(m)
    play = {j: case.get("backlash", j) is not None for j in JOINTS}
    motor = {j: m.joint(f"{j}_rotor" if play[j] else j).id for j in JOINTS}
    out_j = {j: m.joint(f"{j}_play").id for j in JOINTS if play[j]}
    act = {j: m.actuator(j).id for j in JOINTS}
    gain = {j: case.get("gain", j) or 1.0 for j in JOINTS}
    speed = {j: case.get("speed", j) for j in JOINTS}
    offset = {j: case.get("offset", j) or 0.0 for j in JOINTS}
    delay = case.get("latency") or 0.0

    def angle(j: str) -> float:
        q = float(d.qpos[m.jnt_qposadr[motor[j]]])
        return q + (float(d.qpos[m.jnt_qposadr[out_j[j]]]) if j in out_j else 0.0)

    def rate(j: str) -> float:
        w = float(d.qvel[m.jnt_dofadr[motor[j]]])
        return w + (float(d.qvel[m.jnt_dofadr[out_j[j]]]) if j in out_j else 0.0)

    for j in JOINTS:   # start at the first target (the host holds it until the logger starts)
        d.qpos[m.jnt_qposadr[motor[j]]] = target[j][0]
    mujoco.mj_forward(m, d)
    n = len(t)
    ok = rng.uniform(size=n) >= drop
    ok[0] = True
    res = {"ok": ok.astype(float)}
    res |= {f"goal:{j}": np.full(n, np.nan) for j in JOINTS}
    res |= {f"qpos:{j}": np.full(n, np.nan) for j in JOINTS}
    if true_angles:
        res |= {f"{k}:{j}": np.full(n, np.nan) for k in ("true", "rotor") for j in JOINTS}
    steps = np.round((t - t[0]) / TRUTH_DT).astype(int)
    queue: list[tuple[int, dict[str, float]]] = []
    cmd = {j: 0.0 for j in JOINTS}
    r = 0
    for s in range(steps[-1] + 1):
        while r < n and s == steps[r]:
            if ok[r]:
                u = {}
                for j in JOINTS:
                    read = angle(j) + offset[j] + rng.normal(0.0, NOISE)
                    read = float(np.round(read / TICK) * TICK)
                    v = float(np.clip(KP_HOST * (target[j][r] - read), -VMAX, VMAX))
                    u[j] = float(np.round(v / VUNIT) * VUNIT)
                    res[f"qpos:{j}"][r], res[f"goal:{j}"][r] = read, u[j]
                    if true_angles:
                        res[f"true:{j}"][r] = angle(j)
                        res[f"rotor:{j}"][r] = float(d.qpos[m.jnt_qposadr[motor[j]]])
                queue.append((s + round(delay / TRUTH_DT), u))
            r += 1
        while queue and queue[0][0] <= s:
            cmd = queue.pop(0)[1]
        for j in JOINTS:
            d.ctrl[act[j]] = firmware_torque(cmd[j], rate(j), gain[j], speed[j])
        mujoco.mj_step(m, d)
    if not np.all(np.isfinite(d.qpos)):
        raise RuntimeError(f"{case.name}: the truth simulation diverged")
    return res


PAUSE = (2.5, 3.7)   # s: the logger paused (second log) while the loop ran on


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml``, ``logs/log<i>.csv`` (integer ms stamps of a clock at 4711.2 s, angles
    in degrees, velocity goals in deg/s, failed reads' rows absent, the second log's pause) and
    ``truth.json`` into ``folder``. Returns {"model", "logs", "args", "truth"}."""
    folder = pathlib.Path(folder)
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml())
    rng = np.random.default_rng(case.seed)
    clock = 4711.2
    for i, dur in enumerate(case.durations):
        t = host_times(dur, rng)
        style = ("steps", "sine")[i % 2]
        cols = simulate(case, t, {j: targets(j, style, t, rng) for j in JOINTS}, rng)
        keep = (cols["ok"] > 0) & (t >= 0.0)
        if i == 1:
            keep &= (t < PAUSE[0]) | (t >= PAUSE[1])
        stamp = np.floor((t[keep] + clock) * 1e3)
        clock += dur + 20.0
        data = [stamp] + [np.degrees(cols[f"{k}:{j}"][keep]) for k in ("goal", "qpos")
                          for j in JOINTS]
        names = ["time"] + [f"{k}:{j}" for k in ("goal", "qpos") for j in JOINTS]
        np.savetxt(folder / "logs" / f"log{i}.csv", np.column_stack(data), delimiter=",",
                   header=",".join(names), comments="",
                   fmt=["%d"] + ["%.4f"] * (len(names) - 1))
    truth = {"case": case.name, "causes": sorted(case.causes),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case), "args": list(case.args)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": [str(folder / "logs")],
            "args": list(case.args), "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Each hidden effect's catalogue parameter on its joint(s) (a play's width, the offset
    and the friction added, the factors, the no-load speed, the delay)."""
    return [dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=j, value=e.value,
                 **({"abs": True} if e.kind == "offset" else {}))
            for e in case.effects for j in e.joints]


def score(report: dict, truth: dict) -> dict:
    """``redteam_grade.grade`` of ``report`` against ``truth`` with this set's FAMILIES."""
    return redteam_grade.grade(report, truth, FAMILIES)


E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_pantilt", (), durations=(4.0, 4.0, 4.0), seed=131,
         note="no hidden effect; degrees, ms stamps, no velocity, dropped reads, a pause"),
    Case("clean_pantilt_long", (), durations=(8.0, 8.0, 8.0), seed=132,
         note="no hidden effect, three 8 s logs"),
    Case("latency50", (E("latency", 0.050),), seed=133,
         note="50 ms from row to servo on both"),
    Case("backlash_pan", (E("backlash", 0.04, "pan"),), seed=134,
         note="40 mrad play in the pan servo, output encoder, loop across the play"),
    Case("friction_pan", (E("friction", 0.25, "pan"),), seed=135,
         note="+0.25 N m dry friction on the pan (1/6 of the stall torque)"),
    Case("speed_pan", (E("speed", 2.0, "pan"),), seed=136,
         note="pan motor's no-load speed 2 rad/s (host asks up to 4)"),
    Case("gain_tilt", (E("gain", 2.5, "tilt"),), seed=137,
         note="tilt's Velocity P Gain 2.5x the model's kv"),
    Case("offset_tilt", (E("offset", 0.15, "tilt"),), seed=138,
         note="the host reads the tilt 0.15 rad high (gravity sees the true angle)"),
    Case("mass_tilt", (E("mass", 2.0, "tilt"),), seed=139,
         note="the camera weighs 2x the model's (500 g)"),
    Case("armature_pan", (E("armature", 3.0, "pan"),), seed=140,
         note="pan servo's rotor inertia 3x the model's"),
    Case("latency_backlash", (E("latency", 0.030), E("backlash", 0.04, "pan")), seed=141,
         note="30 ms on both + 40 mrad play on the pan"),
    Case("offset_gain_tilt", (E("offset", -0.12, "tilt"), E("gain", 0.5, "tilt")), seed=142,
         note="the tilt read 0.12 rad low and its velocity loop at half gain"),
    Case("friction_pan_mass_tilt", (E("friction", 0.25, "pan"), E("mass", 2.0, "tilt")),
         seed=143, note="+0.25 N m on the pan and the 2x camera"),
)
CASE_BY_NAME = {c.name: c for c in CASES}
