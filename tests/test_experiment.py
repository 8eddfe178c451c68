"""Run directories: safe checkpoints, aligned metrics, resume bookkeeping, learning curves."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lowcostdex.algos import experiment as ex
from lowcostdex.errors import ConfigError


def test_state_round_trip_is_weights_only_safe(tmp_path):
    rng = np.random.default_rng(7)
    rng.standard_normal(3)
    net = torch.nn.Linear(3, 2)
    state = {
        "policy": net.state_dict(),
        "array": np.arange(4.0),
        "rng": rng.bit_generator.state,
        "torch_rng": torch.Generator().manual_seed(1).get_state(),
        "meta": {"iteration": 3, "name": "x", "values": (1.5, None)},
    }
    ex.save_state(tmp_path / "s.pt", state)
    loaded = torch.load(tmp_path / "s.pt", weights_only=True)
    assert torch.equal(loaded["policy"]["weight"], net.weight.detach())
    assert torch.equal(loaded["array"], torch.arange(4.0, dtype=torch.float64))
    restored = np.random.default_rng()
    restored.bit_generator.state = loaded["rng"]
    assert np.array_equal(restored.standard_normal(5), rng.standard_normal(5))
    assert loaded["meta"] == {"iteration": 3, "name": "x", "values": (1.5, None)}


def test_state_keeps_numpy_shapes_exactly(tmp_path):
    arrays = {
        "scalar": np.array(2.5),  # 0-d: must not come back as shape (1,)
        "int_scalar": np.array(7, dtype=np.int64),
        "empty": np.zeros((0, 3)),
        "transposed": np.arange(6.0).reshape(2, 3).T,  # not C-contiguous
    }
    ex.save_state(tmp_path / "s.pt", arrays)
    loaded = ex.load_state(tmp_path / "s.pt")
    for key, value in arrays.items():
        assert tuple(loaded[key].shape) == value.shape, key
        np.testing.assert_array_equal(loaded[key].numpy(), value)
        assert loaded[key].numpy().dtype == value.dtype
    assert loaded["scalar"].item() == 2.5


def test_save_state_refuses_arbitrary_objects(tmp_path):
    with pytest.raises(TypeError, match="state.net"):
        ex.save_state(tmp_path / "s.pt", {"net": torch.nn.Linear(2, 2)})
    assert not (tmp_path / "s.pt").exists()


def test_metrics_widen_without_misaligning(tmp_path):
    log = ex.MetricsLog(tmp_path / "m.csv")
    log.append({"iteration": 0, "a": 1.0})
    log.append({"iteration": 1, "a": 2.0, "b": 5})
    log.append({"iteration": 2, "b": 6})
    m = ex.read_metrics(tmp_path / "m.csv")
    assert list(m) == ["iteration", "a", "b"]
    np.testing.assert_array_equal(m["a"], [1.0, 2.0, np.nan])
    np.testing.assert_array_equal(m["b"], [np.nan, 5, 6])


def test_metrics_reader_skips_a_line_cut_by_a_kill(tmp_path):
    file = tmp_path / "m.csv"
    file.write_text("iteration,a\n0,1.0\n1,2.0\n2,")
    m = ex.read_metrics(file)
    np.testing.assert_array_equal(m["iteration"], [0, 1])


def test_resume_drops_rows_after_last_checkpoint_and_checks_config(tmp_path):
    cfg = {"seed": 1, "n_iter": 5, "policy": {"hidden": [8, 8]}}
    run = ex.Run.open(tmp_path, cfg, mutable_keys=["n_iter"], keep_last=2)
    for it in range(4):
        run.log({"iteration": it, "samples": 10 * (it + 1)})
        if it <= 2:
            run.save_checkpoint(it, {"w": torch.full((2,), float(it))})
    run.close()
    assert sorted(p.name for p in run.checkpoint_dir.glob("*.pt")) == [
        "ckpt_000001.pt",
        "ckpt_000002.pt",
    ]
    with pytest.raises(ConfigError, match="already holds a run"):
        ex.Run.open(tmp_path, cfg)
    with pytest.raises(ConfigError, match=r"policy.hidden"):
        ex.Run.open(
            tmp_path, {**cfg, "policy": {"hidden": [8]}}, resume=True, mutable_keys=["n_iter"]
        )
    run = ex.Run.open(tmp_path, {**cfg, "n_iter": 9}, resume=True, mutable_keys=["n_iter"])
    ckpt = run.load_latest()
    assert ckpt is not None and ckpt.iteration == 2
    assert torch.equal(ckpt.state["w"], torch.full((2,), 2.0))
    np.testing.assert_array_equal(run.read_metrics()["iteration"], [0, 1, 2])
    assert ex.read_json(tmp_path / "config.json")["n_iter"] == 9


def test_resume_without_checkpoint_starts_clean(tmp_path):
    run = ex.Run.open(tmp_path, {"seed": 0})
    run.log({"iteration": 0, "samples": 1})
    run = ex.Run.open(tmp_path, {"seed": 0}, resume=True)
    assert run.load_latest() is None
    assert run.read_metrics().get("iteration", np.array([])).size == 0


def test_learning_curve_png(tmp_path):
    run = ex.Run.open(tmp_path, {})
    for it in range(5):
        run.log(
            {
                ex.ITERATION: it,
                ex.SAMPLES: 100 * (it + 1),
                ex.ROBOT_HOURS: 0.01 * (it + 1),
                ex.SUCCESS_RATE: it / 4,
                ex.RETURN_MEAN: -10 + it,
                ex.EVAL_SUCCESS_RATE: math.nan if it % 2 else it / 4,
            }
        )
    png = run.plot_learning_curves()
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_best_policy_keeps_the_best_evaluation_across_a_resume(tmp_path):
    run = ex.Run.open(tmp_path / "run", {"x": 1}, tensorboard=False)
    best = ex.BestPolicy(run)
    rows = [(0, 0.0, -5.0), (1, 1.0, 10.0), (2, 1.0, 8.0), (3, 0.0, 50.0), (4, 1.0, 12.0)]
    kept = []
    for it, success, ret in rows[:3]:
        row = {ex.SAMPLES: 100 * (it + 1), ex.EVAL_SUCCESS_RATE: success, ex.EVAL_RETURN_MEAN: ret}
        kept.append(best.consider(it, row, {"policy": {"w": torch.tensor([float(it)])}}))
    saved = best.state()
    best = ex.BestPolicy(run)  # a resumed run restores the record from its checkpoint
    best.load_state(saved)
    for it, success, ret in rows[3:]:
        row = {ex.SAMPLES: 100 * (it + 1), ex.EVAL_SUCCESS_RATE: success, ex.EVAL_RETURN_MEAN: ret}
        kept.append(best.consider(it, row, {"policy": {"w": torch.tensor([float(it)])}}))
    # success first, then return: 1.0/10 beats 0/-5, 1.0/8 does not, 0/50 does not, 1.0/12 does
    assert kept == [True, True, False, False, True]
    assert best.record[ex.ITERATION] == 4 and best.record[ex.SAMPLES] == 500
    best.finish({"policy": {"w": torch.tensor([99.0])}})
    assert float(ex.load_state(run.path / ex.POLICY_FILE)["policy"]["w"][0]) == 4.0
    assert float(ex.load_state(run.path / ex.FINAL_POLICY_FILE)["policy"]["w"][0]) == 99.0


def test_a_run_without_evaluation_keeps_its_final_policy(tmp_path):
    run = ex.Run.open(tmp_path / "run", {"x": 1}, tensorboard=False)
    best = ex.BestPolicy(run)
    assert not best.consider(0, {ex.EVAL_SUCCESS_RATE: float("nan")}, {"policy": {}})
    best.finish({"policy": {"w": torch.tensor([7.0])}})
    assert float(ex.load_state(run.path / ex.POLICY_FILE)["policy"]["w"][0]) == 7.0


def test_run_summary_reports_first_crossing_final_and_best_side_by_side():
    nan = float("nan")
    m = {ex.ITERATION: np.arange(6.0), ex.SAMPLES: 1000.0 * np.arange(1, 7),
         ex.ROBOT_HOURS: np.arange(1, 7) / 10.0,
         ex.SUCCESS_RATE: np.array([0.1, 0.5, 0.85, 0.6, 0.9, 0.7]),
         ex.EVAL_SUCCESS_RATE: np.array([nan, 1.0, nan, 0.0, nan, 0.0])}
    s = ex.run_summary(m, {ex.ITERATION: 1, ex.EVAL_SUCCESS_RATE: 1.0}, target=0.8,
                       wall_seconds=12.0)
    assert s["first_train_crossing"] == {ex.ITERATION: 2.0, ex.SAMPLES: 3000.0,
                                         ex.ROBOT_HOURS: 0.3}
    assert s["first_eval_crossing"][ex.SAMPLES] == 2000.0
    # it reached the target at its first evaluation and fell back: final 0, best 1
    assert s["final"][ex.EVAL_SUCCESS_RATE] == 0.0 and s["final"]["eval_iteration"] == 5
    assert s["final"][ex.SUCCESS_RATE] == 0.7 and s["best"][ex.EVAL_SUCCESS_RATE] == 1.0
    assert s["evaluations"] == 3 and s["eval_success_fraction"] == pytest.approx(1 / 3)
    assert ex.run_summary(m, None, target=0.95)["first_train_crossing"] is None


def test_checkpoints_after_the_one_resumed_from_are_dropped_not_the_older_ones(tmp_path):
    """keep_last counts checkpoints of the resumed run: a later (skipped) one of the run before
    the resume must not push out the good one it resumed from."""
    run = ex.Run.open(tmp_path, {"x": 1}, keep_last=2, tensorboard=False)
    for it in (2, 4):
        run.save_checkpoint(it, {"w": torch.tensor([float(it)])})
    (run.checkpoint_dir / "ckpt_000004.pt").write_bytes(b"PK\x03\x04 cut")
    ckpt = run.load_latest(log=None)
    assert ckpt.iteration == 2
    run.save_checkpoint(3, {"w": torch.tensor([3.0])})
    assert sorted(p.name for p in run.checkpoint_dir.glob("*.pt")) == [
        "ckpt_000002.pt", "ckpt_000003.pt"]
