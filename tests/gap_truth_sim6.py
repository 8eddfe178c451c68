"""A sixth independent truth simulator for the gap analysis: effects the other five leave out,
and effects outside any catalogue (issue 11 item 4; gap-sim6, session 18).

Written with mujoco, numpy and the stdlib only, importing nothing from lowcostdex (no effect,
plant, servo or gap code) and without reading the analyzer or the earlier truth simulators'
physics (only their docstrings, to see what they cover). The user's side is what the docs say
(docs/gap_analysis.md: the CSV log format, ``voltage:`` and ``temperature:`` columns, ``motor``
actuators whose goal is the torque a host PD wrote).

Rig (``RIG``): an Allegro-class 4-joint finger hanging from a palm (the hand mounted palm down):
``abd`` (abduction, about x), then ``mcp``, ``pip``, ``dip`` (flexion, about y); links of
16 / 54 / 38.4 / 43.7 mm and 12 / 65 / 35 / 30 g (explicit inertials, the distal one with its
fingertip), a reflected rotor inertia (armature) of 1.0 g m^2 and gear damping 0.01 N m s/rad
per joint. Written two ways (``Case.kind``):

* ``torque``: as an Allegro hand is driven: the host runs a PD at 333 Hz on the joint readings
  (kp 1.2 N m/rad, D on the differenced reading, kd 0.03 N m s/rad, clipped to +-0.7 N m,
  no gravity compensation) and writes TORQUES over CAN; the log's goal is that torque and the
  user's model has ``<motor ctrlrange="-0.7 0.7">`` actuators. Open-loop replay of a torque log
  only stays bounded because the finger hangs (gravity restores) and the gears damp it.
* ``position``: the same finger on position servos, the user's model ``<position kp="1.2"
  kv="0.03" forcerange="-0.7 0.7">``, goals (ticks) written at 100 Hz.

The truth always drives ``motor`` actuators with a torque computed here every 0.25 ms physics
step (the position servo's law on its own reading, or the host's held torque), so every effect
below acts where it acts on the hardware.

Hidden effects (``Effect.kind``), written from their physics:

* ``read_delay``: the reading (host and log) is the joint angle ``value`` s old (a sensor /
  status-packet delay, not a command latency); the servo or host loop acts on that stale read.
  In an open-loop replay it shows as a latency (reference 04-sysid, section 6): scored as
  ``latency`` with delay = ``value``.
* ``voltage_sag``: one supply of ``V0`` = 12 V behind a resistance of ``value`` ohm feeds all
  four motors; each draws |torque| / 0.7 N m x 1.5 A; the motors' torque (PWM drive: stall
  torque and P gain alike) scales with V / V0; the servos report their input voltage
  (``voltage:<actuator>``, 0.1 V resolution). Scored as ``voltage_sag``.
* ``thermal``: each motor's torque per command falls by ``value`` per kelvin above 25 deg C
  (winding resistance and magnet); the logs are taken at three times of one long session, the
  motors at 35, 55 and 75 deg C and warming by their own I^2 R (a first-order thermal model),
  reported as ``temperature:<actuator>`` (1 deg C resolution). Scored as ``thermal_derating``.
* ``deadband``: the drive gives no torque below ``value`` N m of command and ``|c| - value``
  above it (a PWM deadband). Outside the catalogue until session 21; since then scored as its
  ``deadband`` with width = ``value`` (on a torque rig the band is in the command's units, N m).
* Outside any catalogue (the right answer is no confident wrong name; ``OUTSIDE``):
  ``series_elastic``: the joint is a rotor hinge (carrying the
  armature and gear damping, driven by the motor) and a link hinge on it with a spring of
  ``value`` N m/rad (a compliant coupling, e.g. a belt or horn), the servo closing its loop on
  its rotor encoder and the log reading the link (a joint encoder); ``encoder_sine``: the
  joint's encoder reads q + ``value`` sin(q + 0.7) (a once-per-turn eccentricity), the host's
  loop closing on that reading (on the torque rig the replay sees it; a position servo closing
  on its own reading would hide it); ``com_offset``: the centre of mass of the middle and distal links
  moved ``value`` m toward the palm side, perpendicular to the link (a fingertip sensor pad;
  masses unchanged).

Logs (the project's CSV format, ``time``, ``goal:<actuator>``, ``qpos:<joint>``, optionally
``voltage:`` / ``temperature:``; no ``qvel``: an Allegro reports none): row times on the truth's
0.25 ms grid with +-1 step jitter, the reading quantised to 4096 ticks per turn after 0.4 mrad
of read noise, the goal written right after the read and acting from the row. Each log starts
after 1 s held at its first target. Excitation per joint: steps with holds, chirps 0.3-2.5 Hz
and holds approached from both sides, all four joints moving at once.

``write_case`` writes what a user brings (``model.xml``, ``log<i>.csv``) and ``truth.json``;
``score`` grades a report.json: exact / family (confusable) / wrong / miss / clean / false, and
for effects outside the catalogue ``pass`` (nothing named, or what is named lowers the held-out
error with its 95 % interval above zero) or ``fail`` (returned as the harness's ``clean`` and
``false``, the brief's word in ``verdict6``).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import mujoco
import numpy as np
from redteam_grade import grade

TICK = 2 * math.pi / 4096      # rad per encoder tick
TRUTH_DT = 0.00025             # s, the truth's physics step
MODEL_DT = 0.002               # s, the user's model step
READ_NOISE = 0.0004            # rad, read noise before quantisation
SETTLE = 1.0                   # s held at the first target before the first row
JOINTS = ("abd", "mcp", "pip", "dip")
ACTS = tuple(f"m_{j}" for j in JOINTS)
KP, KD, TAU_MAX = 1.2, 0.03, 0.7         # host PD / servo law, N m/rad, N m s/rad, N m
ARMATURE, DAMPING = 0.001, 0.01          # kg m^2, N m s/rad per joint
V0, AMPS_AT_MAX = 12.0, 1.5              # supply [V], current at 0.7 N m [A]
# link: (length to the next joint [m], mass [kg], centre of mass along the link [m])
LINKS = ((0.016, 0.012, 0.008), (0.054, 0.065, 0.027), (0.0384, 0.035, 0.0192),
         (0.0437, 0.030, 0.026))
RANGE = {"abd": (-0.4, 0.4), "mcp": (-0.3, 1.2), "pip": (-0.2, 1.3), "dip": (-0.2, 1.2)}

# the catalogue name a correct analysis gives, per effect kind (None: outside the catalogue)
CATALOGUE = {"read_delay": "latency", "voltage_sag": "voltage_sag",
             "thermal": "thermal_derating", "deadband": "deadband", "series_elastic": None,
             "encoder_sine": None, "com_offset": None}
OUTSIDE = {k for k, v in CATALOGUE.items() if v is None}
# confusable neighbours (naming one of these for the other is "family")
FAMILIES = (
    {"latency"},
    {"voltage_sag", "torque_limit", "gain_error", "motor_strength", "thermal_derating"},
    {"thermal_derating", "gain_error", "motor_strength", "voltage_sag"},
    {"deadband", "coulomb_friction", "backlash", "gain_error"},  # a band: friction-like, a play
)


@dataclasses.dataclass(frozen=True)
class Effect:
    """A hidden effect ``kind`` of size ``value`` on ``joints`` (empty: all four)."""

    kind: str
    value: float
    joints: tuple[str, ...] = ()

    def __post_init__(self):
        if self.kind not in CATALOGUE:
            raise ValueError(f"unknown effect {self.kind!r}; valid: {sorted(CATALOGUE)}")

    def on(self, joint: str) -> bool:
        return not self.joints or joint in self.joints


@dataclasses.dataclass(frozen=True)
class Case:
    """One analysis case: actuator ``kind`` (torque / position), hidden effects, the logs
    (``durations`` s each, ``styles`` cycled, ``rate`` Hz), ``seed``."""

    name: str
    kind: str
    effects: tuple[Effect, ...] = ()
    rate: float = 0.0
    durations: tuple[float, ...] = (10.0, 10.0, 10.0)
    styles: tuple[str, ...] = ("steps", "chirp", "holds")
    seed: int = 0
    note: str = ""
    qvel: bool = False
    rig: str = "allegro_finger"

    def __post_init__(self):
        if self.kind not in ("torque", "position"):
            raise ValueError(f"kind {self.kind!r}; valid: 'torque', 'position'")
        if not self.rate:   # an Allegro's host loop, a Dynamixel bus's usual rate
            object.__setattr__(self, "rate", 333.0 if self.kind == "torque" else 100.0)

    @property
    def log_rate(self) -> float:
        return self.rate

    @property
    def causes(self) -> set[str]:
        return {CATALOGUE[e.kind] for e in self.effects if CATALOGUE[e.kind]}

    @property
    def outside(self) -> bool:
        return any(e.kind in OUTSIDE for e in self.effects)

    def effect(self, kind: str) -> Effect | None:
        return next((e for e in self.effects if e.kind == kind), None)


# ---------------------------------------------------------------------------------------------
# MJCF
# ---------------------------------------------------------------------------------------------

def _inertial(length: float, mass: float, com: float, perp: float) -> str:
    # a slender link along -z: rod inertia about its centre, plus a little thickness
    ixx = mass * (length ** 2 / 12 + 0.01 ** 2 / 4)
    izz = mass * 0.01 ** 2 / 2
    return (f'<inertial pos="{-perp:.6g} 0 {-com:.6g}" mass="{mass:.6g}" '
            f'diaginertia="{ixx:.6g} {ixx:.6g} {izz:.6g}"/>')


def model_xml(kind: str, case: Case | None = None, truth: bool = False) -> str:
    """The finger's MJCF: the user's nominal model (``truth`` False: ``kind``'s actuators, 2 ms)
    or the truth (``motor`` actuators, 0.25 ms, ``case``'s structural effects)."""
    sea = case.effect("series_elastic") if (truth and case) else None
    com = case.effect("com_offset") if (truth and case) else None
    body, close = [], []
    for i, (j, (length, mass, c)) in enumerate(zip(JOINTS, LINKS, strict=True)):
        pos = "0 0 0" if i == 0 else f"0 0 {-LINKS[i - 1][0]:.6g}"
        axis = "1 0 0" if j == "abd" else "0 1 0"
        lo, hi = RANGE[j]
        perp = com.value if (com and i >= 2 and com.on(j)) else 0.0
        if sea and sea.on(j):
            # rotor hinge (armature, gear damping, driven) and the link on a spring
            body.append(f'<body name="r_{j}" pos="{pos}">'
                        f'<joint name="rotor_{j}" axis="{axis}" armature="{ARMATURE}" '
                        f'damping="{DAMPING}"/>'
                        f'<inertial pos="0 0 0" mass="0.001" diaginertia="1e-7 1e-7 1e-7"/>'
                        f'<body name="l_{j}" pos="0 0 0">'
                        f'<joint name="{j}" axis="{axis}" stiffness="{sea.value}" '
                        f'damping="0.002"/>' + _inertial(length, mass, c, perp))
            close.append("</body></body>")
        else:
            body.append(f'<body name="l_{j}" pos="{pos}">'
                        f'<joint name="{j}" axis="{axis}" range="{lo - 0.6} {hi + 0.6}" '
                        f'limited="true" armature="{ARMATURE}" damping="{DAMPING}"/>'
                        + _inertial(length, mass, c, perp))
            close.append("</body>")
    chain = "".join(body) + "".join(reversed(close))
    acts = []
    for j, a in zip(JOINTS, ACTS, strict=True):
        target = f"rotor_{j}" if (sea and sea.on(j)) else j
        if truth or kind == "torque":
            acts.append(f'<motor name="{a}" joint="{target}" ctrlrange="-{TAU_MAX} {TAU_MAX}" '
                        f'ctrllimited="true"/>')
        else:
            lo, hi = RANGE[j]
            acts.append(f'<position name="{a}" joint="{j}" kp="{KP}" kv="{KD}" '
                        f'forcerange="-{TAU_MAX} {TAU_MAX}" ctrlrange="{lo - 0.5} {hi + 0.5}"/>')
    dt = TRUTH_DT if truth else MODEL_DT
    return (f'<mujoco model="allegro_finger">\n<compiler angle="radian"/>\n'
            f'<option timestep="{dt}" integrator="implicitfast" gravity="0 0 -9.81"/>\n'
            f'<worldbody>\n<body name="palm" pos="0 0 0.3">\n{chain}\n</body>\n</worldbody>\n'
            f'<actuator>\n' + "\n".join(acts) + "\n</actuator>\n</mujoco>\n")


# ---------------------------------------------------------------------------------------------
# excitation
# ---------------------------------------------------------------------------------------------

def targets(style: str, joint: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Target angle [rad] of ``joint`` at times ``t`` for a trajectory ``style``."""
    lo, hi = RANGE[joint]
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    if style == "chirp":
        f0, f1 = rng.uniform(0.3, 0.6), rng.uniform(1.5, 2.5)
        T = t[-1] - t[0] + 1e-9
        ph = 2 * math.pi * (f0 * (t - t[0]) + (f1 - f0) * (t - t[0]) ** 2 / (2 * T))
        return mid + 0.6 * half * np.sin(ph + rng.uniform(0, 2 * math.pi))
    out = np.empty_like(t)
    k, level = 0, mid
    while k < len(t):
        hold = rng.uniform(0.3, 1.0) if style == "steps" else rng.uniform(0.6, 1.4)
        n = max(1, int(np.searchsorted(t, t[k] + hold) - k))
        if style == "steps":
            level = rng.uniform(lo + 0.1 * half, hi - 0.1 * half)
            out[k:k + n] = level
        else:  # holds approached from both sides by a ramp
            new = float(np.clip(level + rng.choice([-1, 1]) * rng.uniform(0.2, 0.8) * half,
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


# ---------------------------------------------------------------------------------------------
# the truth
# ---------------------------------------------------------------------------------------------

def simulate(case: Case, t: np.ndarray, target: dict[str, np.ndarray],
             rng: np.random.Generator, temp0: float = 25.0,
             true_angles: bool = False) -> dict[str, np.ndarray]:
    """Run the truth over rows ``t`` (s, on the 0.25 ms grid, from 0) tracking ``target`` (per
    joint, at the rows). Returns the log's columns (rad, N m, V, deg C) per row, and with
    ``true_angles`` the joints' true angles at the rows (``true:<joint>``, not logged)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case.kind, case, truth=True))
    d = mujoco.MjData(m)
    qadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in JOINTS])
    vadr = np.array([m.jnt_dofadr[m.joint(j).id] for j in JOINTS])
    first = np.array([target[j][0] for j in JOINTS])
    sea = case.effect("series_elastic")
    # a series-elastic joint's angle is its rotor's plus the link's on the spring
    radr = np.array([m.jnt_qposadr[m.joint(f"rotor_{j}").id] if (sea and sea.on(j)) else -1
                     for j in JOINTS])
    rdof = np.array([m.jnt_dofadr[m.joint(f"rotor_{j}").id] if (sea and sea.on(j)) else -1
                     for j in JOINTS])
    has_r = radr >= 0
    d.qpos[qadr] = np.where(has_r, 0.0, first)
    d.qpos[radr[has_r]] = first[has_r]
    mujoco.mj_forward(m, d)

    def angle() -> np.ndarray:
        return d.qpos[qadr] + np.where(has_r, d.qpos[radr], 0.0)

    def rotor() -> tuple[np.ndarray, np.ndarray]:
        """What a position servo's own encoder reads: the rotor on a series-elastic joint."""
        return (np.where(has_r, d.qpos[radr], d.qpos[qadr]),
                np.where(has_r, d.qvel[rdof], d.qvel[vadr]))

    def speed() -> np.ndarray:
        return d.qvel[vadr] + np.where(has_r, d.qvel[rdof], 0.0)

    settle = round(SETTLE / TRUTH_DT)
    rows = np.round(t / TRUTH_DT).astype(int) + settle
    n_steps = rows[-1] + 1
    rd = case.effect("read_delay")
    lag = round(rd.value / TRUTH_DT) if rd else 0
    lag_on = np.array([bool(rd and rd.on(j)) for j in JOINTS])
    enc = case.effect("encoder_sine")
    enc_on = np.array([bool(enc and enc.on(j)) for j in JOINTS])
    db = case.effect("deadband")
    vs = case.effect("voltage_sag")
    th = case.effect("thermal")
    hist = np.zeros((n_steps + 1, 4))
    torque_mode = case.kind == "torque"
    cmd = np.zeros(4)        # torque command held (torque mode) / goal held (position mode)
    goal = first.copy()
    last_read, last_read_t = None, None
    temp = np.full(4, temp0)
    volts = V0
    out = {f"goal:{a}": np.empty(len(t)) for a in ACTS}
    out.update({f"qpos:{j}": np.empty(len(t)) for j in JOINTS})
    if vs:
        out.update({f"voltage:{a}": np.empty(len(t)) for a in ACTS})
    if th:
        out.update({f"temperature:{a}": np.empty(len(t)) for a in ACTS})
    if true_angles:
        out.update({f"true:{j}": np.empty(len(t)) for j in JOINTS})
    r = 0
    noise = rng.normal(0.0, READ_NOISE, size=(len(t), 4))

    def sensed(step: int) -> np.ndarray:
        q = np.where(lag_on, hist[max(step - lag, 0)], hist[step])
        if enc:
            q = q + np.where(enc_on, enc.value * np.sin(q + 0.7), 0.0)
        return q

    for s in range(n_steps):
        hist[s] = angle()
        if s < settle:   # the settle: a clean PD / servo holding the first target
            goal_now, is_row = first, False
        else:
            is_row = s == rows[r] if r < len(rows) else False
            goal_now = goal
        if is_row:
            read = np.round((sensed(s) + noise[r]) / TICK) * TICK
            tgt = np.array([target[j][r] for j in JOINTS])
            if torque_mode:
                if last_read is None:
                    dq = np.zeros(4)
                else:
                    dq = (read - last_read) / max(t[r] - last_read_t, 1e-6)
                cmd = np.clip(KP * (tgt - read) - KD * dq, -TAU_MAX, TAU_MAX)
                cmd = np.round(cmd, 5)
                last_read, last_read_t = read, t[r]
                goal_col = cmd
            else:
                goal = np.round(tgt / TICK) * TICK
                goal_col = goal
            for k, (j, a) in enumerate(zip(JOINTS, ACTS, strict=True)):
                out[f"goal:{a}"][r] = goal_col[k]
                out[f"qpos:{j}"][r] = read[k]
                if vs:
                    out[f"voltage:{a}"][r] = round(volts, 1)
                if th:
                    out[f"temperature:{a}"][r] = round(temp[k])
                if true_angles:
                    out[f"true:{j}"][r] = hist[s][k]
            r += 1
        # the drive's torque this step
        if torque_mode and s >= settle:
            tau = cmd.copy()
        else:
            servo_read = sensed(s)   # the servo's / host's own (fresh or stale) reading
            if torque_mode:   # settle: a continuous PD holding the first target
                dq = np.where(lag_on, 0.0, speed())
            else:
                dq = speed() if not lag else np.where(
                    lag_on, (hist[max(s - lag, 0)] - hist[max(s - lag - 1, 0)]) / TRUTH_DT,
                    speed())
                if sea:
                    servo_read, dq = rotor()
            tau = np.clip(KP * (goal_now - servo_read) - KD * dq, -TAU_MAX, TAU_MAX)
        if db:
            on = np.array([db.on(j) for j in JOINTS])
            tau = np.where(on, np.sign(tau) * np.maximum(np.abs(tau) - db.value, 0.0), tau)
        if vs:
            amps = np.abs(tau) / TAU_MAX * AMPS_AT_MAX
            # the supply's own filter (bulk capacitance): 1 ms
            v_target = V0 - vs.value * float(np.sum(amps * volts / V0))
            volts += (v_target - volts) * TRUTH_DT / 0.001
            tau = tau * volts / V0
        if th:
            tau = tau * (1.0 - th.value * (temp - 25.0))
            # I^2 R heating: 2.5 W at the current of 0.7 N m, 8 J/K, 15 K/W to ambient
            p = 2.5 * (tau / TAU_MAX) ** 2
            temp += TRUTH_DT * (p - (temp - 25.0) / 15.0) / 8.0
        d.ctrl[:] = tau
        mujoco.mj_step(m, d)
    return out


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (the user's nominal model), ``log<i>.csv`` and ``truth.json`` into
    ``folder``. Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml(case.kind))
    rng = np.random.default_rng(case.seed)
    th = case.effect("thermal")
    logs = []
    for i, dur in enumerate(case.durations):
        t = row_times(dur, case.log_rate, rng)
        style = case.styles[i % len(case.styles)]
        tgt = {j: targets(style, j, t, rng) for j in JOINTS}
        out = simulate(case, t, tgt, rng, temp0=(35.0 + 20.0 * i) if th else 25.0)
        names = ["time", *out]
        data = np.column_stack([t, *out.values()])
        path = folder / f"log{i}.csv"
        fmt = ["%.5f"] + ["%.8g"] * len(out)
        np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)
        logs.append(str(path))
    truth = {"case": case.name, "kind": case.kind, "causes": sorted(case.causes),
             "outside": case.outside, "effects": [dataclasses.asdict(e) for e in case.effects],
             "expected_params": expected_params(case)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": logs, "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """Documented catalogue parameters whose true value is plain: the read delay as a
    latency's ``delay`` [s]; a torque rig's deadband as its ``width`` [N m of command]."""
    out = []
    for e in case.effects:
        if e.kind == "read_delay":
            out += [dict(effect="latency", param="delay", joint=j, value=e.value, abs=False)
                    for j in (e.joints or JOINTS)]
        if e.kind == "deadband" and case.kind == "torque":
            out += [dict(effect="deadband", param="width", joint=j, value=e.value, abs=False)
                    for j in (e.joints or JOINTS)]
    return out


# ---------------------------------------------------------------------------------------------
# the user's model replayed open loop in plain mujoco (how big each effect is in the logs)
# ---------------------------------------------------------------------------------------------

def replay_nominal(kind: str, t: np.ndarray, goals: np.ndarray, q0: np.ndarray,
                   dt: float = TRUTH_DT) -> np.ndarray:
    """The nominal model replayed open loop from rest at ``q0`` with ``goals`` held from each
    row (zero-order hold) at step ``dt`` (default the truth's, so that the rows' instants are
    steps: a torque log replayed at 2 ms with goals switched on the 2 ms grid drifts 10-100
    mrad from its own truth); returns qpos at the rows."""
    m = mujoco.MjModel.from_xml_string(model_xml(kind))
    m.opt.timestep = dt
    d = mujoco.MjData(m)
    qadr = [m.jnt_qposadr[m.joint(j).id] for j in JOINTS]
    d.qpos[qadr] = q0
    mujoco.mj_forward(m, d)
    out = np.empty((len(t), 4))
    for r in range(len(t)):
        out[r] = d.qpos[qadr]
        d.ctrl[:] = goals[r]
        end = t[r + 1] if r + 1 < len(t) else t[r]
        while d.time < end - 1e-9:
            mujoco.mj_step(m, d)
    return out


def effect_size(case: Case, seconds: float = 6.0) -> dict:
    """RMS and max of (reading - the nominal model's open-loop replay at 0.25 ms) per joint
    [rad] on the first ``seconds`` of each of the case's first two logs."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        short = dataclasses.replace(case, durations=tuple(min(seconds, x)
                                                          for x in case.durations[:2]))
        files = write_case(short, tmp)
        rms, mx = np.zeros(4), np.zeros(4)
        for path in files["logs"]:
            cols = np.genfromtxt(path, delimiter=",", skip_header=1)
            head = pathlib.Path(path).read_text().splitlines()[0].split(",")
            t = cols[:, 0]
            goals = cols[:, [head.index(f"goal:{x}") for x in ACTS]]
            q = cols[:, [head.index(f"qpos:{j}") for j in JOINTS]]
            sim = replay_nominal(case.kind, t, goals, q[0])
            e = q - sim
            rms = np.maximum(rms, np.sqrt(np.mean(e ** 2, axis=0)))
            mx = np.maximum(mx, np.abs(e).max(axis=0))
    return {"rms": rms.tolist(), "max": mx.tolist()}


# ---------------------------------------------------------------------------------------------
# the cases
# ---------------------------------------------------------------------------------------------

E = Effect
CASES: tuple[Case, ...] = (
    Case("clean_torque_333hz", "torque", seed=1,
         note="no hidden effect; host PD torques at 333 Hz on motor actuators"),
    Case("read_delay_9ms_torque", "torque", (E("read_delay", 0.009),), seed=2,
         note="readings 9 ms old (3 host periods): a latency in replay"),
    Case("voltage_sag_torque", "torque", (E("voltage_sag", 0.5),), seed=3,
         styles=("steps",), note="0.5 ohm supply: 12 V sagging ~1 V when the joints push (up to 3 V at full torque)"),
    Case("deadband_torque", "torque", (E("deadband", 0.01),), seed=4,
         note="PWM deadband of 0.01 N m (1.4 % of the torque range); the catalogue's "
              "deadband since session 21"),
    Case("series_elastic_mcp_position", "position", (E("series_elastic", 10.0, ("mcp",)),),
         seed=5, note="a 10 N m/rad spring between the mcp rotor and its link, outside the "
                      "catalogue"),
    Case("thermal_position", "position", (E("thermal", 0.004),), seed=6,
         note="torque per command -0.4 %/K; logs at 35, 55, 75 deg C (-4 % to -20 %)"),
    Case("clean_position_100hz", "position", seed=7, note="no hidden effect"),
    Case("encoder_sine_torque", "torque", (E("encoder_sine", 0.005),), seed=8,
         note="a 5 mrad once-per-turn encoder error on every joint, outside the catalogue"),
    Case("com_offset_torque", "torque", (E("com_offset", 0.005),), seed=9,
         note="middle and distal links' centre of mass 5 mm to the palm side, masses "
              "unchanged, outside the catalogue"),
)
CASE_BY_NAME = {c.name: c for c in CASES}


# ---------------------------------------------------------------------------------------------
# scoring
# ---------------------------------------------------------------------------------------------

def score(report: dict, truth: dict) -> dict:
    """Grade one report.json against ``truth`` with the red-team sets' one grader
    (``redteam_grade.grade``): ``result`` in the harness's words (exact / extra / family / miss /
    clean / false); ``verdict6`` in this set's words: exact, confusable (a neighbour named), wrong
    (something else named), missed, false (a clean case named something), clean, and for effects
    outside the catalogue ``pass`` (nothing named, or the named effects lower the held-out RMSE
    with the gain's 95 % interval above 0) or ``fail`` (something named that does not hold up on
    held-out data)."""
    return grade(report, truth, FAMILIES)
