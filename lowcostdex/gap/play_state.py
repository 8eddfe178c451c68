"""A backlash play's hidden state at a replay window's start, carried from the log before it.

A window of a log starts from the measured state at its first sample (``Replayer``), but a
reading gives the link's angle only: where the link sits inside its play and how fast it moves
through it are hidden. A loaded link at rest leans on the stop its load pushes it to
(``Plant.rest_play``), but an unloaded one (a turntable, a horizontal joint, a gripper in free
air) stays wherever its last move left it, drifting through the play at less than a log's
velocity resolution; a loaded link in motion may be on either stop. Started mid-play, the replay
of such a window first swings the link across the play (the sim2 turntable: 5.7 -> 8.9 mrad on
an episode whose link sat at the upper stop), so a play's replays lose to the nominal model on
some episodes and the play goes unnamed.

What the log says about that state is the motion before the window: ``carry`` replays each
window's preceding ``PREROLL`` seconds (from the measured state there, the play at rest as
``Plant.rest_play`` puts it) under the same column, and the window then starts with the play
angle and rate the pre-roll ends with, its link at the measured angle and velocity. The scored
samples are the window's own, so every model is judged on the same data; a window at a log's
start has no history and keeps ``rest_play``'s state. The same holds on a real gearbox: its play
state at any instant is set by the commands and motion before it.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from lowcostdex.gap.dataset import Window
from lowcostdex.sim.effects.base import play_joint_name

PREROLL = 1.0  # s of log replayed before a window to set its play state


def carry(rep, windows: Sequence[Window], columns: Sequence, groups: dict,
          goal_shift: float = 0.0, preroll: float = PREROLL
          ) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Play angle and rate [rad, rad/s] per ``ds.effect_joints`` at each window's start.

    Args:
      rep: the ``Replayer`` (its ``_setup`` / ``_advance`` step the pre-rolls).
      windows, columns: as in ``Replayer._run``.
      groups: ``Replayer._run``'s simulations per (model, structural, friction) key; only the
        structural ones (a play hinge) are pre-rolled.
      goal_shift: as in ``Replayer.run``.
      preroll: seconds replayed before each window (0: none).
    Returns:
      {(column, window index): (play, rate, reading rate)} for the structural simulations of
      windows that start inside their log (NaN for joints without a play hinge); the reading
      rate (the link's, or the motor side's when the log reads there: ``Backlash.read``) is the
      pre-roll's within the measured velocity's resolution (``_velocity_step``) of the measured
      one.
    """
    out: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    if preroll <= 0:
        return out
    ds = rep.ds
    pre: list[Window] = []
    index: dict[Window, int] = {}
    todo: dict[tuple, list[tuple[int, int]]] = {}  # key -> [(column, pre-window)]
    owners: dict[tuple, list[tuple[int, int]]] = {}  # key -> [(column, window)] alike
    for key, sims in groups.items():
        if not key[1]:
            continue
        for c, wi in sims:
            w = windows[wi]
            if w.start == 0:
                continue
            tr = ds.trajectories[w.traj]
            a = int(np.searchsorted(tr.time, tr.time[w.start] - preroll))
            if w.start - a < 2:
                continue
            pw = Window(w.traj, a, w.start + 1, a)
            if pw not in index:
                index[pw] = len(pre)
                pre.append(pw)
            todo.setdefault(key, []).append((c, index[pw]))
            owners.setdefault(key, []).append((c, wi))
    joints = ds.effect_joints
    cols = [list(ds.joints).index(j) for j in joints]
    for key, psims in todo.items():
        run = rep._setup(key, psims, pre, columns, goal_shift)
        plant = run["plant"]
        share = shares(columns, [c for c, _ in psims], joints)
        k_end = np.array([int(round(rep.grid(pre[p]).frac[-1])) for _, p in psims])
        for k in range(int(k_end.max()) + 1):
            at = np.flatnonzero(k_end == k)
            if len(at):
                q, v, vl = read(plant, joints, share)
                for s in at:
                    c, wi = owners[key][s]
                    w = windows[wi]
                    tr = ds.trajectories[w.traj]
                    meas = tr.qvel[w.start, cols]
                    tol = _velocity_step(tr, cols)
                    out[(c, wi)] = (np.array(q[s]), np.array(v[s]),
                                    np.clip(vl[s], meas - tol, meas + tol))
            if k < k_end.max():
                rep._advance(run, k, False)
    return out


def _velocity_step(tr, cols: Sequence[int]) -> np.ndarray:
    """Resolution of the logged velocity per joint [rad/s]: the smallest step between the
    values it takes when they sit on a grid (a Dynamixel reports 0.229 rpm units, 0.024
    rad/s, so a link drifting at 0.02 rad/s reads 0); 0 for velocities off a grid (floats,
    or estimated from positions), which are then taken as measured."""
    out = np.zeros(len(cols))
    for i, c in enumerate(cols):
        u = np.unique(tr.qvel[:, c])
        if 2 < len(u) <= len(tr.qvel) // 4:
            out[i] = float(np.min(np.diff(u)))
    return out


def _addresses(model, joints: Sequence[str]) -> np.ndarray:
    """(5, len(joints)): joint qpos, joint dof, play qpos, play dof and play joint id per joint
    (-1 where the model has no play hinge for it, ``Backlash.prepare``)."""
    out = np.full((5, len(joints)), -1, int)
    for i, j in enumerate(joints):
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j)
        pid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, play_joint_name(j))
        if jid >= 0 and pid >= 0:
            out[:, i] = (model.jnt_qposadr[jid], model.jnt_dofadr[jid], model.jnt_qposadr[pid],
                         model.jnt_dofadr[pid], pid)
    return out


def shares(columns: Sequence, cs: Sequence[int], joints: Sequence[str]) -> np.ndarray:
    """(len(cs), len(joints)) the share of each joint's play the log reads (``Backlash`` read:
    1 the link, 0 the motor side) in columns ``cs``; 1 where a column has no backlash."""
    out = np.ones((len(cs), len(joints)))
    for s, c in enumerate(cs):
        for e in columns[c]:
            if e.name == "backlash":
                for j, r in zip(e.joints, e.values["read"], strict=True):
                    if j in joints:
                        out[s, list(joints).index(j)] = r
    return out


def read(plant, joints: Sequence[str], share: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angle [rad] and rate [rad/s] of each joint's backlash play (link - motor side) in a
    ``Plant``/``BatchPlant``, and the velocity its reading moves at [rad/s] (motor side +
    ``share`` x play rate; default share 1: the link's): (..., len(joints)) each (leading
    axis: a BatchPlant's simulations); NaN for joints without a play hinge."""
    _, jd, pq, pd, _ = _addresses(plant.model, joints)
    has = pq >= 0
    q = np.where(has, plant.qpos[..., np.where(has, pq, 0)], np.nan)
    v = np.where(has, plant.qvel[..., np.where(has, pd, 0)], np.nan)
    r = 1.0 if share is None else share
    return q, v, r * v + np.where(has, plant.qvel[..., np.where(has, jd, 0)], np.nan)


def place(plant, joints: Sequence[str], play: np.ndarray, rate: np.ndarray,
          link_rate: np.ndarray | None = None, sims: np.ndarray | None = None,
          share: np.ndarray | None = None) -> None:
    """Put a plant's backlash plays at ``play`` [rad] (clipped into each play's range) moving at
    ``rate`` [rad/s], keeping every reading (joint + share x play: the link's angle, or the
    motor side's where ``share`` is 0) and its velocity (or setting it to ``link_rate``, the
    reading's): what the encoder reads stays, the hidden sides move.

    Args:
      plant: a ``Plant`` or ``BatchPlant`` (state forward-computed afterwards).
      joints: joint names (columns of the arrays); joints without a play hinge and NaN entries
        are left as they are.
      play, rate, link_rate: (len(sims), len(joints)) for a BatchPlant, (len(joints),) for a
        Plant.
      sims: BatchPlant simulations to change (default all).
      share: (len(sims), len(joints)) or (len(joints),) the play's share in the reading
        (``shares``; default 1, the link).
    """
    batch = plant.qpos.ndim == 2
    rows = ((np.arange(len(plant.qpos)) if sims is None else np.asarray(sims, int)) if batch
            else np.zeros(1, int))
    qpos, qvel = (plant.qpos, plant.qvel) if batch else (plant.qpos[None], plant.qvel[None])
    rng_ = plant.array("jnt_range") if batch else plant.array("jnt_range")[None]
    play, rate = np.atleast_2d(np.asarray(play, float)), np.atleast_2d(np.asarray(rate, float))
    vl = np.full(play.shape, np.nan) if link_rate is None else np.atleast_2d(link_rate)
    sh = np.broadcast_to(1.0 if share is None else np.atleast_2d(share), play.shape)
    jq, jd, pq, pd, pid = _addresses(plant.model, joints)
    for i in np.flatnonzero(pq >= 0):
        ok = np.isfinite(play[:, i]) & np.isfinite(rate[:, i])
        s, r, k = rows[ok], rate[ok, i], sh[ok, i]
        seen = qpos[s, jq[i]] + k * qpos[s, pq[i]]
        vseen = np.where(np.isfinite(vl[ok, i]), vl[ok, i], qvel[s, jd[i]] + k * qvel[s, pd[i]])
        new = np.clip(play[ok, i], rng_[s, pid[i], 0], rng_[s, pid[i], 1])
        qpos[s, pq[i]], qpos[s, jq[i]] = new, seen - k * new
        qvel[s, pd[i]], qvel[s, jd[i]] = r, vseen - k * r
    plant.forward(rows if batch else None)
