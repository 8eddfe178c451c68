"""``lowcostdex main``: the whole story in one command, on the emulated D'Claw by default.

1. bus: an emulated D'Claw comes up on a Dynamixel bus (the real dynamixel_sdk code path): scanned
   (ids, models, firmware, temperatures, errors) and calibrated against the default map;
2. demos: the virtual teacher records kinesthetic demonstrations, auto-reset between episodes;
3. train: DAPG from those demonstrations, and NPG from scratch for comparison, on the robot with
   its thermal guard and auto-resets active; success rates evaluated (final, best and the first
   crossing of 80 % beside each other; the run's policy is its best evaluated one); on the flip
   the DAPG policy's rollout is plotted (block orientation over time);
4. gap: an identification recording from the robot is compared with the nominal simulation; the
   gap analysis names what differs (the emulated robot carries servo effects the nominal sim
   lacks: ``robot_effects``), extends the model and measures the held-out gain;
5. report: ``report.md`` (and ``report.html``) with the PNG plots, in one output folder.

``--port /dev/ttyUSB0`` runs the same stages on a real D'Claw (kinesthetic demos then need a
person); ``--task`` picks the task (``valve``: turn the valve 180 deg; ``flip``: flip the block 180
deg about a horizontal axis); ``--size`` picks the budget: ``smoke`` (CI, about a minute), ``default`` (about 5 minutes
on a 2-core laptop) or ``long``.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class TaskSetup:
    """What differs between the main job's tasks.

    Attributes:
      env_id: the registered task.
      teacher: class name of the scripted solver the virtual teacher follows.
      station: the D'Claw station (``valve`` has the valve motor, ``block`` does not).
      did: what a successful episode did ("turned the valve").
      title: plot titles.
      playbacks: noisy playbacks of each successful demonstration (see
        ``lowcostdex.hardware.demos``); 0 for the flip, whose open-loop playbacks fail (the block
        outcome is too sensitive to the finger motion: bench/RESULTS.md).
      demo_tries: the demos stage records until ``Budget.demos`` demonstrations succeeded, at
        most this many times as many episodes (a person also throws failed ones away).
    """

    env_id: str
    teacher: str
    station: str
    did: str
    title: str
    playbacks: int
    demo_tries: int


TASKS = {
    "valve": TaskSetup("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher", "valve",
                       "turned the valve", "Valve turning", 2, 1),
    "valve-random": TaskSetup("lowcostdex/DClawTurnValveRandom-v0", "ValveTurnTeacher",
                              "valve", "turned the valve to its random target",
                              "Valve turning (random start and target)", 2, 1),
    "flip": TaskSetup("lowcostdex/DClawFlipBlock-v0", "FlipBlockTeacher", "block",
                      "flipped the block", "Block flipping", 0, 3),
}
ENV_ID = TASKS["valve"].env_id
GAP_JOINTS = ("ff_top", "ff_middle", "ff_bottom")
GAP_RATE = 50.0
"""Control rate of the identification logs [Hz]."""
SIZES = ("smoke", "default", "long")


def robot_effects(joints: tuple[str, ...]) -> list[Any]:
    """The emulated robot's "reality": servo effects the nominal simulation does not model.

    12 ms command latency (USB latency timer plus bus), 1 deg of gear/horn backlash and 0.05 N m
    of extra dry friction per joint: magnitudes inside the plausible D'Claw ranges of
    ../shared/reference/04-sysid.md section 6.
    """
    from lowcostdex.hardware.backend import default_effects

    return default_effects(joints, latency=0.012, backlash=math.radians(1.0), friction=0.05)


@dataclass
class Budget:
    """How much each stage does."""

    demos: int
    dapg_iters: int
    npg_iters: int
    traj_per_iter: int
    eval_episodes: int
    eval_every: int
    gap_logs: int
    gap_seconds: float


BUDGETS = {
    "smoke": Budget(demos=4, dapg_iters=1, npg_iters=1, traj_per_iter=4, eval_episodes=3,
                    eval_every=0, gap_logs=3, gap_seconds=6.0),
    "default": Budget(demos=20, dapg_iters=8, npg_iters=8, traj_per_iter=20, eval_episodes=10,
                      eval_every=2, gap_logs=6, gap_seconds=15.0),
    "long": Budget(demos=50, dapg_iters=60, npg_iters=60, traj_per_iter=40, eval_episodes=20,
                   eval_every=5, gap_logs=10, gap_seconds=30.0),
}


@dataclass
class Context:
    """What every stage sees.

    Attributes:
      out: output folder.
      size: one of SIZES.
      seed: master seed.
      port: serial port of a real robot, or None for the emulated D'Claw.
      task: one of TASKS.
      results: results of earlier stages by name (JSON-serializable).
    """

    out: Path
    size: str = "default"
    seed: int = 0
    port: str | None = None
    task: str = "valve"
    results: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def budget(self) -> Budget:
        return BUDGETS[self.size]

    @property
    def setup(self) -> TaskSetup:
        return TASKS[self.task]

    @property
    def emulated(self) -> bool:
        return self.port is None

    def env_kwargs(self) -> dict[str, Any]:
        """gym.make keyword arguments selecting the robot (JSON-serializable)."""
        from lowcostdex.hardware.hands import dclaw_spec

        if self.port is None:
            effects = robot_effects(dclaw_spec().joint_names)
            return {"backend": "emulated", "effects": [e.to_dict() for e in effects]}
        return {"backend": "hardware", "port": self.port}


# ------------------------------------------------------------------------------------------------
# 1. bus


def stage_bus(ctx: Context) -> dict[str, Any]:
    """Bring the D'Claw up on its bus: scan, then calibrate (emulated) or check the map."""
    import numpy as np

    from lowcostdex.hardware.backend import make_dynamixel_bus, robot_hand
    from lowcostdex.hardware.calibration import calibrate_offsets
    from lowcostdex.hardware.dynamixel import scan
    from lowcostdex.hardware.emulator import emulated_dclaw
    from lowcostdex.hardware.hands import dclaw_spec
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
    play every successful demonstration back with noisy goals (``lowcostdex.hardware.demos``)."""
    import gymnasium as gym
    import numpy as np

    import lowcostdex  # noqa: F401
    from lowcostdex.hardware.demos import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.sim import flip_teacher, scripted

    setup = ctx.setup
    path = ctx.out / "demos.h5"
    env = gym.make(setup.env_id, **ctx.env_kwargs())
    teacher = None
    if ctx.emulated:
        solver = (getattr(scripted, setup.teacher, None)
                  or getattr(flip_teacher, setup.teacher))()
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
    return {"file": path.name, "episodes": stats.episodes, "successful": stats.successes,
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
    """DAPG from the demonstrations and NPG from scratch, on the robot."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.train import TrainConfig, train

    b = ctx.budget
    kwargs = ctx.env_kwargs()
    backend = kwargs.pop("backend")
    demos = ctx.out / ctx.results["demos"]["file"]
    out: dict[str, Any] = {}
    curves: dict[str, dict[str, Any]] = {}
    for algo, iters in (("dapg", b.dapg_iters), ("npg", b.npg_iters)):
        config = TrainConfig(algo=algo, env_id=ctx.setup.env_id, backend=backend,
                             env_kwargs=kwargs, seed=ctx.seed, n_iter=iters,
                             n_traj=b.traj_per_iter, eval_every=b.eval_every,
                             eval_episodes=b.eval_episodes,
                             demos=str(demos) if algo == "dapg" else None,
                             eval_bc=algo == "dapg")
        run_dir = ctx.out / f"train_{algo}"
        t0 = time.perf_counter()
        run = train(config, run_dir)
        metrics = run.read_metrics()
        summary = ex.read_json(run_dir / ex.SUMMARY_FILE)
        curves[algo] = metrics
        first = summary["first_eval_crossing"]
        out[algo] = {
            "iterations": iters,
            "samples": int(metrics["samples"][-1]),
            "robot_hours": float(metrics["robot_hours"][-1]),
            "first_iteration_success": float(metrics["success_rate"][0]),
            "final_training_success": float(metrics["success_rate"][-1]),
            "eval_success": float(summary["final"].get("eval_success_rate", math.nan)),
            "best_eval_success": float((summary["best"] or {}).get("eval_success_rate",
                                                                    math.nan)),
            "best_samples": float((summary["best"] or {}).get("samples", math.nan)),
            "first_eval_crossing_samples": float(first["samples"]) if first else None,
            "evaluations": summary["evaluations"],
            "eval_episodes": b.eval_episodes,
            "eval_successes": _count(summary["final"].get("eval_success_rate"),
                                     b.eval_episodes),
            "wall_seconds": round(time.perf_counter() - t0, 1),
            "curves": f"{run_dir.name}/learning_curves.png",
            "robot": {k: float(metrics[f"robot_{k}"][-1]) for k in
                      ("resets", "reset_failures", "pauses", "pause_time", "max_temperature")
                      if f"robot_{k}" in metrics},
        }
    # the behaviour clone's own deterministic evaluation before DAPG's first iteration
    bc = json.loads((ctx.out / "train_dapg" / "bc.json").read_text())
    out["success_after_bc"] = float(bc["eval_success_rate"])
    out["bc"] = {k: bc[k] for k in ("n_episodes", "n_pairs", "eval_episodes") if k in bc}
    out["bc"]["eval_successes"] = _count(bc["eval_success_rate"],
                                         int(bc.get("eval_episodes", b.eval_episodes)))
    out["random"] = _random_baseline(ctx, b.eval_episodes)
    out["demos_finished"] = ctx.results["demos"].get("finished")
    out["plot"] = _plot_training(ctx, out, curves)
    if ctx.task == "flip":
        out["rollout"] = _flip_rollout(ctx)
    return out


def _count(rate: float | None, n: int) -> int | None:
    """Successful episodes from a success fraction of ``n`` episodes (None: not evaluated)."""
    if rate is None or not math.isfinite(float(rate)):
        return None
    return int(round(float(rate) * n))


def _random_baseline(ctx: Context, episodes: int) -> dict[str, Any]:
    """Measure a policy of uniformly random actions on the same robot and task: ``episodes``
    episodes, success at the final step as in training's evaluation (seeded)."""
    import gymnasium as gym
    import numpy as np

    import lowcostdex  # noqa: F401

    rng = np.random.default_rng(ctx.seed + 3_000_000)
    env = gym.make(ctx.setup.env_id, **ctx.env_kwargs())
    successes, steps, t0 = 0, 0, time.perf_counter()
    try:
        space = env.action_space
        for k in range(episodes):
            env.reset(seed=ctx.seed + 3_000_000 + k)
            done, info = False, {}
            while not done:
                action = rng.uniform(space.low, space.high).astype(space.dtype)
                _, _, term, trunc, info = env.step(action)
                done, steps = term or trunc, steps + 1
            successes += bool(info.get("success", False))
    finally:
        env.close()
    return {"eval_episodes": episodes, "eval_successes": successes,
            "eval_success": successes / episodes if episodes else math.nan, "steps": steps,
            "wall_seconds": round(time.perf_counter() - t0, 1)}


def _flip_rollout(ctx: Context) -> dict[str, Any]:
    """One deterministic episode of the DAPG run's policy on the robot, the block's orientation
    recorded at every step; plotted beside the first successful demonstration."""
    import gymnasium as gym
    import numpy as np

    import lowcostdex  # noqa: F401
    from lowcostdex.algos.train import load_policy
    from lowcostdex.demo_file import read_episodes

    snap = load_policy(ctx.out / "train_dapg").snapshot()
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
        curves["a demonstration"] = (demos[0].qpos, demos[0].goal)
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for (label, (q, g)), color in zip(curves.items(), ("tab:blue", "tab:gray"), strict=False):
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
    fig.suptitle("The flip, rolled out on the emulated D'Claw" if ctx.emulated else
                 "The flip, rolled out on the D'Claw")
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    fig.legend(*axes[1].get_legend_handles_labels(), loc="lower center", ncol=3,
               fontsize="small", frameon=False)
    name = "flip_rollout.png"
    fig.savefig(ctx.out / name, dpi=110)
    plt.close(fig)
    err = float(task.orientation_error(np.array(qpos[-1]), goal))
    return {"plot": name, "final_orientation_error_deg": round(math.degrees(err), 1),
            "success": bool(err < task.config.success_angle), "steps": len(qpos) - 1}


def _plot_training(ctx: Context, res: dict[str, Any], curves: dict[str, dict[str, Any]]) -> str:
    """Success against samples and robot time, from each run's metrics (``curves[algo]``)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for algo, color in (("dapg", "tab:blue"), ("npg", "tab:orange")):
        m = curves[algo]
        label = "DAPG (demos)" if algo == "dapg" else "NPG (scratch)"
        axes[0].plot(m["samples"], m["success_rate"], "-o", color=color, label=label)
        axes[1].plot(m["robot_hours"] * 60, m["success_rate"], "-o", color=color, label=label)
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
    name = "learning_curves.png"
    fig.savefig(ctx.out / name, dpi=110)
    plt.close(fig)
    return name


# ------------------------------------------------------------------------------------------------
# 4. reality gap


def stage_gap(ctx: Context) -> dict[str, Any]:
    """Record an identification log from the robot, compare with the nominal sim, name causes."""
    import numpy as np
    from rich.console import Console

    from lowcostdex.hardware.hands import dclaw_spec
    from lowcostdex.hardware.trace import dclaw_identification_logs
    from lowcostdex.sim.gap import GapConfig, analyze, load_dataset, write_report
    from lowcostdex.sim.gap.cli import analysis_progress
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
        "gain": report["gain"], "report": "gap/report/report.md"}
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


STAGES: tuple[tuple[str, Callable[[Context], dict[str, Any]]], ...] = (
    ("bus", stage_bus),
    ("demos", stage_demos),
    ("train", stage_train),
    ("gap", stage_gap),
    ("report", stage_report),
)


DEPENDS: dict[str, tuple[str, ...]] = {"train": ("demos",)}
"""Stages whose results a stage reads from ``--out`` (``train`` learns from ``demos.h5``)."""
OUTPUTS: dict[str, tuple[str, ...]] = {
    "bus": ("hand.json",),
    "demos": ("demos.h5",),
    "train": ("train_dapg", "train_npg", "learning_curves.png", "flip_rollout.png"),
    "gap": ("gap",),
    "report": ("robot_health.png",),
}
"""What each stage writes into ``--out``; a re-run moves them into ``previous/<time>/`` first."""
COMMAND = "main"
RESULTS = "results.json"


def _settings(ctx: Context) -> dict[str, Any]:
    return {"task": ctx.task, "size": ctx.size, "seed": ctx.seed, "port": ctx.port}


def open_job(ctx: Context, stages: tuple[str, ...]) -> None:
    """Check ``ctx.out`` and load what earlier stages left there into ``ctx.results``.

    Raises:
      OutputRefused: ``ctx.out`` holds files the main job did not write, or a run with another
        task, size, seed or port (its stages cannot build on each other).
      ConfigError: a requested stage needs a stage that neither runs now nor finished earlier in
        ``ctx.out``; the message names it and the command that provides it.
    """
    from lowcostdex.errors import ConfigError
    from lowcostdex.outdir import check_out

    settings = _settings(ctx)
    previous = check_out(ctx.out, COMMAND, settings, must_match=tuple(settings))
    if previous and (ctx.out / RESULTS).exists():
        try:
            loaded = json.loads((ctx.out / RESULTS).read_text())
        except ValueError as exc:
            raise ConfigError(f"{ctx.out / RESULTS} is not readable JSON ({exc}); move it "
                              "away or use another --out") from exc
        ctx.results.update({k: v for k, v in loaded.items() if k in dict(STAGES)})
    for name in stages:
        for need in DEPENDS.get(name, ()):
            if need in stages:
                continue
            done = ctx.results.get(need)
            missing = done is None or not (ctx.out / done.get("file", "")).is_file()
            if missing:
                raise ConfigError(
                    f"stage '{name}' needs the results of stage '{need}', which neither runs "
                    f"now nor finished earlier in {ctx.out}; run "
                    f"`lowcostdex main --out {ctx.out} --stages {need},{name}` (plus the same "
                    "--task/--size/--seed)")


def _write_results(ctx: Context) -> None:
    from lowcostdex.outdir import write_text_atomic

    write_text_atomic(ctx.out / RESULTS, json.dumps(ctx.results, indent=2, default=float))


def run(ctx: Context, stages: tuple[str, ...] | None = None) -> Path:
    """Run the stages, write results.json, report.md and report.html; return report.md.

    Stages compose: results of stages that do not run now are read from ``ctx.out`` (a previous
    run with the same task, size, seed and port), and a stage whose input is missing stops before
    anything is written. A stage that runs again first moves its old outputs and the old
    results.json into ``previous/<time>/``; nothing finished is ever overwritten.
    """
    from rich.console import Console

    from lowcostdex.outdir import archive, write_marker

    console = Console(stderr=True)
    order = tuple(name for name, _ in STAGES)
    chosen = order if stages is None else tuple(n for n in order if n in stages)
    open_job(ctx, chosen)
    ctx.out.mkdir(parents=True, exist_ok=True)
    write_marker(ctx.out, COMMAND, _settings(ctx))
    for name, fn in STAGES:
        if name not in chosen:
            continue
        old = [n for n in OUTPUTS[name] if (ctx.out / n).exists()]
        if old or name in ctx.results:
            target = archive(ctx.out, [*old, "report.md", "report.html"])
            if target is not None and (ctx.out / RESULTS).exists():
                shutil.copy2(ctx.out / RESULTS, target / RESULTS)
            if target is not None:
                console.print(f"{name}: the previous outputs are kept in "
                              f"{target.relative_to(ctx.out)}/")
        console.rule(f"[bold]{name}[/bold]: {fn.__doc__.splitlines()[0]}")
        t0 = time.perf_counter()
        result = fn(ctx)
        result["seconds"] = round(time.perf_counter() - t0, 1)
        result["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        ctx.results[name] = result
        console.print(_summary(name, result))
        _write_results(ctx)
    report = ctx.out / "report.md"
    text = _report(ctx)
    report.write_text(text)
    _html(text, ctx.out / "report.html")
    return report


def _summary(name: str, r: dict[str, Any]) -> str:
    if name == "bus":
        return (f"{r['motors_found']} motors found, missing {r['motors_missing'] or 'none'}; "
                f"calibration moved offsets by {r.get('calibration_ticks', 0):.1f} ticks at most")
    if name == "demos":
        played = (f", {r['successful_playbacks']}/{r['playbacks']} successful playbacks"
                  if "playbacks" in r else "")
        return f"{r['successful']}/{r['episodes']} successful demonstrations{played} -> {r['file']}"
    if name == "train":
        return (f"DAPG eval success {r['dapg']['eval_success']:.2f} (best "
                f"{r['dapg']['best_eval_success']:.2f}, {r['dapg']['samples']} samples), NPG "
                f"{r['npg']['eval_success']:.2f} (best {r['npg']['best_eval_success']:.2f}, "
                f"{r['npg']['samples']} samples); the behaviour clone alone "
                f"{r['success_after_bc']:.2f}; random actions "
                f"{r.get('random', {}).get('eval_success', math.nan):.2f}")
    if name == "gap":
        named = ", ".join(c["effect"] for c in r["causes"]) or "no cause"
        return (f"named: {named}; held-out RMSE {r['baseline_heldout_rmse_mrad']:.1f} -> "
                f"{r['extended_heldout_rmse_mrad']:.1f} mrad (floor {r['noise_floor_mrad']:.2f})")
    return f"done in {r['seconds']} s"


def _report(ctx: Context) -> str:
    R = ctx.results
    lines = ["# lowcostdex: the main job", "",
             f"Robot: {'emulated D' + chr(39) + 'Claw' if ctx.emulated else ctx.port}; task "
             f"{ctx.task} (`{ctx.setup.env_id}`); size {ctx.size}; seed {ctx.seed}.", ""]
    if "bus" in R:
        b = R["bus"]
        lines += ["## 1. The robot on its bus", "",
                  f"{b['motors_found']} motors answered on {b['port']}; missing: "
                  f"{b['motors_missing'] or 'none'}.", "",
                  "| id | model | firmware | temperature [C] | voltage [V] | errors |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {m['id']} | {m['model']} | {m['firmware']} | {m['temperature']} | "
                  f"{m['voltage']} | {', '.join(m['errors']) or '-'} |" for m in b["motors"]]
        if "calibration_ticks" in b:
            lines += ["", f"Calibration (hand in its zero pose) changed the default offsets by at "
                          f"most {b['calibration_ticks']:.1f} encoder ticks; the spec is "
                          f"`{b['hand_spec']}`."]
        lines.append("")
    if "demos" in R:
        d = R["demos"]
        lines += ["## 2. Kinesthetic demonstrations", "",
                  f"{d['successful']} of {d['episodes']} demonstrations {ctx.setup.did} "
                  f"({d['steps']} steps, `{d['file']}`); recording took "
                  f"{d['robot_seconds_recording']} s and the auto-resets "
                  f"{d['robot_seconds_resets']} s of robot time.", ""]
        if "playbacks" in d:
            alpha = d["servo_response"]["alpha"]
            lines += [f"Before recording, {d['robot_seconds_servo_id']} s of random goals "
                      f"identified the servos' response (a servo covers {min(alpha):.2f}-"
                      f"{max(alpha):.2f} of a commanded step per control period); each step is "
                      "labelled with the goal that reproduces it. The robot then played each "
                      f"successful demonstration back with noisy goals: {d['playbacks']} "
                      f"playbacks, {d['successful_playbacks']} {ctx.setup.did} "
                      f"({d['robot_seconds_playbacks']} s). The behaviour clone learns from the "
                      "successful episodes of both.", ""]
    if "train" in R:
        t = R["train"]
        lines += ["## 3. DAPG vs NPG on the robot", "",
                  "Evaluation success: deterministic episodes (the policy's mean action) at the "
                  "end of training, with the number of episodes and a 95 % Wilson interval.", "",
                  "| | samples | robot time [min] | training success (last) | evaluation success "
                  "(last) | best evaluation (samples) | first evaluation >= 80 % at |",
                  "|---|---|---|---|---|---|---|"]
        for algo in ("dapg", "npg"):
            a = t[algo]
            first = a.get("first_eval_crossing_samples")
            lines.append(
                f"| {algo.upper()} | {a['samples']} | {60 * a['robot_hours']:.1f} | "
                f"{a['final_training_success']:.2f} | {_rate(a)} | "
                f"{a.get('best_eval_success', float('nan')):.2f} "
                f"({a.get('best_samples', float('nan')):.0f}) | "
                f"{'not reached' if first is None else f'{first:.0f} samples'} |")
        lines += ["", "The run's policy (`train_*/policy.pt`) is its best evaluated one; the last "
                      "evaluation and the first crossing are shown beside it, so that a policy "
                      "that reached the target once and fell back is not mistaken for one that "
                      "holds it.", "",
                  "| policy | evaluation success |", "|---|---|",
                  f"| uniformly random actions (measured) | {_rate(t.get('random', {}))} |",
                  f"| behaviour clone alone, before any RL | {_rate(t.get('bc', {}))} |",
                  f"| DAPG (clone + RL) | {_rate(t['dapg'])} |",
                  f"| NPG (RL from scratch) | {_rate(t['npg'])} |", "",
                  f"**What each stage added.** {_what_each_stage_added(t)}", "",
                  f"![learning curves]({t['plot']})", ""]
        demos_done = R.get("demos", {}).get("finished")
        if t.get("demos_finished") and demos_done and t["demos_finished"] != demos_done:
            lines += ["Note: the demonstrations were recorded again after this training ran; "
                      "these results come from the earlier demonstrations (kept in "
                      "`previous/`).", ""]
        if "rollout" in t:
            ro = t["rollout"]
            lines += [f"One deterministic rollout of the DAPG policy: final orientation error "
                      f"{ro['final_orientation_error_deg']} deg "
                      f"({'success' if ro['success'] else 'no success'}), beside a recorded "
                      "demonstration:", "", f"![flip rollout]({ro['plot']})", ""]
        lines += ["Run directories: `train_dapg/`, `train_npg/` (config, metrics.csv, "
                  "checkpoints, curves, summary.json; `lowcostdex train ... --resume` continues "
                  "them).", ""]
    if "gap" in R:
        g = R["gap"]
        lines += ["## 4. What the nominal simulation gets wrong", "",
                  f"{g['logs']} identification logs of {g['seconds_per_log']:.0f} s (one finger, "
                  f"50 Hz) replayed in the nominal model.", "", f"**Verdict:** {g['verdict']}", ""]
        if g["causes"]:
            lines += ["| named cause | joints | fitted parameters |", "|---|---|---|"]
            for c in g["causes"]:
                params = "; ".join(f"{k} = " + ", ".join(f"{v:.4g}" for v in vals)
                                   for k, vals in c["params"].items())
                lines.append(f"| {c['effect']} | {', '.join(c['joints'])} | {params} |")
        if g.get("truth"):
            truth = "; ".join(f"{e['effect']} ({', '.join(f'{k}={v:.4g}' for k, v in e['params'].items())})"
                              for e in g["truth"])
            lines += ["", f"What the emulated robot really carries: {truth}."]
        gain = g["gain"]
        lines += ["", f"Held-out RMSE: {g['baseline_heldout_rmse_mrad']:.2f} mrad (nominal) -> "
                      f"{g['extended_heldout_rmse_mrad']:.2f} mrad (extended); noise floor "
                      f"{g['noise_floor_mrad']:.2f} mrad. Full report: `{g['report']}`.", ""]
        if "interval" in gain:
            lines.insert(-1, f"Gain {1e3 * gain.get('absolute', float('nan')):.2f} mrad, 95 % "
                             f"interval {gain['interval']}.")
        lines += [f"![{p}]({p})" for p in g["plots"][:3]] + [""]
    if "report" in R:
        lines += ["## 5. Robot health", "", f"![robot health]({R['report']['plot']})", ""]
    lines += ["Stage timings [s]: " + ", ".join(f"{k} {v['seconds']}" for k, v in R.items()), ""]
    return "\n".join(lines)


def _rate(r: dict[str, Any]) -> str:
    """A measured rate with its episode count and 95 % interval, from a result's
    ``eval_successes`` / ``eval_episodes``."""
    from lowcostdex.stats import rate_text

    k, n = r.get("eval_successes"), r.get("eval_episodes")
    if k is None or not n:
        return "n/a (not evaluated)"
    return rate_text(int(k), int(n))


def _what_each_stage_added(t: dict[str, Any]) -> str:
    """Words for what the clone and the RL stage changed, judged by their intervals: a
    difference is called one only when the 95 % intervals do not overlap."""
    from lowcostdex.stats import wilson_interval

    def ci(r: dict[str, Any]) -> tuple[float, float] | None:
        k, n = r.get("eval_successes"), r.get("eval_episodes")
        return wilson_interval(int(k), int(n)) if k is not None and n else None

    def compare(a: dict[str, Any], b: dict[str, Any], what: str) -> str:
        ia, ib = ci(a), ci(b)
        if ia is None or ib is None:
            return f"{what}: not measured"
        ra, rb = a["eval_successes"] / a["eval_episodes"], b["eval_successes"] / b["eval_episodes"]
        if ib[0] > ia[1]:
            return f"{what} raised success from {ra:.2f} to {rb:.2f}, beyond the intervals"
        if ib[1] < ia[0]:
            return f"{what} lowered success from {ra:.2f} to {rb:.2f}, beyond the intervals"
        return (f"{what} changed success from {ra:.2f} to {rb:.2f}, within the overlap of the "
                "95 % intervals: no difference this run can show")

    random, bc = t.get("random", {}), t.get("bc", {})
    parts = [compare(random, bc, "The demonstrations (behaviour clone vs random actions)"),
             compare(bc, t["dapg"], "RL fine-tuning (DAPG vs the clone it started from)"),
             compare(t["npg"], t["dapg"], "Demonstrations in RL (DAPG vs NPG at the same "
                     "sample budget)")]
    text = "; ".join(parts) + "."
    if (ci(bc) and ci(t["dapg"]) and bc["eval_successes"] == bc["eval_episodes"]
            and t["dapg"]["eval_successes"] == t["dapg"]["eval_episodes"]):
        text += (" The clone alone already solves this task here, so at this budget the RL "
                 "stage cannot show a gain; `--task valve-random` (random start and target "
                 "angles) is the variant where the clone is not enough.")
    return text


def _html(markdown: str, path: Path) -> None:
    """A dependency-free HTML rendering of the report (headings, tables, images, paragraphs)."""
    import html
    import re

    out, table = [], False
    for line in markdown.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-: "):
                continue
            if not table:
                out.append("<table>")
                table = True
                out.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                out.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
            continue
        if table:
            out.append("</table>")
            table = False
        m = re.match(r"!\[(.*)\]\((.*)\)", line)
        if m:
            out.append(f'<img src="{html.escape(m.group(2))}" alt="{html.escape(m.group(1))}" '
                       'style="max-width:100%">')
        elif line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            out.append(f"<h{level}>{html.escape(line.lstrip('# '))}</h{level}>")
        elif line.strip():
            text = html.escape(line)
            text = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", text)
            text = re.sub(r"`(.+?)`", r"<code>\1</code>", text)
            out.append(f"<p>{text}</p>")
    if table:
        out.append("</table>")
    style = ("body{font-family:sans-serif;max-width:60em;margin:2em auto}table{border-collapse:"
             "collapse}td,th{border:1px solid #ccc;padding:2px 8px}")
    path.write_text(f"<!doctype html><meta charset='utf-8'><title>lowcostdex main job</title>"
                    f"<style>{style}</style>\n" + "\n".join(out))


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _progress() -> Any:
    """A transient progress display (one bar per task, named by its description)."""
    from lowcostdex.progress import tasks

    return tasks()


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("main", help="run the main job end to end (emulated D'Claw by default)",
                       description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("runs/main"), help="output folder")
    p.add_argument("--size", choices=SIZES, default="default",
                   help="budget: smoke (CI, ~1 min), default (~5 min on 2 cores), long")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--task", choices=sorted(TASKS), default="valve",
                   help="valve: turn the valve 180 deg; valve-random: random start and target "
                   "angles; flip: flip the block 180 deg")
    p.add_argument("--port", default=None,
                   help="serial port of a real D'Claw, e.g. /dev/ttyUSB0 (default: emulated)")
    p.add_argument("--stages", default=None,
                   help=f"comma-separated subset of: {', '.join(n for n, _ in STAGES)}")
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    from lowcostdex.errors import check_choice

    stages = None
    if args.stages:
        stages = tuple(s.strip() for s in args.stages.split(","))
        for s in stages:
            check_choice("stage", s, [n for n, _ in STAGES])
    ctx = Context(out=args.out, size=args.size, seed=args.seed, port=args.port, task=args.task)
    report = run(ctx, stages)
    print(f"REPORT {report.resolve()}")
    return 0
