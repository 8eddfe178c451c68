"""A user's own LEAP-hand-like finger and the "robot" that records its logs, written here in
plain MuJoCo and numpy (nothing from lowcostdex: no inverse crime).

The user's MJCF (``user_model``): one LEAP-style finger of four hinges, ``if_abd`` (side to
side, about z) then ``if_mcp``, ``if_pip``, ``if_dip`` (flexion, about y), pointing along +x from
a horizontal palm so that flexion lifts against gravity, each link carrying the next Dynamixel
(LEAP hand: XC330 servos, about 23 g). Plain MuJoCo ``position`` actuators, kp 3 N m/rad,
force range +-0.5 N m, joint damping 0.2 N m s/rad, armature 0.001 kg m^2 and a frictionloss of
0.03 N m that the user calls a guess (MuJoCo Playground's LEAP model uses the same kind of
numbers). Physics step 2 ms.

The robot (``record``): the same finger at 0.5 ms with what the user's numbers got wrong,
written out here:

* ``gain``: every servo's stiffness kp (gainprm[0] and -biasprm[1] together) times GAIN (0.5: a
  current-limited XC330 whose position P gain was halved by the user's firmware settings);
* ``offset``: the log's ``if_mcp`` reading is the joint angle plus OFFSET (0.04 rad: an encoder
  zero set by eye); the servo controls the true angle.

A second draw of the robot (``friction``, ``latency``; gain 1 and offset 0): every joint's dry
friction is ``friction`` (e.g. 3x the guess) and each goal reaches the servos ``latency`` after
its row (a goal queue: a USB-serial round trip).

Logged like a host polling the bus with ``time.time()``: rows at 50 Hz with +-20 % jitter, time
stamps starting at a wall-clock epoch (1.7e9 s), each reading taken at its row's time, noise
0.5 mrad, quantised to 4096 ticks per turn; each goal written right after its row's read (acting
from the row's time, zero-order hold); no velocity column (LeRobot-style recordings have none).
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
from user_rig_goals import goal_signal

JOINTS = ("if_abd", "if_mcp", "if_pip", "if_dip")
KP = 3.0  # [N m/rad] the user's position gain
FRICTION_GUESS = 0.03  # [N m] the user's frictionloss guess (the robot has the same)
GAIN = 0.5  # robot kp / model kp
OFFSET = 0.04  # [rad] the if_mcp reading's calibration offset
RATE = 50.0  # [Hz]
JITTER = 0.2  # fraction of the period
TICKS = 4096
NOISE = 5e-4  # [rad]
EPOCH = 1_732_700_000.0  # [s] the host's time.time() at the first row
FLOOR = math.sqrt(NOISE ** 2 + (2 * math.pi / TICKS) ** 2 / 12)  # [rad] reading noise floor

# Goal ranges per joint [rad] (inside the joint ranges below)
GOAL_RANGE = {"if_abd": (-0.3, 0.3), "if_mcp": (-0.2, 1.4), "if_pip": (-0.1, 1.4),
              "if_dip": (-0.1, 1.2)}

MODEL = """<mujoco model="leap_finger">
  <compiler angle="radian"/>
  <option timestep="{dt}" gravity="0 0 -9.81"/>
  <default>
    <joint type="hinge" damping="0.2" armature="0.001" frictionloss="{friction}"/>
    <geom type="box" rgba="0.2 0.2 0.2 1"/>
  </default>
  <worldbody>
    <body name="palm" pos="0 0 0.3">
      <geom size="0.04 0.04 0.01" mass="0.2" contype="0" conaffinity="0"/>
      <body name="mcp_block" pos="0.05 0 0">
        <joint name="if_abd" axis="0 0 1" range="-0.5 0.5"/>
        <geom size="0.012 0.012 0.012" mass="0.03" contype="0" conaffinity="0"/>
        <body name="proximal" pos="0.015 0 0">
          <joint name="if_mcp" axis="0 1 0" range="-0.35 2.0"/>
          <geom pos="0.025 0 0" size="0.025 0.012 0.012" mass="0.04" contype="0" conaffinity="0"/>
          <body name="middle" pos="0.05 0 0">
            <joint name="if_pip" axis="0 1 0" range="-0.3 1.9"/>
            <geom pos="0.018 0 0" size="0.018 0.011 0.011" mass="0.035" contype="0" conaffinity="0"/>
            <body name="distal" pos="0.036 0 0">
              <joint name="if_dip" axis="0 1 0" range="-0.3 1.7"/>
              <geom pos="0.017 0 0" size="0.017 0.01 0.01" mass="0.015" contype="0" conaffinity="0"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
{actuators}
  </actuator>
</mujoco>
"""


def _xml(dt: float, kp: float, friction: float = FRICTION_GUESS) -> str:
    acts = "\n".join(f'    <position name="{j}" joint="{j}" kp="{kp:g}" forcerange="-0.5 0.5" '
                     f'ctrlrange="-0.6 2.0"/>' for j in JOINTS)
    return MODEL.format(dt=dt, friction=friction, actuators=acts)


def user_model() -> str:
    """The user's MJCF (their guess), as they would save it."""
    return _xml(0.002, KP)


def robot_model() -> str:
    """The robot: the user's finger at 0.5 ms with kp times GAIN."""
    return _xml(0.0005, KP * GAIN)


def goals(style: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 4) goals [rad] at the log rows: 'steps' (random levels held 0.3-1.2 s), 'chirp'
    (0.2-2.5 Hz sweeps around mid-range) or 'ramps' (slow triangles)."""
    lo = np.array([GOAL_RANGE[j][0] for j in JOINTS])
    hi = np.array([GOAL_RANGE[j][1] for j in JOINTS])
    return goal_signal(style, n, rng, lo, hi, RATE, hold=(0.3, 1.2), f_max=2.5, amp=0.8,
                       phase_mult=np.array([0.7, 1.0, 1.2, 1.4]))


def record(g: np.ndarray, rng: np.random.Generator, gain: float = GAIN,
           offset: float = OFFSET, friction: float = FRICTION_GUESS,
           latency: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The robot runs the goals ``g`` (one per row). Returns (row times from 0 [s], readings
    (n, 4) [rad]): jittered rows, each goal acting from ``latency`` after its row's time (at
    the first 0.5 ms step from then on), the if_mcp reading off by ``offset``, noise and
    4096-tick quantisation."""
    m = mujoco.MjModel.from_xml_string(_xml(0.0005, KP * gain, friction))
    d = mujoco.MjData(m)
    n = len(g)
    t = (np.arange(n) + rng.uniform(-JITTER, JITTER, n)) / RATE
    t[0] = 0.0
    q = np.zeros((n, 4))
    for k in range(n):
        while d.time < t[k] - 1e-9:
            sent = np.searchsorted(t[:k], d.time - latency + 1e-9, side="right") - 1
            if sent >= 0:  # before the first goal arrives the servo holds ctrl 0
                d.ctrl[:] = g[sent]
            mujoco.mj_step(m, d)
        q[k] = d.qpos
    q[:, 1] += offset
    q = q + rng.normal(0.0, NOISE, q.shape)
    tick = 2 * np.pi / TICKS
    return t, np.round(q / tick) * tick


def write_user_folder(folder: Path, seed: int, n_logs: int = 6, seconds: float = 12.0,
                      gain: float = GAIN, offset: float = OFFSET,
                      friction: float = FRICTION_GUESS, latency: float = 0.0) -> list[Path]:
    """The user's folder: ``leap_finger.xml`` and ``logs/run_<i>.csv`` (time from the epoch,
    goals then readings, no velocity). Returns the log paths."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "leap_finger.xml").write_text(user_model())
    (folder / "logs").mkdir(exist_ok=True)
    paths = []
    start = EPOCH
    for i in range(n_logs):
        style = ("steps", "chirp", "ramps")[i % 3]
        g = goals(style, int(seconds * RATE), rng)
        t, q = record(g, rng, gain, offset, friction, latency)
        path = folder / "logs" / f"run_{i}.csv"
        header = ",".join(["time"] + [f"goal:{j}" for j in JOINTS] + [f"qpos:{j}" for j in JOINTS])
        np.savetxt(path, np.column_stack([start + t, g, q]), delimiter=",", comments="",
                   header=header, fmt=["%.4f"] + ["%.5f"] * 8)
        start += seconds + 30.0
        paths.append(path)
    return paths
