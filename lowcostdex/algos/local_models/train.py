"""Learned-local-model training on the hand envs: ``lowcostdex train tvlg``.

From a fixed start state, each iteration k runs ``n_rollouts`` episodes of the current
time-varying linear-Gaussian controller on the env, then one :func:`.tvlg.tvlg_iteration`
(cost expansion, GMM prior, dynamics fit, step rule, KL-constrained LQR) and, every
``eval_every`` iterations, one noise-free episode of the new controller. Metrics, checkpoints,
curves and resume follow :mod:`lowcostdex.algos.experiment`.

State and time indexing: the controller acts on x = [hand qpos, hand qvel, object qpos,
object qvel] (``env.unwrapped.state_vector()``) plus, by default, the last applied action (servos
track their last goal, so it is part of the physical state). An episode of H steps gives states
x_0..x_H; the controller has T = H + 1 steps and its last action is drawn but not executed, so
the final state is costed. The commanded (unclipped) action is recorded: the env clips it, and
the fitted model learns that saturation.

Reproducibility: the start state is captured once (``reset(seed=seed)``) and every episode
starts there (``reset(options={"qpos", "qvel", "goal"})``); the reset seed and the exploration
noise of episode i of iteration k derive from (seed, stream, k, i) as in
:mod:`lowcostdex.algos.samplers`, and the update's generator from (seed, k). A resumed run
therefore equals the uninterrupted one on a deterministic backend.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import SumCost
from lowcostdex.algos.local_models.episodes import (
    Episode,
    FixedStart,
    capture_start,
    check_hand_qpos,
    controller_state,
    hold_action,
    run_episode,
)
from lowcostdex.algos.local_models.initial import (
    TEACHER_FILE,
    demo_actions_array,
    initial_controller,
    teacher_episodes,
)
from lowcostdex.algos.local_models.task_cost import task_cost
from lowcostdex.algos.local_models.train_config import (
    BACKENDS,
    COST_PRESETS,
    INITS,
    MUTABLE_ON_RESUME,
    TRACKING_KL_STEP,
    TaskCostConfig,
    TVLGTrainConfig,
)
from lowcostdex.algos.local_models.tvlg import (
    TVLGState,
    state_from_arrays,
    state_to_arrays,
    tvlg_iteration,
)
from lowcostdex.algos.samplers import EVAL_STREAM, TRAIN_STREAM, EnvFactory, RolloutJob
from lowcostdex.errors import ConfigError, InputError
from lowcostdex.options import robot_selection

Array = NDArray[np.float64]
_UPDATE = 13  # seed purpose of the update generator (the GMM's EM)
CONTROLLER_FILE = "controller.npz"


def is_solved(noise_free_success: bool, noisy_success_rate: float, solve_rate: float) -> bool:
    """The benchmark's definition: the noise-free episode succeeds and, when noisy held-out
    episodes were run (rate not NaN), at least ``solve_rate`` of them succeed."""
    if not noise_free_success:
        return False
    return math.isnan(noisy_success_rate) or noisy_success_rate >= solve_rate


# ----------------------------------------------------------------------------------------------
# Training loop


def default_env_factory(config: TVLGTrainConfig) -> Callable[[], gym.Env]:
    return EnvFactory(config.env_id, {"backend": config.backend, **config.env_kwargs})


def _progress(config: TVLGTrainConfig, start: int) -> Any:
    from lowcostdex.progress import bar

    return bar(total=config.n_iter, initial=start, disable=not config.progress,
               desc=f"tvlg {config.env_id}", unit="it")


def _numpy(tree: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v.numpy() if hasattr(v, "numpy") else v for k, v in tree.items()}


def train(
    config: TVLGTrainConfig,
    out_dir: str | Path,
    resume: bool = False,
    env_factory: Callable[[], gym.Env] | None = None,
    stop_after: int | None = None,
) -> ex.Run:
    """Train, writing the run directory ``out_dir``; returns the (closed) run.

    Args:
      config: the run.
      out_dir: run directory (see :mod:`lowcostdex.algos.experiment`).
      resume: continue from the last checkpoint in ``out_dir``.
      env_factory: overrides the env built from ``config.env_id``/``backend``.
      stop_after: stop after this iteration index as if killed (tests of resume).
    """
    if not isinstance(config, TVLGTrainConfig):
        raise ConfigError(f"train() takes a TVLGTrainConfig, not {type(config).__name__}: "
                          "TVLGTrainConfig(...), or TVLGTrainConfig.from_dict(d) for a dict")
    ex.Run.check(out_dir, dataclasses.asdict(config), resume=resume,
                 mutable_keys=MUTABLE_ON_RESUME)
    if env_factory is None:
        from lowcostdex.algos.train import check_env_id  # imports torch: not at CLI start

        check_env_id(config.env_id)
    env = (env_factory or default_env_factory(config))()  # fails before anything is written
    run: ex.Run | None = None
    try:
        if config.init == "demos":  # the file fits this env (id, sizes, bounds) before any write
            from lowcostdex.demonstrations.dataset import check_demos, load_demos

            check_demos(load_demos(config.demos), config.demos, env, config.env_id)
        if config.start_hand_qpos is not None:
            check_hand_qpos(config.start_hand_qpos, env.unwrapped.task)
        run = ex.Run.open(
            out_dir, dataclasses.asdict(config), resume=resume, mutable_keys=MUTABLE_ON_RESUME
        )
        ckpt = run.load_latest() if resume else None
        if ckpt is None:
            start = capture_start(env, config.seed, config.start_hand_qpos)
        else:
            start = FixedStart.from_arrays(_numpy(ckpt.state["start"]))
        hold = hold_action(env, start)
        env.reset(options=start.reset_options())
        x0 = controller_state(env, hold if config.include_last_action else None)
        T = (
            int(
                env.spec.max_episode_steps
                if env.spec and env.spec.max_episode_steps
                else env.unwrapped.task.timing.episode_steps
            )
            + 1
        )
        demo_actions = None
        if ckpt is None:
            counters = {"samples": 0, "rollouts": 0, "robot_seconds": 0.0, "teacher_episodes": 0}
            if config.init == "teacher":
                teach = teacher_episodes(env, start, config, hold, T, run.path / TEACHER_FILE)
                obj = 2 * len(hold)  # object angle in the controller state
                start = dataclasses.replace(start, reference=float(np.mean(teach.X[:, -1, obj])))
                demo_actions = teach.U
                counters["teacher_episodes"] = config.teacher_episodes
                counters["robot_seconds"] += teach.robot_seconds
            elif config.init == "demos":
                demo_actions = demo_actions_array(config.demos, T)
            ctl = initial_controller(config, env, start, x0, hold, T, demo_actions)
            state = TVLGState.initial(ctl, config.algo)
            first = 0
        else:
            state = state_from_arrays(_numpy(ckpt.state["tvlg"]))
            counters = dict(ckpt.state["counters"])
            first = ckpt.iteration + 1
            # the demonstration the run started from, not rebuilt from a file: the teacher's
            # episodes are not a demo file's (failed ones kept, last action not executed) and
            # config.demos may have changed since
            if config.init in ("teacher", "demos") and "demo_actions" not in ckpt.state:
                raise ConfigError(
                    f"the checkpoint in {run.path} predates stored demonstration actions; "
                    "start the run again"
                )
            saved = ckpt.state.get("demo_actions")
            demo_actions = None if saved is None else np.asarray(saved)
        cost = task_cost(env, start, hold, config.cost, T, x0.shape[0], demo_actions)
        _loop(config, run, env, state, cost, start, hold, demo_actions, counters, first, stop_after)
    except BaseException as exc:  # Ctrl-C saves the last iteration; a failed start is undone
        stopped = ex.stopped(run, exc, resume)
        if stopped is exc:
            raise
        raise stopped from None
    finally:
        env.close()
        if run is not None:
            run.close()
    return run


def _loop(
    config: TVLGTrainConfig,
    run: ex.Run,
    env: gym.Env,
    state: TVLGState,
    cost: SumCost,
    start: FixedStart,
    hold: Array,
    demo_actions: Array | None,
    counters: dict[str, Any],
    first: int,
    stop_after: int | None,
) -> None:
    bar = _progress(config, first)
    last = config.n_iter - 1

    def episode(ctl: LinearGaussianController, job: RolloutJob) -> Episode:
        return run_episode(
            env, ctl, start, job, config.include_last_action, hold, config.smooth_noise
        )

    for k in range(first, config.n_iter):
        t0 = time.perf_counter()
        episodes = [
            episode(state.controller, RolloutJob(config.seed, TRAIN_STREAM, k, i))
            for i in range(config.n_rollouts)
        ]
        t1 = time.perf_counter()
        X = np.stack([e.X for e in episodes])
        U = np.stack([e.U for e in episodes])
        rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(_UPDATE, k)))
        state, stats = tvlg_iteration(state, X, U, cost, config.algo, rng)
        t2 = time.perf_counter()
        counters["samples"] += sum(len(e.rewards) for e in episodes)
        counters["rollouts"] += len(episodes)
        counters["robot_seconds"] += sum(e.robot_seconds for e in episodes)
        row: dict[str, Any] = {
            ex.ITERATION: k,
            "rollouts": counters["rollouts"],
            "teacher_episodes": counters.get("teacher_episodes", 0),
            ex.SUCCESS_RATE: float(np.mean([e.success(config.success) for e in episodes])),
            ex.RETURN_MEAN: float(np.mean([e.rewards.sum() for e in episodes])),
            "final_abs_error": float(np.mean([abs(e.final_error) for e in episodes])),
            ex.EVAL_SUCCESS_RATE: math.nan,
            ex.EVAL_RETURN_MEAN: math.nan,
            "eval_final_abs_error": math.nan,
            "eval_noisy_success_rate": math.nan,
            "solved": math.nan,
        }
        if k == last or (config.eval_every > 0 and (k + 1) % config.eval_every == 0):
            ev = episode(
                state.controller, RolloutJob(config.seed, EVAL_STREAM, k, 0, deterministic=True)
            )
            noisy = [
                episode(state.controller, RolloutJob(config.seed, EVAL_STREAM, k, 1 + i))
                for i in range(config.eval_noisy_episodes)
            ]
            counters["robot_seconds"] += ev.robot_seconds + sum(e.robot_seconds for e in noisy)
            noisy_rate = (
                float(np.mean([e.success(config.success) for e in noisy])) if noisy else math.nan
            )
            row.update({
                ex.EVAL_SUCCESS_RATE: float(ev.success(config.success)),
                ex.EVAL_RETURN_MEAN: float(ev.rewards.sum()),
                "eval_final_abs_error": abs(ev.final_error),
                "eval_noisy_success_rate": noisy_rate,
                "solved": float(is_solved(ev.success(config.success), noisy_rate,
                                          config.solve_rate)),
            })  # fmt: skip
        row.update(
            {ex.SAMPLES: counters["samples"], ex.ROBOT_HOURS: counters["robot_seconds"] / 3600}
        )
        row.update(stats)
        row.update(
            {
                "time_sampling": t1 - t0,
                "time_update": t2 - t1,
                "time_eval": time.perf_counter() - t2,
            }
        )
        run.log(row)
        snapshot = {
            "tvlg": state_to_arrays(state), "start": start.to_arrays(), "counters": counters,
            "demo_actions": demo_actions,
        }  # fmt: skip
        if k == last or (k + 1) % config.checkpoint_every == 0 or k == stop_after:
            run.save_checkpoint(k, snapshot)
        else:  # saved if Ctrl-C comes before the next checkpoint
            run.keep_for_interrupt(k, snapshot)
        bar.update(1)
        bar.set_postfix(
            rollouts=counters["rollouts"], success=f"{row[ex.SUCCESS_RATE]:.2f}",
            cost=f"{stats['sample_cost']:.1f}", kl=f"{stats['kl']:.2f}",
        )  # fmt: skip
        if k == stop_after:
            break
    bar.close()
    run.plot_learning_curves(f"TVLG on {config.env_id} (seed {config.seed})")
    _write_controller(run.path / CONTROLLER_FILE, state.controller, start)


def _write_controller(path: Path, controller: LinearGaussianController, start: FixedStart) -> None:
    import io

    buf = io.BytesIO()
    arrays = {f"controller/{k}": v for k, v in controller.to_arrays().items()}
    arrays.update({f"start/{k}": v for k, v in start.to_arrays().items()})
    np.savez(buf, **arrays)
    ex.write_bytes_atomic(path, buf.getvalue())


def load_controller(
    run_dir: str | Path,
) -> tuple[LinearGaussianController, FixedStart, TVLGTrainConfig]:
    """The final controller of a run directory, its start state and the run's config."""
    run_dir = Path(run_dir)
    stored = ex.read_json(run_dir / ex.CONFIG_FILE)
    if not isinstance(stored, dict) or "n_rollouts" not in stored:  # no TVLG run's config
        trainer = ex._trainer_of(stored) if isinstance(stored, dict) else "another program"
        raise InputError(f"{run_dir} is a run of {trainer}, not of 'train tvlg': load its "
                         f"policy with lowcostdex.algos.train.load_policy({str(run_dir)!r})")
    config = TVLGTrainConfig.from_dict(stored)
    with np.load(run_dir / CONTROLLER_FILE, allow_pickle=False) as data:
        arrays = dict(data)
    ctl = LinearGaussianController.from_arrays(
        {k[11:]: v for k, v in arrays.items() if k.startswith("controller/")}
    )
    start = FixedStart.from_arrays({k[6:]: v for k, v in arrays.items() if k.startswith("start/")})
    return ctl, start, config


# ----------------------------------------------------------------------------------------------
# CLI: `lowcostdex train tvlg ...`


def add_train_commands(train_subparsers: argparse._SubParsersAction) -> None:
    """Add ``tvlg`` to the ``lowcostdex train`` group."""
    help_text = "learned local models: TVLG dynamics + KL-constrained iLQG from a fixed start"
    p = train_subparsers.add_parser("tvlg", help=help_text, description=help_text)
    d = TVLGTrainConfig()
    p.add_argument(
        "--env", default="DClawTurnValve-v0", help="env id, with or without the lowcostdex/ prefix"
    )
    p.add_argument("--backend", choices=BACKENDS, default=d.backend,
                   help="where episodes run: MuJoCo, the emulated or the real robot (default %(default)s)")
    p.add_argument("--port", default=None, help="serial port of a real robot (hardware backend)")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its last checkpoint"
    )
    p.add_argument("--seed", type=int, default=d.seed, help="run seed (default %(default)s)")
    p.add_argument("--n-iter", type=int, default=d.n_iter, help="training iterations (default %(default)s)")
    p.add_argument("--n-rollouts", type=int, default=d.n_rollouts, help="episodes per iteration")
    p.add_argument("--init", choices=INITS, default=d.init,
                   help="initial controller: a PD hold, fitted to --demos, or the teacher (default %(default)s)")
    p.add_argument("--demos", default=None, help="demonstration dataset (HDF5) for --init demos")
    p.add_argument(
        "--init-noise", type=float, default=d.init_noise, help="initial action noise std"
    )
    p.add_argument(
        "--teacher-episodes", type=int, default=d.teacher_episodes, help="for --init teacher"
    )
    p.add_argument(
        "--smooth-noise", type=float, default=d.smooth_noise, help="noise smoothing [steps]"
    )
    p.add_argument(
        "--kl-step", type=float, default=None,
        help=f"KL per step [nats]; default {d.algo.traj_opt.kl_step}, {TRACKING_KL_STEP} with "
        "--cost tracking (the measured configuration)",
    )  # fmt: skip
    p.add_argument(
        "--min-step-mult", type=float, default=d.algo.traj_opt.min_step_mult,
        help="floor of the adaptive KL step multiplier",
    )  # fmt: skip
    p.add_argument("--prior-strength", type=float, default=d.algo.dynamics.prior_strength,
                   help="pseudo-sample count of the dynamics prior (1.0 ~ one extra rollout; "
                        "default %(default)s)")
    p.add_argument(
        "--cost", choices=COST_PRESETS, default="task",
        help="task: goal at every step, hand near its start pose; tracking: hand near the "
        "demonstrated joint targets, goal over the last steps (needs --init teacher or demos)",
    )  # fmt: skip
    p.add_argument(
        "--object-weight", type=float, default=None, help="object-angle weight (preset's default)"
    )
    p.add_argument(
        "--pose-weight", type=float, default=None, help="hand-joint weight (preset's default)"
    )
    p.add_argument(
        "--final-steps", type=int, default=None,
        help="last steps carrying the goal with the final_only ramp (preset's default)",
    )  # fmt: skip
    p.add_argument(
        "--eval-noisy-episodes", type=int, default=d.eval_noisy_episodes,
        help="held-out noisy episodes per evaluation (success criterion; not used for learning)",
    )  # fmt: skip
    p.add_argument(
        "--no-last-action", action="store_true", help="leave the last action out of the state"
    )
    p.add_argument(
        "--start-hand-qpos", type=float, nargs="+", default=None, metavar="RAD",
        help="hand joint angles of the fixed start (action order) instead of the reset pose",
    )  # fmt: skip
    p.add_argument("--eval-every", type=int, default=d.eval_every,
                   help="evaluate every N iterations (0: after the last only) (default %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_run_command, parser=p)


def config_from_args(args: argparse.Namespace) -> TVLGTrainConfig:
    """Build a config from parsed ``lowcostdex train tvlg`` arguments."""
    from lowcostdex.algos.train_cli import check_resume

    check_resume(args.out, args.resume)
    if args.demos and args.init != "demos":
        raise ConfigError(f"--demos {args.demos} is read with --init demos only (this run starts "
                          f"from --init {args.init}); add --init demos, or leave out --demos")
    backend, robot_kwargs = robot_selection(args.backend, args.port)
    d = TVLGTrainConfig()
    env_id = args.env if "/" in args.env else f"lowcostdex/{args.env}"
    kl_step = args.kl_step
    if kl_step is None:
        kl_step = TRACKING_KL_STEP if args.cost == "tracking" else d.algo.traj_opt.kl_step
    overrides = {
        k: getattr(args, k)
        for k in ("object_weight", "pose_weight", "final_steps")
        if getattr(args, k) is not None
    }
    return TVLGTrainConfig(
        env_id=env_id,
        backend=backend,
        env_kwargs=robot_kwargs,
        seed=args.seed,
        n_iter=args.n_iter,
        n_rollouts=args.n_rollouts,
        include_last_action=not args.no_last_action,
        start_hand_qpos=tuple(args.start_hand_qpos) if args.start_hand_qpos else None,
        init=args.init,
        demos=str(Path(args.demos).resolve()) if args.demos else None,
        teacher_episodes=args.teacher_episodes,
        init_noise=args.init_noise,
        smooth_noise=args.smooth_noise,
        eval_every=args.eval_every,
        eval_noisy_episodes=args.eval_noisy_episodes,
        cost=dataclasses.replace(TaskCostConfig.preset(args.cost), **overrides),
        algo=dataclasses.replace(
            d.algo,
            dynamics=dataclasses.replace(d.algo.dynamics, prior_strength=args.prior_strength),
            traj_opt=dataclasses.replace(
                d.algo.traj_opt, kl_step=kl_step, min_step_mult=args.min_step_mult
            ),
        ),
        progress=not args.no_progress,
    )


def _run_command(args: argparse.Namespace) -> int:
    from lowcostdex.algos.train_cli import beside_note, finished_note

    config = config_from_args(args)
    note = finished_note(args)
    beside = beside_note(args)
    try:
        run = train(config, args.out, resume=args.resume)
    except KeyboardInterrupt as exc:
        from lowcostdex.algos.train_cli import _interrupted

        return _interrupted(args, exc)
    metrics = run.read_metrics()
    print(f"run: {run.path}")
    print(f"curves: {run.path / ex.CURVES_FILE}")
    if metrics.get("rollouts", np.array([])).size:
        print(
            f"rollouts: {int(metrics['rollouts'][-1])}, last training success rate "
            f"{metrics[ex.SUCCESS_RATE][-1]:.2f}, eval success {metrics[ex.EVAL_SUCCESS_RATE][-1]:.0f}"
        )
    for said in (note, beside):
        if said:
            print(said, file=sys.stderr)
    return 0
