"""DAPG trained in simulation from the main job's demonstrations, judged on the emulated robot
(issue 13 item 3).

The main job's train stage runs DAPG on the emulated D'Claw (every sample through the
dynamixel_sdk code path and the emulated servos), where 12 x 20 episodes add nothing measurable
over the behaviour clone (bench/RESULTS.md, "The RL stage in the main job"). This script asks
whether the same demonstrations, cloned the same way, improve when DAPG samples the plain MuJoCo
task instead (optionally with domain randomization over the effect catalogue), which runs many
times faster:

1. ``throughput``: samples/s of the emulated robot env and of the sim env of the same task
   (the same random Gaussian policy, ``--episodes`` episodes each, wall and process CPU time).
2. ``train``: DAPG from ``DIR/demos.h5`` (a main-job output folder: ``lowcostdex main --stages
   bus,demos``) on the sim backend, the main job's DAPG settings except the budget; validation in
   sim on one fixed episode set (``eval_paired``) with the clone competing; then the clone
   (``bc_policy.pt``), the run's policy and its final iterate on the main job's held-out
   episodes of the emulated robot (``HELDOUT_STREAM``, the reset seeds the main job's report
   uses) and on ``--sim-heldout`` held-out episodes in sim. Success: final |goal error| < the
   task's tolerance (``info["success"]`` at the last step), mean action.

3. ``candidates``: the main job's DAPG stage as it trains (best of six clones, 30 x 40 in the
   randomized sim), every evaluated iterate kept; each final candidate (the clone, iterations 9,
   19, 29) on ``--robot-val`` robot validation episodes (their own seed stream,
   ``ROBOT_VALIDATION_STREAM``) and on the 100 held-out ones. ``evaluate``: the same on a
   finished run folder, the robot-validated choice and the clone first.

4. ``streams``: the main job's DAPG stage ``--runs`` times from the same chosen clone, each run
   its own seed (randomization draws, training episodes; ``main_job.streams.stream_seeds``),
   every iterate from ``--avg-from`` on kept; on the held-out robot episodes the clone, each
   run's policy and the averages over the runs (weights of the last iterates: ``soupK``; their
   mean action: ``ensK``; weights of the iterates from ``--avg-from`` on: ``swa0``,
   ``swa_soupK``). ``--config`` overrides TrainConfig fields (e.g. ``{"n_traj": 120}``).

    python bench/main_job_sim.py throughput --episodes 20
    python bench/main_job_sim.py train --demos /tmp/mj_s0 --seed 0 --iters 30 --traj 40 \\
        --out /tmp/sim_dapg [--randomize default|robot]
    python bench/main_job_sim.py candidates --demos /tmp/mj_s0 --seed 0 --robot-val 40 \\
        --out /tmp/cand
    python bench/main_job_sim.py evaluate --run /tmp/cand/cand_s1_i30 --seed 1 --robot-val 20
    python bench/main_job_sim.py streams --demos /tmp/mj_s0 --seed 0 --runs 3 --out /tmp/st \\
        --only clone run0 soup3 ens3 swa_soup3

Prints one JSON line per run and appends it to ``--out``/results.jsonl. Paired statistics:
exact one-sided McNemar (binomial test on the episodes only one policy solved) and one-sided
Wilcoxon signed-rank on the final errors; 95 % Wilson intervals.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

RANDOMIZE = ("none", "default", "robot", "truth")
"""``--randomize``: none (the nominal sim), default (every effect of the catalogue's default
domain randomization, ``DEFAULT_DR_EFFECTS``, at its catalogue range), robot (latency, backlash
and Coulomb friction, the kinds of effect the main job's gap stage names, at their catalogue
ranges), truth (the emulated robot's own effects, ``main_job.setup.robot_effects``, every
episode: what a sim extended by a perfect gap analysis would be; an upper bound, not a recipe)."""



def _record(path: Path, res: dict, hide=lambda key: False) -> None:
    """Append ``res`` as one JSON line to ``path`` (its folder made if missing) and print it
    without the keys ``hide`` names (the per-episode lists)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(res) + "\n")
    print(json.dumps({k: v for k, v in res.items() if not hide(k)}), flush=True)

def sim_kwargs(randomize: str) -> dict[str, Any]:
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.main_job.setup import TASKS
    from lowcostdex.sim.effects.randomization import DEFAULT_DR_EFFECTS

    kw: dict[str, Any] = {**TASKS["valve-target"].env_overrides, "backend": "sim"}
    if randomize == "default":
        kw["randomize"] = list(DEFAULT_DR_EFFECTS)
    elif randomize == "robot":
        kw["randomize"] = {"effects": ["latency", "backlash", "coulomb_friction"],
                           "joints": list(dclaw_spec().joint_names)}
    elif randomize == "truth":
        from lowcostdex.main_job.setup import robot_effects

        joints = dclaw_spec().joint_names
        fixed = {e.name: {p: (float(v[0]), float(v[0])) for p, v in e.values.items()}
                 for e in robot_effects(joints)}
        kw["randomize"] = {"effects": list(fixed), "joints": list(joints), "ranges": fixed}
    return kw


def robot_kwargs() -> dict[str, Any]:
    from lowcostdex.main_job.setup import Context

    return Context(out=Path(".")).env_kwargs()


SIM_CHOICES = ("main", "gap", "gap+dr")
"""``candidates --sim``: main (the main job's randomized sim, ``DAPG_RANDOMIZE`` at the
catalogue's ranges), gap (the gap stage's identified effects only, each parameter drawn from its
fitted range: ``gap.extension.dr_ranges``, the 95 % interval widened to +-10 % of the value, on
every hand joint; a parameter the analysis held, whose interval is unbounded, stays at its
value), gap+dr (the main job's randomization with the identified effects' ranges replaced by
those fitted ranges)."""


def gap_randomization(report: Path, sim: str) -> dict[str, Any]:
    """The DomainRandomization dict of ``--sim gap|gap+dr`` from a gap report folder (its
    ``extended/``): every effect the analysis identified, on every hand joint (the gap stage
    identifies one finger; the others have the same servos), each parameter drawn from its
    fitted range (``gap.extension.dr_ranges``: the 95 % interval widened to at least +-10 % of
    the value); a parameter the analysis held at a value (an unbounded interval) stays at that
    value. gap+dr: the main job's effects (``DAPG_RANDOMIZE``) with those ranges."""
    from lowcostdex.gap.extension import load_extended
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.main_job.setup import DAPG_RANDOMIZE
    from lowcostdex.sim.effects import DomainRandomization

    extended = Path(report) / "extended"
    ext = load_extended(extended)
    if not ext.ranges:
        raise SystemExit(f"{report}: the gap analysis identified no effect")
    ranges = {k: dict(v) for k, v in ext.ranges.items()}
    for e in json.loads((extended / "effects.json").read_text())["effects"]:
        for p, iv in (e.get("interval") or {}).items():
            if not np.all(np.isfinite(np.asarray(iv, float))):
                v = np.asarray(e["params"][p], float)
                ranges[e["effect"]][p] = (float(v.min()), float(v.max()))
    effects = tuple(ranges) if sim == "gap" else DAPG_RANDOMIZE
    ranges = {k: v for k, v in ranges.items() if k in effects}  # others are not randomized
    return DomainRandomization(effects, tuple(dclaw_spec().joint_names), ranges).to_dict()


ROBOT_VALIDATION_STREAM = 4
"""Seed stream of the robot validation episodes (``samplers`` uses 0-3: training, validation,
the clone's validation, held-out)."""


def candidate_files(run_dir: Path) -> dict[int, Path]:
    """The clone (iteration -1) and each evaluated iterate whose checkpoint is still in
    ``run_dir/checkpoints`` (``metrics.csv``'s rows with a validation), by iteration."""
    from lowcostdex.algos import experiment as ex

    metrics = ex.read_metrics(run_dir / ex.METRICS_FILE)
    out = {-1: run_dir / ex.BC_POLICY_FILE}
    for it, val in zip(metrics[ex.ITERATION], metrics[ex.EVAL_SUCCESS_RATE], strict=True):
        f = run_dir / ex.CHECKPOINT_DIR / f"ckpt_{int(it):06d}.pt"
        if math.isfinite(float(val)) and f.is_file():
            out[int(it)] = f
    return out


def choose_finalist(files: dict[int, Path], make_env: Any, seed: int,
                    episodes: int) -> dict[str, Any]:
    """Each candidate (``files``: iteration -> policy file) on the same ``episodes``
    deterministic robot validation episodes (``ROBOT_VALIDATION_STREAM`` at ``seed``, mean
    action), each on a freshly started robot from ``make_env`` (``main_job.heldout``); the
    chosen one by ``main_job.clones.rank_key`` (most successes, then the smallest median final
    |goal error|; the earlier iterate, the clone first, on a full tie)."""
    from lowcostdex.algos.samplers import make_jobs
    from lowcostdex.algos.train import load_policy, trajectory_success
    from lowcostdex.main_job.clones import rank_key
    from lowcostdex.main_job.heldout import evaluate as evaluate_on_robot

    t0, c0 = time.perf_counter(), time.process_time()
    jobs = make_jobs(seed, ROBOT_VALIDATION_STREAM, 0, episodes, deterministic=True)
    runs = evaluate_on_robot(make_env, {it: load_policy(files[it]).snapshot()
                                        for it in sorted(files)}, jobs, fresh=True)
    rows, robot_seconds = [], 0.0
    for it, paths in runs.items():
        robot_seconds += sum(p.robot_seconds for p in paths)
        errors = [float(p.final_goal_error) for p in paths]
        rows.append({"iteration": it, "episodes": len(paths),
                     "successes": int(sum(trajectory_success(p, "final") for p in paths)),
                     "median_final_error": float(np.median(errors)),
                     "solved": [bool(trajectory_success(p, "final")) for p in paths],
                     "errors": errors})
    best = min(rows, key=rank_key)
    return {"iteration": best["iteration"], "candidates": rows,
            "robot_seconds": round(robot_seconds, 1),
            "seconds": round(time.perf_counter() - t0, 1),
            "cpu_seconds": round(time.process_time() - c0, 1)}


def throughput(episodes: int) -> list[dict[str, Any]]:
    from lowcostdex.algos.configs import PolicyConfig
    from lowcostdex.algos.policy import GaussianMLPPolicy
    from lowcostdex.algos.samplers import EnvFactory, SerialSampler, make_jobs
    from lowcostdex.main_job.setup import TASKS

    env_id = TASKS["valve-target"].env_id
    out = []
    for name, kw in (("emulated robot", robot_kwargs()), ("sim", sim_kwargs("none")),
                     ("sim + default randomization", sim_kwargs("default"))):
        sampler = SerialSampler(EnvFactory(env_id, kw))
        env = sampler.env
        policy = GaussianMLPPolicy(env.observation_space.shape[0], env.action_space.shape[0],
                                   PolicyConfig(hidden_sizes=(32, 32), init_log_std=-1.0),
                                   torch.Generator().manual_seed(0))
        snap = policy.snapshot()
        sampler.sample(snap, make_jobs(0, 0, 99, 1))  # warm up
        t0, c0 = time.perf_counter(), time.process_time()
        paths = sampler.sample(snap, make_jobs(0, 0, 0, episodes))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        sampler.close()
        steps = sum(len(p) for p in paths)
        row = {"env": name, "episodes": episodes, "steps": steps, "wall_s": round(wall, 2),
               "cpu_s": round(cpu, 2), "samples_per_s_wall": round(steps / wall, 1),
               "samples_per_cpu_s": round(steps / cpu, 1),
               "robot_s": round(sum(p.robot_seconds for p in paths), 1)}
        print(json.dumps(row), flush=True)
        out.append(row)
    return out


def heldout(env_id: str, kwargs: dict[str, Any], policies: dict[str, Path], seed: int,
            episodes: int, stream: int | None = None) -> dict[str, dict[str, Any]]:
    """Each policy's mean action on the same ``episodes`` held-out episodes (reset seeds of
    ``HELDOUT_STREAM`` at ``seed``, the main job's), each on a freshly started robot (as the
    main job: ``main_job.heldout``, so a policy's results do not depend on the order)."""
    from lowcostdex.algos.samplers import HELDOUT_STREAM, EnvFactory, make_jobs
    from lowcostdex.algos.train import load_policy, trajectory_success
    from lowcostdex.main_job.heldout import evaluate

    jobs = make_jobs(seed, HELDOUT_STREAM if stream is None else stream, 0, episodes,
                     deterministic=True)
    snaps = {name: load_policy(path).snapshot() for name, path in policies.items()}
    runs = evaluate(EnvFactory(env_id, kwargs), snaps, jobs, fresh=True)
    out = {}
    for name, paths in runs.items():
        out[name] = {"solved": [trajectory_success(p, "final") for p in paths],
                     "errors": [float(p.final_goal_error) for p in paths]}
        out[name]["successes"] = int(sum(out[name]["solved"]))
    return out


def paired(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """Paired comparison of ``after`` against ``before`` on the same episodes."""
    from scipy.stats import binomtest, wilcoxon

    from lowcostdex.stats import wilson_interval

    a, b = np.array(before["solved"]), np.array(after["solved"])
    only_after, only_before = int(np.sum(b & ~a)), int(np.sum(a & ~b))
    n = only_after + only_before
    p = binomtest(only_after, n, 0.5, alternative="greater").pvalue if n else 1.0
    ea, eb = np.array(before["errors"]), np.array(after["errors"])
    w = (float(wilcoxon(eb, ea, alternative="less").pvalue) if np.any(ea != eb) else 1.0)
    k = len(a)
    return {"before": int(a.sum()), "after": int(b.sum()), "n": k,
            "before_ci": [round(x, 3) for x in wilson_interval(int(a.sum()), k)],
            "after_ci": [round(x, 3) for x in wilson_interval(int(b.sum()), k)],
            "only_after": only_after, "only_before": only_before,
            "mcnemar_p": round(float(p), 4), "median_err_before": round(float(np.median(ea)), 4),
            "median_err_after": round(float(np.median(eb)), 4), "wilcoxon_p": round(w, 4)}


def train_in_sim(a: argparse.Namespace) -> dict[str, Any]:
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import DAPGConfig, TrainConfig
    from lowcostdex.algos.train import train
    from lowcostdex.main_job.setup import DAPG_LAM0, TASKS

    env_id = TASKS["valve-target"].env_id
    kw = sim_kwargs(a.randomize)
    backend = kw.pop("backend")
    config = TrainConfig(algo="dapg", env_id=env_id, backend=backend, env_kwargs=kw,
                         seed=a.seed, n_iter=a.iters, n_traj=a.traj, eval_every=a.eval_every,
                         eval_episodes=a.val, demos=str(a.demos / "demos.h5"), eval_bc=True,
                         dapg=DAPGConfig(lam0=DAPG_LAM0), eval_paired=True, progress=False)
    if a.config:  # overrides of the TrainConfig fields (nested configs merged), for screens
        d = dataclasses.asdict(config)
        for k, v in a.config.items():
            d[k] = {**d[k], **v} if isinstance(v, dict) else v
        config = TrainConfig.from_dict(d)
    tag = f"{a.randomize}_i{a.iters}_t{a.traj}_v{a.val}_s{a.seed}{a.tag}"
    run_dir = a.out / tag
    shutil.rmtree(run_dir, ignore_errors=True)
    factory = None
    if a.ramp:  # the training reward with main_job.shaping's goal ramp (weight, radius)
        from lowcostdex.algos.train import default_env_factory
        from lowcostdex.main_job.shaping import GoalRamp, ShapedEnvFactory

        factory = ShapedEnvFactory(default_env_factory(config), GoalRamp(*a.ramp))
    t0 = time.perf_counter()
    train(config, run_dir, env_factory=factory)
    train_s = time.perf_counter() - t0
    m = ex.read_metrics(run_dir / ex.METRICS_FILE)
    summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
    final = run_dir / ex.FINAL_POLICY_FILE
    policies = {"clone": run_dir / ex.BC_POLICY_FILE, "chosen": run_dir, "final": final}
    t1 = time.perf_counter()
    sim = heldout(env_id, sim_kwargs("none"), policies, a.seed, a.sim_heldout)
    sim_s = time.perf_counter() - t1
    t1 = time.perf_counter()
    robot = (heldout(env_id, robot_kwargs(), policies, a.seed, a.heldout) if a.heldout
             else {k: {"solved": [], "errors": [], "successes": 0} for k in policies})
    robot_s = time.perf_counter() - t1
    best = summary.get("best") or {}
    res = {"tag": tag, "seed": a.seed, "randomize": a.randomize, "iters": a.iters,
           "traj": a.traj, "validation_episodes": a.val,
           "samples": int(m["samples"][-1]), "chosen_iteration": best.get("iteration"),
           "validation": {int(i): round(float(v), 3) for i, v in
                          zip(m["iteration"], m["eval_success_rate"], strict=True)
                          if math.isfinite(v)},
           "clone_validation": json.loads((run_dir / "bc.json").read_text())
           ["eval_success_rate"],
           "train_success": [round(float(x), 2) for x in m["success_rate"]],
           "sim": {"clone": sim["clone"]["successes"], "chosen_vs_clone":
                   paired(sim["clone"], sim["chosen"]),
                   "final_vs_clone": paired(sim["clone"], sim["final"])} if a.sim_heldout
           else None,
           "robot": {"clone": robot["clone"]["successes"], "chosen_vs_clone":
                     paired(robot["clone"], robot["chosen"]),
                     "final_vs_clone": paired(robot["clone"], robot["final"])} if a.heldout
           else None,
           "config": a.config, "ramp": a.ramp,
           "train_wall_s": round(train_s, 1), "sim_heldout_wall_s": round(sim_s, 1),
           "robot_heldout_wall_s": round(robot_s, 1),
           "robot_errors": {k: v["errors"] for k, v in robot.items()},
           "robot_solved": {k: v["solved"] for k, v in robot.items()}}
    _record(a.out / "results.jsonl", res, lambda k: k.startswith("robot_"))
    return res


def clones(a: argparse.Namespace) -> dict[str, Any]:
    """``--candidates`` clones (``main_job.clones``) from ``DIR/demos.h5``, each judged on its
    validation in the randomized sim (``--val`` episodes of ``BC_EVAL_STREAM``, as the main job
    chooses) and on the main job's ``--heldout`` held-out episodes of the emulated robot: does
    the sim validation predict the robot?"""
    from scipy.stats import spearmanr

    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import DAPGConfig, TrainConfig
    from lowcostdex.main_job.clones import choose_clone
    from lowcostdex.main_job.setup import DAPG_LAM0, TASKS

    env_id = TASKS["valve-target"].env_id
    kw = sim_kwargs(a.randomize)
    backend = kw.pop("backend")
    config = TrainConfig(algo="dapg", env_id=env_id, backend=backend, env_kwargs=kw,
                         seed=a.seed, n_iter=1, n_traj=1, eval_episodes=1,
                         demos=str(a.demos / "demos.h5"), eval_bc=True,
                         dapg=DAPGConfig(lam0=DAPG_LAM0), eval_paired=True, progress=False)
    keep: dict[int, Any] = {}
    chosen = choose_clone(config, a.candidates, a.val, keep)
    folder = a.out / f"clones_s{a.seed}"
    folder.mkdir(parents=True, exist_ok=True)
    files = {}
    for s, policy in keep.items():
        files[str(s)] = folder / f"clone_{s}.pt"
        ex.save_state(files[str(s)], {"policy": policy.to_checkpoint()})
    t1, c1 = time.perf_counter(), time.process_time()
    robot = heldout(env_id, robot_kwargs(), files, a.seed, a.heldout)
    rows = [{**c, "robot_successes": robot[str(c["bc_seed"])]["successes"],
             "robot_median_error": round(float(np.median(robot[str(c["bc_seed"])]["errors"])), 4)}
            for c in chosen["candidates"]]
    rho = spearmanr([r["successes"] for r in rows], [r["robot_successes"] for r in rows])
    res = {"seed": a.seed, "randomize": a.randomize, "val": a.val, "heldout": a.heldout,
           "chosen": chosen["bc_seed"], "rows": rows,
           "chosen_robot": robot[str(chosen["bc_seed"])]["successes"],
           "first_robot": robot[str(a.seed)]["successes"],
           "spearman_val_robot": round(float(rho.statistic), 3),
           "choose_wall_s": chosen["seconds"], "choose_cpu_s": chosen["cpu_seconds"],
           "robot_wall_s": round(time.perf_counter() - t1, 1),
           "robot_cpu_s": round(time.process_time() - c1, 1)}
    _record(a.out / "clones.jsonl", res)
    return res


def candidates(a: argparse.Namespace) -> dict[str, Any]:
    """The main job's DAPG stage as it trains (best of ``CLONES`` clones on the randomized-sim
    validation, then DAPG ``SimTraining`` in the randomized sim), each evaluated iterate kept
    (``checkpoint_every = eval_every``); then the clone and every evaluated iterate on
    ``--robot-val`` robot validation episodes (``ROBOT_VAL_STREAM``) and on the main job's
    ``--heldout`` held-out robot episodes (``HELDOUT_STREAM``): which choice among the final
    candidates, made on a few robot episodes, finds the iterate that beats the clone on the
    held-out ones?"""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import DAPGConfig, TrainConfig
    from lowcostdex.algos.samplers import HELDOUT_STREAM
    from lowcostdex.algos.train import train
    from lowcostdex.main_job.clones import choose_clone
    from lowcostdex.main_job.setup import BUDGETS, DAPG_LAM0, TASKS

    sim = BUDGETS["default"].dapg_sim
    assert sim is not None
    setup = TASKS["valve-target"]
    iters = a.iters or sim.iters
    randomize: Any = list(sim.randomize)
    if a.sim != "main":
        randomize = gap_randomization(a.gap, a.sim)
    kwargs = {**setup.env_overrides, "randomize": randomize}
    config = TrainConfig(algo="dapg", env_id=setup.env_id, backend="sim", env_kwargs=kwargs,
                         seed=a.seed, n_iter=iters, n_traj=sim.traj,
                         eval_every=sim.eval_every, eval_episodes=sim.eval_episodes,
                         demos=str(a.demos / "demos.h5"), eval_bc=True,
                         dapg=DAPGConfig(lam0=DAPG_LAM0), eval_paired=True, progress=False,
                         checkpoint_every=sim.eval_every, eval_dense_from=sim.dense_from)
    c0, t0 = time.process_time(), time.perf_counter()
    chosen = choose_clone(config, sim.clones, sim.eval_episodes)
    config = dataclasses.replace(config, bc_seed=chosen["bc_seed"])
    run_dir = a.out / f"cand_s{a.seed}_i{iters}" if a.sim == "main" else (
        a.out / f"cand_{a.sim}_s{a.seed}_i{iters}")
    shutil.rmtree(run_dir, ignore_errors=True)
    train(config, run_dir)
    train_cpu, train_wall = time.process_time() - c0, time.perf_counter() - t0
    m = ex.read_metrics(run_dir / ex.METRICS_FILE)
    val = {int(i): float(v) for i, v in zip(m["iteration"], m["eval_success_rate"],
                                             strict=True) if math.isfinite(v)}
    policies = {"clone": run_dir / ex.BC_POLICY_FILE}
    for k in sorted(val):
        f = run_dir / "checkpoints" / f"ckpt_{k:06d}.pt"
        if f.is_file():
            policies[f"it{k}"] = f
    summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
    c1 = time.process_time()
    rv = (heldout(setup.env_id, robot_kwargs(), policies, a.seed, a.robot_val,
                  stream=a.val_stream) if a.robot_val else {})
    val_cpu = time.process_time() - c1
    ho = heldout(setup.env_id, robot_kwargs(), policies, a.seed, a.heldout, stream=HELDOUT_STREAM)
    best_it = (summary.get("best") or {}).get("iteration")
    chosen_name = "clone" if best_it is None or best_it < 0 else f"it{best_it}"
    res = {"seed": a.seed, "sim": a.sim, "gap": str(a.gap) if a.sim != "main" else None,
           "iters": iters, "bc_seed": chosen["bc_seed"],
           "main_job_choice": chosen_name,
           "main_job_vs_clone": (paired(ho["clone"], ho[chosen_name])
                                 if chosen_name in ho else None),
           "clone_sim_val": json.loads((run_dir / "bc.json").read_text())["eval_success_rate"],
           "sim_val": val, "chosen_iteration": (summary.get("best") or {}).get("iteration"),
           "robot_val": {k: v["successes"] for k, v in rv.items()},
           "robot_val_median_err": {k: round(float(np.median(v["errors"])), 4)
                                    for k, v in rv.items()},
           "heldout": {k: v["successes"] for k, v in ho.items()},
           "vs_clone": {k: paired(ho["clone"], v) for k, v in ho.items() if k != "clone"},
           "train_cpu_s": round(train_cpu, 1), "train_wall_s": round(train_wall, 1),
           "robot_val_cpu_s": round(val_cpu, 1),
           "robot_val_solved": {k: v["solved"] for k, v in rv.items()},
           "robot_val_errors": {k: v["errors"] for k, v in rv.items()},
           "heldout_solved": {k: v["solved"] for k, v in ho.items()},
           "heldout_errors": {k: v["errors"] for k, v in ho.items()}}
    _record(a.out / "candidates.jsonl", res, lambda k: k.endswith(("_solved", "_errors")))
    return res


def evaluate(a: argparse.Namespace) -> None:
    """A finished ``candidates`` run folder (``--run``): the clone and the evaluated iterates
    on ``--robot-val`` robot validation episodes, the chosen one (``choose_finalist``)
    and the clone on the ``--heldout`` held-out episodes first (printed), then the others."""
    from lowcostdex.algos.samplers import HELDOUT_STREAM, EnvFactory
    from lowcostdex.main_job.setup import TASKS

    setup = TASKS["valve-target"]
    files = candidate_files(a.run)
    c0 = time.process_time()
    f = choose_finalist(files, EnvFactory(setup.env_id, robot_kwargs()), a.seed, a.robot_val)
    val_cpu = time.process_time() - c0
    name = {it: "clone" if it < 0 else f"it{it}" for it in files}
    res: dict[str, Any] = {"seed": a.seed, "run": str(a.run), "finalists": f,
                           "robot_val_cpu_s": round(val_cpu, 1)}
    order = [-1, f["iteration"]] + [it for it in sorted(files) if it not in (-1, f["iteration"])]
    ho: dict[str, Any] = {}
    for it in dict.fromkeys(order):
        ho.update(heldout(setup.env_id, robot_kwargs(), {name[it]: files[it]}, a.seed,
                          a.heldout, stream=HELDOUT_STREAM))
        if it != -1:
            res[f"{name[it]}_vs_clone"] = paired(ho["clone"], ho[name[it]])
            print(json.dumps({"seed": a.seed, "chosen": name[f["iteration"]], name[it]:
                              res[f"{name[it]}_vs_clone"]}), flush=True)
    res["heldout_solved"] = {k: v["solved"] for k, v in ho.items()}
    res["heldout_errors"] = {k: v["errors"] for k, v in ho.items()}
    _record(a.run.parent / "evaluate.jsonl", res, lambda k: k.startswith("heldout_"))


class Ensemble:
    """The mean of several policies' mean actions (a rollout policy: ``act(obs, noise)``; the
    noise is ignored: held-out episodes act deterministically)."""

    def __init__(self, snaps: list[Any]):
        self.snaps = snaps

    @property
    def act_dim(self) -> int:
        return int(self.snaps[0].act_dim)

    def act(self, obs: np.ndarray, noise: np.ndarray | None = None) -> np.ndarray:
        return np.mean([s.act(obs, None) for s in self.snaps], axis=0)


def average_policy(files: list[Path]) -> Any:
    """``main_job.streams.average_weights`` of the policies in ``files``."""
    from lowcostdex.algos.train import load_policy
    from lowcostdex.main_job.streams import average_weights

    return average_weights([load_policy(f) for f in files])


def streams(a: argparse.Namespace) -> dict[str, Any]:
    """The main job's DAPG stage (best of ``CLONES`` clones, ``SimTraining`` in the randomized
    sim) run ``--runs`` times from the same chosen clone with other seeds (other randomization
    draws, training episodes, baseline fits), every iterate from ``--avg-from`` on kept; then on
    the ``--heldout`` held-out robot episodes (each policy on a freshly started robot): the
    clone, each run's validation-chosen policy (run 0 is the main job's), and averages over
    the randomization stream: the weight average of the runs' last iterates (``soupK``), the
    mean action of the runs' last iterates (``ensK``), the weight average of run 0's iterates
    from ``--avg-from`` on (``swa0``) and of every run's (``swa_soupK``). Also each average on
    the sim validation episodes (100, ``EVAL_STREAM`` at the run's seed, the clone competing)."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import DAPGConfig, TrainConfig
    from lowcostdex.algos.samplers import EVAL_STREAM, HELDOUT_STREAM, EnvFactory, make_jobs
    from lowcostdex.algos.train import load_policy, train, trajectory_success
    from lowcostdex.main_job.clones import choose_clone
    from lowcostdex.main_job.heldout import evaluate as evaluate_on
    from lowcostdex.main_job.setup import BUDGETS, DAPG_LAM0, TASKS
    from lowcostdex.main_job.streams import stream_seeds

    sim = BUDGETS["default"].dapg_sim
    assert sim is not None
    setup = TASKS["valve-target"]
    kwargs = {**setup.env_overrides, "randomize": list(sim.randomize)}
    config = TrainConfig(algo="dapg", env_id=setup.env_id, backend="sim", env_kwargs=kwargs,
                         seed=a.seed, n_iter=sim.iters, n_traj=sim.traj,
                         eval_every=sim.eval_every, eval_episodes=sim.eval_episodes,
                         demos=str(a.demos / "demos.h5"), eval_bc=True,
                         dapg=DAPGConfig(lam0=DAPG_LAM0), eval_paired=True, progress=False,
                         checkpoint_every=1, eval_dense_from=sim.dense_from)
    if a.config:
        d = dataclasses.asdict(config)
        for k, v in a.config.items():
            d[k] = {**d[k], **v} if isinstance(v, dict) else v
        config = TrainConfig.from_dict(d)
    c0, t0 = time.process_time(), time.perf_counter()
    chosen = choose_clone(config, sim.clones, sim.eval_episodes)
    folder = a.out / f"streams_s{a.seed}{a.tag}"
    shutil.rmtree(folder, ignore_errors=True)
    runs, train_cpu = [], []
    for k, s in enumerate(stream_seeds(a.seed, a.runs)):
        cfg = dataclasses.replace(config, seed=s, bc_seed=chosen["bc_seed"])
        run_dir = folder / f"run{k}"
        keep = run_dir.parent / f"iterates{k}"
        keep.mkdir(parents=True, exist_ok=True)

        def until(row: dict[str, Any], run_dir: Path = run_dir, keep: Path = keep) -> bool:
            prev = int(row[ex.ITERATION]) - 1  # its checkpoint is on disk (keep_last 3)
            f = run_dir / ex.CHECKPOINT_DIR / f"ckpt_{prev:06d}.pt"
            if prev >= a.avg_from and f.is_file():
                shutil.copy(f, keep / f.name)
            return False

        c1 = time.process_time()
        train(cfg, run_dir, until=until)
        last = cfg.n_iter - 1
        shutil.copy(run_dir / ex.CHECKPOINT_DIR / f"ckpt_{last:06d}.pt", keep)
        train_cpu.append(round(time.process_time() - c1, 1))
        summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
        m = ex.read_metrics(run_dir / ex.METRICS_FILE)
        runs.append({"seed": s, "dir": run_dir, "keep": keep,
                     "chosen": (summary.get("best") or {}).get("iteration"),
                     "sim_val": {int(i): round(float(v), 3) for i, v in
                                 zip(m["iteration"], m["eval_success_rate"], strict=True)
                                 if math.isfinite(v)}})
    total_train_cpu, total_train_wall = time.process_time() - c0, time.perf_counter() - t0
    lasts = [r["keep"] / f"ckpt_{config.n_iter - 1:06d}.pt" for r in runs]
    snaps: dict[str, Any] = {"clone": load_policy(runs[0]["dir"] / ex.BC_POLICY_FILE).snapshot()}
    for k, r in enumerate(runs):
        snaps[f"run{k}"] = load_policy(r["dir"]).snapshot()
    n = len(runs)
    snaps[f"soup{n}"] = average_policy(lasts).snapshot()
    if n > 3:
        snaps["soup3"] = average_policy(lasts[:3]).snapshot()
    snaps[f"ens{n}"] = Ensemble([load_policy(f).snapshot() for f in lasts])
    snaps["swa0"] = average_policy(sorted(runs[0]["keep"].glob("ckpt_*.pt"))).snapshot()
    snaps[f"swa_soup{n}"] = average_policy(sorted(f for r in runs
                                                  for f in r["keep"].glob("ckpt_*.pt"))).snapshot()
    # sim validation of the averages (the main job's validation episodes of run 0)
    c1 = time.process_time()
    sim_jobs = make_jobs(a.seed, EVAL_STREAM, 0, sim.eval_episodes, deterministic=True)
    sim_names = ["clone", f"soup{n}", f"ens{n}", "swa0", f"swa_soup{n}"]
    sv = evaluate_on(EnvFactory(setup.env_id, {**kwargs, "backend": "sim"}),
                     {k: snaps[k] for k in sim_names}, sim_jobs, fresh=True)
    sim_val = {k: int(sum(trajectory_success(p, "final") for p in v)) for k, v in sv.items()}
    sim_cpu = time.process_time() - c1
    c1 = time.process_time()
    jobs = make_jobs(a.seed, HELDOUT_STREAM, 0, a.heldout, deterministic=True)
    judged = {k: v for k, v in snaps.items() if not a.only or k in a.only}
    ho_runs = evaluate_on(EnvFactory(setup.env_id, robot_kwargs()), judged, jobs, fresh=True)
    ho = {}
    for k, paths in ho_runs.items():
        ho[k] = {"solved": [bool(trajectory_success(p, "final")) for p in paths],
                 "errors": [float(p.final_goal_error) for p in paths]}
        ho[k]["successes"] = int(sum(ho[k]["solved"]))
    res = {"seed": a.seed, "runs": n, "avg_from": a.avg_from, "bc_seed": chosen["bc_seed"],
           "config": a.config, "tag": a.tag,
           "run_seeds": [r["seed"] for r in runs], "run_chosen": [r["chosen"] for r in runs],
           "run_sim_val": [r["sim_val"] for r in runs], "sim_val_averages": sim_val,
           "heldout": {k: v["successes"] for k, v in ho.items()},
           "vs_clone": {k: paired(ho["clone"], v) for k, v in ho.items() if k != "clone"},
           "train_cpu_s": train_cpu, "all_train_cpu_s": round(total_train_cpu, 1),
           "all_train_wall_s": round(total_train_wall, 1), "sim_val_cpu_s": round(sim_cpu, 1),
           "heldout_cpu_s": round(time.process_time() - c1, 1),
           "heldout_solved": {k: v["solved"] for k, v in ho.items()},
           "heldout_errors": {k: v["errors"] for k, v in ho.items()}}
    _record(a.out / "streams.jsonl", res, lambda k: k.startswith("heldout_"))
    return res


def main() -> None:
    torch.set_num_threads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("throughput")
    t.add_argument("--episodes", type=int, default=20)
    r = sub.add_parser("train")
    r.add_argument("--demos", type=Path, required=True, help="main-job output folder")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--iters", type=int, default=30)
    r.add_argument("--traj", type=int, default=40)
    r.add_argument("--val", type=int, default=40, help="validation episodes (sim)")
    r.add_argument("--eval-every", type=int, default=4)
    r.add_argument("--randomize", choices=RANDOMIZE, default="none")
    r.add_argument("--heldout", type=int, default=40, help="held-out episodes on the robot")
    r.add_argument("--sim-heldout", type=int, default=100)
    r.add_argument("--config", type=json.loads, default={},
                   help='TrainConfig overrides as JSON, e.g. \'{"npg": {"step_size": 0.05}}\'')
    r.add_argument("--tag", default="", help="appended to the run's folder name")
    r.add_argument("--ramp", type=float, nargs=2, metavar=("WEIGHT", "RADIUS"),
                   help="add main_job.shaping.GoalRamp to the training reward")
    c = sub.add_parser("clones")
    c.add_argument("--demos", type=Path, required=True, help="main-job output folder")
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--candidates", type=int, default=6)
    c.add_argument("--val", type=int, default=100, help="validation episodes (sim)")
    c.add_argument("--randomize", choices=RANDOMIZE, default="default")
    c.add_argument("--heldout", type=int, default=40, help="held-out episodes on the robot")
    d = sub.add_parser("candidates")
    d.add_argument("--demos", type=Path, required=True, help="main-job output folder")
    d.add_argument("--out", type=Path, required=True)
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--iters", type=int, default=0, help="0: the main job's")
    d.add_argument("--robot-val", type=int, default=40, help="robot validation episodes")
    d.add_argument("--val-stream", type=int, default=4, help="their seed stream")
    d.add_argument("--heldout", type=int, default=100, help="held-out episodes on the robot")
    d.add_argument("--sim", choices=SIM_CHOICES, default="main",
                   help="the sim DAPG trains in (SIM_CHOICES)")
    d.add_argument("--gap", type=Path, help="gap report folder (--sim gap, gap+dr)")
    e = sub.add_parser("evaluate")
    e.add_argument("--run", type=Path, required=True, help="a candidates run folder")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--robot-val", type=int, default=20, help="robot validation episodes")
    e.add_argument("--heldout", type=int, default=100, help="held-out episodes on the robot")
    st = sub.add_parser("streams")
    st.add_argument("--demos", type=Path, required=True, help="main-job output folder")
    st.add_argument("--out", type=Path, required=True)
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--runs", type=int, default=4, help="DAPG runs from the same clone")
    st.add_argument("--avg-from", type=int, default=15, help="first iterate averaged (swa)")
    st.add_argument("--heldout", type=int, default=100, help="held-out episodes on the robot")
    st.add_argument("--config", type=json.loads, default={}, help="TrainConfig overrides")
    st.add_argument("--tag", default="")
    st.add_argument("--only", nargs="*", default=[],
                    help="policies judged on the robot (default all), e.g. clone soup3")
    a = ap.parse_args()
    if a.cmd == "streams":
        streams(a)
    elif a.cmd == "evaluate":
        evaluate(a)
    elif a.cmd == "candidates":
        candidates(a)
    elif a.cmd == "clones":
        clones(a)
    elif a.cmd == "throughput":
        throughput(a.episodes)
    else:
        train_in_sim(a)


if __name__ == "__main__":
    main()
