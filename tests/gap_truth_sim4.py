"""A fourth independent truth simulator for the gap analysis: the holes of the coverage audit
(issue 11 items 1, 2 and 4; gap-judge9, session 15).

Written with mujoco, numpy and the stdlib only, importing nothing from lowcostdex (no effect,
plant, servo or gap code) and not reusing the earlier truth simulators' physics. Where the first
three test ``position`` actuators (and ``general`` / ``intvelocity`` written as position servos)
at mid-range sizes, this one takes what the audit found untested (bench/RESULTS.md, gap-judge9):

- a user's ``velocity`` actuator (the log's goal is a velocity command [rad/s] from the host's
  own position loop, as a Dynamixel in velocity mode is driven) and a ``motor`` actuator (the
  goal is the torque [N m] a host-side PD wrote): no analysis case covered either but a latency
  on a motor;
- range edges: a gain of 3x on a ``position`` actuator WITH kv, an armature of 3x on a
  ``general`` servo, a link mass of 0.3x, a velocity loop gain of 0.4x;
- a pair on ONE joint: a 50 ms latency and a reading offset of -0.2 rad.

One rig, written four ways: ``pendulum``, a hinge about a horizontal axis (gravity), a rod and a
tip mass. Per actuator kind (``KINDS``) the nominal numbers are a servo of that class:

- ``velocity``: ``<velocity kv forcerange>`` (a velocity-mode servo's loop, kv 0.6 N m s/rad,
  +-1.5 N m); host loop at the log rate: goal = clip(KP_V (target - reading), +-VMAX).
- ``motor``: ``<motor ctrlrange>`` +-1 N m; host PD at the log rate on the readings:
  goal = clip(KP_M (target - reading) - KD_M (reading - last reading) / row interval, +-1).
- ``position``: ``<position kp kv forcerange>`` kp 5, kv 0.1, +-2 N m.
- ``general``: ``<general gainprm="kp" biasprm="0 -kp -kv" forcerange>`` kp 4, kv 0.08.
- ``dcmotor``: MuJoCo's own ``<dcmotor input="pos" nominal="12 1.5 6" controller="kp 0 kd 0 0
  12">`` (kp 4, kd 0.1; back-EMF and the drive clamped at Vmax 12 V are MuJoCo's: without a
  Vmax its controller is not clamped at all, a 6 N m push from a 1.5 N m motor).
- ``dcmotor_unclamped``: the same dcmotor written as MuJoCo's default leaves it, Vmax 0 (no drive
  limit: its torque kp (goal - q) - kd qdot is never clamped; a user's model with no stall).

Hidden effects, written here from their physics (``Effect.kind``):

- ``latency``: each goal reaches the actuator ``value`` s after its row (continuous time; the
  host's loop still reads at the row).
- ``reading_offset``: the log (and a host loop) reads q + ``value``; a position servo holds the
  true angle at its goal (a host-side calibration error).
- ``gain``: the actuator's loop gain times ``value``: kp on ``position`` / ``general`` (kv
  kept), the controller's kp on ``dcmotor`` (kd kept), kv (the whole velocity loop: gain and
  bias) on ``velocity``, the torque per command on ``motor``.
- ``viscous``: a torque -``value`` qdot applied to the joint by this module.
- ``coulomb``: dry friction of ``value`` N m (MuJoCo's frictionloss, made stiff: it sticks).
- ``inertia``: the joint armature times ``value``. ``mass``: rod and tip masses times ``value``.
- ``torque_limit`` (``motor``): the motor delivers at most ``value`` N m whatever it is commanded
  (a current limit below the host's command range).

Logs (the project's CSV format): rows at 100 Hz (or 50 Hz) with jitter, goals held from their
row, reads quantised to 4096 ticks per turn with read noise, ``qvel`` in Dynamixel units (0.229
rpm) or absent. The truth physics runs at 0.25 ms (implicitfast), the user's model at 2 ms.
``write_case`` writes what a user would bring and a ``truth.json`` in the form
``gap_truth_sim2.score`` grades.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np

# the one scorer of the red-team sets (exact / extra / family / miss / clean / false, intervals
# holding the truth): grading is not physics, and two graders would drift apart
from gap_truth_sim2 import score  # noqa: F401

TICK = 2 * math.pi / 4096           # rad per encoder tick
VEL_UNIT = 0.229 * 2 * math.pi / 60  # rad/s per Dynamixel velocity unit
TRUTH_DT = 0.00025                   # s, truth physics step
MODEL_DT = 0.002                     # s, the user's model step
NOISE = 0.0005                       # rad, read noise before quantisation
SETTLE = 1.0                         # s run (host loop included) before the first logged row

KINDS = ("velocity", "motor", "position", "general", "dcmotor", "dcmotor_unclamped")
# host loops of the velocity- and torque-commanded kinds
KP_V, VMAX = 4.0, 3.0                # 1/s, rad/s
KP_M, KD_M, UMAX = 3.0, 0.12, 1.0    # N m/rad, N m s/rad, N m

# per kind: rod mass, tip mass [kg], link length [m], armature [kg m^2], joint damping
# [N m s/rad], actuator numbers
NOMINAL = {
    "velocity": dict(rod=0.03, tip=0.10, length=0.10, armature=0.002, damping=0.01,
                     kv=0.6, force=1.5),
    "motor": dict(rod=0.04, tip=0.20, length=0.12, armature=0.003, damping=0.05, force=UMAX),
    "position": dict(rod=0.08, tip=0.30, length=0.15, armature=0.004, damping=0.02,
                     kp=5.0, kv=0.1, force=2.0),
    "general": dict(rod=0.05, tip=0.20, length=0.12, armature=0.004, damping=0.02,
                    kp=4.0, kv=0.08, force=2.0),
    # MuJoCo's own dcmotor (12 V, 1.5 N m stall, 6 rad/s no-load: an XL430-class motor at the
    # output) on position input with its controller's kp and kd
    "dcmotor": dict(rod=0.04, tip=0.20, length=0.12, armature=0.003, damping=0.02,
                    kp=4.0, kv=0.1, force=1.5, volts=12.0, no_load=6.0),
    # the same motor and controller with no drive limit (controller Vmax 0)
    "dcmotor_unclamped": dict(rod=0.04, tip=0.20, length=0.12, armature=0.003, damping=0.02,
                              kp=4.0, kv=0.1, force=1.5, volts=12.0, no_load=6.0, vmax=0.0),
}
GOAL_RANGE = (-1.0, 1.0)             # rad, targets of the excitation
EFFECTS = ("latency", "reading_offset", "gain", "viscous", "coulomb", "inertia", "mass",
           "torque_limit")
CATALOGUE = {"latency": "latency", "reading_offset": "position_offset", "gain": "gain_error",
             "viscous": "viscous_damping", "coulomb": "coulomb_friction",
             "inertia": "inertia_error", "mass": "mass_error", "torque_limit": "torque_limit"}
PARAM = {"latency": "delay", "reading_offset": "offset", "gain": "scale", "viscous": "damping",
         "coulomb": "frictionloss", "inertia": "scale", "mass": "scale", "torque_limit": "torque"}
JOINT, ACTUATOR = "hinge", "servo"


@dataclasses.dataclass(frozen=True)
class Effect:
    """One hidden effect ``kind`` of size ``value`` (s, rad, a factor or N m s/rad)."""

    kind: str
    value: float
    joints: tuple[str, ...] = (JOINT,)  # the rig's one joint (the red-team harness reads it)

    def __post_init__(self):
        if self.kind not in EFFECTS:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {', '.join(EFFECTS)}")


@dataclasses.dataclass(frozen=True)
class Case:
    """A case: actuator ``kind``, hidden ``effects``, logs of ``durations`` s at ``rate`` Hz in
    trajectory ``styles`` (cycled), with a ``qvel`` column or not."""

    name: str
    kind: str
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0
    durations: tuple[float, ...] = (12.0, 12.0)
    styles: tuple[str, ...] = ("steps", "sine")
    jitter: float = 0.15
    qvel: bool = True
    seed: int = 0
    note: str = ""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown actuator kind {self.kind!r}; valid: {', '.join(KINDS)}")

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects}

    @property
    def rig(self) -> str:
        return f"pendulum_{self.kind}"

    def size(self, kind: str, default: float) -> float:
        return next((e.value for e in self.effects if e.kind == kind), default)


def model_xml(kind: str, case: Case | None = None, timestep: float = MODEL_DT) -> str:
    """The rig's MJCF: nominal (``case`` None: what the user hands to ``gap analyze``) or the
    truth with ``case``'s gain, inertia and mass effects written into it."""
    p = NOMINAL[kind]
    gain = case.size("gain", 1.0) if case else 1.0
    mass = case.size("mass", 1.0) if case else 1.0
    arm = p["armature"] * (case.size("inertia", 1.0) if case else 1.0)
    dry = case.size("coulomb", 0.0) if case else 0.0
    # dry friction as MuJoCo's frictionloss constraint made stiff (true stiction: the default
    # soft constraint creeps at a few cm/s below its level)
    fric = (f' frictionloss="{dry:.9g}" solreffriction="0.0005 1" '
            f'solimpfriction="0.999 0.9999 0.001"' if dry else "")
    f = p["force"]
    lim = f'forcelimited="true" forcerange="{-f:.9g} {f:.9g}"'
    if kind == "velocity":
        act = f'<velocity name="{ACTUATOR}" joint="{JOINT}" kv="{p["kv"] * gain:.9g}" {lim}/>'
    elif kind == "motor":
        cap = case.size("torque_limit", 0.0) if case else 0.0
        cap = f' forcelimited="true" forcerange="{-cap:.9g} {cap:.9g}"' if cap else ""
        act = (f'<motor name="{ACTUATOR}" joint="{JOINT}" gear="{gain:.9g}" ctrllimited="true" '
               f'ctrlrange="{-f:.9g} {f:.9g}"{cap}/>')
    elif kind == "position":
        act = (f'<position name="{ACTUATOR}" joint="{JOINT}" kp="{p["kp"] * gain:.9g}" '
               f'kv="{p["kv"]:.9g}" {lim}/>')
    elif kind.startswith("dcmotor"):
        act = (f'<dcmotor name="{ACTUATOR}" joint="{JOINT}" input="pos" '
               f'nominal="{p["volts"]:.9g} {f:.9g} {p["no_load"]:.9g}" '
               f'controller="{p["kp"] * gain:.9g} 0 {p["kv"]:.9g} 0 0 '
               f'{p.get("vmax", p["volts"]):.9g}"/>')
    else:
        kp = p["kp"] * gain
        act = (f'<general name="{ACTUATOR}" joint="{JOINT}" gaintype="fixed" biastype="affine" '
               f'gainprm="{kp:.9g}" biasprm="0 {-kp:.9g} {-p["kv"]:.9g}" {lim}/>')
    length = p["length"]
    return (f'<mujoco model="pendulum_{kind}"><compiler angle="radian"/>'
            f'<option timestep="{timestep:.9g}" integrator="implicitfast"/>'
            f'<default><geom contype="0" conaffinity="0"/></default><worldbody>'
            f'<body name="link" pos="0 0 0.3"><joint name="{JOINT}" type="hinge" axis="0 1 0" '
            f'damping="{p["damping"]:.9g}" armature="{arm:.9g}"{fric}/>'
            f'<geom type="capsule" fromto="0 0 0 0 0 {-length:.9g}" size="0.01" '
            f'mass="{p["rod"] * mass:.9g}"/>'
            f'<geom type="sphere" pos="0 0 {-length:.9g}" size="0.02" '
            f'mass="{p["tip"] * mass:.9g}"/></body></worldbody>'
            f'<actuator>{act}</actuator></mujoco>')


def row_times(duration: float, rate: float, jitter: float, rng: np.random.Generator
              ) -> np.ndarray:
    """Host row times [s] from -SETTLE (rows before 0 are run, not logged): the period plus
    uniform jitter of +-``jitter`` periods, 1 % of rows a period late."""
    period = 1.0 / rate
    n = int((duration + SETTLE) * rate)
    steps = period * (1.0 + rng.uniform(-jitter, jitter, n))
    steps[rng.random(n) < 0.01] += period
    return np.cumsum(steps) - SETTLE


def targets(style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Target angles [rad] at times ``t`` (held at the first target before 0)."""
    lo, hi = GOAL_RANGE
    mid, amp = (lo + hi) / 2, (hi - lo) / 2
    tt = np.maximum(t, 0.0)
    if style == "steps":
        edges = np.cumsum(rng.uniform(0.5, 1.4, int(t[-1] / 0.5) + 2))
        levels = mid + amp * rng.uniform(0.15, 0.95, len(edges) + 1) * \
            np.where(np.arange(len(edges) + 1) % 2 == 0, 1.0, -1.0)
        return levels[np.searchsorted(edges, tt, side="right")]
    if style == "sine":
        f = rng.uniform(0.3, 0.7)
        return mid + 0.75 * amp * np.sin(2 * np.pi * f * tt + rng.uniform(0.5, 1.0))
    if style == "chirp":
        f0, f1, T = 0.1, 2.0, t[-1]
        return mid + 0.6 * amp * np.sin(2 * np.pi * (f0 * tt + (f1 - f0) * tt ** 2 / (2 * T)))
    raise ValueError(f"unknown style {style!r}; valid: steps, sine, chirp")


def simulate(case: Case, t_rows: np.ndarray, target: np.ndarray, rng: np.random.Generator
             ) -> dict[str, np.ndarray]:
    """Run the truth through one log. Returns per row: ``goal`` (what the host wrote: the target
    for position kinds, the host loop's command for velocity/motor), ``qpos`` (read, noisy,
    quantised, offset included), ``qvel`` (Dynamixel units, quantised)."""
    model = mujoco.MjModel.from_xml_string(model_xml(case.kind, case, TRUTH_DT))
    data = mujoco.MjData(model)
    latency = case.size("latency", 0.0)
    offset = case.size("reading_offset", 0.0)
    visc = case.size("viscous", 0.0)
    n = len(t_rows)
    noise = rng.normal(0.0, NOISE, n)
    vnoise = rng.normal(0.0, 0.3 * VEL_UNIT, n)
    goal, qpos, qvel = np.empty(n), np.empty(n), np.empty(n)
    pending: list[tuple[float, float]] = []      # (when it acts, value), in time order
    host = case.kind in ("velocity", "motor")
    # start at rest at the first target; a host-commanded kind starts with no command
    data.qpos[0] = target[0]
    data.ctrl[0] = 0.0 if host else target[0]
    mujoco.mj_forward(model, data)
    t = t_rows[0] - TRUTH_DT
    row, last = 0, None
    while row < n:
        while row < n and t_rows[row] <= t + TRUTH_DT / 2:
            r = np.round((data.qpos[0] + offset + noise[row]) / TICK) * TICK
            if case.kind == "velocity":
                g = float(np.clip(KP_V * (target[row] - r), -VMAX, VMAX))
            elif case.kind == "motor":
                dt_row = t_rows[row] - t_rows[row - 1] if row else 1.0 / case.rate
                d = 0.0 if last is None else (r - last) / dt_row
                g = float(np.clip(KP_M * (target[row] - r) - KD_M * d, -UMAX, UMAX))
            else:
                g = float(target[row])
            last = r
            goal[row], qpos[row] = g, r
            qvel[row] = np.round((data.qvel[0] + vnoise[row]) / VEL_UNIT) * VEL_UNIT
            pending.append((t_rows[row] + latency, g))
            row += 1
        while pending and pending[0][0] <= t + TRUTH_DT / 2:
            data.ctrl[0] = pending.pop(0)[1]
        if visc:
            data.qfrc_applied[0] = -visc * data.qvel[0]
        mujoco.mj_step(model, data)
        t += TRUTH_DT
    if not np.all(np.isfinite(qpos)):
        raise RuntimeError(f"{case.name}: the truth simulation diverged")
    return {"goal": goal, "qpos": qpos, "qvel": qvel}


def expected_params(case: Case) -> list[dict]:
    """Each hidden cause's catalogue parameter as sim2's ``score`` reads it."""
    return [dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=JOINT, value=e.value,
                 abs=e.kind == "reading_offset") for e in case.effects]


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (nominal), ``log<i>.csv`` and ``truth.json`` into ``folder``.
    Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml(case.kind))
    rng = np.random.default_rng(case.seed)
    logs = []
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.rate, case.jitter, rng)
        out = simulate(case, t, targets(case.styles[i % len(case.styles)], t, rng), rng)
        keep = t >= 0.0
        cols = {"time": t[keep] + 0.02, f"goal:{ACTUATOR}": out["goal"][keep],
                f"qpos:{JOINT}": out["qpos"][keep]}
        if case.qvel:
            cols[f"qvel:{JOINT}"] = out["qvel"][keep]
        path = folder / f"log{i}.csv"
        np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.9g")
        logs.append(str(path))
    truth = {"case": case.name, "kind": case.kind, "causes": sorted(case.causes),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": logs, "truth": truth}


E = Effect
# priority order (the audit's worst holes first)
CASES: tuple[Case, ...] = (
    Case("clean_velocity", "velocity", (), seed=41, note="no hidden effect on a new kind"),
    Case("gain04_velocity", "velocity", (E("gain", 0.4),), seed=42,
         note="the velocity loop's kv x0.4"),
    Case("viscous_motor_posonly", "motor", (E("viscous", 0.04),), qvel=False, seed=43,
         note="+0.04 N m s/rad beside the nominal 0.05 (issue 11: viscous named load friction)"),
    Case("latency050_offsetm020_position", "position",
         (E("latency", 0.050), E("reading_offset", -0.20)), seed=44,
         note="a pair on one joint at the offset range's edge"),
    Case("mass03_motor_posonly", "motor", (E("mass", 0.3),), qvel=False, seed=45,
         note="the mass range's lower edge on a torque-driven joint"),
    Case("gain30_position", "position", (E("gain", 3.0),), styles=("steps", "chirp"), seed=46,
         note="the gain range's upper edge on a position actuator with kv"),
    Case("inertia30_general_50hz", "general", (E("inertia", 3.0),), rate=50.0,
         styles=("chirp", "steps"), seed=47, note="the inertia range's upper edge"),
    Case("clean_motor_posonly", "motor", (), qvel=False, seed=48),
    Case("gain05_dcmotor", "dcmotor", (E("gain", 0.5),), seed=49,
         note="MuJoCo's own dcmotor, its controller's kp x0.5"),
    Case("latency030_dcmotor_posonly", "dcmotor", (E("latency", 0.030),), qvel=False, seed=50),
    Case("latency080_velocity", "velocity", (E("latency", 0.080),), seed=51,
         note="the latency range's upper edge on a velocity-commanded joint"),
    Case("coulomb060_motor_posonly", "motor", (E("coulomb", 0.6),), qvel=False, seed=52,
         note="dry friction at 60 % of the 1 N m torque command range"),
    Case("gain03_general", "general", (E("gain", 0.3),), styles=("steps", "chirp"), seed=53,
         note="the gain range's lower edge"),
    Case("mass30_general", "general", (E("mass", 3.0),), seed=54,
         note="the mass range's upper edge (the catalogue's search bound)"),
    Case("torque_limit06_motor_posonly", "motor", (E("torque_limit", 0.6),), qvel=False, seed=55,
         note="60 % of the host's +-1 N m commands delivered at most"),
    Case("gain05_motor", "motor", (E("gain", 0.5),), seed=56, note="half the torque per command"),
    Case("coulomb020_dcmotor_unclamped", "dcmotor_unclamped", (E("coulomb", 0.2),), seed=57,
         note="dry friction on a dcmotor with no drive limit (no stall torque to bound it)"),
)
CASE_BY_NAME = {c.name: c for c in CASES}


def effect_size(case: Case) -> dict:
    """How far each log of ``case`` is from the user's nominal model replayed open loop in plain
    mujoco (2 ms, the logged goals held from their rows, from the first logged reading at rest):
    {"rms": [rad], "max": [rad]} over the logs (one joint). A clean case sits near the read
    floor; a hidden effect well above it."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        files = write_case(case, tmp)
        logs = [np.genfromtxt(p, delimiter=",", names=True) for p in files["logs"]]
    model = mujoco.MjModel.from_xml_string(model_xml(case.kind))
    errs = []
    for a in logs:
        t, g, q = a["time"], a[f"goal{ACTUATOR}"], a[f"qpos{JOINT}"]
        data = mujoco.MjData(model)
        data.qpos[0] = q[0]
        sim_q = np.empty(len(t))
        tt, k = t[0], 0
        while k < len(t):
            while k < len(t) and t[k] <= tt + MODEL_DT / 2:
                sim_q[k] = data.qpos[0]
                data.ctrl[0] = g[k]
                k += 1
            mujoco.mj_step(model, data)
            tt += MODEL_DT
        errs.append(q - sim_q)
    e = np.concatenate(errs)
    return {"rms": [float(np.sqrt(np.mean(e ** 2)))], "max": [float(np.abs(e).max())]}
