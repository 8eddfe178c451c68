"""Hidden-effect data: "measured" logs from a nominal model plus effects the analyzer is not told.

The generator drives a ``Plant`` (nominal model + hidden effects) with a rich excitation (steps of
many sizes, holds approached from both sides, slow ramps with reversals, chirps), and logs what a
Dynamixel driver would: goals written at a jittered rate, positions read just before each write,
quantized to 4096 ticks/rev with read noise, velocities in 0.229 rpm units, current, and the supply
voltage and winding temperature channels (which drift, so thermal and voltage effects are
identifiable and must not be "found" when absent). Timestamps carry host-clock noise.

Everything is drawn from the ``np.random.Generator`` passed in.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice, check_number
from lowcostdex.gap.logs import Trajectory
from lowcostdex.sim import servo
from lowcostdex.sim.effects import CAUSES, AppliedEffect, effect
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig, build_bench
from lowcostdex.sim.plant import Plant, prepare_spec

TICKS = 4096

# Hidden magnitudes: plausible for a D'Claw-class X430 servo (04-sysid.md section 6), drawn away
# from the null so the effect is visible above the encoder floor. (low, high) intervals; a
# second interval is mirrored around the null for two-sided effects.
HIDDEN: dict[str, dict[str, tuple[float, float]]] = {
    "latency": {"delay": (0.006, 0.03)},
    "backlash": {"width": (0.006, 0.017)},
    "coulomb_friction": {"frictionloss": (0.04, 0.1)},
    "stribeck_friction": {"static": (0.06, 0.12), "velocity": (0.1, 0.3)},
    "load_dependent_friction": {"mu": (0.12, 0.25)},
    "viscous_damping": {"damping": (0.1, 0.4)},
    "gain_error": {"scale": (1.25, 1.6)},
    "torque_limit": {"torque": (0.2, 0.45)},  # x the nominal stall torque
    "velocity_limit": {"scale": (1.25, 1.6)},
    "position_offset": {"offset": (0.006, 0.04)},
    "inertia_error": {"scale": (2.0, 4.0)},
    "mass_error": {"scale": (1.25, 1.6)},
    "thermal_derating": {"tempcoef": (0.006, 0.012)},
    "voltage_sag": {"weight": (0.7, 1.0)},
}
# Effects whose magnitude may lie on either side of the null (scale s -> 1/s, offset -> -offset).
# velocity_limit is one-sided: a slower no-load speed (scale < 1) only adds back-EMF damping,
# which is exactly viscous_damping for a dcmotor servo (the pair is not identifiable), so the
# generator hides the faster-than-modelled case, which damping cannot mimic.
TWO_SIDED = {"gain_error", "position_offset", "inertia_error", "mass_error"}


@dataclass(frozen=True)
class LogSettings:
    """How the synthetic driver logs.

    Attributes:
      rate: nominal read/write rate [Hz].
      jitter: uniform jitter of each read instant, fraction of the period.
      stamp_noise: host-clock timestamp noise (std) [s].
      noise: encoder read noise (std) before quantization [rad].
      ticks: encoder ticks per revolution (0: no quantization).
      velocity_unit: velocity register unit [rad/s] (0.229 rpm).
    """

    rate: float = 100.0
    jitter: float = 0.3
    stamp_noise: float = 1e-4
    noise: float = 3e-4
    ticks: int = TICKS
    velocity_unit: float = servo.TWO_PI * 0.229 / 60.0

    @property
    def floor(self) -> float:
        """Expected RMS of (reading - true position) [rad]: read noise plus quantization."""
        q = 2 * math.pi / self.ticks if self.ticks else 0.0
        return math.sqrt(self.noise**2 + q * q / 12.0)


def bench_config(motor: str = "XM430-W350") -> BenchConfig:
    """The synthetic-test bench: an X430 servo swinging 0.3 kg at 0.1 m (D'Claw-class loads)."""
    return BenchConfig(motor=motor, mass=0.3, length=0.1, arm_mass=0.05, damping=0.02)


def finger_spec(motor: str = "XM430-W350") -> mujoco.MjSpec:
    """One D'Claw finger (ff_top, ff_middle, ff_bottom) without a station."""
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.sim.models.dclaw import build_dclaw

    return build_dclaw("none", hand=dclaw_spec(motor), thermal=False, fingers=("ff",))


def draw_hidden(name: str, joints: Sequence[str], rng: np.random.Generator,
                model: mujoco.MjModel | None = None, level: float | None = None
                ) -> AppliedEffect:
    """Draw a hidden effect with a plausible, visible magnitude per joint.

    Args:
      name: canonical effect name.
      joints: joints it acts on.
      rng: generator.
      model: the nominal model (torque limits are drawn relative to its stall torque).
      level: None: uniform in the range; else the magnitude at this fraction of the range
        (0 smallest, 1 largest), +-5 % per joint.
    """
    check_choice("hidden effect", name, HIDDEN)
    n = len(joints)
    vals = {}
    flip = rng.random() < 0.5 if name in TWO_SIDED else False
    for p, (lo, hi) in HIDDEN[name].items():
        if level is None:
            v = rng.uniform(lo, hi, size=n)
        else:
            v = (lo + level * (hi - lo)) * rng.uniform(0.95, 1.05, size=n)
        if name == "torque_limit":
            if model is None:
                raise ConfigError("torque_limit needs the model (stall torque)")
            v = v * _stall_torque(model, joints)
        if flip:
            v = -v if name == "position_offset" else 1.0 / v
        vals[p] = v
    return AppliedEffect(name, tuple(joints), vals)


def _stall_torque(model: mujoco.MjModel, joints: Sequence[str]) -> np.ndarray:
    from lowcostdex.sim.effects import Targets

    st = servo.stall_torque(model, Targets.resolve(model, tuple(joints)).actuators)
    if not np.all(np.isfinite(st)):  # a position actuator's was K Vmax / R of its gains: 0
        bad = [j for j, s in zip(joints, st, strict=True) if not np.isfinite(s)]
        raise ConfigError(f"torque_limit is drawn as a share of the servo's stall torque; the "
                          f"actuators of {bad} have none (not a dcmotor, or one without a drive "
                          "limit and force range)")
    return st


def excitation(rng: np.random.Generator, duration: float, dt: float, low: np.ndarray,
               high: np.ndarray) -> np.ndarray:
    """Goal positions on a grid of step ``dt`` for ``duration`` s, one column per joint.

    A random sequence of pieces per joint: small and large steps with holds (approached from
    both sides), slow triangular ramps (reversals at low speed), and chirps.

    Returns:
      (K, n) goals [rad] within [low, high].
    """
    n = len(low)
    k_total = int(round(duration / dt))
    out = np.zeros((k_total, n))
    for j in range(n):
        c, span = 0.5 * (low[j] + high[j]), 0.5 * (high[j] - low[j])
        seq: list[np.ndarray] = []
        pos = c + rng.uniform(-0.3, 0.3) * span
        while sum(len(s) for s in seq) < k_total:
            kind = rng.choice(["steps", "ramp", "chirp"], p=[0.5, 0.25, 0.25])
            if kind == "steps":
                for _ in range(int(rng.integers(3, 7))):
                    size = span * (rng.uniform(0.02, 0.12) if rng.random() < 0.5
                                   else rng.uniform(0.3, 1.0))
                    pos = np.clip(pos + size * rng.choice([-1, 1]), c - span, c + span)
                    seq.append(np.full(int(rng.uniform(0.25, 0.6) / dt), pos))
            elif kind == "ramp":
                speed = rng.uniform(0.05, 0.4)  # [rad/s]
                amp = span * rng.uniform(0.1, 0.4)
                a0 = pos
                t = np.arange(int(rng.uniform(1.5, 3.0) / dt)) * dt
                tri = amp * (2 / math.pi) * np.arcsin(np.sin(speed * t / amp * math.pi / 2))
                piece = np.clip(a0 + tri, c - span, c + span)
                seq.append(piece)
                pos = piece[-1]
            else:
                t = np.arange(int(rng.uniform(1.5, 3.0) / dt)) * dt
                f0, f1 = rng.uniform(0.2, 0.8), rng.uniform(1.5, 4.0)
                phase = 2 * math.pi * (f0 * t + 0.5 * (f1 - f0) / t[-1] * t * t)
                amp = span * rng.uniform(0.2, 0.6)
                piece = np.clip(pos + amp * np.sin(phase), c - span, c + span)
                seq.append(piece)
                pos = piece[-1]
        out[:, j] = np.concatenate(seq)[:k_total]
    return out


def _channels(rng: np.random.Generator, t: np.ndarray, n: int, vnom: np.ndarray
              ) -> dict[str, np.ndarray]:
    """Drifting temperature and sagging supply per actuator, as a driver would read them."""
    # each log at its own temperature (logs recorded at different points of a long session),
    # drifting up a few kelvin within the log
    level = rng.uniform(30.0, 65.0)
    temp = level + rng.uniform(-2.0, 2.0, size=n) + rng.uniform(2.0, 6.0) * t[:, None] / t[-1]
    # Sag: a smooth random load on the shared supply (other servos moving), 0..18 %.
    knots = np.arange(0.0, t[-1] + 1.0, 0.5)
    u = np.clip(np.interp(t, knots, rng.uniform(0, 1, size=len(knots))), 0, 1)
    volt = vnom[None, :] * (1.0 - 0.18 * u[:, None])
    return {"temperature": np.round(temp), "voltage": np.round(volt * 10) / 10}


def simulate_log(spec: mujoco.MjSpec, hidden: Sequence[AppliedEffect], goals: np.ndarray,
                 actuators: Sequence[str], joints: Sequence[str], rng: np.random.Generator,
                 settings: LogSettings = LogSettings(), t_start: float = 0.0,
                 name: str = "synthetic") -> Trajectory:
    """Run the hidden model on goal sequence ``goals`` and log it like a Dynamixel driver.

    Args:
      spec: nominal model (copied; hidden effects get their structural room).
      hidden: the hidden effects.
      goals: (K, na) goals on the physics grid [rad] (the driver samples them at its rate).
      actuators / joints: names of the commanded actuators (all of the model's) and measured
        joints.
      rng: generator (timing jitter, noise, channels).
      settings: driver timing and sensor resolution.
      t_start: session time at the start [s] (the logs' timestamps start there).
    """
    spec = spec.copy()
    prepare_spec(spec, hidden, hidden_dofs=True)  # the physics the analysis replays
    model = spec.compile()
    plant = Plant(model, hidden, rng=np.random.default_rng(rng.integers(2**63)))
    dt = model.opt.timestep
    act = np.array([model.actuator(a).id for a in actuators])
    jq = np.array([model.jnt_qposadr[model.joint(j).id] for j in joints])
    jd = np.array([model.jnt_dofadr[model.joint(j).id] for j in joints])
    k_total = len(goals)
    period = 1.0 / settings.rate
    n_rows = int((k_total * dt) / period) - 1
    instants = np.arange(n_rows) * period + rng.uniform(-settings.jitter, settings.jitter,
                                                        n_rows) * period
    steps = np.unique(np.clip(np.round(instants / dt).astype(int), 0, k_total - 1))
    times = steps * dt
    chans = _channels(rng, times, len(actuators),
                      model.actuator_user[act, servo.USER_SUPPLY_VOLTAGE])
    q0 = model.qpos0.copy()
    q0[jq] = goals[0]
    ctrl0 = np.zeros(model.nu)
    ctrl0[act] = goals[0]
    plant.reset(q0, np.zeros(model.nv), ctrl0)
    rows = {"q": [], "v": [], "i": []}
    full_goal = ctrl0.copy()
    held = np.zeros((len(steps), len(actuators)))
    exo = plant.required_channels
    ch_now = {c: _full(model.nu, act, chans[c][0]) for c in exo}
    nxt = 0
    for k in range(steps[-1] + 1):
        if nxt < len(steps) and k == steps[nxt]:
            q_read = plant.measured_qpos()[jq]
            rows["q"].append(q_read)
            rows["v"].append(plant.qvel[jd].copy())
            rows["i"].append(servo.motor_current(plant.model, plant.data)[act])
            held[nxt] = goals[k]
            full_goal[act] = goals[k]
            ch_now = {c: _full(model.nu, act, chans[c][nxt]) for c in exo}
            nxt += 1
        plant.step(full_goal, 1, ch_now if exo else None)
    q = np.array(rows["q"])
    q = q + rng.normal(size=q.shape) * settings.noise
    if settings.ticks:
        step = 2 * math.pi / settings.ticks
        q = np.round(q / step) * step
    v = np.array(rows["v"])
    v = np.round((v + rng.normal(size=v.shape) * 0.5 * settings.velocity_unit)
                 / settings.velocity_unit) * settings.velocity_unit
    cur = np.round(np.array(rows["i"]) / 2.69e-3) * 2.69e-3
    stamps = times + t_start + rng.normal(size=times.shape) * settings.stamp_noise
    stamps = np.maximum.accumulate(stamps + np.arange(len(stamps)) * 1e-9)
    channels = {"current": cur, **chans}
    return Trajectory(name=name, time=stamps, goal=held, qpos=q, actuators=tuple(actuators),
                      joints=tuple(joints), qvel=v, channels=channels)


def _full(nu: int, act: np.ndarray, values: np.ndarray) -> np.ndarray:
    out = np.zeros(nu)
    out[act] = values
    return out


@dataclass
class Synthetic:
    """A generated data set: nominal model, logs, and the truth the analyzer must find."""

    spec: mujoco.MjSpec
    trajectories: list[Trajectory]
    hidden: list[AppliedEffect]
    settings: LogSettings

    @property
    def xml(self) -> str:
        return self.spec.to_xml()


def generate(rig: str, hidden: Sequence[str] | None, rng: np.random.Generator, *,
             n_logs: int = 4, duration: float = 8.0, settings: LogSettings = LogSettings(),
             motor: str = "XM430-W350", level: float | None = None) -> Synthetic:
    """Generate logs of a rig with hidden effects.

    Args:
      rig: "bench" (one servo with a 0.3 kg load) or "finger" (one D'Claw finger).
      hidden: canonical effect names to hide (None or empty: effect-free data); an effect drawn
        at random when the list holds "random"; one name as a string is that effect.
      rng: generator for everything (the effect, its magnitude, excitation, noise).
      n_logs: number of logs (trajectories), >= 1.
      duration: seconds per log, in [1, 3600].
      settings: driver timing and sensor resolution.
      motor: servo model.
      level: magnitude as a fraction of the plausible range, in [0, 1] (None: random).
    """
    check_choice("rig", rig, ("bench", "finger"))
    if not isinstance(rng, np.random.Generator):
        raise ConfigError(f"rng={rng!r} must be a numpy Generator, e.g. "
                          "numpy.random.default_rng(0)")
    check_number("n_logs", n_logs, 1, integer=True)
    check_number("duration", duration, 1.0, 3600.0)  # [s]: gap generate --duration's bounds
    check_number("level", level, 0.0, 1.0, none_ok=True)
    if isinstance(hidden, str):  # one effect typed as a string, not its letters
        hidden = [hidden]
    if rig == "bench":
        spec = build_bench(bench_config(motor))
        joints = (BENCH_JOINT,)
        low, high = np.array([-1.3]), np.array([1.3])
    else:
        from lowcostdex.hands import dclaw_spec

        spec = finger_spec(motor)
        hand = dclaw_spec(motor)
        joints = hand.joint_names[:3]
        low = np.array([hand.joint(j).low for j in joints])
        high = np.array([hand.joint(j).high for j in joints])
    model = spec.compile()
    names = list(hidden or [])
    twice = sorted({n for n in names if n != "random" and names.count(n) > 1})
    if twice:  # before: both drawn and compounded, truth.json listing the effect twice
        raise ConfigError(f"hidden effect {twice[0]!r} given twice; each effect is hidden once "
                          "(on every joint of the rig)")
    names = [str(rng.choice(list(HIDDEN))) if n == "random" else n for n in names]
    for n in names:
        check_choice("hidden effect", n, CAUSES)
    effects = [draw_hidden(n, joints, rng, model, level) for n in names]
    trajs = []
    dt = model.opt.timestep
    for i in range(n_logs):
        goals = excitation(rng, duration, dt, low, high)
        trajs.append(simulate_log(spec, effects, goals, joints, joints, rng, settings,
                                  t_start=i * (duration + 2.0), name=f"log{i:02d}"))
    return Synthetic(spec, trajs, effects, settings)


def effect_names() -> tuple[str, ...]:
    """Effects the generator can hide (every canonical cause)."""
    for n in HIDDEN:
        effect(n)
    return tuple(HIDDEN)
