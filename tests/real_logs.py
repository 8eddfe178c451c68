"""The measured servo logs as the real-log tests read them (shared by tests/test_gap_real.py and
tests/test_gap_real_torque_off.py): the data folder (LOWCOSTDEX_MEASURED_DATA, else
../shared/data/measured beside the clone), a folder's BAM-grid dataset with its lift_and_drop
logs, and the position error of a torque-off law on a set of real swings."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lowcostdex.gap import bam_measure as bm
from lowcostdex.gap import load_dataset

ROOT = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA") or os.environ.get("LOWCOSTDEX_MEASURED")
            or Path(__file__).resolve().parents[2] / "shared" / "data" / "measured")


def lift_logs(folder: Path):
    """(BAM-grid dataset of ``folder``'s logs, indices of its lift_and_drop trajectories: the
    ones that let the arm go with the torque off)."""
    ds = bm.grid_dataset(load_dataset(sorted(folder.glob("*.json")), timestep=bm.BAM_DT))
    return ds, [i for i, tr in enumerate(ds.trajectories)
                if tr.meta.get("trajectory") == "lift_and_drop"]


def swing_maes(swings, params) -> np.ndarray:
    """Mean absolute position error [rad] of each torque-off swing replayed under ``params``
    (``gap.torque_off.simulate``'s parameter vector: armature, Coulomb, viscous[, load share])."""
    from lowcostdex.gap.torque_off import simulate

    p = np.asarray(params, float)
    return np.array([np.mean(np.abs(simulate(p, s)[0] - s.q)) for s in swings])
