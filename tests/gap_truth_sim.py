"""An independent "truth" simulator for the gap analysis (issue 11): no inverse crime.

The analyzer's own generator (``lowcostdex gap generate``) makes its "measured" data with the
same effect code, plant and servo model the analyzer fits, so it cannot catch a wrong or narrow
model of an effect. This module is written from the physics instead and imports only mujoco and
numpy (nothing from lowcostdex): plain MJCF with standard ``position`` actuators (kp, forcerange),
each hidden effect implemented here, its own excitation, sensor model and CSV writer.

Rigs (both hang under gravity; actuators are named after the joints they drive):

* ``bench``: one hinge about x swinging a 0.3 kg point load on a 0.1 m arm, kp 8 N m/rad,
  force range +-5 N m, armature 0.01 kg m^2, damping 0.05 N m s/rad.
* ``finger``: a D'Claw-like 3-joint finger pointing down (top joint about y, middle and bottom
  about x), links of 0.068 / 0.068 / 0.05 m carrying the next servo's mass, kp 6 N m/rad.

Hidden effects, written out (magnitudes per joint, drawn by ``draw``):

* ``latency``: a goal queue; a goal written at t reaches the servo at t + delay (20-60 ms), at
  the first physics step at or after that instant.
* ``backlash``: a second hinge between the motor and the link whose range is the play
  (+-width/2, width 20-60 mrad, a stiff joint limit); the position actuator drives the motor
  joint (its own sensor), the log reads the link angle (motor + play).
* ``position_offset``: the logged reading is the joint angle plus a constant (+-30-80 mrad); the
  servo itself controls the true angle.
* ``gain_error``: the actuator's kp (gainprm[0] and biasprm[1] together) times 0.5-0.7 or
  1.5-2.0.
* ``viscous_damping``: joint damping raised by 0.1-0.4 N m s/rad (bench; 0.05-0.2 finger).
* ``coulomb_friction``: joint frictionloss 0.05-0.15 N m (finger 0.03-0.08).
* ``inertia_error``: armature times 0.4-0.7 or 1.4-1.6 (+-30-60 %).
* ``mass_error``: the moving link masses times 0.4-0.7 or 1.3-1.6.
* ``torque_limit``: forcerange cut to 35-60 % of the peak force the nominal servo uses on the
  same goals.

Actuator kinds (``kind``; a user's MJCF is not always a plain ``position`` servo), each the
same servo physics written another way in MuJoCo, the log's goal being the ctrl it writes:

* ``position``: ``<position kp kv forcerange>`` (the default).
* ``dampratio``: ``<position kp dampratio>``: MuJoCo computes kv from the reflected inertia at
  compile time; models with hidden effects write the nominal model's compiled kv out (a real
  servo's D gain does not change with the load it carries).
* ``general``: ``<general gaintype="fixed" biastype="affine" gainprm="kp" biasprm="0 -kp -kv">``.
* ``gear``: a position actuator with ``gear`` = GEAR (2): ctrl and force in actuator units, kp
  and kv divided by GEAR^2, the force range by GEAR (the same joint stiffness and torque); the
  goals are GEAR times the joint angles and the torque limit is GEAR times the force limit.
* ``intvelocity``: ``<intvelocity kp kv actrange>``: the goal is a velocity [rad/s] that the
  actuator integrates into its setpoint (activation); the goals are the clipped velocities
  (at most VMAX) that bring the setpoint to the position excitation by the next row, the
  setpoint starting at the first position goal.
* ``timeconst``: ``<position kp kv timeconst>``: the servo follows its goal through a
  first-order filter of time constant TIMECONST (its activation), starting at the first goal.
* ``joint_set``: the position servo on joints that already carry a frictionloss (FRICTIONLOSS)
  besides their armature and damping (hidden Coulomb friction adds to it).

Logging, like a host polling a Dynamixel bus: rows at 100 Hz with +-30 % jitter; each row's
position is read at its time (linear interpolation between physics steps), noise std 0.3 mrad,
quantised to 4096 ticks/rev; the goal is written right after the read (takes effect at ``time``;
no ``goal_time`` column). Time is continuous: the physics steps land exactly on every read and on
every goal's arrival (steps of at most 2 ms), as on a real servo, not on the analyzer's grid. Excitation per joint: random steps (small and large) with holds, random
holds approached from both sides, chirps 0.2-3 Hz and slow triangle ramps.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

TICKS = 4096
NOISE = 3e-4  # [rad] read noise before quantisation
RATE = 100.0  # [Hz] log rate
JITTER = 0.3  # fraction of the period
TIMESTEP = 0.002  # [s]
FLOOR = math.sqrt(NOISE ** 2 + (2 * math.pi / TICKS) ** 2 / 12)  # [rad] reading noise floor

KINDS = ("position", "dampratio", "general", "gear", "intvelocity", "timeconst", "joint_set")
TIMECONST = 0.02  # [s] the ``timeconst`` kind's goal filter
GEAR = 2.0  # the ``gear`` kind's transmission ratio (actuator length = GEAR * joint angle)
DAMPRATIO = 1.0  # the ``dampratio`` kind's damping ratio
VMAX = 8.0  # [rad/s] the ``intvelocity`` kind's largest velocity goal
FRICTIONLOSS = 0.03  # [N m] the ``joint_set`` kind's nominal joint frictionloss

EFFECTS = ("latency", "backlash", "position_offset", "gain_error", "viscous_damping",
           "coulomb_friction", "inertia_error", "mass_error", "torque_limit")


# ------------------------------------------------------------------------------------------------
# rigs


@dataclass(frozen=True)
class Link:
    """One actuated joint and the link it moves (all in the parent's frame)."""

    joint: str
    axis: tuple[float, float, float]
    pos: tuple[float, float, float]  # body position in the parent [m]
    length: float  # link along -z [m]
    rod_mass: float  # [kg] uniform rod
    tip_mass: float  # [kg] point-like mass at the link's end (load, or the next servo)
    low: float  # excitation range [rad]
    high: float
    kp: float  # [N m / rad]
    kv: float  # [N m s / rad] the servo's velocity feedback (position actuator kv)
    force: float  # actuator force range +- [N m]
    armature: float  # [kg m^2]
    damping: float  # [N m s / rad]


RIGS: dict[str, tuple[Link, ...]] = {
    "bench": (
        Link("shoulder", (1, 0, 0), (0, 0, 0.4), 0.1, 0.05, 0.3, -1.3, 1.3, 8.0, 0.4, 5.0, 0.01,
             0.05),
    ),
    "finger": (
        Link("f_top", (0, 1, 0), (0, 0, 0.4), 0.068, 0.02, 0.085, -0.6, 0.6, 6.0, 0.25, 4.0, 0.005,
             0.05),
        Link("f_middle", (1, 0, 0), (0, 0, -0.068), 0.068, 0.02, 0.085, -1.0, 1.0, 6.0, 0.25, 4.0,
             0.005, 0.05),
        Link("f_bottom", (1, 0, 0), (0, 0, -0.068), 0.05, 0.015, 0.03, -1.0, 1.0, 6.0, 0.25, 4.0,
             0.005, 0.05),
    ),
}


@dataclass
class Hidden:
    """Hidden effects and their magnitudes: {effect: (n_joints,) values}."""

    values: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def names(self) -> set[str]:
        return set(self.values)


def build_xml(rig: str, hidden: Hidden | None = None, kind: str = "position",
              timestep: float = TIMESTEP) -> str:
    """MJCF of ``rig`` with the model-expressible hidden effects written in (None: nominal),
    its servos written as actuator ``kind`` (``KINDS``).

    Backlash adds a play hinge ``<joint>_play`` between the motor body and the link; the motor
    body then carries the armature, the link everything else.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown actuator kind {kind!r}; valid: {', '.join(KINDS)}")
    h = hidden.values if hidden is not None else {}
    if kind == "dampratio" and h:
        # the servo's D gain is the nominal model's, whatever the hidden effects
        nominal = mujoco.MjModel.from_xml_string(build_xml(rig, None, kind, timestep))
        kvs = [-float(nominal.actuator_biasprm[nominal.actuator(ln.joint).id, 2])
               for ln in RIGS[rig]]
    fl0 = FRICTIONLOSS if kind == "joint_set" else 0.0
    links = RIGS[rig]
    body_xml = ""
    for i, ln in reversed(list(enumerate(links))):
        kd = ln.damping + (h["viscous_damping"][i] if "viscous_damping" in h else 0.0)
        fl = fl0 + (h["coulomb_friction"][i] if "coulomb_friction" in h else 0.0)
        arm = ln.armature * (h["inertia_error"][i] if "inertia_error" in h else 1.0)
        ms = h["mass_error"][i] if "mass_error" in h else 1.0
        ax = " ".join(f"{a:g}" for a in ln.axis)
        geoms = (f'<geom type="capsule" fromto="0 0 0 0 0 {-ln.length:g}" size="0.006" '
                 f'mass="{ln.rod_mass * ms:.6g}"/>'
                 f'<geom type="sphere" pos="0 0 {-ln.length:g}" size="0.012" '
                 f'mass="{ln.tip_mass * ms:.6g}"/>')
        pos = " ".join(f"{p:g}" for p in ln.pos)
        joint = (f'<joint name="{ln.joint}" type="hinge" axis="{ax}" damping="{kd:.6g}" '
                 f'armature="{arm:.6g}" frictionloss="{fl:.6g}"/>')
        if "backlash" in h:
            half = 0.5 * h["backlash"][i]
            body_xml = (
                f'<body name="{ln.joint}_motor" pos="{pos}">{joint}'
                '<inertial pos="0 0 0" mass="0.001" diaginertia="1e-7 1e-7 1e-7"/>'
                f'<body name="{ln.joint}_link"><joint name="{ln.joint}_play" type="hinge" '
                f'axis="{ax}" range="{-half:.6g} {half:.6g}" limited="true" '
                'solreflimit="0.004 1" damping="0.0005"/>'
                f'{geoms}{body_xml}</body></body>')
        else:
            body_xml = f'<body name="{ln.joint}_link" pos="{pos}">{joint}{geoms}{body_xml}</body>'
    acts = ""
    for i, ln in enumerate(links):
        kp = ln.kp * (h["gain_error"][i] if "gain_error" in h else 1.0)
        f = h["torque_limit"][i] if "torque_limit" in h else ln.force
        lim = f'forcelimited="true" forcerange="{-f:.6g} {f:.6g}"'
        head = f'name="{ln.joint}" joint="{ln.joint}"'
        if kind in ("position", "joint_set"):
            acts += f'<position {head} kp="{kp:.6g}" kv="{ln.kv:g}" {lim}/>'
        elif kind == "timeconst":
            acts += (f'<position {head} kp="{kp:.6g}" kv="{ln.kv:g}" '
                     f'timeconst="{TIMECONST:g}" {lim}/>')
        elif kind == "dampratio":
            damp = f'kv="{kvs[i]:.9g}"' if h else f'dampratio="{DAMPRATIO:g}"'
            acts += f'<position {head} kp="{kp:.6g}" {damp} {lim}/>'
        elif kind == "general":
            acts += (f'<general {head} gaintype="fixed" biastype="affine" gainprm="{kp:.6g}" '
                     f'biasprm="0 {-kp:.6g} {-ln.kv:g}" {lim}/>')
        elif kind == "gear":
            fg = f / GEAR
            acts += (f'<position {head} gear="{GEAR:g}" kp="{kp / GEAR ** 2:.6g}" '
                     f'kv="{ln.kv / GEAR ** 2:.6g}" forcelimited="true" '
                     f'forcerange="{-fg:.6g} {fg:.6g}"/>')
        else:  # intvelocity
            acts += (f'<intvelocity {head} kp="{kp:.6g}" kv="{ln.kv:g}" '
                     f'actrange="{ln.low - 1:g} {ln.high + 1:g}" {lim}/>')
    return (f'<mujoco model="truth_{rig}"><compiler angle="radian"/>'
            f'<option timestep="{timestep}" '
            'integrator="implicitfast"/>'
            f"<worldbody>{body_xml}</worldbody><actuator>{acts}</actuator></mujoco>")


# ------------------------------------------------------------------------------------------------
# excitation


def excitation(rng: np.random.Generator, t: np.ndarray, low: float, high: float) -> np.ndarray:
    """Goals [rad] at the log times ``t``: steps, random holds, chirps and ramps in [low, high]."""
    c, span = 0.5 * (low + high), 0.5 * (high - low)
    out = np.empty(len(t))
    pos = c + rng.uniform(-0.3, 0.3) * span
    i = 0
    while i < len(t):
        kind = rng.choice(["steps", "holds", "chirp", "ramp"], p=[0.35, 0.2, 0.3, 0.15])
        t0 = t[i]
        if kind == "steps":
            for _ in range(int(rng.integers(2, 5))):
                size = span * (rng.uniform(0.05, 0.15) if rng.random() < 0.4
                               else rng.uniform(0.3, 0.9))
                pos = float(np.clip(pos + size * rng.choice([-1, 1]), low, high))
                j = int(np.searchsorted(t, t[min(i, len(t) - 1)] + rng.uniform(0.3, 0.7)))
                out[i:j] = pos
                i = j
        elif kind == "holds":
            target = c + rng.uniform(-0.7, 0.7) * span
            for side in (-1, 1) if rng.random() < 0.5 else (1, -1):
                for v in (target + side * span * rng.uniform(0.15, 0.4), target):
                    j = int(np.searchsorted(t, t[min(i, len(t) - 1)] + rng.uniform(0.25, 0.5)))
                    out[i:j] = np.clip(v, low, high)
                    i = j
            pos = float(np.clip(target, low, high))
        elif kind == "chirp":
            dur = rng.uniform(1.5, 2.5)
            j = int(np.searchsorted(t, t0 + dur))
            tau = t[i:j] - t0
            f0, f1 = rng.uniform(0.2, 0.6), rng.uniform(1.5, 3.0)
            amp = span * rng.uniform(0.2, 0.5)
            mid = float(np.clip(pos, low + amp, high - amp))
            phase = 2 * math.pi * (f0 * tau + 0.5 * (f1 - f0) / dur * tau * tau)
            out[i:j] = mid + amp * np.sin(phase)
            i = j
            pos = float(out[i - 1]) if i > 0 else pos
        else:
            dur = rng.uniform(1.0, 2.0)
            j = int(np.searchsorted(t, t0 + dur))
            tau = t[i:j] - t0
            speed = rng.uniform(0.2, 0.6)  # [rad/s]
            amp = span * rng.uniform(0.1, 0.3)
            tri = amp * (2 / math.pi) * np.arcsin(np.sin(speed * tau / amp * math.pi / 2))
            out[i:j] = np.clip(pos + tri, low, high)
            i = j
            pos = float(out[i - 1]) if i > 0 else pos
    return out


# ------------------------------------------------------------------------------------------------
# simulation and logging


@dataclass
class Log:
    """One logged trajectory in the project's column layout."""

    time: np.ndarray  # (T,)
    goal: np.ndarray  # (T, n)
    qpos: np.ndarray  # (T, n) readings
    joints: tuple[str, ...]

    def write_csv(self, path: str | Path) -> Path:
        """Write the project's CSV log format: time, goal:<actuator>, qpos:<joint>."""
        path = Path(path)
        names = ["time"] + [f"goal:{j}" for j in self.joints] + [f"qpos:{j}" for j in self.joints]
        data = np.column_stack([self.time, self.goal, self.qpos])
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(names)
            for row in data:
                w.writerow([repr(float(x)) for x in row])
        return path


def log_times(rng: np.random.Generator, duration: float) -> np.ndarray:
    """Jittered read instants at ``RATE`` over ``duration`` s, strictly increasing."""
    n = int(duration * RATE)
    t = (np.arange(n) + rng.uniform(-JITTER, JITTER, n)) / RATE
    t[0] = max(t[0], 0.0)
    return np.maximum.accumulate(t + np.arange(n) * 1e-9)


def commands(kind: str, times: np.ndarray, goals: np.ndarray) -> np.ndarray:
    """The ctrl a host writes to servos of actuator ``kind`` for joint-angle goals.

    Args:
      times: (T,) write instants [s].
      goals: (T, n) joint-angle goals [rad].
    Returns:
      (T, n): the goals for position servos, GEAR times them for ``gear``, for ``intvelocity``
      the velocity [rad/s] (within +-VMAX) that moves the integrated setpoint from where it is
      to the next row's goal by the next row (0 on the last row; the setpoint starts at the
      first goal).
    """
    if kind == "gear":
        return GEAR * goals
    if kind != "intvelocity":
        return goals.copy()
    out = np.zeros_like(goals)
    setpoint = goals[0].astype(float).copy()
    dt = np.diff(times)
    for k in range(len(times) - 1):
        out[k] = np.clip((goals[k + 1] - setpoint) / dt[k], -VMAX, VMAX)
        setpoint = setpoint + out[k] * dt[k]
    return out


def simulate(rig: str, hidden: Hidden, times: np.ndarray, goals: np.ndarray,
             rng: np.random.Generator, kind: str = "position",
             truth_step: float = TIMESTEP) -> Log:
    """Run the truth model on goals written at ``times`` and log the readings.

    Args:
      rig: "bench" or "finger".
      hidden: hidden effects.
      times: (T,) read/write instants [s].
      goals: (T, n) joint-angle goal written right after the read at each instant [rad]; the
        servos of ``kind`` get (and the log holds) ``commands(kind, times, goals)``.
      rng: noise generator.
      kind: actuator kind (``KINDS``).
      truth_step: the truth's largest physics step [s] (TIMESTEP, the nominal model's; smaller:
        closer to continuous time, as a real robot is).
    """
    links = RIGS[rig]
    h = hidden.values
    model = mujoco.MjModel.from_xml_string(build_xml(rig, hidden, kind, truth_step))
    ctrl = commands(kind, times, goals)
    data = mujoco.MjData(model)
    n = len(links)
    motor_q = np.array([model.jnt_qposadr[model.joint(ln.joint).id] for ln in links])
    play_q = (np.array([model.jnt_qposadr[model.joint(ln.joint + "_play").id] for ln in links])
              if "backlash" in h else None)
    act = np.array([model.actuator(ln.joint).id for ln in links])
    delay = h["latency"] if "latency" in h else np.zeros(n)
    offset = h["position_offset"] if "position_offset" in h else np.zeros(n)

    def angles() -> np.ndarray:
        q = data.qpos[motor_q].copy()
        if play_q is not None:
            q += data.qpos[play_q]
        return q

    # start at rest at the first goal, servos holding it (an integrating servo's setpoint is
    # its activation, its velocity goal 0 while it settles)
    data.qpos[motor_q] = goals[0]
    if kind == "intvelocity":
        data.act[model.actuator_actadr[act]] = goals[0]
        data.ctrl[act] = 0.0
    elif kind == "timeconst":
        data.act[model.actuator_actadr[act]] = goals[0]
        data.ctrl[act] = ctrl[0]
    else:
        data.ctrl[act] = ctrl[0]
    mujoco.mj_forward(model, data)
    # settle under gravity (the play hangs where the load pushes it)
    for _ in range(int(0.5 / truth_step)):
        mujoco.mj_step(model, data)
    data.time = 0.0
    # Continuous time: physics advances in steps of at most TIMESTEP that land exactly on every
    # event (a goal reaching a servo at write time + its latency, a read), so goals act from
    # their instant, not from a grid step.
    arrive = times[:, None] + delay[None, :]
    events = np.unique(np.concatenate([times, arrive.ravel()]))
    nxt = np.zeros(n, dtype=int)  # next goal row per servo
    reads = np.empty((len(times), n))
    k_read = 0
    for t_ev in events:
        while data.time < t_ev - 1e-9:
            model.opt.timestep = min(truth_step, t_ev - data.time)
            mujoco.mj_step(model, data)
        data.time = t_ev
        while k_read < len(times) and times[k_read] <= t_ev + 1e-12:
            reads[k_read] = angles()  # read, then write (the goal arriving now acts next)
            k_read += 1
        for j in range(n):
            while nxt[j] < len(times) and arrive[nxt[j], j] <= t_ev + 1e-12:
                data.ctrl[act[j]] = ctrl[nxt[j], j]
                nxt[j] += 1
    reads = reads + offset[None, :] + rng.normal(size=reads.shape) * NOISE
    step = 2 * math.pi / TICKS
    reads = np.round(reads / step) * step
    return Log(times.copy(), ctrl, reads, tuple(ln.joint for ln in links))


def peak_force(rig: str, times: np.ndarray, goals: np.ndarray) -> np.ndarray:
    """Peak |actuator force| per joint of the nominal rig (position servos) on these goals
    [N m]."""
    links = RIGS[rig]
    model = mujoco.MjModel.from_xml_string(build_xml(rig))
    data = mujoco.MjData(model)
    q = np.array([model.jnt_qposadr[model.joint(ln.joint).id] for ln in links])
    data.qpos[q] = goals[0]
    data.ctrl[:] = goals[0]
    mujoco.mj_forward(model, data)
    peak = np.zeros(len(links))
    k = 0
    steps = int(times[-1] / TIMESTEP) + 1
    for s in range(steps):
        while k < len(times) and times[k] <= s * TIMESTEP:
            data.ctrl[:] = goals[k]
            k += 1
        mujoco.mj_step(model, data)
        peak = np.maximum(peak, np.abs(data.actuator_force))
    return peak


# ------------------------------------------------------------------------------------------------
# hidden magnitudes


def _two_sided(rng: np.random.Generator, n: int, low: tuple[float, float],
               high: tuple[float, float]) -> np.ndarray:
    """A factor below 1 (from ``low``) or above (from ``high``), one side for all joints."""
    lo, hi = low if rng.random() < 0.5 else high
    return rng.uniform(lo, hi, n)


def draw(rig: str, names: list[str], rng: np.random.Generator, peak: np.ndarray | None = None
         ) -> Hidden:
    """Draw realistic magnitudes per joint for the named effects."""
    n = len(RIGS[rig])
    finger = rig == "finger"
    vals: dict[str, np.ndarray] = {}
    for name in names:
        if name == "latency":
            v = np.full(n, rng.uniform(0.02, 0.06))  # one bus: one latency
        elif name == "backlash":
            v = rng.uniform(0.02, 0.06, n)
        elif name == "position_offset":
            v = rng.uniform(0.03, 0.08, n) * rng.choice([-1, 1], n)
        elif name == "gain_error":
            v = _two_sided(rng, n, (0.5, 0.7), (1.5, 2.0))
        elif name == "viscous_damping":
            v = rng.uniform(0.05, 0.2, n) if finger else rng.uniform(0.1, 0.4, n)
        elif name == "coulomb_friction":
            v = rng.uniform(0.03, 0.08, n) if finger else rng.uniform(0.05, 0.15, n)
        elif name == "inertia_error":
            v = _two_sided(rng, n, (0.4, 0.7), (1.4, 1.6))
        elif name == "mass_error":
            v = _two_sided(rng, n, (0.4, 0.7), (1.3, 1.6))
        elif name == "torque_limit":
            if peak is None:
                raise ValueError("torque_limit needs the nominal peak force")
            v = rng.uniform(0.35, 0.6, n) * peak
        else:
            raise ValueError(f"unknown effect {name!r}; valid: {', '.join(EFFECTS)}")
        vals[name] = np.asarray(v, float)
    return Hidden(vals)


@dataclass
class Case:
    """A generated data set: nominal MJCF, the truth, CSV logs."""

    rig: str
    hidden: Hidden
    nominal_xml: str
    logs: list[Log]
    kind: str = "position"

    def write(self, folder: str | Path) -> tuple[Path, list[Path]]:
        """Write ``model.xml`` (nominal) and ``logNN.csv``; returns (model path, log paths)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        model = folder / "model.xml"
        model.write_text(self.nominal_xml)
        paths = [lg.write_csv(folder / f"log{i:02d}.csv") for i, lg in enumerate(self.logs)]
        return model, paths


def make_case(rig: str, names: list[str], seed: int, n_logs: int = 3,
              duration: float = 6.0, values: dict[str, float] | None = None,
              kind: str = "position", truth_step: float = TIMESTEP) -> Case:
    """Logs of ``rig`` with the named effects hidden at random realistic magnitudes, or at the
    given ``values`` ({effect: magnitude on every joint}; the same excitation and noise as the
    drawn case of this seed), its servos written as actuator ``kind`` (the same joint-angle
    excitation, drawn magnitudes and noise for every kind), the truth simulated with physics
    steps of at most ``truth_step`` (the nominal model keeps TIMESTEP)."""
    if rig not in RIGS:
        raise ValueError(f"unknown rig {rig!r}; valid: {', '.join(RIGS)}")
    rng = np.random.default_rng(seed)
    links = RIGS[rig]
    plans = []
    for _ in range(n_logs):
        t = log_times(rng, duration)
        g = np.column_stack([excitation(rng, t, ln.low, ln.high) for ln in links])
        plans.append((t, g))
    peak = None
    if "torque_limit" in names:
        peak = np.max([peak_force(rig, t, g) for t, g in plans], axis=0)
    hidden = draw(rig, list(names), rng, peak)
    if values is not None:
        n = len(links)
        hidden = Hidden({k: np.full(n, float(v)) for k, v in values.items()})
    logs = [simulate(rig, hidden, t, g, rng, kind, truth_step) for t, g in plans]
    return Case(rig, hidden, build_xml(rig, None, kind), logs, kind)


# ------------------------------------------------------------------------------------------------
# the case list of tests/test_gap_independent.py and bench/gap_independent.py

# (case id, rig, hidden effects, seed, seconds per log); three logs per case
CASES: tuple[tuple[str, str, tuple[str, ...], int, float], ...] = (
    ("bench-latency", "bench", ("latency",), 101, 5.0),
    ("bench-backlash", "bench", ("backlash",), 102, 5.0),
    ("bench-position_offset", "bench", ("position_offset",), 103, 5.0),
    ("bench-gain_error", "bench", ("gain_error",), 104, 5.0),
    ("bench-viscous_damping", "bench", ("viscous_damping",), 105, 5.0),
    ("bench-coulomb_friction", "bench", ("coulomb_friction",), 106, 5.0),
    ("bench-inertia_error", "bench", ("inertia_error",), 107, 5.0),
    ("bench-mass_error", "bench", ("mass_error",), 108, 5.0),
    ("bench-torque_limit", "bench", ("torque_limit",), 109, 5.0),
    ("finger-latency", "finger", ("latency",), 201, 4.0),
    ("finger-backlash", "finger", ("backlash",), 202, 4.0),
    ("finger-gain_error", "finger", ("gain_error",), 203, 4.0),
    ("bench-offset+gain", "bench", ("position_offset", "gain_error"), 301, 5.0),
    ("finger-latency+damping", "finger", ("latency", "viscous_damping"), 302, 4.0),
    ("bench-clean", "bench", (), 401, 5.0),
    ("finger-clean", "finger", (), 402, 4.0),
)

# Sizes written out, beyond the drawn ranges above (issue 11's real-world magnitudes) and beyond
# the analyzer's usual search ranges (latency 0.1 s, offsets +-0.2 rad, gain 0.2-4x): (case id,
# rig, {effect: magnitude}, seed, seconds per log). The last three exercise the range widening.
WIDE_CASES: tuple[tuple[str, str, dict[str, float], int, float], ...] = (
    ("bench-latency-80ms", "bench", {"latency": 0.08}, 501, 5.0),
    ("bench-offset-0.15rad", "bench", {"position_offset": 0.15}, 502, 5.0),
    ("bench-gain-2.5x", "bench", {"gain_error": 2.5}, 503, 5.0),
    # a horn mounted one spline tooth off (25-tooth spline: 2 pi / 25 = 0.251 rad)
    ("bench-offset-1tooth", "bench", {"position_offset": -2 * math.pi / 25}, 504, 5.0),
    # a P gain set to 5x the model's (e.g. firmware P 640 where the model assumed 128)
    ("bench-gain-5x", "bench", {"gain_error": 5.0}, 505, 5.0),
    # a slow host loop: 130 ms from the goal's write to the servo
    ("bench-latency-130ms", "bench", {"latency": 0.13}, 506, 5.0),
)

# Confusable families (04-sysid.md 4.2): effects whose residual signatures overlap on this kind
# of excitation. A named set matches "up to family" when every hidden effect has a named cause
# in its family and every named cause belongs to the family of a hidden effect.
_GROUPS = (
    {"latency", "gain_error", "torque_limit", "velocity_limit"},  # late response
    {"coulomb_friction", "backlash", "stribeck_friction", "load_dependent_friction"},  # dry/play
    {"viscous_damping", "velocity_limit", "load_dependent_friction"},  # velocity-proportional
    {"inertia_error", "mass_error"},  # inertia
    {"position_offset", "mass_error", "gain_error"},  # static error (offset, gravity sag)
)


def family(name: str) -> set[str]:
    """Effects confusable with ``name`` (itself included)."""
    out = {name}
    for g in _GROUPS:
        if name in g:
            out |= g
    return out


def grade(hidden: set[str], named: set[str]) -> str:
    """"exact", "family" (up to confusable families), "miss"; for clean data "clean" or
    "false" (something was named)."""
    if not hidden:
        return "clean" if not named else "false"
    if named == hidden:
        return "exact"
    covered = all(named & family(h) for h in hidden)
    explained = all(any(n in family(h) for h in hidden) for n in named)
    return "family" if named and covered and explained else "miss"
