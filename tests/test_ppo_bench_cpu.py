"""bench/npg_dapg.py's CPU seconds to a first crossing (issue 15 item 4: PPO vs NPG to 80 % on a
shared machine, where the wall-clock depends on whoever else runs): the run's stop rule records,
per iteration, the process's CPU seconds since the run began, keyed by the iteration's samples,
and the table prints them beside the wall-clock."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from bench_script import script_module  # noqa: E402

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "npg_dapg.py"


@pytest.fixture(scope="module")
def bench():
    yield from script_module(SCRIPT, "npg_dapg_bench")


def burn(cpu_seconds: float) -> float:
    """Spin until this process has used ``cpu_seconds`` of CPU (measured with
    time.process_time, not the bench's clock); returns the CPU used."""
    t0 = time.process_time()
    x = 0
    while time.process_time() - t0 < cpu_seconds:
        x += 1
    return time.process_time() - t0


def row(bench, it: int, samples: int, success: float) -> dict[str, float]:
    ex = bench.ex
    return {ex.ITERATION: it, ex.SAMPLES: samples, ex.SUCCESS_RATE: success}


def test_the_stop_rule_records_cpu_per_iteration_and_stops_after_the_extra_iterations(bench):
    cpu: dict[float, float] = {}
    stopped = {"why": "budget"}
    until = bench._until(0.8, 2, None, stopped, cpu)
    assert until(row(bench, 0, 1000, 0.1)) is False
    used = burn(0.3)
    assert until(row(bench, 1, 2000, 0.85)) is False  # the first crossing
    assert until(row(bench, 2, 3000, 0.5)) is False
    assert until(row(bench, 3, 4000, 0.5)) is True  # 2 iterations after it
    assert stopped["why"] == "target"
    assert sorted(cpu) == [1000.0, 2000.0, 3000.0, 4000.0]
    values = [cpu[k] for k in sorted(cpu)]
    assert values == sorted(values)
    # the CPU spent between the two iterations is in the record (rusage and process_time
    # count the same process's CPU; half is a generous bound for their different clocks)
    assert cpu[2000.0] - cpu[1000.0] >= 0.5 * used
    assert cpu[1000.0] < 0.5 * used  # counted from the rule's creation, not the process start


def test_the_table_prints_cpu_beside_the_wall_clock_and_a_ppo_npg_cpu_ratio(bench):
    def result(train_cpu: float, seed: int) -> dict[str, float]:
        nan = math.nan
        return {"seed": seed, "train_samples": 300e3, "eval_samples": 160e3,
                "train_wall": 600.0, "eval_wall": 250.0, "train_cpu": train_cpu,
                "eval_cpu": 80.0, "final_train": 0.7, "final_eval": 1.0, "best_eval": 1.0,
                "best_samples": 300e3, "eval_episodes": 10.0, "holds": 1.0, "samples": 400e3,
                "run_wall": 650.0, "run_cpu": 210.0, "load_start": 1.0, "load_end": 2.0,
                "stopped": "budget", "eval_distinct": 3.0, "final_goal_error": nan}

    results = {"npg": [result(200.0, 1)], "ppo": [result(150.0, 1)]}
    lines = bench.table("valve", results, {"npg": 400e3, "ppo": 400e3}, {"npg": 50, "ppo": 32})
    text = "\n".join(lines)
    assert "| 600 (200) / 250 (80) |" in text
    assert "| 600 (150) / 250 (80) |" in text
    assert "CPU 0.8x (150 s vs 200 s)" in text  # 150 / 200 = 0.75, printed to one decimal
    # a run recorded before the CPU was measured prints "-" instead of failing
    old = {k: v for k, v in result(0.0, 2).items() if k not in ("train_cpu", "eval_cpu")}
    lines = bench.table("valve", {"npg": [old]}, {"npg": 400e3}, {"npg": 50})
    assert "| 600 (-) / 250 (-) |" in "\n".join(lines)
