"""Several behaviour clones from the same demonstrations; DAPG starts from the one that
validates best.

From the same demonstrations and at the same BC loss, the clone's seed alone (network
initialisation, minibatch order) moved the main job's clone from 1 to 16 of 40 held-out robot
episodes (bench/RESULTS.md, "Main job leftovers"): one clone is a draw. Fitting a few clones
costs seconds of CPU and judging them in the simulation DAPG trains in costs no robot time, so
the main job fits ``candidates`` clones and hands DAPG the best on their own validation
episodes: the clone stream (``samplers.BC_EVAL_STREAM``), disjoint from the episodes that then
choose DAPG's policy (``EVAL_STREAM``, the chosen clone competing there again on fresh episodes)
and from the held-out episodes on which the report compares them (``HELDOUT_STREAM``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

CLONE_SEED_KEY = 20
"""Spawn key of the candidate clones' seeds (``SeedSequence(seed, spawn_key=(20, i))``)."""


def clone_seeds(seed: int, candidates: int) -> list[int]:
    """The candidates' BC seeds: ``seed`` itself first (a single candidate is the clone every
    run fitted before), then seeds drawn from ``seed``."""
    extra = [int(np.random.SeedSequence(seed, spawn_key=(CLONE_SEED_KEY, i))
                 .generate_state(1, np.uint32)[0] >> 1) for i in range(1, candidates)]
    return [seed, *extra]


def rank_key(candidate: dict[str, Any]) -> tuple[float, float]:
    """Most validation successes first, then the smallest median final ``|goal_error|``."""
    err = candidate.get("median_final_error")
    return (-candidate["successes"], err if err is not None and np.isfinite(err) else np.inf)


def choose_clone(config: Any, candidates: int, episodes: int,
                 keep: dict[int, Any] | None = None) -> dict[str, Any]:
    """Fit ``candidates`` clones for ``config`` (a DAPG ``TrainConfig``; its env, demos and BC
    settings) and judge each on the same ``episodes`` deterministic episodes of ``config``'s env
    (``BC_EVAL_STREAM`` at ``config.seed``, mean action).

    Returns ``{"bc_seed": chosen, "candidates": [{"bc_seed", "successes", "episodes",
    "median_final_error", "bc_loss"}...], "seconds", "cpu_seconds", "samples"}``. With ``keep``
    each candidate's policy is stored there by its BC seed.
    """
    import dataclasses

    import torch

    from lowcostdex.algos.samplers import BC_EVAL_STREAM, SerialSampler, make_jobs
    from lowcostdex.algos.train import clone_policy, default_env_factory, trajectory_success
    from lowcostdex.demonstrations.dataset import load_demos

    t0, c0 = time.perf_counter(), time.process_time()
    demos = load_demos(config.demos).first(config.n_demos)
    jobs = make_jobs(config.seed, BC_EVAL_STREAM, 0, episodes, deterministic=True)
    sampler = SerialSampler(default_env_factory(config))
    rows, steps = [], 0
    threads = torch.get_num_threads()
    torch.set_num_threads(config.torch_threads)
    try:
        for s in clone_seeds(config.seed, candidates):
            policy, stats = clone_policy(dataclasses.replace(config, bc_seed=s), sampler.env,
                                         demos)
            if keep is not None:
                keep[s] = policy
            paths = sampler.sample(policy.snapshot(), jobs)
            steps += sum(len(p) for p in paths)
            errors = [float(p.final_goal_error) for p in paths]
            rows.append({"bc_seed": s, "episodes": len(paths),
                         "successes": int(sum(trajectory_success(p, config.success)
                                              for p in paths)),
                         "median_final_error": (float(np.median(errors))
                                                if np.all(np.isfinite(errors)) else None),
                         "bc_loss": float(stats["bc_loss_after"])})
    finally:
        torch.set_num_threads(threads)
        sampler.close()
    best = min(rows, key=rank_key)
    return {"bc_seed": best["bc_seed"], "candidates": rows, "samples": steps,
            "seconds": round(time.perf_counter() - t0, 1),
            "cpu_seconds": round(time.process_time() - c0, 1)}
