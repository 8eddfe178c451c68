"""An eighth independent truth simulator for the gap analysis: a Dynamixel's motion profile on
the goal (Profile Velocity / Profile Acceleration; issue 11, gap-profile16, session 21).

Written with mujoco, numpy and the stdlib only, importing nothing from lowcostdex (no effect,
plant, servo or gap code). The user's side is what docs/gap_analysis.md says (the CSV log format:
``time``, ``goal:<actuator>``, ``qpos:<joint>``); the profile is written from the Dynamixel
e-manual's description of the velocity-based profile (Drive Mode bit 2 clear): the firmware moves
its own setpoint toward the goal position written last, at most at Profile Velocity, changing
speed at most at Profile Acceleration, and brakes so as to stop on the goal (a trapezoid, a
triangle on a short move, a rectangle with acceleration 0, no profile with velocity 0); the
position loop acts on that setpoint. The log holds the goal the user wrote (the raw goal).

Rig: a servo bench, one hinge (``arm``, axis y: gravity loads it, most at 0 where the arm is
horizontal) carrying an arm of 0.1 kg at 80 mm (a ``load`` case: 0.35 kg at 100 mm, in the
user's model too), a reflected rotor inertia of 3 g m^2 and gear damping 0.02 N m s/rad. The
user's model: ``<position kp="4" kv="0.08" forcerange="-1.4 1.4">`` (an XL430-class servo:
1.4 N m stall) at 2 ms. The truth drives a ``motor`` actuator with the servo's law computed
every 0.25 ms physics step: tau = clip(kp (p - q) - kv qdot, +-1.4) on the profile's setpoint p.

Logs: 100 Hz rows (+-1 step of jitter on the 0.25 ms grid), the reading quantised to 4096
ticks per turn after 0.4 mrad of read noise, the goal written (in ticks) right after the read
and acting from the row; each log starts after 1 s held at its first goal. Excitation: goal
steps of 0.15-1.4 rad held 0.8-1.6 s (long enough for the profile to arrive), and holds
approached from both sides by ramps slower than the profile.

Cases (``CASES``): the profile velocity alone (1.5 and 2.5 rad/s), velocity and acceleration
(3 rad/s, 12 rad/s^2), the profile on the loaded arm (steps the user's model runs saturated, the
truth ramps below the force limit: a torque limit cannot replay it), a clean case, and a torque
limit with no profile (the confusable saturation: must not be named a profile).
``tests/redteam_check.grade`` grades a report.json with this module's ``FAMILIES`` (exact /
family / miss / clean / false).
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
READ_NOISE = 0.0004            # rad, read noise before quantisation
SETTLE = 1.0                   # s held at the first goal before the first row
RATE = 100.0                   # Hz, log rows
KP, KV, TAU_MAX = 4.0, 0.08, 1.4          # servo law: N m/rad, N m s/rad, N m
ARMATURE, DAMPING = 0.003, 0.02           # kg m^2, N m s/rad
ARMS = {"light": (0.1, 0.08), "load": (0.35, 0.10)}   # arm mass [kg], centre of mass [m]
RANGE = (-1.0, 1.0)            # rad, goals

FAMILIES = ({"goal_profile", "velocity_limit", "latency", "torque_limit"},)


@dataclasses.dataclass(frozen=True)
class Case:
    """One analysis case: the profile ``velocity`` [rad/s] and ``acceleration`` [rad/s^2] (0:
    off, as on the servo), the ``arm``, a hidden ``torque`` limit [N m] (0: none), logs of
    ``durations`` s, ``seed``."""

    name: str
    velocity: float = 0.0
    acceleration: float = 0.0
    arm: str = "light"
    torque: float = 0.0
    durations: tuple[float, ...] = (8.0, 8.0, 8.0)
    seed: int = 0
    note: str = ""

    @property
    def causes(self) -> set[str]:
        out = set()
        if self.velocity > 0:
            out.add("goal_profile")
        if self.torque > 0:
            out.add("torque_limit")
        return out


def model_xml(case: Case, truth: bool = False) -> str:
    """The bench's MJCF: the user's nominal model (``position`` actuator, 2 ms) or the truth
    (``motor`` actuator, 0.25 ms)."""
    mass, com = ARMS[case.arm]
    ixx = mass * (2 * com) ** 2 / 12
    if truth:
        act = f'<motor name="m_arm" joint="arm" ctrlrange="-{TAU_MAX} {TAU_MAX}" ctrllimited="true"/>'
    else:
        act = (f'<position name="m_arm" joint="arm" kp="{KP}" kv="{KV}" '
               f'forcerange="-{TAU_MAX} {TAU_MAX}" ctrlrange="-1.6 1.6"/>')
    dt = TRUTH_DT if truth else MODEL_DT
    return (f'<mujoco model="profile_bench">\n<compiler angle="radian"/>\n'
            f'<option timestep="{dt}" integrator="implicitfast" gravity="0 0 -9.81"/>\n'
            f'<worldbody>\n<body name="horn" pos="0 0 0.2">\n'
            f'<joint name="arm" axis="0 1 0" range="-2.5 2.5" limited="true" '
            f'armature="{ARMATURE}" damping="{DAMPING}"/>\n'
            f'<inertial pos="{com} 0 0" mass="{mass}" diaginertia="1e-5 {ixx:.6g} {ixx:.6g}"/>\n'
            f'</body>\n</worldbody>\n<actuator>\n{act}\n</actuator>\n</mujoco>\n')


def profile(p: float, w: float, goal: float, vmax: float, amax: float, dt: float
            ) -> tuple[float, float]:
    """The firmware's setpoint ``p`` and its speed ``w`` after ``dt`` s toward ``goal``
    (velocity-based profile; ``vmax`` / ``amax`` 0: unlimited; ``vmax`` 0: no profile)."""
    if vmax <= 0:
        return goal, 0.0
    e = goal - p
    # fastest speed from which the profile still stops on the goal at amax
    reach = math.sqrt(2.0 * amax * abs(e)) if amax > 0 else math.inf
    want = math.copysign(min(vmax, reach), e)
    if amax > 0:
        w += max(-amax * dt, min(amax * dt, want - w))
    else:
        w = want
    if abs(w * dt) >= abs(e):
        return goal, 0.0
    return p + w * dt, w


def targets(style: str, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Goal [rad] at times ``t`` for a trajectory ``style`` (steps, or ramps to holds)."""
    lo, hi = RANGE
    out = np.empty_like(t)
    k, level = 0, rng.uniform(lo, hi)
    while k < len(t):
        hold = rng.uniform(0.8, 1.6)
        n = max(1, int(np.searchsorted(t, t[k] + hold) - k))
        new = float(np.clip(level + rng.choice([-1, 1]) * rng.uniform(0.15, 1.4), lo, hi))
        if style == "steps":
            out[k:k + n] = new
        else:  # a ramp over half the hold (0.3-1.9 rad/s at most), then the hold
            ramp = np.clip((t[k:k + n] - t[k]) / (0.5 * hold), 0, 1)
            out[k:k + n] = level + (new - level) * ramp
        level = new
        k += n
    return out


def row_times(duration: float, rng: np.random.Generator) -> np.ndarray:
    """Row times [s] on the truth grid: the log period with +-1 step of jitter."""
    period = round(1.0 / RATE / TRUTH_DT)
    steps = period + rng.integers(-1, 2, size=int(duration * RATE) + 1)
    k = np.concatenate([[0], np.cumsum(steps)])
    return k[k * TRUTH_DT <= duration] * TRUTH_DT


def simulate(case: Case, t: np.ndarray, target: np.ndarray, rng: np.random.Generator
             ) -> dict[str, np.ndarray]:
    """Run the truth over rows ``t`` (s, on the 0.25 ms grid, from 0) with the goals ``target``
    written at the rows. Returns the log's columns and the profile's setpoint at the rows
    (``setpoint``, not logged)."""
    m = mujoco.MjModel.from_xml_string(model_xml(case, truth=True))
    d = mujoco.MjData(m)
    tau_max = case.torque if case.torque > 0 else TAU_MAX
    goal = float(np.round(target[0] / TICK) * TICK)
    d.qpos[0] = goal
    mujoco.mj_forward(m, d)
    settle = round(SETTLE / TRUTH_DT)
    rows = np.round(t / TRUTH_DT).astype(int) + settle
    noise = rng.normal(0.0, READ_NOISE, size=len(t))
    out = {"goal:m_arm": np.empty(len(t)), "qpos:arm": np.empty(len(t)),
           "setpoint": np.empty(len(t))}
    p, w, r = goal, 0.0, 0
    for s in range(rows[-1] + 1):
        if r < len(rows) and s == rows[r]:
            out["qpos:arm"][r] = np.round((d.qpos[0] + noise[r]) / TICK) * TICK
            goal = float(np.round(target[r] / TICK) * TICK)
            out["goal:m_arm"][r] = goal
            out["setpoint"][r] = p
            r += 1
        p, w = profile(p, w, goal, case.velocity, case.acceleration, TRUTH_DT)
        d.ctrl[0] = np.clip(KP * (p - d.qpos[0]) - KV * d.qvel[0], -tau_max, tau_max)
        mujoco.mj_step(m, d)
    return out


def write_case(case: Case, folder: str | pathlib.Path) -> dict:
    """Write ``model.xml`` (the user's nominal model), ``log<i>.csv`` and ``truth.json`` into
    ``folder``. Returns {"model", "logs", "truth"}."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "model.xml").write_text(model_xml(case))
    rng = np.random.default_rng(case.seed)
    logs = []
    for i, dur in enumerate(case.durations):
        t = row_times(dur, rng)
        style = ("steps", "steps", "ramps")[i % 3]
        out = simulate(case, t, targets(style, t, rng), rng)
        out.pop("setpoint")
        data = np.column_stack([t, *out.values()])
        path = folder / f"log{i}.csv"
        np.savetxt(path, data, delimiter=",", header=",".join(["time", *out]), comments="",
                   fmt=["%.5f"] + ["%.8g"] * len(out))
        logs.append(str(path))
    truth = {"case": case.name, "causes": sorted(case.causes),
             "effects": dataclasses.asdict(case), "expected_params": expected_params(case)}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"model": str(folder / "model.xml"), "logs": logs, "truth": truth}


def expected_params(case: Case) -> list[dict]:
    """The profile velocity [rad/s] (and acceleration [rad/s^2] where set) as the catalogue's
    ``goal_profile`` parameters; a torque limit's ``torque``."""
    out = []
    if case.velocity > 0:
        out.append(dict(effect="goal_profile", param="velocity", joint="arm",
                        value=case.velocity))
        if case.acceleration > 0:
            out.append(dict(effect="goal_profile", param="acceleration", joint="arm",
                            value=case.acceleration))
    if case.torque > 0:
        out.append(dict(effect="torque_limit", param="torque", joint="arm", value=case.torque))
    return out


CASES: tuple[Case, ...] = (
    Case("clean_bench", seed=1, note="no hidden effect"),
    Case("profile_v2_5_bench", velocity=2.5, seed=2,
         note="Profile Velocity 2.5 rad/s (104 x 0.229 rev/min), acceleration 0: a rectangle"),
    Case("profile_v1_5_bench", velocity=1.5, seed=3,
         note="Profile Velocity 1.5 rad/s (63 units): every step longer than ~0.1 rad ramps"),
    Case("profile_v3_a12_bench", velocity=3.0, acceleration=12.0, seed=4,
         note="a trapezoid: 3 rad/s (125 units), 12 rad/s^2 (34 x 214.577 rev/min^2): "
              "0.25 s to full speed"),
    Case("profile_v2_load_bench", velocity=2.0, arm="load", seed=5,
         note="2 rad/s on the loaded arm (0.34 N m of gravity): the nominal model saturates on "
              "big steps, the truth ramps below the force limit"),
    Case("torque_limit_bench", torque=0.5, arm="load", seed=6,
         note="no profile; the servo delivers 0.5 N m, not 1.4 (saturation, load-dependent "
              "speeds): must not be named a profile"),
)
CASE_BY_NAME = {c.name: c for c in CASES}
