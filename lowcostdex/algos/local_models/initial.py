"""The TVLG trainer's initial controller: hold the start pose, or replay the mean action of
demonstrations or of the scripted teacher's episodes (``teacher_episodes``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController, pd_controller
from lowcostdex.algos.local_models.episodes import FixedStart, controller_state
from lowcostdex.algos.local_models.train_config import TVLGTrainConfig
from lowcostdex.algos.samplers import RolloutJob, control_period
from lowcostdex.errors import ConfigError

Array = NDArray[np.float64]
_TEACHER_STREAM = 2  # rollout stream of the teacher episodes (0: training, 1: evaluation)
TEACHER_FILE = "teacher_demo.h5"


def initial_controller(
    config: TVLGTrainConfig,
    env: gym.Env,
    start: FixedStart,
    x0: Array,
    hold: Array,
    T: int,
    demo_actions: Array | None = None,
) -> LinearGaussianController:
    """The first controller: hold the start pose, or replay demonstrations, with noise.

    Args:
      demo_actions: (M, T, dU) actions of M episodes to replay (their mean per step); default:
        the episodes of ``config.demos`` when ``config.init == "demos"``.
    """
    task = env.unwrapped.task
    n_hand = len(task.hand_qpos)
    ctl = pd_controller(
        x0, hold, T, list(range(n_hand)), None, config.pd_gain, 0.0, config.init_noise**2
    )
    if demo_actions is None and config.init != "demos":
        return ctl
    if demo_actions is None:
        demo_actions = demo_actions_array(config.demos, T)
    k = ctl.k + np.nanmean(demo_actions, axis=0) - hold
    return LinearGaussianController.from_cov(ctl.K, k, ctl.cov)


def demo_actions_array(path: str | None, T: int) -> Array:
    """Actions (M, T, dU) of a demo file's episodes, nan-padded; a step no episode reaches
    repeats the last action of the longest one."""
    from lowcostdex.demonstrations.dataset import load_demos

    demos = load_demos(path)
    starts = np.concatenate([[0], demos.episode_ends[:-1]])
    out = np.full((demos.n_episodes, T, demos.actions.shape[1]), np.nan)
    for i, (s, e) in enumerate(zip(starts, demos.episode_ends, strict=True)):
        n = min(e - s, T)
        out[i, :n] = demos.actions[s : s + n]
    longest = int(np.argmax(demos.episode_ends - starts))
    for t in range(1, T):
        if np.all(np.isnan(out[:, t, 0])):
            out[longest, t] = out[longest, t - 1]
    return out


@dataclass(frozen=True)
class TeacherEpisodes:
    """Episodes of the scripted teacher with exploration noise on its actions.

    Attributes:
      X: (M, T, dX) controller states; U: (M, T, dU) actions applied (teacher + noise; the last
        one is the teacher's, not executed).
      successes: (M,) final-step success of each episode.
      robot_seconds: robot time of all episodes [s].
    """

    X: Array
    U: Array
    successes: NDArray[np.bool_]
    robot_seconds: float


def teacher_episodes(
    env: gym.Env,
    start: FixedStart,
    config: TVLGTrainConfig,
    hold: Array,
    T: int,
    demo_path: Path | None = None,
    noise: float = 0.0,
) -> TeacherEpisodes:
    """Run the scripted valve teacher ``config.teacher_episodes`` times from ``start``.

    Gaussian noise of std ``noise`` may be added to every teacher action (reset seed and noise
    from (seed, stream 2, 0, i)), e.g. to identify the teacher's feedback with
    :func:`.policy_fit.fit_policy`. With ``demo_path`` the episodes are also saved as a
    demonstration dataset (:mod:`lowcostdex.demonstrations.file`, the applied actions as labels).

    Raises:
      ConfigError: if the task has no scripted teacher.
    """
    try:
        from lowcostdex.teachers.valve import ValveTurnTeacher
    except ImportError as exc:
        raise ConfigError(
            "init 'teacher' needs lowcostdex.teachers.valve (the valve teacher)"
        ) from exc
    from lowcostdex.demonstrations.dataset import EpisodeRecorder
    from lowcostdex.sim.envs import goal_to_action

    base = env.unwrapped
    dX = controller_state(env, hold if config.include_last_action else None).shape[0]
    M, dU = config.teacher_episodes, len(hold)
    X, U = np.zeros((M, T, dX)), np.zeros((M, T, dU))
    successes, seconds, demos = np.zeros(M, dtype=bool), 0.0, []
    for i in range(M):
        job = RolloutJob(config.seed, _TEACHER_STREAM, 0, i)
        rng = job.noise_rng()
        obs, info = env.reset(seed=job.env_seed(), options=start.reset_options())
        seconds += float(info.get("reset_time", 0.0)) + float(info.get("thermal_pause_time", 0.0))
        teacher = ValveTurnTeacher()
        teacher.reset(base)
        last = hold.copy() if config.include_last_action else None
        recorder = EpisodeRecorder(env, obs, info, job.env_seed())
        for t in range(T):
            X[i, t] = controller_state(env, last)
            goal = teacher(base.data.qpos.copy(), base.goal)
            action = goal_to_action(goal, base.task.hand_low, base.task.hand_high)
            if t == T - 1:
                U[i, t] = action
                break
            U[i, t] = np.clip(action + noise * rng.standard_normal(dU), -1.0, 1.0)
            obs, reward, terminated, _, info = env.step(U[i, t].astype(np.float32))
            recorder.step(U[i, t], obs, reward, terminated, info)
            last = U[i, t].copy() if config.include_last_action else None
        successes[i] = bool(info.get("success", False))
        seconds += (T - 1) * control_period(env)
        demos.append(recorder.episode())
    if demo_path is not None:
        from lowcostdex.demonstrations.dataset import save_demos
        from lowcostdex.demonstrations.file import DatasetInfo

        save_demos(demo_path, demos, DatasetInfo.from_env(env, "scripted_teacher"))
    return TeacherEpisodes(X, U, successes, seconds)
