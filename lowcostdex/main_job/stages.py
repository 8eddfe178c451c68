"""The main job's stages: bus, demos, gap, train, report (each returns its results)."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from typing import Any

from lowcostdex.main_job.setup import DAPG_LAM0, GAP_JOINTS, GAP_RATE, Context, robot_effects

# ------------------------------------------------------------------------------------------------
# 1. bus


def stage_bus(ctx: Context) -> dict[str, Any]:
    """Bring the D'Claw up on its bus: scan, then calibrate (emulated) or check the map."""
    import numpy as np

    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.dynamixel.scan import scan
    from lowcostdex.hardware.emulated.chain import emulated_dclaw
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus, robot_hand
    from lowcostdex.hardware.robot.calibration import calibrate_offsets
    from lowcostdex.sim.models.dclaw import build_dclaw

    hand = robot_hand(dclaw_spec(), build_dclaw(ctx.setup.station).compile())
    ids = [j.motor_id for j in hand.all_joints]
    if ctx.emulated:
        effects = robot_effects(hand.joint_names)
        chain = emulated_dclaw(ctx.setup.station, hand=hand, effects=effects,
                               rng=np.random.default_rng(ctx.seed))
        port: Any = chain.port()
    else:
        port = ctx.port
    infos = scan(port, ids=ids)
    motors = [{"id": m.motor_id, "model": m.model, "firmware": m.firmware,
               "temperature": m.temperature, "voltage": m.voltage,
               "errors": list(m.hardware_error)} for m in infos]
    missing = sorted(set(ids) - {m.motor_id for m in infos})
    result: dict[str, Any] = {"port": "emulated (in-process dynamixel_sdk port)" if ctx.emulated
                              else ctx.port, "motors_found": len(infos),
                              "motors_missing": missing, "motors": motors}
    if ctx.emulated:
        # The calibration a user runs with the hand held in its zero pose: here the servos hold
        # it (default map), so the recorded offsets must reproduce ROBEL's map within a tick or
        # two of steady-state error. (On a real robot: `lowcostdex calibrate`.)
        model = build_dclaw(ctx.setup.station, hand).compile()
        h = robot_hand(hand, model)
        bus = make_dynamixel_bus(h, chain.port(), model)
        with bus:
            zero = np.array([j.calibration.to_motor(0.0) for j in h.all_joints])
            bus.set_torque(True)
            bus.write_goal_positions(zero, [j.motor_id for j in h.all_joints])
            bus.sleep(1.0)
            calibrated = calibrate_offsets(bus, h)
        change = [abs(a.calibration.offset - b.calibration.offset)
                  for a, b in zip(h.all_joints, calibrated.all_joints, strict=True)]
        calibrated.save(ctx.out / "hand.json")
        result["calibration_max_change_rad"] = float(max(change))
        result["calibration_ticks"] = float(max(change) / (2 * math.pi / 4096))
        result["hand_spec"] = "hand.json"
    return result


# ------------------------------------------------------------------------------------------------
# 2. demonstrations


def stage_demos(ctx: Context) -> dict[str, Any]:
    """Record kinesthetic demonstrations (the virtual teacher on the emulated robot): identify
    the servos' response, record, label each step with the servo goal that reproduces it, and
    play every successful demonstration back with noisy goals (``lowcostdex.demonstrations.kinesthetic``)."""
    import gymnasium as gym
    import numpy as np

    import lowcostdex  # noqa: F401
    from lowcostdex.demonstrations.kinesthetic import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.teachers import teacher_class

    setup = ctx.setup
    path = ctx.out / "demos.h5"
    env = gym.make(setup.env_id, **ctx.env_kwargs())
    teacher = None
    if ctx.emulated:
        solver = teacher_class(setup.teacher)()
        teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task, solver=solver,
                                 config=virtual_teacher_config(solver),
                                 rng=np.random.default_rng(ctx.seed))
    n = ctx.budget.demos
    progress = _progress()
    try:
        with progress:
            ident = progress.add_task("servo response (random goals)", total=SERVO_ID_EPISODES)
            response, id_seconds = identify_servo_response(
                env, episodes=SERVO_ID_EPISODES, seed=ctx.seed + 1_000_000,
                on_episode=lambda k: progress.advance(ident))
            task = progress.add_task(f"{n} successful demonstrations, {setup.playbacks} "
                                     "playbacks of each", total=n)
            recorder = KinestheticRecorder(
                env, path, setup.env_id, teacher=teacher, response=response,
                playbacks=setup.playbacks, playback_noise=PLAYBACK_NOISE,
                rng=np.random.default_rng(ctx.seed),
                on_episode=lambda k, ep: progress.advance(task) if ep.source != "playback"
                and ep.length and ep.success[-1] else None)
            stats = recorder.record(n * setup.demo_tries, seed=ctx.seed,
                                    successes=n if setup.demo_tries > 1 else None)
            robot = env.unwrapped.backend.robot.metrics.as_dict()
    finally:
        env.close()
    return {"file": path.name, "teacher": setup.teacher if ctx.emulated else None,
            "episodes": stats.episodes, "successful": stats.successes,
            "steps": stats.steps, "playbacks": stats.playbacks,
            "successful_playbacks": stats.playback_successes,
            "servo_response": {"alpha": [round(a, 3) for a in response.alpha],
                               "r2": [round(r, 3) for r in response.r2]},
            "robot_seconds_servo_id": round(id_seconds, 1),
            "robot_seconds_recording": round(stats.record_time, 1),
            "robot_seconds_resets": round(stats.reset_time, 1),
            "robot_seconds_playbacks": round(stats.playback_time, 1),
            "robot": {k: robot[k] for k in sorted(robot) if k in _ROBOT_KEYS}}


SERVO_ID_EPISODES = 2
"""Random-goal episodes (4 s each) that identify the servo response before recording."""
PLAYBACK_NOISE = 0.05
"""Half-width of the playback goal noise [action units]."""


_ROBOT_KEYS = ("resets", "reset_failures", "reset_time", "pauses", "pause_time", "faults",
               "max_temperature", "overloads", "invalid_reads")


# ------------------------------------------------------------------------------------------------
# 3. training


def stage_train(ctx: Context) -> dict[str, Any]:
    """DAPG from the demonstrations (in simulation with domain randomization, or on the robot)
    and NPG from scratch on the robot; all judged on the robot's held-out episodes."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.configs import DAPGConfig
    from lowcostdex.algos.train import TrainConfig, train
    from lowcostdex.main_job.gapsim import validation_sim

    b = ctx.budget
    demos = ctx.out / ctx.results["demos"]["file"]
    out: dict[str, Any] = {}
    curves: dict[str, dict[str, Any]] = {}
    for algo in ("dapg", "npg"):
        kwargs = ctx.env_kwargs()
        backend = kwargs.pop("backend")
        iters, traj, every, episodes = b.npg_iters, b.traj_per_iter, b.eval_every, b.eval_episodes
        sim = b.dapg_sim if algo == "dapg" else None
        if algo == "dapg":
            iters = b.dapg_iters
        if sim is not None:
            backend = "sim"
            kwargs = {**ctx.setup.env_overrides, "randomize": list(sim.randomize)}
            iters, traj, every, episodes = sim.iters, sim.traj, sim.eval_every, sim.eval_episodes
        validation = validation_sim(ctx) if sim is not None else None  # where it chooses
        config = TrainConfig(algo=algo, env_id=ctx.setup.env_id, backend=backend,
                             env_kwargs=kwargs, seed=ctx.seed, n_iter=iters,
                             n_traj=traj, eval_every=every, eval_episodes=episodes,
                             demos=str(demos) if algo == "dapg" else None,
                             eval_bc=algo == "dapg", dapg=DAPGConfig(lam0=DAPG_LAM0),
                             eval_paired=True,
                             eval_dense_from=sim.dense_from if sim is not None else None,
                             eval_env_kwargs=(validation or {}).get("env_kwargs"))
        if sim is not None and sim.clones > 1:
            # several clones, DAPG from the one that validates best in its simulation
            from lowcostdex.main_job.clones import choose_clone

            out["clones"] = choose_clone(config, sim.clones, sim.eval_episodes)
            config = dataclasses.replace(config, bc_seed=out["clones"]["bc_seed"])
        run_dir = ctx.out / f"train_{algo}"
        t0 = time.perf_counter()
        if sim is not None and sim.runs > 1:
            # several runs from the same clone, their last iterates' weights averaged
            from lowcostdex.main_job.streams import train_streams

            out["streams"] = train_streams(config, run_dir, sim.runs)
            metrics = ex.read_metrics(run_dir / ex.METRICS_FILE)
        else:
            metrics = train(config, run_dir).read_metrics()
        summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
        curves[algo] = metrics
        first = summary["first_eval_crossing"]
        best = summary["best"] or {}
        out[algo] = {
            "trained_in": "simulation" if sim is not None else "robot",
            "randomized": list(sim.randomize) if sim is not None else [],
            "iterations": iters,
            "episodes_per_iteration": traj,
            "samples": int(metrics["samples"][-1]),
            # the validation episodes' steps, not in "samples" (on the robot they cost robot time)
            "validation_samples": (int(metrics["eval_samples"][-1]) if "eval_samples" in metrics
                                   else None),
            # in simulation no robot time is spent (the run's robot_hours counts sim time)
            "robot_hours": 0.0 if sim is not None else float(metrics["robot_hours"][-1]),
            "first_iteration_success": float(metrics["success_rate"][0]),
            "final_training_success": float(metrics["success_rate"][-1]),
            "last_validation_success": float(summary["final"].get("eval_success_rate",
                                                                  math.nan)),
            "best_eval_success": float(best.get("eval_success_rate", math.nan)),
            "best_iteration": int(best["iteration"]) if best else None,
            "best_samples": float(best.get("samples", math.nan)),
            "first_eval_crossing_samples": float(first["samples"]) if first else None,
            "evaluations": summary["evaluations"],
            "validation_episodes": episodes,
            "validation_every": every,
            "validation_dense_from": config.eval_dense_from,
            "validation_paired": config.eval_paired,
            # which simulation chose the iterate (None: the run validated where it trained)
            "validated_in": ({k: v for k, v in validation.items() if k != "env_kwargs"}
                             if validation is not None else None),
            "policy": "the run's best validated policy",
            "wall_seconds": round(time.perf_counter() - t0, 1),
            "curves": f"{run_dir.name}/learning_curves.png",
            "robot": {k: float(metrics[f"robot_{k}"][-1]) for k in
                      ("resets", "reset_failures", "pauses", "pause_time", "max_temperature")
                      if f"robot_{k}" in metrics},
        }
    # the behaviour clone's own deterministic evaluation before DAPG's first iteration
    bc = json.loads((ctx.out / "train_dapg" / "bc.json").read_text())
    if "streams" in out:
        avg = out["streams"]["average"]
        # the average unless it validated below the clone (on the same episodes)
        chosen = avg["eval_successes"] >= round(bc["eval_success_rate"] * bc["eval_episodes"])
        out["streams"]["chosen"] = "average" if chosen else "clone"
        out["dapg"]["policy"] = (f"the average of {len(out['streams']['runs'])} runs' last "
                                 "iterates" if chosen else "the clone (the average of the "
                                 "runs validated below it)")
    out["success_after_bc"] = float(bc["eval_success_rate"])
    out["bc"] = {k: bc[k] for k in ("n_episodes", "n_pairs") if k in bc}
    out["bc"]["validation_success"] = float(bc["eval_success_rate"])
    out["bc"]["bc_seed"] = out["clones"]["bc_seed"] if "clones" in out else ctx.seed
    heldout = _heldout(ctx, b.heldout_episodes, dapg_policy_file(out, ctx.out))
    out["random"] = heldout.pop("random")
    for name, r in heldout.items():
        out[name].update(r)
    out["demos_finished"] = ctx.results["demos"].get("finished")
    out["plot"] = _plot_training(ctx, out, curves)
    if ctx.task == "flip":
        out["rollout"] = _flip_rollout(ctx, dapg_policy_file(out, ctx.out))
    return out


def _heldout(ctx: Context, episodes: int, dapg_file: Any) -> dict[str, dict[str, Any]]:
    """Uniformly random actions, the behaviour clone (before any RL step), DAPG's and NPG's run
    policies (each its best on the validation evaluations) on the same ``episodes`` held-out
    episodes of the robot: reset seeds of ``HELDOUT_STREAM``, disjoint from the training episodes
    and from the evaluations that chose each run's policy, so the comparison is paired and not
    biased by that choice. On the emulated robot each policy runs on a freshly started robot
    (``main_job.heldout``: a robot carries its reset's residue and its motors' warmth from one
    episode into the next, so what ran before would change a policy's episodes); on a real
    robot they run one after another. Policies act with their mean action; success at the
    final step as in training's evaluation; each episode's final ``|goal_error|`` is kept
    (``final_goal_errors``). The random actions are seeded."""
    import numpy as np

    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.samplers import HELDOUT_STREAM, EnvFactory, make_jobs
    from lowcostdex.algos.train import load_policy, trajectory_success
    from lowcostdex.main_job.heldout import evaluate, uniform_actions

    jobs = make_jobs(ctx.seed, HELDOUT_STREAM, 0, episodes, deterministic=True)
    files = {"bc": ctx.out / "train_dapg" / ex.BC_POLICY_FILE,
             "dapg": dapg_file, "npg": ctx.out / "train_npg"}
    policies: dict[str, Any] = {"random": uniform_actions(np.random.default_rng(ctx.seed
                                                                                + 3_000_000))}
    policies.update({name: load_policy(path, env=ctx.setup.env_id).snapshot()
                     for name, path in files.items()})
    out: dict[str, dict[str, Any]] = {}
    progress = _progress()
    with progress:
        task = progress.add_task(f"held-out episodes: random actions, clone, DAPG, NPG "
                                 f"({episodes} each)", total=4 * episodes)
        runs = evaluate(EnvFactory(ctx.setup.env_id, ctx.env_kwargs()), policies, jobs,
                        fresh=ctx.emulated, on_episode=lambda _: progress.advance(task))
    for name, paths in runs.items():
        solved = [trajectory_success(p, "final") for p in paths]
        errors = [float(p.final_goal_error) for p in paths]
        out[name] = {"eval_episodes": episodes, "eval_successes": int(sum(solved)),
                     "eval_success": sum(solved) / episodes if episodes else math.nan}
        if name == "random":
            out[name]["steps"] = sum(len(p) for p in paths)
            if all(math.isfinite(e) for e in errors):
                out[name]["final_goal_errors"] = errors
        else:
            out[name].update(solved=solved, final_goal_errors=errors)
        out[name]["heldout_robot"] = ("a freshly started emulated robot" if ctx.emulated
                                      else "the robot, after the policies before it")
    return out


def dapg_policy_file(train: dict[str, Any], out: Any) -> Any:
    """DAPG's policy as the train stage (its results ``train``, output folder ``out``) chose
    it: the runs' average (``main_job.streams``), the clone when the average validated below
    it, or the single run's best validated policy (its run directory)."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.main_job.streams import AVERAGE_FILE

    chosen = train.get("streams", {}).get("chosen")
    if chosen == "average":
        return out / "train_dapg" / AVERAGE_FILE
    if chosen == "clone":
        return out / "train_dapg" / ex.BC_POLICY_FILE
    return out / "train_dapg"


ROLLOUT_DATA = "flip_rollout.npz"
"""The flip rollout's recorded episodes (``flip_rollout_figure`` rebuilds the figure from it)."""


def _flip_rollout(ctx: Context, dapg_file: Any) -> dict[str, Any]:
    """One deterministic episode of DAPG's policy (``dapg_file``) on the robot, the block's orientation
    recorded at every step; plotted beside the first successful demonstration. The joint
    positions of both (qpos, one row per control step) go to ``ROLLOUT_DATA``."""
    import gymnasium as gym
    import numpy as np

    import lowcostdex  # noqa: F401
    from lowcostdex.algos.train import load_policy
    from lowcostdex.demonstrations.file import read_episodes

    snap = load_policy(dapg_file, env=ctx.setup.env_id).snapshot()
    env = gym.make(ctx.setup.env_id, **ctx.env_kwargs())
    u = env.unwrapped
    try:
        obs, _ = env.reset(seed=ctx.seed + 2_000_000)
        qpos, done = [u.data.qpos.copy()], False
        while not done:
            obs, _, term, trunc, info = env.step(np.clip(snap.mean(obs), -1, 1)
                                                 .astype(np.float32))
            qpos.append(u.data.qpos.copy())
            done = term or trunc
        goal, period, task = dict(u.goal), u.control_period, u.task
    finally:
        env.close()
    demos = [e for e in read_episodes(ctx.out / ctx.results["demos"]["file"])
             if e.length and e.success[-1]]
    curves = {"DAPG policy (mean action)": (np.array(qpos), goal)}
    if demos:
        curves["a demonstration"] = (np.asarray(demos[0].qpos), demos[0].goal)
    np.savez(ctx.out / ROLLOUT_DATA, period=period,
             **{f"qpos_{i}": q for i, (q, _) in enumerate(curves.values())})
    plt = _pyplot()
    fig = flip_rollout_figure(task, period, curves, ctx.emulated)
    name = "flip_rollout.png"
    fig.savefig(ctx.out / name, dpi=110)
    plt.close(fig)
    err = float(task.orientation_error(np.array(qpos[-1]), goal))
    return {"plot": name, "data": ROLLOUT_DATA,
            "final_orientation_error_deg": round(math.degrees(err), 1),
            "success": bool(err < task.config.success_angle), "steps": len(qpos) - 1}


def flip_rollout_figure(task: Any, period: float, curves: dict[str, tuple[Any, Any]],
                        emulated: bool = True) -> Any:
    """The flip's rollout figure: the block's tilt (its top face from up) and its orientation
    error to the goal [deg] against time [s], one line per episode.

    Args:
      task: the flip task (``tilt``, ``orientation_error``, ``config.success_angle``).
      period: control period [s] (one qpos row per control step).
      curves: label -> (qpos (T, nq), goal).
      emulated: whether the episodes ran on the emulated D'Claw (the title says so).
    """
    import numpy as np

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for (label, (q, g)), color in zip(curves.items(), ("tab:blue", "tab:gray"), strict=False):
        q = np.asarray(q)
        t = np.arange(len(q)) * period
        axes[0].plot(t, np.degrees(task.tilt(q)), color=color, label=label)
        axes[1].plot(t, np.degrees(task.orientation_error(q, g)), color=color, label=label)
    axes[0].set_ylabel("block's top face from up [deg]")
    axes[1].set_ylabel("orientation error to the goal [deg]")
    axes[1].axhline(np.degrees(task.config.success_angle), color="k", ls="--", lw=1,
                    label="success threshold")
    for ax in axes:
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    fig.suptitle("The flip, rolled out on the emulated D'Claw" if emulated else
                 "The flip, rolled out on the D'Claw")
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    fig.legend(*axes[1].get_legend_handles_labels(), loc="lower center", ncol=3,
               fontsize="small", frameon=False)
    return fig


def _plot_training(ctx: Context, res: dict[str, Any], curves: dict[str, dict[str, Any]]) -> str:
    """``training_figure`` saved as learning_curves.png; returns its name."""
    plt = _pyplot()
    fig = training_figure(ctx, res, curves)
    name = "learning_curves.png"
    fig.savefig(ctx.out / name, dpi=110)
    plt.close(fig)
    return name


def training_figure(ctx: Context, res: dict[str, Any], curves: dict[str, dict[str, Any]]
                    ) -> Any:
    """Success against samples and robot time, from each run's metrics (``curves[algo]``)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for algo, color in (("dapg", "tab:blue"), ("npg", "tab:orange")):
        m = curves[algo]
        in_sim = res[algo].get("trained_in") == "simulation"
        label = ("DAPG (demos" + (", in simulation)" if in_sim else ")") if algo == "dapg"
                 else "NPG (scratch)")
        axes[0].plot(m["samples"], m["success_rate"], "-o", color=color, label=label)
        if not in_sim:  # a run in simulation spent no robot time
            axes[1].plot(m["robot_hours"] * 60, m["success_rate"], "-o", color=color,
                         label=label)
        axes[0].plot(m["samples"][-1:], m["eval_success_rate"][-1:], "*", ms=14, color=color)
    # the behaviour clone's own evaluation, before any RL sample
    axes[0].plot([0], [res["success_after_bc"]], "D", ms=8, color="tab:blue", mfc="white",
                 label="behaviour clone alone")
    axes[0].set_xlabel("samples (env steps)")
    axes[1].set_xlabel("robot time incl. resets [min]")
    for ax in axes:
        ax.set_ylabel("success rate")
        ax.set_ylim(-0.05, 1.12)
        ax.grid(alpha=0.3)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=3,
               title="training (star: final evaluation)", frameon=False)
    fig.suptitle(f"{ctx.setup.title} on the emulated D'Claw" if ctx.emulated else
                 f"{ctx.setup.title} on the D'Claw")
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    return fig


# ------------------------------------------------------------------------------------------------
# 4. reality gap


def stage_gap(ctx: Context) -> dict[str, Any]:
    """Record an identification log from the robot, compare with the nominal sim, name causes."""
    import numpy as np
    from rich.console import Console

    from lowcostdex.gap import GapConfig, analyze, load_dataset, write_report
    from lowcostdex.gap.cli import analysis_progress
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.robot.trace import dclaw_identification_logs
    from lowcostdex.sim.models.dclaw import build_dclaw

    b = ctx.budget
    gap_dir = ctx.out / "gap"
    logs_dir = gap_dir / "logs"
    logs_dir.mkdir(parents=True)
    hand = dclaw_spec()
    truth = robot_effects(hand.joint_names) if ctx.emulated else []
    steps = int(b.gap_seconds * GAP_RATE)
    progress = _progress()
    with progress:
        task = progress.add_task("identification logs", total=b.gap_logs * steps)
        paths = dclaw_identification_logs(
            hand, GAP_JOINTS, logs_dir, b.gap_logs, b.gap_seconds,
            np.random.default_rng(ctx.seed + 2), port=ctx.port, effects=truth,
            emulator_rng=np.random.default_rng(ctx.seed + 1), rate=GAP_RATE,
            on_step=lambda _: progress.advance(task))
    nominal = gap_dir / "nominal_finger.xml"
    nominal.write_text(build_dclaw("none", hand, thermal=False, fingers=("ff",)).to_xml())
    dataset = load_dataset([str(p) for p in paths], model=str(nominal))
    t0 = time.perf_counter()
    with analysis_progress(Console(stderr=True)) as on_progress:
        result = analyze(dataset, GapConfig(), on_progress)
    seconds = time.perf_counter() - t0
    write_report(result, gap_dir / "report")
    report = json.loads((gap_dir / "report" / "report.json").read_text())
    causes = [{"effect": c["effect"], "joints": c["joints"],
               "params": {p: v["value"] for p, v in c["params"].items()}} for c in report["causes"]]
    out = {"logs": len(paths), "seconds_per_log": b.gap_seconds, "analysis_seconds": round(
        seconds, 1), "verdict": report["verdict"], "causes": causes,
        "baseline_heldout_rmse_mrad": 1e3 * report["gain"]["baseline_rmse"],
        "extended_heldout_rmse_mrad": 1e3 * report["gain"]["extended_rmse"],
        "noise_floor_mrad": 1e3 * report["noise_floor"]["rmse"],
        "gain": report["gain"], "report": "gap/report/report.md",
        "log_notes": list(dataset.notes)}
    if truth:
        out["truth"] = [{"effect": e.name, "params": {k: float(v[0]) for k, v in e.values.items()}}
                        for e in truth]
        named = {c["effect"] for c in causes}
        out["truth_named"] = sorted(named & {e.name for e in truth})
    out["plots"] = [f"gap/report/{p}" for p in report.get("plots", [])]
    return out


# ------------------------------------------------------------------------------------------------
# 5. report


def stage_report(ctx: Context) -> dict[str, Any]:
    """Reset and thermal statistics plot; the report itself is written by ``run``."""
    plt = _pyplot()
    fig = robot_health_figure(ctx.results)
    name = "robot_health.png"
    fig.savefig(ctx.out / name, dpi=110)
    plt.close(fig)
    return {"plot": name}


def robot_health_figure(results: dict[str, dict[str, Any]]) -> Any:
    """Auto-resets (attempted, failed) and the hottest motor with the time paused by the thermal
    guard, per training run (``results["train"][algo]["robot"]``)."""
    import numpy as np

    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    names, resets, failures, pause_min, temps = [], [], [], [], []
    for algo in ("dapg", "npg"):
        r = results.get("train", {}).get(algo, {}).get("robot", {})
        if r:
            names.append(algo.upper())
            resets.append(r.get("resets", np.nan))
            failures.append(r.get("reset_failures", np.nan))
            pause_min.append(r.get("pause_time", 0.0) / 60)
            temps.append(r.get("max_temperature", np.nan))
    x = np.arange(len(names))
    axes[0].bar(x - 0.2, resets, 0.4, label="resets")
    axes[0].bar(x + 0.2, failures, 0.4, label="failed resets")
    axes[0].set_xticks(x, names)
    axes[0].set_xlabel("training run")
    axes[0].set_ylabel("auto-resets [count]")
    axes[0].set_title("auto-resets during training")
    axes[1].bar(x, temps, 0.5, color="tab:red", label="hottest motor")
    axes[1].axhline(65, color="k", ls="--", lw=1, label="thermal pause threshold (65 C)")
    axes[1].axhline(80, color="tab:red", ls=":", lw=1, label="firmware shutdown (80 C)")
    for i, p in enumerate(pause_min):
        axes[1].annotate(f"{p:.1f} min paused", (x[i], temps[i]), ha="center",
                         xytext=(0, 4), textcoords="offset points")
    axes[1].set_xticks(x, names)
    axes[1].set_xlabel("training run")
    axes[1].set_ylabel("hottest motor [deg C]")
    axes[1].set_ylim(0, 90)
    axes[1].set_title("thermal guard")
    fig.suptitle("Robot health while it learned")
    fig.tight_layout(rect=(0, 0.16, 1, 1))
    handles, labels = [], []
    for ax in axes:
        h, lab = ax.get_legend_handles_labels()
        handles += h
        labels += lab
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize="small", frameon=False)
    return fig


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _progress() -> Any:
    """A transient progress display (one bar per task, named by its description)."""
    from lowcostdex.progress import tasks

    return tasks()
