"""The transfer loop's EXTEND rule (transfer18): a simulated policy below the success target in
its own training sim at the end of its budget trains on from its checkpoint, once, up to
``EXTEND`` x the iterations - the same run as one trained that long from the start."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np


def summary(success, iteration, target=0.8):
    return {"target": target, "final": {"eval_success_rate": success, "iteration": iteration}}


def test_only_a_run_below_its_target_and_short_of_the_cap_is_extended():
    from lowcostdex.transfer.config import EXTEND, extended_iterations

    assert EXTEND == 2
    assert extended_iterations(summary(0.2, 29), 30) == 60  # (d) seed 1 on C, transfer17
    assert extended_iterations(summary(0.8, 29), 30) is None  # reached the target
    assert extended_iterations(summary(1.0, 29), 30) is None
    assert extended_iterations(summary(0.2, 59), 30) is None  # extended once already
    assert extended_iterations(summary(math.nan, 29), 30) is None  # never evaluated
    assert extended_iterations({"target": 0.8, "final": {"iteration": 29}}, 30) is None
    assert extended_iterations(summary(0.5, 9, target=0.4), 10) is None


def test_an_extended_run_is_the_run_trained_that_long_from_the_start(tmp_path, monkeypatch):
    import torch

    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.train import load_policy
    from lowcostdex.transfer import config
    from lowcostdex.transfer.loop import SIZES, TASKS, read_json, train_policy

    # one iteration, evaluated: 0 successes in its own sim (a 4-trajectory NPG step)
    size = replace(SIZES["smoke"], n_iter=1, eval_every=1, eval_episodes=2)
    out = train_policy(tmp_path / "a", "npg", TASKS["valve"], None, None, size, 0)
    monkeypatch.setattr(config, "EXTEND", 1)  # the reference: 2 iterations, the rule off
    ref = train_policy(tmp_path / "b", "npg", TASKS["valve"], None, None,
                       replace(size, n_iter=2), 0)
    monkeypatch.undo()
    assert read_json(tmp_path / "b" / ex.SUMMARY_FILE)["final"]["eval_success_rate"] == 0.0
    assert out["samples"] == ref["samples"] == 2 * 4 * 40
    assert read_json(tmp_path / "a" / "transfer_cpu.json")["extended_to"] == 2
    a, b = (ex.read_metrics(tmp_path / d / ex.METRICS_FILE) for d in "ab")
    for k in a:
        if not k.startswith("time_"):  # wall-clock
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    pa, pb = (list(load_policy(tmp_path / d).parameters()) for d in "ab")
    assert all(torch.equal(p, q) for p, q in zip(pa, pb, strict=True))
    # run again (a resumed table): nothing more is trained
    again = train_policy(tmp_path / "a", "npg", TASKS["valve"], None, None, size, 0)
    assert again["samples"] == out["samples"]


def test_a_size_without_in_training_evaluations_keeps_its_budget(tmp_path):
    """The smoke size (eval_every 0; the final iteration is still evaluated, at 0 here)."""
    from lowcostdex.transfer.loop import SIZES, TASKS, train_policy

    size = replace(SIZES["smoke"], n_iter=1)
    assert size.eval_every == 0
    assert train_policy(tmp_path / "a", "npg", TASKS["valve"], None, None, size, 0
                        )["samples"] == 4 * 40


def test_a_folder_from_before_the_rule_resumed_trains_on_once_and_says_so(tmp_path, monkeypatch):
    """transfer19: a table made before the rule holds finished runs below their target; resumed,
    such a run trains on once, its evaluation cells are redone on the longer policy (before: the
    48k policy's cells were kept beside the 96k row), the report names it, and a second resume
    changes nothing. Truth: the extended policy evaluated afresh on the same robot."""
    import json

    from lowcostdex.transfer import config
    from lowcostdex.transfer.loop import SIZES, evaluate, make_robots, run

    size = replace(SIZES["smoke"], robots=1, algos=("npg",), conditions=("nominal",),
                   n_iter=1, eval_every=1, eval_episodes=2, episodes=2, valve_episodes=0)
    said: list[str] = []
    monkeypatch.setattr(config, "EXTEND", 1)  # the code before the rule
    before = run(tmp_path, size, tell=said.append)
    monkeypatch.undo()
    (row,) = before["rows"]
    assert row["samples"] == 4 * 40 and row["extended"] is None
    run_dir = tmp_path / "runs" / "npg" / "nominal_seed0"
    assert json.loads((run_dir / "summary.json").read_text())["final"]["eval_success_rate"] < 0.8
    cell = run_dir.parent / "nominal_seed0.on_A.json"
    old_cell = json.loads(cell.read_text())

    said.clear()
    after = run(tmp_path, size, tell=said.append)  # resumed under the rule
    (row,) = after["rows"]
    assert row["samples"] == 2 * 4 * 40
    assert row["extended"]["to_iterations"] == 2 and row["extended"]["iteration"] == 0
    assert any("trains on to 2 iterations" in s for s in said), said
    assert "Trained on under the EXTEND rule" in after["text"]
    assert "npg/nominal seed 0: own sim 0.00 after 1 iterations" in after["text"]
    (robot,) = make_robots(1, 0)
    fresh = evaluate(run_dir, config.TASKS["valve"], robot.env_kwargs(), 2)
    new_cell = json.loads(cell.read_text())
    assert new_cell["final_error"] == row["final_error"] == fresh["final_error"]
    # the shorter policy's cells were redone, not kept (kept in previous/, never deleted)
    kept = list((tmp_path / "previous").rglob("nominal_seed0.*.json"))
    assert sorted(p.name for p in kept) == ["nominal_seed0.on_A.json", "nominal_seed0.sim.json"]
    assert [json.loads(p.read_text()) for p in kept if p.name == cell.name] == [old_cell]

    said.clear()
    again = run(tmp_path, size, tell=said.append)  # a second resume: nothing trains
    assert again["rows"][0]["samples"] == 2 * 4 * 40
    assert not any("trains on" in s for s in said), said
    assert json.loads(cell.read_text()) == new_cell
