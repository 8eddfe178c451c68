"""Which main-job variant lets the RL stage show a gain over the behaviour clone? (issue 13)

For each seed: record demonstrations on the emulated D'Claw as the main job's demos stage does
(virtual teacher, servo-response labels, noisy playbacks), run DAPG for the given budget on the
same robot, then evaluate the behaviour clone (rebuilt exactly as DAPG's iteration 0: same seed)
and DAPG's final policy on the same ``--eval`` held-out episode seeds (mean action), recording
each episode's final |goal error|, so that success at other thresholds can be read off too.

    python bench/main_job_variants.py --out /tmp/variants --seeds 0 1 2 --eval 20 \\
        --task '{"init_range": 0.5}' --demos 20 --iters 8 --traj 20

Prints one line per seed and appends a JSON line per seed to ``--out``/results.jsonl. NPG is
not run here (the main job's NPG from scratch has not turned the valve at these budgets).
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np

THRESHOLDS = (0.15, 0.1, 0.07, 0.05, 0.03)
"""Final |goal error| thresholds [rad] read off the evaluation episodes."""
EVAL_STREAM = 7
"""Seed stream of this script's evaluation episodes (train.py uses 0-2)."""


def record(path: Path, env_id: str, env_kwargs: dict[str, Any], n: int, playbacks: int,
           playback_noise: float, teacher_noise: float, seed: int) -> dict[str, Any]:
    import dataclasses

    import gymnasium as gym

    import lowcostdex  # noqa: F401
    from lowcostdex.demonstrations.kinesthetic import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.main_job.stages import SERVO_ID_EPISODES
    from lowcostdex.teachers import teacher_class

    env = gym.make(env_id, **env_kwargs)
    try:
        solver = teacher_class("ValveTurnTeacher")()
        # the main job's hand (FIRM_HAND for the valve teacher); until 2026-11-26 06:40 this
        # script used the soft default hand, so its clones were weaker than the main job's
        hand = dataclasses.replace(virtual_teacher_config(solver), target_noise=teacher_noise)
        teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task, solver=solver,
                                 config=hand,
                                 rng=np.random.default_rng(seed))
        response, _ = identify_servo_response(env, episodes=SERVO_ID_EPISODES,
                                              seed=seed + 1_000_000)
        rec = KinestheticRecorder(env, path, env_id, teacher=teacher, response=response,
                                  playbacks=playbacks, playback_noise=playback_noise,
                                  rng=np.random.default_rng(seed))
        stats = rec.record(n, seed=seed)
    finally:
        env.close()
    return {"demos": stats.episodes, "successful": stats.successes,
            "playbacks": stats.playbacks, "successful_playbacks": stats.playback_successes}


def evaluate(sampler: Any, policy: Any, seed: int, episodes: int) -> list[float]:
    from lowcostdex.algos.samplers import make_jobs

    paths = sampler.sample(policy.snapshot(), make_jobs(seed, EVAL_STREAM, 0, episodes,
                                                        deterministic=True))
    return [float(p.final_goal_error) for p in paths]


def rates(errors: list[float]) -> dict[str, int]:
    return {f"{t:g}": int(sum(e < t for e in errors)) for t in THRESHOLDS}


def run_seed(args: argparse.Namespace, seed: int) -> dict[str, Any]:
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import (
        BCConfig,
        DAPGConfig,
        NPGConfig,
        PolicyConfig,
        TrainConfig,
    )
    from lowcostdex.algos.policy import GaussianMLPPolicy
    from lowcostdex.algos.samplers import SerialSampler
    from lowcostdex.algos.train import _init_state, default_env_factory, train
    from lowcostdex.demonstrations.dataset import load_demos
    from lowcostdex.main_job.setup import Context

    out = args.out / f"seed{seed}"
    out.mkdir(parents=True, exist_ok=True)
    env_kwargs = {**Context(out=out).env_kwargs(), **args.task}
    t0 = time.perf_counter()
    demos_file = out / "demos.h5"
    stats_file = out / "demos.json"
    if not stats_file.exists():  # a re-run evaluates what an interrupted one left
        demos_file.unlink(missing_ok=True)
        stats_file.write_text(json.dumps(record(
            demos_file, args.env, env_kwargs, args.demos, args.playbacks, args.playback_noise,
            args.teacher_noise, seed)))
    demo_stats = json.loads(stats_file.read_text())
    t1 = time.perf_counter()
    kwargs = dict(env_kwargs)
    backend = kwargs.pop("backend")
    config = TrainConfig(algo="dapg", env_id=args.env, backend=backend, env_kwargs=kwargs,
                         seed=seed, n_iter=args.iters, n_traj=args.traj, eval_every=0,
                         eval_episodes=1, demos=str(demos_file), progress=False,
                         dapg=DAPGConfig(lam0=args.lam0),
                         policy=PolicyConfig(hidden_sizes=(32, 32), init_log_std=(
                             math.log(args.std) if args.std else -1.0)),
                         bc=BCConfig(epochs=100, log_std="keep" if args.std else "residual"),
                         npg=NPGConfig(step_size=args.step_size, damping=1e-2))
    if not (out / "train_dapg" / "final_policy.pt").exists():
        shutil.rmtree(out / "train_dapg", ignore_errors=True)
        train(config, out / "train_dapg")
    metrics = ex.read_metrics(out / "train_dapg" / ex.METRICS_FILE)
    t2 = time.perf_counter()
    sampler = SerialSampler(default_env_factory(config))
    try:
        demos = load_demos(config.demos)
        state, _ = _init_state(config, sampler.env, demos)
        bc_err = evaluate(sampler, state.policy, seed, args.eval)
        final = GaussianMLPPolicy.from_checkpoint(
            ex.load_state(out / "train_dapg" / "final_policy.pt")["policy"])
        dapg_err = evaluate(sampler, final, seed, args.eval)
    finally:
        sampler.close()
    t3 = time.perf_counter()
    return {"seed": seed, "task": args.task, "demos_requested": args.demos,
            "playbacks_each": args.playbacks, "playback_noise": args.playback_noise,
            "teacher_noise": args.teacher_noise, "iters": args.iters, "traj": args.traj,
            "lam0": args.lam0, "step_size": args.step_size, "std": args.std,
            **demo_stats, "eval": args.eval, "bc": rates(bc_err), "dapg": rates(dapg_err),
            "bc_err": [round(e, 4) for e in bc_err], "dapg_err": [round(e, 4) for e in dapg_err],
            "train_success": [round(float(x), 2) for x in metrics["success_rate"]],
            "samples": int(metrics["samples"][-1]),
            "seconds": {"demos": round(t1 - t0), "dapg": round(t2 - t1),
                        "eval": round(t3 - t2)}}


def main() -> None:
    import torch

    torch.set_num_threads(1)  # small networks; 2 threads on a busy 2-core VM are far slower
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--env", default="lowcostdex/DClawTurnValve-v0")
    p.add_argument("--task", type=json.loads, default={},
                   help="TurnConfig overrides as JSON, e.g. '{\"init_range\": 0.5}'")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--demos", type=int, default=20)
    p.add_argument("--playbacks", type=int, default=2)
    p.add_argument("--playback-noise", type=float, default=0.05)
    p.add_argument("--teacher-noise", type=float, default=0.0)
    p.add_argument("--iters", type=int, default=8)
    p.add_argument("--traj", type=int, default=20)
    p.add_argument("--eval", type=int, default=20)
    p.add_argument("--lam0", type=float, default=0.1, help="DAPG's initial demo weight")
    p.add_argument("--step-size", type=float, default=0.1, help="the NPG step's delta")
    p.add_argument("--std", type=float, default=0.0,
                   help="exploration std after BC [action units] (0: the clone's residual)")
    args = p.parse_args()
    for seed in args.seeds:
        r = run_seed(args, seed)
        with open(args.out / "results.jsonl", "a") as f:
            f.write(json.dumps(r) + "\n")
        print(f"seed {seed}: demos {r['successful']}/{r['demos']} (playbacks "
              f"{r['successful_playbacks']}/{r['playbacks']}); of {r['eval']}: "
              f"BC {r['bc']}, DAPG {r['dapg']}; training success {r['train_success']}; "
              f"{r['seconds']}", flush=True)


if __name__ == "__main__":
    main()
