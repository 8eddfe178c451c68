"""A ninth independent truth simulator for the gap analysis: a user's own 4-joint arm with a
DIFFERENT hidden effect on each joint, logged the way users log (issue 11; gap-sim9, session 22).

Written with mujoco, numpy and the stdlib only, importing nothing from lowcostdex (no effect,
plant, servo or gap code) and reusing no earlier truth simulator's physics. The earlier truth sets
are 1-3 joint rigs with one effect (or one pair) on every joint. Here:

- the rig is a user's own arm MJCF written the way Menagerie's ``low_cost_robot_arm`` and Trossen
  arms are: four hinges (``shoulder``, ``elbow``, ``wrist`` in the vertical plane, a ``gripper``
  jaw), plain ``<position kp kv forcerange>`` actuators, ``armature``, ``damping`` and
  ``frictionloss`` on every joint (04-sysid.md section 3.3's range for X-series servos), gravity
  loading the shoulder (0.68 N m with the arm horizontal, at 0);
- each joint carries its OWN hidden effect at a real-world size (``Case.effects``), e.g. the
  shoulder a torque limit (a weak supply or current limit: 40 % of the force range) or
  load-dependent gear friction (BAM's M3, mu 0.15), the elbow a 10 mrad gear play with the
  encoder behind it (on the output shaft: the firmware's PD reads across the play) or a P gain
  0.6x the model's, the wrist a 30 mrad calibration offset between the user's read and write
  conversions, the gripper none;
- reads quantised to 4096 ticks per turn after 0.4 mrad of noise, goals written in whole ticks;
- logs as a user writes them, in the project's documented CSV format (docs/gap_analysis.md):
  angles in degrees (``--units deg``, as LeRobot records), integer-millisecond stamps of a
  board's ``millis()`` (``--time-unit ms``), no velocity column, a stretch of rows dropped by a
  USB hiccup, columns in the user's order, rows written twice.

Hidden effects (``Effect.kind``; each on the joints named), written here from their physics:

- ``torque_limit``: the servo delivers at most ``value`` N m (the truth's force range).
- ``load_friction``: the joint's dry friction is the model's frictionloss + ``value`` x |the
  actuator's torque| of the step before (gear-tooth friction grows with the torque the gears
  carry; BAM M3), made stiff (it sticks).
- ``backlash``: a play of ``value`` rad between the servo's output gear (a rotor hinge carrying
  the armature, damping and frictionloss) and the link (a hinge limited to +-value/2 on it);
  the firmware's PD (the model's kp, kv, force range) acts on the rotor from the link's angle
  and speed (the encoder sits on the output shaft), computed every truth step here.
- ``gain``: the joint's kp times ``value`` (kv kept).
- ``reading_offset``: the log reads q + ``value``; the servo holds the true angle at the goal.
- ``latency``: every goal reaches its servo ``value`` s after its row.

The truth runs at 0.25 ms (implicitfast), the user's model at 2 ms. ``write_case`` writes what a
user brings (``model.xml``, ``logs/log<i>.csv``), the options a user passes for that spelling
(``Case.args``) and ``truth.json`` (``causes``: the catalogue names; ``per_joint``: {joint:
[causes]}; ``expected_params``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np

TICK = 2 * math.pi / 4096       # rad per encoder tick
TRUTH_DT = 0.00025              # s, the truth's physics step
MODEL_DT = 0.002                # s, the user's model step
NOISE = 0.0004                  # rad, read noise before quantisation
SETTLE = 1.0                    # s held at the first goals before the first row

JOINTS = ("shoulder", "elbow", "wrist", "gripper")
# joint: (body pos in its parent [m], axis, link: (com along x [m], mass [kg]), armature
# [kg m^2], damping [N m s/rad], frictionloss [N m], servo (kp [N m/rad], kv [N m s/rad],
# force [N m]), goal range [rad])
ARM: dict[str, tuple] = {
    "shoulder": ("0 0 0.12", "0 1 0", (0.06, 0.25), 0.012, 0.10, 0.04, (20.0, 0.4, 3.0),
                 (-0.8, 0.8)),
    "elbow": ("0.12 0 0", "0 1 0", (0.05, 0.15), 0.008, 0.08, 0.03, (10.0, 0.2, 2.0),
              (-2.2, 0.4)),
    "wrist": ("0.10 0 0", "0 1 0", (0.03, 0.08), 0.004, 0.03, 0.02, (6.0, 0.08, 1.4),
              (-1.0, 1.0)),
    "gripper": ("0.05 0 0", "0 0 1", (0.02, 0.03), 0.002, 0.02, 0.01, (3.0, 0.03, 1.0),
                (0.0, 0.8)),
}
KINDS = ("torque_limit", "load_friction", "backlash", "gain", "reading_offset", "latency")
CATALOGUE = {"torque_limit": "torque_limit", "load_friction": "load_dependent_friction",
             "backlash": "backlash", "gain": "gain_error", "reading_offset": "position_offset",
             "latency": "latency"}
PARAM = {"torque_limit": "torque", "load_friction": "mu", "backlash": "width", "gain": "scale",
         "reading_offset": "offset", "latency": "delay"}
# confusable neighbours (04-sysid.md section 4.2) for redteam_check.grade
FAMILIES = (
    {"torque_limit", "velocity_limit", "latency", "gain_error"},
    {"load_dependent_friction", "coulomb_friction", "gearbox_friction", "stribeck_friction",
     "mass_error"},
    {"backlash", "coulomb_friction", "deadband"},
    {"gain_error", "latency", "inertia_error", "viscous_damping", "deadband"},
    {"position_offset", "mass_error", "mounting_offset", "sensor_scale"},
)


def servo(joint: str) -> str:
    return f"{joint}_servo"


@dataclasses.dataclass(frozen=True)
class Effect:
    """Hidden effect ``kind`` of size ``value`` (N m, 1, rad, a factor or s) on ``joint``
    (latency: every servo; it names the first)."""

    kind: str
    value: float
    joint: str = "shoulder"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {', '.join(KINDS)}")
        if self.joint not in JOINTS:
            raise ValueError(f"unknown joint {self.joint!r}; valid: {', '.join(JOINTS)}")


@dataclasses.dataclass(frozen=True)
class Case:
    """One case: hidden ``effects``; logs of ``durations`` s at ``rate`` Hz, spelled as the user
    writes them: ``deg`` angles, ``ms`` stamps (integer millis() of a board booted earlier),
    ``qvel`` logged or not, ``dropped`` s of rows missing mid-log, ``doubled`` share of rows
    written twice, ``shuffled`` columns."""

    name: str
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0
    durations: tuple[float, ...] = (8.0, 8.0, 8.0)
    deg: bool = True
    ms: bool = True
    qvel: bool = False
    dropped: float = 0.0
    doubled: float = 0.0
    shuffled: bool = False
    seed: int = 0
    note: str = ""

    def size(self, kind: str, joint: str | None = None, default: float = 0.0) -> float:
        return next((e.value for e in self.effects if e.kind == kind
                     and (joint is None or e.joint == joint)), default)

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects}

    @property
    def per_joint(self) -> dict[str, list[str]]:
        """{joint: catalogue causes hidden on it} (latency on every joint)."""
        out: dict[str, list[str]] = {j: [] for j in JOINTS}
        for e in self.effects:
            for j in (JOINTS if e.kind == "latency" else (e.joint,)):
                out[j].append(CATALOGUE[e.kind])
        return out

    @property
    def args(self) -> tuple[str, ...]:
        """The options a user passes ``gap analyze`` for this spelling."""
        return (("--units", "deg") if self.deg else ()) + (("--time-unit", "ms") if self.ms
                                                            else ())


def model_xml(case: Case | None = None, timestep: float = MODEL_DT) -> str:
    """The arm's MJCF: the user's nominal model (``case`` None) or the truth with ``case``'s
    torque limit, gain, and play (a ``<joint>_rotor`` hinge driven by a ``motor`` the caller
    computes) written in."""
    body = "{inner}"
    acts = []
    for j in reversed(JOINTS):
        pos, axis, (com, mass), arm, damp, fric, (kp, kv, force), _ = ARM[j]
        stiff = ""
        if case and case.size("load_friction", j):
            stiff = ' solreffriction="0.0005 1" solimpfriction="0.999 0.9999 0.001"'
        inertial = (f'<inertial pos="{com} 0 0" mass="{mass}" '
                    f'diaginertia="{mass * 5e-5:.4g} {mass * ((2 * com) ** 2 / 12 + 2.5e-5):.4g} '
                    f'{mass * ((2 * com) ** 2 / 12 + 2.5e-5):.4g}"/>'
                    f'<geom type="capsule" fromto="0 0 0 {2 * com:.4g} 0 0" size="0.01" '
                    f'mass="0"/>')
        play = case.size("backlash", j) if case else 0.0
        if play:
            inner = (f'<body name="{j}_gear" pos="{pos}"><joint name="{j}_rotor" axis="{axis}" '
                     f'armature="{arm}" damping="{damp}" frictionloss="{fric}"/>'
                     f'<geom type="sphere" size="0.004" mass="0.0005"/>'
                     f'<body name="{j}_link"><joint name="{j}" axis="{axis}" limited="true" '
                     f'range="{-play / 2:.9g} {play / 2:.9g}" solreflimit="0.0005 1"/>'
                     f'{inertial}{body}</body></body>')
            acts.append(f'<motor name="{servo(j)}" joint="{j}_rotor" ctrllimited="false"/>')
        else:
            inner = (f'<body name="{j}_link" pos="{pos}"><joint name="{j}" axis="{axis}" '
                     f'armature="{arm}" damping="{damp}" frictionloss="{fric}"{stiff}/>'
                     f'{inertial}{body}</body>')
            if case:
                kp *= case.size("gain", j, 1.0)
                force = case.size("torque_limit", j, force)
            acts.append(f'<position name="{servo(j)}" joint="{j}" kp="{kp:.9g}" kv="{kv}" '
                        f'forcelimited="true" forcerange="{-force:.9g} {force:.9g}" '
                        f'ctrlrange="-3.1 3.1"/>')
        body = inner
    acts.reverse()
    return (f'<mujoco model="arm4">\n<compiler angle="radian"/>\n'
            f'<option timestep="{timestep:.9g}" integrator="implicitfast"/>\n'
            f'<default><geom contype="0" conaffinity="0"/></default>\n'
            f'<worldbody>\n<body name="base" pos="0 0 0.05">\n'
            f'{body.replace("{inner}", "")}\n</body>\n</worldbody>\n'
            f'<actuator>\n' + "\n".join(acts) + '\n</actuator>\n</mujoco>\n')


def row_times(duration: float, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Host row times [s] from 0: the period with +-15 % jitter, 1 % of rows a period late."""
    n = int(duration * rate)
    steps = (1.0 + rng.uniform(-0.15, 0.15, n)) / rate
    steps[rng.random(n) < 0.01] += 1.0 / rate
    t = np.concatenate([[0.0], np.cumsum(steps)])
    return t[t <= duration]


def targets(joint: str, style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Goals [rad] of ``joint`` at times ``t``: ``steps`` (held 0.4-1.4 s) or ``sine`` (a
    0.2-0.7 Hz sine plus a slower one), inside the joint's goal range."""
    lo, hi = ARM[joint][-1]
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    if style == "steps":
        edges = np.cumsum(rng.uniform(0.4, 1.4, int(t[-1] / 0.4) + 2))
        levels = mid + half * rng.uniform(-0.95, 0.95, len(edges) + 1)
        return levels[np.searchsorted(edges, t, side="right")]
    f1, f2 = rng.uniform(0.2, 0.7), rng.uniform(0.05, 0.15)
    p1, p2 = rng.uniform(0, 2 * math.pi, 2)
    return mid + half * (0.6 * np.sin(2 * math.pi * f1 * t + p1)
                         + 0.3 * np.sin(2 * math.pi * f2 * t + p2))


def simulate(case: Case, t: np.ndarray, goals: dict[str, np.ndarray],
             rng: np.random.Generator, true_angles: bool = False) -> dict[str, np.ndarray]:
    """Run the truth over rows ``t`` [s] with ``goals`` [rad] written right after each row's
    read. Returns ``goal:<servo>`` and ``qpos:<joint>`` [rad] per row and ``qvel:<joint>``
    [rad/s] (and ``true:<joint>``, the link's angle, when ``true_angles``)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case, TRUTH_DT))
    d = mujoco.MjData(m)
    qadr = {j: int(m.jnt_qposadr[m.joint(j).id]) for j in JOINTS}
    dadr = {j: int(m.jnt_dofadr[m.joint(j).id]) for j in JOINTS}
    rotor = {j: (int(m.jnt_qposadr[m.joint(f"{j}_rotor").id]),
                 int(m.jnt_dofadr[m.joint(f"{j}_rotor").id]))
             for j in JOINTS if case.size("backlash", j)}
    act = {j: m.actuator(servo(j)).id for j in JOINTS}
    loadf = {j: case.size("load_friction", j) for j in JOINTS}
    fric0 = {j: float(m.dof_frictionloss[dadr[j]]) for j in JOINTS}
    latency = case.size("latency")

    def angle(j: str) -> float:   # the link's angle: gear + play
        return float(d.qpos[qadr[j]] + (d.qpos[rotor[j][0]] if j in rotor else 0.0))

    def speed(j: str) -> float:
        return float(d.qvel[dadr[j]] + (d.qvel[rotor[j][1]] if j in rotor else 0.0))

    def ticks(x: float) -> float:
        return float(np.round(x / TICK) * TICK)

    first = {j: ticks(goals[j][0]) for j in JOINTS}
    for j in JOINTS:
        d.qpos[rotor[j][0] if j in rotor else qadr[j]] = first[j]
    mujoco.mj_forward(m, d)
    n = len(t)
    out = {f"goal:{servo(j)}": np.empty(n) for j in JOINTS}
    out |= {f"qpos:{j}": np.empty(n) for j in JOINTS}
    out |= {f"qvel:{j}": np.empty(n) for j in JOINTS}
    if true_angles:
        out |= {f"true:{j}": np.empty(n) for j in JOINTS}
    rows = np.round((t + SETTLE) / TRUTH_DT).astype(int)
    queue: list[tuple[int, dict[str, float]]] = []
    cmd = dict(first)
    r = 0
    for s in range(rows[-1] + 1):
        while r < n and s == rows[r]:
            for j in JOINTS:
                read = angle(j) + case.size("reading_offset", j) + rng.normal(0.0, NOISE)
                out[f"qpos:{j}"][r] = ticks(read)
                out[f"qvel:{j}"][r] = speed(j)
                if true_angles:
                    out[f"true:{j}"][r] = angle(j)
            g = {j: ticks(goals[j][r]) for j in JOINTS}
            for j in JOINTS:
                out[f"goal:{servo(j)}"][r] = g[j]
            queue.append((s + round(latency / TRUTH_DT), g))
            r += 1
        while queue and queue[0][0] <= s:
            cmd = queue.pop(0)[1]
        for j in JOINTS:
            if j in rotor:   # the firmware's PD on the output shaft's reading
                kp, kv, force = ARM[j][6]
                kp *= case.size("gain", j, 1.0)
                force = case.size("torque_limit", j, force)
                d.ctrl[act[j]] = float(np.clip(kp * (cmd[j] - angle(j)) - kv * speed(j),
                                               -force, force))
            else:
                d.ctrl[act[j]] = cmd[j]
            if loadf[j]:
                m.dof_frictionloss[dadr[j]] = fric0[j] + loadf[j] * abs(
                    float(d.actuator_force[act[j]]))
        mujoco.mj_step(m, d)
    if not all(np.all(np.isfinite(v)) for v in out.values()):
        raise RuntimeError(f"{case.name}: the truth simulation diverged")
    return out


def spelled(case: Case, t: np.ndarray, cols: dict[str, np.ndarray], rng: np.random.Generator
            ) -> tuple[list[str], np.ndarray, list[str]]:
    """The columns as the user's logger writes them: (header, rows, formats)."""
    cols = {k: v for k, v in cols.items() if case.qvel or not k.startswith("qvel:")}
    if case.deg:
        cols = {k: np.degrees(v) for k, v in cols.items()}
    if case.ms:   # millis() of a board booted 412.35 s before the log
        stamp, tfmt = np.floor((t + 412.35) * 1e3), "%d"
    else:
        stamp, tfmt = t, "%.6f"
    names = ["time", *cols]
    fmts = [tfmt] + ["%.6f" if case.deg else "%.8g"] * len(cols)
    data = np.column_stack([stamp, *cols.values()])
    if case.shuffled:
        perm = rng.permutation(len(names))
        names, data, fmts = [names[i] for i in perm], data[:, perm], [fmts[i] for i in perm]
    if case.dropped:
        a = rng.uniform(0.3, 0.6) * t[-1]
        data = data[~((t >= a) & (t < a + case.dropped))]
    if case.doubled:
        data = np.repeat(data, np.where(rng.random(len(data)) < case.doubled, 2, 1), axis=0)
    return names, data, fmts


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (the user's nominal model), ``logs/log<i>.csv`` and ``truth.json``
    into ``folder``. Returns {"model", "logs" (the folder, as a user passes it), "args",
    "truth"}."""
    folder = pathlib.Path(folder)
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml())
    rng = np.random.default_rng(case.seed)
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.rate, rng)
        style = ("steps", "sine")[i % 2]
        goals = {j: targets(j, style if j != "gripper" else "steps", t, rng) for j in JOINTS}
        cols = simulate(case, t, goals, rng)
        names, data, fmts = spelled(case, t, cols, np.random.default_rng([case.seed, i]))
        np.savetxt(folder / "logs" / f"log{i}.csv", data, delimiter=",",
                   header=",".join(names), comments="", fmt=fmts)
    truth = {"case": case.name, "causes": sorted(case.causes), "per_joint": case.per_joint,
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case), "args": list(case.args)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": [str(folder / "logs")],
            "args": list(case.args), "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Each hidden effect's catalogue parameter on its joint (latency: every joint)."""
    out = []
    for e in case.effects:
        for j in (JOINTS if e.kind == "latency" else (e.joint,)):
            out.append(dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=j,
                            value=e.value))
    return out


E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_arm4_deg_ms", (), dropped=0.3, seed=91,
         note="no hidden effect; degrees, millis() stamps, no velocity, 0.3 s of rows dropped"),
    Case("limit_play_offset_arm4",
         (E("torque_limit", 1.2, "shoulder"), E("backlash", 0.010, "elbow"),
          E("reading_offset", 0.030, "wrist")), dropped=0.3, seed=92,
         note="shoulder delivers 1.2 of 3 N m; elbow 10 mrad play, encoder on the output; "
              "wrist read 30 mrad off; gripper clean; degrees, millis(), no velocity"),
    Case("loadfric_gain_arm4",
         (E("load_friction", 0.15, "shoulder"), E("gain", 0.6, "elbow")),
         deg=False, ms=False, qvel=True, doubled=0.02, shuffled=True, seed=93,
         note="shoulder gear friction 0.15 x |torque| on top of 0.04 N m; elbow P gain 0.6x; "
              "wrist and gripper clean; seconds, rad/s velocities, shuffled columns, 2 % rows "
              "doubled"),
    Case("latency_offset_gain_arm4",
         (E("latency", 0.025), E("reading_offset", -0.030, "wrist"), E("gain", 1.6, "gripper")),
         seed=94, note="25 ms on every servo (USB latency timer + bus); wrist read -30 mrad off; "
                       "gripper P gain 1.6x; degrees, millis()"),
)
CASE_BY_NAME = {c.name: c for c in CASES}
