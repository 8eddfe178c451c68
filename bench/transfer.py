"""Does the identified model make policies that work on the robot? The transfer table (issue 14).

    python bench/transfer.py --out bench_runs/transfer                 # 3 hidden robots, 1 seed
    python bench/transfer.py --out bench_runs/transfer --seeds 3
    python bench/transfer.py --out /tmp/transfer_quick --quick         # smoke check (tests)
    python bench/transfer.py --task valve-near ...                     # +-0.25 rad starts, goals

Hidden robots (``lowcostdex.hardware.emulated.hidden_robots``) stand in for real D'Claws: emulated
robots behind the real dynamixel_sdk code path, each with its own mix of servo effects, MJCF
perturbations no effect names and a firmware imperfection. The training side never sees them.
Every condition trains DAPG with the same algorithm, demonstrations and sample budget:

  nominal                the nominal simulation;
  randomized             the nominal simulation with the project's domain randomization
                         (``effects.DEFAULT_DR_EFFECTS`` over their plausible D'Claw ranges);
  identified             the model ``gap analyze`` identified from identification logs recorded
                         on that robot (``trace.dclaw_identification_logs``: every finger, a
                         fixed budget of seconds), loaded into the sim as fixed per-joint
                         effects (one policy per robot);
  identified_randomized  the same with narrow randomization around the identified values (per
                         joint: the fitted 95 % interval, at least +-10 % of the value).

The demonstrations are recorded once, by the virtual teacher on a nominal emulated D'Claw (no
hidden robot), and shared by every condition. Each policy (the run's best evaluated one in its
own training sim) is evaluated with the mean action on every hidden robot (fresh emulated robot
per cell, the same episode seeds everywhere) and in its own training sim; success rates carry
95 % Wilson intervals (``lowcostdex.stats``). The sim-to-robot drop is success in the training
sim minus success on the robot.

Outputs in ``--out``: ``transfer.json`` (one row per condition, robot and seed), ``table.md``,
``transfer.png``, ``identified.json`` (what the analysis named per robot and finger, beside the
truth), the demonstrations, identification logs and reports, and the training runs. Finished
pieces are kept: running again with the same ``--out`` resumes where it stopped.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

CONDITIONS = ("nominal", "randomized", "identified", "identified_randomized")


@dataclass(frozen=True)
class Task:
    """The task every condition trains and is evaluated on: a registered id and its task
    options (``gym.make`` keyword arguments, e.g. ``TurnConfig`` fields)."""

    env_id: str
    kwargs: tuple[tuple[str, Any], ...] = ()

    def make_kwargs(self, **more: Any) -> dict[str, Any]:
        return {**dict(self.kwargs), **more}

    def label(self) -> str:
        opts = ", ".join(f"{k}={v}" for k, v in self.kwargs)
        return self.env_id.split("/")[1] + (f" ({opts})" if opts else "")


TASKS = {
    "valve": Task("lowcostdex/DClawTurnValve-v0"),  # 180 deg from the fixed start
    # start and goal each within +-0.25 rad of the fixed ones
    "valve-near": Task("lowcostdex/DClawTurnValve-v0", (("init_range", 0.25),
                                                         ("goal_range", 0.25))),
    "valve-random": Task("lowcostdex/DClawTurnValveRandom-v0"),  # +-60 deg start and goal
}
FINGERS = ("ff", "mf", "th")
EVAL_SEED = 20261125  # seeds of the evaluation episodes (same in every cell)
NARROW_PAD = 0.1  # identified_randomized: ranges at least +-10 % of each identified value


@dataclass(frozen=True)
class Size:
    """How much each stage does.

    Attributes:
      robots: hidden robots.
      demos: virtual-teacher demonstrations (each played back ``playbacks`` times).
      n_iter, n_traj: DAPG iterations and trajectories per iteration (the sample budget).
      eval_every, eval_episodes: in-training evaluations (choose the run's policy).
      episodes: evaluation episodes per cell (policy x robot, policy x its sim).
      id_logs, id_seconds: identification logs per finger and their length [s].
      fingers: fingers identified (others keep the nominal model).
      gap: ``GapConfig`` overrides (the quick size trims the search; default: none, what
        ``lowcostdex gap analyze`` does).
      bc_epochs: behaviour-cloning epochs before DAPG (None: the trainer's default).
    """

    robots: int
    demos: int
    playbacks: int
    n_iter: int
    n_traj: int
    eval_every: int
    eval_episodes: int
    episodes: int
    id_logs: int
    id_seconds: float
    fingers: tuple[str, ...] = FINGERS
    gap: tuple[tuple[str, Any], ...] = ()
    bc_epochs: int | None = None


SIZES = {
    "quick": Size(robots=2, demos=2, playbacks=1, n_iter=1, n_traj=4, eval_every=0,
                  eval_episodes=2, episodes=2, id_logs=3, id_seconds=3.0, fingers=("ff",),
                  gap=(("max_effects", 1), ("top_k", 2), ("search", "forward"),
                       ("bootstrap", 100), ("max_rounds", 5), ("rank_seconds", 3.0)),
                  bc_epochs=10),
    "default": Size(robots=3, demos=20, playbacks=2, n_iter=30, n_traj=40, eval_every=5,
                    eval_episodes=20, episodes=50, id_logs=3, id_seconds=10.0),
}


# ------------------------------------------------------------------------------------------------
# small helpers


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())


def write_json(path: Path, obj: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1))
    tmp.replace(path)


def cached(path: Path, make) -> Any:
    """``make()``'s JSON result, computed once and kept in ``path`` (resume)."""
    if path.exists():
        return read_json(path)
    value = make()
    write_json(path, value)
    return value


# ------------------------------------------------------------------------------------------------
# 1. demonstrations: the virtual teacher on a nominal emulated D'Claw


def record_demos(out: Path, task: Task, size: Size, seed: int) -> dict[str, Any]:
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the ids)
    from lowcostdex.hardware.demos import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.sim.scripted import ValveTurnTeacher

    path = out / "demos.h5"
    if path.exists():
        path.unlink()  # a recording cut short is redone whole
    t0 = time.perf_counter()
    env = gym.make(task.env_id, **task.make_kwargs(backend="emulated", effects=[]))
    try:
        solver = ValveTurnTeacher()
        teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task, solver=solver,
                                 config=virtual_teacher_config(solver),
                                 rng=np.random.default_rng(seed))
        response, _ = identify_servo_response(env, episodes=2, seed=seed + 1_000_000)
        recorder = KinestheticRecorder(env, path, task.env_id, teacher=teacher,
                                       response=response,
                                       playbacks=size.playbacks, playback_noise=0.05,
                                       rng=np.random.default_rng(seed))
        stats = recorder.record(size.demos, seed=seed)
    finally:
        env.close()
    return {"file": path.name, "robot": "nominal emulated D'Claw (no hidden effects)",
            "episodes": stats.episodes, "successful": stats.successes,
            "playbacks": stats.playbacks, "successful_playbacks": stats.playback_successes,
            "wall_seconds": round(time.perf_counter() - t0, 1)}


# ------------------------------------------------------------------------------------------------
# 2. identification: record on the hidden robot, `gap analyze` each finger


def identify_finger(robot: Any, finger: str, folder: Path, size: Size, seed: int
                    ) -> dict[str, Any]:
    """Identification logs of one finger on the hidden robot (its valve-less station, the
    other fingers parked), then the gap analysis on the nominal one-finger model."""
    from lowcostdex.gap import GapConfig, analyze, load_dataset, write_report
    from lowcostdex.hardware.hands import dclaw_spec
    from lowcostdex.hardware.robot.trace import dclaw_identification_logs
    from lowcostdex.sim.models.dclaw import build_dclaw

    hand = dclaw_spec(robot.motor)
    joints = tuple(j for j in hand.joint_names if j.startswith(finger + "_"))
    chain = robot.chain("none", rng=np.random.default_rng(seed))
    t0 = time.perf_counter()
    paths = dclaw_identification_logs(hand, joints, folder / "logs", size.id_logs,
                                      size.id_seconds, np.random.default_rng(seed),
                                      port=chain.port())
    t1 = time.perf_counter()
    nominal = folder / f"nominal_{finger}.xml"
    nominal.write_text(build_dclaw("none", hand, thermal=False, fingers=(finger,)).to_xml())
    dataset = load_dataset([str(p) for p in paths], model=str(nominal))
    result = analyze(dataset, GapConfig(seed=seed, **dict(size.gap)))
    write_report(result, folder / "report")
    report = read_json(folder / "report" / "report.json")
    causes = [{"effect": c["effect"], "joints": c["joints"],
               "params": {p: {"value": v["value"], "interval": v.get("interval")}
                          for p, v in c["params"].items()}} for c in report["causes"]]
    return {"finger": finger, "joints": list(joints), "verdict": report["verdict"],
            "causes": causes, "robot_seconds": size.id_logs * size.id_seconds,
            "baseline_rmse_mrad": 1e3 * report["gain"]["baseline_rmse"],
            "extended_rmse_mrad": 1e3 * report["gain"]["extended_rmse"],
            "noise_floor_mrad": 1e3 * report["noise_floor"]["rmse"],
            "record_wall_seconds": round(t1 - t0, 1),
            "analysis_wall_seconds": round(time.perf_counter() - t1, 1)}


def identify(robot: Any, out: Path, size: Size, seed: int) -> dict[str, Any]:
    fingers = {}
    for k, finger in enumerate(size.fingers):
        folder = out / "identify" / robot.name / finger
        fingers[finger] = cached(folder / "finger.json",
                                 lambda f=finger, d=folder, k=k: identify_finger(
                                     robot, f, d, size, seed + 17 * k))
        log(f"  {robot.name}/{finger}: named {[c['effect'] for c in fingers[finger]['causes']]} "
            f"({fingers[finger]['verdict']}; held-out "
            f"{fingers[finger]['baseline_rmse_mrad']:.2f} -> "
            f"{fingers[finger]['extended_rmse_mrad']:.2f} mrad)")
    return {"robot": robot.name, "fingers": fingers, "truth": robot.to_dict()}


def identified_effects(ident: dict[str, Any], joints: tuple[str, ...]
                       ) -> dict[str, dict[str, tuple[list[float], list[float], list[float]]]]:
    """The analysis' causes of every finger as one per-joint table: effect -> parameter ->
    (value, interval low, interval high) per hand joint; joints where the effect was not named
    hold its null value (its interval collapsed on it)."""
    from lowcostdex.sim.effects import effect

    table: dict[str, dict[str, tuple[list[float], list[float], list[float]]]] = {}
    for finger in ident["fingers"].values():
        for cause in finger["causes"]:
            cls = effect(cause["effect"])
            entry = table.setdefault(cls.name, {
                p.name: ([p.null] * len(joints), [p.null] * len(joints), [p.null] * len(joints))
                for p in cls.params})
            for p, v in cause["params"].items():
                values = np.broadcast_to(np.asarray(v["value"], float), (len(cause["joints"]),))
                interval = v.get("interval")
                for i, j in enumerate(cause["joints"]):
                    k = joints.index(j)
                    entry[p][0][k] = float(values[i])
                    lo, hi = (interval[i] if interval is not None and len(interval) > i
                              else (values[i], values[i]))
                    entry[p][1][k], entry[p][2][k] = float(lo), float(hi)
    return table


def condition_randomize(condition: str, ident: dict[str, Any] | None,
                        joints: tuple[str, ...]) -> Any:
    """The ``randomize`` env kwarg of a training condition (JSON-serializable)."""
    from lowcostdex.sim.effects import DEFAULT_DR_EFFECTS, DomainRandomization, effect

    if condition == "nominal":
        return None
    if condition == "randomized":
        return list(DEFAULT_DR_EFFECTS)
    assert ident is not None
    table = identified_effects(ident, joints)
    if not table:
        return None  # nothing named: the nominal model
    ranges: dict[str, dict[str, tuple[list[float], list[float]]]] = {}
    for name, params in table.items():
        ranges[name] = {}
        for p, (value, lo, hi) in params.items():
            if condition == "identified":
                ranges[name][p] = (value, value)
                continue
            param = effect(name).param(p)
            v, lo_, hi_ = (np.asarray(x, float) for x in (value, lo, hi))
            lo_ = np.where(np.isfinite(lo_), lo_, v)
            hi_ = np.where(np.isfinite(hi_), hi_, v)
            pad = NARROW_PAD * np.abs(v)
            named = v != param.null  # joints without the effect keep it off
            low = np.where(named, np.minimum(lo_, v - pad), v)
            high = np.where(named, np.maximum(hi_, v + pad), v)
            low = np.clip(low, param.low, param.high)
            high = np.clip(high, param.low, param.high)
            ranges[name][p] = (low.tolist(), np.maximum(high, low).tolist())
    return DomainRandomization(tuple(table), joints, ranges).to_dict()


# ------------------------------------------------------------------------------------------------
# 3. training and evaluation


def train_condition(run_dir: Path, task: Task, randomize: Any, demos: Path, size: Size,
                    seed: int) -> dict[str, Any]:
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import TrainConfig
    from lowcostdex.algos.train import train

    summary = run_dir / ex.SUMMARY_FILE
    if not summary.exists():
        import shutil

        if run_dir.exists():
            shutil.rmtree(run_dir)  # cut short: train again from the start
        extra = {} if randomize is None else {"randomize": randomize}
        config = TrainConfig(algo="dapg", env_id=task.env_id,
                             env_kwargs=task.make_kwargs(**extra),
                             seed=seed, n_iter=size.n_iter, n_traj=size.n_traj,
                             sampler="vector", n_workers=size.n_traj,
                             eval_every=size.eval_every, eval_episodes=size.eval_episodes,
                             demos=str(demos), progress=False)
        if size.bc_epochs is not None:
            config = replace(config, bc=replace(config.bc, epochs=size.bc_epochs))
        train(config, run_dir)
    metrics = ex.read_metrics(run_dir / ex.METRICS_FILE)
    s = read_json(summary)
    return {"samples": int(metrics[ex.SAMPLES][-1]),
            "wall_seconds": float(metrics[ex.WALL_SECONDS][-1]),
            "best_iteration": (s.get("best") or {}).get(ex.ITERATION),
            "final_training_success": float(metrics[ex.SUCCESS_RATE][-1])}


def evaluate(run_dir: Path, task: Task, env_kwargs: dict[str, Any], episodes: int
             ) -> dict[str, Any]:
    """Mean-action episodes of the run's policy; the same episode seeds for every cell."""
    import gymnasium as gym

    import lowcostdex  # noqa: F401
    from lowcostdex.algos.samplers import RolloutJob, rollout
    from lowcostdex.algos.train import load_policy

    policy = load_policy(run_dir).snapshot()
    env = gym.make(task.env_id, **task.make_kwargs(**env_kwargs))
    t0 = time.perf_counter()
    try:
        paths = [rollout(env, policy, RolloutJob(EVAL_SEED, 0, 0, i, deterministic=True))
                 for i in range(episodes)]
    finally:
        env.close()
    return {"successes": int(sum(bool(p.successes[-1]) for p in paths)), "episodes": episodes,
            "final_error": [round(float(p.final_goal_error), 4) for p in paths],
            "wall_seconds": round(time.perf_counter() - t0, 1)}


# ------------------------------------------------------------------------------------------------
# 4. table, figure


def _cell(successes: int, n: int) -> str:
    from lowcostdex.stats import wilson_interval

    lo, hi = wilson_interval(successes, n)
    return f"{successes / n:.2f} [{lo:.2f}, {hi:.2f}]"


def summarize(rows: list[dict[str, Any]], robots: list[str]) -> dict[str, dict[str, Any]]:
    """Per condition: pooled successes per robot (over seeds), on robots, in training sims."""
    out: dict[str, dict[str, Any]] = {}
    for cond in CONDITIONS:
        rs = [r for r in rows if r["condition"] == cond]
        if not rs:
            continue
        per_robot = {}
        for name in robots:
            cell = [r for r in rs if r["robot"] == name]
            per_robot[name] = (sum(r["success"] for r in cell), sum(r["episodes"] for r in cell))
        robot_k = sum(k for k, _ in per_robot.values())
        robot_n = sum(n for _, n in per_robot.values())
        # each policy's own-sim evaluation once (a nominal policy has one row per robot)
        sims = {(r["policy"], r["seed"]): r for r in rs}.values()
        sim_k = sum(r["sim_success"] for r in sims)
        sim_n = sum(r["sim_episodes"] for r in sims)
        identical = all(len(set(r["sim_final_error"])) == 1 for r in sims)
        errors = [e for r in rs for e in r["final_error"]]
        out[cond] = {"per_robot": per_robot, "robots": (robot_k, robot_n), "sim": (sim_k, sim_n),
                     "sim_identical": identical, "policies": len(sims),
                     "drop": sim_k / sim_n - robot_k / robot_n,
                     "median_final_error": float(np.median(errors)) if errors else math.nan}
    return out


def table_markdown(summary: dict[str, dict[str, Any]], robots: list[str]) -> str:
    head = ["condition", *[f"robot {r}" for r in robots], "mean on robots", "in training sim",
            "sim-to-robot drop", "median final error [rad]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cond, s in summary.items():
        cells = [_cell(*s["per_robot"][r]) for r in robots]
        sim = _cell(*s["sim"])
        if s["sim_identical"]:  # a deterministic policy from a fixed start in a fixed sim
            k, n = s["sim"]
            sim = f"{k / n:.2f} (one deterministic episode per policy, x{s['policies']})"
        lines.append("| " + " | ".join([cond, *cells, _cell(*s["robots"]), sim,
                                        f"{s['drop']:+.2f}", f"{s['median_final_error']:.2f}"])
                     + " |")
    return "\n".join(lines)


def plot(summary: dict[str, dict[str, Any]], robots: list[str], path: Path, title: str) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lowcostdex.stats import wilson_interval

    columns = [*robots, "mean"]
    fig, ax = plt.subplots(figsize=(9, 4.5))
    width = 0.8 / max(1, len(summary))
    colors = ["#888888", "#4c72b0", "#dd8452", "#55a868"]
    for i, (cond, s) in enumerate(summary.items()):
        cells = [s["per_robot"][r] for r in robots] + [s["robots"]]
        rate = np.array([k / n for k, n in cells])
        ci = np.array([wilson_interval(k, n) for k, n in cells])
        x = np.arange(len(columns)) + (i - (len(summary) - 1) / 2) * width
        ax.bar(x, rate, width, color=colors[i % len(colors)],
               label=f"{cond} (training sim {s['sim'][0] / s['sim'][1]:.2f})",
               yerr=[rate - ci[:, 0], ci[:, 1] - rate], capsize=3)
        ax.plot(x[-1:], [s["sim"][0] / s["sim"][1]], marker="_", markersize=14, color="k",
                linestyle="None", label="success in the training sim" if i == 0 else None)
    ax.set_xticks(np.arange(len(columns)))
    ax.set_xticklabels([f"robot {r}" for r in robots] + ["mean over robots"])
    ax.set_xlabel("hidden robot (emulated D'Claw)")
    ax.set_ylabel("success rate (95 % Wilson interval)")
    ax.set_ylim(0, 1.05)
    ax.set_title(title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return fig


def named_vs_truth(idents: dict[str, dict[str, Any]]) -> list[str]:
    """Per robot and finger: the catalogue effects it carries vs the ones the analysis named."""
    from lowcostdex.sim.effects import effect

    lines = ["| robot | finger | carries (catalogue) | named by gap analyze | held-out RMSE "
             "before -> after [mrad] |", "|---|---|---|---|---|"]
    for name, ident in idents.items():
        for finger, f in ident["fingers"].items():
            carried = []
            for e in ident["truth"]["effects"]:
                cls = effect(e["effect"])
                idx = [k for k, j in enumerate(e["joints"]) if j.startswith(finger + "_")]
                for p, values in e["params"].items():
                    if any(not np.isclose(values[k], cls.param(p).null) for k in idx):
                        carried.append(e["effect"])
                        break
            named = [c["effect"] for c in f["causes"]]
            lines.append(f"| {name} | {finger} | {', '.join(carried) or '-'} | "
                         f"{', '.join(named) or '-'} | {f['baseline_rmse_mrad']:.2f} -> "
                         f"{f['extended_rmse_mrad']:.2f} |")
    return lines


# ------------------------------------------------------------------------------------------------


def run(out: Path, size: Size, seeds: list[int], task_name: str, robot_seed: int = 0
        ) -> dict[str, Any]:
    """The whole table into ``out`` (resumable); returns the summary."""
    from lowcostdex.hardware.emulated.hidden_robots import hidden_robots
    from lowcostdex.hardware.hands import dclaw_spec

    task = TASKS[task_name]
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    robots = hidden_robots(size.robots, seed=robot_seed)
    joints = dclaw_spec().joint_names
    wall: dict[str, float] = {}

    t0 = time.perf_counter()
    log(f"demonstrations: {size.demos} by the virtual teacher on a nominal emulated D'Claw")
    demos = cached(out / "demos.json", lambda: record_demos(out, task, size, seeds[0]))
    wall["demos"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    idents = {}
    for robot in robots:
        log(f"identification of robot {robot.name}: {size.id_logs} x {size.id_seconds:g} s per "
            f"finger {size.fingers}")
        idents[robot.name] = identify(robot, out, size, seed=1000 + robot.seed)
    write_json(out / "identified.json", idents)
    wall["identification"] = time.perf_counter() - t0

    rows: list[dict[str, Any]] = []
    t_train = t_eval = 0.0
    for seed in seeds:
        jobs = [("nominal", None), ("randomized", None)]
        jobs += [(c, r) for c in ("identified", "identified_randomized") for r in robots]
        for condition, robot in jobs:
            ident = idents[robot.name] if robot is not None else None
            randomize = condition_randomize(condition, ident, joints)
            tag = condition if robot is None else f"{condition}_{robot.name}"
            run_dir = out / "runs" / f"{tag}_seed{seed}"
            t0 = time.perf_counter()
            log(f"seed {seed}: train DAPG, {condition}" + (f" (robot {robot.name})" if robot
                                                          else ""))
            trained = train_condition(run_dir, task, randomize, out / demos["file"], size, seed)
            t_train += time.perf_counter() - t0
            t0 = time.perf_counter()
            sim_kwargs = {} if randomize is None else {"randomize": randomize}
            sim = cached(run_dir.parent / f"{tag}_seed{seed}.sim.json",
                         lambda d=run_dir, k=sim_kwargs: evaluate(d, task, k, size.episodes))
            targets = robots if robot is None else [robot]
            for target in targets:
                cell = cached(run_dir.parent / f"{tag}_seed{seed}.on_{target.name}.json",
                              lambda t=target, d=run_dir: evaluate(d, task, t.env_kwargs(),
                                                                   size.episodes))
                rows.append({"condition": condition, "robot": target.name, "seed": seed,
                             "success": cell["successes"], "episodes": cell["episodes"],
                             "final_error": cell["final_error"],
                             "sim_success": sim["successes"], "sim_episodes": sim["episodes"],
                             "sim_final_error": sim["final_error"], "policy": tag,
                             "samples": trained["samples"],
                             "train_wall_seconds": round(trained["wall_seconds"], 1),
                             "eval_wall_seconds": cell["wall_seconds"]})
                log(f"  on robot {target.name}: {cell['successes']}/{cell['episodes']}, in its "
                    f"training sim {sim['successes']}/{sim['episodes']}")
            t_eval += time.perf_counter() - t0
    wall["training"], wall["evaluation"] = t_train, t_eval
    wall["total"] = time.perf_counter() - t_start
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu = usage.ru_utime + usage.ru_stime  # this process (the 2-core machine is shared)

    names = [r.name for r in robots]
    summary = summarize(rows, names)
    table = table_markdown(summary, names)
    truth = named_vs_truth(idents)
    title = (f"DAPG on {task.label()}: {len(seeds)} seed(s), "
             f"{size.n_iter * size.n_traj * 40 // 1000}k samples per policy")
    fig = plot(summary, names, out / "transfer.png", title)
    info = {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(),
            "cpus": __import__("os").cpu_count(), "task": task.label(), "seeds": seeds,
            "robot_seed": robot_seed, "size": asdict(size),
            "wall_seconds": {k: round(v, 1) for k, v in wall.items()},
            "cpu_seconds_this_invocation": round(cpu, 1)}
    write_json(out / "transfer.json", {"info": info, "rows": rows})
    text = "\n".join([f"# Transfer table: {title}", "", table, "",
                      "Identification (catalogue effects only; the MJCF perturbations and the "
                      "firmware imperfection have no catalogue name):", "", *truth, "",
                      "Wall-clock [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in wall.items())
                      + f" (pieces found done are not re-run); CPU of this invocation {cpu:.0f} s"])
    (out / "table.md").write_text(text + "\n")
    print(text, flush=True)
    return {"summary": summary, "rows": rows, "info": info, "figure": fig, "table": table}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="bench_runs/transfer")
    p.add_argument("--seeds", type=int, default=1, help="training seeds (0, 1, ...)")
    p.add_argument("--task", default="valve", choices=sorted(TASKS))
    p.add_argument("--robots", type=int, default=None, help="hidden robots (default by size)")
    p.add_argument("--robot-seed", type=int, default=0, help="the hidden robots' seed")
    p.add_argument("--episodes", type=int, default=None, help="evaluation episodes per cell")
    p.add_argument("--quick", action="store_true", help="tiny budget: checks the pipeline runs")
    args = p.parse_args(argv)
    size = SIZES["quick" if args.quick else "default"]
    if args.robots is not None:
        size = Size(**{**asdict(size), "robots": args.robots})
    if args.episodes is not None:
        size = Size(**{**asdict(size), "episodes": args.episodes})
    run(Path(args.out), size, list(range(args.seeds)), args.task, args.robot_seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
