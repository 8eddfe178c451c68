"""Training runs of NPG and DAPG: sampling, advantages, updates, evaluation, run directory.

One iteration k (mjrl's order):

1. sample ``n_traj`` trajectories of the current policy (seeded per trajectory index, so the
   result does not depend on the sampler or its number of workers);
2. advantages by GAE with the value baseline fitted on iteration k-1's data; a truncated
   episode is bootstrapped with V(s_T), a terminated one with 0;
3. an NPG step (:func:`npg.npg_update`) or a DAPG step (:func:`dapg.dapg_update`, demo weight
   decaying with k; BC runs once before iteration 0);
4. refit the baseline on this batch; merge the batch into the running observation statistics
   (the policy mean is preserved; skipped when they are frozen, e.g. set from demos);
5. every ``eval_every`` iterations and at the last one, deterministic (mean-action) evaluation
   episodes from a separate seed stream;
6. log a metrics row, checkpoint, update the progress bar.

All randomness is derived from ``seed`` per (purpose, iteration, trajectory), so a run resumed
from its last checkpoint reproduces the uninterrupted run exactly (on a deterministic
backend); the checkpoint holds the policy, the baseline with its Adam state, and counters.

Robot time counts every episode the robot ran (training and evaluation): steps times the
control period, plus the reset and thermal-pause time the env reports.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.baseline import BaselineConfig, MLPBaseline
from lowcostdex.algos.bc import BC_LOG_STD, BCConfig, behavior_clone
from lowcostdex.algos.dapg import DAPGConfig, dapg_update
from lowcostdex.algos.demos import Demos, load_demos
from lowcostdex.algos.npg import NPGConfig, npg_update
from lowcostdex.algos.policy import GaussianMLPPolicy, PolicyConfig
from lowcostdex.algos.returns import discounted_returns, gae
from lowcostdex.algos.samplers import (
    EVAL_STREAM,
    SAMPLERS,
    TRAIN_STREAM,
    EnvFactory,
    EnvFactoryFn,
    ProcessSampler,
    RaySampler,
    Sampler,
    SerialSampler,
    Trajectory,
    VectorSampler,
    make_jobs,
)
from lowcostdex.errors import ConfigError, check_choice

ALGOS = ("npg", "dapg")
BACKENDS = ("sim", "emulated", "hardware")
OBS_NORMS = ("running", "frozen")
SUCCESS_MODES = ("final", "any")
ROBOT_COUNTERS = (
    "resets",
    "reset_failures",
    "reset_success_rate",
    "reset_time",
    "pauses",
    "pause_time",
    "overloads",
    "thermal_relaxations",
    "faults",
    "invalid_reads",
    "max_temperature",
)
"""Robot telemetry logged every iteration on emulated/hardware backends (as ``robot_<key>``);
cumulative over the process's lifetime (they restart after a resume)."""
MUTABLE_ON_RESUME = ("n_iter", "progress", "torch_threads")
"""Config keys a resumed run may change."""

# Seed-sequence purposes (first spawn-key entry); trajectories use samplers.*_STREAM (0, 1).
_POLICY_INIT, _BASELINE_INIT, _BC, _UPDATE, _BASELINE_FIT = 10, 11, 12, 13, 14


@dataclass(frozen=True)
class TrainConfig:
    """One NPG or DAPG run.

    Attributes:
      algo: one of ALGOS.
      env_id: registered gymnasium id, e.g. "lowcostdex/DClawTurnValve-v0".
      backend: one of BACKENDS; "emulated" and "hardware" sample serially on one robot.
      env_kwargs: extra ``gym.make`` keyword arguments (e.g. ``{"port": "/dev/ttyUSB0"}``).
      seed: the run's seed; every random draw derives from it.
      n_iter: number of iterations.
      n_traj: trajectories per iteration (hand_dapg: 200 of 200 steps).
      gamma: discount (mjrl/hand_dapg: 0.995).
      gae_lambda: GAE lambda (mjrl/hand_dapg: 0.97).
      bootstrap_truncated: bootstrap time-limit truncations with V(s_T) (mjrl does).
      sampler: one of SAMPLERS ("serial" on emulated/hardware backends).
      n_workers: workers of the process/ray samplers, envs of the vector sampler.
      obs_norm: "running" (update from each batch unless frozen, e.g. by BC) or "frozen".
      success: trajectory success from ``info["success"]``: at the final step or at any step.
      eval_every: evaluation period [iterations]; 0 evaluates only after the last iteration.
      eval_episodes: deterministic evaluation episodes per evaluation.
      checkpoint_every: checkpoint period [iterations] (the last iteration always saves).
      demos: demonstration dataset (:mod:`lowcostdex.demo_file`; its successful episodes are
        used), required for DAPG; for NPG, ``bc_init`` uses it.
      n_demos: use only the first n demo episodes (None: all).
      bc_init: behaviour-clone before RL (always on for DAPG; NPG + BC is "BCRL").
      policy, baseline, npg, dapg, bc: component configs. Defaults: the hand_dapg policy
        (32, 32) with init log-std -0.5; the NPG step delta 0.1 with damping 1e-2 rather than
        mjrl's 0.05 / 1e-4: on DClawTurnValve-v0 with 40 trajectories per iteration, 0.05 /
        1e-4 had no successful episode after 100 iterations while 0.1 / 1e-2 reached 80 %
        training success in ~140 (bench/RESULTS.md); 1e-4 damping also let single steps reach
        KL ~1 on small batches (second-order model off).
      torch_threads: torch intra-op threads during training. The networks are small, so one
        thread is fastest (two threads on a busy 2-core machine measured ~70x slower per
        Fisher-vector product).
      progress: show a progress bar.
    """

    algo: str = "npg"
    env_id: str = "lowcostdex/DClawTurnValve-v0"
    backend: str = "sim"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    n_iter: int = 100
    n_traj: int = 50
    gamma: float = 0.995
    gae_lambda: float = 0.97
    bootstrap_truncated: bool = True
    sampler: str = "serial"
    n_workers: int = 1
    obs_norm: str = "running"
    success: str = "final"
    eval_every: int = 5
    eval_episodes: int = 10
    checkpoint_every: int = 1
    demos: str | None = None
    n_demos: int | None = None
    bc_init: bool = False
    policy: PolicyConfig = field(
        default_factory=lambda: PolicyConfig(hidden_sizes=(32, 32), init_log_std=-0.5)
    )
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    npg: NPGConfig = field(default_factory=lambda: NPGConfig(step_size=0.1, damping=1e-2))
    dapg: DAPGConfig = field(default_factory=DAPGConfig)
    bc: BCConfig = field(default_factory=BCConfig)
    torch_threads: int = 1
    progress: bool = True

    def __post_init__(self) -> None:
        check_choice("algorithm", self.algo, ALGOS)
        check_choice("backend", self.backend, BACKENDS)
        check_choice("sampler", self.sampler, SAMPLERS)
        check_choice("observation normalisation", self.obs_norm, OBS_NORMS)
        check_choice("success mode", self.success, SUCCESS_MODES)
        if self.backend != "sim" and self.sampler != "serial":
            raise ConfigError(
                f"backend {self.backend!r} runs one robot: use sampler 'serial', not {self.sampler!r}"
            )
        if self.algo == "dapg" and not self.demos:
            raise ConfigError("DAPG needs demonstrations: set demos (--demos PATH)")
        if self.bc_init and not self.demos:
            raise ConfigError("bc_init needs demonstrations: set demos (--demos PATH)")
        for name in (
            "n_iter",
            "n_traj",
            "n_workers",
            "eval_episodes",
            "checkpoint_every",
            "torch_threads",
        ):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 1")
        if self.eval_every < 0:
            raise ConfigError(f"eval_every={self.eval_every} must be >= 0")
        if self.n_demos is not None and self.n_demos < 1:
            raise ConfigError(f"n_demos={self.n_demos} must be >= 1 or None")
        if not (0 <= self.gamma <= 1 and 0 <= self.gae_lambda <= 1):
            raise ConfigError(
                f"gamma={self.gamma} and gae_lambda={self.gae_lambda} must be in [0, 1]"
            )

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of ``dataclasses.asdict`` (e.g. a run's config.json)."""
        d = dict(d)
        nested = {
            "policy": PolicyConfig.from_dict,
            "baseline": BaselineConfig.from_dict,
            "npg": lambda x: NPGConfig(**x),
            "dapg": lambda x: DAPGConfig(**x),
            "bc": lambda x: BCConfig(**x),
        }
        for key, build in nested.items():
            if key in d and isinstance(d[key], dict):
                d[key] = build(d[key])
        return cls(**d)

    @property
    def uses_demos(self) -> bool:
        return self.algo == "dapg" or self.bc_init


# ----------------------------------------------------------------------------------------------
# Pieces of an iteration


def seed_generator(seed: int, *key: int) -> torch.Generator:
    """A torch.Generator seeded from ``SeedSequence(seed, spawn_key=key)``."""
    state = np.random.SeedSequence(seed, spawn_key=key).generate_state(2, np.uint32)
    return torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))


def trajectory_success(path: Trajectory, mode: str) -> bool:
    """Success of an episode from its per-step flags (see SUCCESS_MODES)."""
    if len(path) == 0:
        return False
    return bool(path.successes[-1]) if mode == "final" else bool(path.successes.any())


@dataclass
class Batch:
    """Flattened samples of one iteration: obs (N, d), actions (N, m), t (N,), advantages and
    returns (N,)."""

    obs: np.ndarray
    actions: np.ndarray
    t: np.ndarray
    advantages: np.ndarray
    returns: np.ndarray


def compute_batch(
    paths: Sequence[Trajectory], baseline: MLPBaseline, gamma: float, lam: float, bootstrap: bool
) -> Batch:
    """GAE advantages and (bootstrapped) returns for every path."""
    obs, acts, ts, advs, rets = [], [], [], [], []
    for p in paths:
        t = np.arange(len(p))
        values = baseline.predict(p.observations, t)
        last = 0.0
        if p.truncated and bootstrap:
            last = float(baseline.predict(p.final_observation[None], np.array([len(p)]))[0])
        advs.append(gae(p.rewards, values, last, gamma, lam))
        rets.append(discounted_returns(p.rewards, gamma, last))
        obs.append(p.observations)
        acts.append(p.actions)
        ts.append(t)
    return Batch(
        np.concatenate(obs),
        np.concatenate(acts),
        np.concatenate(ts),
        np.concatenate(advs),
        np.concatenate(rets),
    )


def path_metrics(
    paths: Sequence[Trajectory], success_mode: str, prefix: str = ""
) -> dict[str, float]:
    """Success rate and return statistics of a set of episodes."""
    returns = np.array([p.total_reward for p in paths])
    out = {
        f"{prefix}success_rate": float(
            np.mean([trajectory_success(p, success_mode) for p in paths])
        ),
        f"{prefix}return_mean": float(returns.mean()),
    }
    if not prefix:
        out.update(
            return_std=float(returns.std()),
            return_min=float(returns.min()),
            return_max=float(returns.max()),
            episode_length=float(np.mean([len(p) for p in paths])),
            goal_error_final=float(np.mean([p.final_goal_error for p in paths])),
        )
        terms = sorted({k for p in paths for k in p.reward_terms})
        for k in terms:
            out[k] = float(np.mean([p.reward_terms.get(k, 0.0) for p in paths]))
    return out


def make_sampler(config: TrainConfig, env_factory: EnvFactoryFn) -> Sampler:
    """The sampler the config asks for."""
    if config.sampler == "serial":
        return SerialSampler(env_factory)
    if config.sampler == "process":
        return ProcessSampler(env_factory, config.n_workers)
    if config.sampler == "ray":
        return RaySampler(env_factory, config.n_workers)
    return VectorSampler(config.env_id, config.n_workers, dict(config.env_kwargs))


def default_env_factory(config: TrainConfig) -> EnvFactory:
    return EnvFactory(config.env_id, {"backend": config.backend, **config.env_kwargs})


# ----------------------------------------------------------------------------------------------
# The training loop


@dataclass
class _State:
    policy: GaussianMLPPolicy
    baseline: MLPBaseline
    samples: int = 0
    robot_seconds: float = 0.0
    pause_seconds: float = 0.0

    def to_checkpoint(self, iteration: int) -> dict[str, Any]:
        return {
            "iteration": iteration,
            "policy": self.policy.to_checkpoint(),
            "baseline": self.baseline.to_checkpoint(),
            "counters": {
                "samples": self.samples,
                "robot_seconds": self.robot_seconds,
                "pause_seconds": self.pause_seconds,
            },
            # All draws after this point derive from the seed and the iteration index, so no
            # generator state is carried; the torch default generator is recorded for audit.
            "torch_rng": torch.get_rng_state(),
        }


def _init_state(config: TrainConfig, probe: Any, demos: Demos | None, run: ex.Run) -> _State:
    obs_dim = int(np.prod(probe.observation_space.shape))
    act_dim = int(np.prod(probe.action_space.shape))
    horizon = probe.spec.max_episode_steps if probe.spec and probe.spec.max_episode_steps else 1000
    policy = GaussianMLPPolicy(
        obs_dim, act_dim, config.policy, seed_generator(config.seed, _POLICY_INIT)
    )
    baseline = MLPBaseline(
        obs_dim, horizon, config.baseline, seed_generator(config.seed, _BASELINE_INIT)
    )
    if demos is not None:
        if demos.observations.shape[1] != obs_dim or demos.actions.shape[1] != act_dim:
            raise ConfigError(
                f"demos have obs/action sizes {demos.observations.shape[1]}/{demos.actions.shape[1]}, "
                f"the env {obs_dim}/{act_dim}"
            )
        stats = behavior_clone(
            policy, demos.observations, demos.actions, config.bc, seed_generator(config.seed, _BC)
        )
        run.write_json(
            "bc.json", {**stats, "n_episodes": demos.n_episodes, "n_pairs": len(demos.actions)}
        )
    return _State(policy, baseline)


def _restore(state: _State, ckpt: ex.Checkpoint) -> None:
    state.policy.load_state_dict(ckpt.state["policy"]["state_dict"])
    state.baseline.load_checkpoint(ckpt.state["baseline"])
    counters = ckpt.state["counters"]
    state.samples = int(counters["samples"])
    state.robot_seconds = float(counters["robot_seconds"])
    state.pause_seconds = float(counters["pause_seconds"])


def _update(
    config: TrainConfig, state: _State, batch: Batch, demos: Demos | None, k: int
) -> dict[str, float]:
    gen = seed_generator(config.seed, _UPDATE, k)
    if config.algo == "dapg":
        assert demos is not None
        stats = dapg_update(
            state.policy, batch.obs, batch.actions, batch.advantages,
            demos.observations, demos.actions, k, config.dapg, config.npg, gen,
        )  # fmt: skip
    else:
        stats = npg_update(
            state.policy, batch.obs, batch.actions, batch.advantages, config.npg, gen
        )
        stats.update(demo_weight=math.nan, demo_log_lik=math.nan)
    return stats


def _progress(config: TrainConfig, start: int) -> Any:
    from tqdm.auto import tqdm

    return tqdm(
        total=config.n_iter, initial=start, disable=not config.progress, desc=f"{config.algo} {config.env_id}",
        unit="it", dynamic_ncols=True,
    )  # fmt: skip


def train(
    config: TrainConfig,
    out_dir: str | Path,
    resume: bool = False,
    env_factory: EnvFactoryFn | None = None,
    stop_after: int | None = None,
    until: Callable[[Mapping[str, float]], bool] | None = None,
) -> ex.Run:
    """Train, writing the run directory ``out_dir``; returns the (closed) :class:`~experiment.Run`.

    Args:
      config: the run.
      out_dir: run directory (see :mod:`lowcostdex.algos.experiment`).
      resume: continue from the last checkpoint in ``out_dir``.
      env_factory: overrides the env built from ``config.env_id``/``backend`` (tests use
        this for small inline envs; it must be picklable for the process sampler). The vector
        sampler always batches ``config.env_id``.
      stop_after: stop after this iteration index as if killed (for tests of resume).
      until: called with each iteration's training metrics (the row's keys so far); when it
        returns True that iteration becomes the last one (evaluated, checkpointed), e.g. to
        stop a benchmark run some iterations after it reached a success rate.
    """
    run = ex.Run.open(
        out_dir, dataclasses.asdict(config), resume=resume, mutable_keys=MUTABLE_ON_RESUME
    )
    env_factory = env_factory or default_env_factory(config)
    demos = load_demos(config.demos).first(config.n_demos) if config.uses_demos else None
    probe = SerialSampler(env_factory) if config.sampler != "serial" else None
    sampler = make_sampler(config, env_factory)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.torch_threads)
    try:
        env = probe.env if probe is not None else sampler.env  # type: ignore[attr-defined]
        ckpt = run.load_latest() if resume else None
        state = _init_state(config, env, demos if ckpt is None else None, run)
        if probe is not None:
            probe.close()
        start = 0
        if ckpt is not None:
            _restore(state, ckpt)
            start = ckpt.iteration + 1
        _loop(config, run, sampler, state, demos, start, stop_after, until)
    finally:
        torch.set_num_threads(threads)
        sampler.close()
        run.close()
    return run


def _loop(
    config: TrainConfig,
    run: ex.Run,
    sampler: Sampler,
    state: _State,
    demos: Demos | None,
    start: int,
    stop_after: int | None,
    until: Callable[[Mapping[str, float]], bool] | None,
) -> None:
    bar = _progress(config, start)
    last = config.n_iter - 1
    for k in range(start, config.n_iter):
        t0 = time.perf_counter()
        paths = sampler.sample(
            state.policy.snapshot(), make_jobs(config.seed, TRAIN_STREAM, k, config.n_traj)
        )
        t1 = time.perf_counter()
        batch = compute_batch(
            paths, state.baseline, config.gamma, config.gae_lambda, config.bootstrap_truncated
        )
        stats = _update(config, state, batch, demos, k)
        stats.update(
            state.baseline.fit(
                batch.obs, batch.t, batch.returns, seed_generator(config.seed, _BASELINE_FIT, k)
            )
        )
        if config.obs_norm == "running":
            state.policy.update_obs_normalizer(batch.obs)
        t2 = time.perf_counter()
        state.samples += len(batch.obs)
        state.robot_seconds += sum(p.robot_seconds for p in paths)
        state.pause_seconds += sum(p.pause_seconds for p in paths)
        row: dict[str, Any] = {ex.ITERATION: k}
        row.update(path_metrics(paths, config.success))
        row.update({ex.SAMPLES: state.samples, ex.ROBOT_HOURS: state.robot_seconds / 3600})
        final = k == last or (until is not None and until(dict(row)))
        evaluate = final or (config.eval_every > 0 and (k + 1) % config.eval_every == 0)
        row.update({ex.EVAL_SUCCESS_RATE: math.nan, ex.EVAL_RETURN_MEAN: math.nan})
        if evaluate:
            jobs = make_jobs(config.seed, EVAL_STREAM, k, config.eval_episodes, deterministic=True)
            eval_paths = sampler.sample(state.policy.snapshot(), jobs)
            state.robot_seconds += sum(p.robot_seconds for p in eval_paths)
            state.pause_seconds += sum(p.pause_seconds for p in eval_paths)
            row.update(path_metrics(eval_paths, config.success, prefix="eval_"))
            latest = eval_paths[-1]
        else:
            latest = paths[-1]
        if latest.telemetry:  # robot backends: the robot's cumulative counters
            row.update({f"robot_{k}": latest.telemetry.get(k, math.nan) for k in ROBOT_COUNTERS})
        row.update(
            {
                ex.SAMPLES: state.samples,
                ex.ROBOT_HOURS: state.robot_seconds / 3600,
                "thermal_pause_hours": state.pause_seconds / 3600,
                "policy_std_mean": float(torch.exp(state.policy.log_std.detach()).mean()),
                **stats,
                "time_sampling": t1 - t0,
                "time_update": t2 - t1,
                "time_eval": time.perf_counter() - t2,
            }
        )
        run.log(row)
        if final or (k + 1) % config.checkpoint_every == 0 or k == stop_after:
            run.save_checkpoint(k, state.to_checkpoint(k))
        bar.update(1)
        bar.set_postfix(
            samples=state.samples, success=f"{row[ex.SUCCESS_RATE]:.2f}",
            robot_h=f"{state.robot_seconds / 3600:.2f}", pause_h=f"{state.pause_seconds / 3600:.2f}",
        )  # fmt: skip
        if final or k == stop_after:
            break
    bar.close()
    run.plot_learning_curves(f"{config.algo.upper()} on {config.env_id} (seed {config.seed})")
    ex.save_state(run.path / "policy.pt", {"policy": state.policy.to_checkpoint()})


def load_policy(path: str | Path) -> GaussianMLPPolicy:
    """Load the policy of a run directory (``policy.pt``) or of a checkpoint file."""
    path = Path(path)
    file = path / "policy.pt" if path.is_dir() else path
    return GaussianMLPPolicy.from_checkpoint(ex.load_state(file)["policy"])


# ----------------------------------------------------------------------------------------------
# CLI: `lowcostdex train npg|dapg ...`


def add_train_commands(train_subparsers: argparse._SubParsersAction) -> None:
    """Add ``npg`` and ``dapg`` to the ``lowcostdex train`` group."""
    for algo, help_text in (
        ("npg", "natural policy gradient (truncated NPG)"),
        ("dapg", "demo-augmented policy gradient (BC, then NPG with a decaying demo term)"),
    ):
        p = train_subparsers.add_parser(algo, help=help_text, description=help_text)
        _add_arguments(p, algo)
        p.set_defaults(func=_run_command, algo=algo)


def _add_arguments(p: argparse.ArgumentParser, algo: str) -> None:
    d = TrainConfig()
    p.add_argument("--env", default=d.env_id, help="gymnasium id (default %(default)s)")
    p.add_argument("--backend", choices=BACKENDS, default=d.backend)
    p.add_argument("--port", default=None, help="serial port of a real robot (hardware backend)")
    p.add_argument(
        "--demos", default=None, required=algo == "dapg",
        help="demonstration dataset (HDF5, lowcostdex.demo_file); its successful episodes are used",
    )
    p.add_argument("--n-demos", type=int, default=None, help="use the first N demo episodes")
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its last checkpoint"
    )
    p.add_argument("--n-iter", type=int, default=d.n_iter)
    p.add_argument("--n-traj", type=int, default=d.n_traj, help="trajectories per iteration")
    p.add_argument("--sampler", choices=SAMPLERS, default=d.sampler)
    p.add_argument("--workers", type=int, default=d.n_workers)
    p.add_argument(
        "--step-size", type=float, default=d.npg.step_size, help="NPG delta (KL ~ delta/2)"
    )
    p.add_argument("--damping", type=float, default=d.npg.damping, help="Fisher damping")
    p.add_argument("--gamma", type=float, default=d.gamma)
    p.add_argument("--gae-lambda", type=float, default=d.gae_lambda)
    p.add_argument("--hidden", type=int, nargs="*", default=list(d.policy.hidden_sizes))
    p.add_argument("--init-log-std", type=float, default=d.policy.init_log_std)
    p.add_argument("--eval-every", type=int, default=d.eval_every)
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes)
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="extra gym.make argument (VALUE parsed as JSON when possible)")  # fmt: skip
    p.add_argument("--no-progress", action="store_true")
    if algo == "dapg":
        p.add_argument("--lam0", type=float, default=d.dapg.lam0)
        p.add_argument("--lam1", type=float, default=d.dapg.lam1)
        p.add_argument("--demo-weight", choices=("paper", "mjrl"), default=d.dapg.demo_weight)
        p.add_argument("--bc-epochs", type=int, default=d.bc.epochs)
        p.add_argument("--bc-log-std", choices=BC_LOG_STD, default=d.bc.log_std,
                       help="initial exploration noise after BC")  # fmt: skip
    else:
        p.add_argument(
            "--bc-init", action="store_true", help="behaviour-clone the demos first (BCRL)"
        )


def _parse_env_kwargs(items: Sequence[str]) -> dict[str, Any]:
    import json

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError(f"--env-kwarg {item!r} must be KEY=VALUE")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """Build a TrainConfig from parsed ``lowcostdex train npg|dapg`` arguments."""
    d = TrainConfig()
    env_kwargs = _parse_env_kwargs(args.env_kwarg)
    if args.port:
        env_kwargs["port"] = args.port
    return TrainConfig(
        algo=args.algo,
        env_id=args.env,
        backend=args.backend,
        env_kwargs=env_kwargs,
        seed=args.seed,
        n_iter=args.n_iter,
        n_traj=args.n_traj,
        gamma=args.gamma,
        gae_lambda=args.gae_lambda,
        sampler=args.sampler,
        n_workers=args.workers,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        demos=str(Path(args.demos).resolve()) if args.demos else None,
        n_demos=args.n_demos,
        bc_init=bool(getattr(args, "bc_init", False)),
        policy=dataclasses.replace(
            d.policy, hidden_sizes=tuple(args.hidden), init_log_std=args.init_log_std
        ),
        npg=dataclasses.replace(d.npg, step_size=args.step_size, damping=args.damping),
        dapg=DAPGConfig(lam0=args.lam0, lam1=args.lam1, demo_weight=args.demo_weight)
        if args.algo == "dapg"
        else d.dapg,
        bc=dataclasses.replace(d.bc, epochs=args.bc_epochs, log_std=args.bc_log_std)
        if args.algo == "dapg"
        else d.bc,
        progress=not args.no_progress,
    )


def _run_command(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    run = train(config, args.out, resume=args.resume)
    metrics = run.read_metrics()
    print(f"run: {run.path}")
    print(f"curves: {run.path / ex.CURVES_FILE}")
    if metrics.get(ex.EVAL_SUCCESS_RATE, np.array([])).size:
        print(f"final eval success rate: {metrics[ex.EVAL_SUCCESS_RATE][-1]:.2f}")
    return 0
