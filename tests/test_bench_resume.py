"""bench/npg_dapg.py --resume (issue 15: a long flip run stopped by --max-wall continues from its
checkpoint): the resumed run is the uninterrupted run (every metric but the timings, and the
final policy, equal), its outcome adds the earlier session's CPU and wall seconds, and a run that
finished is refused instead of being run again. The truth is the same run made in one session."""

from __future__ import annotations

import json
import sys
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).parent))
from bench_script import script_module  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "npg_dapg.py"
TIMINGS = ("time_", "wall", "cpu")


@pytest.fixture(scope="module")
def bench():
    yield from script_module(SCRIPT, "npg_dapg_bench_resume")


def args(**kw) -> Namespace:
    base = dict(n_traj=2, sampler="vector", eval_every=1, eval_episodes=2, reuse=False,
                target=0.8, extra_iters=20, max_wall=None, held_out=0, resume=False,
                ppo_set=["num_envs=2", "num_minibatches=2", "update_epochs=1"])
    return Namespace(**{**base, **kw})


def run(bench, algo: str, out: Path, a: Namespace) -> dict[str, float]:
    task, budget = bench.TASKS["valve"], 3 * 2 * 80  # 3 iterations of 2 episodes of 80 steps
    if algo == "ppo":
        return bench.run_ppo(task, 0, budget, out, a)
    return bench.run_train(task, algo, 0, budget, None, out, a)


def rows(bench, out: Path) -> dict[str, np.ndarray]:
    m = bench.ex.read_metrics(out / bench.ex.METRICS_FILE)
    return {k: v for k, v in m.items() if not any(t in k for t in TIMINGS)}


def policy(out: Path) -> list[torch.Tensor]:
    state = torch.load(out / "final_policy.pt", weights_only=True)
    flat: list[torch.Tensor] = []

    def walk(d):
        for k in sorted(d):
            v = d[k]
            if isinstance(v, dict):
                walk(v)
            elif torch.is_tensor(v):
                flat.append(v)
    walk(state)
    return flat


@pytest.mark.parametrize("algo", ["npg", "ppo"])
def test_a_wall_limited_run_resumed_equals_the_uninterrupted_run(bench, tmp_path, algo):
    whole = run(bench, algo, tmp_path / "whole", args())
    assert whole["stopped"] == "budget" and whole["sessions"] == 1

    cut = run(bench, algo, tmp_path / "cut", args(max_wall=0.0))  # stops after iteration 0
    assert cut["stopped"] == "wall limit" and cut["samples"] < whole["samples"]
    resumed = run(bench, algo, tmp_path / "cut", args(resume=True))
    assert resumed["stopped"] == "budget" and resumed["sessions"] == 2
    assert resumed["resumed_from"] == 0.0
    assert resumed["samples"] == whole["samples"]
    # the earlier session's seconds are in the total
    assert resumed["run_cpu"] > cut["run_cpu"] and resumed["run_wall"] > cut["run_wall"]

    a, b = rows(bench, tmp_path / "whole"), rows(bench, tmp_path / "cut")
    assert sorted(a) == sorted(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    for x, y in zip(policy(tmp_path / "whole"), policy(tmp_path / "cut"), strict=True):
        assert torch.equal(x, y)


def test_resume_refuses_a_finished_run_and_leaves_it_as_it_is(bench, tmp_path):
    out = tmp_path / "done"
    run(bench, "npg", out, args())
    before = (out / bench.OUTCOME_FILE).read_text()
    with pytest.raises(SystemExit, match="finished \\(stopped by budget\\)"):
        run(bench, "npg", out, args(resume=True))
    assert (out / bench.OUTCOME_FILE).read_text() == before
    assert json.loads(before)["outcome"]["sessions"] == 1


def test_without_resume_a_wall_limited_run_starts_again(bench, tmp_path):
    out = tmp_path / "again"
    run(bench, "npg", out, args(max_wall=0.0))
    again = run(bench, "npg", out, args())
    assert again["sessions"] == 1 and "resumed_from" not in again
