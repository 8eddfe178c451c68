"""The friction that holds a servo at rest when no training log shows the torque off.

With the torque on, the position loop hides how much friction a resting gear train has: on
Pham's XL330 bench (an unloaded arm, 4 mN m of gravity at the horizontal) a breakaway of 4 mN m
at rest on top of the fitted sliding level moves the training logs' mean MAE by 0.1 mrad (9.6 ->
9.7), so least squares leaves it wherever its path ends (0). With the torque off the same level
decides everything: the real arm stays where the torque went off, the fitted model without it
falls (held out 452.8 mrad), with it stays (3.4; BAM's published M3 17). Measured 2026-11-27.

So when the torque is never off in the training logs, ``rest_breakaway`` scans a breakaway
acting at rest only (``stribeck_friction`` static level, Stribeck velocity at its catalogue
floor) from small to large and keeps the largest level that costs the training logs no more than
``FAMILY_MARGIN`` (2 %) of their mean MAE: of the models the training logs cannot tell
apart, the one whose gears stick as much as those logs allow. A gear train sticks at rest (its
breakaway exceeds its sliding friction); a model with no breakaway at all is not the neutral
choice but the extreme one. A loaded arm whose gravity exceeds what the torque-on logs allow
still falls: there the torque-on holds against gravity bound the level.

The level scanned is the joint's whole breakaway at rest, not an addition to one the fit
already has: a fitted gear friction's breakaway share (``gearbox_friction`` static, per N m the
gears carry) holds a resting back-driven joint with ``static x backdrive x |gravity torque|``,
and that is as invisible to the torque-on logs as the scanned level (a loop holding the load at
rest leaves the gears ~|tau_motor - tau_load| = 0 to carry). Stacking the two counted the same
unmeasured breakaway twice: on Rhoban's STS3250 (1.13 kg at 0.12 m) the fit's 0.447 share (0.35
N m at the first swing's top) plus the scanned 0.256 N m plus the joint Coulomb 0.39 N m held
the arm at +0.63 rad after the drop, where the real arm swings back and settles hanging
(lift_and_drop held out 373.9 mrad). So the level added is what the scan allows beyond the gear's
own breakaway at the largest gravity torque the logs put on the joint (``gear_breakaway``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import mujoco
import numpy as np

from lowcostdex.gap.bam_measure import per_log_mae, whole_logs
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.replay import Replayer
from lowcostdex.sim.effects import EFFECTS, AppliedEffect

# Breakaway levels scanned [N m]: from 1 mN m doubling to the servo's stall torque.
FIRST_LEVEL = 1e-3


def rest_breakaway(rep: Replayer, ds: Dataset, train: Sequence[int],
                   effects: list[AppliedEffect], stall: float, margin: float
                   ) -> tuple[list[AppliedEffect], float, list[float]]:
    """``effects`` plus the largest rest breakaway the training logs allow (module doc).

    Args:
      rep: a Replayer with room for ``stribeck_friction``.
      ds, train: the data set and the training logs.
      effects: the fitted model (without ``stribeck_friction``).
      stall: [N m] the servo's stall torque: the scan's last level.
      margin: relative rise of the training logs' mean per-log MAE allowed.
    Returns:
      (effects with the breakaway, or ``effects`` unchanged when even the first level costs
      more or the gear friction's own breakaway at rest already reaches the level allowed; the
      level added [N m] (0: none; the largest over joints); the training MAE [rad] at 0 and at
      each level scanned).
    """
    levels = []
    lv = FIRST_LEVEL
    # a servo without a drive limit (stall inf) scans up to dry friction's hard limit
    top = stall if math.isfinite(stall) else EFFECTS["coulomb_friction"].param(
        "frictionloss").hard[1]
    while lv <= top:
        levels.append(lv)
        lv *= 2.0
    vel = EFFECTS["stribeck_friction"].param("velocity").low
    joints = ds.effect_joints
    cols = [effects] + [effects + [AppliedEffect("stribeck_friction", joints,
                                                 {"static": np.asarray(x), "velocity":
                                                  np.asarray(vel)})] for x in levels]
    mae = per_log_mae(rep, whole_logs(ds, train), cols).mean(axis=1)
    # the largest level below the first one that costs more than the margin (a friction that
    # holds the arm still at a far larger level can score well again by accident)
    best = 0
    for k in range(1, len(cols)):
        if mae[k] > (1.0 + margin) * mae[0]:
            break
        best = k
    if not best:
        return effects, 0.0, mae.tolist()
    # the gear's own breakaway at rest counts toward the level (module doc)
    add = np.maximum(levels[best - 1] - gear_breakaway(ds, train, effects), 0.0)
    if not np.any(add > 0):
        return effects, 0.0, mae.tolist()
    return (effects + [AppliedEffect("stribeck_friction", joints,
                                     {"static": add, "velocity": np.asarray(vel)})],
            float(np.max(add)), mae.tolist())


def gravity_torque(ds: Dataset, logs: Sequence[int]) -> np.ndarray:
    """[N m] per effect joint, the largest |gravity torque| on it at the logs' measured positions
    (MuJoCo's bias force at rest on the nominal models: what a resting, back-driven joint's gears
    carry with the torque off)."""
    joints = ds.effect_joints
    out = np.zeros(len(joints))
    for i in logs:
        tr = ds.trajectories[i]
        m = ds.compiled(tr.model)
        d = mujoco.MjData(m)
        adr = [int(m.jnt_qposadr[m.joint(j).id]) for j in tr.joints]
        dof = [int(m.jnt_dofadr[m.joint(j).id]) for j in joints]
        for q in tr.qpos:
            d.qpos[adr] = q
            mujoco.mj_forward(m, d)
            out = np.maximum(out, np.abs(d.qfrc_bias[dof]))
    return out


def gear_breakaway(ds: Dataset, logs: Sequence[int], effects: Sequence[AppliedEffect]
                   ) -> np.ndarray:
    """[N m] per effect joint, the breakaway at rest the fitted ``gearbox_friction`` gives a
    back-driven joint at the largest gravity torque of ``logs``: static x backdrive x |tau_g|
    (torque off: the gears carry backdrive x the load; 0 without a gear friction)."""
    joints = ds.effect_joints
    out = np.zeros(len(joints))
    tau = None
    for e in effects:
        if e.name != "gearbox_friction":
            continue
        tau = gravity_torque(ds, logs) if tau is None else tau
        n = (len(e.joints),)
        static = np.broadcast_to(np.asarray(e.values.get("static", 0.0), float), n)
        back = np.broadcast_to(np.asarray(e.values.get("backdrive", 1.0), float), n)
        for k, j in enumerate(e.joints):
            if j in joints:
                out[joints.index(j)] += static[k] * back[k] * tau[joints.index(j)]
    return out


def held_at_rest(ds: Dataset, effect_names: Sequence[str], nthread: int, logs: Sequence[int],
                 columns: Sequence[list[AppliedEffect]], stall: float, margin: float
                 ) -> tuple[Replayer, list[list[AppliedEffect]], list[float]]:
    """``rest_breakaway`` for each fitted model in ``columns`` on the fitted ``logs``, with a
    Replayer that has room for it (returned, to score the models with)."""
    rep = Replayer(ds, (*effect_names, "stribeck_friction"), nthread=nthread)
    out = [rest_breakaway(rep, ds, logs, list(c), stall, margin) for c in columns]
    return rep, [o[0] for o in out], [o[1] for o in out]
