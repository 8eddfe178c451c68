"""The transfer loop's training and evaluation of one policy: ``train_policy`` trains it in a
condition's simulation or on a robot (resuming a run cut short; a simulated policy below its
success target in its own sim at the end of its budget trains on, once, up to ``config.EXTEND``
x the iterations), ``evaluate`` runs its mean action over the cell's episodes (the same episode
seeds in every cell); with the run folders' JSON files (``read_json``, ``write_json``) and a
simulated condition's env kwargs (``sim_kwargs``). The loop is ``lowcostdex.transfer.loop``.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from lowcostdex.algos import run_files
from lowcostdex.algos.run_files import read_json
from lowcostdex.transfer.config import CPU_FILE, EVAL_SEED, Size, Task, extended_iterations
from lowcostdex.transfer.robots import HiddenRobotEnv, PortRobot


def write_json(path: Path, obj: Any) -> None:
    """A run folder's JSON file, its keys in the order written (:func:`loop.cached` hands a resumed
    run what a fresh one computed, in the same order)."""
    run_files.write_json(path, obj, sort_keys=False)


def sim_kwargs(randomize: Any, model_edit: dict[str, Any] | None) -> dict[str, Any]:
    """The env kwargs of a simulated condition's model (its effects, its MJCF edit)."""
    return {**({} if randomize is None else {"randomize": randomize}),
            **({} if model_edit is None else {"model_edit": model_edit})}


def train_policy(run_dir: Path, algo: str, task: Task, randomize: Any, demos: Path | None,
                 size: Size, seed: int, robot: Any = None, robot_seed: int | None = None,
                 model_edit: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train one policy into ``run_dir`` (resumes a run cut short); ``robot``: train on it
    (on_robot, serial sampling) instead of in simulation; ``model_edit``: the simulation's
    D'Claw edit (``sim.models.dclaw_edit.DClawEdit.to_dict()``; None: the nominal MJCF)."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import TrainConfig
    from lowcostdex.algos.train import train

    summary = run_dir / ex.SUMMARY_FILE
    extra = sim_kwargs(randomize, model_edit)
    common = dict(algo=algo, env_id=task.env_id, seed=seed, n_iter=size.n_iter,
                  n_traj=size.n_traj, eval_every=size.eval_every,
                  eval_episodes=size.eval_episodes,
                  demos=str(demos) if algo == "dapg" else None, progress=False)
    factory = None
    if robot is None:
        config = TrainConfig(**common, env_kwargs=task.make_kwargs(**extra),
                             sampler="vector", n_workers=size.n_traj)
    elif isinstance(robot, PortRobot):
        config = TrainConfig(**common, env_kwargs=task.make_kwargs(**robot.bus_kwargs()),
                             backend="hardware", sampler="serial")
    else:  # a hidden robot: its definition stays out of the run's config
        config = TrainConfig(**common, env_kwargs=task.make_kwargs(), backend="emulated",
                             sampler="serial")
        assert robot_seed is not None
        factory = HiddenRobotEnv(task.env_id, task.kwargs, robot_seed, robot.name)
    if algo == "dapg" and size.bc_epochs is not None:
        config = replace(config, bc=replace(config.bc, epochs=size.bc_epochs))
    if not summary.exists():
        resume = (run_dir / ex.CHECKPOINT_DIR / ex.LATEST_FILE).exists()
        c0 = time.process_time()  # CPU of this process (resumed: only the part run last)
        train(config, run_dir, resume=resume, env_factory=factory)
        write_json(run_dir / CPU_FILE, {"cpu_seconds": round(time.process_time() - c0, 1),
                                        "resumed": resume})
    more = extension(run_dir, size, simulated=robot is None)
    if more is not None:  # not learnt in its own sim: on from its checkpoint (config.EXTEND)
        final = read_json(summary)["final"]
        c0 = time.process_time()
        before = read_json(run_dir / CPU_FILE) if (run_dir / CPU_FILE).exists() else {}
        train(replace(config, n_iter=more), run_dir, resume=True, env_factory=factory)
        write_json(run_dir / CPU_FILE, {
            "cpu_seconds": round(before.get("cpu_seconds", 0.0) + time.process_time() - c0, 1),
            "resumed": True, "extended_to": more,
            "extended_from": {"iteration": int(final["iteration"]),
                              "eval_success_rate": float(final["eval_success_rate"]),
                              "cpu_seconds": before.get("cpu_seconds")},
            "extension_cpu_seconds": round(time.process_time() - c0, 1)})
    metrics = ex.read_metrics(run_dir / ex.METRICS_FILE)
    s = read_json(summary)
    out = {"samples": int(metrics[ex.SAMPLES][-1]),
           "wall_seconds": float(metrics[ex.WALL_SECONDS][-1]),
           "best_iteration": (s.get("best") or {}).get(ex.ITERATION),
           "final_training_success": float(metrics[ex.SUCCESS_RATE][-1])}
    if ex.ROBOT_HOURS in metrics:
        out["robot_hours"] = float(metrics[ex.ROBOT_HOURS][-1])
    if (run_dir / CPU_FILE).exists():  # runs made before it was written have none
        cpu = read_json(run_dir / CPU_FILE)
        out["cpu_seconds"] = float(cpu["cpu_seconds"])
        if "extended_to" in cpu:  # trained on under the EXTEND rule
            out["extended"] = {"to_iterations": int(cpu["extended_to"]),
                               **cpu.get("extended_from", {}),
                               "final_eval_success_rate": (s.get("final") or {}).get(
                                   "eval_success_rate"),
                               "extension_cpu_seconds": cpu.get("extension_cpu_seconds")}
    return out


def extension(run_dir: Path, size: Size, simulated: bool = True) -> int | None:
    """The iterations a finished run in ``run_dir`` still trains to under the EXTEND rule
    (``config.extended_iterations``), or None: only simulated runs (on_robot keeps its robot
    time) of a size with in-training evaluations (not smoke: its budget is fixed), once. A
    folder made before the rule holds finished runs below their target: they extend when it
    is resumed, and their evaluation cells (of the shorter policy) must then be redone."""
    from lowcostdex.algos import experiment as ex

    summary = run_dir / ex.SUMMARY_FILE
    if not (simulated and size.eval_every and summary.exists()):
        return None
    return extended_iterations(read_json(summary), size.n_iter)


def evaluate(run_dir: Path, task: Task, env_kwargs: dict[str, Any], episodes: int
             ) -> dict[str, Any]:
    """Mean-action episodes of the run's policy; the same episode seeds for every cell."""
    import gymnasium as gym

    import lowcostdex.sim  # noqa: F401  (registers the ids)
    from lowcostdex.algos.samplers import RolloutJob, rollout
    from lowcostdex.algos.train import load_policy

    policy = load_policy(run_dir, env=task.env_id).snapshot()
    env = gym.make(task.env_id, **task.make_kwargs(**env_kwargs))
    t0 = time.perf_counter()
    try:
        paths = [rollout(env, policy, RolloutJob(EVAL_SEED, 0, 0, i, deterministic=True))
                 for i in range(episodes)]
    finally:
        env.close()
    return {"successes": int(sum(bool(p.successes[-1]) for p in paths)), "episodes": episodes,
            "solved": [bool(p.successes[-1]) for p in paths],
            "final_error": [round(float(p.final_goal_error), 4) for p in paths],
            "wall_seconds": round(time.perf_counter() - t0, 1)}
