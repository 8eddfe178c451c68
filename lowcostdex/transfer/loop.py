"""The transfer loop: identify the robot, train under each condition, evaluate on every robot.

Robots are the user's D'Claw on a serial port (``PortRobot``) or emulated hidden robots
(``lowcostdex.hardware.emulated.hidden_robots``: emulated D'Claws behind the real dynamixel_sdk
path, each with its own servo effects, MJCF perturbations no effect names and a firmware
imperfection; the training side never reads them). Every condition trains the same learner
(DAPG from the same demonstrations, or NPG) with the same sample budget:

  nominal                the nominal simulation;
  randomized             the nominal simulation with the project's domain randomization
                         (``effects.DEFAULT_DR_EFFECTS`` over their plausible D'Claw ranges);
  identified             the model ``gap analyze`` identified from identification logs recorded
                         on that robot (``trace.dclaw_identification_logs``: every finger, a
                         fixed budget of seconds), loaded into the sim as fixed per-joint
                         effects (one policy per robot);
  identified_randomized  the same with narrow randomization around the identified values (per
                         joint: the fitted 95 % interval, at least +-10 % of the value);
  on_robot               trained on the robot itself (serial sampling; wall-clock reported).

The demonstrations are recorded once, by the virtual teacher on a nominal emulated D'Claw (no
hidden robot), and shared by every DAPG policy. Each policy (the run's best evaluated one in its
own training environment) is evaluated with the mean action on every robot (a fresh robot per
cell, the same episode seeds everywhere) and in its own training sim; success rates carry 95 %
Wilson intervals (``lowcostdex.stats``). The sim-to-robot drop is success in the training sim
minus success on the robot. A policy made for one robot (identified, identified_randomized,
on_robot) is also evaluated on the other robots: the cross table says whether robot A's model
helps on robot B.

Everything lands in one output folder (``lowcostdex.outdir`` rules: a folder holding files the
command did not write is refused untouched): ``transfer.json`` (``{"info", "rows"}``, one row per
algorithm, condition, policy, robot and seed), ``table.md``, ``transfer.png``,
``identified.json`` (what the analysis named per robot and finger, beside the truth when the
robot is a hidden one), the demonstrations, identification logs and reports, the training runs
and every evaluation cell. Finished pieces are kept: running again on the same folder resumes
where it stopped (a training cut short resumes from its last checkpoint); the previous table
files move into ``previous/<time>/``.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

COMMAND = "transfer"
CONDITIONS = ("nominal", "randomized", "identified", "identified_randomized", "on_robot")
PER_ROBOT = ("identified", "identified_randomized", "on_robot")  # one policy per robot
ALGOS = ("dapg", "npg")
FINGERS = ("ff", "mf", "th")
EVAL_SEED = 20261125  # seeds of the evaluation episodes (same in every cell)
NARROW_PAD = 0.1  # identified_randomized: ranges at least +-10 % of each identified value
STEPS = 40  # steps per episode of the valve tasks (the sample count of an episode)
OUTPUTS = ("table.md", "transfer.json", "transfer.png", "identified.json")


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


@dataclass(frozen=True)
class Size:
    """How much each stage does.

    Attributes:
      robots: hidden robots (ignored with a port: one robot).
      seeds: training seeds (0, 1, ...).
      algos: learners ("dapg", "npg"), each trained under every condition.
      conditions: training conditions (subset of ``CONDITIONS``).
      demos: virtual-teacher demonstrations (each played back ``playbacks`` times).
      n_iter, n_traj: iterations and trajectories per iteration (the sample budget:
        ``n_iter * n_traj * 40`` steps per policy, every condition and learner).
      eval_every, eval_episodes: in-training evaluations (choose the run's policy).
      episodes: evaluation episodes per cell (policy x robot, policy x its sim).
      id_logs, id_seconds: identification logs per finger and their length [s].
      fingers: fingers identified (others keep the nominal model).
      gap: ``GapConfig`` overrides (the smoke size trims the search; default: none, what
        ``lowcostdex gap analyze`` does).
      bc_epochs: behaviour-cloning epochs before DAPG (None: the trainer's default).
    """

    robots: int
    seeds: int
    algos: tuple[str, ...]
    conditions: tuple[str, ...]
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

    def __post_init__(self) -> None:
        from lowcostdex.errors import ConfigError, check_choice

        for a in self.algos:
            check_choice("algo", a, ALGOS)
        for c in self.conditions:
            check_choice("condition", c, CONDITIONS)
        for f in self.fingers:
            check_choice("finger", f, FINGERS)
        for name in ("robots", "seeds", "demos", "n_iter", "n_traj", "episodes", "id_logs"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"size: {name} must be >= 1, got {getattr(self, name)}")
        if not self.algos or not self.conditions:
            raise ConfigError("size: give at least one algo and one condition")
        if not (self.id_seconds > 0 and math.isfinite(self.id_seconds)):
            raise ConfigError(f"size: id_seconds must be > 0 [s], got {self.id_seconds}")

    def budget(self) -> dict[str, Any]:
        """The settings that finished pieces were made with (a resume must keep them)."""
        d = asdict(self)
        for k in ("robots", "seeds", "algos", "conditions"):
            d.pop(k)
        return json.loads(json.dumps(d))

    @property
    def samples(self) -> int:
        return self.n_iter * self.n_traj * STEPS


SIZES = {
    # checks the loop end to end in well under a minute (2 robots, 1 seed, every condition)
    "smoke": Size(robots=2, seeds=1, algos=("dapg", "npg"), conditions=CONDITIONS, demos=2,
                  playbacks=1, n_iter=1, n_traj=4, eval_every=0, eval_episodes=2, episodes=2,
                  id_logs=3, id_seconds=3.0, fingers=("ff",),
                  gap=(("max_effects", 1), ("top_k", 2), ("search", "forward"),
                       ("bootstrap", 100), ("max_rounds", 5), ("rank_seconds", 3.0)),
                  bc_epochs=10),
    # the table of bench/RESULTS.md (48k samples per policy, 50 episodes per cell)
    "default": Size(robots=3, seeds=3, algos=("dapg", "npg"), conditions=CONDITIONS, demos=20,
                    playbacks=2, n_iter=30, n_traj=40, eval_every=5, eval_episodes=20,
                    episodes=50, id_logs=3, id_seconds=10.0),
    "long": Size(robots=3, seeds=3, algos=("dapg", "npg"), conditions=CONDITIONS, demos=40,
                 playbacks=2, n_iter=100, n_traj=40, eval_every=10, eval_episodes=20,
                 episodes=100, id_logs=6, id_seconds=10.0),
}


# ------------------------------------------------------------------------------------------------
# robots


@dataclass(frozen=True)
class PortRobot:
    """The user's D'Claw on a serial port (real, or an emulated one behind a pty)."""

    port: str
    name: str = "robot"
    motor: str = "XH430-W350"

    def env_kwargs(self) -> dict[str, Any]:
        return {"backend": "hardware", "port": self.port, "motor": self.motor}

    def identification_port(self, seed: int) -> str:
        return self.port

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "port": self.port, "motor": self.motor}


class HiddenRobotTarget:
    """A hidden robot as a loop target (its identification port is its station without the
    valve, a fresh emulated chain)."""

    def __init__(self, robot: Any) -> None:
        self.robot = robot
        self.name = robot.name
        self.motor = robot.motor

    def env_kwargs(self) -> dict[str, Any]:
        return self.robot.env_kwargs()

    def identification_port(self, seed: int) -> Any:
        return self.robot.chain("none", rng=np.random.default_rng(seed)).port()

    def to_dict(self) -> dict[str, Any]:
        return self.robot.to_dict()


def make_robots(n: int, robot_seed: int = 0, port: str | None = None) -> list[Any]:
    """The loop's robots: the one on ``port``, or ``n`` hidden robots drawn from ``robot_seed``."""
    if port is not None:
        return [PortRobot(port)]
    from lowcostdex.hardware.emulated.hidden_robots import hidden_robots

    return [HiddenRobotTarget(r) for r in hidden_robots(n, seed=robot_seed)]


@dataclass(frozen=True)
class HiddenRobotEnv:
    """``gym.make`` of the task on a hidden robot (picklable, rebuilt from its seed): the
    on_robot condition's environment; the robot's definition stays out of the run's config."""

    env_id: str
    task_kwargs: tuple[tuple[str, Any], ...]
    robot_seed: int
    robot_name: str

    def __call__(self) -> Any:
        import gymnasium as gym

        import lowcostdex.sim  # noqa: F401  (registers the ids)
        from lowcostdex.hardware.emulated.hidden_robots import hidden_robot

        robot = hidden_robot(self.robot_seed, self.robot_name)
        return gym.make(self.env_id, **dict(self.task_kwargs), **robot.env_kwargs())


# ------------------------------------------------------------------------------------------------
# small helpers

Say = Callable[[str], None]


def say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())


def write_json(path: Path, obj: Any) -> None:
    from lowcostdex.outdir import write_text_atomic

    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(obj, indent=1))


def cached(path: Path, make: Callable[[], Any]) -> Any:
    """``make()``'s JSON result, computed once and kept in ``path`` (resume)."""
    if path.exists():
        return read_json(path)
    value = make()
    write_json(path, value)
    return value


class Progress:
    """Progress lines over the loop's pieces (identifications, trainings, evaluation cells):
    ``[progress] transfer: k/N pieces (x %), elapsed, about T left``; pieces found done count
    as done without counting toward the rate."""

    def __init__(self, total: int, out: Say) -> None:
        self.total, self.done, self.skipped = total, 0, 0
        self.t0 = time.monotonic()
        self.out = out

    def step(self, what: str, was_cached: bool) -> None:
        from lowcostdex.progress import line

        self.done += 1
        self.skipped += was_cached
        text = line("transfer", self.done, self.total, time.monotonic() - self.t0, "pieces",
                    postfix=what + (" (found done)" if was_cached else ""), start=self.skipped)
        self.out(text)


# ------------------------------------------------------------------------------------------------
# 1. demonstrations: the virtual teacher on a nominal emulated D'Claw


def record_demos(out: Path, task: Task, size: Size, seed: int) -> dict[str, Any]:
    import gymnasium as gym

    import lowcostdex.sim  # noqa: F401  (registers the ids)
    from lowcostdex.demonstrations.kinesthetic import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.demonstrations.teachers.valve import ValveTurnTeacher
    from lowcostdex.outdir import archive

    path = out / "demos.h5"
    archive(out, [path.name])  # a recording cut short is redone whole (the old one kept)
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
# 2. identification: record on the robot, `gap analyze` each finger


def identify_finger(robot: Any, finger: str, folder: Path, size: Size, seed: int
                    ) -> dict[str, Any]:
    """Identification logs of one finger on the robot (without its valve, the other fingers
    parked), then the gap analysis on the nominal one-finger model."""
    from lowcostdex.gap import GapConfig, analyze, load_dataset, write_report
    from lowcostdex.hardware.hands import dclaw_spec
    from lowcostdex.hardware.robot.trace import dclaw_identification_logs
    from lowcostdex.outdir import archive
    from lowcostdex.sim.models.dclaw import build_dclaw

    nominal = folder / f"nominal_{finger}.xml"
    if folder.exists():  # cut short: redone whole, the old pieces kept
        archive(folder, ["logs", "report", nominal.name])
    folder.mkdir(parents=True, exist_ok=True)
    hand = dclaw_spec(robot.motor)
    joints = tuple(j for j in hand.joint_names if j.startswith(finger + "_"))
    t0 = time.perf_counter()
    paths = dclaw_identification_logs(hand, joints, folder / "logs", size.id_logs,
                                      size.id_seconds, np.random.default_rng(seed),
                                      port=robot.identification_port(seed))
    t1 = time.perf_counter()
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


def identify(robot: Any, out: Path, size: Size, seed: int, progress: Progress,
             tell: Say) -> dict[str, Any]:
    fingers = {}
    for k, finger in enumerate(size.fingers):
        folder = out / "identify" / robot.name / finger
        done = (folder / "finger.json").exists()
        fingers[finger] = cached(folder / "finger.json",
                                 lambda f=finger, d=folder, k=k: identify_finger(
                                     robot, f, d, size, seed + 17 * k))
        f = fingers[finger]
        tell(f"  {robot.name}/{finger}: named {[c['effect'] for c in f['causes']]} "
             f"({f['verdict']}; held-out {f['baseline_rmse_mrad']:.2f} -> "
             f"{f['extended_rmse_mrad']:.2f} mrad)")
        progress.step(f"identified {robot.name}/{finger}", done)
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
    """The ``randomize`` env kwarg of a simulated training condition (JSON-serializable)."""
    from lowcostdex.sim.effects import DEFAULT_DR_EFFECTS, DomainRandomization, effect

    if condition == "nominal":
        return None
    if condition == "randomized":
        return list(DEFAULT_DR_EFFECTS)
    if condition not in ("identified", "identified_randomized"):
        raise ValueError(f"{condition!r} is not a simulated condition")
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


def train_policy(run_dir: Path, algo: str, task: Task, randomize: Any, demos: Path | None,
                 size: Size, seed: int, robot: Any = None, robot_seed: int | None = None
                 ) -> dict[str, Any]:
    """Train one policy into ``run_dir`` (resumes a run cut short); ``robot``: train on it
    (on_robot, serial sampling) instead of in simulation."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import TrainConfig
    from lowcostdex.algos.train import train

    summary = run_dir / ex.SUMMARY_FILE
    if not summary.exists():
        resume = (run_dir / ex.CHECKPOINT_DIR / ex.LATEST_FILE).exists()
        extra = {} if randomize is None else {"randomize": randomize}
        common = dict(algo=algo, env_id=task.env_id, seed=seed, n_iter=size.n_iter,
                      n_traj=size.n_traj, eval_every=size.eval_every,
                      eval_episodes=size.eval_episodes,
                      demos=str(demos) if algo == "dapg" else None, progress=False)
        factory = None
        if robot is None:
            config = TrainConfig(**common, env_kwargs=task.make_kwargs(**extra),
                                 sampler="vector", n_workers=size.n_traj)
        elif isinstance(robot, PortRobot):
            config = TrainConfig(**common, env_kwargs=task.make_kwargs(port=robot.port,
                                                                       motor=robot.motor),
                                 backend="hardware", sampler="serial")
        else:  # a hidden robot: its definition stays out of the run's config
            config = TrainConfig(**common, env_kwargs=task.make_kwargs(), backend="emulated",
                                 sampler="serial")
            assert robot_seed is not None
            factory = HiddenRobotEnv(task.env_id, task.kwargs, robot_seed, robot.name)
        if algo == "dapg" and size.bc_epochs is not None:
            config = replace(config, bc=replace(config.bc, epochs=size.bc_epochs))
        train(config, run_dir, resume=resume, env_factory=factory)
    metrics = ex.read_metrics(run_dir / ex.METRICS_FILE)
    s = read_json(summary)
    out = {"samples": int(metrics[ex.SAMPLES][-1]),
           "wall_seconds": float(metrics[ex.WALL_SECONDS][-1]),
           "best_iteration": (s.get("best") or {}).get(ex.ITERATION),
           "final_training_success": float(metrics[ex.SUCCESS_RATE][-1])}
    if ex.ROBOT_HOURS in metrics:
        out["robot_hours"] = float(metrics[ex.ROBOT_HOURS][-1])
    return out


def evaluate(run_dir: Path, task: Task, env_kwargs: dict[str, Any], episodes: int
             ) -> dict[str, Any]:
    """Mean-action episodes of the run's policy; the same episode seeds for every cell."""
    import gymnasium as gym

    import lowcostdex.sim  # noqa: F401  (registers the ids)
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
# 4. tables, figure


def _cell(successes: int, n: int) -> str:
    from lowcostdex.stats import wilson_interval

    if n == 0:
        return "-"
    lo, hi = wilson_interval(successes, n)
    return f"{successes / n:.2f} [{lo:.2f}, {hi:.2f}]"


def own_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows of policies on the robot they were made for (or, for nominal and randomized, made
    for none): the main table."""
    return [r for r in rows if r["policy_robot"] in (None, r["robot"])]


def summarize(rows: list[dict[str, Any]], robots: list[str]) -> dict[str, dict[str, Any]]:
    """Per condition (rows of one algo): pooled successes per robot (over seeds), on robots, in
    training sims; only each policy on the robot it was made for."""
    out: dict[str, dict[str, Any]] = {}
    for cond in CONDITIONS:
        rs = [r for r in own_rows(rows) if r["condition"] == cond]
        if not rs:
            continue
        per_robot = {}
        for name in robots:
            cell = [r for r in rs if r["robot"] == name]
            per_robot[name] = (sum(r["success"] for r in cell), sum(r["episodes"] for r in cell))
        robot_k = sum(k for k, _ in per_robot.values())
        robot_n = sum(n for _, n in per_robot.values())
        # each policy's own-sim evaluation once (a nominal policy has one row per robot)
        sims = list({(r["policy"], r["seed"]): r for r in rs}.values())
        sim_k = sum(r["sim_success"] for r in sims)
        sim_n = sum(r["sim_episodes"] for r in sims)
        identical = all(len(set(r["sim_final_error"])) == 1 for r in sims)
        errors = [e for r in rs for e in r["final_error"]]
        out[cond] = {"per_robot": per_robot, "robots": (robot_k, robot_n), "sim": (sim_k, sim_n),
                     "sim_identical": identical, "policies": len(sims),
                     "drop": sim_k / sim_n - robot_k / robot_n,
                     "median_final_error": float(np.median(errors)) if errors else math.nan,
                     "train_wall_seconds": float(np.mean([r["train_wall_seconds"]
                                                          for r in sims]))}
    return out


def table_markdown(summary: dict[str, dict[str, Any]], robots: list[str]) -> str:
    head = ["condition", *[f"robot {r}" for r in robots], "mean on robots",
            "in training sim (on_robot: the robot)", "sim-to-robot drop",
            "median final error [rad]", "training wall [s]"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cond, s in summary.items():
        cells = [_cell(*s["per_robot"][r]) for r in robots]
        sim = _cell(*s["sim"])
        if s["sim_identical"]:  # a deterministic policy from a fixed start in a fixed sim
            k, n = s["sim"]
            sim = f"{k / n:.2f} (one deterministic episode per policy, x{s['policies']})"
        lines.append("| " + " | ".join([cond, *cells, _cell(*s["robots"]), sim,
                                        f"{s['drop']:+.2f}", f"{s['median_final_error']:.2f}",
                                        f"{s['train_wall_seconds']:.0f}"]) + " |")
    return "\n".join(lines)


def cross_markdown(rows: list[dict[str, Any]], robots: list[str]) -> str:
    """Per-robot policies (rows: made for robot X) on every robot (columns), pooled over seeds,
    beside the nominal policy on the same robot: does robot A's model help on robot B?"""
    head = ["condition", "made for", *[f"on robot {r}" for r in robots]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]

    def pooled(rs: list[dict[str, Any]]) -> str:
        return _cell(sum(r["success"] for r in rs), sum(r["episodes"] for r in rs))

    nominal = [r for r in rows if r["condition"] == "nominal"]
    if nominal:
        lines.append("| " + " | ".join(["nominal", "-", *[
            pooled([r for r in nominal if r["robot"] == y]) for y in robots]]) + " |")
    for cond in PER_ROBOT:
        for x in robots:
            rs = [r for r in rows if r["condition"] == cond and r["policy_robot"] == x]
            if not rs:
                continue
            cells = []
            for y in robots:
                c = pooled([r for r in rs if r["robot"] == y])
                cells.append(f"**{c}**" if x == y else c)
            lines.append("| " + " | ".join([cond, x, *cells]) + " |")
    if len(lines) == 2:
        return ""
    off = {}
    for cond in PER_ROBOT:
        rs = [r for r in rows if r["condition"] == cond and r["policy_robot"] is not None]
        other = [r for r in rs if r["policy_robot"] != r["robot"]]
        own = [r for r in rs if r["policy_robot"] == r["robot"]]
        if other:
            off[cond] = (pooled(own), pooled(other))
    summary = "; ".join(f"{c}: own robot {a}, other robots {b}" for c, (a, b) in off.items())
    return "\n".join(lines) + ("\n\nPooled: " + summary if summary else "")


def plot(summaries: dict[str, dict[str, dict[str, Any]]], robots: list[str], path: Path,
         title: str) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from lowcostdex.stats import wilson_interval

    columns = [*robots, "mean"]
    fig, axes = plt.subplots(1, len(summaries), figsize=(7 * len(summaries) + 2.5, 4.5),
                             squeeze=False)
    colors = {"nominal": "#888888", "randomized": "#4c72b0", "identified": "#dd8452",
              "identified_randomized": "#55a868", "on_robot": "#c44e52"}
    for ax, (algo, summary) in zip(axes[0], summaries.items(), strict=True):
        width = 0.8 / max(1, len(summary))
        for i, (cond, s) in enumerate(summary.items()):
            cells = [s["per_robot"][r] for r in robots] + [s["robots"]]
            rate = np.array([k / n if n else np.nan for k, n in cells])
            ci = np.array([wilson_interval(k, n) if n else (np.nan, np.nan) for k, n in cells])
            x = np.arange(len(columns)) + (i - (len(summary) - 1) / 2) * width
            ax.bar(x, rate, width, color=colors[cond],
                   label=f"{cond} (training env {s['sim'][0] / s['sim'][1]:.2f})",
                   yerr=[rate - ci[:, 0], ci[:, 1] - rate], capsize=3)
            ax.plot(x[-1:], [s["sim"][0] / s["sim"][1]], marker="_", markersize=14, color="k",
                    linestyle="None", label="success in the training env" if i == 0 else None)
        ax.set_xticks(np.arange(len(columns)))
        ax.set_xticklabels([f"robot {r}" for r in robots] + ["mean over robots"])
        ax.set_xlabel("robot (policies on the robot they were made for)")
        ax.set_ylabel("success rate (95 % Wilson interval)")
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{algo.upper()}: {title}", fontsize=9)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return fig


def named_vs_truth(idents: dict[str, dict[str, Any]]) -> list[str]:
    """Per robot and finger: the catalogue effects it carries (hidden robots) vs the ones the
    analysis named."""
    from lowcostdex.sim.effects import effect

    lines = ["| robot | finger | carries (catalogue) | named by gap analyze | held-out RMSE "
             "before -> after [mrad] |", "|---|---|---|---|---|"]
    for name, ident in idents.items():
        for finger, f in ident["fingers"].items():
            carried = []
            for e in ident["truth"].get("effects", ()):
                cls = effect(e["effect"])
                idx = [k for k, j in enumerate(e["joints"]) if j.startswith(finger + "_")]
                for p, values in e["params"].items():
                    if any(not np.isclose(values[k], cls.param(p).null) for k in idx):
                        carried.append(e["effect"])
                        break
            truth = (", ".join(carried) or "-") if "effects" in ident["truth"] else "unknown"
            named = [c["effect"] for c in f["causes"]]
            lines.append(f"| {name} | {finger} | {truth} | {', '.join(named) or '-'} | "
                         f"{f['baseline_rmse_mrad']:.2f} -> {f['extended_rmse_mrad']:.2f} |")
    return lines


# ------------------------------------------------------------------------------------------------


def settings(size: Size, task_name: str, robot_seed: int, port: str | None) -> dict[str, Any]:
    """The output folder's settings; a resume must keep all of them (pieces build on them)."""
    return {"task": task_name, "robot_seed": None if port else robot_seed, "port": port,
            "budget": size.budget()}


def open_out(out: Path, size: Size, task_name: str, robot_seed: int, port: str | None) -> bool:
    """Check ``out`` (``lowcostdex.outdir`` rules) and mark it; True when it held a run."""
    from lowcostdex.outdir import check_out, write_marker

    s = settings(size, task_name, robot_seed, port)
    previous = check_out(out, COMMAND, s, must_match=tuple(s))
    write_marker(out, COMMAND, s)
    return previous


def run(out: str | Path, size: Size, task_name: str = "valve", robot_seed: int = 0,
        port: str | None = None, tell: Say = say) -> dict[str, Any]:
    """The whole loop into ``out`` (resumable); returns the summaries, rows and figure.

    Raises:
      OutputRefused: ``out`` holds files this command did not write, or a run with another
        task, robots or budget.
    """
    from lowcostdex.errors import check_choice
    from lowcostdex.hardware.hands import dclaw_spec
    from lowcostdex.outdir import archive

    check_choice("task", task_name, tuple(TASKS))
    out = Path(out)
    task = TASKS[task_name]
    robots = make_robots(size.robots, robot_seed, port)
    open_out(out, size, task_name, robot_seed, port)
    seeds = list(range(size.seeds))
    t_start = time.perf_counter()
    joints = dclaw_spec().joint_names
    names = [r.name for r in robots]
    wall: dict[str, float] = {}

    n_id = len(robots) * len(size.fingers) if {"identified", "identified_randomized"} & set(
        size.conditions) else 0
    per_seed = 0
    for cond in size.conditions:
        policies = len(robots) if cond in PER_ROBOT else 1
        # training, its own-sim evaluation (on_robot: none) and a cell per robot
        per_seed += policies * (1 + (cond != "on_robot") + len(robots))
    progress = Progress(n_id + len(seeds) * len(size.algos) * per_seed, tell)
    tell(f"transfer: {task.label()}, robots {', '.join(names)}, seeds {seeds}, algos "
         f"{list(size.algos)}, conditions {list(size.conditions)}; {size.samples} samples per "
         f"policy, {size.episodes} episodes per cell -> {out}")

    demos = None
    if "dapg" in size.algos:
        t0 = time.perf_counter()
        tell(f"demonstrations: {size.demos} by the virtual teacher on a nominal emulated D'Claw")
        demos = cached(out / "demos.json", lambda: record_demos(out, task, size, seeds[0]))
        wall["demos"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    idents: dict[str, dict[str, Any]] = {}
    if n_id:
        for k, robot in enumerate(robots):
            tell(f"identification of robot {robot.name}: {size.id_logs} x {size.id_seconds:g} s "
                 f"per finger {list(size.fingers)}")
            idents[robot.name] = identify(robot, out, size, 1000 + robot_seed + k, progress,
                                          tell)
    wall["identification"] = time.perf_counter() - t0
    if port is not None and progress.done > progress.skipped:
        # the identification ran with the valve off: the user puts it back, then resumes
        tell(f"identification done ({out / 'identify'}). Put the valve back on and run the "
             "same command again: it continues with training and evaluation.")
        return {"stopped": "after identification", "identified": idents}

    rows: list[dict[str, Any]] = []
    t_train = t_eval = 0.0
    for algo in size.algos:
        for seed in seeds:
            jobs: list[tuple[str, Any]] = [(c, None) for c in size.conditions
                                           if c not in PER_ROBOT]
            jobs += [(c, r) for c in size.conditions if c in PER_ROBOT for r in robots]
            for condition, made_for in jobs:
                tag = condition if made_for is None else f"{condition}_{made_for.name}"
                run_dir = out / "runs" / algo / f"{tag}_seed{seed}"
                on_robot = condition == "on_robot"
                randomize = None if on_robot else condition_randomize(
                    condition, idents.get(made_for.name) if made_for else None, joints)
                where = f" for robot {made_for.name}" if made_for else ""
                t0 = time.perf_counter()
                done = (run_dir / "summary.json").exists()
                if not done:
                    tell(f"{algo} seed {seed}: train {condition}{where}")
                trained = train_policy(run_dir, algo, task, randomize,
                                       out / demos["file"] if demos else None, size, seed,
                                       robot=made_for if on_robot else None,
                                       robot_seed=(robot_seed + names.index(made_for.name)
                                                   if made_for else None))
                t_train += time.perf_counter() - t0
                progress.step(f"trained {algo} {condition}{where} seed {seed} "
                              f"({trained['wall_seconds']:.0f} s)", done)
                t0 = time.perf_counter()
                cells: dict[str, dict[str, Any]] = {}
                for target in robots:
                    path = run_dir.parent / f"{tag}_seed{seed}.on_{target.name}.json"
                    done = path.exists()
                    cells[target.name] = cached(path, lambda t=target, d=run_dir: evaluate(
                        d, task, t.env_kwargs(), size.episodes))
                    c = cells[target.name]
                    progress.step(f"{algo} {tag} seed {seed} on robot {target.name}: "
                                  f"{c['successes']}/{c['episodes']}", done)
                if on_robot:  # its training environment is the robot
                    sim = cells[made_for.name]
                else:
                    path = run_dir.parent / f"{tag}_seed{seed}.sim.json"
                    done = path.exists()
                    sim = cached(path, lambda d=run_dir, r=randomize: evaluate(
                        d, task, {} if r is None else {"randomize": r}, size.episodes))
                    progress.step(f"{algo} {tag} seed {seed} in its training sim: "
                                  f"{sim['successes']}/{sim['episodes']}", done)
                for target in robots:
                    cell = cells[target.name]
                    rows.append({"algo": algo, "condition": condition, "robot": target.name,
                                 "seed": seed, "success": cell["successes"],
                                 "episodes": cell["episodes"],
                                 "policy_robot": made_for.name if made_for else None,
                                 "final_error": cell["final_error"],
                                 "sim_success": sim["successes"], "sim_episodes": sim["episodes"],
                                 "sim_final_error": sim["final_error"],
                                 "policy": f"{algo}/{tag}",
                                 "samples": trained["samples"],
                                 "train_wall_seconds": round(trained["wall_seconds"], 1),
                                 "robot_hours": trained.get("robot_hours"),
                                 "eval_wall_seconds": cell["wall_seconds"]})
                t_eval += time.perf_counter() - t0
    wall["training"], wall["evaluation"] = t_train, t_eval
    wall["total"] = time.perf_counter() - t_start
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu = usage.ru_utime + usage.ru_stime  # this process (the 2-core machine is shared)

    summaries = {a: summarize([r for r in rows if r["algo"] == a], names) for a in size.algos}
    title = (f"{task.label()}: {len(seeds)} seed(s), {size.samples // 1000}k samples per "
             "policy" if size.samples >= 1000 else
             f"{task.label()}: {len(seeds)} seed(s), {size.samples} samples per policy")
    archive(out, OUTPUTS)  # the previous table files move into previous/<time>/
    write_json(out / "identified.json", idents)
    fig = plot(summaries, names, out / "transfer.png", title)
    info = {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(),
            "cpus": os.cpu_count(), "load": [round(x, 1) for x in os.getloadavg()],
            "task": task.label(), "seeds": seeds, "algos": list(size.algos),
            "conditions": list(size.conditions), "robots": [r.to_dict()["name"] for r in robots],
            "robot_seed": None if port else robot_seed, "port": port, "size": asdict(size),
            "wall_seconds": {k: round(v, 1) for k, v in wall.items()},
            "cpu_seconds_this_invocation": round(cpu, 1)}
    write_json(out / "transfer.json", {"info": info, "rows": rows})
    parts = [f"# Transfer table: {title}", ""]
    for algo, summary in summaries.items():
        parts += [f"## {algo.upper()}: each policy on the robot it was made for", "",
                  table_markdown(summary, names), ""]
        cross = cross_markdown([r for r in rows if r["algo"] == algo], names)
        if cross and len(robots) > 1:
            parts += [f"### {algo.upper()}: policies made for one robot on every robot "
                      "(bold: its own robot)", "", cross, ""]
    if idents:
        parts += ["## Identification (catalogue effects only; a hidden robot's MJCF "
                  "perturbations and firmware imperfection have no catalogue name)", "",
                  *named_vs_truth(idents), ""]
    parts.append("Wall-clock [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in wall.items())
                 + f" (pieces found done are not re-run); CPU of this invocation {cpu:.0f} s")
    text = "\n".join(parts)
    (out / "table.md").write_text(text + "\n")
    tell(f"wrote {out / 'table.md'}, {out / 'transfer.json'}, {out / 'transfer.png'}")
    return {"summaries": summaries, "rows": rows, "info": info, "figure": fig, "text": text}


def size_with(name: str, **overrides: Any) -> Size:
    """A named size with some fields replaced (None values are ignored)."""
    from lowcostdex.errors import check_choice

    check_choice("size", name, tuple(SIZES))
    return replace(SIZES[name], **{k: v for k, v in overrides.items() if v is not None})


def parse_list(text: str | None, valid: Sequence[str], what: str) -> tuple[str, ...] | None:
    """``"a,b"`` -> ``("a", "b")`` checked against ``valid``; None stays None."""
    from lowcostdex.errors import check_choice

    if text is None:
        return None
    items = tuple(s.strip() for s in text.split(",") if s.strip())
    for s in items:
        check_choice(what, s, tuple(valid))
    return items
