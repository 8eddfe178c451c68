"""``gap.torque_off.swing_fit``: a servo's armature and back-driven friction from its torque-off
swings alone. Truth: a pendulum integrated in this file by scipy's adaptive RK45 (not the
module's 1 ms Euler). On the real logs (BAM's published XL330 armature as the truth):
tests/test_gap_real.py."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.torque_off import swing_fit
from lowcostdex.gap.trajectory import Trajectory
from lowcostdex.sim import servo
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig, build_bench

DT = 0.005
J = (BENCH_JOINT,)


def _drop(q0: float, armature: float, coulomb: float, viscous: float, mass: float,
          length: float, hold: float = 0.5, total: float = 3.0) -> Trajectory:
    """A point mass at ``length`` below the joint, held at ``q0`` [rad] for ``hold`` s, then
    let go with the torque off: (m l^2 + armature) qdd = -m g l sin q - coulomb tanh(qd /
    0.01) - viscous qd, RK45 at rtol 1e-9, sampled every 5 ms."""
    inertia = mass * length**2 + armature

    def f(_t, y):
        q, v = y
        tau = -mass * 9.81 * length * np.sin(q) - coulomb * np.tanh(v / 0.01) - viscous * v
        return [v, tau / inertia]

    t = np.arange(0.0, total, DT)
    after = t[t >= hold] - hold
    sol = solve_ivp(f, (0.0, after[-1]), [q0, 0.0], t_eval=after, rtol=1e-9, atol=1e-12,
                    max_step=1e-3)
    q = np.r_[np.full(int(np.sum(t < hold)), q0), sol.y[0]]
    on = (t < hold).astype(float)
    return Trajectory("drop", t, np.full((len(t), 1), q0), q[:, None], J, J,
                      channels={"torque_enable": on}, model=f"m{mass}",
                      meta={"kp": 400, "trajectory": "lift_and_drop"})


def test_swing_fit_recovers_the_armature_and_friction_of_a_pendulum_written_out():
    models, trs = {}, []
    for mass, q0 in ((0.3, -1.4), (0.5, 1.2)):
        cfg = BenchConfig(motor="XL330-M288", mass=mass, length=0.1, timestep=DT,
                          gains=servo.ServoGains(position_p=400, supply_voltage=5.0))
        models[f"m{mass}"] = build_bench(cfg).to_xml()
        trs.append(_drop(q0, 0.0019, 0.01, 0.007, mass, 0.1))
    ds = Dataset(models, trs)
    fit = swing_fit(ds, [0, 1])
    assert fit.logs == (0, 1)
    assert fit.catalogue_armature == pytest.approx(0.0003)  # the catalogue XL330-M288's
    assert fit.armature == pytest.approx(0.0019, rel=0.03)
    assert fit.coulomb == pytest.approx(0.01, rel=0.1)
    assert fit.viscous == pytest.approx(0.007, rel=0.1)
    assert max(fit.mae) < 2e-3
    # no torque-off run: nothing to fit
    held = Trajectory("hold", trs[0].time, trs[0].goal, trs[0].qpos, J, J,
                      channels={"torque_enable": np.ones(len(trs[0].time))}, model="m0.3")
    assert swing_fit(Dataset(models, [held]), [0]) is None
