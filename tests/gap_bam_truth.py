"""A truth simulator for servos we hold no logs of (MX-64, STS3215): BAM's pendulum bench driven
by BAM's published actuator model, logged as BAM's recorders write raw logs.

Written from the equations only, with plain numpy; it imports nothing from lowcostdex (checked by
tests/test_gap_bam_truth.py with tests/user_rig_goals.project_imports), so a fit of the project's
servo model on these logs is not the inverse crime.

Facts used (Rhoban/bam @ its mirrored HEAD, numbers and equations, not code):
- firmware P law: duty = clip(error_gain * kp * (goal - q), +-max_pwm), volts = vin * duty;
  MX (Protocol 1.0): error_gain 0.158, max_pwm 0.9625 (oscilloscope, bam/dynamixel/actuator.py);
  STS3215 7.4 V: error_gain 0.166, max_pwm 0.97, the goal slewed at <= 3400 steps/s
  (bam/feetech/actuator.py).
- DC motor: torque = kt * volts / R - kt^2 * dq / R, zero with the torque off.
- friction budget (bam/model.py): Coulomb ``friction_base`` (+ Stribeck bump
  ``friction_stribeck * exp(-|dq / dtheta_stribeck|^alpha)``), load-dependent (M3/M4):
  ``|tau_ext - tau_motor| * (load_friction_base + load_friction_stribeck * stribeck)``, viscous
  ``friction_viscous * |dq|``; it opposes the stopping torque ``I / dt * dq + tau`` and never
  exceeds it (stiction).
- pendulum (bam/testbench.py): I = m l^2 + arm_mass l^2 / 3 + armature, gravity
  -(m + arm_mass / 2) g l sin(q + q_offset), q = 0 hanging down; a bench may add its own
  q_offset (an arm re-mounted between set-ups hangs at another encoder angle).
- published parameters: bam/params/mx64/m4.json, bam/params/feetech_sts3215_7_4V/m1.json (the
  only STS3215 fit BAM publishes).
- trajectories (bam/trajectory.py, 6 s): lift_and_drop (cubic 0 -> -pi/2 in 2 s, then torque
  off), sin_time_square sin(t^2), up_and_down (cubic 0 -> pi/2 at 3 s -> 0.8 pi/2 at 6 s),
  sin_sin sin(t) pi/2 + 0.5 sin(5t) sin(2t).
- recorders (bam/dynamixel/record.py, bam/feetech/record.py): 1 s holding goal(0) with the torque
  set before recording; each loop writes the goal, reads the state, stamps it at the read's
  middle; header mass/arm-mass/length/kp/vin/motor/trajectory (the Feetech recorder writes no arm
  mass); MX position 2 pi (count / 4096 - 0.5), speed in 0.11 rpm steps, load a signed 0-1023
  register, input_volts in 0.1 V; Feetech position/speed from 4096 steps per turn, load and temp 0.
- kp grids (all_record.py): 4, 8, 16, 32 for both.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

G = 9.80665  # [m/s^2] BAM's pendulum
TICKS = 4096  # encoder steps per turn (MX-64, STS3215)


@dataclass(frozen=True)
class BamMotor:
    """One motor's truth: firmware constants and a published BAM fit (SI units)."""
    name: str  # BAM's motor name, as in the log header
    vin: float  # [V] BAM's bench supply
    error_gain: float  # duty per (kp * rad)
    max_pwm: float
    kt: float  # [N m / A]
    R: float  # [Ohm]
    armature: float  # [kg m^2]
    friction_base: float  # [N m]
    friction_viscous: float  # [N m s / rad]
    friction_stribeck: float = 0.0  # [N m]
    load_friction_base: float = 0.0  # [-]
    load_friction_stribeck: float = 0.0  # [-]
    dtheta_stribeck: float = 1.0  # [rad/s]
    alpha: float = 1.0
    q_offset: float = 0.0  # [rad] gravity's zero vs the encoder's
    max_goal_speed: float = math.inf  # [rad/s] firmware slew of the goal (STS)
    arm_mass_key: str | None = "arm-mass"  # None: the recorder writes no arm mass
    position_units: str = "mx"  # "mx" or "feetech"
    m6: tuple[float, ...] | None = None  # M6's directional terms (see ``Pendulum.step``)


MOTORS = {
    # bam/params/mx64/m4.json (M4: Stribeck load-dependent), vin 15 V (MXActuator default and
    # all_record.py's --vin default)
    "mx64": BamMotor("mx64", 15.0, 0.158, 0.9625, kt=1.6631556605652682, R=3.1560000816605682,
                     armature=0.010961212217454795, friction_base=0.061549466501679174,
                     friction_viscous=0.014754905791636505,
                     friction_stribeck=0.02389528618121147,
                     load_friction_base=1.9611119490261663e-10,
                     load_friction_stribeck=0.23428996680337053,
                     dtheta_stribeck=1.5205782308422509, alpha=1.3344007931759223),
    # bam/params/mx64/m6.json (M6: directional + quadratic); m6 = (load_friction_motor,
    # load_friction_external, load_friction_motor_stribeck, load_friction_external_stribeck,
    # load_friction_motor_quad, load_friction_external_quad)
    "mx64-m6": BamMotor("mx64", 15.0, 0.158, 0.9625, kt=1.6016832750318712, R=2.3164043271967447,
                        armature=0.012265893049213158, friction_base=6.217919698787649e-07,
                        friction_viscous=0.02533701181690149,
                        friction_stribeck=0.12269525980968875,
                        dtheta_stribeck=2.575277366960116, alpha=0.8409018066017007,
                        m6=(0.3114720375111298, 2.0462014258729542e-08, 0.18774381222411038,
                            0.014065853481003015, 0.006908512882777861, 0.009999980627672081)),
    # bam/params/feetech_sts3215_7_4V/m1.json (M1: Coulomb + viscous), vin 7.4 V
    "sts3215": BamMotor("sts3215", 7.4, 0.166, 0.97, kt=1.21164135295077, R=2.6761663274455603,
                        armature=0.02840336348682085, friction_base=0.05239296084748866,
                        friction_viscous=0.05908515565091076, q_offset=-0.05116067663549731,
                        max_goal_speed=3400 * 2 * math.pi / TICKS, arm_mass_key=None,
                        position_units="feetech"),
}
TRAJECTORIES = ("lift_and_drop", "sin_time_square", "up_and_down", "sin_sin")
KPS = (4, 8, 16, 32)
DURATION = 6.0  # [s]


def _cubic(keys: list[tuple[float, float]], t: float) -> float:
    """Cubic through (time, value) keyframes with zero slope at each (BAM's keyframes all have
    zero derivative): smoothstep between consecutive keys, held outside."""
    if t <= keys[0][0]:
        return keys[0][1]
    for (t0, x0), (t1, x1) in zip(keys[:-1], keys[1:], strict=True):
        if t <= t1:
            s = (t - t0) / (t1 - t0)
            return x0 + (x1 - x0) * (3 * s * s - 2 * s ** 3)
    return keys[-1][1]


def goal(trajectory: str, t: float) -> tuple[float, bool]:
    """(goal angle [rad], torque enabled) of a BAM trajectory at time t."""
    if trajectory == "lift_and_drop":
        return _cubic([(0.0, 0.0), (2.0, -math.pi / 2)], t), t < 2.0
    if trajectory == "sin_time_square":
        return math.sin(t * t), True
    if trajectory == "up_and_down":
        return _cubic([(0.0, 0.0), (3.0, math.pi / 2), (6.0, 0.8 * math.pi / 2)], t), True
    if trajectory == "sin_sin":
        return math.sin(t) * math.pi / 2 + math.sin(5 * t) * 0.5 * math.sin(2 * t), True
    raise ValueError(f"trajectory {trajectory!r}; valid: {list(TRAJECTORIES)}")


@dataclass(frozen=True)
class Bench:
    mass: float  # [kg] at the tip
    length: float  # [m]
    arm_mass: float  # [kg] uniform rod
    q_offset: float = 0.0  # [rad] this mounting's gravity zero vs the motor's (added to its)


class Pendulum:
    """The bench and servo, integrated at ``dt`` with BAM's stiction-clipped friction."""

    def __init__(self, motor: BamMotor, bench: Bench, kp: float, dt: float = 1e-3):
        self.m, self.b, self.kp, self.dt = motor, bench, float(kp), dt
        self.inertia = (bench.mass * bench.length ** 2 + bench.arm_mass * bench.length ** 2 / 3
                        + motor.armature)
        self.q = 0.0
        self.dq = 0.0
        self.goal_fw = 0.0  # the firmware's (slewed) goal
        self.duty = 0.0

    def step(self, goal_q: float, enabled: bool) -> None:
        m, dt = self.m, self.dt
        lim = m.max_goal_speed * dt
        self.goal_fw = min(max(goal_q, self.goal_fw - lim), self.goal_fw + lim)
        self.duty = min(max(m.error_gain * self.kp * (self.goal_fw - self.q), -m.max_pwm),
                        m.max_pwm)
        motor = (m.kt * m.vin * self.duty / m.R - m.kt ** 2 * self.dq / m.R) if enabled else 0.0
        ext = -(self.b.mass + self.b.arm_mass / 2) * G * self.b.length * math.sin(
            self.q + m.q_offset + self.b.q_offset)
        stribeck = math.exp(-abs(self.dq / m.dtheta_stribeck) ** m.alpha)
        budget = m.friction_base + m.friction_stribeck * stribeck + m.friction_viscous * abs(
            self.dq)
        if m.m6 is None:  # M1-M4: the gearbox carries |tau_ext - tau_motor|
            gear = abs(ext - motor)
            budget += gear * (m.load_friction_base + m.load_friction_stribeck * stribeck)
        else:  # M6: motor and load torques weighted apart, quadratic when they oppose
            lm, le, lms, les, lmq, leq = m.m6
            budget += abs(ext * le - motor * lm) + stribeck * abs(ext * les - motor * lms)
            if math.copysign(1, ext) != math.copysign(1, motor) and ext != 0 and motor != 0:
                quad = leq * ext ** 2 if abs(ext) < abs(motor) else (
                    lmq * motor ** 2 if abs(ext) > abs(motor) else 0.0)
                budget += stribeck * quad
        tau = motor + ext
        stop = self.inertia / dt * self.dq + tau
        tau -= math.copysign(min(abs(stop), budget), stop)
        acc = tau / self.inertia
        self.dq += acc * dt
        self.q += self.dq * dt + 0.5 * acc * dt * dt


def _read(motor: BamMotor, q: float, dq: float, duty: float, vin: float) -> dict:
    """The registers as the recorder converts them."""
    count = round(q / (2 * math.pi) * TICKS)
    if motor.position_units == "mx":
        # 12-bit position around 2048; speed in 0.11 rpm steps; load the signed 10-bit register
        pos = 2 * math.pi * ((count + 2048) / TICKS - 0.5)
        step = 0.11 * 2 * math.pi / 60.0
        return {"position": pos, "speed": round(dq / step) * step,
                "load": int(round(duty * 1023)), "input_volts": round(vin * 10) / 10.0,
                "temp": 35}
    # Feetech: steps -> degrees -> radians (position and speed), load and temp not read
    return {"position": math.radians(count * 360.0 / TICKS),
            "speed": math.radians(round(dq / (2 * math.pi) * TICKS) * 360.0 / TICKS),
            "load": 0.0, "input_volts": round(vin * 10) / 10.0, "temp": 0.0}


def record(motor: str, bench: Bench, kp: float, trajectory: str, rng: np.random.Generator,
           period: float = 0.010) -> tuple[dict, np.ndarray]:
    """One BAM raw log of the truth, and the true positions at its timestamps (for the floor).

    The loop period is ``period`` + uniform jitter in [-1, +2] ms; each iteration writes the
    goal (in effect 0.5 ms later), reads the state 1.5-2.5 ms after the loop start, and stamps the
    read's middle."""
    m = MOTORS[motor]
    sim = Pendulum(m, bench, kp)
    g0, on0 = goal(trajectory, 0.0)
    sim.goal_fw = g0
    for _ in range(int(1.0 / sim.dt)):  # the recorder's 1 s holding goal(0)
        sim.step(g0, on0)
    header = {"mass": bench.mass}
    if m.arm_mass_key:
        header[m.arm_mass_key] = bench.arm_mass
    header.update({"length": bench.length, "kp": kp, "vin": m.vin, "motor": m.name,
                   "trajectory": trajectory, "entries": []})
    t_sim, t_loop = 0.0, float(rng.uniform(0.0, 0.002))
    g, on = g0, on0
    truth = []

    def advance(until: float) -> None:
        nonlocal t_sim
        while t_sim + sim.dt / 2 < until:
            sim.step(g, on)
            t_sim += sim.dt

    while t_loop < DURATION:
        advance(t_loop + 0.0005)
        g, on = goal(trajectory, t_loop)
        read = t_loop + float(rng.uniform(0.0015, 0.0025))
        advance(read)
        entry = _read(m, sim.q, sim.dq, sim.duty if on else 0.0, m.vin)
        entry.update({"timestamp": round(t_sim, 6), "goal_position": g, "torque_enable": on})
        header["entries"].append(entry)
        truth.append(sim.q)
        t_loop += period + float(rng.uniform(-0.001, 0.002))
    return header, np.asarray(truth)


MX64_BENCHES = (Bench(0.335, 0.105, 0.02), Bench(0.535, 0.15, 0.02))
"""MX-64 benches: 0.335 kg at 0.105 m is BAM's MX passive-fall bench (reference 07); 0.535 kg at
0.15 m a heavier arm within the MX-64's 6 N m; arm mass 0.02 kg as BAM's acquisition docs."""
STS3215_BENCHES = (Bench(0.2, 0.1, 0.0), Bench(0.4, 0.1, 0.0))
"""STS3215 benches (no arm mass: the Feetech recorder writes none): 0.2/0.4 kg at 0.1 m, 0.2-0.4
N m of gravity against a 1.15 N m (6 V) servo."""


def write_set(motor: str, folder: str | Path, seed: int = 0, kps=KPS,
              trajectories=TRAJECTORIES, benches=None) -> dict[str, float]:
    """Write the grid benches x kps x trajectories to ``folder`` as BAM raw logs named
    ``<motor>_m<mass>_kp<kp>_<trajectory>.json``; returns each file's truth floor (MAE of the
    logged position against the true one [rad], the quantisation)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    benches = benches or (MX64_BENCHES if motor.startswith("mx64") else STS3215_BENCHES)
    rng = np.random.default_rng(seed)
    floors = {}
    for b in benches:
        for kp in kps:
            for tr in trajectories:
                log, q = record(motor, b, kp, tr, rng)
                name = f"{MOTORS[motor].name}_m{b.mass:g}_kp{kp:g}_{tr}.json"
                (folder / name).write_text(json.dumps(log))
                pos = np.array([e["position"] for e in log["entries"]])
                floors[name] = float(np.mean(np.abs(pos - q)))
    return floors


if __name__ == "__main__":
    import sys
    f = write_set(sys.argv[1], sys.argv[2], seed=int(sys.argv[3]) if len(sys.argv) > 3 else 0)
    print(f"{len(f)} logs; truth floor (quantisation) mean {1e3 * np.mean(list(f.values())):.3f}"
          " mrad")
