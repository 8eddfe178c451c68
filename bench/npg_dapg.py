"""Samples to 80 % success: NPG from scratch vs DAPG with 25 demonstrations, in simulation.

    python bench/npg_dapg.py                                  # D'Claw valve, 3 seeds
    python bench/npg_dapg.py --tasks valve flip-keypoints flip-quaternion allegro-valve
    python bench/npg_dapg.py --quick                          # smoke run, tiny budget
    python bench/npg_dapg.py --record                         # append a section to bench/RESULTS.md

For every task, algorithm and seed it trains until the training (stochastic-policy) success rate
first reaches ``--target`` (0.8) and then ``--extra-iters`` more iterations, or until
``--max-samples``. It prints the samples (and robot-equivalent hours at the 10 Hz control rate)
at which the target was first reached, the final training success rate (mean of the last three
iterations) and the final deterministic evaluation success rate, and the ratio
NPG samples / DAPG samples (median over seeds; a lower bound "> x" when NPG did not reach the
target within the budget). The target ratio is >= 5x (BAIR hardware: ~9 h vs < 3 h; hand_dapg:
up to 30x on Adroit).

Demonstrations: on the D'Claw and Allegro valves, 25 episodes of the scripted teachers
(``lowcostdex.sim.scripted``: ``ValveTurnTeacher``, ``AllegroValveTeacher``), written as the demo
dataset (``lowcostdex.demo_file``, ``<out>/<task>/demos.h5``). Tasks without a scripted teacher use a "computational expert" as the DAPG paper did for the pen:
the mean action of this benchmark's NPG policy for seed 0, provided that mean action solves the
task at the end of its run (``--expert-run DIR`` names another run); only successful expert
episodes are kept.
Both algorithms share every RL setting (the trainer's defaults: 40 trajectories per iteration,
delta 0.1, damping 1e-2, gamma 0.995, GAE 0.97, (32, 32) policy, init log-std -0.5); DAPG adds
BC and the decaying demo term. DAPG defaults here: the teacher's demonstrations are recorded
with +-0.1 executed-action noise and clean labels (as the DAPG authors injected actuator noise),
BC runs 100 epochs and sets the exploration noise to the clone's residual. mjrl's settings
(clean demos, 5 BC epochs, noise = demo action spread) are
``--demo-noise 0 --bc-epochs 5 --bc-log-std demo_spread``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import platform
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

import lowcostdex  # noqa: F401  (registers the env ids)
from lowcostdex.algos import experiment as ex
from lowcostdex.algos.demos import save_demos, teacher_episodes
from lowcostdex.algos.npg import NPGConfig
from lowcostdex.algos.policy import PolicyConfig
from lowcostdex.algos.train import TrainConfig, load_policy, train
from lowcostdex.demo_file import DatasetInfo


@dataclass(frozen=True)
class Task:
    env_id: str
    teacher: str | None  # class name in lowcostdex.sim.scripted, or None (NPG expert)


TASKS = {
    "valve": Task("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher"),
    "flip-keypoints": Task("lowcostdex/DClawFlipBlock-v0", None),
    "flip-quaternion": Task("lowcostdex/DClawFlipBlockQuaternion-v0", None),
    "allegro-valve": Task("lowcostdex/AllegroTurnValve-v0", "AllegroValveTeacher"),
}


class ScriptedTeacher:
    """A scripted teacher of ``lowcostdex.sim.scripted`` as a demo-recording policy
    (env, obs) -> action: its joint goals for the observed state, as normalized actions."""

    def __init__(self, name: str) -> None:
        from lowcostdex.sim import scripted

        self.teacher = getattr(scripted, name)()

    def reset(self, env: gym.Env) -> None:
        self.teacher.reset(env.unwrapped)

    def __call__(self, env: gym.Env, obs: np.ndarray) -> np.ndarray:
        from lowcostdex.sim.envs import goal_to_action

        u = env.unwrapped
        goals = self.teacher(u.backend.observed_qpos(), u.goal)
        return goal_to_action(goals, u.task.hand_low, u.task.hand_high)


class PolicyTeacher:
    """A trained policy's mean action as the teacher."""

    def __init__(self, run_dir: Path) -> None:
        self.snapshot = load_policy(run_dir).snapshot()

    def __call__(self, env: gym.Env, obs: np.ndarray) -> np.ndarray:
        return np.clip(self.snapshot.mean(obs), -1.0, 1.0)


def base_config(args: argparse.Namespace, env_id: str, seed: int) -> TrainConfig:
    horizon = gym.spec(env_id).max_episode_steps or 40
    return TrainConfig(
        env_id=env_id,
        seed=seed,
        n_iter=max(1, args.max_samples // (args.n_traj * horizon)),
        n_traj=args.n_traj,
        gamma=args.gamma,
        gae_lambda=args.gae_lambda,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        policy=PolicyConfig(hidden_sizes=tuple(args.hidden), init_log_std=args.init_log_std),
        npg=NPGConfig(step_size=args.step_size, damping=args.damping),
        progress=False,
    )


def samples_to_target(
    m: dict[str, np.ndarray], target: float, key: str = ex.SUCCESS_RATE
) -> tuple[float, float]:
    """(samples, robot hours) at the first iteration whose ``key`` success >= target."""
    hit = np.flatnonzero(np.nan_to_num(m[key], nan=-1.0) >= target)
    if hit.size == 0:
        return math.nan, math.nan
    return float(m[ex.SAMPLES][hit[0]]), float(m[ex.ROBOT_HOURS][hit[0]])


def run_one(config: TrainConfig, out: Path, target: float, extra: int) -> dict[str, float]:
    if out.exists():
        shutil.rmtree(out)
    reached: list[int] = []

    def until(row: dict[str, float]) -> bool:
        if not reached and row[ex.SUCCESS_RATE] >= target:
            reached.append(int(row[ex.ITERATION]))
        return bool(reached) and row[ex.ITERATION] >= reached[0] + extra

    t0 = time.perf_counter()
    m = train(config, out, until=until).read_metrics()
    samples, hours = samples_to_target(m, target)
    eval_samples, _ = samples_to_target(m, target, ex.EVAL_SUCCESS_RATE)
    return {
        "samples_to_target": samples,
        "robot_hours_to_target": hours,
        "eval_samples_to_target": eval_samples,
        "final_success": float(np.mean(m[ex.SUCCESS_RATE][-3:])),
        "final_eval_success": float(m[ex.EVAL_SUCCESS_RATE][-1]),
        "samples_used": float(m[ex.SAMPLES][-1]),
        "wall_seconds": time.perf_counter() - t0,
    }


def record_demos(
    task: Task, out: Path, n: int, npg_expert: Path | None, noise: float
) -> Path | None:
    env = gym.make(task.env_id)
    if task.teacher is not None:
        teacher = ScriptedTeacher(task.teacher)
    elif npg_expert is not None:
        teacher = PolicyTeacher(npg_expert)
    else:
        return None
    episodes = teacher_episodes(env, teacher, seeds=range(10_000, 10_000 + n), action_noise=noise)
    source = "policy" if isinstance(teacher, PolicyTeacher) else "scripted_teacher"
    info = DatasetInfo.from_env(env, source)
    env.close()
    return save_demos(out / "demos.h5", episodes, info)


def fmt_samples(x: float) -> str:
    return "not reached" if not math.isfinite(x) else f"{x / 1e3:.0f}k"


def _median(runs: list[dict[str, float]], key: str) -> float:
    samples = np.array([r[key] for r in runs])
    return float(np.median(np.where(np.isnan(samples), np.inf, samples)))


def _ratio(npg: float, dapg: float, budget: int) -> str:
    if not math.isfinite(dapg):
        return "n/a (DAPG median not reached)"
    if not math.isfinite(npg):
        return f"> {budget / dapg:.1f}x (NPG median not reached in {budget / 1e3:.0f}k)"
    return f"{npg / dapg:.1f}x"


def summarize(name: str, results: dict[str, list[dict[str, float]]], budget: int) -> list[str]:
    lines = [
        f"### {name}",
        "",
        "| algorithm | seed | samples to 80% (train) | robot h | samples to 80% (eval) "
        "| final success (train / eval) |",
        "|---|---|---|---|---|---|",
    ]
    for algo, runs in results.items():
        for seed, r in enumerate(runs):
            hours = r["robot_hours_to_target"]
            lines.append(
                f"| {algo} | {seed} | {fmt_samples(r['samples_to_target'])} | "
                f"{'-' if math.isnan(hours) else f'{hours:.2f}'} | "
                f"{fmt_samples(r['eval_samples_to_target'])} | "
                f"{r['final_success']:.2f} / {r['final_eval_success']:.2f} |"
            )
    if "npg" in results and "dapg" in results:
        for key, label in (("samples_to_target", "training"), ("eval_samples_to_target", "eval")):
            npg, dapg = _median(results["npg"], key), _median(results["dapg"], key)
            lines += [
                "",
                f"Median samples to 80% ({label} success): NPG {fmt_samples(npg)}, "
                f"DAPG {fmt_samples(dapg)}; ratio NPG/DAPG = {_ratio(npg, dapg, budget)}.",
            ]
    return lines + [""]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=["valve"], choices=sorted(TASKS))
    p.add_argument("--algos", nargs="+", default=["npg", "dapg"], choices=["npg", "dapg"])
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--max-samples", type=int, default=400_000)
    p.add_argument("--n-traj", type=int, default=40)
    p.add_argument("--n-demos", type=int, default=25)
    p.add_argument("--target", type=float, default=0.8)
    p.add_argument("--extra-iters", type=int, default=5)
    p.add_argument("--step-size", type=float, default=TrainConfig().npg.step_size)
    p.add_argument("--damping", type=float, default=TrainConfig().npg.damping)
    p.add_argument("--gamma", type=float, default=TrainConfig().gamma)
    p.add_argument("--gae-lambda", type=float, default=TrainConfig().gae_lambda)
    p.add_argument("--hidden", type=int, nargs="*", default=list(TrainConfig().policy.hidden_sizes))
    p.add_argument("--init-log-std", type=float, default=TrainConfig().policy.init_log_std)
    p.add_argument("--bc-epochs", type=int, default=100)
    p.add_argument(
        "--bc-log-std",
        default="residual",
        choices=["demo_spread", "residual", "keep"],
    )
    p.add_argument("--lam0", type=float, default=TrainConfig().dapg.lam0)
    p.add_argument("--lam1", type=float, default=TrainConfig().dapg.lam1)
    p.add_argument(
        "--demo-noise", type=float, default=0.1, help="executed-action noise while recording"
    )
    p.add_argument("--eval-every", type=int, default=5)
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--out", default="bench_runs/npg_dapg")
    p.add_argument(
        "--expert-run",
        default=None,
        help="run directory whose policy records the demos (no teacher)",
    )
    p.add_argument("--quick", action="store_true", help="tiny budget: checks the script runs")
    p.add_argument("--record", action="store_true", help="append the results to bench/RESULTS.md")
    args = p.parse_args()
    if args.quick:
        args.seeds, args.max_samples, args.n_traj, args.n_demos = 1, 3 * 8 * 40, 8, 5

    out_root = Path(args.out)
    report = [
        f"## NPG vs DAPG, samples to {args.target:.0%} success ({datetime.date.today()}, "
        f"{platform.node()}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs)",
        "",
        f"Settings: {args.n_traj} trajectories/iteration, delta {args.step_size}, damping {args.damping}, "
        f"gamma {args.gamma}, GAE {args.gae_lambda}, policy {tuple(args.hidden)}, init log-std "
        f"{args.init_log_std}, {args.n_demos} demos (recording noise {args.demo_noise}), BC "
        f"{args.bc_epochs} epochs (noise {args.bc_log_std}), DAPG lam0 {args.lam0} lam1 {args.lam1}, budget {args.max_samples / 1e3:.0f}k samples, "
        f"{args.seeds} seeds. Success = training (stochastic) policy; eval = mean action, "
        f"{args.eval_episodes} episodes.",
        "",
    ]
    for name in args.tasks:
        task = TASKS[name]
        if task.env_id not in gym.registry:
            report += [f"### {name}", "", f"skipped: {task.env_id} is not registered", ""]
            print(report[-2])
            continue
        results: dict[str, list[dict[str, float]]] = {}
        if "npg" in args.algos:
            results["npg"] = []
            for seed in range(args.seeds):
                cfg = base_config(args, task.env_id, seed)
                r = run_one(cfg, out_root / name / f"npg_{seed}", args.target, args.extra_iters)
                results["npg"].append(r)
                print(name, "npg", seed, json.dumps(r), flush=True)
        if "dapg" in args.algos:
            expert = Path(args.expert_run) if args.expert_run else out_root / name / "npg_0"
            has_expert = (expert / "policy.pt").exists() and (
                bool(args.expert_run)
                or ("npg" in results and results["npg"][0]["final_eval_success"] >= args.target)
            )
            demos = record_demos(
                task, out_root / name, args.n_demos, expert if has_expert else None, args.demo_noise
            )
            if demos is None:
                report += [
                    f"(DAPG on {name} skipped: no scripted teacher and no NPG expert reached the target)",
                    "",
                ]
            else:
                results["dapg"] = []
                for seed in range(args.seeds):
                    cfg = dataclasses.replace(
                        base_config(args, task.env_id, seed),
                        algo="dapg",
                        demos=str(demos),
                        bc=dataclasses.replace(
                            TrainConfig().bc, epochs=args.bc_epochs, log_std=args.bc_log_std
                        ),
                        dapg=dataclasses.replace(
                            TrainConfig().dapg, lam0=args.lam0, lam1=args.lam1
                        ),
                    )
                    r = run_one(
                        cfg, out_root / name / f"dapg_{seed}", args.target, args.extra_iters
                    )
                    results["dapg"].append(r)
                    print(name, "dapg", seed, json.dumps(r), flush=True)
        report += summarize(name, results, args.max_samples)
    text = "\n".join(report)
    print(text)
    if args.record:
        results_md = Path(__file__).with_name("RESULTS.md")
        with results_md.open("a", encoding="utf-8") as f:
            f.write("\n" + text + "\n")
        print(f"appended to {results_md}")


if __name__ == "__main__":
    main()
