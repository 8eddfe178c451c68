"""Demonstrations for BC and DAPG: (observation, action) pairs grouped in episodes.

File format read and written here (no pickle): an NPZ with

- ``observations`` (N, obs_dim) float64,
- ``actions`` (N, act_dim) float64, in the env's action space ([-1, 1]),
- ``episode_ends`` (E,) int64, the exclusive end index of each episode in the arrays above.

Kinesthetic demonstrations recorded on a robot (``lowcostdex record-demos``, an HDF5 file from
``lowcostdex.hardware.demo_file``) are read through that package's reader when the file is not
an NPZ; only their successful episodes are used.

:func:`teacher_episodes` records demonstrations in any env from a scripted or learned teacher
(a function of the env returning the next action), e.g. for simulation benchmarks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np

from lowcostdex.errors import ConfigError

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
    """

    observations: np.ndarray
    actions: np.ndarray
    episode_ends: np.ndarray

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
        """The first ``n`` episodes (all if None)."""
        if n is None or n >= self.n_episodes:
            return self
        end = int(self.episode_ends[n - 1])
        return Demos(self.observations[:end], self.actions[:end], self.episode_ends[:n])

    @classmethod
    def from_episodes(cls, episodes: Sequence[tuple[np.ndarray, np.ndarray]]) -> Demos:
        """Concatenate (observations (T, obs_dim), actions (T, act_dim)) episodes."""
        if not episodes:
            raise ConfigError("no demonstration episodes")
        obs = np.concatenate([np.asarray(o, dtype=np.float64) for o, _ in episodes])
        act = np.concatenate([np.asarray(a, dtype=np.float64) for _, a in episodes])
        ends = np.cumsum([len(o) for o, _ in episodes]).astype(np.int64)
        return cls(obs, act, ends)


def save_demos(path: str | Path, demos: Demos | Sequence[tuple[np.ndarray, np.ndarray]]) -> Path:
    """Write demos (or a list of episodes) as the NPZ described in the module docstring."""
    if not isinstance(demos, Demos):
        demos = Demos.from_episodes(demos)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        np.savez(
            f,
            observations=demos.observations,
            actions=demos.actions,
            episode_ends=demos.episode_ends,
        )
    return path


def load_demos(path: str | Path) -> Demos:
    """Read demonstrations: our NPZ, or a recording from ``lowcostdex.hardware``.

    Raises:
      ConfigError: missing file, missing arrays, or an unknown format.
    """
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"demonstration file {path} does not exist")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            missing = {"observations", "actions", "episode_ends"} - set(data.files)
            if missing:
                raise ConfigError(f"{path} lacks {sorted(missing)}; it has {sorted(data.files)}")
            return Demos(
                np.asarray(data["observations"], dtype=np.float64),
                np.asarray(data["actions"], dtype=np.float64),
                np.asarray(data["episode_ends"], dtype=np.int64),
            )
    return _load_recording(path)


def _load_recording(path: Path) -> Demos:
    """Kinesthetic recordings (HDF5, ``lowcostdex.hardware.demo_file``); successful episodes."""
    try:
        from lowcostdex.hardware.demo_file import read_demo_pairs
    except ImportError as exc:  # pragma: no cover - the hardware layer ships with the package
        raise ConfigError(
            f"{path}: not an .npz, and the robot-recording reader is missing"
        ) from exc
    episodes = read_demo_pairs(path, only_successful=True)
    if not episodes:
        raise ConfigError(f"{path} holds no successful demonstration")
    return Demos.from_episodes(episodes)


def teacher_episodes(
    env: gym.Env,
    teacher: Teacher,
    seeds: Sequence[int],
    only_successful: bool = True,
    max_tries: int = 4,
    action_noise: float = 0.0,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Record one demonstration per seed by running ``teacher`` in ``env``.

    With ``action_noise > 0`` the env executes the teacher's action plus uniform noise in
    [-action_noise, action_noise] (per dimension, clipped to [-1, 1]) while the recorded label is
    the teacher's own action: the demonstrations then also show how to recover from the small
    deviations a cloned policy makes (the DAPG authors added +-0.1 rad actuator noise while
    collecting for the same reason; labelling the clean action is DART, Laskey et al. 2017).

    Args:
      env: the environment (reset with each seed; its reset info and observations are used).
      teacher: (env, observation) -> action.
      seeds: reset seeds, one episode each; the noise of an episode is drawn from a generator
        seeded with the same seed.
      only_successful: keep an episode only if ``info["success"]`` holds at its last step;
        a failed seed is retried with seed + 10**6 * k (k = 1..max_tries-1).
      max_tries: attempts per seed.
      action_noise: half-width of the executed-action noise, in action units.

    Returns:
      [(observations (T, obs_dim), actions (T, act_dim)), ...].

    Raises:
      ConfigError: a seed produced no successful episode in ``max_tries`` attempts.
    """
    episodes = []
    for seed in seeds:
        for k in range(max_tries):
            episode_seed = int(seed) + 10**6 * k
            obs, info = env.reset(seed=episode_seed)
            rng = np.random.default_rng(episode_seed)
            if hasattr(teacher, "reset"):
                teacher.reset(env)
            observations, actions = [], []
            done = False
            while not done:
                action = np.asarray(teacher(env, obs), dtype=np.float64)
                observations.append(np.asarray(obs, dtype=np.float64))
                actions.append(action)
                executed = action
                if action_noise > 0:
                    noise = rng.uniform(-action_noise, action_noise, action.shape)
                    executed = np.clip(action + noise, -1.0, 1.0)
                obs, _, terminated, truncated, info = env.step(
                    executed.astype(env.action_space.dtype)
                )
                done = terminated or truncated
            if not only_successful or bool(info.get("success", False)):
                episodes.append((np.asarray(observations), np.asarray(actions)))
                break
        else:
            raise ConfigError(f"the teacher failed {max_tries} times from seed {seed}")
    return episodes
