"""A fifth independent truth simulator for the gap analysis: plants and logs as users bring them
(issue 11 items 2 and 4; gap-judge11, session 16).

Written with mujoco, numpy and the stdlib only, importing nothing from lowcostdex (no effect,
plant, servo or gap code) and not reusing the earlier truth simulators' physics. The first four
sets test one pendulum or a 3-joint finger whose model sets no friction and little armature,
with logs in the project's own CSV spelling. This one takes what they leave out:

- plants whose MJCF already sets what the hidden effect adds to: a two-link ``arm2`` in a
  vertical plane (gravity-loaded, the joints coupled through the links' inertia) whose user set
  ``armature`` and ``frictionloss`` on both joints (the truth has MORE of one of them), and a
  ``finger`` whose distal joint is unactuated and follows the proximal one through a passive
  fixed tendon (a coupling spring, as on underactuated hands);
- effects at real-world sizes and in pairs: latency 8-40 ms, a backlash of 2 deg with the
  encoder on the output shaft (the firmware's PD closes on the output), a reading offset of
  0.28 rad (beyond the catalogue's +-0.2 search range), gains 0.6-1.8x, a real small servo's
  Coulomb + viscous friction together;
- logs as users write them: angles in degrees (``--units deg``), integer-millisecond
  (``millis()``) or integer-microsecond stamps from a clock that did not start at 0, rates
  30-1000 Hz, columns in another order, a stretch of dropped rows (a USB hiccup), rows written
  twice.

Rigs (``RIGS``), every actuator a ``<position kp kv forcerange>`` servo:

- ``pendulum``: one hinge about a horizontal axis, rod + tip mass, armature 0.003.
- ``arm2``: shoulder and elbow hinges about parallel horizontal axes; the user's model sets
  armature 0.010 / 0.004 and frictionloss 0.04 / 0.03 N m on them (a geared servo's reflected
  rotor inertia and a guessed friction).
- ``finger``: ``pip`` driven by a servo, ``dip`` unactuated, a fixed tendon (pip - dip) with
  stiffness 0.15 N m/rad pulling the distal link along.

Hidden effects, written here from their physics (``Effect.kind``, per ``joint``):

- ``latency``: each goal of every actuator reaches it ``value`` s after its row.
- ``reading_offset``: the log reads q + ``value`` on that joint; the servo holds the true angle
  at its goal (a host-side calibration error).
- ``gain``: the joint's actuator kp times ``value`` (kv kept).
- ``coulomb``: ``value`` N m of dry friction MORE than the model's frictionloss (MuJoCo's
  frictionloss made stiff: it sticks).
- ``viscous``: a torque -``value`` qdot applied to the joint by this module.
- ``armature``: the joint's armature times ``value``.
- ``backlash``: a play of ``value`` rad between the motor's shaft and the link: the servo's
  rotor is a hinge of its own carrying the armature, the link hangs on it through a hinge
  limited to +-value/2, and the firmware's PD (kp, kv, force range of the model) acts on the
  rotor from the OUTPUT angle and speed (the encoder sits on the output shaft), computed every
  truth step by this module.

The truth physics runs at 0.25 ms (implicitfast), the user's model at 2 ms. ``write_case``
writes what a user would bring (``model.xml``, ``log<i>.csv``), the ``gap analyze`` options a
user passes for that log spelling (``Case.args``: ``--units deg``, ``--time-unit ms``) and a
``truth.json`` in the form ``gap_truth_sim2.score`` grades.
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

TICK = 2 * math.pi / 4096            # rad per encoder tick
VEL_UNIT = 0.229 * 2 * math.pi / 60   # rad/s per Dynamixel velocity unit
TRUTH_DT = 0.00025                    # s, truth physics step
MODEL_DT = 0.002                      # s, the user's model step
NOISE = 0.0005                        # rad, read noise before quantisation
SETTLE = 1.0                          # s run before the first logged row
GRAVITY_AXIS = "0 1 0"

# joint: (parent body, pos of the joint's body in its parent, link length [m], rod mass, tip
# mass [kg], armature [kg m^2], damping [N m s/rad], frictionloss [N m], actuator (kp, kv,
# force) or None: unactuated)
RIGS: dict[str, dict] = {
    "pendulum": dict(joints={
        "hinge": ("world", 0.0, 0.12, 0.05, 0.15, 0.003, 0.02, 0.0, (6.0, 0.12, 2.0))}),
    "arm2": dict(joints={
        "shoulder": ("world", 0.0, 0.20, 0.15, 0.0, 0.010, 0.05, 0.04, (14.0, 0.4, 4.0)),
        "elbow": ("shoulder", 0.20, 0.16, 0.08, 0.10, 0.004, 0.03, 0.03, (6.0, 0.15, 2.0))}),
    "finger": dict(joints={
        "pip": ("world", 0.0, 0.05, 0.03, 0.0, 0.002, 0.01, 0.0, (2.0, 0.05, 1.0)),
        "dip": ("pip", 0.05, 0.04, 0.02, 0.02, 0.0005, 0.004, 0.0, None)},
        tendon=("pip", "dip", 0.15)),
}
GOAL_RANGE = {"hinge": (-1.0, 1.0), "shoulder": (-0.9, 0.9), "elbow": (-1.0, 1.0),
              "pip": (-0.2, 1.2)}
EFFECTS = ("latency", "reading_offset", "gain", "coulomb", "viscous", "armature", "backlash")
CATALOGUE = {"latency": "latency", "reading_offset": "position_offset", "gain": "gain_error",
             "coulomb": "coulomb_friction", "viscous": "viscous_damping",
             "armature": "inertia_error", "backlash": "backlash"}
PARAM = {"latency": "delay", "reading_offset": "offset", "gain": "scale",
         "coulomb": "frictionloss", "viscous": "damping", "armature": "scale",
         "backlash": "width"}
SPELLINGS = ("rad_s", "deg", "ms", "us")


def servo(joint: str) -> str:
    return f"{joint}_servo"


@dataclasses.dataclass(frozen=True)
class Effect:
    """One hidden effect ``kind`` of size ``value`` (s, rad, a factor, N m or N m s/rad) on
    ``joints`` (one joint; latency acts on every actuator and names the first)."""

    kind: str
    value: float
    joints: tuple[str, ...] = ("hinge",)

    def __post_init__(self):
        if self.kind not in EFFECTS:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {', '.join(EFFECTS)}")


@dataclasses.dataclass(frozen=True)
class Case:
    """A case on ``rig`` with hidden ``effects``; logs of ``durations`` s at ``rate`` Hz in
    trajectory ``styles`` (cycled), written in the user's spelling: ``angles`` "rad" or "deg",
    ``stamps`` "s" (float seconds from 0), "ms" (integer milliseconds of a clock started
    before the log) or "us" (integer microseconds), ``order`` of the columns ("project": time,
    goals, qpos, qvel; "shuffled": a user's order), ``dropped`` s of rows missing mid-log,
    ``doubled`` share of rows written twice."""

    name: str
    rig: str
    effects: tuple[Effect, ...] = ()
    rate: float = 100.0
    durations: tuple[float, ...] = (12.0, 12.0)
    styles: tuple[str, ...] = ("steps", "sine")
    jitter: float = 0.15
    qvel: bool = True
    angles: str = "rad"
    stamps: str = "s"
    order: str = "project"
    dropped: float = 0.0
    doubled: float = 0.0
    seed: int = 0
    note: str = ""

    def __post_init__(self):
        if self.rig not in RIGS:
            raise ValueError(f"unknown rig {self.rig!r}; valid: {', '.join(RIGS)}")
        for e in self.effects:
            for j in e.joints:
                if j not in RIGS[self.rig]["joints"]:
                    raise ValueError(f"{self.name}: no joint {j!r} on {self.rig}")

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects}

    @property
    def args(self) -> tuple[str, ...]:
        """The options a user passes ``gap analyze`` for this log spelling."""
        out: tuple[str, ...] = ()
        if self.angles == "deg":
            out += ("--units", "deg")
        if self.stamps in ("ms", "us"):
            out += ("--time-unit", self.stamps)
        return out

    def size(self, kind: str, joint: str | None = None, default: float = 0.0) -> float:
        return next((e.value for e in self.effects if e.kind == kind
                     and (joint is None or joint in e.joints)), default)


def model_xml(rig: str, case: Case | None = None, timestep: float = MODEL_DT) -> str:
    """The rig's MJCF: nominal (``case`` None: what the user hands to ``gap analyze``) or the
    truth with ``case``'s gain, armature, Coulomb and backlash written into it (a backlash
    joint gets a rotor hinge ``<joint>_rotor`` with a ``motor`` the caller drives)."""
    spec = RIGS[rig]
    bodies: dict[str, list[str]] = {}
    acts = []
    for j, (parent, pos, length, rod, tip, arm, damp, fric, act) in spec["joints"].items():
        if case:
            arm *= case.size("armature", j, 1.0)
            fric += case.size("coulomb", j, 0.0)
        play = case.size("backlash", j, 0.0) if case else 0.0
        stiff = (' solreffriction="0.0005 1" solimpfriction="0.999 0.9999 0.001"'
                 if case and case.size("coulomb", j, 0.0) else "")
        fl = f' frictionloss="{fric:.9g}"{stiff}' if fric else ""
        geoms = (f'<geom type="capsule" fromto="0 0 0 0 0 {-length:.9g}" size="0.008" '
                 f'mass="{rod:.9g}"/>')
        if tip:
            geoms += (f'<geom type="sphere" pos="0 0 {-length:.9g}" size="0.015" '
                      f'mass="{tip:.9g}"/>')
        at = "0 0 0.3" if parent == "world" else f"0 0 {-pos:.9g}"
        if play:
            # rotor (armature, damping, model friction) on the motor side; the link on a
            # hinge limited to the play, stiff limits
            body = (f'<body name="{j}_rotor" pos="{at}"><joint name="{j}_rotor" type="hinge" '
                    f'axis="{GRAVITY_AXIS}" damping="{damp:.9g}" armature="{arm:.9g}"{fl}/>'
                    f'<geom type="cylinder" size="0.005 0.005" mass="0.001"/>'
                    f'<body name="{j}" pos="0 0 0"><joint name="{j}" type="hinge" '
                    f'axis="{GRAVITY_AXIS}" limited="true" range="{-play / 2:.9g} '
                    f'{play / 2:.9g}" solreflimit="0.001 1"/>{geoms}{{{j}}}</body></body>')
        else:
            body = (f'<body name="{j}" pos="{at}"><joint name="{j}" type="hinge" '
                    f'axis="{GRAVITY_AXIS}" damping="{damp:.9g}" armature="{arm:.9g}"{fl}/>'
                    f'{geoms}{{{j}}}</body>')
        bodies.setdefault(parent, []).append(body)
        if act is None:
            continue
        kp, kv, force = act
        kp *= case.size("gain", j, 1.0) if case else 1.0
        if play:
            acts.append(f'<motor name="{servo(j)}" joint="{j}_rotor" ctrllimited="false"/>')
        else:
            acts.append(f'<position name="{servo(j)}" joint="{j}" kp="{kp:.9g}" kv="{kv:.9g}" '
                        f'forcelimited="true" forcerange="{-force:.9g} {force:.9g}"/>')

    # children are written into their parent's '{parent}' slot
    text = "".join(bodies["world"])
    for j in spec["joints"]:
        inner = "".join(bodies.get(j, []))
        text = text.replace("{" + j + "}", inner)
    tendon = ""
    if "tendon" in spec:
        a, b, k = spec["tendon"]
        tendon = (f'<tendon><fixed name="couple" stiffness="{k:.9g}" springlength="0">'
                  f'<joint joint="{a}" coef="1"/><joint joint="{b}" coef="-1"/></fixed></tendon>')
    return (f'<mujoco model="{rig}"><compiler angle="radian"/>'
            f'<option timestep="{timestep:.9g}" integrator="implicitfast"/>'
            f'<default><geom contype="0" conaffinity="0"/></default><worldbody>{text}'
            f'</worldbody>{tendon}<actuator>{"".join(acts)}</actuator></mujoco>')


def row_times(duration: float, rate: float, jitter: float, rng: np.random.Generator
              ) -> np.ndarray:
    """Host row times [s] from -SETTLE: the period plus uniform jitter of +-``jitter`` periods,
    1 % of rows a period late."""
    period = 1.0 / rate
    n = int((duration + SETTLE) * rate)
    steps = period * (1.0 + rng.uniform(-jitter, jitter, n))
    steps[rng.random(n) < 0.01] += period
    return np.cumsum(steps) - SETTLE


def targets(style: str, joint: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Target angles [rad] of ``joint`` at times ``t`` (held at the first target before 0)."""
    lo, hi = GOAL_RANGE[joint]
    mid, amp = (lo + hi) / 2, (hi - lo) / 2
    tt = np.maximum(t, 0.0)
    if style == "steps":
        edges = np.cumsum(rng.uniform(0.4, 1.3, int(t[-1] / 0.4) + 2))
        levels = mid + amp * rng.uniform(-0.95, 0.95, len(edges) + 1)
        return levels[np.searchsorted(edges, tt, side="right")]
    if style == "sine":
        f = rng.uniform(0.3, 0.8)
        return mid + 0.8 * amp * np.sin(2 * np.pi * f * tt + rng.uniform(0.0, 2 * np.pi))
    if style == "chirp":
        f0, f1, T = 0.1, 2.0, t[-1]
        return mid + 0.6 * amp * np.sin(2 * np.pi * (f0 * tt + (f1 - f0) * tt ** 2 / (2 * T)))
    raise ValueError(f"unknown style {style!r}; valid: steps, sine, chirp")


def simulate(case: Case, t_rows: np.ndarray, target: dict[str, np.ndarray],
             rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Run the truth through one log. Returns per row ``goal:<actuator>`` [rad],
    ``qpos:<joint>`` (read: offset, noise, 4096 ticks) and ``qvel:<joint>`` [rad/s]
    (quantised to Dynamixel units)."""
    spec = RIGS[case.rig]["joints"]
    model = mujoco.MjModel.from_xml_string(model_xml(case.rig, case, TRUTH_DT))
    data = mujoco.MjData(model)
    joints = list(spec)
    actuated = [j for j in joints if spec[j][-1] is not None]
    qadr = {j: model.jnt_qposadr[model.joint(j).id] for j in joints}
    dadr = {j: model.jnt_dofadr[model.joint(j).id] for j in joints}
    rotor = {j: (model.jnt_qposadr[model.joint(f"{j}_rotor").id],
                 model.jnt_dofadr[model.joint(f"{j}_rotor").id])
             for j in joints if case.size("backlash", j)}
    act = {j: model.actuator(servo(j)).id for j in actuated}

    def angle(j: str) -> float:   # the output angle (rotor + play) [rad]
        return data.qpos[qadr[j]] + (data.qpos[rotor[j][0]] if j in rotor else 0.0)

    def speed(j: str) -> float:
        return data.qvel[dadr[j]] + (data.qvel[rotor[j][1]] if j in rotor else 0.0)

    latency = case.size("latency")
    n = len(t_rows)
    out = {f"goal:{servo(j)}": np.empty(n) for j in actuated}
    out |= {f"qpos:{j}": np.empty(n) for j in joints}
    out |= {f"qvel:{j}": np.empty(n) for j in joints}
    # start at rest at the first targets (the distal joint where the tendon holds it)
    for j in joints:
        q0 = target[j][0] if j in target else 0.0
        if j in rotor:
            data.qpos[rotor[j][0]] = q0
        else:
            data.qpos[qadr[j]] = q0
    cmd = {j: target[j][0] for j in actuated}
    pending: list[tuple[float, dict]] = []
    mujoco.mj_forward(model, data)
    t = t_rows[0] - TRUTH_DT
    row = 0
    while row < n:
        while row < n and t_rows[row] <= t + TRUTH_DT / 2:
            for j in joints:
                off = case.size("reading_offset", j)
                noisy = angle(j) + off + rng.normal(0.0, NOISE)
                out[f"qpos:{j}"][row] = np.round(noisy / TICK) * TICK
                v = speed(j) + rng.normal(0.0, 0.3 * VEL_UNIT)
                out[f"qvel:{j}"][row] = np.round(v / VEL_UNIT) * VEL_UNIT
            goals = {j: float(target[j][row]) for j in actuated}
            for j in actuated:
                out[f"goal:{servo(j)}"][row] = goals[j]
            pending.append((t_rows[row] + latency, goals))
            row += 1
        while pending and pending[0][0] <= t + TRUTH_DT / 2:
            cmd = pending.pop(0)[1]
        for j in actuated:
            if j in rotor:   # the firmware's PD on the output reading, its force range
                kp, kv, force = spec[j][-1]
                kp *= case.size("gain", j, 1.0)
                data.ctrl[act[j]] = float(np.clip(kp * (cmd[j] - angle(j)) - kv * speed(j),
                                                  -force, force))
            else:
                data.ctrl[act[j]] = cmd[j]
        data.qfrc_applied[:] = 0.0
        for j in joints:
            visc = case.size("viscous", j)
            if visc:
                data.qfrc_applied[dadr[j]] = -visc * speed(j)
        mujoco.mj_step(model, data)
        t += TRUTH_DT
    if not all(np.all(np.isfinite(v)) for v in out.values()):
        raise RuntimeError(f"{case.name}: the truth simulation diverged")
    return out


def expected_params(case: Case) -> list[dict]:
    """Each hidden cause's catalogue parameter as sim2's ``score`` reads it."""
    return [dict(effect=CATALOGUE[e.kind], param=PARAM[e.kind], joint=e.joints[0],
                 value=e.value, abs=e.kind == "reading_offset") for e in case.effects]


def spelled(case: Case, t: np.ndarray, cols: dict[str, np.ndarray], rng: np.random.Generator
            ) -> tuple[list[str], np.ndarray, list[str]]:
    """The columns as the user's logger writes them: (header, rows, number formats)."""
    cols = dict(cols)
    if case.angles == "deg":
        cols = {k: v * 180 / math.pi if k.split(":")[0] in ("goal", "qpos", "qvel") else v
                for k, v in cols.items()}
    if not case.qvel:
        cols = {k: v for k, v in cols.items() if not k.startswith("qvel:")}
    if case.stamps == "ms":      # millis() of a board booted 731.2 s before the log
        stamp = np.floor((t + 731.2) * 1e3)
    elif case.stamps == "us":    # a monotonic clock in integer microseconds
        stamp = np.floor((t + 58_211.0) * 1e6)
    else:
        stamp = t
    names = ["time", *cols]
    fmts = ["%d" if case.stamps in ("ms", "us") else "%.9g"] + ["%.9g"] * len(cols)
    data = np.column_stack([stamp, *cols.values()])
    if case.order == "shuffled":
        perm = rng.permutation(len(names))
        names, data, fmts = [names[i] for i in perm], data[:, perm], [fmts[i] for i in perm]
    keep = np.ones(len(t), bool)
    if case.dropped:
        a = rng.uniform(0.3, 0.6) * t[-1]
        keep &= ~((t >= a) & (t < a + case.dropped))
    data = data[keep]
    if case.doubled:
        twice = rng.random(len(data)) < case.doubled
        data = np.repeat(data, np.where(twice, 2, 1), axis=0)
    return names, data, fmts


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (nominal), ``log<i>.csv``, ``args.json`` (the options a user passes
    for these logs) and ``truth.json`` into ``folder``. Returns {"model", "logs", "args",
    "truth"}."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml(case.rig))
    rng = np.random.default_rng(case.seed)
    spec = RIGS[case.rig]["joints"]
    logs = []
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.rate, case.jitter, rng)
        style = case.styles[i % len(case.styles)]
        target = {j: targets(style, j, t, rng) for j in spec if spec[j][-1] is not None}
        out = simulate(case, t, target, rng)
        keep = t >= 0.0
        cols = {k: v[keep] for k, v in out.items()}
        # the spelling draws from its own stream: a log's truth is the same however spelled
        names, data, fmt = spelled(case, t[keep] + 0.02, cols,
                                   np.random.default_rng([case.seed, 1000 + i]))
        path = folder / f"log{i}.csv"
        np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)
        logs.append(str(path))
    truth = {"case": case.name, "rig": case.rig, "causes": sorted(case.causes),
             "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case), "args": list(case.args)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    (folder / "args.json").write_text(json.dumps(list(case.args)))
    return {"model": str(folder / "model.xml"), "logs": logs, "args": list(case.args),
            "truth": truth}


E = Effect
SH, EL = ("shoulder",), ("elbow",)
# priority order (what the other sets leave out first)
CASES: tuple[Case, ...] = (
    Case("clean_arm2_deg_ms", "arm2", (), angles="deg", stamps="ms", order="shuffled",
         dropped=0.4, seed=61,
         note="no hidden effect; degrees, millis() stamps, a user's column order, 0.4 s of "
              "rows dropped"),
    Case("coulomb_more_arm2", "arm2", (E("coulomb", 0.12, EL),), rate=200.0, doubled=0.02,
         seed=62, note="the elbow's friction 0.03 -> 0.15 N m (the model's guess too low); "
                       "2 % of rows written twice"),
    Case("latency040_gain18_pendulum_30hz", "pendulum",
         (E("latency", 0.040), E("gain", 1.8)), rate=30.0, stamps="ms",
         durations=(20.0, 20.0), seed=63, note="a pair at 30 Hz with millis() stamps"),
    Case("servo_friction_pendulum", "pendulum", (E("coulomb", 0.08), E("viscous", 0.03)),
         seed=64, order="shuffled", note="a small servo's Coulomb + viscous (BAM's M1 class)"),
    Case("backlash2deg_pendulum_500hz_us", "pendulum", (E("backlash", math.radians(2.0)),),
         rate=500.0, stamps="us", durations=(8.0, 8.0), styles=("steps", "chirp"), seed=65,
         note="2 deg of play, encoder on the output; integer-us stamps at 500 Hz"),
    Case("armature25_arm2_deg", "arm2", (E("armature", 2.5, SH),), angles="deg",
         styles=("steps", "chirp"), seed=66,
         note="the shoulder's reflected inertia 0.010 -> 0.025 (the user's guess too low)"),
    Case("gain06_finger_tendon_50hz", "finger", (E("gain", 0.6, ("pip",)),), rate=50.0,
         seed=67, note="an unactuated distal joint on a passive tendon spring"),
    Case("offset028_arm2", "arm2", (E("reading_offset", 0.28, EL),), dropped=0.3, seed=68,
         note="a reading offset beyond the +-0.2 search range; 0.3 s of rows dropped"),
    Case("latency008_pendulum_1khz", "pendulum", (E("latency", 0.008),), rate=1000.0,
         durations=(8.0, 8.0), seed=69, note="a few ms of latency logged at 1 kHz"),
)
CASE_BY_NAME = {c.name: c for c in CASES}


def effect_size(case: Case) -> dict:
    """How far each joint of ``case``'s logs is from the user's nominal model replayed open loop
    in plain mujoco (2 ms, the logged goals held from their rows, from the first logged reading
    at rest): {"rms": [rad per joint], "max": [rad per joint]}. Read in rad/s whatever the
    spelling (the truth is simulated before it is spelled)."""
    rng = np.random.default_rng(case.seed)
    spec = RIGS[case.rig]["joints"]
    joints = list(spec)
    model = mujoco.MjModel.from_xml_string(model_xml(case.rig))
    errs = {j: [] for j in joints}
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.rate, case.jitter, rng)
        style = case.styles[i % len(case.styles)]
        target = {j: targets(style, j, t, rng) for j in spec if spec[j][-1] is not None}
        out = simulate(case, t, target, rng)
        keep = t >= 0.0
        t = t[keep]
        data = mujoco.MjData(model)
        for j in joints:
            data.qpos[model.jnt_qposadr[model.joint(j).id]] = out[f"qpos:{j}"][keep][0]
        sim_q = {j: np.empty(len(t)) for j in joints}
        tt, k = t[0], 0
        while k < len(t):
            while k < len(t) and t[k] <= tt + MODEL_DT / 2:
                for j in joints:
                    sim_q[j][k] = data.qpos[model.jnt_qposadr[model.joint(j).id]]
                for a in range(model.nu):
                    data.ctrl[a] = out[f"goal:{model.actuator(a).name}"][keep][k]
                k += 1
            mujoco.mj_step(model, data)
            tt += MODEL_DT
        for j in joints:
            errs[j].append(out[f"qpos:{j}"][keep] - sim_q[j])
    e = {j: np.concatenate(v) for j, v in errs.items()}
    return {"rms": [float(np.sqrt(np.mean(x ** 2))) for x in e.values()],
            "max": [float(np.abs(x).max()) for x in e.values()]}
