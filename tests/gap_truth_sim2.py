"""A second, independently written truth simulator for the gap analysis (issue 11, redteam).

Written without reading the analyzer, its effect catalogue, its plant/servo models or the first
truth simulator (``tests/gap_truth_sim.py``): it imports only mujoco, numpy and the stdlib. Its
rigs are not a D'Claw finger, and each hidden effect is implemented here from its physics, the
way a user's real robot would carry it:

Rigs (MJCF written by this module; the nominal one, without the hidden effect, is what a user
would hand to ``lowcostdex gap analyze --model``):

- ``pendulum``: one hinge about a horizontal axis (gravity), a 0.15 m link with a 0.3 kg tip
  (0.5 N m gravity torque, XM430-class); a plain ``position`` actuator with ``kp`` only (the
  servo's damping sits on the joint) and a ``forcerange`` of +-3 N m.
- ``arm2``: a two-link planar arm in a vertical plane (XL330-class: 0.6 N m force range),
  actuated by ``general`` actuators written as position servos (``gainprm = kp``,
  ``biasprm = 0 -kp -kv``).
- ``turntable``: one hinge about a vertical axis (no gravity torque), a 0.4 kg disk with an
  off-centre load, a ``position`` actuator with ``kp`` and ``kv`` and no force range.

Hidden effects (``Effect.kind``; sizes are real-world servo sizes):

- ``latency``: every goal reaches the servo ``value`` s after its row (continuous time, not a
  multiple of the log period). ``latency_queue``: a goal queue at the control rate: the goal of
  row k acts from row k + ``value`` (an integer number of control periods).
- ``backlash_body``: a play joint of full width ``value`` rad between a motor body (which the
  position actuator drives and which carries the armature, damping and friction) and the link;
  the log reads the link. ``backlash_output``: the same play, but the servo's P-D loop (written
  here, a ``motor`` actuator) feeds back the OUTPUT position, as a Dynamixel does (encoder on the
  output shaft), so the motor side hunts inside the play; the joint's nominal damping is that
  loop's D on the output velocity (taken off the motor joint: damping once).
- ``coulomb_mj``: MuJoCo ``frictionloss`` on the joint. ``coulomb_own``: a smooth Coulomb torque
  ``-F tanh(qdot / v0)`` applied by this module.
- ``viscous_mj``: extra joint ``damping``. ``viscous_own``: ``-b qdot`` applied by this module.
- ``reading_offset``: the log reports q + value; the servo holds the true angle at the goal
  (a calibration error on the host side).
- ``mounting_offset``: the servo reads q + value and holds that reading at the goal (a horn
  mounted off by ``value``); the log reports the servo's reading.
- ``gain``: the actuator stiffness is ``value`` x the nominal kp (kv unchanged).
- ``torque_limit``: the actuator force is clipped at +-``value`` N m.
- ``inertia``: the joint armature is ``value`` x nominal. ``mass``: every link mass ``value`` x.

Logs (the project's CSV format): row times at 50/100/200 Hz with jitter (optionally a stall of
the host mid-log, during which the last goal is held), goals in continuous time, reads quantised
to 4096 ticks per turn with read noise, ``qvel`` as a Dynamixel reports it (0.229 rpm units) or
absent, trajectory styles ``steps``, ``chirp``, ``holds`` (random targets held a random time)
and ``sine``. The physics runs at 0.25 ms (the nominal models at 1-2 ms, as a user writes them).

Why one module (over 600 lines): it is one self-contained truth (rigs, effects, logs, cases and
the scoring of a report against them) that must import nothing from the project; split, its
pieces would invite importing project helpers. ``bench/gap_redteam.py`` and
``tests/test_gap_redteam.py`` run it through the CLI.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np
from redteam_grade import grade

TICK = 2 * math.pi / 4096          # rad per encoder tick (12-bit absolute encoder)
VEL_UNIT = 0.229 * 2 * math.pi / 60  # rad/s per Dynamixel present-velocity unit
TRUTH_DT = 0.00025                  # s, physics step of the truth simulation
READ_NOISE = 0.0006                 # rad, standard deviation of read noise before quantisation
SETTLE = 1.0                        # s simulated before the first row (holding the first goal)

# catalogue name of each hidden effect kind (docs/gap_analysis.md, `gap generate --effect`)
CATALOGUE = {
    "latency": "latency", "latency_queue": "latency",
    "backlash_body": "backlash", "backlash_output": "backlash",
    "coulomb_mj": "coulomb_friction", "coulomb_own": "coulomb_friction",
    "viscous_mj": "viscous_damping", "viscous_own": "viscous_damping",
    "reading_offset": "position_offset", "mounting_offset": "mounting_offset",
    "gain": "gain_error", "torque_limit": "torque_limit",
    "inertia": "inertia_error", "mass": "mass_error",
}
# confusable neighbours: naming one of these for the other is a "family" answer, not exact
FAMILIES = (
    {"coulomb_friction", "stribeck_friction", "load_dependent_friction", "gearbox_friction"},
    {"viscous_damping", "velocity_limit", "motor_strength"},
    {"position_offset", "mounting_offset"},
    {"inertia_error", "mass_error"},
    {"gain_error", "motor_strength"},
    {"torque_limit", "velocity_limit", "motor_strength"},
    {"backlash"},
    {"latency"},
)


@dataclasses.dataclass(frozen=True)
class Effect:
    """One hidden effect: ``kind`` (see module docstring), its size ``value`` (SI units, or a
    factor), on ``joints`` (logged joint names; empty: every joint of the rig)."""

    kind: str
    value: float
    joints: tuple[str, ...] = ()

    def __post_init__(self):
        if self.kind not in CATALOGUE:
            raise ValueError(f"unknown effect kind {self.kind!r}; valid: {sorted(CATALOGUE)}")


@dataclasses.dataclass(frozen=True)
class Case:
    """One analysis case: a rig, hidden effects (none: clean), and the logs a user would bring.

    ``observable``: False when the hidden effects change nothing the logs can show (scored as
    a clean case: naming anything is a false discovery);
    ``durations``: seconds per log file; ``styles``: trajectory style per file (cycled);
    ``rate``: nominal log rate [Hz]; ``jitter``: row-time jitter as a fraction of the period;
    ``stall``: seconds of a host stall mid-log in the first file (0: none); ``qvel``: log a
    velocity column; ``perturb``: a model difference the truth has that the analysis should NOT
    name (below the noise), as {joint attribute: factor}; ``model_dt``: the nominal model's
    timestep [s] (0: the rig's default)."""

    name: str
    rig: str
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0
    durations: tuple[float, ...] = (15.0, 15.0)
    styles: tuple[str, ...] = ("steps", "sine")
    jitter: float = 0.1
    stall: float = 0.0
    qvel: bool = True
    seed: int = 0
    perturb: tuple[tuple[str, float], ...] = ()
    model_dt: float = 0.0
    note: str = ""
    observable: bool = True

    @property
    def causes(self) -> set[str]:
        """The catalogue causes a correct analysis names: none when the hidden effects cannot
        be seen in the logs (``observable`` False: the case is scored as clean)."""
        return {CATALOGUE[e.kind] for e in self.effects} if self.observable else set()


# ---------------------------------------------------------------------------------------------
# rigs
# ---------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class RigInfo:
    joints: tuple[str, ...]
    actuators: tuple[str, ...]
    goal_low: tuple[float, ...]
    goal_high: tuple[float, ...]


RIGS = {
    "pendulum": RigInfo(("hinge",), ("servo",), (-1.2,), (1.2,)),
    "arm2": RigInfo(("shoulder", "elbow"), ("a_shoulder", "a_elbow"), (-0.9, -1.0), (0.5, 1.0)),
    "turntable": RigInfo(("yaw",), ("yaw_servo",), (-2.0,), (2.0,)),
}

# nominal physical parameters per rig joint: damping [N m s/rad], armature [kg m^2],
# frictionloss [N m], kp [N m/rad], kv [N m s/rad], force range [N m] (0: none)
NOMINAL = {
    "hinge": dict(damping=0.25, armature=0.006, frictionloss=0.0, kp=6.0, kv=0.0, force=3.0),
    "shoulder": dict(damping=0.02, armature=0.002, frictionloss=0.0, kp=2.0, kv=0.03, force=0.6),
    "elbow": dict(damping=0.02, armature=0.002, frictionloss=0.0, kp=1.5, kv=0.02, force=0.6),
    "yaw": dict(damping=0.05, armature=0.004, frictionloss=0.0, kp=4.0, kv=0.12, force=0.0),
}
MASSES = {  # kg of the bodies' geoms per rig
    "pendulum": dict(rod=0.08, tip=0.30),
    "arm2": dict(upper=0.05, elbow_servo=0.02, fore=0.03, tip=0.05),
    "turntable": dict(disk=0.4, load=0.05),
}


def _joint_xml(name: str, axis: str, p: dict, play: float, kind: str) -> tuple[str, str]:
    """Opening tag(s) for a hinge ``name``; with a play (> 0) a motor body and a play joint."""
    attrs = (f'damping="{p["damping"]:.9g}" armature="{p["armature"]:.9g}" '
             f'frictionloss="{p["frictionloss"]:.9g}"')
    if play <= 0:
        return f'<joint name="{name}" type="hinge" axis="{axis}" {attrs}/>', ""
    half = play / 2
    # the motor side: a light rotor body carrying the gearbox's armature/damping/friction
    head = (f'<joint name="{name}_motor" type="hinge" axis="{axis}" {attrs}/>'
            f'<geom type="cylinder" size="0.008 0.004" mass="0.002"/>'
            f'<body name="{name}_out">'
            f'<joint name="{name}_play" type="hinge" axis="{axis}" range="{-half:.9g} {half:.9g}" '
            f'solreflimit="0.001 1" armature="1e-6"/>')
    return head, "</body>"


def _actuator_xml(rig: str, joint: str, actuator: str, p: dict, play: float, own: bool) -> str:
    target = f"{joint}_motor" if play > 0 else joint
    if own:  # this module computes the servo torque itself
        return f'<motor name="{actuator}" joint="{target}"/>'
    force = (f' forcelimited="true" forcerange="{-p["force"]:.9g} {p["force"]:.9g}"'
             if p["force"] > 0 else "")
    if rig == "arm2":
        return (f'<general name="{actuator}" joint="{target}" gaintype="fixed" biastype="affine" '
                f'gainprm="{p["kp"]:.9g}" biasprm="0 {-p["kp"]:.9g} {-p["kv"]:.9g}"{force}/>')
    kv = f' kv="{p["kv"]:.9g}"' if p["kv"] > 0 else ""
    return f'<position name="{actuator}" joint="{target}" kp="{p["kp"]:.9g}"{kv}{force}/>'


def rig_xml(rig: str, joint_params: dict | None = None, masses: dict | None = None,
            plays: dict | None = None, own: bool = False, timestep: float | None = None) -> str:
    """The rig's MJCF. Defaults: the nominal model a user would have (timestep 2 ms pendulum and
    arm, 1 ms turntable). ``joint_params`` overrides ``NOMINAL`` per joint, ``masses`` the body
    masses, ``plays`` adds a backlash play [rad] per joint, ``own`` swaps the actuators for
    ``motor`` actuators driven by this module's servo loop."""
    info = RIGS[rig]
    jp = {j: dict(NOMINAL[j], **(joint_params or {}).get(j, {})) for j in info.joints}
    m = dict(MASSES[rig], **(masses or {}))
    pl = {j: (plays or {}).get(j, 0.0) for j in info.joints}
    dt = timestep or (0.001 if rig == "turntable" else 0.002)
    if rig == "pendulum":
        j, close = _joint_xml("hinge", "0 1 0", jp["hinge"], pl["hinge"], "hinge")
        body = (f'<body name="link" pos="0 0 0.3">{j}'
                f'<geom type="capsule" fromto="0 0 0 0 0 -0.15" size="0.012" mass="{m["rod"]:.9g}"/>'
                f'<geom type="sphere" pos="0 0 -0.15" size="0.025" mass="{m["tip"]:.9g}"/>'
                f'{close}</body>')
    elif rig == "arm2":
        j1, c1 = _joint_xml("shoulder", "0 1 0", jp["shoulder"], pl["shoulder"], "shoulder")
        j2, c2 = _joint_xml("elbow", "0 1 0", jp["elbow"], pl["elbow"], "elbow")
        body = (f'<body name="upper" pos="0 0 0.4">{j1}'
                f'<geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="{m["upper"]:.9g}"/>'
                f'<geom type="sphere" pos="0.1 0 0" size="0.014" mass="{m["elbow_servo"]:.9g}"/>'
                f'<body name="fore" pos="0.1 0 0">{j2}'
                f'<geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.008" mass="{m["fore"]:.9g}"/>'
                f'<geom type="sphere" pos="0.1 0 0" size="0.015" mass="{m["tip"]:.9g}"/>'
                f'{c2}</body>{c1}</body>')
    elif rig == "turntable":
        j, close = _joint_xml("yaw", "0 0 1", jp["yaw"], pl["yaw"], "yaw")
        body = (f'<body name="table" pos="0 0 0.1">{j}'
                f'<geom type="cylinder" size="0.08 0.01" mass="{m["disk"]:.9g}"/>'
                f'<geom type="box" pos="0.06 0 0.02" size="0.02 0.01 0.01" mass="{m["load"]:.9g}"/>'
                f'{close}</body>')
    else:
        raise ValueError(f"unknown rig {rig!r}; valid: {sorted(RIGS)}")
    acts = "".join(_actuator_xml(rig, j, a, jp[j], pl[j], own)
                   for j, a in zip(info.joints, info.actuators, strict=True))
    return (f'<mujoco model="{rig}"><compiler angle="radian" autolimits="true"/>'
            f'<option timestep="{dt:.9g}" integrator="implicitfast"/>'
            f'<default><geom contype="0" conaffinity="0"/></default>'
            f'<worldbody>{body}</worldbody><actuator>{acts}</actuator></mujoco>')


# ---------------------------------------------------------------------------------------------
# trajectories and row times
# ---------------------------------------------------------------------------------------------

def row_times(duration: float, rate: float, jitter: float, stall: float,
              rng: np.random.Generator) -> np.ndarray:
    """Sample times [s] of a host loop at ``rate`` with jitter (and an occasional late row, 2 %
    of rows up to 2.5 periods late) and optionally one stall of ``stall`` s mid-log."""
    period = 1.0 / rate
    n = int(duration * rate)
    t = np.arange(n) * period + rng.normal(0.0, jitter * period, n).clip(-0.4 * period,
                                                                          0.4 * period)
    late = rng.random(n) < 0.02
    t[late] += rng.uniform(0.5, 1.5, late.sum()) * period
    t = np.maximum.accumulate(t)
    keep = np.concatenate([[True], np.diff(t) > 0.2 * period])
    t = t[keep]
    if stall > 0:
        mid = duration * 0.45
        t = t[(t < mid) | (t > mid + stall)]
    return t - t[0] + 0.05


def goals(style: str, t: np.ndarray, low: np.ndarray, high: np.ndarray,
          rng: np.random.Generator) -> np.ndarray:
    """Goals [rad] (rows x joints) of a trajectory ``style`` at row times ``t``."""
    nj = len(low)
    mid, amp = (low + high) / 2, (high - low) / 2
    g = np.empty((len(t), nj))
    if style in ("steps", "holds"):
        for j in range(nj):
            edges, tt = [0.0], 0.0
            while tt < t[-1]:
                tt += (rng.uniform(0.6, 1.5) if style == "steps"
                       else rng.choice([rng.uniform(0.1, 0.4), rng.uniform(0.8, 2.5)]))
                edges.append(tt)
            levels = rng.uniform(low[j], high[j], len(edges))
            if style == "steps":  # steps of a useful size: alternate around the middle
                levels = mid[j] + amp[j] * rng.uniform(0.2, 0.9, len(edges)) * \
                    np.where(np.arange(len(edges)) % 2 == 0, 1.0, -1.0)
            g[:, j] = levels[np.searchsorted(edges, t, side="right") - 1]
    elif style == "chirp":
        f0, f1 = 0.1, 2.5
        T = t[-1]
        for j in range(nj):
            phase = 2 * np.pi * (f0 * t + (f1 - f0) * t ** 2 / (2 * T)) + j * 0.7
            g[:, j] = mid[j] + 0.6 * amp[j] * np.sin(phase)
    elif style == "sine":
        for j in range(nj):
            f = rng.uniform(0.15, 0.5)
            g[:, j] = mid[j] + 0.7 * amp[j] * np.sin(2 * np.pi * f * t + rng.uniform(0, 6.28))
    else:
        raise ValueError(f"unknown style {style!r}; valid: steps, holds, chirp, sine")
    return g


# ---------------------------------------------------------------------------------------------
# the truth simulation
# ---------------------------------------------------------------------------------------------

def _per_joint(case: Case, kind: str) -> dict[str, float]:
    joints = RIGS[case.rig].joints
    out: dict[str, float] = {}
    for e in case.effects:
        if e.kind == kind:
            for j in (e.joints or joints):
                out[j] = e.value
    return out


def truth_xml(case: Case) -> tuple[str, bool]:
    """The truth MJCF of ``case`` (the rig with its hidden effects) and whether the servo loop is
    this module's own (``backlash_output``)."""
    info = RIGS[case.rig]
    jp: dict[str, dict] = {j: {} for j in info.joints}
    for attr, f in case.perturb:
        for j in info.joints:
            jp[j][attr] = NOMINAL[j][attr] * f
    for j, v in _per_joint(case, "coulomb_mj").items():
        jp[j]["frictionloss"] = v
    for j, v in _per_joint(case, "viscous_mj").items():
        jp[j]["damping"] = NOMINAL[j]["damping"] + v
    for j, v in _per_joint(case, "gain").items():
        jp[j]["kp"] = NOMINAL[j]["kp"] * v
    for j, v in _per_joint(case, "torque_limit").items():
        jp[j]["force"] = v
    for j, v in _per_joint(case, "inertia").items():
        jp[j]["armature"] = NOMINAL[j]["armature"] * v
    masses = {}
    for e in case.effects:
        if e.kind == "mass":
            masses = {k: v * e.value for k, v in MASSES[case.rig].items()}
    for j in _per_joint(case, "backlash_output"):
        # the servo's own loop puts the nominal joint damping on the OUTPUT velocity (its D term,
        # ``simulate``): it is taken off the motor joint, which keeps only what a hidden effect
        # adds (``viscous_mj``) or a perturbation changes. Until 2026-11-27 (session 14) the motor
        # joint kept its nominal damping too, an unnamed extra D term of the same size: that
        # physics is now the case ``backlash_output_damped_pendulum`` (play + viscous_mj).
        jp[j]["damping"] = jp[j].get("damping", NOMINAL[j]["damping"]) - NOMINAL[j]["damping"]
    plays = {**_per_joint(case, "backlash_body"), **_per_joint(case, "backlash_output")}
    own = bool(_per_joint(case, "backlash_output"))
    return rig_xml(case.rig, jp, masses, plays, own, timestep=TRUTH_DT), own


def simulate(case: Case, t_rows: np.ndarray, g_rows: np.ndarray,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Run the truth physics through one log: rows at ``t_rows`` [s] with goals ``g_rows``
    (rows x actuators). Returns what the log reports: positions [rad] and velocities [rad/s]
    (rows x joints), quantised and noisy."""
    info = RIGS[case.rig]
    xml, own = truth_xml(case)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    nj = len(info.joints)
    plays = {**_per_joint(case, "backlash_body"), **_per_joint(case, "backlash_output")}
    # qpos addresses summed into a reading, and the dof that carries the gearbox torques
    read_adr, drive_dof = [], []
    for j in info.joints:
        if j in plays:
            a = model.joint(f"{j}_motor")
            b = model.joint(f"{j}_play")
            read_adr.append([a.qposadr[0], b.qposadr[0]])
            drive_dof.append(a.dofadr[0])
        else:
            a = model.joint(j)
            read_adr.append([a.qposadr[0]])
            drive_dof.append(a.dofadr[0])
    out_dof = [model.joint(f"{j}_play").dofadr[0] if j in plays else drive_dof[i]
               for i, j in enumerate(info.joints)]
    read_off = np.array([_per_joint(case, "reading_offset").get(j, 0.0) for j in info.joints])
    mount_off = np.array([_per_joint(case, "mounting_offset").get(j, 0.0) for j in info.joints])
    coul = np.array([_per_joint(case, "coulomb_own").get(j, 0.0) for j in info.joints])
    visc = np.array([_per_joint(case, "viscous_own").get(j, 0.0) for j in info.joints])
    nominal = [NOMINAL[j] for j in info.joints]
    kp = np.array([p["kp"] * _per_joint(case, "gain").get(j, 1.0)
                   for p, j in zip(nominal, info.joints, strict=True)])
    # own loop (backlash_output): P-D on the output (kp, kv; clipped at the force range, as a
    # position actuator's force) plus the nominal joint damping on the OUTPUT velocity, taken
    # off the motor joint (``truth_xml``) and, like a joint's damping, outside the force range:
    # damping once, where the encoder reads (with no play this is the nominal rig; until
    # session 14 the damping sat inside the clip and on the motor joint as well)
    kv = np.array([p["kv"] for p in nominal])
    damp_out = np.array([p["damping"] for p in nominal])
    fmax = np.array([_per_joint(case, "torque_limit").get(j, p["force"] or np.inf)
                     for p, j in zip(nominal, info.joints, strict=True)])

    # when each row's goal reaches the servo
    lat = _per_joint(case, "latency")
    queue = _per_joint(case, "latency_queue")
    n = len(t_rows)
    eff_t = np.empty((n, nj))
    for i, j in enumerate(info.joints):
        if j in queue:
            k = int(round(queue[j]))
            eff_t[:, i] = np.concatenate([t_rows[k:], t_rows[-1] + np.arange(1, k + 1)])
        else:
            eff_t[:, i] = t_rows + lat.get(j, 0.0)

    def reading(qpos):
        return np.array([qpos[a].sum() for a in read_adr])

    # start settled at the first goal, SETTLE s before the first row
    for i, a in enumerate(read_adr):
        data.qpos[a[0]] = g_rows[0, i] - mount_off[i]
    cur = g_rows[0].copy()
    ptr = np.zeros(nj, dtype=int)
    t = t_rows[0] - SETTLE
    n_steps = int(math.ceil((t_rows[-1] - t) / TRUTH_DT)) + 2
    pos = np.empty((n, nj))
    vel = np.empty((n, nj))
    row = 0
    has_play = np.array([j in plays for j in info.joints])
    damping_own = visc  # own viscous torque coefficient
    v0 = 0.02           # rad/s, smoothing of this module's Coulomb torque
    for _ in range(n_steps):
        for i in range(nj):
            while ptr[i] < n and eff_t[ptr[i], i] <= t:
                cur[i] = g_rows[ptr[i], i]
                ptr[i] += 1
        q = reading(data.qpos)
        if own:
            qd_out = data.qvel[out_dof] + data.qvel[drive_dof]
            tau = kp * (cur - mount_off - q) - kv * qd_out
            data.ctrl[:] = np.clip(tau, -fmax, fmax) - damp_out * qd_out
        else:
            data.ctrl[:] = cur - mount_off
        if coul.any() or damping_own.any():
            qd = data.qvel[drive_dof]
            data.qfrc_applied[drive_dof] = -coul * np.tanh(qd / v0) - damping_own * qd
        while row < n and t_rows[row] <= t + TRUTH_DT / 2:
            pos[row] = q
            vel[row] = data.qvel[drive_dof] + np.where(has_play, data.qvel[out_dof], 0.0)
            row += 1
        if row >= n:
            break
        mujoco.mj_step(model, data)
        t += TRUTH_DT
    if not np.all(np.isfinite(pos)):
        raise RuntimeError(f"{case.name}: the truth simulation diverged")
    reported = pos + read_off + mount_off
    reported = np.round((reported + rng.normal(0.0, READ_NOISE, reported.shape)) / TICK) * TICK
    v = np.round((vel + rng.normal(0.0, 0.3 * VEL_UNIT, vel.shape)) / VEL_UNIT) * VEL_UNIT
    return reported, v


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``case`` as a user would bring it: ``model.xml`` (the nominal rig), ``log<i>.csv``
    and ``truth.json`` (what is hidden). Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    info = RIGS[case.rig]
    (folder / "model.xml").write_text(rig_xml(case.rig, timestep=case.model_dt or None))
    rng = np.random.default_rng(case.seed)
    low, high = np.array(info.goal_low), np.array(info.goal_high)
    logs = []
    for f, dur in enumerate(case.durations):
        style = case.styles[f % len(case.styles)]
        t = row_times(dur, case.rate, case.jitter, case.stall if f == 0 else 0.0, rng)
        g = goals(style, t, low, high, rng)
        q, v = simulate(case, t, g, rng)
        cols = {"time": t}
        cols.update({f"goal:{a}": g[:, i] for i, a in enumerate(info.actuators)})
        cols.update({f"qpos:{j}": q[:, i] for i, j in enumerate(info.joints)})
        if case.qvel:
            cols.update({f"qvel:{j}": v[:, i] for i, j in enumerate(info.joints)})
        path = folder / f"log{f}.csv"
        np.savetxt(path, np.column_stack(list(cols.values())), delimiter=",",
                   header=",".join(cols), comments="", fmt="%.9g")
        logs.append(str(path))
    truth = {"case": case.name, "rig": case.rig, "causes": sorted(case.causes),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "observable": case.observable,
             "expected_params": expected_params(case) if case.observable else []}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": logs, "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """What each hidden cause's catalogue parameter should come out as, where its meaning is
    plain from the docs: {effect, param, joint, value, abs} (``abs``: compare magnitudes, the
    sign convention of an offset not being documented)."""
    out = []
    for e in case.effects:
        name = CATALOGUE[e.kind]
        for j in e.joints or RIGS[case.rig].joints:
            if e.kind == "latency":
                out.append(dict(effect=name, param="delay", joint=j, value=e.value, abs=False))
            elif e.kind == "latency_queue":
                out.append(dict(effect=name, param="delay", joint=j, value=e.value / case.rate,
                                abs=False))
            elif e.kind.startswith("backlash"):
                out.append(dict(effect=name, param="width", joint=j, value=e.value, abs=False))
            elif e.kind.startswith("coulomb"):
                out.append(dict(effect=name, param="frictionloss", joint=j, value=e.value,
                                abs=False))
            elif e.kind.startswith("viscous"):
                out.append(dict(effect=name, param="damping", joint=j, value=e.value, abs=False))
            elif e.kind == "reading_offset":
                out.append(dict(effect=name, param="offset", joint=j, value=e.value, abs=True))
            elif e.kind in ("gain", "mass"):
                out.append(dict(effect=name, param="scale", joint=j, value=e.value, abs=False))
            elif e.kind == "torque_limit":
                out.append(dict(effect=name, param="torque", joint=j, value=e.value, abs=False))
            elif e.kind == "inertia":
                out.append(dict(effect=name, param="scale", joint=j, value=e.value, abs=False))
    return out


# ---------------------------------------------------------------------------------------------
# the cases
# ---------------------------------------------------------------------------------------------

DEG = math.pi / 180
E = Effect
CASES: tuple[Case, ...] = (
    # clean: noise + quantisation only, or a difference below the noise, or an invisible one
    Case("clean_pendulum", "pendulum", (), 100, (15, 15), ("steps", "sine"), seed=1),
    Case("clean_pendulum_fine_step", "pendulum", (), 100, (15, 15), ("steps", "sine"), seed=5,
         model_dt=0.0005, note="the user's model at a 0.5 ms step"),
    Case("clean_arm2_posonly", "arm2", (), 50, (20, 20), ("chirp", "holds"), jitter=0.2,
         qvel=False, seed=2),
    Case("clean_turntable_below_noise", "turntable", (), 200, (15, 15), ("steps", "chirp"),
         perturb=(("damping", 1.005), ("armature", 1.005)), seed=3,
         note="damping and armature +0.5 %"),
    Case("clean_mounting_vertical", "turntable", (E("mounting_offset", 3 * DEG),), 100,
         (15, 15), ("holds", "sine"), seed=4,
         note="a mounting offset on a vertical axis changes nothing observable",
         observable=False),
    # single effects
    Case("latency_queue_pendulum", "pendulum", (E("latency_queue", 2),), 100, (15, 15),
         ("steps", "holds"), seed=11, note="2 control periods at 100 Hz"),
    Case("latency_17ms_arm2_50hz_posonly", "arm2", (E("latency", 0.017),), 50, (20, 20),
         ("steps", "chirp"), jitter=0.2, qvel=False, seed=12),
    Case("latency_7ms_turntable_200hz", "turntable", (E("latency", 0.007),), 200, (15, 15),
         ("chirp", "steps"), seed=13),
    Case("backlash_body_pendulum", "pendulum", (E("backlash_body", 1.5 * DEG),), 100,
         (20, 20), ("sine", "steps"), seed=14),
    Case("backlash_output_pendulum", "pendulum", (E("backlash_output", 2.5 * DEG),), 100,
         (20, 20), ("steps", "holds"), seed=15, note="encoder on the output shaft"),
    Case("backlash_output_damped_pendulum", "pendulum",
         (E("backlash_output", 2.5 * DEG), E("viscous_mj", 0.25)), 100, (20, 20),
         ("steps", "holds"), seed=15,
         note="backlash_output_pendulum's extra damping before session 14, named: the motor "
              "joint keeps 0.25 N m s/rad beside the loop's 0.25 on the output (damping "
              "twice; the loop's D now outside the force range, as in the fixed case)"),
    Case("backlash_body_turntable", "turntable", (E("backlash_body", 1.0 * DEG),), 200,
         (15, 15), ("holds", "sine"), seed=16),
    Case("coulomb_mj_turntable", "turntable", (E("coulomb_mj", 0.08),), 100, (15, 15),
         ("steps", "sine"), seed=17),
    Case("coulomb_own_pendulum_50hz_posonly", "pendulum", (E("coulomb_own", 0.15),), 50,
         (20, 20), ("holds", "chirp"), qvel=False, seed=18),
    Case("viscous_own_arm2", "arm2", (E("viscous_own", 0.02),), 100, (15, 15),
         ("chirp", "steps"), seed=19),
    Case("viscous_mj_pendulum_200hz", "pendulum", (E("viscous_mj", 0.1),), 200, (15, 15),
         ("chirp", "sine"), seed=20),
    Case("reading_offset_arm2", "arm2", (E("reading_offset", 3 * DEG, ("shoulder",)),
                                         E("reading_offset", -2 * DEG, ("elbow",))),
         100, (15, 15), ("holds", "sine"), seed=21),
    Case("mounting_offset_pendulum", "pendulum", (E("mounting_offset", 4 * DEG),), 100,
         (15, 15), ("steps", "sine"), seed=22),
    Case("gain_low_pendulum_posonly", "pendulum", (E("gain", 0.6),), 100, (15, 15),
         ("steps", "holds"), qvel=False, seed=23),
    Case("gain_high_arm2_50hz", "arm2", (E("gain", 1.8),), 50, (20, 20), ("steps", "chirp"),
         seed=24),
    Case("torque_limit_turntable", "turntable", (E("torque_limit", 1.5),), 100, (15, 15),
         ("steps", "holds"), seed=25, note="nominal: no force range"),
    Case("inertia_pendulum_200hz", "pendulum", (E("inertia", 1.8),), 200, (15, 15),
         ("chirp", "steps"), seed=26),
    Case("mass_arm2", "arm2", (E("mass", 1.6),), 100, (15, 15), ("steps", "sine"), seed=27),
    # pairs
    Case("latency_coulomb_pendulum", "pendulum", (E("latency", 0.025), E("coulomb_mj", 0.1)),
         100, (20, 20), ("steps", "chirp"), seed=31),
    Case("backlash_offset_pendulum_stall", "pendulum",
         (E("backlash_body", 2.0 * DEG), E("reading_offset", -3 * DEG)), 100, (20, 20),
         ("sine", "holds"), stall=0.8, seed=32, note="a 0.8 s host stall mid-log"),
    Case("gain_viscous_turntable", "turntable", (E("gain", 0.7), E("viscous_own", 0.08)), 100,
         (15, 15), ("steps", "chirp"), seed=33),
    Case("queue_mass_arm2_posonly", "arm2", (E("latency_queue", 3), E("mass", 1.5)), 100,
         (20, 20), ("steps", "holds"), qvel=False, seed=34),
    Case("torque_coulomb_pendulum", "pendulum", (E("torque_limit", 1.2), E("coulomb_own", 0.1)),
         100, (20, 20), ("steps", "sine"), seed=35),
)
CASE_BY_NAME = {c.name: c for c in CASES}


# ---------------------------------------------------------------------------------------------
# scoring a report.json against the truth
# ---------------------------------------------------------------------------------------------

def score(report: dict, truth: dict) -> dict:
    """Score one ``report.json`` (dict) against ``truth`` (``write_case``'s truth dict) with the
    red-team sets' one grader (``redteam_grade.grade``: exact / extra / family / miss / clean /
    false; per expected parameter of a named cause, its interval against the truth)."""
    return grade(report, truth, FAMILIES)
