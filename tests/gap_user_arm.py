"""A user's own two-joint arm on ``general`` actuators, and the "robot" that records its logs,
written here in plain MuJoCo and numpy (nothing from lowcostdex: no inverse crime).

The user's MJCF (``user_model``): a small arm in a vertical plane, ``shoulder`` then ``elbow``
(both about y, so that gravity loads them), an upper arm of 0.20 m / 0.30 kg carrying a forearm
of 0.18 m / 0.15 kg, each joint driven through a hobby-servo-class gearbox (armature 0.005 kg m^2,
damping 0.05 N m s/rad, frictionloss 0.02 N m). The servos are written the way many users write
them: ``general`` actuators with the PD law spelled out, gain kp and bias (0, -kp, -kv), kp 12
N m/rad, kv 0.8 N m s/rad (the motor's back-EMF), force range +-3 N m (an XM430-class stall torque), 2 ms step.

The robot (``record``): the same arm at 0.5 ms, but the shoulder's servo runs a proportional gain
of GAIN (0.6) times the user's (its kp, both gainprm[0] and biasprm[1]; kv unchanged): a position
P gain lowered in the servo's control table. Nothing else differs.

Logged like a host polling the bus at 100 Hz with ``time.time()`` stamps (1.7e9 s), rows with
+-10 % jitter; each row's position quantised to 4096 ticks with 0.5 mrad noise and its velocity
in the servo's units (0.229 rev/min, 0.0240 rad/s, Dynamixel X series) with 0.02 rad/s noise;
each goal written right after its row's read and acting from the row's time (zero-order hold).
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
from user_rig_goals import goal_signal

JOINTS = ("shoulder", "elbow")
KP = 12.0  # [N m/rad]
KV = 0.8  # [N m s/rad] ~ an XM430's back-EMF: 4.1 N m stall / 4.8 rad/s no-load
GAIN = 0.6  # robot shoulder kp / model kp
RATE = 100.0  # [Hz]
JITTER = 0.1  # fraction of the period
TICKS = 4096
NOISE = 5e-4  # [rad]
VEL_UNIT = 0.229 * 2 * math.pi / 60  # [rad/s] per Dynamixel velocity unit (0.229 rev/min)
VEL_NOISE = 0.02  # [rad/s]
EPOCH = 1_732_700_000.0  # [s]
FLOOR = math.sqrt(NOISE ** 2 + (2 * math.pi / TICKS) ** 2 / 12)  # [rad] reading noise floor
GOAL_RANGE = {"shoulder": (-0.6, 1.2), "elbow": (-0.2, 1.8)}  # [rad]

MODEL = """<mujoco model="user_arm">
  <compiler angle="radian"/>
  <option timestep="{dt}" gravity="0 0 -9.81"/>
  <default>
    <joint type="hinge" axis="0 1 0" damping="0.05" armature="0.005" frictionloss="0.02"/>
    <geom type="capsule" contype="0" conaffinity="0"/>
  </default>
  <worldbody>
    <body name="base" pos="0 0 0.5">
      <geom type="box" size="0.03 0.03 0.03" mass="0.5"/>
      <body name="upper" pos="0 0 0">
        <joint name="shoulder" range="-1.0 1.6"/>
        <geom fromto="0 0 0 0.2 0 0" size="0.015" mass="0.3"/>
        <body name="fore" pos="0.2 0 0">
          <joint name="elbow" range="-0.5 2.2"/>
          <geom fromto="0 0 0 0.18 0 0" size="0.012" mass="0.15"/>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
{actuators}
  </actuator>
</mujoco>
"""


def _xml(dt: float, shoulder_gain: float = 1.0) -> str:
    acts = []
    for j in JOINTS:
        kp = KP * (shoulder_gain if j == "shoulder" else 1.0)
        acts.append(f'    <general name="{j}" joint="{j}" gaintype="fixed" biastype="affine" '
                    f'gainprm="{kp:g}" biasprm="0 {-kp:g} {-KV:g}" forcelimited="true" '
                    f'forcerange="-3 3" ctrllimited="true" ctrlrange="-1.0 2.2"/>')
    return MODEL.format(dt=dt, actuators="\n".join(acts))


def user_model() -> str:
    """The user's MJCF, as they would save it."""
    return _xml(0.002)


def goals(style: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) goals [rad] at the log rows: 'steps' (random levels held 0.4-1.5 s), 'chirp'
    (0.2-2 Hz sweeps) or 'ramps' (slow triangles)."""
    lo = np.array([GOAL_RANGE[j][0] for j in JOINTS])
    hi = np.array([GOAL_RANGE[j][1] for j in JOINTS])
    return goal_signal(style, n, rng, lo, hi, RATE, hold=(0.4, 1.5), f_max=2.0, amp=0.7,
                       phase_mult=np.array([1.0, 1.3]))


def record(g: np.ndarray, rng: np.random.Generator, gain: float = GAIN
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The robot runs the goals ``g`` (one per row), from rest hanging at 0 with goal 0 until
    the first row. Returns (row times from 0 [s], positions (n, 2) [rad], velocities (n, 2)
    [rad/s]) as read: jittered rows, noise, 4096 ticks, velocity units."""
    m = mujoco.MjModel.from_xml_string(_xml(0.0005, gain))
    d = mujoco.MjData(m)
    n = len(g)
    t = (np.arange(n) + rng.uniform(-JITTER, JITTER, n)) / RATE
    t[0] = 0.0
    q, v = np.zeros((n, 2)), np.zeros((n, 2))
    for k in range(n):
        while d.time < t[k] - 1e-9:
            mujoco.mj_step(m, d)
        q[k], v[k] = d.qpos, d.qvel
        d.ctrl[:] = g[k]
    tick = 2 * np.pi / TICKS
    q = np.round((q + rng.normal(0.0, NOISE, q.shape)) / tick) * tick
    v = np.round((v + rng.normal(0.0, VEL_NOISE, v.shape)) / VEL_UNIT) * VEL_UNIT
    return t, q, v


def write_user_folder(folder: Path, seed: int, n_logs: int = 4, seconds: float = 10.0,
                      gain: float = GAIN) -> list[Path]:
    """The user's folder: ``arm.xml`` and ``logs/run_<i>.csv`` (time from the epoch, goals,
    positions, velocities). Returns the log paths."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "arm.xml").write_text(user_model())
    (folder / "logs").mkdir(exist_ok=True)
    paths = []
    start = EPOCH
    for i in range(n_logs):
        style = ("steps", "chirp", "ramps")[i % 3]
        g = goals(style, int(seconds * RATE), rng)
        t, q, v = record(g, rng, gain)
        path = folder / "logs" / f"run_{i}.csv"
        header = ",".join(["time"] + [f"goal:{j}" for j in JOINTS] + [f"qpos:{j}" for j in JOINTS]
                          + [f"qvel:{j}" for j in JOINTS])
        np.savetxt(path, np.column_stack([start + t, g, q, v]), delimiter=",", comments="",
                   header=header, fmt=["%.4f"] + ["%.5f"] * 6)
        start += seconds + 20.0
        paths.append(path)
    return paths
