"""The deadband's data gate (``lowcostdex.gap.offer``): a default analysis offers the opt-in
``deadband`` where the rests of the logs stand off by a band on the load's side.

Truth written here in plain MuJoCo (no project code): a one-joint arm under gravity whose rests
take loads of both signs, a position servo (kp, kv) holding step goals; the hidden effect drives
a ``motor`` with the servo's law written out (a deadband: kp sign(e) max(|e| - w, 0) - kv
qdot), or a joint frictionloss, or a reading offset, or a softer kp. Logs at 100 Hz, 4096 ticks
per turn after 0.4 mrad of read noise, in the project's CSV format; the nominal model is the
plain position servo.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.gap import band_motion, offer
from lowcostdex.gap.analyze import available_candidates
from lowcostdex.gap.dataset import load_dataset

KP, KV, DT, RATE = 3.0, 0.08, 0.001, 100


def arm(actuator: str, frictionloss: float = 0.0) -> str:
    """A 0.2 kg point mass 0.1 m out on a hinge about y; q = 0 is horizontal (load m g l cos q
    changes sign past +-pi/2)."""
    return ('<mujoco><option timestep="0.001" integrator="implicitfast"/><worldbody>'
            '<body name="arm"><joint name="j" axis="0 1 0" armature="0.005" damping="0.02" '
            f'frictionloss="{frictionloss}"/><geom type="sphere" size="0.01" pos="0.1 0 0" '
            f'mass="0.2"/></body></worldbody><actuator>{actuator}</actuator></mujoco>')


NOMINAL = arm(f'<position name="a" joint="j" kp="{KP}" kv="{KV}"/>')


def simulate(seed: int, width: float = 0.0, friction: float = 0.0, offset: float = 0.0,
             kp: float = KP, seconds: float = 30.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times, goals, readings) of step goals held 1 s each across -2.6..-0.5 and 0.5..2.6
    rad (the arm above and below its hinge on both sides: loads of both signs)."""
    rng = np.random.default_rng(seed)
    m = mujoco.MjModel.from_xml_string(arm('<motor name="a" joint="j"/>', friction))
    d = mujoco.MjData(m)
    goal = rng.choice([-1, 1]) * rng.uniform(0.5, 2.6)
    d.qpos[0] = goal
    mujoco.mj_forward(m, d)
    n = round(seconds * RATE)
    per = round(1 / (RATE * DT))
    times, goals, reads = [], [], []
    for k in range(n):
        if k and k % RATE == 0:
            goal = rng.choice([-1, 1]) * rng.uniform(0.5, 2.6)
        q = d.qpos[0] + offset + rng.normal(0, 4e-4)
        times.append(k / RATE)
        goals.append(goal)
        reads.append(round(q * 4096 / (2 * math.pi)) * 2 * math.pi / 4096)
        for _ in range(per):
            e = goal - d.qpos[0]
            d.ctrl[0] = kp * math.copysign(max(abs(e) - width, 0.0), e) - KV * d.qvel[0]
            mujoco.mj_step(m, d)
    return np.array(times), np.array(goals), np.array(reads)


def dataset(tmp_path, sim=None, nominal=None, seed=10, **hidden):
    """Three logs of ``sim`` (default ``simulate``) with ``hidden`` effects, read against the
    ``nominal`` MJCF (default ``NOMINAL``)."""
    paths = []
    for i in range(3):
        t, g, q = (sim or simulate)(seed + i, **hidden)
        p = tmp_path / f"log{i}.csv"
        np.savetxt(p, np.column_stack([t, g, q]), delimiter=",", header="time,goal:a,qpos:j",
                   comments="", fmt="%.9g")
        paths.append(p)
    model = tmp_path / "model.xml"
    model.write_text(nominal or NOMINAL)
    return load_dataset(paths, model=model)


@pytest.mark.parametrize("hidden, shown", [
    ({"width": 0.02}, True),
    ({}, False),
    ({"friction": 0.03}, False),  # Coulomb: the rest stands off on the approach's side
    ({"offset": 0.05}, False),
    ({"kp": 0.6 * KP}, False),
])
def test_the_gate_offers_the_deadband_where_the_rests_show_a_band(tmp_path, hidden, shown):
    ds = dataset(tmp_path, **hidden)
    band, _ = offer.band_scores(ds)["j"]
    assert (band > offer.BAND_Z) == shown, band
    assert offer.offered(ds, "deadband") == shown
    assert ("deadband" in available_candidates(ds, None)) == shown
    assert "deadband" in available_candidates(ds, ("deadband",))  # asked for: always fitted


# A torque rig (sim6's kind): a host PD loop at 200 Hz writes torque commands to a `motor`; the
# arm's goals stay on one side of its hinge (every rest loaded the same way), where a band's
# rest imbalance is a reading offset's. Written here: the command c, the drive's output with a
# PWM band w of sign(c) max(|c| - w, 0), a joint frictionloss, a reading offset, a weaker drive.
HOST_KP, HOST_KD, HOST_RATE, TAU = 2.0, 0.05, 200, 0.5
TORQUE_NOMINAL = arm(f'<motor name="a" joint="j" ctrlrange="-{TAU} {TAU}" ctrllimited="true"/>')


def simulate_torque(seed: int, width: float = 0.0, friction: float = 0.0, offset: float = 0.0,
                    strength: float = 1.0, seconds: float = 20.0):
    """(times, commands, readings): step goals held 0.4-1.2 s in 0.2..1.3 rad (the load
    m g l cos q of one sign), tracked by the host PD on its own readings."""
    rng = np.random.default_rng(seed)
    m = mujoco.MjModel.from_xml_string(arm('<motor name="a" joint="j"/>', friction))
    d = mujoco.MjData(m)
    goal = rng.uniform(0.2, 1.3)
    d.qpos[0] = goal
    mujoco.mj_forward(m, d)
    per = round(1 / (HOST_RATE * DT))
    times, cmds, reads = [], [], []
    last, hold_until, k = None, rng.uniform(0.4, 1.2), 0
    while k / HOST_RATE < seconds:
        t = k / HOST_RATE
        if t >= hold_until:
            goal, hold_until = rng.uniform(0.2, 1.3), t + rng.uniform(0.4, 1.2)
        q = d.qpos[0] + offset + rng.normal(0, 4e-4)
        q = round(q * 4096 / (2 * math.pi)) * 2 * math.pi / 4096
        dq = 0.0 if last is None else (q - last) * HOST_RATE
        c = float(np.clip(HOST_KP * (goal - q) - HOST_KD * dq, -TAU, TAU))
        last = q
        times.append(t)
        cmds.append(c)
        reads.append(q)
        out = strength * math.copysign(max(abs(c) - width, 0.0), c)
        for _ in range(per):
            d.ctrl[0] = out
            mujoco.mj_step(m, d)
        k += 1
    return np.array(times), np.array(cmds), np.array(reads)


def torque_dataset(tmp_path, **hidden):
    return dataset(tmp_path, simulate_torque, TORQUE_NOMINAL, 20, **hidden)


@pytest.mark.parametrize("hidden, shown", [
    ({"width": 0.02}, True),
    ({}, False),
    ({"friction": 0.02}, False),  # Coulomb: a force on the speed's side, not the command's
    ({"offset": 0.05}, False),
    ({"strength": 0.7}, False),
])
def test_a_torque_rigs_moves_show_its_band_where_its_rests_cannot(tmp_path, hidden, shown):
    ds = torque_dataset(tmp_path, **hidden)
    z = band_motion.motion_band_scores(ds)["j"]
    assert (z > offer.MOTION_Z) == shown, z
    assert offer.offered(ds, "deadband") == shown
    if shown:  # the band's size: the fitted force on the command's side
        w = band_motion.motion_band_fits(ds)["j"]["coef"]["band"]
        assert w == pytest.approx(hidden["width"], rel=0.15), w
