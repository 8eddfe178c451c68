"""One bench log recorded from a Plant the way a BAM-style servo log is (shared by
tests/test_identify.py and tests/test_gap_rest_friction.py, which build their own plants and
goals): the measured position and velocity sampled before each control step, the torque
switched per sample, one control step per sample."""

from __future__ import annotations

import numpy as np

from lowcostdex.gap.logs import Trajectory
from lowcostdex.sim.models.bench import BENCH_JOINT
from lowcostdex.sim.plant import Plant

J = (BENCH_JOINT,)


def record(plant: Plant, t: np.ndarray, goal: np.ndarray, on: np.ndarray, kind: str,
           kp: int) -> Trajectory:
    """Run ``plant`` from rest at 0 rad through ``goal`` [rad] with the torque on where ``on``
    is 1; returns the log named ``{kind}_kp{kp}`` with its torque_enable channel."""
    plant.reset(qpos=np.array([0.0]), qvel=np.array([0.0]), ctrl=np.array([0.0]))
    q, v = np.empty_like(t), np.empty_like(t)
    for k in range(len(t)):
        q[k] = plant.measured_qpos()[0]
        v[k] = plant.qvel[0]
        plant.set_torque_enabled([0], bool(on[k]))
        plant.step(np.array([goal[k]]), 1)
    return Trajectory(f"{kind}_kp{kp}", t, goal[:, None], q[:, None], J, J, qvel=v[:, None],
                      channels={"torque_enable": on[:, None]}, model=f"kp{kp}",
                      meta={"kp": kp, "trajectory": kind})
