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


def _bench_swings(armature: float, q0s=(-1.4, 1.2)) -> Dataset:
    models, trs = {}, []
    for mass, q0 in zip((0.3, 0.5), q0s, strict=True):
        cfg = BenchConfig(motor="XL330-M288", mass=mass, length=0.1, timestep=DT,
                          gains=servo.ServoGains(position_p=400, supply_voltage=5.0))
        models[f"m{mass}"] = build_bench(cfg).to_xml()
        trs.append(_drop(q0, armature, 0.01, 0.007, mass, 0.1))
    return Dataset(models, trs)


def test_the_armature_seed_is_the_swings_armature_only_where_it_differs_from_the_catalogue():
    from lowcostdex.gap.torque_off import SEED_FACTOR, armature_seed

    # the swings of a pendulum whose armature is 0.0019 (the catalogue XL330-M288 says 0.0003)
    seed = armature_seed(_bench_swings(0.0019), [0, 1])
    assert seed is not None and seed.armature == pytest.approx(0.0019, rel=0.03)
    # the catalogue's own armature (and one within SEED_FACTOR of it): no seed, the start stays
    assert armature_seed(_bench_swings(0.0003), [0, 1]) is None
    assert armature_seed(_bench_swings(0.0003 * SEED_FACTOR * 0.8), [0, 1]) is None
    # arms that hardly move with the torque off (Pham's unloaded XL330: 2 mrad) say nothing
    assert armature_seed(_bench_swings(0.0019, q0s=(-0.05, 0.05)), [0, 1]) is None


def test_seeded_starts_put_the_named_scalars_at_their_values_within_bounds():
    from lowcostdex.gap import fit as fitmod
    from lowcostdex.gap.identify_starts import seeded

    ctx = fitmod.Context(dt=DT, peak_force=np.array([0.5]), stall=np.array([0.5]),
                         damping=np.array([0.0]))
    st = fitmod.Structure.build(("inertia_error", "coulomb_friction"), J, ctx)
    x0 = np.array([f.start for f in st.free])
    names = [(f.effect, f.param) for f in st.free]
    i = names.index(("inertia_error", "scale"))
    x = seeded(st, x0, {("inertia_error", "scale"): 6.3})
    assert x[i] == 6.3 and np.array_equal(np.delete(x, i), np.delete(x0, i))
    assert seeded(st, x0, {("inertia_error", "scale"): 1e6})[i] == st.free[i].hi
