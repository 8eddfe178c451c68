"""Samples and wall-clock to 80 % success: NPG, DAPG and PPO on the D'Claw valve and flip.

    python bench/npg_dapg.py                                  # valve: NPG, DAPG, PPO; 3 seeds
    python bench/npg_dapg.py --tasks flip                     # flip: DAPG, NPG, PPO; keypoints
                                                              #   and quaternion (the flip table)
    python bench/npg_dapg.py --tasks allegro-valve --algos dapg
    python bench/npg_dapg.py --quick                          # smoke run, tiny budget
    python bench/npg_dapg.py ... --record                     # append a section to bench/RESULTS.md
    python bench/npg_dapg.py --tasks flip-keypoints --algos dapg --seeds 2 --reuse
                                          # runs seed 1 only: seed 0's finished run is reused

Each finished run writes ``outcome.json`` in its run folder; ``--reuse`` reads it instead of
training again when the run's settings match, so a long table is built one seed (one process)
at a time and survives an interrupted session. ``--max-wall`` stops a run after that many
wall-clock seconds (how far it got within e.g. the issue's 30 min is then what it reports).
``--resume`` continues a run stopped that way (or killed) from its last checkpoint with the same
command (the trainers' resume: same config, sample count and per-iteration seeds, so it goes on
as the uninterrupted run would); its outcome adds the earlier sessions' wall and CPU seconds.

Every run uses the trainers' defaults (``TrainConfig`` for NPG/DAPG, ``PPOConfig`` for PPO): what a
user gets from ``lowcostdex train npg|dapg|ppo`` without options. A run goes until its training
(stochastic-policy) success first reaches ``--target`` (0.8) and then ``--extra-iters`` more
iterations, or until its sample budget; deterministic (mean-action) evaluations every
``eval_every`` iterations. For each run it prints and records, beside each other:

- the first crossing: samples and wall-clock seconds at which training success and evaluation
  success first reached the target;
- the final training success (mean of the last three iterations) and the final evaluation;
- the best evaluation (the run's policy, ``policy.pt``) and ``holds``: the share of evaluations
  after the first evaluation crossing that are still at or above the target (1.0 = it held);
  final and best deterministic success with 95 % Wilson intervals over their evaluation episodes;
- the run's wall-clock and CPU seconds (this process, all threads) and the 1-min load average
  at its start and end (the machine is shared).

Ratios: NPG / DAPG samples to the target (medians over seeds; a lower bound "> x" when NPG did
not reach it in its budget), and PPO / NPG wall-clock to the target. On the flip NPG and PPO get
``--scratch-budget-factor`` (5) times DAPG's median samples to the training target; the keypoint
and quaternion variants (observation and reward) are compared with 95 % t-intervals over seeds.

Demonstrations: the scripted teachers (``ValveTurnTeacher``, ``AllegroValveTeacher``,
``PinchFlipTeacher``; ``FlipBlockTeacher`` before 2026-11-27 session 10, ``PlannedFlipTeacher``
for the 2026-11-27 runs at 0586db6) run in simulation with uniform executed-action noise and clean labels
(``lowcostdex.demonstrations.dataset.teacher_episodes``), written as the demo dataset in ``<out>/<task>/``.
Sampling uses the vector sampler (``mujoco.batch``; trajectories identical to the serial
sampler's), so wall-clock is what NPG/DAPG take with batched simulation on this machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib
import json
import math
import os
import platform
import resource
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

import lowcostdex  # noqa: F401  (registers the env ids)
from lowcostdex.algos import experiment as ex
from lowcostdex.algos.configs import PPOConfig, TrainConfig
from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes
from lowcostdex.demonstrations.file import DatasetInfo
from lowcostdex.stats import wilson_interval


@dataclass(frozen=True)
class Task:
    env_id: str
    teacher: str  # class name of a scripted teacher
    n_demos: int
    demo_noise: float  # executed-action noise while recording [action units]


TASKS = {
    "valve": Task("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher", 25, 0.1),
    # PinchFlipTeacher (2026-11-27, session 10): under the demos' executed-action noise it flips
    # 54 of 80 starts against FlipBlockTeacher's 38 (bench/RESULTS.md, "The pinched flip
    # teacher"); PlannedFlipTeacher's demos (0586db6) gave DAPG no gain
    "flip-keypoints": Task("lowcostdex/DClawFlipBlock-v0", "PinchFlipTeacher", 10, 0.05),
    "flip-quaternion": Task("lowcostdex/DClawFlipBlockQuaternion-v0", "PinchFlipTeacher", 10,
                            0.05),
    "allegro-valve": Task("lowcostdex/AllegroTurnValve-v0", "AllegroValveTeacher", 25, 0.1),
}
ALIASES = {"flip": ["flip-keypoints", "flip-quaternion"]}
ALGOS = ("npg", "dapg", "ppo")
TEACHER_MODULES = ("lowcostdex.teachers.valve", "lowcostdex.teachers.flip",
                   "lowcostdex.teachers.flip_plan", "lowcostdex.teachers.flip_pinch")


class ScriptedTeacher:
    """A scripted teacher as a demo-recording policy (env, obs) -> action: its joint goals for
    the observed state, as normalised actions."""

    def __init__(self, name: str) -> None:
        modules = [importlib.import_module(m) for m in TEACHER_MODULES]
        self.teacher = next(getattr(m, name) for m in modules if hasattr(m, name))()

    def reset(self, env: gym.Env) -> None:
        self.teacher.reset(env.unwrapped)

    def __call__(self, env: gym.Env, obs: np.ndarray) -> np.ndarray:
        from lowcostdex.sim.envs import goal_to_action

        u = env.unwrapped
        goals = self.teacher(u.backend.observed_qpos(), u.goal)
        return goal_to_action(goals, u.task.hand_low, u.task.hand_high)


def record_demos(task: Task, out: Path, n: int) -> Path:
    env = gym.make(task.env_id)
    episodes = teacher_episodes(env, ScriptedTeacher(task.teacher),
                                seeds=range(10_000, 10_000 + n), action_noise=task.demo_noise,
                                max_tries=8)
    info = DatasetInfo.from_env(env, "scripted_teacher")
    env.close()
    return save_demos(out / "demos.h5", episodes, info)


def teacher_success(task: Task, n: int, noise: float) -> tuple[int, float, float]:
    """The scripted teacher's final-step successes over ``n`` held-out starts with uniform
    executed-action noise ``noise``: (successes, 95 % Wilson low, high)."""
    env = gym.make(task.env_id)
    episodes = teacher_episodes(env, ScriptedTeacher(task.teacher),
                                seeds=range(HELD_OUT_SEED, HELD_OUT_SEED + n),
                                only_successful=False, max_tries=1, action_noise=noise)
    env.close()
    k = int(sum(bool(e.success[-1]) for e in episodes))
    return (k, *wilson_interval(k, n))


# ----------------------------------------------------------------------------------------------
# One run


OUTCOME_FILE = "outcome.json"


def _until(target: float, extra: int, max_wall: float | None = None,
           stopped: dict[str, str] | None = None, cpu: dict[float, float] | None = None,
           reached_at: int | None = None, cpu_before: float = 0.0):
    """Stop ``extra`` iterations after training success first reaches ``target``, or once
    ``max_wall`` wall-clock seconds have passed since this call; ``stopped["why"]`` says which.
    ``cpu`` gets, per iteration, samples -> CPU seconds of this process since this call (after
    the iteration's update, before its evaluation) plus ``cpu_before`` (a resumed run's earlier
    sessions): the CPU to a crossing, which the shared machine's load does not inflate as it
    does the wall-clock. ``reached_at``: the iteration a resumed run first reached ``target``."""
    reached: list[int] = [] if reached_at is None else [reached_at]
    t0 = time.perf_counter()
    cpu0 = _usage()[1] - cpu_before

    def until(row: dict[str, float]) -> bool:
        if cpu is not None:
            cpu[float(row[ex.SAMPLES])] = _usage()[1] - cpu0
        if not reached and row[ex.SUCCESS_RATE] >= target:
            reached.append(int(row[ex.ITERATION]))
        if bool(reached) and row[ex.ITERATION] >= reached[0] + extra:
            if stopped is not None:
                stopped["why"] = "target"
            return True
        if max_wall is not None and time.perf_counter() - t0 >= max_wall:
            if stopped is not None:
                stopped["why"] = "wall limit"
            return True
        return False

    return until


def _usage() -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process and its children)."""
    cpu = sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                resource.getrusage(resource.RUSAGE_CHILDREN)))
    return time.perf_counter(), cpu


def resumable(out: Path) -> dict | None:
    """What a resume of the run in ``out`` starts from: ``{"iteration", "run_wall", "run_cpu",
    "sessions", "reached_at"}`` (the earlier sessions' seconds from its ``outcome.json``, 0 when
    it was killed before writing one; ``reached_at`` the iteration training success first
    reached the target, from its metrics), or None when ``out`` has no checkpoint. A run that
    finished (stopped by its budget or target) is refused."""
    latest = out / ex.CHECKPOINT_DIR / ex.LATEST_FILE
    if not latest.exists():
        return None
    prior = {"run_wall": 0.0, "run_cpu": 0.0, "sessions": 0}
    if (out / OUTCOME_FILE).exists():
        o = json.loads((out / OUTCOME_FILE).read_text())["outcome"]
        if o["stopped"] != "wall limit":
            raise SystemExit(f"--resume: the run in {out} finished (stopped by {o['stopped']}); "
                             "--reuse reads its outcome, or remove the folder to run it again")
        prior = {"run_wall": float(o["run_wall"]), "run_cpu": float(o["run_cpu"]),
                 "sessions": int(o.get("sessions", 1))}
    return {"iteration": int(ex.read_json(latest)["iteration"]), **prior}


def _first_reached(out: Path, target: float) -> int | None:
    """The iteration whose training success first reached ``target`` in ``out``'s metrics."""
    m = ex.read_metrics(out / ex.METRICS_FILE)
    hit = np.flatnonzero(np.nan_to_num(m[ex.SUCCESS_RATE], nan=-1.0) >= target)
    return int(m[ex.ITERATION][hit[0]]) if hit.size else None


def _timed(run, out: Path, settings: dict, target: float, n_held_out: int = 0,
           resume: bool = False) -> dict[str, float]:
    """Run ``run(stopped, cpu, prior)`` in ``out`` (emptied first, unless ``resume`` and it
    holds a checkpoint: then ``prior`` is :func:`resumable`'s answer, else None) and write its
    outcome with the wall/CPU seconds (the whole run's, all sessions, and to each first
    crossing) and loads beside the settings it ran with."""
    prior = resumable(out) if resume else None
    if prior is not None:
        prior["reached_at"] = _first_reached(out, target)
    elif out.exists():
        shutil.rmtree(out)
    stopped = {"why": "budget"}
    cpu: dict[float, float] = {}
    load0 = os.getloadavg()[0]
    w0, c0 = _usage()
    run(stopped, cpu, prior)
    w1, c1 = _usage()
    r = outcome(out, target)
    r.update({"train_cpu": cpu.get(r["train_samples"], math.nan),
              "eval_cpu": cpu.get(r["eval_samples"], math.nan)})
    before = prior or {"run_wall": 0.0, "run_cpu": 0.0, "sessions": 0}
    r.update({"run_wall": before["run_wall"] + w1 - w0, "run_cpu": before["run_cpu"] + c1 - c0,
              "sessions": before["sessions"] + 1, "load_start": load0,
              "load_end": os.getloadavg()[0], "stopped": stopped["why"],
              "eval_distinct": distinct_episodes(out)})
    if prior is not None:
        r["resumed_from"] = float(prior["iteration"])
    if n_held_out:
        r.update(held_out(out, n_held_out))
    (out / OUTCOME_FILE).write_text(json.dumps({"settings": settings, "outcome": r}, indent=1))
    return r


def reused(out: Path, settings: dict, n_held_out: int = 0) -> dict[str, float] | None:
    """The outcome of a finished run in ``out`` made with the same settings, else None."""
    f = out / OUTCOME_FILE
    if not f.exists():
        return None
    saved = json.loads(f.read_text())
    if saved["settings"] != settings:
        return None
    if "eval_distinct" not in saved["outcome"]:  # written before the count existed
        saved["outcome"]["eval_distinct"] = distinct_episodes(out)
        f.write_text(json.dumps(saved, indent=1))
    if n_held_out and saved["outcome"].get("heldout_n") != n_held_out:
        saved["outcome"].update(held_out(out, n_held_out))
        f.write_text(json.dumps(saved, indent=1))
    return saved["outcome"]


HELD_OUT_SEED = 50_000  # held-out reset seeds 50000.. (demos: 10000..; trainers: 32-bit SeedSequence hashes)


def _episodes(run_dir: Path, policy_file: str, n: int) -> tuple[int, int]:
    """(successes, distinct episodes) of a run's policy (mean action) from ``n`` reset seeds."""
    import torch

    from lowcostdex.algos.train import load_policy

    config = ex.read_json(run_dir / ex.CONFIG_FILE)
    policy = load_policy(run_dir / policy_file)
    env = gym.make(config["env_id"], **dict(config.get("env_kwargs") or {}))
    ends, wins = set(), 0
    for seed in range(n):
        obs, _ = env.reset(seed=HELD_OUT_SEED + seed)
        done, info = False, {}
        while not done:
            with torch.no_grad():
                a = policy.act(obs, deterministic=True)[0].numpy()
            obs, _, term, trunc, info = env.step(a)
            done = term or trunc
        wins += bool(info.get("success", False))
        ends.add(tuple(np.round(obs, 9)))
    env.close()
    return wins, len(ends)


def distinct_episodes(run_dir: Path, n: int = 3) -> float:
    """How many different episodes the run's final policy (mean action) makes from ``n`` reset
    seeds: 1 means a fixed start in a noise-free simulation, where the trainer's evaluation
    episodes are copies of one episode (its success rate is 0 or 1, an n = 1 sample)."""
    return float(_episodes(run_dir, ex.FINAL_POLICY_FILE, n)[1])


def held_out(run_dir: Path, n: int) -> dict[str, float]:
    """Success of the final and the best (``policy.pt``) policy, mean action, over ``n`` reset
    seeds that neither training nor the trainer's evaluations used: the best policy was chosen
    on the trainer's evaluations, so its own evaluation is biased upwards; this one is not."""
    final, distinct = _episodes(run_dir, ex.FINAL_POLICY_FILE, n)
    best, _ = _episodes(run_dir, ex.POLICY_FILE, n)
    return {"heldout_n": float(n), "heldout_final": final / n, "heldout_best": best / n,
            "heldout_distinct": float(distinct)}


def _crossing(m: dict[str, np.ndarray], key: str, target: float) -> tuple[float, float]:
    """(samples, wall seconds) at the first row whose ``key`` >= target, else NaNs."""
    hit = np.flatnonzero(np.nan_to_num(m[key], nan=-1.0) >= target)
    if hit.size == 0:
        return math.nan, math.nan
    return float(m[ex.SAMPLES][hit[0]]), float(m[ex.WALL_SECONDS][hit[0]])


def outcome(run_dir: Path, target: float) -> dict[str, float]:
    """What a benchmark row reports about one finished run."""
    m = ex.read_metrics(run_dir / ex.METRICS_FILE)
    summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
    train_s, train_w = _crossing(m, ex.SUCCESS_RATE, target)
    eval_s, eval_w = _crossing(m, ex.EVAL_SUCCESS_RATE, target)
    evals = m[ex.EVAL_SUCCESS_RATE]
    done = np.flatnonzero(np.isfinite(evals))
    after = done[done >= np.flatnonzero(np.nan_to_num(evals, nan=-1) >= target)[0]] \
        if math.isfinite(eval_s) else np.array([], int)
    best = summary.get("best") or {}
    return {
        "train_samples": train_s, "train_wall": train_w,
        "eval_samples": eval_s, "eval_wall": eval_w,
        "final_train": float(np.mean(m[ex.SUCCESS_RATE][-3:])),
        "final_eval": float(evals[done[-1]]) if done.size else math.nan,
        "best_eval": float(best.get(ex.EVAL_SUCCESS_RATE, math.nan)),
        "best_samples": float(best.get(ex.SAMPLES, math.nan)),
        "eval_episodes": float(ex.read_json(run_dir / ex.CONFIG_FILE).get("eval_episodes",
                                                                         math.nan)),
        "holds": float(np.mean(evals[after] >= target)) if after.size else math.nan,
        "samples": float(m[ex.SAMPLES][-1]),
        "wall": float(m[ex.WALL_SECONDS][-1]),
        "final_goal_error": float(np.mean(m["goal_error_final"][-3:]))
        if "goal_error_final" in m else math.nan,
    }


PROBE_STEPS = 10
"""Steps of the fixed action sequence ``env_fingerprint`` runs from reset seed 0."""


def env_fingerprint(env_id: str, env_kwargs: dict | None = None) -> str:
    """12 hex digits that change when the task a run learns changes: a SHA-256 of the compiled
    MuJoCo model (``mj_saveModel``: geometry, masses, gains, contact settings), the per-step
    motion bound, the episode length and a probe: observations, rewards and success flags of
    ``PROBE_STEPS`` fixed actions from reset seed 0 (the start, the goal, the reward and the
    observation; rounded to 1e-6).

    Why: on 2026-11-26 (9edd932) the valve's spokes moved to ROBEL's phase, and NPG/PPO on the
    fixed-start valve went from 176-232k to 330-390k samples to 80 % training success; nothing in
    the bench's records said the task had changed, and the rise stayed untraced for a day
    (bench/RESULTS.md, flip7's section). Runs with different fingerprints learned different
    tasks: ``--reuse`` does not mix them, and the table names the fingerprint."""
    import hashlib

    import mujoco

    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        u = env.unwrapped
        model = np.empty(mujoco.mj_sizeModel(u.model), dtype=np.uint8)
        mujoco.mj_saveModel(u.model, None, model)
        h = hashlib.sha256(model.tobytes())
        h.update(np.asarray(getattr(u, "max_step", np.zeros(0)), float).round(9).tobytes())
        h.update(str(env.spec.max_episode_steps if env.spec else None).encode())
        obs, _ = env.reset(seed=0)
        n = env.action_space.shape[0]
        probe = [np.asarray(obs, float)]
        for t in range(PROBE_STEPS):
            action = 0.8 * np.sin(0.7 * t + np.arange(n))  # every joint moves, none alike
            obs, reward, terminated, truncated, info = env.step(action)
            probe += [np.asarray(obs, float), [float(reward), float(bool(info.get("success")))]]
            if terminated or truncated:
                break
        h.update(np.round(np.concatenate([np.ravel(p) for p in probe]), 6).tobytes())
    finally:
        env.close()
    return h.hexdigest()[:12]


_FINGERPRINTS: dict[str, str] = {}


def _env_fingerprint(env_id: str, env_kwargs: dict) -> str:
    key = json.dumps([env_id, env_kwargs], sort_keys=True)
    if key not in _FINGERPRINTS:
        _FINGERPRINTS[key] = env_fingerprint(env_id, env_kwargs)
    return _FINGERPRINTS[key]


def _settings(cfg, args: argparse.Namespace) -> dict:
    """What makes two runs the same run (for ``--reuse``): the trainer's config, the stop rule
    and the task's ``env_fingerprint``."""
    return {"config": json.loads(json.dumps(dataclasses.asdict(cfg))), "target": args.target,
            "extra_iters": args.extra_iters, "max_wall": args.max_wall,
            "env": _env_fingerprint(cfg.env_id, dict(cfg.env_kwargs))}


def ppo_overrides(items: list[str] | None) -> dict:
    """``--ppo-set KEY=VALUE`` pairs as ``PPOConfig`` keyword arguments (VALUE in JSON: 1e-3,
    64, false, null); unknown keys are an error listing the valid ones."""
    fields = {f.name for f in dataclasses.fields(PPOConfig)}
    fixed = {"env_id", "seed", "n_iter", "eval_every", "eval_episodes", "progress"}
    out: dict = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or key not in fields - fixed:
            raise SystemExit(f"--ppo-set {item!r}: expected KEY=VALUE with KEY one of "
                             f"{sorted(fields - fixed)}")
        out[key] = json.loads(value)
    return out


def run_train(task: Task, algo: str, seed: int, budget: float, demos: Path | None,
              out: Path, args: argparse.Namespace) -> dict[str, float]:
    from lowcostdex.algos.train import train

    horizon = gym.spec(task.env_id).max_episode_steps
    d = TrainConfig()
    n_traj = args.n_traj or d.n_traj
    cfg = TrainConfig(algo=algo, env_id=task.env_id, seed=seed, n_traj=n_traj,
                      n_iter=max(1, int(budget // (n_traj * horizon))),
                      demos=str(demos) if algo == "dapg" else None,
                      sampler=args.sampler, n_workers=n_traj if args.sampler == "vector" else 1,
                      eval_every=args.eval_every, eval_episodes=args.eval_episodes,
                      progress=False)
    settings = _settings(cfg, args)
    if args.reuse and (r := reused(out, settings, args.held_out)) is not None:
        return r
    return _timed(lambda stopped, cpu, prior: train(
        cfg, out, resume=prior is not None, until=_until(
            args.target, args.extra_iters, args.max_wall, stopped, cpu,
            *((prior["reached_at"], prior["run_cpu"]) if prior else ()))),
        out, settings, args.target, args.held_out, args.resume)


def run_ppo(task: Task, seed: int, budget: float, out: Path,
            args: argparse.Namespace) -> dict[str, float]:
    from lowcostdex.algos.ppo import train

    horizon = gym.spec(task.env_id).max_episode_steps
    overrides = ppo_overrides(args.ppo_set)
    num_envs = overrides.get("num_envs", PPOConfig().num_envs)
    cfg = PPOConfig(env_id=task.env_id, seed=seed,
                    n_iter=max(1, int(budget // (num_envs * horizon))),
                    eval_every=args.eval_every, eval_episodes=args.eval_episodes,
                    progress=False, **overrides)
    settings = _settings(cfg, args)
    if args.reuse and (r := reused(out, settings, args.held_out)) is not None:
        return r
    return _timed(lambda stopped, cpu, prior: train(
        cfg, out, resume=prior is not None, until=_until(
            args.target, args.extra_iters, args.max_wall, stopped, cpu,
            *((prior["reached_at"], prior["run_cpu"]) if prior else ()))),
        out, settings, args.target, args.held_out, args.resume)


# ----------------------------------------------------------------------------------------------
# Tables


def _k(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x / 1e3:.0f}k"


def _s(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.0f}"


def _f2(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.2f}"


def _median(values: list[float]) -> float:
    return float(np.median([v if math.isfinite(v) else math.inf for v in values]))


def _interval(values: list[float]) -> str:
    """Mean and 95 % t-interval over seeds (NaN entries count as not reached)."""
    v = np.array([x for x in values if math.isfinite(x)])
    if len(v) < len(values):
        return f"{len(values) - len(v)}/{len(values)} not reached"
    if len(v) == 1:
        return f"{v[0]:.3g}"
    t95 = {2: 12.71, 3: 4.303, 4: 3.182, 5: 2.776}.get(len(v), 1.96)
    half = t95 * v.std(ddof=1) / math.sqrt(len(v))
    return f"{v.mean():.3g} [{v.mean() - half:.3g}, {v.mean() + half:.3g}]"


def _ratio(num: float, den: float, budget: float | None = None) -> str:
    if not math.isfinite(den):
        return "n/a (denominator not reached)"
    if not math.isfinite(num):
        return (f"> {budget / den:.1f}x (not reached in {budget / 1e3:.0f}k)" if budget
                else "n/a (numerator not reached)")
    return f"{num / den:.1f}x"


def _rate(rate: float, n: float, distinct: float = math.nan) -> str:
    """A success rate over ``n`` evaluation episodes with its 95 % Wilson interval; when the
    episodes are copies of one (``distinct`` == 1) the interval is that of one episode."""
    if not (math.isfinite(rate) and math.isfinite(n) and n > 0):
        return "-"
    if distinct == 1:
        k = round(rate)
        low, high = wilson_interval(k, 1)
        return f"{k}/1 [{low:.2f}, {high:.2f}]"
    k = round(rate * n)
    low, high = wilson_interval(k, int(n))
    return f"{k}/{int(n)} [{low:.2f}, {high:.2f}]"


def _held_out(r: dict[str, float]) -> str:
    """Held-out final and best success (``held_out``) with 95 % Wilson intervals."""
    n = r.get("heldout_n", math.nan)
    if not math.isfinite(n):
        return "-"
    return " / ".join(_rate(r[k], n, r.get("heldout_distinct", math.nan))
                      for k in ("heldout_final", "heldout_best"))


def _train_rate(r: dict[str, float], n_traj: int) -> str:
    """Final training success (stochastic policy, last three iterations, ``3 n_traj``
    independent episodes) with its 95 % Wilson interval."""
    if not math.isfinite(r["final_train"]):
        return "-"
    n = 3 * n_traj
    k = round(r["final_train"] * n)
    low, high = wilson_interval(k, n)
    return f"{k / n:.2f} [{low:.2f}, {high:.2f}]"


def table(name: str, results: dict[str, list[dict[str, float]]],
          budgets: dict[str, float], n_traj: dict[str, int]) -> list[str]:
    lines = [f"### {name}", "",
             "| algorithm | seed | samples to 80 % train | to 80 % eval | wall s (CPU s) to 80 % "
             "train / eval | final train [95 % Wilson] | final eval [95 % Wilson] | best eval [95 % Wilson] "
             "(samples) | holds | held-out final / best [95 % Wilson] | ran: samples, wall s, CPU s "
             "| load start/end | stopped by |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for algo, runs in results.items():
        for r in runs:
            seed = int(r["seed"])
            n, dist = r.get("eval_episodes", math.nan), r.get("eval_distinct", math.nan)
            lines.append(
                f"| {algo.upper()} | {seed} | {_k(r['train_samples'])} | {_k(r['eval_samples'])}"
                f" | {_s(r['train_wall'])} ({_s(r.get('train_cpu', math.nan))}) / {_s(r['eval_wall'])}"
                f" ({_s(r.get('eval_cpu', math.nan))}) | "
                f"{_train_rate(r, n_traj[algo])} | "
                f"{_rate(r['final_eval'], n, dist)} | {_rate(r['best_eval'], n, dist)} "
                f"({_k(r['best_samples'])}) | {_f2(r['holds'])} | {_held_out(r)} | "
                f"{_k(r['samples'])}, "
                f"{_s(r.get('run_wall', math.nan))}, {_s(r.get('run_cpu', math.nan))} | "
                f"{_f2(r.get('load_start', math.nan))}/{_f2(r.get('load_end', math.nan))} | "
                f"{r.get('stopped', '-')} (budget {_k(budgets[algo])}) |")
    distinct = [r.get("eval_distinct", math.nan) for runs in results.values() for r in runs]
    lines.append("")
    if 1.0 in distinct:
        lines.append("Evaluation episodes marked n/1: the final policy's mean-action episodes "
                     "from different reset seeds were identical (a fixed start in a noise-free "
                     "simulation), so each evaluation is one episode repeated; the interval is "
                     "that of one episode. The training success is over 3 x the trajectories "
                     "per iteration independent stochastic episodes (last three iterations).")
        lines.append("")
    med = {a: {k: _median([r.get(k, math.nan) for r in runs]) for k in ("train_samples", "eval_samples",
                                                           "train_wall", "eval_wall",
                                                           "train_cpu")}
           for a, runs in results.items()}
    if "npg" in med and "dapg" in med:
        lines.append(f"NPG / DAPG samples to 80 % (medians): training "
                     f"{_ratio(med['npg']['train_samples'], med['dapg']['train_samples'], budgets['npg'])}"
                     f", evaluation {_ratio(med['npg']['eval_samples'], med['dapg']['eval_samples'], budgets['npg'])}.")
    if "ppo" in med and "npg" in med:
        lines.append(f"PPO / NPG wall-clock to 80 % training success (medians): "
                     f"{_ratio(med['ppo']['train_wall'], med['npg']['train_wall'])} "
                     f"({_s(med['ppo']['train_wall'])} s vs {_s(med['npg']['train_wall'])} s); "
                     f"CPU {_ratio(med['ppo']['train_cpu'], med['npg']['train_cpu'])} "
                     f"({_s(med['ppo']['train_cpu'])} s vs {_s(med['npg']['train_cpu'])} s); "
                     f"samples {_ratio(med['ppo']['train_samples'], med['npg']['train_samples'])}.")
    return lines + [""]


def representation_table(results: dict[str, dict[str, list[dict[str, float]]]]) -> list[str]:
    lines = ["### Keypoints vs quaternion (observation and reward), 95 % t-intervals over seeds",
             "", "| algorithm | representation | samples to 80 % train | samples to 80 % eval "
             "| final train success | final orientation error [rad] |", "|---|---|---|---|---|---|"]
    for algo in ALGOS:
        for task in ("flip-keypoints", "flip-quaternion"):
            runs = results.get(task, {}).get(algo)
            if not runs:
                continue
            lines.append(
                f"| {algo.upper()} | {task.split('-')[1]} | "
                f"{_interval([r['train_samples'] for r in runs])} | "
                f"{_interval([r['eval_samples'] for r in runs])} | "
                f"{_interval([r['final_train'] for r in runs])} | "
                f"{_interval([r['final_goal_error'] for r in runs])} |")
    return lines + [""]


# ----------------------------------------------------------------------------------------------


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", nargs="+", default=["valve"],
                   choices=sorted(TASKS) + sorted(ALIASES))
    p.add_argument("--algos", nargs="+", default=list(ALGOS), choices=ALGOS)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--first-seed", type=int, default=0,
                   help="seeds first-seed .. first-seed + seeds - 1 (one more seed of a table)")
    p.add_argument("--max-samples", type=int, default=400_000,
                   help="budget of every run on the valve tasks (and of DAPG on the flip)")
    p.add_argument("--scratch-budget-factor", type=float, default=5.0,
                   help="flip: NPG and PPO budget = this x DAPG's median samples to the target")
    p.add_argument("--n-traj", type=int, default=None, help="NPG/DAPG trajectories/iteration")
    p.add_argument("--target", type=float, default=0.8)
    p.add_argument("--extra-iters", type=int, default=20,
                   help="iterations after the first training crossing (shows if it holds)")
    p.add_argument("--eval-every", type=int, default=5)
    p.add_argument("--eval-episodes", type=int, default=10,
                   help="mean-action episodes per evaluation (the trainers' default: 10)")
    p.add_argument("--held-out", type=int, default=0,
                   help="after each run: final and best policy over this many fresh starts")
    p.add_argument("--teacher-episodes", type=int, default=0,
                   help="measure the scripted teacher's success over this many starts first")
    p.add_argument("--sampler", default="vector", choices=("vector", "serial"))
    p.add_argument("--out", default="bench_runs/npg_dapg")
    p.add_argument("--max-wall", type=float, default=None,
                   help="stop each run after this many wall-clock seconds (default: no limit)")
    p.add_argument("--ppo-set", nargs="+", metavar="KEY=VALUE", default=None,
                   help="PPOConfig fields other than the defaults, e.g. lr=1e-3 num_envs=64 "
                        "(the sample budget still sets n_iter)")
    p.add_argument("--reuse", action="store_true",
                   help="reuse finished runs (their outcome.json) made with the same settings")
    p.add_argument("--resume", action="store_true",
                   help="continue each run that has a checkpoint (e.g. one stopped by --max-wall) "
                        "instead of starting it again; with --reuse a finished run is reused")
    p.add_argument("--quick", action="store_true", help="tiny budget: checks the script runs")
    p.add_argument("--record", action="store_true", help="append the results to bench/RESULTS.md")
    args = p.parse_args()
    tasks = [t for name in args.tasks for t in ALIASES.get(name, [name])]
    if args.quick:
        args.seeds, args.max_samples, args.n_traj, args.extra_iters = 1, 2 * 4 * 80, 4, 0

    out_root = Path(args.out)
    d, dp = TrainConfig(), PPOConfig(**ppo_overrides(args.ppo_set))
    report = [
        f"## NPG, DAPG and PPO: samples and wall-clock to {args.target:.0%} success "
        f"({datetime.date.today()}, {platform.node()}, {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} CPUs)", "",
        f"`python bench/npg_dapg.py --tasks {' '.join(args.tasks)} --algos {' '.join(args.algos)}"
        f" --seeds {args.seeds} --first-seed {args.first_seed} --eval-episodes {args.eval_episodes} --held-out {args.held_out}"
        f" --teacher-episodes {args.teacher_episodes}"
        f"{' --ppo-set ' + ' '.join(args.ppo_set) if args.ppo_set else ''}`. Trainer defaults: NPG/DAPG {args.n_traj or d.n_traj} "
        f"trajectories/iteration, delta {d.npg.step_size}, policy {d.policy.hidden_sizes} "
        f"init log-std {d.policy.init_log_std}, BC {d.bc.epochs} epochs (noise {d.bc.log_std}), "
        f"DAPG lam0 {d.dapg.lam0}; PPO {dp.num_envs} envs, lr {dp.lr}, {dp.update_epochs} "
        f"epochs x {dp.num_minibatches} minibatches, clip {dp.clip_coef}, anneal "
        f"{dp.anneal_lr}, policy "
        f"{dp.policy.hidden_sizes} init log-std {dp.policy.init_log_std}. {args.sampler} sampler; "
        f"evaluation every {args.eval_every} iterations (mean action). A run stops "
        f"{args.extra_iters} iterations after its first training crossing or at its budget.", ""]
    all_results: dict[str, dict[str, list[dict[str, float]]]] = {}
    for name in tasks:
        task = TASKS[name]
        if task.env_id not in gym.registry:
            report += [f"### {name}", "", f"skipped: {task.env_id} is not registered", ""]
            continue
        flip = name.startswith("flip")
        n_demos = 2 if args.quick else task.n_demos
        results: dict[str, list[dict[str, float]]] = {}
        budgets: dict[str, float] = {}
        order = [a for a in ("dapg", "npg", "ppo") if a in args.algos]
        if args.teacher_episodes:
            n = args.teacher_episodes
            for noise in (0.0, task.demo_noise):
                k, low, high = teacher_success(task, n, noise)
                line = (f"{name}: scripted teacher {task.teacher}, executed-action noise "
                        f"{noise}: {k}/{n} [{low:.2f}, {high:.2f}] (95 % Wilson)")
                print(line, flush=True)
                report += [line, ""]
        for algo in order:
            budget = float(args.max_samples)
            if flip and algo != "dapg" and "dapg" in results:
                dapg_median = _median([r["train_samples"] for r in results["dapg"]])
                if math.isfinite(dapg_median):
                    budget = args.scratch_budget_factor * dapg_median
            budgets[algo] = budget
            demos = record_demos(task, out_root / name, n_demos) if algo == "dapg" else None
            results[algo] = []
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                run_dir = out_root / name / f"{algo}_{seed}"
                if algo == "ppo":
                    r = run_ppo(task, seed, budget, run_dir, args)
                else:
                    r = run_train(task, algo, seed, budget, demos, run_dir, args)
                results[algo].append({**r, "seed": seed})
                print(name, algo, seed, json.dumps(r), flush=True)
        all_results[name] = results
        n_traj = {a: (ppo_overrides(args.ppo_set).get("num_envs", dp.num_envs) if a == "ppo"
                      else args.n_traj or d.n_traj) for a in results}
        report += table(f"{name} (`{task.env_id}`, env {_env_fingerprint(task.env_id, {})}, "
                        f"{n_demos} demos for DAPG)", results, budgets, n_traj)
    if "flip-keypoints" in all_results and "flip-quaternion" in all_results:
        report += representation_table(all_results)
    text = "\n".join(report)
    print(text)
    if args.record:
        results_md = Path(__file__).with_name("RESULTS.md")
        with results_md.open("a", encoding="utf-8") as f:
            f.write("\n" + text + "\n")
        print(f"appended to {results_md}")


if __name__ == "__main__":
    main()
