"""The torque-off RELEASE: how long a servo still holds its load after a torque-off command
(``gap.torque_off.release_delay``), and the grid a replay lets the arm go on
(``gap.bam_measure.resample(..., release=)``).

Truth: a pendulum held still until the release, then let go, integrated in this file by scipy's
adaptive RK45 (not the module's 0.2 ms Euler), sampled at jittered raw times (seeded); on the
real logs the 18 STS3032 and 4 Rhoban XL330 lift_and_drop logs (skipped when the measured folder
is absent): their falls start ~5 ms after the logged command (bench/RESULTS.md gap-real21)."""

from __future__ import annotations

import numpy as np
import pytest
from real_logs import ROOT
from scipy.integrate import solve_ivp

from lowcostdex.gap import bam_measure as bm
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.trajectory import Trajectory
from lowcostdex.sim import servo
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig, build_bench

J = (BENCH_JOINT,)
G = 9.81


def _held_drop(rng: np.random.Generator, q0: float, delay: float, mass: float,
               length: float = 0.1, armature: float = 0.0019, coulomb: float = 0.01,
               viscous: float = 0.007, t_cmd: float = 0.5, total: float = 3.0) -> Trajectory:
    """A point mass at ``length`` resting at ``q0`` [rad]; torque-off commanded at the first
    raw sample after ``t_cmd`` s, the arm let go ``delay`` s later: (m l^2 + armature) qdd =
    -m g l sin q - coulomb tanh(qd / 0.01) - viscous qd (RK45, rtol 1e-10). Raw samples every
    5 ms +- 1 ms (uniform jitter from ``rng``)."""
    inertia = mass * length**2 + armature

    def f(_t, y):
        q, v = y
        tau = -mass * G * length * np.sin(q) - coulomb * np.tanh(v / 0.01) - viscous * v
        return [v, tau / inertia]

    t = np.cumsum(np.r_[0.0, 0.005 + rng.uniform(-0.001, 0.001, int(total / 0.005))])
    k = int(np.searchsorted(t, t_cmd))
    go = t[k] + delay
    after = t[t >= go] - go
    sol = solve_ivp(f, (0.0, after[-1]), [q0, 0.0], t_eval=after, rtol=1e-10, atol=1e-12,
                    max_step=1e-3)
    q = np.r_[np.full(int(np.sum(t < go)), q0), sol.y[0]]
    on = (np.arange(len(t)) < k).astype(float)[:, None]
    return Trajectory("drop", t, np.full((len(t), 1), q0), q[:, None], J, J,
                      channels={"torque_enable": on}, model=f"m{mass}",
                      meta={"kp": 400, "trajectory": "lift_and_drop"})


def _bench(rng: np.random.Generator, delay: float) -> tuple[Dataset, Dataset]:
    models, trs = {}, []
    for mass, q0 in ((0.3, -1.4), (0.5, 1.2)):
        cfg = BenchConfig(motor="XL330-M288", mass=mass, length=0.1, timestep=bm.BAM_DT,
                          gains=servo.ServoGains(position_p=400, supply_voltage=5.0))
        models[f"m{mass}"] = build_bench(cfg).to_xml()
        trs.append(_held_drop(rng, q0, delay, mass))
    raw = Dataset(models, trs)
    return raw, bm.grid_dataset(raw)


@pytest.mark.parametrize("delay", [0.0, 0.007])
def test_release_delay_recovers_how_long_a_written_out_pendulum_was_held(delay):
    from lowcostdex.gap.torque_off import release_delay

    raw, grid = _bench(np.random.default_rng(3), delay)
    r = release_delay(raw, grid, [0, 1])
    assert r.logs == (0, 1)
    assert r.delays == pytest.approx([delay, delay], abs=7e-4)
    assert r.delay == pytest.approx(delay, abs=7e-4)
    assert max(r.rms) < 2e-3
    if delay:  # the arm let go at the command instead: tens of mrad off over 0.3 s
        assert min(r.rms_none) > 10 * max(r.rms)


def test_a_log_without_a_torque_off_swing_has_no_release_to_measure():
    from lowcostdex.gap.torque_off import release_delay

    raw, grid = _bench(np.random.default_rng(4), 0.005)
    tr = raw.trajectories[0]
    held = Trajectory("hold", tr.time, tr.goal, tr.qpos, J, J,
                      channels={"torque_enable": np.ones((len(tr.time), 1))}, model="m0.3")
    assert release_delay(Dataset(raw.models, [held]), bm.grid_dataset(Dataset(raw.models,
                                                                              [held])), [0]) is None


def test_the_grid_lets_go_at_the_grid_point_nearest_the_command_plus_the_release():
    # raw samples at 0, 6, 13, 19, 26 ... ms; the torque-off command logged at 13 ms
    t = np.array([0.0, 0.006, 0.013, 0.019, 0.026, 0.031, 0.038, 0.044, 0.05, 0.057])
    on = (t < 0.01).astype(float)[:, None]
    tr = Trajectory("x", t, np.zeros((len(t), 1)), np.zeros((len(t), 1)), J, J,
                    channels={"torque_enable": on}, model="m")
    # BAM's rule (no release): off on the 5 ms grid where the interpolated flag < 0.5, i.e.
    # after the midpoint 9.5 ms of the samples at 6 and 13 ms: from 10 ms
    grid_t = np.arange(0.0, t[-1], 0.005)
    bam = bm.resample(tr).channels["torque_enable"][:, 0]
    assert np.array_equal(bam, (grid_t < 0.0095).astype(float))
    # release 7 ms: the servo lets go at 13 + 7 = 20 ms, the grid point nearest it
    rel = bm.resample(tr, release=0.007).channels["torque_enable"][:, 0]
    assert np.array_equal(rel, (grid_t < 0.0199).astype(float))
    # 9 ms -> 22 ms: nearest grid point 20 ms; 11 ms -> 24 ms: 25 ms
    assert np.array_equal(bm.resample(tr, release=0.009).channels["torque_enable"][:, 0],
                          (grid_t < 0.0199).astype(float))
    assert np.array_equal(bm.resample(tr, release=0.011).channels["torque_enable"][:, 0],
                          (grid_t < 0.0249).astype(float))
    # a log that starts with the torque off has nothing to release there
    off = Trajectory("y", t, np.zeros((len(t), 1)), np.zeros((len(t), 1)), J, J,
                     channels={"torque_enable": np.zeros((len(t), 1))}, model="m")
    assert not np.any(bm.resample(off, release=0.007).channels["torque_enable"])


STS3032 = ROOT / "qua-robotics-bam-sts3032"
XL330 = ROOT / "rhoban-bam-xl330"


@pytest.mark.skipif(not (STS3032.is_dir() and XL330.is_dir()),
                    reason=f"measured data not found at {ROOT}")
def test_real_servos_let_go_about_5_ms_after_the_torque_off_command():
    # Measured 2026-11-29 (bench/RESULTS.md gap-real21): each swing fitted alone from 50 ms
    # after the release, then let go from rest at the last torque-on reading: STS3032's 18
    # lift_and_drop logs want 3.0-10.8 ms (median 5.3, RMS over 0.3 s 8.4 mrad median, 48.6
    # let go at the command), Rhoban XL330's four 1.2-12.6 (median 4.5). Checked here on the
    # 0.457 kg set-ups of the STS3032 (6 logs) and the XL330's four.
    from lowcostdex.gap import load_dataset
    from lowcostdex.gap.torque_off import release_delay
    from lowcostdex.motors import motor_spec

    for folder, mass, lo, hi, cat in ((STS3032, 0.457, 0.0025, 0.0095, "STS3032"),
                                      (XL330, 0.49, 0.001, 0.013, "XL330-M288")):
        raw = load_dataset(sorted(folder.glob("*.json")), timestep=bm.BAM_DT)
        grid = bm.grid_dataset(raw)
        lift = [i for i, tr in enumerate(raw.trajectories)
                if tr.meta.get("trajectory") == "lift_and_drop" and tr.meta.get("mass") == mass]
        r = release_delay(raw, grid, lift)
        assert r.logs == tuple(lift) and len(lift) in (4, 6)
        assert all(lo <= d <= hi for d in r.delays), r.delays
        assert 0.003 <= r.delay <= 0.006
        assert motor_spec(cat).release == pytest.approx(r.delay, abs=0.002)
        if cat == "STS3032":  # let go at the command: the first 0.3 s twice as far off or more
            assert all(a < 0.6 * b for a, b in zip(r.rms, r.rms_none, strict=True))
