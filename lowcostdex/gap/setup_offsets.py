"""A mounting offset per bench set-up (``identify``'s last stage): the arm's zero as each
mounting left it, read from the set-up's own torque-off swings.

BAM benches change the arm (length) and the load (mass) between recordings; each change may
re-mount the arm, and the angle at which it hangs is then off by a few tens of mrad from the
other set-ups'. One mounting offset for all logs splits the difference. With the torque off, the
arm swings about its hanging angle and comes to rest near it: a set-up's torque-off logs pin its
own offset. Torque-on logs do not (the offset there trades against the drive's gravity load:
on the STS3032 lift_and_drop fold, offsets chosen on the torque-on logs of each set-up made the
held-out swings worse on 6 of 9 set-ups, bench/RESULTS.md 'lead24'), so a set-up gets its own
offset only when its training logs have the torque off, and only when it lowers that set-up's
training error by ``MARGIN``; held-out logs of a set-up seen so use it, any other log the common
offset. Only the offset moves (every other fitted parameter is kept).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from lowcostdex.gap.bam_measure import per_log_mae, whole_logs
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.identify_logs import torque_off_seen
from lowcostdex.sim.effects import AppliedEffect

OFFSET = ("mounting_offset", "offset")
SETUP_FIELDS = ("motor", "mass", "arm_mass", "length")
"""The header fields of a BAM log that name its bench set-up (kp, vin, trajectory vary within)."""
COARSE = np.round(np.arange(-0.2, 0.2001, 0.02), 3)  # [rad] first scan, around the common offset
FINE = np.round(np.arange(-0.02, 0.0201, 0.004), 3)  # [rad] then around the scan's best
MARGIN = 0.02
"""A set-up's own offset is kept when it lowers the set-up's training-log mean MAE by 2 % (as
``identify_select.FAMILY_MARGIN`` keeps a family with more parameters)."""


def setup_key(meta: Mapping) -> str | None:
    """The bench set-up of a log's header ("mass 0.457 kg, length 0.07 m"), None for a log
    without one (a project-format CSV/NPZ log)."""
    if meta.get("mass") is None or meta.get("length") is None:
        return None
    arm = meta.get("arm_mass")
    return (f"{meta.get('motor', 'servo')}: mass {float(meta['mass']):g} kg"
            + (f", arm mass {float(arm):g} kg" if arm else "")
            + f", length {float(meta['length']):g} m")


def shifted(effects: Sequence[AppliedEffect], delta: float) -> list[AppliedEffect]:
    """``effects`` with the mounting offset moved by ``delta`` [rad] (on every joint)."""
    out = []
    for e in effects:
        if e.name == OFFSET[0]:
            e = AppliedEffect(e.name, e.joints, {**e.values, OFFSET[1]: e.values[OFFSET[1]] + delta})
        out.append(e)
    return out


def groups(ds: Dataset, logs: Sequence[int]) -> dict[str, list[int]]:
    """{set-up: its logs among ``logs``} (logs without a set-up left out)."""
    out: dict[str, list[int]] = {}
    for i in logs:
        key = setup_key(ds.trajectories[i].meta)
        if key is not None:
            out.setdefault(key, []).append(int(i))
    return out


def fit(ds: Dataset, train: Sequence[int], rep, effects: Sequence[AppliedEffect]
        ) -> dict[str, float]:
    """{set-up: offset change [rad]} for the set-ups whose training logs have the torque off
    and gain ``MARGIN`` from their own offset; {} when the effects have no mounting offset or
    the training logs hold one set-up only. ``rep``: the identification's ``Replayer``."""
    if not any(e.name == OFFSET[0] for e in effects):
        return {}
    g = groups(ds, train)
    if len(g) < 2:
        return {}
    g = {k: v for k, v in g.items() if torque_off_seen(ds, v)}
    if not g:
        return {}
    logs = [i for v in g.values() for i in v]
    coarse = per_log_mae(rep, whole_logs(ds, logs), [shifted(effects, d) for d in COARSE])
    out: dict[str, float] = {}
    for key, members in g.items():
        cols = [logs.index(i) for i in members]
        mean = coarse[:, cols].mean(axis=1)
        best = float(COARSE[int(np.argmin(mean))])
        grid = best + FINE
        fine = per_log_mae(rep, whole_logs(ds, members),
                           [shifted(effects, d) for d in grid]).mean(axis=1)
        at_zero = float(mean[int(np.argmin(np.abs(COARSE)))])
        if float(fine.min()) < (1.0 - MARGIN) * at_zero:
            out[key] = float(grid[int(np.argmin(fine))])
    return out


def scored(ds: Dataset, logs: Sequence[int], rep, columns: Sequence[Sequence[AppliedEffect]],
           offsets: Mapping[str, float]) -> np.ndarray:
    """BAM's per-log MAE [rad], shape (len(columns), len(logs)), as ``per_log_mae`` does, each
    log's set-up with its own offset change (``offsets``; an empty column, the nominal model,
    and a column without a mounting offset stay as they are)."""
    logs = list(logs)
    out = per_log_mae(rep, whole_logs(ds, logs), columns)
    if not offsets:
        return out
    for key, members in groups(ds, logs).items():
        if key not in offsets:
            continue
        moved = [c for c, col in enumerate(columns) if any(e.name == OFFSET[0] for e in col)]
        if not moved:
            continue
        redo = per_log_mae(rep, whole_logs(ds, members),
                           [shifted(columns[c], offsets[key]) for c in moved])
        for r, c in enumerate(moved):
            out[c, [logs.index(i) for i in members]] = redo[r]
    return out
