"""Trajectory samplers: serial, a persistent process pool, a batched vector env, and Ray.

Reproducibility contract: a trajectory depends only on (seed, stream, iteration, index) and the
policy, never on which worker ran it or how many workers there are. Each trajectory gets its
own env reset seed and its own action-noise generator, both derived with
``np.random.SeedSequence(seed, spawn_key=(stream, iteration, index, k))``, and actions are
computed one observation at a time by :class:`~lowcostdex.algos.policy.PolicySnapshot`. (mjrl
instead seeds per worker, so its results change with the worker count.) This assumes the env is
deterministic given its reset seed, which every lowcostdex sim env is; on the emulated and real
robots, sampling is serial on one robot at its control rate.

Samplers take an ``env_factory``: a picklable zero-argument callable returning a gymnasium env
(:class:`EnvFactory` for registered ids). Workers build their env once and keep it across
iterations.
"""

from __future__ import annotations

import abc
import multiprocessing as mp
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from lowcostdex.algos.snapshot import PolicySnapshot
from lowcostdex.errors import ConfigError, LowcostdexError, check_choice
from lowcostdex.sim.envs.hand_env import control_period

TRAIN_STREAM = 0
"""Seed stream of training trajectories."""
EVAL_STREAM = 1
"""Seed stream of evaluation trajectories (disjoint from training)."""
BC_EVAL_STREAM = 2
"""Seed stream of the behaviour clone's evaluation before RL."""
HELDOUT_STREAM = 3
"""Seed stream of held-out evaluation episodes: disjoint from training (0) and from the
evaluations that choose a run's best policy (1, 2), so a comparison of policies on them is not
biased by that choice (the main job compares the clone, DAPG, NPG and random actions on the
same held-out episodes)."""
SAMPLERS = ("serial", "process", "vector", "ray")

EnvFactoryFn = Callable[[], gym.Env]
"""Picklable zero-argument callable that builds one environment."""


@dataclass(frozen=True)
class EnvFactory:
    """Builds ``gym.make(env_id, **kwargs)`` after importing lowcostdex (which registers ids)."""

    env_id: str
    kwargs: Mapping[str, Any] = field(default_factory=dict)

    def __call__(self) -> gym.Env:
        import lowcostdex.sim  # noqa: F401  (registers the lowcostdex/... ids)

        return gym.make(self.env_id, **dict(self.kwargs))


# ----------------------------------------------------------------------------------------------
# One trajectory


@dataclass(frozen=True)
class RolloutJob:
    """Which trajectory to sample: ``index`` within (``seed``, ``stream``, ``iteration``)."""

    seed: int
    stream: int
    iteration: int
    index: int
    deterministic: bool = False

    def seed_sequence(self, k: int) -> np.random.SeedSequence:
        """Sub-stream k: 0 = env reset seed, 1 = action noise."""
        return np.random.SeedSequence(
            self.seed, spawn_key=(self.stream, self.iteration, self.index, k)
        )

    def env_seed(self) -> int:
        return int(self.seed_sequence(0).generate_state(1, np.uint32)[0])

    def noise_rng(self) -> np.random.Generator:
        return np.random.default_rng(self.seed_sequence(1))


def make_jobs(
    seed: int, stream: int, iteration: int, n: int, deterministic: bool = False
) -> list[RolloutJob]:
    """Jobs for trajectories 0..n-1 of one iteration."""
    return [RolloutJob(seed, stream, iteration, i, deterministic) for i in range(n)]


@dataclass
class Trajectory:
    """One episode.

    Attributes:
      observations: (T, obs_dim) s_0..s_{T-1}.
      actions: (T, act_dim) actions as sampled (before clipping to the action space).
      rewards: (T,) rewards.
      successes: (T,) ``info["success"]`` after each step (False where absent).
      final_observation: (obs_dim,) s_T, for bootstrapping a truncated episode.
      terminated: the episode reached a terminal state (value 0 after it).
      truncated: the episode was cut by the time limit (bootstrap with V(s_T)).
      index: the job index (trajectory index within its iteration).
      reward_terms: per-term sums over the episode of ``info["reward_<term>"]``.
      robot_seconds: robot wall-clock time of the episode [s]: T * control period, plus on a
        robot backend the auto-reset before it (``info["telemetry"]["last_reset_time"]`` at
        reset, which includes any thermal pause).
      pause_seconds: thermal-pause time before the episode [s] (set by the serial sampler from
        the robot's cumulative ``pause_time``; 0 in simulation).
      telemetry: scalar robot telemetry after the last step (cumulative counters such as
        ``resets``, ``pause_time``, ``overloads``, ``max_temperature``); empty in simulation.
      final_goal_error: ``|info["goal_error"]|`` after the last step (NaN if the env does not
        report one), e.g. the valve's angle error [rad].
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    successes: np.ndarray
    final_observation: np.ndarray
    terminated: bool
    truncated: bool
    index: int
    reward_terms: dict[str, float]
    robot_seconds: float
    pause_seconds: float = 0.0
    final_goal_error: float = float("nan")
    telemetry: dict[str, float] = field(default_factory=dict)
    pause_total: float | None = None

    def __len__(self) -> int:
        return int(self.rewards.shape[0])

    @property
    def total_reward(self) -> float:
        return float(self.rewards.sum())


def rollout(
    env: gym.Env, policy: PolicySnapshot, job: RolloutJob, max_steps: int | None = None
) -> Trajectory:
    """Run one episode of ``policy`` in ``env`` for ``job``.

    The env is reset with ``job.env_seed()``; stochastic actions use ``job.noise_rng()``;
    actions are clipped to a Box action space before stepping. The episode ends when the env
    terminates or truncates (TimeLimit), or after ``max_steps`` (counted as truncation).
    """
    obs, info = env.reset(seed=job.env_seed())
    rng = None if job.deterministic else job.noise_rng()
    space = env.action_space
    low, high = (space.low, space.high) if isinstance(space, gym.spaces.Box) else (None, None)
    reset_tel = info.get("telemetry") or {}
    reset_seconds = float(reset_tel.get("last_reset_time", 0.0))
    pause_total = float(reset_tel["pause_time"]) if "pause_time" in reset_tel else None
    observations, actions, rewards, successes = [], [], [], []
    terms: dict[str, float] = {}
    terminated = truncated = False
    while not (terminated or truncated):
        noise = None if rng is None else rng.standard_normal(policy.act_dim)
        action = policy.act(obs, noise)
        observations.append(np.asarray(obs, dtype=np.float64))
        actions.append(action)
        env_action = action if low is None else np.clip(action, low, high)
        obs, reward, terminated, truncated, info = env.step(env_action.astype(space.dtype))
        rewards.append(float(reward))
        successes.append(bool(info.get("success", False)))
        for key, value in info.items():
            if key.startswith("reward_") and np.isscalar(value):
                terms[key] = terms.get(key, 0.0) + float(value)
        if max_steps is not None and len(rewards) >= max_steps:
            truncated = truncated or not terminated
    n = len(rewards)
    return Trajectory(
        observations=np.asarray(observations).reshape(n, -1),
        actions=np.asarray(actions).reshape(n, -1),
        rewards=np.asarray(rewards),
        successes=np.asarray(successes, dtype=bool),
        final_observation=np.asarray(obs, dtype=np.float64),
        terminated=bool(terminated),
        truncated=bool(truncated and not terminated),
        index=job.index,
        reward_terms=terms,
        robot_seconds=n * control_period(env) + reset_seconds,
        final_goal_error=abs(float(info.get("goal_error", np.nan))) if n else float("nan"),
        telemetry=_scalars(info.get("telemetry") or {}),
        pause_total=pause_total,
    )


def _scalars(telemetry: Mapping[str, Any]) -> dict[str, float]:
    out = {}
    for key, value in telemetry.items():
        if isinstance(value, (bool, int, float, np.bool_, np.integer, np.floating)):
            out[key] = float(value)
    return out


# ----------------------------------------------------------------------------------------------
# Samplers


class Sampler(abc.ABC):
    """Runs rollout jobs; results are ordered by job index. Use as a context manager."""

    @abc.abstractmethod
    def sample(self, policy: PolicySnapshot, jobs: Sequence[RolloutJob]) -> list[Trajectory]:
        """Sample one trajectory per job, returned in the order of ``jobs``."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release envs and workers."""

    def __enter__(self) -> Sampler:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SerialSampler(Sampler):
    """One env in this process; also the sampler for the emulated and real robots.

    On a robot it turns the robot's cumulative thermal-pause time into the pause before each
    episode (``Trajectory.pause_seconds``).
    """

    def __init__(self, env_factory: EnvFactoryFn, max_steps: int | None = None):
        self.env_factory, self.max_steps = env_factory, max_steps
        self._env: gym.Env | None = None
        self._pause_seen = 0.0

    @property
    def env(self) -> gym.Env:
        if self._env is None:
            self._env = self.env_factory()
        return self._env

    def sample(self, policy: PolicySnapshot, jobs: Sequence[RolloutJob]) -> list[Trajectory]:
        paths = []
        for job in jobs:
            path = rollout(self.env, policy, job, self.max_steps)
            if path.pause_total is not None:
                path.pause_seconds = max(path.pause_total - self._pause_seen, 0.0)
                self._pause_seen = path.pause_total
            paths.append(path)
        return paths

    def close(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None


def _split(jobs: Sequence[RolloutJob], n: int) -> list[list[RolloutJob]]:
    """Contiguous chunks of nearly equal size (some may be empty)."""
    bounds = np.linspace(0, len(jobs), n + 1).round().astype(int)
    return [list(jobs[bounds[i] : bounds[i + 1]]) for i in range(n)]


def _worker_main(conn: Any, env_factory: EnvFactoryFn, max_steps: int | None) -> None:
    """Worker loop: build the env once, then answer ("sample", policy, jobs) until "close"."""
    env = None
    try:
        while True:
            message = conn.recv()
            if message[0] == "close":
                break
            _, policy, jobs = message
            try:
                if env is None:
                    env = env_factory()
                conn.send(("ok", [rollout(env, policy, job, max_steps) for job in jobs]))
            except Exception:  # reported to the parent, which raises
                conn.send(("error", traceback.format_exc()))
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        if env is not None:
            env.close()
        conn.close()


class SamplerError(LowcostdexError, RuntimeError):
    """A sampling worker failed; the message carries its traceback."""


class ProcessSampler(Sampler):
    """A pool of worker processes that live across iterations, each with its own env.

    Args:
      env_factory: picklable env builder (run once in each worker).
      n_workers: number of processes (>= 1).
      max_steps: optional cap on episode length.
      start_method: multiprocessing start method; "spawn" (default) is safe with torch and
        MuJoCo threads; "forkserver" and "fork" start faster.
    """

    def __init__(
        self,
        env_factory: EnvFactoryFn,
        n_workers: int,
        max_steps: int | None = None,
        start_method: str = "spawn",
    ):
        if n_workers < 1:
            raise ConfigError(f"n_workers={n_workers} must be >= 1")
        check_choice("start method", start_method, mp.get_all_start_methods())
        ctx = mp.get_context(start_method)
        self._conns, self._procs = [], []
        for _ in range(n_workers):
            parent, child = ctx.Pipe()
            proc = ctx.Process(
                target=_worker_main, args=(child, env_factory, max_steps), daemon=True
            )
            proc.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(proc)

    @property
    def n_workers(self) -> int:
        return len(self._procs)

    def sample(self, policy: PolicySnapshot, jobs: Sequence[RolloutJob]) -> list[Trajectory]:
        chunks = _split(list(jobs), self.n_workers)
        busy = []
        for conn, chunk in zip(self._conns, chunks, strict=True):
            if chunk:
                conn.send(("sample", policy, chunk))
                busy.append(conn)
        out: list[Trajectory] = []
        errors = []
        for conn in busy:
            try:
                status, payload = conn.recv()
            except EOFError:
                status, payload = "error", "worker process died"
            if status == "ok":
                out.extend(payload)
            else:
                errors.append(payload)
        if errors:
            raise SamplerError("sampling worker failed:\n" + "\n".join(errors))
        return out

    def close(self) -> None:
        for conn in self._conns:
            try:
                conn.send(("close",))
            except (BrokenPipeError, OSError):
                pass
        for proc in self._procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.terminate()
                proc.join()
        for conn in self._conns:
            conn.close()
        self._conns, self._procs = [], []


class VectorSampler(Sampler):
    """Steps ``num_envs`` copies of a lowcostdex sim task at once (``lowcostdex.sim.vector``).

    Jobs run in consecutive groups of ``num_envs``; copy i of a group is reset with the job's
    own seed and uses the job's own noise generator, and the policy is evaluated row by row,
    so trajectories equal the serial sampler's whatever ``num_envs`` is. Rows whose episode
    ended are ignored until the whole group has ended (the vector env's auto-reset steps are
    never recorded).

    Args:
      env_id: a registered ``lowcostdex/...`` id.
      num_envs: copies stepped together.
      env_kwargs: ``gym.make`` keyword arguments (sim backend only).
      nthread: ``mujoco.batch`` threads (0: all CPUs).
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        env_kwargs: Mapping[str, Any] | None = None,
        nthread: int = 0,
    ):
        from lowcostdex.sim.vector import make_vec

        if num_envs < 1:
            raise ConfigError(f"num_envs={num_envs} must be >= 1")
        self.env = make_vec(env_id, num_envs, nthread=nthread, **dict(env_kwargs or {}))
        self.num_envs = num_envs
        self.period = float(self.env._template.control_period)

    def sample(self, policy: PolicySnapshot, jobs: Sequence[RolloutJob]) -> list[Trajectory]:
        out: list[Trajectory] = []
        for start in range(0, len(jobs), self.num_envs):
            out.extend(self._group(policy, list(jobs[start : start + self.num_envs])))
        return out

    def _group(self, policy: PolicySnapshot, jobs: list[RolloutJob]) -> list[Trajectory]:
        n, m = len(jobs), self.num_envs
        seeds = [job.env_seed() for job in jobs] + [0] * (m - n)  # idle rows: any seed
        obs, _ = self.env.reset(seed=seeds)
        rngs = [None if job.deterministic else job.noise_rng() for job in jobs]
        act_dim = policy.act_dim
        live = np.ones(n, dtype=bool)
        rec: list[dict[str, Any]] = [
            {
                "obs": [],
                "act": [],
                "rew": [],
                "succ": [],
                "terms": {},
                "term": False,
                "trunc": False,
            }
            for _ in range(n)
        ]
        while live.any():
            actions = np.zeros((m, act_dim))
            for i in np.flatnonzero(live):
                noise = None if rngs[i] is None else rngs[i].standard_normal(act_dim)
                actions[i] = policy.act(obs[i], noise)
                rec[i]["obs"].append(np.asarray(obs[i], dtype=np.float64))
                rec[i]["act"].append(actions[i].copy())
            obs, reward, terminated, truncated, info = self.env.step(np.clip(actions, -1.0, 1.0))
            for i in np.flatnonzero(live):
                r = rec[i]
                r["rew"].append(float(reward[i]))
                r["succ"].append(bool(info["success"][i]))
                for key, value in info.items():
                    if key.startswith("reward_"):
                        r["terms"][key] = r["terms"].get(key, 0.0) + float(value[i])
                if terminated[i] or truncated[i]:
                    r.update(
                        term=bool(terminated[i]), trunc=bool(truncated[i] and not terminated[i])
                    )
                    r["final"] = np.asarray(obs[i], dtype=np.float64)
                    r["goal_error"] = (
                        abs(float(info["goal_error"][i])) if "goal_error" in info else np.nan
                    )
                    live[i] = False
        return [
            Trajectory(
                observations=np.asarray(r["obs"]),
                actions=np.asarray(r["act"]),
                rewards=np.asarray(r["rew"]),
                successes=np.asarray(r["succ"], dtype=bool),
                final_observation=r["final"],
                terminated=r["term"],
                truncated=r["trunc"],
                index=job.index,
                reward_terms=r["terms"],
                robot_seconds=len(r["rew"]) * self.period,
                final_goal_error=r["goal_error"],
            )
            for job, r in zip(jobs, rec, strict=True)
        ]

    def close(self) -> None:
        self.env.close()


class RaySampler(Sampler):
    """Ray actors, one env each, for sampling across machines (optional extra ``ray``).

    Args:
      env_factory: picklable env builder.
      n_workers: number of actors.
      max_steps: optional cap on episode length.
      ray_init_kwargs: passed to ``ray.init`` if Ray is not initialised yet.
    """

    def __init__(
        self,
        env_factory: EnvFactoryFn,
        n_workers: int,
        max_steps: int | None = None,
        ray_init_kwargs: Mapping[str, Any] | None = None,
    ):
        try:
            import ray
        except ImportError as exc:
            raise LowcostdexError(
                "the Ray sampler needs Ray: pip install 'lowcostdex[ray]'"
            ) from exc
        if n_workers < 1:
            raise ConfigError(f"n_workers={n_workers} must be >= 1")
        if not ray.is_initialized():
            ray.init(**dict(ray_init_kwargs or {}))
        actor_cls = ray.remote(_RayWorker)
        self._ray = ray
        self._actors = [actor_cls.remote(env_factory, max_steps) for _ in range(n_workers)]

    def sample(self, policy: PolicySnapshot, jobs: Sequence[RolloutJob]) -> list[Trajectory]:
        chunks = _split(list(jobs), len(self._actors))
        ref = self._ray.put(policy)
        futures = [a.sample.remote(ref, c) for a, c in zip(self._actors, chunks, strict=True) if c]
        return [t for part in self._ray.get(futures) for t in part]

    def close(self) -> None:
        for actor in getattr(self, "_actors", []):
            self._ray.kill(actor)
        self._actors = []


class _RayWorker:
    """Body of a Ray actor (wrapped with ``ray.remote`` at run time)."""

    def __init__(self, env_factory: EnvFactoryFn, max_steps: int | None):
        self.env = env_factory()
        self.max_steps = max_steps

    def sample(self, policy: PolicySnapshot, jobs: list[RolloutJob]) -> list[Trajectory]:
        return [rollout(self.env, policy, job, self.max_steps) for job in jobs]
