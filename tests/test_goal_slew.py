"""The servo firmware's goal slew (issue 11): a Feetech STS moves its internal goal toward a
written goal at its Running Speed, one model for the simulation, the replays of the gap analysis
and identification (``MotorSpec.goal_speed``, the dcmotor's ``slewmax``, ``goal_slew``).

Vendor numbers typed in here: Feetech's STS memory table (ftservo/ftservo-wiki
docs/en/reference/parameter/memory-sts.md @9522ce19) has the Running Speed register (46) boot at
the factory maximum speed (0 there also means the maximum), 4096 steps per turn; BAM measured
and models the STS3215's maximum as 3400 steps/s (Rhoban/bam bam/feetech/actuator.py,
``default_max_velocity = 3400 * 2 pi / 4096``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

STS_SLEW = 3400 * 2 * math.pi / 4096  # [rad/s] 3400 steps/s, 4096 steps per turn


def _bench_plant(motor: str, effects=(), **gains):
    from lowcostdex.sim import servo
    from lowcostdex.sim.models.bench import BenchConfig, build_bench
    from lowcostdex.sim.plant import Plant

    cfg = BenchConfig(motor=motor, mass=0.2, length=0.1,
                      gains=servo.ServoGains(position_p=32, pwm_limit=858, **gains))
    return Plant(build_bench(cfg).compile(), list(effects))


def _slewed_goal(plant) -> float:
    from lowcostdex.sim import servo

    _, adr = servo.goal_slew_states(plant.model)
    assert len(adr) == 1
    return float(plant.data.act[adr[0]])


def test_an_sts3215_moves_its_goal_at_3400_steps_per_second():
    plant = _bench_plant("STS3215")
    dt = float(plant.model.opt.timestep)
    plant.reset(np.zeros(1), np.zeros(1), np.zeros(1))
    assert _slewed_goal(plant) == 0.0
    n = 20
    for _ in range(n):
        plant.step(np.array([1.0]), 1)
    # the firmware's goal ramps at the Running Speed, whatever the load and gain ...
    assert _slewed_goal(plant) == pytest.approx(n * dt * STS_SLEW, rel=1e-4)
    # ... and the arm follows the ramp, not the step: it cannot lead the firmware's goal
    assert 0.0 < plant.qpos[0] < n * dt * STS_SLEW
    for _ in range(int(0.5 / dt)):
        plant.step(np.array([1.0]), 1)
    assert _slewed_goal(plant) == pytest.approx(1.0, abs=1e-9)  # reached, no overshoot


def test_a_written_running_speed_replaces_the_factory_maximum():
    # Running Speed 1000 steps/s written (1 step/s per unit on the STS: Present Speed's LSB)
    plant = _bench_plant("STS3215", profile_velocity=1000)
    dt = float(plant.model.opt.timestep)
    plant.reset(np.zeros(1), np.zeros(1), np.zeros(1))
    for _ in range(10):
        plant.step(np.array([1.0]), 1)
    assert _slewed_goal(plant) == pytest.approx(10 * dt * 1000 * 2 * math.pi / 4096, rel=1e-4)


@pytest.mark.parametrize("motor", ["XL330-M288", "MX-64(1.0)", "STS3032", "STS3250"])
def test_servos_without_a_firmware_slew_act_on_their_goal_at_once(motor):
    """Dynamixel: Profile Velocity 0 is no profile. STS3032/STS3250: their real logs move
    faster than the STS3215's 3400 steps/s (``test_real_sts_logs_outrun_3400_steps_per_second``)."""
    from lowcostdex.sim import servo

    plant = _bench_plant(motor)
    assert len(servo.goal_slew_states(plant.model)[0]) == 0 and plant.model.na == 0


MEASURED = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA") or os.environ.get(
    "LOWCOSTDEX_MEASURED") or Path(__file__).resolve().parents[2] / "shared" / "data" / "measured")


@pytest.mark.parametrize("folder, at_least", [("qua-robotics-bam-sts3032", 11.0),
                                              ("rhoban-bam-feetech-sts3250", 8.0)])
def test_real_sts_logs_outrun_3400_steps_per_second(folder, at_least):
    """Why the STS3032 and STS3250 carry no goal slew: with the torque on, their arms move
    faster than 3400 steps/s (5.2 rad/s) for 0.2 s at a time on sin_time_square, which a servo
    whose goal moved at that speed cannot (measured 2026-11-27: 11.9 and 8.6 rad/s over 50 ms
    windows); BAM's own STS3032 fits put the clamp at 16.8-29.7 rad/s (reference 08)."""
    import json

    files = sorted((MEASURED / folder).glob("*.json"))
    if not files:
        pytest.skip(f"measured data not found at {MEASURED / folder}")
    fastest = 0.0
    for f in files:
        e = json.loads(f.read_text())["entries"]
        t = np.array([x["timestamp"] for x in e])
        q = np.array([x["position"] for x in e])
        on = np.array([bool(x.get("torque_enable", True)) for x in e])
        k = max(1, int(round(0.05 / np.median(np.diff(t)))))  # 50 ms of samples
        v = np.abs(q[k:] - q[:-k]) / (t[k:] - t[:-k])
        fastest = max(fastest, float(np.max(v[on[k:] & on[:-k]])))
    assert fastest > at_least > 1.5 * STS_SLEW


def test_a_reset_puts_the_slewed_goal_where_the_servo_holds():
    """A servo at rest holds its goal: after a reset at 0.5 rad it must not slew from 0 (the
    activation's zero) and swing the arm back toward it."""
    from lowcostdex.sim import servo
    from lowcostdex.sim.models.bench import BenchConfig, build_bench
    from lowcostdex.sim.plant import BatchPlant

    plant = _bench_plant("STS3215")
    plant.reset(np.array([0.5]), np.zeros(1))
    assert _slewed_goal(plant) == pytest.approx(0.5)
    for _ in range(40):
        plant.step(np.array([0.5]), 1)
    assert abs(plant.qpos[0] - 0.5) < 0.05  # held near it (the gravity sag), no swing to 0
    cfg = BenchConfig(motor="STS3215", gains=servo.ServoGains(position_p=32, pwm_limit=858))
    batch = BatchPlant(build_bench(cfg).compile(), 3, nthread=1)
    batch.reset(np.array([[0.1], [0.2], [-0.3]]), np.zeros((3, 1)),
                np.array([[0.1], [0.2], [-0.3]]))
    _, adr = servo.goal_slew_states(batch.model)
    np.testing.assert_allclose(batch.act[:, adr[0]], [0.1, 0.2, -0.3])


def test_goal_slew_scales_the_firmware_speed_and_is_nothing_on_a_servo_without_one():
    from lowcostdex.sim.effects import AppliedEffect

    eff = [AppliedEffect("goal_slew", ("arm",), {"scale": np.array([2.5])})]
    plant = _bench_plant("STS3215", eff)
    dt = float(plant.model.opt.timestep)
    plant.reset(np.zeros(1), np.zeros(1), np.zeros(1))
    for _ in range(10):
        plant.step(np.array([1.0]), 1)
    assert _slewed_goal(plant) == pytest.approx(10 * dt * 2.5 * STS_SLEW, rel=1e-4)
    # a Dynamixel without a profile has no slewed goal: the effect leaves its response alone
    base, slewed = _bench_plant("XL330-M288"), _bench_plant("XL330-M288", eff)
    for p in (base, slewed):
        p.reset(np.zeros(1), np.zeros(1), np.zeros(1))
        for _ in range(50):
            p.step(np.array([0.8]), 1)
    assert slewed.qpos[0] == base.qpos[0]


def test_a_window_starts_from_the_goal_the_firmware_had_slewed_to():
    """The replay's window-start state (``Activations.slewed``) against the firmware written
    out here: a 0.1 ms loop moving its goal toward the goal in force at <= 3400 steps/s, from
    the first goal (the servo held it before the log)."""
    from lowcostdex.gap.activation import Activations

    u = np.arange(0.0, 1.0, 0.02)  # goals every 20 ms
    goal = np.where(u < 0.3, 0.0, 1.2) + 0.8 * np.sin(7 * u) * (u > 0.6)
    tr = SimpleNamespace(goal=goal[:, None], goal_times=u)
    acts = Activations(SimpleNamespace(trajectories=[tr]), {}, {})
    dt, fw = 1e-4, goal[0]
    t, checks = 0.0, {}
    times = [0.0, 0.05, 0.31, 0.42, 0.55, 0.61, 0.733, 0.97]
    for x in times:  # the loop, advanced to each check time
        while t < x - dt / 2:
            g = goal[max(int(np.searchsorted(u, t + dt / 2, side="right")) - 1, 0)]
            fw += min(max(g - fw, -STS_SLEW * dt), STS_SLEW * dt)
            t += dt
        checks[x] = fw
    for x in times:
        assert acts.slewed(0, 0, STS_SLEW, x) == pytest.approx(checks[x], abs=2e-3), x
    # mid-ramp after the step (0.3 s): 0.12 s at 5.2 rad/s, not the goal (1.2) nor the old (0)
    assert acts.slewed(0, 0, STS_SLEW, 0.42) == pytest.approx(0.12 * STS_SLEW, abs=2e-3)
