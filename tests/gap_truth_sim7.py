"""A seventh independent truth simulator for the gap analysis: the two rows of the reference's
hidden-effect table (04-sysid.md section 6) no earlier set has, a sensor scale (gear-ratio)
error and delay jitter / dropped goal packets (issue 11; gap-scale16, session 21).

Written with mujoco, numpy and the stdlib only, importing nothing from lowcostdex (no effect,
plant, servo or gap code). The user's side is what the docs say (docs/gap_analysis.md: the CSV
log format; a plain MJCF ``position`` actuator with kp, kv and a force range).

Rig: a one-joint servo bench: a hinge about the horizontal y axis, an arm of 150 g with its
centre of mass 60 mm from the axis (hanging down at 0), rotor armature 2 g m^2 and gear damping
0.01 N m s/rad. The servo is a position loop at the truth's step (kp 4 N m/rad, kv 0.06 N m
s/rad, torque clipped to +-1.5 N m) computed here on the servo's own (true) encoder angle and
applied through a ``motor`` actuator; the user's model is ``<position kp="4" kv="0.06"
forcerange="-1.5 1.5">`` at MuJoCo's default 2 ms step.

Hidden effects (``Effect.kind``), written from their physics:

* ``scale``: the angle the host reads is (1 + ``value``) q (an output encoder read through a
  wrong gear ratio or ticks per turn: 4000 for 4096 is -2.3 %, 4095 for 4096 +0.02 %); the servo
  closes its loop on its own encoder and holds the goal in the true angle. The residual grows
  with the angle (r = value q). Scored as ``sensor_scale`` with ``scale`` = 1 + value.
* ``offset``: the reading is further shifted by ``value`` rad (after the scale: reading =
  (1 + s) q + offset). Scored as ``position_offset``.
* ``jitter``: each row's goal reaches the servo ``k`` log periods late, ``k`` drawn uniformly
  from {0, ..., ``value``} per row (the servo then holds the goal of row i - k_i: a USB-serial
  latency timer, an OS scheduler, a busy bus; goals may arrive out of order). A serious tool
  names the mean latency (``value`` / 2 periods) or nothing when it is below what the data
  resolves, and no friction, inertia or gain from it: scored as nothing or ``latency``.
* ``drop``: each row's goal packet is lost with probability ``value`` and the servo keeps the
  goal it held (a dropped / corrupt packet). Scored as nothing (or ``latency``).

Logs (the project's CSV format: ``time``, ``goal:servo``, ``qpos:q``; no ``qvel``): rows at the
case's rate on the truth's 0.25 ms grid with +-1 step jitter of the row time, the reading
quantised to 4096 ticks per turn after 0.5 mrad of read noise, the goal (whole ticks) written
right after the read and meant to act from the row. Each log starts after 1 s held at its first
target. Excitation: steps with holds, a chirp 0.3-2 Hz and holds approached by ramps from both
sides, over -1.2 .. 1.2 rad.

``write_case`` writes what a user brings (``model.xml``, ``log<i>.csv``) and ``truth.json``;
``tests/redteam_check.grade`` grades a report.json with this module's ``FAMILIES``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np

TICK = 2 * math.pi / 4096      # rad per encoder tick
TRUTH_DT = 0.00025             # s, the truth's physics step
MODEL_DT = 0.002               # s, the user's model step
READ_NOISE = 0.0005            # rad, read noise before quantisation
SETTLE = 1.0                   # s held at the first target before the first row
KP, KV, TAU_MAX = 4.0, 0.06, 1.5         # servo law: N m/rad, N m s/rad, N m
ARMATURE, DAMPING = 0.002, 0.01          # kg m^2, N m s/rad
ARM_MASS, ARM_COM = 0.15, 0.06           # kg, m
RANGE = (-1.2, 1.2)                      # rad, excitation range

# the catalogue name a correct analysis gives, per effect kind (None: name nothing, or the
# ALLOWED names)
CATALOGUE = {"scale": "sensor_scale", "offset": "position_offset", "jitter": None,
             "drop": None}
ALLOWED = {"jitter": {"latency"}, "drop": {"latency"}}
# confusable neighbours (naming one of these for the other is "family"; 04-sysid.md section 6:
# a scale error is confusable with kp (static) and calibration)
FAMILIES = (
    {"sensor_scale", "gain_error", "position_offset", "mounting_offset"},
)


@dataclasses.dataclass(frozen=True)
class Effect:
    """A hidden effect ``kind`` of size ``value``."""

    kind: str
    value: float

    def __post_init__(self):
        if self.kind not in CATALOGUE:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {sorted(CATALOGUE)}")


@dataclasses.dataclass(frozen=True)
class Case:
    """One analysis case: hidden effects, the logs (``durations`` s each, ``styles`` cycled,
    ``rate`` Hz), ``seed``."""

    name: str
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0
    durations: tuple[float, ...] = (8.0, 8.0, 8.0)
    styles: tuple[str, ...] = ("steps", "chirp", "holds")
    seed: int = 0
    note: str = ""

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects if CATALOGUE[e.kind]}

    @property
    def allowed(self) -> set[str]:
        return set().union(*(ALLOWED.get(e.kind, set()) for e in self.effects))

    def effect(self, kind: str) -> Effect | None:
        return next((e for e in self.effects if e.kind == kind), None)


# ---------------------------------------------------------------------------------------------
# MJCF
# ---------------------------------------------------------------------------------------------

def model_xml(truth: bool = False) -> str:
    """The bench's MJCF: the user's nominal model (a ``position`` actuator, 2 ms) or the truth
    (a ``motor`` actuator driven by the servo law computed here, 0.25 ms)."""
    lo, hi = RANGE
    if truth:
        act = f'<motor name="servo" joint="q" ctrlrange="-{TAU_MAX} {TAU_MAX}" ctrllimited="true"/>'
    else:
        act = (f'<position name="servo" joint="q" kp="{KP}" kv="{KV}" '
               f'forcerange="-{TAU_MAX} {TAU_MAX}" ctrlrange="{lo - 0.5} {hi + 0.5}"/>')
    dt = TRUTH_DT if truth else MODEL_DT
    ixx = ARM_MASS * 0.02 ** 2 / 2
    return (f'<mujoco model="scale_bench">\n<compiler angle="radian"/>\n'
            f'<option timestep="{dt}" integrator="implicitfast" gravity="0 0 -9.81"/>\n'
            f'<worldbody>\n<body name="arm" pos="0 0 0.3">\n'
            f'<joint name="q" axis="0 1 0" armature="{ARMATURE}" damping="{DAMPING}"/>\n'
            f'<inertial pos="0 0 {-ARM_COM}" mass="{ARM_MASS}" '
            f'diaginertia="{ixx:.6g} {ixx:.6g} {ixx:.6g}"/>\n'
            f'</body>\n</worldbody>\n<actuator>\n{act}\n</actuator>\n</mujoco>\n')


# ---------------------------------------------------------------------------------------------
# excitation
# ---------------------------------------------------------------------------------------------

def targets(style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Target angle [rad] at times ``t`` for a trajectory ``style``."""
    lo, hi = RANGE
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    if style == "chirp":
        f0, f1 = rng.uniform(0.3, 0.5), rng.uniform(1.5, 2.0)
        T = t[-1] - t[0] + 1e-9
        ph = 2 * math.pi * (f0 * (t - t[0]) + (f1 - f0) * (t - t[0]) ** 2 / (2 * T))
        return mid + 0.8 * half * np.sin(ph + rng.uniform(0, 2 * math.pi))
    out = np.empty_like(t)
    k, level = 0, mid
    while k < len(t):
        hold = rng.uniform(0.3, 0.9) if style == "steps" else rng.uniform(0.6, 1.4)
        n = max(1, int(np.searchsorted(t, t[k] + hold) - k))
        if style == "steps":
            level = rng.uniform(lo + 0.05 * half, hi - 0.05 * half)
            out[k:k + n] = level
        else:  # holds approached from both sides by a ramp
            new = float(np.clip(level + rng.choice([-1, 1]) * rng.uniform(0.3, 1.0) * half,
                                lo, hi))
            ramp = np.clip((t[k:k + n] - t[k]) / (0.5 * hold), 0, 1)
            out[k:k + n] = level + (new - level) * ramp
            level = new
        k += n
    return out


def row_times(duration: float, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Row times [s] on the truth grid: the log period with +-1 step of jitter."""
    period = round(1.0 / rate / TRUTH_DT)
    steps = period + rng.integers(-1, 2, size=int(duration * rate) + 1)
    k = np.concatenate([[0], np.cumsum(steps)])
    k = k[k * TRUTH_DT <= duration]
    return k * TRUTH_DT


def servo_goals(case: Case, goals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The goal the servo holds from each row on (rad), from the goals the host wrote: row i's
    goal i - k_i under jitter (k_i uniform in {0..value}), the previous one held when row i's
    packet is dropped."""
    held = goals.copy()
    jit = case.effect("jitter")
    if jit:
        k = rng.integers(0, int(jit.value) + 1, size=len(goals))
        held = goals[np.maximum(np.arange(len(goals)) - k, 0)]
    drop = case.effect("drop")
    if drop:
        lost = rng.random(len(goals)) < drop.value
        lost[0] = False
        for i in np.flatnonzero(lost):
            held[i] = held[i - 1]
    return held


# ---------------------------------------------------------------------------------------------
# the truth
# ---------------------------------------------------------------------------------------------

def simulate(case: Case, t: np.ndarray, target: np.ndarray, rng: np.random.Generator,
             true_angles: bool = False) -> dict[str, np.ndarray]:
    """Run the truth over rows ``t`` (s, on the 0.25 ms grid, from 0) tracking ``target`` (at
    the rows). Returns the log's columns (rad) per row, and with ``true_angles`` the true angle
    (``true:q``) and the goal the servo held (``held:servo``) at the rows (not logged)."""
    m = mujoco.MjModel.from_xml_string(model_xml(truth=True))
    d = mujoco.MjData(m)
    goals = np.round(target / TICK) * TICK
    held = servo_goals(case, goals, rng)
    d.qpos[0] = goals[0]
    mujoco.mj_forward(m, d)
    settle = round(SETTLE / TRUTH_DT)
    rows = np.round(t / TRUTH_DT).astype(int) + settle
    sc, off = case.effect("scale"), case.effect("offset")
    gain = 1.0 + (sc.value if sc else 0.0)
    shift = off.value if off else 0.0
    noise = rng.normal(0.0, READ_NOISE, size=len(t))
    qpos, true = np.empty(len(t)), np.empty(len(t))
    goal_now, r = goals[0], 0
    for s in range(rows[-1] + 1):
        if r < len(rows) and s == rows[r]:
            q = float(d.qpos[0])
            true[r] = q
            qpos[r] = np.round((gain * q + shift + noise[r]) / TICK) * TICK
            goal_now = held[r]
            r += 1
        tau = KP * (goal_now - d.qpos[0]) - KV * d.qvel[0]
        d.ctrl[0] = np.clip(tau, -TAU_MAX, TAU_MAX)
        mujoco.mj_step(m, d)
    out = {"goal:servo": goals, "qpos:q": qpos}
    if true_angles:
        out.update({"true:q": true, "held:servo": held})
    return out


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (the user's nominal model), ``log<i>.csv`` and ``truth.json`` into
    ``folder``. Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml())
    rng = np.random.default_rng(case.seed)
    logs = []
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.rate, rng)
        tgt = targets(case.styles[i % len(case.styles)], t, rng)
        out = simulate(case, t, tgt, rng)
        names = ["time", *out]
        data = np.column_stack([t, *out.values()])
        path = folder / f"log{i}.csv"
        fmt = ["%.5f"] + ["%.8g"] * len(out)
        np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)
        logs.append(str(path))
    truth = {"case": case.name, "causes": sorted(case.causes), "allowed": sorted(case.allowed),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": logs, "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Catalogue parameters whose true value is plain: the scale as ``sensor_scale``'s
    ``scale`` (1 + value), the offset as ``position_offset``'s ``offset`` [rad]."""
    out = []
    for e in case.effects:
        if e.kind == "scale":
            out.append(dict(effect="sensor_scale", param="scale", joint="q", value=1 + e.value))
        elif e.kind == "offset":
            out.append(dict(effect="position_offset", param="offset", joint="q", value=e.value))
    return out


# ---------------------------------------------------------------------------------------------
# the cases
# ---------------------------------------------------------------------------------------------

E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_100hz", seed=1, note="no hidden effect"),
    Case("scale_p15", (E("scale", 0.015),), seed=2,
         note="reading 1.5 % large (an output encoder through a wrong ratio)"),
    Case("scale_4000ticks", (E("scale", 4000 / 4096 - 1),), seed=3,
         note="ticks converted at 4000 per turn instead of 4096: reading 2.3 % small"),
    Case("scale_p10_offset_m40", (E("scale", 0.010), E("offset", -0.040)), seed=4,
         note="reading 1.0 % large and 40 mrad low"),
    Case("jitter2_100hz", (E("jitter", 2),), seed=5,
         note="goals 0-2 periods late (0, 10, 20 ms; mean 10 ms), out of order at times"),
    Case("jitter2_333hz", (E("jitter", 2),), rate=333.0, seed=6,
         note="goals 0-2 periods late at 333 Hz (mean 3 ms)"),
    Case("drop1_100hz", (E("drop", 0.01),), seed=7, note="1 % of goal packets lost"),
    Case("drop5_100hz", (E("drop", 0.05),), seed=8, note="5 % of goal packets lost"),
)
CASE_BY_NAME = {c.name: c for c in CASES}
