"""DAPG in the randomized simulation, several runs from the same clone, their weights averaged.

One DAPG run in the randomized simulation is one draw of the randomization's stream (which
effects each episode draws, the training episodes, the baseline fits), and its gain on the robot
moves with that draw: the same recipe from the same clone went 37 -> 53 and 37 -> 35 of 100
held-out robot episodes with nothing but another stream (bench/RESULTS.md, "Paired evaluations
that do not depend on order; DAPG in the gap-extended simulation"). Averaging over the stream
removes what is particular to one draw and keeps what every draw teaches: ``runs`` runs start
from the same clone with seeds drawn from the run's seed (the first is the run's seed itself,
the single run the main job made before), and the policy is the mean of their last iterates'
weights. The runs start from the same clone and BC froze the observation statistics and the
action scaling, so their networks share every buffer and stay close in weight space (small
natural-gradient steps from one start): the average is a policy of the same form, saved as one
(``AVERAGE_FILE``), loaded like any other.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

STREAM_SEED_KEY = 21
"""Spawn key of the extra runs' seeds (``SeedSequence(seed, spawn_key=(21, k))``)."""
AVERAGE_FILE = "averaged_policy.pt"
"""The averaged policy, in the first run's directory (a ``{"policy": ...}`` state file)."""


def stream_seeds(seed: int, runs: int) -> list[int]:
    """The runs' seeds: ``seed`` itself first, then ``runs - 1`` seeds drawn from it."""
    extra = [int(np.random.SeedSequence(seed, spawn_key=(STREAM_SEED_KEY, k))
                 .generate_state(1, np.uint32)[0] >> 1) for k in range(1, runs)]
    return [seed, *extra]


def average_weights(policies: list[Any]) -> Any:
    """A policy whose floating-point parameters and buffers are the element-wise mean of
    ``policies`` (``GaussianMLPPolicy``s of the same sizes); the other buffers (the frozen
    normaliser's flag) must agree. Returns a new policy; the inputs are unchanged."""
    import copy

    import torch

    from lowcostdex.errors import ConfigError

    if not policies:
        raise ConfigError("average_weights needs at least one policy")
    states = [p.state_dict() for p in policies]
    keys = list(states[0])
    if any(list(s) != keys or any(s[k].shape != states[0][k].shape for k in keys)
           for s in states[1:]):
        raise ConfigError("average_weights: the policies' networks differ in their sizes")
    mean = {}
    for k in keys:
        v = states[0][k]
        if v.is_floating_point():
            mean[k] = torch.stack([s[k] for s in states]).mean(0)
        elif all(torch.equal(s[k], v) for s in states[1:]):
            mean[k] = v.clone()
        else:
            raise ConfigError(f"average_weights: the policies differ in {k}")
    out = copy.deepcopy(policies[0])
    out.load_state_dict(mean)
    return out


def train_streams(config: Any, first_dir: Path, runs: int,
                  env_factory: Any = None) -> dict[str, Any]:
    """``runs`` DAPG runs of ``config``, each from the same clone (``config.bc_seed``, or
    ``config.seed`` when None), the first with ``config.seed`` into ``first_dir``, run k into
    ``first_dir``'s sibling ``<name>_run<k>``; their last iterates' weights averaged into
    ``first_dir / AVERAGE_FILE`` and validated on the first run's validation episodes
    (``train.evaluation_jobs``: the episodes that chose among its iterates and the clone).
    ``env_factory``: as ``train``'s (None: the env of ``config.env_id``).

    Returns ``{"runs": [{"seed", "dir", "best_iteration", "best_eval_success"}...],
    "average": {"file", "eval_successes", "eval_episodes", "eval_success"}}``.
    """
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.samplers import SerialSampler
    from lowcostdex.algos.train import (
        default_env_factory,
        evaluation_env_factory,
        evaluation_jobs,
        load_policy,
        train,
        trajectory_success,
    )

    rows, lasts = [], []
    # the same clone in every run: the first run's BC seed
    bc_seed = config.seed if config.bc_seed is None else config.bc_seed
    for k, seed in enumerate(stream_seeds(config.seed, runs)):
        run_dir = first_dir if k == 0 else first_dir.with_name(f"{first_dir.name}_run{k}")
        train(dataclasses.replace(config, seed=seed, bc_seed=bc_seed), run_dir,
              env_factory=env_factory)
        summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
        best = summary.get("best") or {}
        rows.append({"seed": seed, "dir": run_dir.name,
                     "best_iteration": best.get("iteration"),
                     "best_eval_success": best.get("eval_success_rate")})
        lasts.append(load_policy(run_dir / ex.FINAL_POLICY_FILE))
    avg = average_weights(lasts)
    ex.save_state(first_dir / AVERAGE_FILE, {"policy": avg.to_checkpoint()})
    sampler = SerialSampler(evaluation_env_factory(config) or env_factory
                            or default_env_factory(config))
    try:
        paths = sampler.sample(avg.snapshot(), evaluation_jobs(config, 0))
    finally:
        sampler.close()
    solved = int(sum(trajectory_success(p, config.success) for p in paths))
    return {"runs": rows, "average": {"file": f"{first_dir.name}/{AVERAGE_FILE}",
                                      "eval_successes": solved, "eval_episodes": len(paths),
                                      "eval_success": solved / len(paths) if paths else None}}
