"""`gap identify` on servos we hold no logs of: BAM-model truth logs (tests/gap_bam_truth.py, plain
numpy, BAM's published MX-64 M4 / STS3215 M1 fits) read, replayed and fitted by the project."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gap_bam_truth as truth
import numpy as np
import pytest
from user_rig_goals import project_imports

HERE = Path(__file__).parent


def test_the_truth_imports_nothing_from_the_project():
    assert project_imports(HERE / "gap_bam_truth.py") == set()


def test_the_truth_follows_bam_s_trajectory_shapes():
    # bam/trajectory.py: lift_and_drop reaches -pi/2 at 2 s then the torque goes off;
    # up_and_down pi/2 at 3 s, 0.8 pi/2 at 6 s; sin_sin sin(t) pi/2 + 0.5 sin(5t) sin(2t)
    assert truth.goal("lift_and_drop", 2.0 - 1e-9) == (pytest.approx(-math.pi / 2), True)
    assert truth.goal("lift_and_drop", 2.5) == (pytest.approx(-math.pi / 2), False)
    assert truth.goal("up_and_down", 1.5)[0] == pytest.approx(math.pi / 4)  # cubic midpoint
    assert truth.goal("up_and_down", 6.0)[0] == pytest.approx(0.8 * math.pi / 2)
    t = 1.3
    assert truth.goal("sin_sin", t)[0] == pytest.approx(
        math.sin(t) * math.pi / 2 + 0.5 * math.sin(5 * t) * math.sin(2 * t))


def test_a_held_servo_settles_where_its_p_law_balances_gravity():
    """Statics written out here: at rest the MX-64 at kp 4 holds the arm near -pi/2 where its P
    law's torque kt vin / R * 0.158 * 4 * e meets gravity (m + a/2) g l, up to the friction
    budget, whose load-dependent part is M4's |tau_gravity - tau_motor| (gravity and motor oppose:
    their magnitudes add)."""
    m, b = truth.MOTORS["mx64"], truth.Bench(0.335, 0.105, 0.02)
    sim = truth.Pendulum(m, b, kp=4)
    sim.goal_fw = 0.0
    for _ in range(4000):
        sim.step(-math.pi / 2, True)
    grav = (b.mass + b.arm_mass / 2) * truth.G * b.length  # at -pi/2, sin = -1
    stiff = m.kt * m.vin / m.R * m.error_gain * 4  # [N m / rad]
    err = sim.q + math.pi / 2
    budget = m.friction_base + m.friction_stribeck + (m.load_friction_base
                                                      + m.load_friction_stribeck) * (
        grav + stiff * err)
    assert abs(sim.dq) < 1e-3
    assert abs(stiff * err - grav) <= budget + 1e-9
    assert err > 0.03  # the sag is real (about 0.09 rad), not lost in the friction


@pytest.mark.parametrize("motor", ["mx64", "mx64-m6", "sts3215"])
def test_truth_logs_load_and_the_nominal_model_replays_them(tmp_path, motor):
    from lowcostdex.gap import bam_measure as bm
    from lowcostdex.gap.bam_logs import read_bam
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.replay import Replayer

    floors = truth.write_set(motor, tmp_path, seed=1, kps=(16,), trajectories=("sin_sin",
                                                                                "lift_and_drop"))
    files = sorted(tmp_path.glob("*.json"))
    assert len(files) == 4
    # the truth's floor is the 4096-step quantisation: mean |error| of a uniform rounding is a
    # quarter step
    assert np.mean(list(floors.values())) == pytest.approx(2 * math.pi / 4096 / 4, rel=0.2)
    raw = json.loads(files[0].read_text())
    _, bench = read_bam(files[0])
    assert bench.mass == raw["mass"] and bench.length == raw["length"]
    assert bench.arm_mass == pytest.approx(raw.get("arm-mass", 0.0))
    ds = bm.grid_dataset(load_dataset(files, timestep=bm.BAM_DT))
    rep = Replayer(ds, (), nthread=1)
    mae = bm.per_log_mae(rep, bm.whole_logs(ds), [[]])[0]
    assert mae.shape == (4,) and np.all(np.isfinite(mae))
    # files sorted: lift_and_drop, sin_sin per bench. With the torque on, the nominal
    # (datasheet) servo follows the truth to a few mrad (measured 5.9-17 mrad): a replay that
    # moved nowhere or diverged would be off by the motion's size (sin_sin swings +-2 rad).
    on = [i for i, f in enumerate(files) if "sin_sin" in f.name]
    assert np.all(mae[on] < 0.05), mae
    # With the torque off the nominal arm swings on where BAM's gearbox friction stops it within
    # a swing or two: measured 0.53-0.65 rad (the issue's 'friction that vanishes when the torque
    # is off'); kept as a finite number here, fitted away by identify (slow test below).


def _identify_cli(motor: str, folder: Path, holdout_kp: int) -> dict:
    """`lowcostdex gap identify` as a user runs it on a folder of BAM logs, one gain held out."""
    from lowcostdex.cli import main

    logs = folder / motor
    truth.write_set(motor, logs, seed=0)
    held = sorted(str(p) for p in logs.glob(f"*_kp{holdout_kp}_*.json"))
    out = folder / "identified.json"
    assert main(["gap", "identify", "--log", str(logs), "--holdout", *held, "--threads", "1",
                 "--json", str(out)]) in (0, None)
    return json.loads(out.read_text())


@pytest.mark.slow  # about 105 s of CPU (one thread): 24 training logs, three families
def test_identify_fits_the_mx64_truth_and_predicts_a_held_out_gain(tmp_path):
    """MX-64 under BAM's published M4 (2 benches x kp 4/8/32 x 4 trajectories fitted, kp 16 held
    out), BAM's measure. Measured 2026-11-27: held out 3.7 mrad (nominal 161.1; truth floor, the
    quantisation, 0.38), lift_and_drop 3.1-3.6 (nominal 574-651), no parameter on a bound.

    Bound 10 mrad on the held-out mean and on each drop: below the nominal's torque-on held-out
    mean (10.6 mrad: identify must beat the datasheet model where it is already good) and below
    every fit with one of the friction effects removed (held-out ablation 22-56 mrad), so a fit
    that lost the gearbox's friction with the torque off fails it."""
    res = _identify_cli("mx64", tmp_path, 16)
    held = res["held_out"]
    assert len(held) == 8
    assert res["held_out_mean"] < 0.010, res["held_out_mean"]
    drops = [v for k, v in held.items() if "lift_and_drop" in k]
    assert len(drops) == 2 and max(drops) < 0.010, drops
    assert res["at_bound"] == []


@pytest.mark.slow  # about 111 s of CPU (one thread)
def test_identify_fits_the_sts3215_truth_and_predicts_a_held_out_gain(tmp_path):
    """STS3215 at 7.4 V under BAM's published M1, its -0.051 rad gravity offset and the
    firmware's 3400 steps/s goal slew, kp 16 held out. The project's STS3215 slews its goal at
    that speed (``MotorSpec.goal_speed``, the dcmotor's slewmax) and identify fits a factor on it
    (``goal_slew``). Measured 2026-11-27 (gap-slew7): held out 4.4 mrad (nominal 158.7; truth
    floor 0.37), goal_slew x0.973, Coulomb 0.0527 N m and viscous 0.0592 N m s/rad (truth 0.0524
    / 0.0591), lift_and_drop 1.8/2.2, sin_time_square 9.0/9.2, no parameter on a bound. Before
    the slew (main 2359690, no slew in the model): held out 11.8, sin_time_square 25.9/23.7.

    Bounds: the held-out mean below 8 mrad, under every held-out ablation of a fitted effect
    that matters (velocity limit 9.1, mounting offset 11.4, motor strength 21.3, friction 31-79
    mrad) and under the 11.8 of the fit without a slew; each sin_time_square (the trajectory the
    slew shapes: the truth with and without it differs by 30.0 mrad at kp 16) below 15 mrad
    (23.7-25.9 without the slew); each drop below 15 mrad (nominal 533-583)."""
    res = _identify_cli("sts3215", tmp_path, 16)
    held = res["held_out"]
    assert len(held) == 8
    assert res["held_out_mean"] < 0.008, res["held_out_mean"]
    chirps = [v for k, v in held.items() if "sin_time_square" in k]
    assert len(chirps) == 2 and max(chirps) < 0.015, chirps
    drops = [v for k, v in held.items() if "lift_and_drop" in k]
    assert len(drops) == 2 and max(drops) < 0.015, drops
    assert res["at_bound"] == []
    assert 0.8 < res["params"]["goal_slew"]["scale"][0] < 1.25  # the firmware's 3400 steps/s
