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

The run's configuration is :class:`~lowcostdex.algos.configs.TrainConfig`; the command line
``lowcostdex train npg|dapg`` is :mod:`lowcostdex.algos.train_cli`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.baseline import MLPBaseline
from lowcostdex.algos.bc import behavior_clone
from lowcostdex.algos.configs import TrainConfig
from lowcostdex.algos.dapg import dapg_update
from lowcostdex.algos.npg import npg_update
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.algos.policy_files import load_policy  # noqa: F401  (long imported from here)
from lowcostdex.algos.returns import discounted_returns, gae
from lowcostdex.algos.samplers import (
    BC_EVAL_STREAM,
    EVAL_STREAM,
    TRAIN_STREAM,
    EnvFactory,
    EnvFactoryFn,
    ProcessSampler,
    RaySampler,
    RolloutJob,
    Sampler,
    SerialSampler,
    Trajectory,
    VectorSampler,
    make_jobs,
)
from lowcostdex.demonstrations.dataset import Demos, check_demos, load_demos
from lowcostdex.errors import ConfigError, LowcostdexError, check_bool, did_you_mean

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
    "person_resets",
)
"""Robot telemetry logged every iteration on emulated/hardware backends (as ``robot_<key>``);
cumulative over the process's lifetime (they restart after a resume)."""
MUTABLE_ON_RESUME = ("n_iter", "progress", "torch_threads")
"""Config keys a resumed run may change."""

# Seed-sequence purposes (first spawn-key entry); trajectories use samplers.*_STREAM (0, 1).
_POLICY_INIT, _BASELINE_INIT, _BC, _UPDATE, _BASELINE_FIT = 10, 11, 12, 13, 14


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


def _backend_kwargs(config: TrainConfig) -> dict[str, Any]:
    # "sim" is every env's own default: a gymnasium env without a backend (Pendulum-v1) gets
    # none (before: TypeError "unexpected keyword argument 'backend'" from gym.make)
    return {} if config.backend == "sim" else {"backend": config.backend}


def default_env_factory(config: TrainConfig) -> EnvFactory:
    return EnvFactory(config.env_id, {**_backend_kwargs(config), **config.env_kwargs})


def evaluation_env_factory(config: TrainConfig) -> EnvFactory | None:
    """The evaluations' own env (``config.eval_env_kwargs``), or None: the training env's."""
    if config.eval_env_kwargs is None:
        return None
    return EnvFactory(config.env_id, {**_backend_kwargs(config), **config.eval_env_kwargs})


# ----------------------------------------------------------------------------------------------
# The training loop


@dataclass
class _State:
    policy: GaussianMLPPolicy
    baseline: MLPBaseline
    samples: int = 0
    eval_samples: int = 0
    robot_seconds: float = 0.0
    pause_seconds: float = 0.0
    wall_seconds: float = 0.0
    best: ex.BestPolicy | None = None

    def to_checkpoint(self, iteration: int) -> dict[str, Any]:
        return {
            "iteration": iteration,
            "policy": self.policy.to_checkpoint(),
            "baseline": self.baseline.to_checkpoint(),
            "counters": {
                "samples": self.samples,
                "eval_samples": self.eval_samples,
                "robot_seconds": self.robot_seconds,
                "pause_seconds": self.pause_seconds,
                "wall_seconds": self.wall_seconds,
            },
            "best": self.best.state() if self.best is not None else {},
            # All draws after this point derive from the seed and the iteration index, so no
            # generator state is carried; the torch default generator is recorded for audit.
            "torch_rng": torch.get_rng_state(),
        }


def _init_state(config: TrainConfig, probe: Any, demos: Demos | None
                ) -> tuple[_State, dict[str, Any] | None]:
    """A fresh policy and baseline; with demos the policy is behaviour-cloned first and its
    statistics (``bc.json``) returned with it."""
    obs_dim = int(np.prod(probe.observation_space.shape))
    act_dim = int(np.prod(probe.action_space.shape))
    horizon = probe.spec.max_episode_steps if probe.spec and probe.spec.max_episode_steps else 1000
    # a clone's network and minibatch order come from its own seed (``bc_seed``)
    clone_seed = config.seed if demos is None or config.bc_seed is None else config.bc_seed
    policy = GaussianMLPPolicy(
        obs_dim, act_dim, config.policy, seed_generator(clone_seed, _POLICY_INIT)
    )
    # saved with it (load_policy(path, env=...) checks it); an env_factory's env without a
    # gymnasium spec leaves it unknown rather than naming config.env_id, which it did not make
    policy.trained_on = getattr(getattr(probe, "spec", None), "id", None)
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
            policy, demos.observations, demos.actions, config.bc, seed_generator(clone_seed, _BC)
        )
        bc = {**stats, "n_episodes": demos.n_episodes, "n_pairs": len(demos.actions)}
        return _State(policy, baseline), bc
    return _State(policy, baseline), None


def clone_policy(config: TrainConfig, env: Any, demos: Demos) -> tuple[GaussianMLPPolicy,
                                                                         dict[str, Any]]:
    """The behaviour clone a run with ``config`` starts from (seed ``config.bc_seed``, else
    ``config.seed``) and its statistics, fitted to ``demos`` for ``env``'s spaces; the run
    itself fits the same clone."""
    state, bc = _init_state(config, env, demos)
    assert bc is not None
    return state.policy, bc


def evaluation_jobs(config: TrainConfig, k: int, clone: bool = False) -> list[RolloutJob]:
    """The deterministic episodes of the evaluation after iteration ``k`` (the behaviour
    clone's before iteration 0 with ``clone``): with ``config.eval_paired`` always those of
    (EVAL_STREAM, 0); otherwise (EVAL_STREAM, k), the clone's (BC_EVAL_STREAM, 0)."""
    if config.eval_paired:
        stream, k = EVAL_STREAM, 0
    else:
        stream, k = (BC_EVAL_STREAM, 0) if clone else (EVAL_STREAM, k)
    return make_jobs(config.seed, stream, k, config.eval_episodes, deterministic=True)


def _evaluate(
    config: TrainConfig, sampler: Sampler, state: _State, k: int, clone: bool = False
) -> tuple[list[Trajectory], dict[str, float]]:
    """``eval_episodes`` deterministic episodes of the current policy (:func:`evaluation_jobs`);
    their robot time counts. Returns the paths and the ``eval_`` metrics."""
    jobs = evaluation_jobs(config, k, clone)
    paths = sampler.sample(state.policy.snapshot(), jobs)
    state.eval_samples += sum(len(p.rewards) for p in paths)
    state.robot_seconds += sum(p.robot_seconds for p in paths)
    state.pause_seconds += sum(p.pause_seconds for p in paths)
    return paths, path_metrics(paths, config.success, prefix="eval_")


def _restore(state: _State, ckpt: ex.Checkpoint) -> None:
    state.policy.load_state_dict(ckpt.state["policy"]["state_dict"])
    state.baseline.load_checkpoint(ckpt.state["baseline"])
    counters = ckpt.state["counters"]
    state.samples = int(counters["samples"])
    state.eval_samples = int(counters.get("eval_samples", 0))
    state.robot_seconds = float(counters["robot_seconds"])
    state.pause_seconds = float(counters["pause_seconds"])
    state.wall_seconds = float(counters.get("wall_seconds", 0.0))
    if state.best is not None:
        state.best.load_state(ckpt.state.get("best"))


class TrainingDiverged(LowcostdexError):
    """An update produced non-finite policy parameters (the run stops; nothing is overwritten)."""


def _update(
    config: TrainConfig, state: _State, batch: Batch, demos: Demos | None, k: int
) -> dict[str, float]:
    gen = seed_generator(config.seed, _UPDATE, k)
    before = torch.nn.utils.parameters_to_vector(state.policy.parameters()).detach().clone()
    stats = _step(config, state, batch, demos, k, gen)
    after = torch.nn.utils.parameters_to_vector(state.policy.parameters())
    if not bool(torch.isfinite(after).all()):
        torch.nn.utils.vector_to_parameters(before, state.policy.parameters())
        raise TrainingDiverged(
            f"iteration {k}: the {config.algo} update produced non-finite policy parameters "
            f"(step size {config.npg.step_size}, damping {config.npg.damping}); the policy "
            "was restored and the run stopped; its checkpoints up to the previous iteration are "
            "kept. Start a new run with a smaller --step-size or a larger --damping.")
    return stats


def _step(config: TrainConfig, state: _State, batch: Batch, demos: Demos | None, k: int,
          gen: torch.Generator) -> dict[str, float]:
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


EVAL_SAMPLES = "eval_samples"
"""Metrics column: env steps of the evaluation episodes so far (not in ``samples``, which counts
the training episodes' steps only; on a robot both cost robot time)."""


def _time_postfix(config: TrainConfig, state: _State) -> dict[str, str]:
    """The progress bar's time fields: robot hours and thermal-pause hours on a robot backend;
    simulated hours (episode time, no robot involved) in simulation."""
    if config.backend == "sim":
        return {"sim_h": f"{state.robot_seconds / 3600:.2f}"}
    return {"robot_h": f"{state.robot_seconds / 3600:.2f}",
            "pause_h": f"{state.pause_seconds / 3600:.2f}"}


def _progress(config: TrainConfig, start: int) -> Any:
    from lowcostdex.progress import bar

    return bar(total=config.n_iter, initial=start, disable=not config.progress,
               desc=f"{config.algo} {config.env_id}", unit="it")


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
    if not isinstance(config, TrainConfig):  # asdict() raised a TypeError about dataclasses
        raise ConfigError(f"train() takes a TrainConfig, not {type(config).__name__}: "
                          "TrainConfig(algo='npg', ...), or TrainConfig.from_dict(d) for a dict "
                          "(a JSON config)")
    check_bool("resume", resume)  # "no" is truthy: resume="no" resumed a run
    ex.Run.check(out_dir, dataclasses.asdict(config), resume=resume,
                 mutable_keys=MUTABLE_ON_RESUME)
    if env_factory is None:
        check_env_id(config.env_id)
        if config.backend != "sim" and not config.env_id.startswith("lowcostdex/"):
            raise ConfigError(f"backend {config.backend!r} drives a lowcostdex robot; "
                              f"{config.env_id} is not a lowcostdex env (lowcostdex/...): "
                              "train it with backend 'sim'")
        env_factory = default_env_factory(config)
    demos = load_demos(config.demos).first(config.n_demos) if config.uses_demos else None
    run: ex.Run | None = None
    probe: SerialSampler | None = None
    sampler: Sampler | None = None
    evaluator: Sampler | None = None  # the evaluations' own env (``eval_env_kwargs``)
    threads = torch.get_num_threads()
    try:
        # everything is validated before the run directory is written
        probe = SerialSampler(env_factory) if config.sampler != "serial" else None
        sampler = make_sampler(config, env_factory)
        eval_factory = evaluation_env_factory(config)
        if eval_factory is not None:
            evaluator = SerialSampler(eval_factory)
        env = probe.env if probe is not None else sampler.env  # type: ignore[attr-defined]
        check_env_spaces(env, config)
        if demos is not None:
            check_demos(demos, config.demos, env, config.env_id)  # type: ignore[arg-type]
        run = ex.Run.open(
            out_dir, dataclasses.asdict(config), resume=resume, mutable_keys=MUTABLE_ON_RESUME
        )
        torch.set_num_threads(config.torch_threads)
        ckpt = run.load_latest(required=("policy", "baseline", "counters")) if resume else None
        state, bc = _init_state(config, env, demos if ckpt is None else None)
        state.best = ex.BestPolicy(run)
        if probe is not None:
            probe.close()
            probe = None
        if bc is not None:
            clone = {"policy": state.policy.to_checkpoint()}
            ex.save_state(run.path / ex.BC_POLICY_FILE, clone)
            if config.eval_bc:  # the clone alone, before any RL sample
                paths, metrics = _evaluate(config, evaluator or sampler, state, 0, clone=True)
                bc.update(metrics, eval_episodes=len(paths))
                errors = [p.final_goal_error for p in paths]
                if all(np.isfinite(errors)):  # per episode, for a test against a baseline
                    bc["eval_final_goal_errors"] = errors
                # the clone competes for the run's policy (iteration -1, 0 samples): RL's
                # policy replaces it only by beating it in these evaluations
                state.best.consider(-1, {**metrics, ex.SAMPLES: 0}, clone)
            run.write_json("bc.json", bc)
        start = 0
        if ckpt is not None:
            _restore(state, ckpt)
            start = ckpt.iteration + 1
        _loop(config, run, sampler, state, demos, start, stop_after, until, evaluator)
    except BaseException as exc:
        stopped = ex.stopped(run, exc, resume)
        if stopped is exc:
            raise
        raise stopped from None
    finally:
        torch.set_num_threads(threads)
        for s in (probe, sampler, evaluator):
            if s is not None:
                s.close()
        if run is not None:
            run.close()
    return run


def check_env_id(env_id: str) -> None:
    """Raise ConfigError unless ``env_id`` is a registered gymnasium id (after importing
    :mod:`lowcostdex.sim`, which registers the ``lowcostdex/...`` ids); lists those."""
    import gymnasium as gym

    import lowcostdex.sim  # noqa: F401  (registers the lowcostdex/... ids)

    if env_id not in gym.registry:
        ours = sorted(k for k in gym.registry if k.startswith("lowcostdex/"))
        hint = did_you_mean(env_id, ours) or did_you_mean(f"lowcostdex/{env_id}", ours)
        raise ConfigError(f"unknown env {env_id!r}; lowcostdex envs: {', '.join(ours)}{hint}")


def check_env_spaces(env: Any, config: TrainConfig) -> None:
    """Raise ConfigError unless ``env`` has the Box observations and actions the Gaussian
    policy needs (before: an AssertionError from inside the first rollout, CartPole-v1)."""
    import gymnasium as gym

    for what, space in (("actions", env.action_space), ("observations", env.observation_space)):
        if not isinstance(space, gym.spaces.Box):
            raise ConfigError(f"{config.algo} trains envs with continuous {what} (a Box space); "
                              f"{config.env_id} has {space}")


def _loop(
    config: TrainConfig,
    run: ex.Run,
    sampler: Sampler,
    state: _State,
    demos: Demos | None,
    start: int,
    stop_after: int | None,
    until: Callable[[Mapping[str, float]], bool] | None,
    evaluator: Sampler | None = None,
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
        evaluate = (final or (config.eval_every > 0 and (k + 1) % config.eval_every == 0)
                    or (config.eval_dense_from is not None and k >= config.eval_dense_from))
        row.update({ex.EVAL_SUCCESS_RATE: math.nan, ex.EVAL_RETURN_MEAN: math.nan})
        if evaluate:
            eval_paths, metrics = _evaluate(config, evaluator or sampler, state, k)
            row.update(metrics)
            latest = eval_paths[-1]
            state.best.consider(k, {**row, ex.SAMPLES: state.samples},
                                {"policy": state.policy.to_checkpoint()})
        else:
            latest = paths[-1]
        if latest.telemetry:  # robot backends: the robot's cumulative counters
            row.update({f"robot_{k}": latest.telemetry.get(k, math.nan) for k in ROBOT_COUNTERS})
        state.wall_seconds += time.perf_counter() - t0
        row.update(
            {
                ex.SAMPLES: state.samples,
                EVAL_SAMPLES: state.eval_samples,
                ex.ROBOT_HOURS: state.robot_seconds / 3600,
                "thermal_pause_hours": state.pause_seconds / 3600,
                "policy_std_mean": float(torch.exp(state.policy.log_std.detach()).mean()),
                **stats,
                "time_sampling": t1 - t0,
                "time_update": t2 - t1,
                "time_eval": time.perf_counter() - t2,
                ex.WALL_SECONDS: state.wall_seconds,
            }
        )
        run.log(row)
        if final or (k + 1) % config.checkpoint_every == 0 or k == stop_after:
            run.save_checkpoint(k, state.to_checkpoint(k))
        else:  # saved if Ctrl-C comes before the next checkpoint
            run.keep_for_interrupt(k, state.to_checkpoint(k))
        bar.update(1)
        bar.set_postfix(
            samples=state.samples, success=f"{row[ex.SUCCESS_RATE]:.2f}",
            **_time_postfix(config, state),
        )  # fmt: skip
        if final or k == stop_after:
            break
    bar.close()
    run.plot_learning_curves(f"{config.algo.upper()} on {config.env_id} (seed {config.seed})")
    state.best.finish({"policy": state.policy.to_checkpoint()})
    run.write_json(ex.SUMMARY_FILE, ex.run_summary(run.read_metrics(), state.best.record,
                                                   wall_seconds=state.wall_seconds))
