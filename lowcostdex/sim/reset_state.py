"""A simulation's state at a reset (``Plant.reset`` / ``BatchPlant.reset``): the ctrl that holds
the joints where they are, the actuator delay buffers filled with past ctrl, and each backlash
play where the static load pushes it (``rest_play``)."""

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


def rest_play(plant, sims: np.ndarray | None = None) -> None:
    """Put each backlash play where the static load pushes it, keeping the readings.

    For a state set from measurements (``reset``; a replay's start): the reading (joint +
    read x play, as ``measured_qpos``: the link, or the motor side) is what was measured;
    its play is unknown. A link at rest leans on the stop its external load (gravity,
    ``-qfrc_bias`` on the play hinge) pushes it to (``Backlash.rest``); an unloaded link
    (load below 1e-9 N m) is put in the middle. The joint angle becomes reading - read x
    play, velocities are kept.

    Args:
      plant: the ``Plant`` or ``BatchPlant`` (its applied effects and state).
      sims: simulations to change (BatchPlant; default all); their state must be forward-
        computed (``qfrc_bias``), as after ``reset``.
    """
    plays = [b for b in plant._bound if b.cls.name == "backlash" and np.any(b.targets.has_play)]
    if not plays:
        return
    qpos, bias = plant.qpos, plant.qfrc_bias
    rows = (slice(None) if sims is None else np.asarray(sims, int)) if plant._lead else ...
    for b in plays:
        h = b.targets.has_play
        jq, pq, pd = b.targets.qpos[h], b.targets.play_qpos[h], b.targets.play_dofs[h]
        v = {k: np.broadcast_to(np.asarray(x, float), plant._lead + (len(h),))[..., h]
             for k, x in b.values.items()}
        v = {k: x[rows] for k, x in v.items()} if plant._lead else v
        joint, play = b.cls.rest(v, qpos[rows][..., jq], qpos[rows][..., pq],
                                 -bias[rows][..., pd])
        if plant._lead:
            r = np.arange(plant._lead[0])[rows]
            qpos[np.ix_(r, pq)] = play
            qpos[np.ix_(r, jq)] = joint
        else:
            qpos[pq] = play
            qpos[jq] = joint
    plant.forward(sims)
