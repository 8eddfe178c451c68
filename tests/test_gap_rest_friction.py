"""The breakaway at rest an identification adds when no training log has the torque off
(``lowcostdex.gap.rest_friction``): a light arm whose gears hold it when the torque goes off is
predicted to stay; a loaded arm that falls still falls (tests/test_identify.py's torque-off
test). The logs come from a plain bench with a joint frictionloss (MuJoCo's dry friction: static
level = sliding level), which the fitted structure below cannot express."""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.gap import rest_friction
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.identify import IdentifyConfig, identify
from lowcostdex.gap.logs import Trajectory
from lowcostdex.sim import servo
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig, build_bench
from lowcostdex.sim.plant import Plant

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import bench_servo_logs  # noqa: E402

DT = 0.005
J = (BENCH_JOINT,)
MASS, LENGTH = 0.01, 0.1  # gravity at the horizontal: 0.01 x 9.81 x 0.1 = 9.8 mN m
FRICTION = 0.03  # [N m] joint dry friction, three times the gravity torque: the arm stays


def _log(kp: int, kind: str) -> tuple[Trajectory, str]:
    cfg = BenchConfig(motor="XL330-M288", mass=MASS, length=LENGTH, timestep=DT,
                      gains=servo.ServoGains(position_p=kp, supply_voltage=5.0))
    xml = build_bench(cfg).to_xml()
    model = build_bench(cfg).compile()
    model.dof_frictionloss[:] = FRICTION
    plant = Plant(model, [AppliedEffect("inertia_error", J, {"scale": 2.0})])
    t = np.arange(0.0, 3.0, DT)
    if kind == "sin":
        goal = 0.5 * np.pi * np.sin(2.0 * t) * np.minimum(t, 1.0)
        on = np.ones_like(t)
    else:  # a cubic lift to -pi/2 ending at rest at 1.5 s (BAM's lift_and_drop), torque off
        s = np.clip(t / 1.5, 0, 1)
        goal = -0.5 * np.pi * (3 * s ** 2 - 2 * s ** 3)
        on = (t < 1.5).astype(float)
    tr = bench_servo_logs.record(plant, t, goal, on, kind, kp)
    return tr, xml


def test_a_light_arm_held_by_its_gears_is_predicted_to_stay_when_the_torque_goes_off():
    trs, models = [], {}
    for kp in (100, 400):
        for kind in ("sin", "drop"):
            tr, xml = _log(kp, kind)
            trs.append(tr)
            models[tr.model] = xml
    ds = Dataset(models, trs)
    drops = [1, 3]
    # the truth arm stays within 20 mrad of where the torque went off
    for i in drops:
        q = ds.trajectories[i].qpos[:, 0]
        assert np.ptp(q[ds.trajectories[i].time >= 1.6]) < 0.02
    res = identify(ds, [0, 2], drops, IdentifyConfig(effects=("inertia_error", "viscous_damping"),
                                                     max_rounds=20, select="train"))
    level = res.params()["stribeck_friction"]["static"][0]
    assert level > MASS * 9.81 * LENGTH  # holds the arm against gravity
    assert any("breakaway at rest" in n for n in res.notes)
    # the nominal model (no friction) lets the arm fall and swing; the identified one holds it
    nominal = res.mean(drops, identified=False)
    assert nominal > 0.3
    assert res.mean(drops) < 0.1 * nominal


def test_the_gear_s_own_breakaway_at_rest_is_its_share_of_the_largest_gravity_torque():
    # a heavy arm (0.5 kg at 0.1 m) swung by a sine; gravity on a pendulum hanging at q = 0,
    # written out: m g l |sin q|, largest where the logs swing furthest from hanging
    mass, length = 0.5, 0.1
    cfg = BenchConfig(motor="XL330-M288", mass=mass, length=length, timestep=DT,
                      gains=servo.ServoGains(position_p=400, supply_voltage=5.0))
    plant = Plant(build_bench(cfg).compile(), [])
    t = np.arange(0.0, 2.0, DT)
    goal = 1.2 * np.sin(2.0 * t) * np.minimum(t, 1.0)
    tr = bench_servo_logs.record(plant, t, goal, np.ones_like(t), "sin", 400)
    ds = Dataset({tr.model: build_bench(cfg).to_xml()}, [tr])
    tau = mass * 9.81 * length * np.max(np.abs(np.sin(tr.qpos[:, 0])))
    assert tau > 0.25  # the arm swung past 0.5 rad: the check below is not about a hanging arm
    assert rest_friction.gravity_torque(ds, [0]) == pytest.approx([tau], rel=1e-3)
    gear = AppliedEffect("gearbox_friction", J, {"mu": 0.1, "static": 0.4, "velocity": 0.3,
                                                 "backdrive": 0.5, "alpha": 2.0})
    # torque off at rest the gears carry backdrive x the load; mu is the sliding share (not a
    # breakaway) and the joint's other friction is not the gear's
    assert rest_friction.gear_breakaway(ds, [0], [gear]) == pytest.approx([0.2 * tau], rel=1e-3)
    others = [AppliedEffect("coulomb_friction", J, {"frictionloss": 0.3})]
    assert rest_friction.gear_breakaway(ds, [0], others) == pytest.approx([0.0])
