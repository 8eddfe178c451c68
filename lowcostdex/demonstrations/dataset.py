"""Demonstrations for BC and DAPG: reading the demo dataset, recording teachers in simulation.

Every demonstration file is the HDF5 dataset of :mod:`lowcostdex.demonstrations.file` (one group per
episode with observations, actions, rewards, qpos/qvel, times, success flags and the goal),
whoever produced it: a person on the robot or the emulator's virtual teacher
(``lowcostdex record-demos``), or a teacher run here in simulation.

- :func:`load_demos` reads a file's successful episodes as :class:`Demos`, the (observation,
  action) pairs BC and DAPG train on (the final observation of each episode is dropped).
- :func:`teacher_episodes` runs a scripted or learned teacher (a function of the env returning
  the next action) in an env and returns full :class:`~lowcostdex.demonstrations.file.Episode` s;
  :func:`save_demos` writes them as a new dataset. :class:`EpisodeRecorder` is the step-by-step
  piece underneath, for trainers with their own rollout loop.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from lowcostdex.demonstrations.file import (
    DatasetInfo,
    DemoWriter,
    Episode,
    read_info,
    read_numbered_episodes,
)
from lowcostdex.errors import ConfigError, InputError, check_bool, check_number
from lowcostdex.outdir import user_path
from lowcostdex.sim.envs.hand_env import control_period

Teacher = Callable[[gym.Env, np.ndarray], np.ndarray]
"""(env, observation (obs_dim,)) -> action (act_dim,) in the env's action space. A teacher
with state may also have a ``reset(env)`` method, called after every ``env.reset``."""


@dataclass(frozen=True)
class Demos:
    """Demonstration pairs, concatenated over episodes.

    Attributes:
      observations: (N, obs_dim).
      actions: (N, act_dim) in the env's action space.
      episode_ends: (E,) exclusive end index of each episode.
      episode_ids: (E,) each episode's index in its file (``episode_<id>``); None: 0..E-1.
    """

    observations: np.ndarray
    actions: np.ndarray
    episode_ends: np.ndarray
    episode_ids: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = self.observations.shape[0]
        if self.actions.shape[0] != n or (self.episode_ends.size and self.episode_ends[-1] != n):
            raise ConfigError(
                f"inconsistent demos: {n} observations, {self.actions.shape[0]} actions, "
                f"episodes ending at {self.episode_ends[-1:] if self.episode_ends.size else 'none'}"
            )

    @property
    def n_episodes(self) -> int:
        return int(self.episode_ends.shape[0])

    def episodes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """[(observations (T, obs_dim), actions (T, act_dim)), ...]."""
        starts = np.concatenate([[0], self.episode_ends[:-1]])
        return [
            (self.observations[s:e], self.actions[s:e])
            for s, e in zip(starts, self.episode_ends, strict=True)
        ]

    def first(self, n: int | None) -> Demos:
        """The first ``n`` episodes (all if None; n >= 1: 0 gave them all, -1 all but one)."""
        check_number("n (demo episodes)", n, 1, integer=True, none_ok=True)
        if n is None or n >= self.n_episodes:
            return self
        end = int(self.episode_ends[n - 1])
        ids = None if self.episode_ids is None else self.episode_ids[:n]
        return Demos(self.observations[:end], self.actions[:end], self.episode_ends[:n], ids)

    def locate(self, row: int) -> tuple[int, int]:
        """(episode id, step) of pair ``row``."""
        e = int(np.searchsorted(self.episode_ends, row, side="right"))
        start = int(self.episode_ends[e - 1]) if e else 0
        return (int(self.episode_ids[e]) if self.episode_ids is not None else e), row - start

    @classmethod
    def from_episodes(cls, episodes: Sequence[tuple[np.ndarray, np.ndarray]],
                      episode_ids: Sequence[int] | None = None) -> Demos:
        """Concatenate (observations (T, obs_dim), actions (T, act_dim)) episodes."""
        if not episodes:
            raise ConfigError("no demonstration episodes")
        obs = np.concatenate([np.asarray(o, dtype=np.float64) for o, _ in episodes])
        act = np.concatenate([np.asarray(a, dtype=np.float64) for _, a in episodes])
        ends = np.cumsum([len(o) for o, _ in episodes]).astype(np.int64)
        ids = None if episode_ids is None else np.asarray(episode_ids, dtype=np.int64)
        return cls(obs, act, ends, ids)


def load_demos(path: str | Path, only_successful: bool = True) -> Demos:
    """Read a demonstration dataset (:mod:`lowcostdex.demonstrations.file`) as BC/DAPG pairs.

    Args:
      path: the HDF5 file.
      only_successful: keep only the episodes whose last step succeeded.

    Raises:
      InputError: a missing, unreadable or corrupt file, a file of another format (e.g. an
        NPZ), a field of the wrong shape, or a NaN/inf observation or action (the message
        names the file, the field and the value).
      ConfigError: no episode left.
    """
    check_bool("only_successful", only_successful)  # "no"/"false" are truthy: kept as True
    used = read_numbered_episodes(path, only_successful=only_successful)
    if not used:
        kind = "successful demonstration" if only_successful else "episode"
        raise ConfigError(f"{path} holds no {kind}")
    if not any(ep.length for _, ep in used):  # (before: Demos of no pairs, BC failing later)
        raise ConfigError(f"{path}: its {len(used)} episode(s) have 0 steps: no observation-"
                          "action pair to learn from")
    for k, ep in used:
        for field in ("observations", "actions"):
            values = getattr(ep, field)
            bad = np.argwhere(~np.isfinite(values))
            if bad.size:
                t, j = (int(i) for i in bad[0])
                value = float(values[t, j])
                raise InputError(f"{path}: episode_{k}/{field}[{t}, {j}] = {value!r} is not "
                                 "finite")
    return Demos.from_episodes([(ep.observations[:-1], ep.actions) for _, ep in used],
                               [k for k, _ in used])


ACTION_TOLERANCE = 1e-6
"""How far [action units] a demonstration action may lie outside the env's action bounds."""


def check_demos(demos: Demos, path: str | Path, env: gym.Env, env_id: str) -> None:
    """Check that demonstrations read from ``path`` fit the env a run trains.

    Args:
      demos: from :func:`load_demos`.
      path: their file (its ``env_id``, ``obs_dim`` and ``act_dim`` attributes are compared).
      env: the run's env.
      env_id: the run's gymnasium id.

    Raises:
      InputError: the demos were recorded in another env (id or sizes), or an action lies
        outside the env's action bounds (the message names the file, the field, the value).
    """
    info = read_info(path)[0]
    obs_dim = int(np.prod(env.observation_space.shape))
    act_dim = int(np.prod(env.action_space.shape))
    if info.env_id != env_id:
        raise InputError(f"{path}: env_id is {info.env_id!r}: these demonstrations are of "
                         f"another env; this run trains {env_id!r}: "
                         + _other_env_fix(info.env_id, env_id))
    if (info.obs_dim, info.act_dim) != (obs_dim, act_dim) or \
            demos.observations.shape[1] != obs_dim or demos.actions.shape[1] != act_dim:
        raise InputError(f"{path}: obs_dim/act_dim are {demos.observations.shape[1]}/"
                         f"{demos.actions.shape[1]}; the env {env_id} has {obs_dim}/{act_dim}")
    low = np.broadcast_to(np.asarray(env.action_space.low, np.float64).ravel(), (act_dim,))
    high = np.broadcast_to(np.asarray(env.action_space.high, np.float64).ravel(), (act_dim,))
    outside = (demos.actions < low - ACTION_TOLERANCE) | (demos.actions > high + ACTION_TOLERANCE)
    bad = np.argwhere(outside)
    if bad.size:
        row, j = (int(i) for i in bad[0])
        k, t = demos.locate(row)
        value = float(demos.actions[row, j])
        raise InputError(f"{path}: episode_{k}/actions[{t}, {j}] = {value!r} is "
                         f"outside the env's action bounds [{low[j]}, {high[j]}] "
                         f"({int(outside.any(axis=1).sum())} actions outside)")


def _other_env_fix(theirs: str, ours: str) -> str:
    """What to type when demonstrations of env ``theirs`` meet a run of env ``ours``."""
    return (f"train their env (--env {theirs}; TrainConfig.env_id), or record demonstrations "
            f"of {ours} (`lowcostdex record-demos --help` lists each hand's tasks)")


def save_demos(path: str | Path, episodes: Sequence[Episode], info: DatasetInfo) -> Path:
    """Write ``episodes`` as a new demonstration dataset at ``path``, replacing any file there.

    The file is built next to ``path`` and moved into place when complete, so ``path`` never
    holds a partial dataset. To add episodes to an existing file use
    :class:`~lowcostdex.demonstrations.file.DemoWriter`.

    Args:
      path: the HDF5 file (conventionally ``.h5``).
      episodes: full episodes, e.g. from :func:`teacher_episodes`.
      info: the file's metadata; for a lowcostdex env
        ``DatasetInfo.from_env(env, "scripted_teacher")``.
    """
    if not episodes:
        raise ConfigError("no demonstration episodes to save")
    if not isinstance(info, DatasetInfo) or not all(isinstance(e, Episode) for e in episodes):
        raise ConfigError("save_demos(path, episodes, info) takes a list of Episode and a "
                          f"DatasetInfo, not {type(episodes[0]).__name__} and "
                          f"{type(info).__name__}")
    path = user_path(path)
    if path.is_dir():  # (before: written beside it as NAME.partial, then IsADirectoryError)
        raise ConfigError(f"{path} is a folder; give the demo file, e.g. {path / 'demos.h5'}")
    partial = path.with_name(path.name + ".partial")
    partial.unlink(missing_ok=True)
    try:
        writer = DemoWriter(partial, info)
        for ep in episodes:
            writer.append(ep)
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    os.replace(partial, path)
    return path


class EpisodeRecorder:
    """Collects one episode of a running env into an :class:`~lowcostdex.demonstrations.file.Episode`.

    Create it right after ``env.reset`` and call :meth:`step` after every ``env.step``::

        obs, info = env.reset(seed=seed)
        rec = EpisodeRecorder(env, obs, info, seed)
        while not done:
            obs, reward, terminated, truncated, info = env.step(executed)
            rec.step(label, obs, reward, terminated, info)
            done = terminated or truncated
        episode = rec.episode()

    The physical state is read from ``env.unwrapped.data`` (MuJoCo ``qpos``/``qvel``; an env
    without one records zero-width arrays); times are the robot clock
    (``info["telemetry"]["clock"]``) on a robot, else ``info["time"]`` when the env reports it,
    else steps times the control period [s]; the goal is ``env.unwrapped.goal`` at reset (if
    it is a dict of arrays); success per step is ``info["success"]``; the auto-reset time comes
    from the reset info's robot telemetry (NaN in simulation).

    Args:
      env: the env, just reset.
      obs: the reset observation.
      info: the reset info.
      seed: the reset seed (stored with the episode).
    """

    def __init__(self, env: gym.Env, obs: np.ndarray, info: Mapping[str, Any], seed: int = -1):
        self.env = env
        self.base = env.unwrapped
        self.period = control_period(env)
        goal = getattr(self.base, "goal", None)
        goal = goal if isinstance(goal, Mapping) else {}
        self.goal = {k: np.array(v, dtype=np.float64) for k, v in goal.items()}
        self.seed = int(seed)
        telemetry = info.get("telemetry") or {}  # robot backends report the auto-reset
        self.reset_time = float(telemetry.get("last_reset_time", float("nan")))
        self.observations = [np.asarray(obs, dtype=np.float64).ravel()]
        self.actions: list[np.ndarray] = []
        self.rewards: list[float] = []
        self.success: list[bool] = []
        self.qpos: list[np.ndarray] = []
        self.qvel: list[np.ndarray] = []
        self.time: list[float] = []
        self.terminated = False
        self._state(info)

    def _state(self, info: Mapping[str, Any]) -> None:
        data = getattr(self.base, "data", None)
        self.qpos.append(np.array(data.qpos if data is not None else [], dtype=np.float64))
        self.qvel.append(np.array(data.qvel if data is not None else [], dtype=np.float64))
        telemetry = info.get("telemetry") or {}  # a robot: its clock, as demonstrations are
        self.time.append(float(telemetry.get("clock",
                                              info.get("time", len(self.actions) * self.period))))

    def step(
        self,
        action: np.ndarray,
        obs: np.ndarray,
        reward: float,
        terminated: bool,
        info: Mapping[str, Any],
    ) -> None:
        """Record one transition: the action label (act_dim,) and what ``env.step`` returned."""
        self.actions.append(np.asarray(action, dtype=np.float64).ravel())
        self.observations.append(np.asarray(obs, dtype=np.float64).ravel())
        self.rewards.append(float(reward))
        self.success.append(bool(info.get("success", False)))
        self.terminated = bool(terminated)
        self._state(info)

    def episode(self) -> Episode:
        """The episode so far."""
        n_act = int(np.prod(self.env.action_space.shape))
        return Episode(
            observations=np.stack(self.observations),
            actions=np.asarray(self.actions, dtype=np.float64).reshape(-1, n_act),
            rewards=np.asarray(self.rewards, dtype=np.float64),
            qpos=np.stack(self.qpos),
            qvel=np.stack(self.qvel),
            time=np.asarray(self.time),
            success=np.asarray(self.success, dtype=bool),
            goal=dict(self.goal),
            seed=self.seed,
            reset_time=self.reset_time,
            terminated=self.terminated,
        )


def teacher_episodes(
    env: gym.Env,
    teacher: Teacher,
    seeds: Sequence[int],
    only_successful: bool = True,
    max_tries: int = 4,
    action_noise: float = 0.0,
) -> list[Episode]:
    """Record one demonstration per seed by running ``teacher`` in ``env``.

    With ``action_noise > 0`` the env executes the teacher's action plus uniform noise in
    [-action_noise, action_noise] (per dimension, clipped to [-1, 1]) while the recorded label is
    the teacher's own action: the demonstrations then also show how to recover from the small
    deviations a cloned policy makes (the DAPG authors added +-0.1 rad actuator noise while
    collecting for the same reason; labelling the clean action is DART, Laskey et al. 2017).

    Args:
      env: the environment (reset with each seed).
      teacher: (env, observation) -> action.
      seeds: reset seeds, one episode each; the noise of an episode is drawn from a generator
        seeded with the same seed.
      only_successful: keep an episode only if ``info["success"]`` holds at its last step;
        a failed seed is retried with seed + 10**6 * k (k = 1..max_tries-1).
      max_tries: attempts per seed.
      action_noise: half-width of the executed-action noise, in action units.

    Returns:
      One :class:`~lowcostdex.demonstrations.file.Episode` per seed (observations (T+1, obs_dim), the
      teacher's actions (T, act_dim), rewards, qpos/qvel, times, success flags, goal, seed);
      write them with :func:`save_demos`.

    Raises:
      ConfigError: a seed produced no successful episode in ``max_tries`` attempts; seeds not a
        list of distinct integers >= 0 (a seed given twice recorded the same episode twice, the
        string "12" seeds 1 and 2), max_tries < 1, action_noise outside [0, 2].
    """
    if isinstance(seeds, (str, bytes)) or not isinstance(seeds, Sequence | np.ndarray):
        raise ConfigError(f"seeds={seeds!r} must be a list of reset seeds, e.g. range(25)")
    seen: set[int] = set()
    for seed in seeds:
        check_number("seed", seed, 0, integer=True)
        if int(seed) in seen:
            raise ConfigError(f"seed {int(seed)} given twice: the same episode would be recorded "
                              "twice (give distinct seeds)")
        seen.add(int(seed))
    check_number("max_tries", max_tries, 1, integer=True)
    check_number("action_noise", action_noise, 0, 2)  # half-width in a [-1, 1] action range
    episodes = []
    for seed in seeds:
        for k in range(max_tries):
            episode_seed = int(seed) + 10**6 * k
            obs, info = env.reset(seed=episode_seed)
            rng = np.random.default_rng(episode_seed)
            if hasattr(teacher, "reset"):
                teacher.reset(env)
            recorder = EpisodeRecorder(env, obs, info, episode_seed)
            done = False
            while not done:
                action = np.asarray(teacher(env, obs), dtype=np.float64)
                executed = action
                if action_noise > 0:
                    noise = rng.uniform(-action_noise, action_noise, action.shape)
                    executed = np.clip(action + noise, -1.0, 1.0)
                obs, reward, terminated, truncated, info = env.step(
                    executed.astype(env.action_space.dtype)
                )
                recorder.step(action, obs, reward, terminated, info)
                done = terminated or truncated
            episode = recorder.episode()
            if not only_successful or (episode.length and bool(episode.success[-1])):
                episodes.append(episode)
                break
        else:
            raise ConfigError(f"the teacher failed {max_tries} times from seed {seed}")
    return episodes
