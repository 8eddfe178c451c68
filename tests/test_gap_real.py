"""The gap analysis on real servo logs (BAM pendulum benches). Skips cleanly when the measured
data folder is absent (LOWCOSTDEX_MEASURED_DATA overrides ../shared/data/measured)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from lowcostdex.sim.gap import GapConfig, analyze, load_dataset

ROOT = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA",
                           Path(__file__).resolve().parents[2] / "shared" / "data" / "measured"))
STS3250 = ROOT / "rhoban-bam-feetech-sts3250"


@pytest.mark.skipif(not STS3250.is_dir(), reason=f"measured data not found at {ROOT}")
def test_real_feetech_bench_logs_are_explained_better_after_extension():
    files = sorted(STS3250.glob("*.json"))
    ds = load_dataset(files)  # BAM JSON auto-detected and mapped onto the bench
    assert len(ds.trajectories) == 4 and ds.trajectories[0].meta["motor"] == "sts3250"
    assert {"voltage", "torque_enable"} <= ds.channels()
    res = analyze(ds, GapConfig(seed=0))
    # the nominal (datasheet) model is far off on real hardware; the named causes cut the
    # held-out error substantially and every accepted fit is inside its bounds
    assert res.causes, res.verdict
    assert all(not c.flags for c in res.causes)
    base = np.mean(res.baseline["per_episode_mae"])
    ext = np.mean(res.extended["per_episode_mae"])
    assert ext < 0.5 * base
    assert res.extended["heldout_rmse"] < res.baseline["heldout_rmse"]
