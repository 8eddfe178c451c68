"""bench/npg_dapg.py names the task a run learned (issue 15): ``env_fingerprint`` changes with the
task's physics, start, goal or motion bound and with nothing else, so runs on different tasks are
neither reused for each other nor tabled as the same.

The case that motivated it: 9edd932 (2026-11-26) moved the D'Claw valve's spokes from -90/30/150
deg to ROBEL's 0/120/240 deg at valve angle 0; NPG on the fixed-start valve then needed 384k
samples to 80 % training success on seed 1 instead of 188k (today's code with the old phase) and
232k (31f2cda), and the bench's records did not say that the task had changed."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest

import lowcostdex.sim.envs.hand_env as hand_env
import lowcostdex.sim.models.dclaw as dclaw
from lowcostdex.algos.configs import TrainConfig

sys.path.insert(0, str(Path(__file__).parent))
from bench_script import script_module  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "npg_dapg.py"
VALVE = "lowcostdex/DClawTurnValve-v0"


@pytest.fixture(scope="module")
def bench():
    yield from script_module(SCRIPT, "npg_dapg_bench_env")


def test_the_same_task_built_twice_has_one_fingerprint(bench):
    a, b = bench.env_fingerprint(VALVE), bench.env_fingerprint(VALVE)
    assert a == b
    assert len(a) == 12 and int(a, 16) >= 0


def test_the_old_spoke_phase_is_another_task(bench, monkeypatch):
    today = bench.env_fingerprint(VALVE)
    # the valve before 9edd932: spoke 0 at -90 deg at valve angle 0 (the spokes at -90, 30, 150)
    monkeypatch.setattr(dclaw, "VALVE", dataclasses.replace(dclaw.VALVE, spoke_phase=-math.pi / 2))
    assert bench.env_fingerprint(VALVE) != today


def test_a_goal_or_motion_bound_change_is_another_task_the_same_model(bench, monkeypatch):
    today = bench.env_fingerprint(VALVE)
    # the model is the same; only the goal (90 deg instead of 180) differs
    assert bench.env_fingerprint(VALVE, {"goal_offset": math.pi / 2}) != today
    # the motion bound before 780a4c4: max_velocity x period, not narrowed for the bus
    monkeypatch.setattr(hand_env, "motion_bound", lambda hand, period, n: np.array(
        [j.max_velocity for j in hand.joints]) * period)
    assert bench.env_fingerprint(VALVE) != today


def test_a_finished_run_on_another_task_is_not_reused(bench, tmp_path):
    args = Namespace(target=0.8, extra_iters=20, max_wall=None)
    cfg = TrainConfig(algo="npg", env_id=VALVE, seed=1)
    settings = bench._settings(cfg, args)
    assert settings["env"] == bench.env_fingerprint(VALVE)
    outcome = {"train_samples": 384000.0, "eval_distinct": 1.0}
    (tmp_path / bench.OUTCOME_FILE).write_text(json.dumps({"settings": settings,
                                                           "outcome": outcome}))
    assert bench.reused(tmp_path, settings) == outcome
    other = {**settings, "env": "0" * 12}  # the same config and stop rule on another task
    assert bench.reused(tmp_path, other) is None
    # a run recorded before the fingerprint existed may have been on another task
    legacy = {k: v for k, v in settings.items() if k != "env"}
    (tmp_path / bench.OUTCOME_FILE).write_text(json.dumps({"settings": legacy,
                                                           "outcome": outcome}))
    assert bench.reused(tmp_path, settings) is None
