"""The run's policy: the best evaluated one (``BestPolicy``), the final one, and what the run
reached when (``run_summary``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from lowcostdex.algos.metrics import (
    EVAL_RETURN_MEAN,
    EVAL_SUCCESS_RATE,
    ITERATION,
    ROBOT_HOURS,
    SAMPLES,
    SUCCESS_RATE,
)
from lowcostdex.algos.run_files import load_state, save_state


class Run(Protocol):
    """What ``BestPolicy`` needs of an ``experiment.Run`` (this module does not import it)."""

    path: Path


# ----------------------------------------------------------------------------------------------
# The run's policy: the best evaluated one, and what the run reached when


BEST_POLICY_FILE = "best_policy.pt"
"""The best evaluated policy so far, written whenever an evaluation beats the previous best."""
FINAL_POLICY_FILE = "final_policy.pt"
"""The policy after the last iteration."""
POLICY_FILE = "policy.pt"
"""The run's policy: the best evaluated one (the last one when the run never evaluated)."""
BC_POLICY_FILE = "bc_policy.pt"
"""The behaviour clone a run started from (runs with demonstrations), before any RL step."""
SUMMARY_FILE = "summary.json"


def evaluation_score(metrics: Mapping[str, float]) -> tuple[float, float]:
    """How evaluations are ranked: deterministic success first, then deterministic return.

    On a task with a fixed start every deterministic episode is the same, so the success rate
    is 0 or 1 and the return (which counts, e.g., the steps spent at the goal) separates two
    successful policies by how well they hold the goal.
    """
    def finite(x: Any) -> float:
        x = float(x)
        return x if math.isfinite(x) else -math.inf

    return finite(metrics.get(EVAL_SUCCESS_RATE, math.nan)), finite(
        metrics.get(EVAL_RETURN_MEAN, math.nan))


class BestPolicy:
    """Keeps the best evaluated policy of a run (``best_policy.pt``) across resumes.

    Call :meth:`consider` after every evaluation with its metrics and the policy's state; the
    record (iteration, samples, scores) goes into the trainer's checkpoint through
    :meth:`state` / :meth:`load_state`, the policy itself into ``best_policy.pt``.
    """

    def __init__(self, run: Run):
        self.run = run
        self.record: dict[str, float] | None = None

    def consider(self, iteration: int, metrics: Mapping[str, Any],
                 policy_state: Mapping[str, Any]) -> bool:
        """Keep ``policy_state`` if its evaluation beats the best so far; True if it did."""
        score = evaluation_score(metrics)
        if not math.isfinite(score[0]):
            return False
        if self.record is not None and score <= evaluation_score(self.record):
            return False
        self.record = {ITERATION: int(iteration), SAMPLES: float(metrics.get(SAMPLES, math.nan)),
                       EVAL_SUCCESS_RATE: score[0],
                       EVAL_RETURN_MEAN: float(metrics.get(EVAL_RETURN_MEAN, math.nan))}
        save_state(self.run.path / BEST_POLICY_FILE, {**policy_state, "best": dict(self.record)})
        return True

    def state(self) -> dict[str, Any]:
        return {"record": dict(self.record) if self.record is not None else {}}

    def load_state(self, state: Mapping[str, Any] | None) -> None:
        record = dict((state or {}).get("record") or {})
        self.record = {k: float(v) for k, v in record.items()} or None

    def finish(self, final_state: Mapping[str, Any]) -> Path:
        """Write ``final_policy.pt`` and ``policy.pt`` (the best, else the final one)."""
        save_state(self.run.path / FINAL_POLICY_FILE, final_state)
        best = self.run.path / BEST_POLICY_FILE
        chosen = load_state(best) if self.record is not None and best.exists() else final_state
        save_state(self.run.path / POLICY_FILE, chosen)
        return self.run.path / POLICY_FILE


def first_crossing(metrics: Mapping[str, np.ndarray], key: str, target: float
                   ) -> dict[str, float] | None:
    """The first row whose ``key`` >= ``target``: {iteration, samples, robot_hours} or None."""
    if key not in metrics:
        return None
    hit = np.flatnonzero(np.nan_to_num(np.asarray(metrics[key], float), nan=-1.0) >= target)
    if hit.size == 0:
        return None
    i = int(hit[0])
    return {k: float(metrics[k][i]) for k in (ITERATION, SAMPLES, ROBOT_HOURS) if k in metrics}


def run_summary(metrics: Mapping[str, np.ndarray], best: Mapping[str, float] | None,
                target: float = 0.8, wall_seconds: float | None = None) -> dict[str, Any]:
    """First crossing of ``target`` (training and evaluation success), the final and the best
    evaluation: what a benchmark reports beside each other so that a run that reached the
    target once and fell back is not mistaken for one that holds it."""
    evals = np.asarray(metrics.get(EVAL_SUCCESS_RATE, []), float)
    done = np.flatnonzero(np.isfinite(evals))
    final: dict[str, float] = {}
    if len(metrics.get(ITERATION, [])):
        last = len(metrics[ITERATION]) - 1
        final = {ITERATION: float(metrics[ITERATION][last]), SAMPLES: float(metrics[SAMPLES][last]),
                 SUCCESS_RATE: float(metrics[SUCCESS_RATE][last]) if SUCCESS_RATE in metrics
                 else math.nan}
        if done.size:
            final[EVAL_SUCCESS_RATE] = float(evals[done[-1]])
            final["eval_iteration"] = float(metrics[ITERATION][done[-1]])
    out: dict[str, Any] = {
        "target": target,
        "first_train_crossing": first_crossing(metrics, SUCCESS_RATE, target),
        "first_eval_crossing": first_crossing(metrics, EVAL_SUCCESS_RATE, target),
        "final": final,
        "best": dict(best) if best else None,
        "evaluations": int(done.size),
        "eval_success_fraction": float(np.mean(evals[done] >= target)) if done.size else math.nan,
    }
    if wall_seconds is not None:
        out["wall_seconds"] = float(wall_seconds)
    return out
