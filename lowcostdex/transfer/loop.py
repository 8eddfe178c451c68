"""The transfer loop: identify the robot, train under each condition, evaluate on every robot.

Robots are the user's D'Claw on a serial port (``PortRobot``) or emulated hidden robots
(``lowcostdex.hardware.emulated.hidden_robots``: emulated D'Claws behind the real dynamixel_sdk
path, each with its own servo effects, MJCF perturbations no effect names and a firmware
imperfection; the training side never reads them). Every condition trains the same learner
(DAPG from the same demonstrations, or NPG) with the same sample budget (a simulated policy
below the success target in its own sim at the end trains on, once, up to ``config.EXTEND`` x the
budget; the samples each policy used are in its row):

  nominal                the nominal simulation;
  randomized             the nominal simulation with the project's domain randomization
                         (``effects.DEFAULT_DR_EFFECTS`` over their plausible D'Claw ranges);
  identified             the model ``gap analyze`` identified from identification logs recorded
                         on that robot (``trace.dclaw_identification_logs``: every finger, a
                         fixed budget of seconds), loaded into the sim as fixed per-joint
                         effects (one policy per robot); with ``Size.valve_episodes`` also the
                         D'Claw geometry and valve fitted to a valve log recorded on that robot
                         (``transfer.valve_fit``: a finger base's tilt, the valve's friction /
                         damping / inertia, the link lengths), as the tasks' ``model_edit``;
  identified_randomized  the same with narrow randomization around the identified values (per
                         joint: the fitted 95 % interval, at least +-10 % of the value; the
                         valve's friction and damping drawn per episode around the valve-log
                         fit: ``valve_fit.valve_ranges``, the rest of the edit held);
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
command did not write is refused untouched): ``transfer.json`` (``{"info", "rows", "cells"}``: one
row per algorithm, condition, policy, robot and seed; one cell per algorithm, condition and robot
with success at the task's tolerance and at ``LOOSE_TOL`` and the final error's median, its
interval and each seed's median), ``table.md``, ``transfer.png``,
``identified.json`` (what the analysis named per robot and finger, beside the truth when the
robot is a hidden one), the demonstrations, identification logs and reports, the training runs
and every evaluation cell. Finished pieces are kept: running again on the same folder resumes
where it stopped (a training cut short resumes from its last checkpoint); the previous table
files move into ``previous/<time>/``.
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.transfer.conditions import (
    condition_model,
    condition_randomize,
    identified_effects,
    identify_finger,
)
from lowcostdex.transfer.config import (
    ALGOS,
    COMMAND,
    CONDITIONS,
    EVAL_SEED,
    FINGERS,
    LOOSE_TOL,
    NARROW_PAD,
    OUTPUTS,
    PER_ROBOT,
    SIZES,
    STEPS,
    TASKS,
    VALVE_FIT_FILE,
    Size,
    Task,
    parse_list,
    size_with,
)
from lowcostdex.transfer.pieces import jobs, piece_files, run_tag
from lowcostdex.transfer.robots import HiddenRobotEnv, HiddenRobotTarget, PortRobot, make_robots
from lowcostdex.transfer.tables import (
    cells_json,
    cost_markdown,
    cross_markdown,
    errors_markdown,
    extended_lines,
    loose_successes,
    named_vs_truth,
    own_rows,
    paired_markdown,
    plot,
    summarize,
    table_markdown,
)
from lowcostdex.transfer.training import (
    evaluate,
    extension,
    read_json,
    sim_kwargs,
    train_policy,
    write_json,
)

__all__ = [
    "ALGOS", "COMMAND", "CONDITIONS", "EVAL_SEED", "FINGERS", "LOOSE_TOL", "NARROW_PAD", "OUTPUTS",
    "PER_ROBOT", "SIZES", "STEPS", "TASKS", "HiddenRobotEnv", "HiddenRobotTarget", "PortRobot",
    "Progress", "Size", "Task", "cells_json", "condition_randomize", "cross_markdown",
    "errors_markdown", "evaluate", "identified_effects", "identify", "identify_finger",
    "make_robots", "named_vs_truth", "own_rows", "paired_markdown", "parse_list", "plot",
    "record_demos", "run",
    "settings", "size_with", "summarize", "table_markdown", "train_policy",
]

# ------------------------------------------------------------------------------------------------
# small helpers

Say = Callable[[str], None]


def say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def cached(path: Path, make: Callable[[], Any]) -> Any:
    """``make()``'s JSON result, computed once and kept in ``path`` (resume)."""
    if path.exists():
        return read_json(path)
    value = make()
    write_json(path, value)
    return value


class Progress:
    """Progress lines over the loop's pieces (identifications, trainings, evaluation cells):
    ``[progress] transfer: k/N pieces (x %), elapsed, about T left``. Pieces found done count
    as done without counting toward the rate, and the time left counts only the pieces still
    to run: ``found`` pieces were done when the run started (a resume), each reported once.
    """

    def __init__(self, total: int, out: Say, found: int = 0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.total, self.found, self.done, self.skipped = total, found, 0, 0
        self.clock = clock
        self.t0 = clock()
        self.out = out

    def step(self, what: str, was_cached: bool) -> None:
        from lowcostdex.progress import line

        self.done += 1
        self.skipped += was_cached
        todo = (self.total - self.done) - max(0, self.found - self.skipped)
        text = line("transfer", self.done, self.total, self.clock() - self.t0, "pieces",
                    postfix=what + (" (found done)" if was_cached else ""), start=self.skipped,
                    todo=max(0, todo))
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
    from lowcostdex.outdir import archive
    from lowcostdex.teachers.valve import ValveTurnTeacher

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


def valve_log_fit(robot: Any, out: Path, task: Task, size: Size, ident: dict[str, Any],
                  joints: tuple[str, ...], progress: Progress, tell: Say) -> dict[str, Any]:
    """The robot's valve-log fit (``transfer.valve_fit``) in its identified model: the
    identified conditions' MJCF edit. Once per robot (a resume keeps it)."""
    from lowcostdex.transfer.valve_fit import DESIGNS, describe, fit_valve_log

    path = out / "identify" / robot.name / VALVE_FIT_FILE
    done = path.exists()
    if not done:
        tell(f"valve-log fit of robot {robot.name}: it plays {size.valve_episodes} valve "
             f"episodes from the demonstrations ({', '.join(DESIGNS[:size.valve_episodes])}), "
             f"then a base tilt of {list(size.valve_fingers)}, the valve and the link lengths "
             "are fitted in its identified model")
    fit = cached(path, lambda: fit_valve_log(
        robot.env_kwargs(), task.env_id, dict(task.kwargs), out / "demos.h5",
        condition_randomize("identified", ident, joints), size.valve_episodes,
        size.valve_fingers, dict(size.valve_fit)))
    tell(f"  {robot.name}: {describe(fit)}")
    progress.step(f"valve-log fit of robot {robot.name}", done)
    return fit


# ------------------------------------------------------------------------------------------------


def redo_extended(out: Path, size: Size, robots: list[Any], made_for: tuple[str, ...] | None,
                  seeds: list[int]) -> list[str]:
    """Finished simulated runs that the EXTEND rule will train on (a folder made before the
    rule, resumed): their evaluation cells evaluated the shorter policy, so they move into
    ``previous/<time>/`` and are redone after the run trains on. Returns one note per run."""
    from lowcostdex.outdir import archive

    notes = []
    for algo in size.algos:
        for seed in seeds:
            for condition, policy_robot in jobs(size.conditions, robots, made_for):
                run_dir = out / "runs" / algo / f"{run_tag(condition, policy_robot)}_seed{seed}"
                more = extension(run_dir, size, simulated=condition != "on_robot")
                if more is None:
                    continue
                final = read_json(run_dir / "summary.json")["final"]
                cells = [p.relative_to(out) for p in run_dir.parent.glob(run_dir.name + ".*.json")]
                moved = archive(out, [str(c) for c in cells])
                notes.append(
                    f"{algo} {run_tag(condition, policy_robot)} seed {seed}: finished at "
                    f"{final['eval_success_rate']:.2f} in its own sim (iteration "
                    f"{final['iteration']}), below its target: it trains on to {more} "
                    f"iterations (the EXTEND rule)"
                    + (f"; its {len(cells)} evaluation cells moved to {moved} and are redone"
                       if moved else ""))
    return notes


def settings(size: Size, task_name: str, robot_seed: int, port: str | None,
             start_range: float = 0.0) -> dict[str, Any]:
    """The output folder's settings; a resume must keep all of them (pieces build on them).
    ``start_range`` is one only when set (folders made before it existed still resume; one
    without it was trained from the task's starts: ``open_out`` reads it as 0)."""
    s = {"task": task_name, "robot_seed": None if port else robot_seed, "port": port,
         "budget": size.budget()}
    return {**s, "start_range": start_range} if start_range else s


def open_out(out: Path, size: Size, task_name: str, robot_seed: int, port: str | None,
             start_range: float = 0.0) -> bool:
    """Check ``out`` (``lowcostdex.outdir`` rules) and mark it; True when it held a run."""
    from lowcostdex.outdir import check_out, write_marker

    s = settings(size, task_name, robot_seed, port, start_range)
    previous = check_out(out, COMMAND, s, must_match=tuple({**s, "start_range": 0.0}),
                         absent={"start_range": 0.0})
    write_marker(out, COMMAND, s)
    return previous


def run(out: str | Path, size: Size, task_name: str = "valve", robot_seed: int = 0,
        port: str | None = None, tell: Say = say, latency_ms: float | None = None,
        start_range: float = 0.0, made_for: tuple[str, ...] | None = None,
        first_seed: int = 0) -> dict[str, Any]:
    """The whole loop into ``out`` (resumable); returns the summaries, rows and figure.
    ``latency_ms``: with ``port``, see ``PortRobot`` (not a setting: a resume may change it).
    ``start_range`` [rad]: every condition trains from valve starts and goals each within
    +-start_range of the task's (``Task.training``; the fixed-start policies sit on a knife
    edge: the start 0.002 rad past goal - pi) and is evaluated on the task's own starts, on
    the robots and in its training sim, and also in its training sim from its training starts
    (did it learn what it trained on?).
    ``made_for``: names of the robots the per-robot conditions (identified,
    identified_randomized, on_robot) make policies for (None: all; not a setting: a later
    run on the folder adds the others); every policy is still evaluated on every robot.
    ``first_seed``: train seeds first_seed .. size.seeds - 1 only (not a setting: one seed
    of a table without re-running the others); a lower seed enters the table only when the
    folder holds all its pieces. The demonstrations are recorded with seed 0 whatever it is
    (every DAPG policy of a folder learns from the same ones).

    Raises:
      OutputRefused: ``out`` holds files this command did not write, or a run with another
        task, robots or budget.
    """
    size = size_with(size) if isinstance(size, str) else size  # a name, as --size takes it
    from lowcostdex.errors import ConfigError, check_choice
    from lowcostdex.gap import GapConfig
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.outdir import archive, user_path

    if not isinstance(size, Size):  # (before: AttributeError deep in the loop)
        raise ConfigError(f"size={size!r:.60} must be a transfer Size or one of "
                          f"{', '.join(SIZES)} (e.g. size_with('smoke', seeds=2))")
    GapConfig(seed=0, **dict(size.gap))  # a misspelt override, before hours of robot time

    check_choice("task", task_name, tuple(TASKS))
    if not (0.0 <= start_range <= math.pi and math.isfinite(start_range)):
        raise ConfigError(f"start_range must be in [0, pi] rad, got {start_range}")
    if start_range and task_name == "valve-random":
        raise ConfigError("start_range: valve-random already starts anywhere within +-60 deg")
    out = user_path(out)  # ("~/runs/t" went to ./~/runs/t; None a TypeError)
    task = TASKS[task_name]
    train_task = task.training(start_range)
    robots = make_robots(size.robots, robot_seed, port, latency_ms)
    if made_for is not None:
        if not made_for:
            raise ConfigError("made_for: give at least one robot (None: every robot)")
        for name in made_for:
            check_choice("robot", name, [r.name for r in robots])
    if not (isinstance(first_seed, int) and 0 <= first_seed < size.seeds):
        raise ConfigError(f"first_seed must be in [0, {size.seeds - 1}] (the seeds are 0 .. "
                          f"{size.seeds - 1}), got {first_seed}: for seed {first_seed} alone "
                          f"give seeds {first_seed + 1} (--seeds {first_seed + 1})")
    starts_wider = train_task != task
    # lower seeds the folder already holds whole join the table; nothing of them runs again
    held = [k for k in range(first_seed) if all(p.exists() for p in piece_files(
        out, size, robots, made_for, starts_wider, seeds=[k], identification=False))]
    open_out(out, size, task_name, robot_seed, port, start_range)
    seeds = held + list(range(first_seed, size.seeds))
    t_start = time.perf_counter()
    joints = dclaw_spec().joint_names
    names = [r.name for r in robots]
    wall: dict[str, float] = {}

    id_robots = [r for r in robots if made_for is None or r.name in made_for]
    n_id = len(id_robots) * len(size.fingers) if {"identified", "identified_randomized"} & set(
        size.conditions) else 0
    for note in redo_extended(out, size, robots, made_for, seeds):
        tell(note)
    pieces = piece_files(out, size, robots, made_for, starts_wider, seeds=seeds)
    progress = Progress(len(pieces), tell, found=sum(p.exists() for p in pieces))
    tell(f"transfer: {task.label()}, robots {', '.join(names)}, seeds {seeds}, algos "
         f"{list(size.algos)}, conditions {list(size.conditions)}; {size.samples} samples per "
         f"policy, {size.episodes} episodes per cell -> {out}")

    demos = None
    if "dapg" in size.algos or (size.valve_episodes and n_id):  # the valve log plays them
        t0 = time.perf_counter()
        tell(f"demonstrations: {size.demos} by the virtual teacher on a nominal emulated D'Claw")
        demos = cached(out / "demos.json", lambda: record_demos(out, task, size, 0))
        wall["demos"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    idents: dict[str, dict[str, Any]] = {}
    if n_id:
        for k, robot in enumerate(robots):
            if robot not in id_robots:
                continue
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
    if size.valve_episodes and n_id:
        t0 = time.perf_counter()
        for robot in id_robots:
            idents[robot.name]["valve_fit"] = valve_log_fit(
                robot, out, task, size, idents[robot.name], joints, progress, tell)
        wall["valve_fit"] = time.perf_counter() - t0

    rows: list[dict[str, Any]] = []
    t_train = t_eval = 0.0
    for algo in size.algos:
        for seed in seeds:
            for condition, policy_robot in jobs(size.conditions, robots, made_for):
                tag = run_tag(condition, policy_robot)
                run_dir = out / "runs" / algo / f"{tag}_seed{seed}"
                on_robot = condition == "on_robot"
                randomize, edit = (None, None) if on_robot else condition_model(
                    condition, idents.get(policy_robot.name) if policy_robot else None, joints)
                where = f" for robot {policy_robot.name}" if policy_robot else ""
                t0 = time.perf_counter()
                done = (run_dir / "summary.json").exists()
                if not done:
                    tell(f"{algo} seed {seed}: train {condition}{where}")
                trained = train_policy(run_dir, algo, train_task, randomize,
                                       out / demos["file"] if demos else None, size, seed,
                                       robot=policy_robot if on_robot else None,
                                       robot_seed=(robot_seed + names.index(policy_robot.name)
                                                   if policy_robot else None),
                                       model_edit=edit)
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
                    sim = cells[policy_robot.name]
                else:
                    path = run_dir.parent / f"{tag}_seed{seed}.sim.json"
                    done = path.exists()
                    sim = cached(path, lambda d=run_dir, r=randomize, e=edit: evaluate(
                        d, task, sim_kwargs(r, e), size.episodes))
                    progress.step(f"{algo} {tag} seed {seed} in its training sim: "
                                  f"{sim['successes']}/{sim['episodes']}", done)
                starts = None  # its training sim from its training starts (--start-range)
                if train_task != task and not on_robot:
                    path = run_dir.parent / f"{tag}_seed{seed}.sim_starts.json"
                    done = path.exists()
                    starts = cached(path, lambda d=run_dir, r=randomize, e=edit: evaluate(
                        d, train_task, sim_kwargs(r, e), size.episodes))
                    progress.step(f"{algo} {tag} seed {seed} in its training sim from its "
                                  f"training starts: {starts['successes']}/"
                                  f"{starts['episodes']}", done)
                for target in robots:
                    cell = cells[target.name]
                    rows.append({"algo": algo, "condition": condition, "robot": target.name,
                                 "seed": seed, "success": cell["successes"],
                                 "episodes": cell["episodes"],
                                 "policy_robot": policy_robot.name if policy_robot else None,
                                 "final_error": cell["final_error"],
                                 "solved": cell.get("solved"),  # cells made before: None
                                 "final_error_median": round(
                                     float(np.median(cell["final_error"])), 5),
                                 "success_loose": loose_successes(cell["final_error"]),
                                 "loose_tolerance": LOOSE_TOL,
                                 "sim_success": sim["successes"], "sim_episodes": sim["episodes"],
                                 "sim_final_error": sim["final_error"],
                                 "sim_starts_success": None if starts is None
                                 else starts["successes"],
                                 "sim_starts_episodes": None if starts is None
                                 else starts["episodes"],
                                 "policy": f"{algo}/{tag}",
                                 # which MJCF it trained in: None the nominal, else the
                                 # valve-log fit's edit (``DClawEdit.to_dict()``)
                                 "model_edit": edit,
                                 "samples": trained["samples"],
                                 "train_wall_seconds": round(trained["wall_seconds"], 1),
                                 "robot_hours": trained.get("robot_hours"),
                                 "train_cpu_seconds": trained.get("cpu_seconds"),
                                 # trained on under the EXTEND rule (None: not)
                                 "extended": trained.get("extended"),
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
    if train_task != task:
        title += f", trained from valve starts within +-{start_range:g} rad"
    archive(out, OUTPUTS)  # the previous table files move into previous/<time>/
    write_json(out / "identified.json", idents)
    fig = plot(summaries, names, out / "transfer.png", title)
    info = {"date": time.strftime("%Y-%m-%d"), "machine": platform.machine(),
            "cpus": os.cpu_count(), "load": [round(x, 1) for x in os.getloadavg()],
            "task": task.label(), "seeds": seeds, "algos": list(size.algos),
            "conditions": list(size.conditions), "robots": [r.to_dict()["name"] for r in robots],
            "robot_seed": None if port else robot_seed, "port": port, "size": asdict(size),
            "training_task": train_task.label(),
            "wall_seconds": {k: round(v, 1) for k, v in wall.items()},
            "cpu_seconds_this_invocation": round(cpu, 1)}
    write_json(out / "transfer.json", {"info": info, "rows": rows,
                                       "cells": cells_json(summaries, names)})
    parts = [f"# Transfer table: {title}", ""]
    for algo, summary in summaries.items():
        parts += [f"## {algo.upper()}: each policy on the robot it was made for", "",
                  table_markdown(summary, names), "",
                  f"### {algo.upper()}: final valve error and success at {LOOSE_TOL:g} rad "
                  "(measures that do not flip at the tolerance; intervals over the pooled "
                  "episodes, the seeds are the independent units)", "",
                  errors_markdown(summary, names), ""]
        paired = paired_markdown([r for r in rows if r["algo"] == algo], names)
        if paired:
            parts += [f"### {algo.upper()}: each condition against nominal on the same "
                      "episodes (paired; per seed, then the seeds as the units)", "",
                      paired, ""]
        cross = cross_markdown([r for r in rows if r["algo"] == algo], names)
        if cross and len(robots) > 1:
            parts += [f"### {algo.upper()}: policies made for one robot on every robot "
                      "(bold: its own robot)", "", cross, ""]
        parts += [f"### {algo.upper()}: what a policy cost (samples, robot time, wall and CPU "
                  "at this run's load)", "",
                  cost_markdown([r for r in rows if r["algo"] == algo], idents), "",
                  *extended_lines([r for r in rows if r["algo"] == algo])]
    if idents:
        parts += ["## Identification (catalogue effects only; a hidden robot's MJCF "
                  "perturbations and firmware imperfection have no catalogue name)", "",
                  *named_vs_truth(idents), ""]
    fits = {n: i["valve_fit"] for n, i in idents.items() if "valve_fit" in i}
    if fits:
        from lowcostdex.transfer.valve_fit import describe

        parts += ["## The identified conditions' MJCF: the valve-log fit per robot (their "
                  "rows' `model_edit` in transfer.json; every other condition trains in the "
                  "nominal MJCF)", "", *[f"- robot {n}: {describe(f)}" for n, f in fits.items()],
                  ""]
    elif {"identified", "identified_randomized"} & set(size.conditions):
        parts += ["The identified conditions trained in the nominal MJCF (no valve-log fit: "
                  "valve_episodes 0).", ""]
    parts.append("Wall-clock [s]: " + ", ".join(f"{k} {v:.0f}" for k, v in wall.items())
                 + f" (pieces found done are not re-run); CPU of this invocation {cpu:.0f} s")
    text = "\n".join(parts)
    (out / "table.md").write_text(text + "\n")
    tell(f"wrote {out / 'table.md'}, {out / 'transfer.json'}, {out / 'transfer.png'}")
    return {"summaries": summaries, "rows": rows, "info": info, "figure": fig, "text": text}
