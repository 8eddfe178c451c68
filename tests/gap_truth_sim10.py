"""A tenth independent truth simulator for the gap analysis: a user's 3-joint D'Claw-like finger
with hidden effects OUTSIDE the project's catalogue (issue 11; gap-sim11, session 24).

Written with mujoco, numpy and the stdlib only (and the sets' one grader, tests/redteam_grade.py),
importing nothing from lowcostdex (no effect, plant, servo or gap code). The question it asks: when an outside judge's simulator hides an
effect the catalogue has no name for, does the analysis name a confident WRONG cause, or does it
report the residual it cannot explain?

The rig: one finger of a D'Claw hanging palm down from its mount, three hinges (``base``
swinging the finger sideways about x, ``middle`` and ``distal`` curling it about y), links of
55 / 65 / 90 mm carrying the next servo (80 / 80 / 30 g), Dynamixel-X-like servos as plain MuJoCo
``<position kp kv forcerange>`` actuators (kp 6 N m/rad, kv 0.15 N m s/rad, 3 N m: an XM430's
stall torque), ``armature`` 0.008 kg m^2 (212:1 gearing), ``damping`` 0.1 and ``frictionloss``
0.03 N m on every joint. Reads are the servo's own encoder: 0.4 mrad of noise, then 4096 ticks
per turn; goals written in whole ticks. The truth runs at 0.25 ms (implicitfast), the user's
model at 2 ms.

Hidden effects (``Effect.kind``), each written here from its physics:

- ``series_spring`` (outside): a compliant coupling between the servo's horn and the link: the
  servo (its armature, damping, friction, encoder and PD loop) turns a horn; the link hangs on
  the horn through a torsion spring of ``k`` N m/rad and ``c`` N m s/rad. The log reads the
  horn (the servo's encoder), the link swings behind it (its gravity sag is unseen).
- ``gear_spring`` (outside): the same compliance inside the servo, before its encoder: the
  motor (the armature, damping and friction) drives the output shaft through a gear train of
  ``k`` N m/rad and ``c`` N m s/rad; the encoder and the log read the output (the link), the
  firmware's PD (kp, kv, force range) acts on the motor from that reading and its rate.
- ``encoder_ripple`` (outside): the servo's encoder reads r = q + a sin(n q + phi) (a magnet's
  harmonic error, ``n`` cycles per turn); the firmware's PD closes on r (and on its rate) and
  the log records r.
- ``friction_drift`` (outside): the joints' dry friction rises linearly over the session (the
  logs recorded back to back) from the model's 0.03 N m to ``factor`` times it at the end
  (grease stiffening / wear; no temperature column is logged).
- ``supply_sag`` (outside): the three servos share a 12 V supply behind ``R`` ohm (a thin
  cable, a weak bench supply): the bus voltage is 12 - R sum(I), I = |tau| / kt (kt 1.3 N m/A,
  an XM430-W210: 3 N m at 2.3 A) and each servo's torque limit is 3 N m x V / 12 (its stall
  current follows the voltage), from the previous step's torques.
- ``tight_spot`` (outside): a position-dependent dry friction bump on one joint (a gear tooth
  or bearing with a burr): frictionloss + ``A`` exp(-(q - q0)^2 / (2 w^2)).
- ``latency`` (catalogue): every goal reaches its servo ``value`` s after its row.

``write_case`` writes what a user brings (``model.xml``, ``logs/log<i>.csv`` in the project's
CSV format, or a user's spelling: degrees and integer millis() stamps, ``Case.args`` the
options for it) and ``truth.json``: ``causes`` (catalogue names of the hidden catalogue effects),
``outside`` (an effect outside the catalogue is hidden), ``nearest`` (the catalogue effects a
report may name as the nearest stand-in for it, written from the physics before any analysis
was run, see ``NEAREST``), ``expected_params``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np
import redteam_grade  # the red-team sets' one grader (tests/, no project imports)

TICK = 2 * math.pi / 4096       # rad per encoder tick
TRUTH_DT = 0.00025              # s, the truth's physics step
MODEL_DT = 0.002                # s, the user's model step
NOISE = 0.0004                  # rad, read noise before quantisation
SETTLE = 1.0                    # s held at the first goals before the first row
V0, KT = 12.0, 1.3              # supply [V], torque constant [N m/A] (XM430-W210)

JOINTS = ("base", "middle", "distal")
# joint: (body pos in its parent [m], axis, link: (length [m], com along -z [m], mass [kg]),
# goal range [rad])
FINGER: dict[str, tuple] = {
    "base": ("0 0 0", "1 0 0", (0.055, 0.030, 0.08), (-0.45, 0.45)),
    "middle": ("0 0 -0.055", "0 1 0", (0.065, 0.035, 0.08), (-0.5, 1.3)),
    "distal": ("0 0 -0.065", "0 1 0", (0.090, 0.045, 0.03), (-0.5, 1.3)),
}
ARMATURE, DAMPING, FRICTION = 0.008, 0.1, 0.03     # kg m^2, N m s/rad, N m
KP, KV, FORCE = 6.0, 0.15, 3.0                      # N m/rad, N m s/rad, N m

KINDS = ("series_spring", "gear_spring", "encoder_ripple", "friction_drift", "supply_sag", "tight_spot",
         "latency")
CATALOGUE = {"latency": "latency"}          # the kinds the project's catalogue has by name
PARAM = {"latency": "delay"}
# The catalogue effects a report may name as the nearest stand-in for each outside effect
# (mechanism in common), decided from the physics before any run:
# - a series spring is compliance in the drive train: the catalogue's nearest is a play
#   (backlash: a compliance of zero stiffness over a band) and, at low frequency, the link's
#   inertia carried by the horn (inertia_error);
# - an encoder's harmonic error is a reading error (sensor_scale, position_offset are the
#   catalogue's reading errors) whose local slope 1 + n a cos(n q + phi) scales the loop's gain
#   (gain_error);
# - friction that rises over the session is dry friction at a level the model lacks
#   (coulomb_friction, stribeck_friction, gearbox_friction);
# - a sagging supply lowers the torque the servos can deliver (torque_limit, voltage_sag,
#   motor_strength);
# - a tight spot is dry friction (coulomb_friction, stribeck_friction, gearbox_friction).
NEAREST: dict[str, tuple[str, ...]] = {
    "series_spring": ("backlash", "inertia_error"),
    "gear_spring": ("backlash", "inertia_error"),
    "encoder_ripple": ("sensor_scale", "position_offset", "gain_error"),
    "friction_drift": ("coulomb_friction", "stribeck_friction", "gearbox_friction"),
    "supply_sag": ("torque_limit", "voltage_sag", "motor_strength"),
    "tight_spot": ("coulomb_friction", "stribeck_friction", "gearbox_friction"),
}


@dataclasses.dataclass(frozen=True)
class Effect:
    """Hidden effect ``kind`` on ``joint`` (friction_drift, supply_sag, latency: every joint)
    with its sizes ``values``: series_spring, gear_spring (k [N m/rad], c [N m s/rad]);
    encoder_ripple (a
    [rad], n [cycles/turn], phi [rad]); friction_drift (factor at the session's end);
    supply_sag (R [ohm]); tight_spot (A [N m], q0 [rad], w [rad]); latency (delay [s])."""

    kind: str
    values: tuple[float, ...]
    joint: str = "middle"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {', '.join(KINDS)}")
        if self.joint not in JOINTS:
            raise ValueError(f"unknown joint {self.joint!r}; valid: {', '.join(JOINTS)}")


@dataclasses.dataclass(frozen=True)
class Case:
    """One case: hidden ``effects``; logs of ``durations`` s at ``rate`` Hz, spelled ``deg``
    (angles in degrees) and ``ms`` (integer millis() stamps) or in the project's units."""

    name: str
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0
    durations: tuple[float, ...] = (6.0, 6.0, 6.0)
    deg: bool = False
    ms: bool = False
    seed: int = 0
    note: str = ""

    def get(self, kind: str, joint: str | None = None) -> tuple[float, ...] | None:
        return next((e.values for e in self.effects if e.kind == kind
                     and (joint is None or e.joint == joint)), None)

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects if e.kind in CATALOGUE}

    @property
    def outside(self) -> bool:
        return any(e.kind not in CATALOGUE for e in self.effects)

    @property
    def nearest(self) -> list[str]:
        return sorted({n for e in self.effects for n in NEAREST.get(e.kind, ())})

    @property
    def args(self) -> tuple[str, ...]:
        return (("--units", "deg") if self.deg else ()) + (("--time-unit", "ms") if self.ms
                                                            else ())


def model_xml(case: Case | None = None, timestep: float = MODEL_DT) -> str:
    """The finger's MJCF: the user's nominal model (``case`` None) or the truth with ``case``'s
    series spring (a horn hinge, the link on a spring hinge) and encoder ripple (a ``motor``
    the caller drives with the firmware's PD on the rippled reading) written in."""
    body = ""
    acts = []
    for j in reversed(JOINTS):
        pos, axis, (length, com, mass), _ = FINGER[j]
        ixx = mass * (length ** 2 / 12 + 1e-5)     # a rod about its centre of mass
        inertial = (f'<inertial pos="0 0 {-com}" mass="{mass}" '
                    f'diaginertia="{ixx:.4g} {ixx:.4g} {mass * 4e-5:.4g}"/>'
                    f'<geom type="capsule" fromto="0 0 0 0 0 {-length}" size="0.012" mass="0"/>')
        servo = (f'armature="{ARMATURE}" damping="{DAMPING}" frictionloss="{FRICTION}"')
        spring = case.get("series_spring", j) if case else None
        ripple = case.get("encoder_ripple", j) if case else None
        gear = case.get("gear_spring", j) if case else None
        if gear:
            k, c = gear
            body = (f'<body name="{j}_rotor" pos="{pos}"><joint name="{j}_motor" axis="{axis}" '
                    f'{servo}/><geom type="sphere" size="0.005" mass="0.001"/>'
                    f'<body name="{j}_link"><joint name="{j}" axis="{axis}" stiffness="{k}" '
                    f'damping="{c}"/>{inertial}{body}</body></body>')
        elif spring:
            k, c = spring
            body = (f'<body name="{j}_horn" pos="{pos}"><joint name="{j}" axis="{axis}" {servo}/>'
                    f'<geom type="sphere" size="0.005" mass="0.001"/>'
                    f'<body name="{j}_link"><joint name="{j}_spring" axis="{axis}" '
                    f'stiffness="{k}" damping="{c}"/>{inertial}{body}</body></body>')
        else:
            body = (f'<body name="{j}_link" pos="{pos}"><joint name="{j}" axis="{axis}" {servo}/>'
                    f'{inertial}{body}</body>')
        if ripple or gear:
            acts.append(f'<motor name="{j}_servo" joint="{j}{"_motor" if gear else ""}" '
                        f'ctrllimited="false"/>')
        else:
            acts.append(f'<position name="{j}_servo" joint="{j}" kp="{KP}" kv="{KV}" '
                        f'forcelimited="true" forcerange="{-FORCE} {FORCE}" '
                        f'ctrlrange="-3.1 3.1"/>')
    acts.reverse()
    return (f'<mujoco model="dclaw_finger">\n<compiler angle="radian"/>\n'
            f'<option timestep="{timestep:.9g}" integrator="implicitfast"/>\n'
            f'<default><geom contype="0" conaffinity="0"/></default>\n'
            f'<worldbody>\n<body name="mount" pos="0 0 0.3">\n{body}\n</body>\n</worldbody>\n'
            f'<actuator>\n' + "\n".join(acts) + '\n</actuator>\n</mujoco>\n')


def row_times(duration: float, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Host row times [s] from 0: the period with +-10 % jitter."""
    n = int(duration * rate)
    t = np.concatenate([[0.0], np.cumsum((1.0 + rng.uniform(-0.1, 0.1, n)) / rate)])
    return t[t <= duration]


def targets(joint: str, style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Goals [rad] at times ``t``: ``steps`` (held 0.4-1.2 s) or ``sine`` (a 0.3-0.8 Hz sine
    plus a slower one), inside the joint's goal range."""
    lo, hi = FINGER[joint][-1]
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    if style == "steps":
        edges = np.cumsum(rng.uniform(0.4, 1.2, int(t[-1] / 0.4) + 2))
        levels = mid + half * rng.uniform(-0.95, 0.95, len(edges) + 1)
        return levels[np.searchsorted(edges, t, side="right")]
    f1, f2 = rng.uniform(0.3, 0.8), rng.uniform(0.05, 0.15)
    p1, p2 = rng.uniform(0, 2 * math.pi, 2)
    return mid + half * (0.6 * np.sin(2 * math.pi * f1 * t + p1)
                         + 0.3 * np.sin(2 * math.pi * f2 * t + p2))


def ripple_reading(q: float, a: float, n: float, phi: float) -> float:
    """The encoder's reading [rad] of the true angle ``q``: q + a sin(n q + phi)."""
    return q + a * math.sin(n * q + phi)


def simulate(case: Case, t: np.ndarray, goals: dict[str, np.ndarray], rng: np.random.Generator,
             session: tuple[float, float] = (0.0, 1.0), true_angles: bool = False
             ) -> dict[str, np.ndarray]:
    """Run the truth over rows ``t`` [s] with ``goals`` [rad] written right after each row's
    read. ``session``: (this log's start, the whole session's length) [s] for the friction
    drift. Returns ``goal:<joint>_servo`` and ``qpos:<joint>`` [rad] per row (and
    ``true:<joint>``, the link's angle, and ``force:<joint>`` [N m] when ``true_angles``)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case, TRUTH_DT))
    d = mujoco.MjData(m)
    qadr = {j: int(m.jnt_qposadr[m.joint(j).id]) for j in JOINTS}
    dadr = {j: int(m.jnt_dofadr[m.joint(j).id]) for j in JOINTS}
    spring = {j: int(m.jnt_qposadr[m.joint(f"{j}_spring").id]) for j in JOINTS
              if case.get("series_spring", j)}
    act = {j: m.actuator(f"{j}_servo").id for j in JOINTS}
    gear = {j: (int(m.jnt_qposadr[m.joint(f"{j}_motor").id]),
                int(m.jnt_dofadr[m.joint(f"{j}_motor").id])) for j in JOINTS
            if case.get("gear_spring", j)}
    ripple = {j: case.get("encoder_ripple", j) for j in JOINTS if case.get("encoder_ripple", j)}
    spot = {j: case.get("tight_spot", j) for j in JOINTS if case.get("tight_spot", j)}
    drift = case.get("friction_drift")
    sag = case.get("supply_sag")
    latency = (case.get("latency") or (0.0,))[0]

    def reading(j: str) -> float:   # the servo's encoder (the horn when a spring is hidden)
        q = float(d.qpos[qadr[j]] + (d.qpos[gear[j][0]] if j in gear else 0.0))
        return ripple_reading(q, *ripple[j]) if j in ripple else q

    def link(j: str) -> float:
        return float(d.qpos[qadr[j]] + (d.qpos[spring[j]] if j in spring else 0.0)
                     + (d.qpos[gear[j][0]] if j in gear else 0.0))

    def ticks(x: float) -> float:
        return float(np.round(x / TICK) * TICK)

    first = {j: ticks(goals[j][0]) for j in JOINTS}
    for j in JOINTS:
        d.qpos[gear[j][0] if j in gear else qadr[j]] = first[j]
    mujoco.mj_forward(m, d)
    n = len(t)
    out = {f"goal:{j}_servo": np.empty(n) for j in JOINTS}
    out |= {f"qpos:{j}": np.empty(n) for j in JOINTS}
    if true_angles:
        out |= {f"true:{j}": np.empty(n) for j in JOINTS}
        out |= {f"force:{j}": np.empty(n) for j in JOINTS}
    rows = np.round((t + SETTLE) / TRUTH_DT).astype(int)
    queue: list[tuple[int, dict[str, float]]] = []
    cmd = dict(first)
    r = 0
    for s in range(rows[-1] + 1):
        while r < n and s == rows[r]:
            for j in JOINTS:
                out[f"qpos:{j}"][r] = ticks(reading(j) + rng.normal(0.0, NOISE))
                if true_angles:
                    out[f"true:{j}"][r] = link(j)
                    out[f"force:{j}"][r] = float(d.actuator_force[act[j]])
            g = {j: ticks(goals[j][r]) for j in JOINTS}
            for j in JOINTS:
                out[f"goal:{j}_servo"][r] = g[j]
            queue.append((s + round(latency / TRUTH_DT), g))
            r += 1
        while queue and queue[0][0] <= s:
            cmd = queue.pop(0)[1]
        if sag:   # the shared supply: this step's limit from the last step's currents
            amps = sum(abs(float(d.actuator_force[act[j]])) for j in JOINTS) / KT
            volts = max(V0 - sag[0] * amps, 0.0)
            m.actuator_forcerange[:, 0] = -FORCE * volts / V0
            m.actuator_forcerange[:, 1] = FORCE * volts / V0
        if drift:
            now = session[0] + max(s * TRUTH_DT - SETTLE, 0.0)
            m.dof_frictionloss[[dadr[j] for j in JOINTS]] = FRICTION * (
                1.0 + (drift[0] - 1.0) * min(now / session[1], 1.0))
        for j, (amp, q0, w) in spot.items():
            m.dof_frictionloss[dadr[j]] = FRICTION + amp * math.exp(
                -0.5 * ((float(d.qpos[qadr[j]]) - q0) / w) ** 2)
        for j in JOINTS:
            if j in ripple:   # the firmware's PD on the rippled reading and its rate
                a, k, phi = ripple[j]
                q, v = float(d.qpos[qadr[j]]), float(d.qvel[dadr[j]])
                rate = v * (1.0 + a * k * math.cos(k * q + phi))
                d.ctrl[act[j]] = float(np.clip(KP * (cmd[j] - reading(j)) - KV * rate,
                                               -FORCE, FORCE))
            elif j in gear:   # the firmware's PD on the output shaft, acting on the motor
                rate = float(d.qvel[dadr[j]] + d.qvel[gear[j][1]])
                d.ctrl[act[j]] = float(np.clip(KP * (cmd[j] - reading(j)) - KV * rate,
                                               -FORCE, FORCE))
            else:
                d.ctrl[act[j]] = cmd[j]
        mujoco.mj_step(m, d)
    if not all(np.all(np.isfinite(v)) for v in out.values()):
        raise RuntimeError(f"{case.name}: the truth simulation diverged")
    return out


def spelled(case: Case, t: np.ndarray, cols: dict[str, np.ndarray]
            ) -> tuple[list[str], np.ndarray, list[str]]:
    """The columns as the user's logger writes them: (header, rows, formats)."""
    if case.deg:
        cols = {k: np.degrees(v) for k, v in cols.items()}
    if case.ms:   # millis() of a board booted 97.5 s before the log
        stamp, tfmt = np.floor((t + 97.5) * 1e3), "%d"
    else:
        stamp, tfmt = t, "%.6f"
    names = ["time", *cols]
    fmts = [tfmt] + ["%.6f" if case.deg else "%.8g"] * len(cols)
    return names, np.column_stack([stamp, *cols.values()]), fmts


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (the user's nominal model), ``logs/log<i>.csv`` (recorded back to
    back: one session) and ``truth.json`` into ``folder``. Returns {"model", "logs", "args",
    "truth"}."""
    folder = pathlib.Path(folder)
    (folder / "logs").mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml())
    rng = np.random.default_rng(case.seed)
    total, start = sum(case.durations), 0.0
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.rate, rng)
        style = ("steps", "sine")[i % 2]
        goals = {j: targets(j, style, t, rng) for j in JOINTS}
        cols = simulate(case, t, goals, rng, session=(start, total))
        start += dur
        names, data, fmts = spelled(case, t, cols)
        np.savetxt(folder / "logs" / f"log{i}.csv", data, delimiter=",",
                   header=",".join(names), comments="", fmt=fmts)
    truth = {"case": case.name, "causes": sorted(case.causes), "outside": case.outside,
             "nearest": case.nearest, "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case), "args": list(case.args)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": [str(folder / "logs")],
            "args": list(case.args), "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Each hidden catalogue effect's parameter (latency: on every joint)."""
    return [dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=j, value=e.values[0])
            for e in case.effects if e.kind in CATALOGUE for j in JOINTS]


E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_finger", (), seed=101, note="no hidden effect; radians, seconds"),
    Case("latency40_finger", (E("latency", (0.040,)),), deg=True, ms=True, seed=102,
         note="40 ms on every servo (catalogue); degrees, millis()"),
    Case("series_spring_base", (E("series_spring", (2.0, 0.005), "base"),), seed=103,
         note="2 N m/rad coupling between the base servo's horn and the finger (outside)"),
    Case("encoder_ripple_middle", (E("encoder_ripple", (0.02, 4.0, 0.7), "middle"),),
         deg=True, ms=True, seed=104,
         note="middle encoder reads q + 20 mrad sin(4 q + 0.7); the loop closes on it "
              "(outside)"),
    Case("friction_drift_finger", (E("friction_drift", (4.0,)),), seed=105,
         note="dry friction 0.03 -> 0.12 N m over the session on every joint (outside)"),
    Case("supply_sag_finger", (E("supply_sag", (0.5,)),), seed=106,
         note="12 V supply behind 0.5 ohm shared by the three servos: limits 3 N m x V/12 "
              "(outside)"),
    Case("tight_spot_middle", (E("tight_spot", (0.25, 0.4, 0.06), "middle"),), seed=107,
         note="middle joint: +0.25 N m friction bump at 0.4 rad, width 0.06 rad (outside)"),
    Case("gear_spring_middle", (E("gear_spring", (8.0, 0.01), "middle"),), seed=108,
         note="middle servo's gear train 8 N m/rad between motor and output, encoder and loop "
              "on the output (outside)"),
    # a catalogue effect beside an outside one: the latency must be named, nothing wrong beside
    Case("latency_tight_spot", (E("latency", (0.025,)),
                                E("tight_spot", (0.25, 0.4, 0.06), "middle")), seed=109,
         note="25 ms on every servo + the middle's tight spot"),
    Case("latency_friction_drift", (E("latency", (0.025,)), E("friction_drift", (4.0,))),
         deg=True, ms=True, seed=110, note="25 ms on every servo + friction rising 4x"),
    Case("latency_gear_spring", (E("latency", (0.025,)),
                                 E("gear_spring", (8.0, 0.01), "middle")), seed=111,
         note="25 ms on every servo + the middle servo's 8 N m/rad gear train"),
    Case("latency_supply_sag", (E("latency", (0.025,)), E("supply_sag", (0.5,))), seed=112,
         note="25 ms on every servo + the shared supply behind 0.5 ohm"),
    # the same effects in six logs of 5 s (more held out: a gain can be reliable there, which
    # is where a stand-in would be named with confidence)
    Case("series_spring_base_6logs", (E("series_spring", (2.0, 0.005), "base"),),
         durations=(5.0,) * 6, seed=113, note="as series_spring_base, six logs"),
    Case("encoder_ripple_middle_6logs", (E("encoder_ripple", (0.02, 4.0, 0.7), "middle"),),
         durations=(5.0,) * 6, deg=True, ms=True, seed=114,
         note="as encoder_ripple_middle, six logs"),
    Case("friction_drift_finger_6logs", (E("friction_drift", (4.0,)),), durations=(5.0,) * 6,
         seed=115, note="as friction_drift_finger, six logs"),
    Case("latency_tight_spot_6logs", (E("latency", (0.025,)),
                                      E("tight_spot", (0.25, 0.4, 0.06), "middle")),
         durations=(5.0,) * 6, seed=119, note="as latency_tight_spot, six logs"),
    Case("tight_spot_middle_6logs", (E("tight_spot", (0.25, 0.4, 0.06), "middle"),),
         durations=(5.0,) * 6, seed=117, note="as tight_spot_middle, six logs"),
)
CASE_BY_NAME = {c.name: c for c in CASES}

# what a report says when it does not claim to explain the logs (gap analysis verdicts and
# cause notes; docs/gap_analysis.md "Say what may be a stand-in")
FLAGS = ("not explained", "partial stand-in", "may stand in")


def score(report: dict, truth: dict) -> dict:
    """Grade one report.json against ``truth``.

    A case whose truth hides an effect outside the catalogue (``truth["outside"]``) PASSES when
    the report names no confident wrong cause: nothing named (``pass_nothing``), or only effects
    in the case's ``nearest`` list (``pass_nearest``), or other effects while the report flags
    what it names as not explaining the logs (a verdict or cause note with one of ``FLAGS``:
    ``pass_flagged``). Anything else named is ``fail_wrong``. Either way the residual must be
    reported: the held-out RMSE left (``gain.extended_rmse``, the nominal one's when nothing is
    named) and the noise floor as finite numbers (``residual_floors`` = their ratio); a report
    without them fails (``fail_no_residual``); a catalogue effect hidden beside the outside one
    must be named too (else ``fail_missed``). A catalogue case (nothing outside) is graded as
    the earlier sets are: ``exact`` (exactly the hidden causes named) or ``clean`` (nothing
    hidden, nothing named), else ``extra`` / ``miss`` / ``false`` (``redteam_grade.grade``,
    the sets' one grader, which also checks the parameters). ``result`` is the red-team
    harness's word: ``clean`` for a pass of an outside case."""
    causes = report.get("causes", [])
    base = redteam_grade.grade(report, {**truth, "outside": False}, ())
    named, hidden = base["named"], set(truth["causes"])
    g = report.get("gain") or {}
    before, after, floor = g.get("baseline_rmse"), g.get("extended_rmse"), g.get("noise_floor")
    left = after if named else before
    verdict = str(report.get("verdict", ""))
    notes = " ".join(str(n) for c in causes for n in (c.get("stand_in") or []))
    flagged = any(f in verdict or f in notes for f in FLAGS)
    residual = None
    if all(isinstance(x, (int, float)) and math.isfinite(x) for x in (left, floor)) and floor:
        residual = float(left) / float(floor)
    wrong = sorted(set(named) - set(truth.get("nearest", ())) - hidden)
    if not truth.get("outside"):
        grade = result = base["result"]
    elif residual is None:
        grade = "fail_no_residual"
    elif not hidden <= set(named):
        grade = "fail_missed"
    elif not named:
        grade = "pass_nothing"
    elif not wrong:
        grade = "pass_nearest"
    else:
        grade = "pass_flagged" if flagged else "fail_wrong"
    if truth.get("outside"):
        result = "clean" if grade.startswith("pass") else "false"
    return {"result": result, "grade": grade, "named": named, "wrong": wrong,
            "hidden": sorted(hidden), "flagged": flagged, "residual_floors": residual,
            "heldout": [before, after], "noise_floor": floor, "gain_ci95": g.get("ci95"),
            "verdict": verdict, "params": base["params"]}
