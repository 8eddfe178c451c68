"""A simulation's state at a reset (``Plant.reset`` / ``BatchPlant.reset``): the ctrl that holds
the joints where they are, and the actuator delay buffers filled with past ctrl."""

from __future__ import annotations

import mujoco
import numpy as np


def actuated_positions(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """Position of the joint each actuator drives (nu,) [rad]; 0 for other transmissions."""
    out = np.zeros(model.nu)
    joint = model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT
    ids = model.actuator_trnid[:, 0]
    out[joint] = qpos[model.jnt_qposadr[ids[joint]]]
    return out


def fill_ctrl_history(m: mujoco.MjModel, d: mujoco.MjData,
                      history: np.ndarray | None = None) -> None:
    """Fill actuator delay buffers: with d.ctrl, or with ``history`` (k, nu) of past ctrl at
    one-timestep spacing, oldest first, ending now (padded with its first row when short)."""
    for i in np.flatnonzero(m.actuator_history[:, 0] > 0):
        n = int(m.actuator_history[i, 0])
        if history is None:
            values = np.full((n, 1), d.ctrl[i])
        else:
            h = np.asarray(history, float)[-n:, i]
            values = np.concatenate([np.full(n - len(h), h[0]), h])[:, None]
        mujoco.mj_initCtrlHistory(m, d, int(i), None, np.ascontiguousarray(values))
