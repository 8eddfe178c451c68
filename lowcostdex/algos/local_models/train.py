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
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.local_models.controller import (
    LinearGaussianController,
    exploration_noise,
    pd_controller,
)
from lowcostdex.algos.local_models.costs import RAMP_KINDS, ActionCost, StateCost, SumCost
from lowcostdex.algos.local_models.dynamics import DynamicsConfig
from lowcostdex.algos.local_models.traj_opt import TrajOptConfig
from lowcostdex.algos.local_models.tvlg import (
    TVLGConfig,
    TVLGState,
    state_from_arrays,
    state_to_arrays,
    tvlg_iteration,
)
from lowcostdex.algos.samplers import (
    EVAL_STREAM,
    TRAIN_STREAM,
    EnvFactory,
    RolloutJob,
    control_period,
)
from lowcostdex.errors import ConfigError, check_choice, check_number

Array = NDArray[np.float64]
BACKENDS = ("sim", "emulated", "hardware")
INITS = ("pd", "demos", "teacher")
SUCCESS_MODES = ("final", "any")
HAND_REFERENCES = ("start", "demo")
COST_PRESETS = ("task", "tracking")
TRACKING_KL_STEP = 0.5
"""KL step the CLI uses with ``--cost tracking`` (bench/RESULTS.md measured it at 0.5)."""
MUTABLE_ON_RESUME = ("n_iter", "progress")
"""Config keys a resumed run may change."""
_UPDATE = 13  # seed purpose of the update generator (the GMM's EM)
_TEACHER_STREAM = 2  # rollout stream of the teacher episodes (0: training, 1: evaluation)
CONTROLLER_FILE = "controller.npz"
TEACHER_FILE = "teacher_demo.h5"


@dataclass(frozen=True)
class TaskCostConfig:
    """Quadratic cost of a goal-angle task (valve turning, screw), in state units.

    Two presets (``preset``): ``task()`` (the defaults) pulls the object angle to the goal at every
    step and keeps the hand near its start pose; ``tracking()`` keeps the hand joints near the
    demonstrated joint targets and pays for the object angle only over the last ``final_steps``
    steps (bench/RESULTS.md: from the PD-hold start the task cost has no gradient before contact,
    and around a demonstration it pulls the valve ahead of the demonstrated gait at every step).

    Attributes:
      object_weight: weight of the squared object-angle error [1/rad^2].
      object_l1: weight of a smooth |error| term on the object angle (keeps pulling near the goal).
      pose_weight: squared deviation of the hand joints from their reference [1/rad^2].
      velocity_weight: squared hand and object joint velocities [s^2/rad^2].
      action_weight: squared deviation of the normalised action from the one holding the start
        pose.
      final_multiplier: extra weight of the final step's state terms.
      ramp: growth of the object term over the episode, one of RAMP_KINDS.
      final_steps: steps at the end weighted by the ``final_only`` ramp (reach the goal and hold
        it).
      hand_reference: the hand joints' reference, one of HAND_REFERENCES: "start" (the start
        pose) or "demo" (the joint targets of the demonstration the controller starts from; needs
        init "teacher" or "demos").
    """

    object_weight: float = 1.0
    object_l1: float = 0.0
    pose_weight: float = 0.01
    velocity_weight: float = 1e-3
    action_weight: float = 1e-3
    final_multiplier: float = 10.0
    ramp: str = "constant"
    final_steps: int = 1
    hand_reference: str = "start"

    def __post_init__(self) -> None:
        check_choice("ramp", self.ramp, RAMP_KINDS)
        check_choice("hand reference", self.hand_reference, HAND_REFERENCES)
        for name in (
            "object_weight",
            "object_l1",
            "pose_weight",
            "velocity_weight",
            "action_weight",
        ):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 0")
        if self.final_multiplier <= 0:
            raise ConfigError(f"final_multiplier={self.final_multiplier} must be > 0")
        if self.final_steps < 1:
            raise ConfigError(f"final_steps={self.final_steps} must be >= 1")

    @classmethod
    def task(cls) -> TaskCostConfig:
        """The goal at every step, the hand near its start pose (the defaults)."""
        return cls()

    @classmethod
    def tracking(cls) -> TaskCostConfig:
        """Hand joints near the demonstrated joint targets (weight 0.1 / rad^2), the object at
        the goal over the last 5 steps (weight 10 / rad^2): the configuration measured in
        bench/RESULTS.md."""
        return cls(
            object_weight=10.0, pose_weight=0.1, final_multiplier=1.0, ramp="final_only",
            final_steps=5, hand_reference="demo",
        )  # fmt: skip

    @classmethod
    def preset(cls, name: str) -> TaskCostConfig:
        """One of COST_PRESETS by name."""
        check_choice("cost preset", name, COST_PRESETS)
        return getattr(cls, name)()


@dataclass(frozen=True)
class TVLGTrainConfig:
    """One learned-local-model run on a fixed start state.

    Attributes:
      env_id: registered gymnasium id with a goal angle (valve and screw tasks).
      backend: one of BACKENDS.
      env_kwargs: extra ``gym.make`` keyword arguments (e.g. ``{"port": "/dev/ttyUSB0"}``).
      seed: the run's seed; every random draw derives from it.
      n_iter: iterations.
      n_rollouts: episodes per iteration (5 in Kumar et al. 2016 and the GPS examples).
      include_last_action: append the last applied action to the state.
      start_hand_qpos: hand joint angles [rad, action order] of the fixed start instead of the
        task's reset pose (e.g. fingertips already behind the valve's spokes); None: the task's.
      init: initial controller, one of INITS: "pd" holds the start pose (plus ``pd_gain``
        feedback) with exploration noise; "demos" replays the mean action of the demonstrations
        in ``demos`` (the DAPG demo format) with the same noise; "teacher" first runs the
        scripted teacher (``lowcostdex.demonstrations.teachers.valve``) ``teacher_episodes`` times from the fixed
        start (saved as ``teacher_demo.h5``) and replays its mean action like "demos".
      teacher_episodes: teacher episodes for init "teacher" (logged as ``teacher_episodes``,
        counted in robot time, not in ``rollouts``).
      demos: demonstration dataset (HDF5, :mod:`lowcostdex.demonstrations.file`).
      init_noise: std of the initial controller's exploration noise [normalised action].
      pd_gain: position feedback of the initial controller [normalised action / rad].
      smooth_noise: Gaussian smoothing of the exploration noise over time [steps]; 0 = white.
      success: episode success from ``info["success"]`` at the final step or at any step.
      eval_every: noise-free evaluation episode every this many iterations (0: last only).
      eval_noisy_episodes: held-out episodes of the controller with its exploration noise at
        every evaluation (not used for learning; counted in robot time, not in ``rollouts``);
        logged as ``eval_noisy_success_rate``.
      solve_rate: an evaluated iteration is ``solved`` when its noise-free episode succeeds and,
        if ``eval_noisy_episodes`` > 0, at least this fraction of the noisy ones do.
      checkpoint_every: checkpoint period [iterations] (the last iteration always saves).
      cost: the task cost.
      algo: the optimiser (dynamics fit, KL trust region).
      progress: show a progress bar.
    """

    env_id: str = "lowcostdex/DClawTurnValve-v0"
    backend: str = "sim"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    n_iter: int = 12
    n_rollouts: int = 5
    include_last_action: bool = True
    start_hand_qpos: tuple[float, ...] | None = None
    init: str = "pd"
    demos: str | None = None
    teacher_episodes: int = 1
    init_noise: float = 0.3
    pd_gain: float = 0.0
    smooth_noise: float = 0.0
    success: str = "final"
    eval_every: int = 1
    eval_noisy_episodes: int = 0
    solve_rate: float = 0.8
    checkpoint_every: int = 1
    cost: TaskCostConfig = field(default_factory=TaskCostConfig)
    algo: TVLGConfig = field(default_factory=TVLGConfig)
    progress: bool = True

    def __post_init__(self) -> None:
        check_choice("backend", self.backend, BACKENDS)
        check_choice("initial controller", self.init, INITS)
        check_choice("success mode", self.success, SUCCESS_MODES)
        if self.init == "demos" and not self.demos:
            raise ConfigError("init 'demos' needs a demonstration file (--demos PATH)")
        for name in ("n_iter", "n_rollouts", "checkpoint_every", "teacher_episodes"):
            check_number(name, getattr(self, name), 1, integer=True)
        for name in ("eval_every", "eval_noisy_episodes", "seed"):
            check_number(name, getattr(self, name), 0, integer=True)
        check_number("solve_rate", self.solve_rate, 0, 1, low_open=True)
        check_number("init_noise", self.init_noise, 0, low_open=True)
        check_number("smooth_noise", self.smooth_noise, 0)
        check_number("pd_gain", self.pd_gain, 0)
        if self.cost.hand_reference == "demo" and self.init not in ("teacher", "demos"):
            raise ConfigError(
                "cost hand_reference 'demo' (--cost tracking) needs a demonstration: "
                "init 'teacher' or 'demos'"
            )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TVLGTrainConfig:
        """Inverse of ``dataclasses.asdict`` (e.g. a run's config.json)."""
        d = dict(d)
        if d.get("start_hand_qpos") is not None:
            d["start_hand_qpos"] = tuple(d["start_hand_qpos"])
        if isinstance(d.get("cost"), Mapping):
            d["cost"] = TaskCostConfig(**d["cost"])
        if isinstance(d.get("algo"), Mapping):
            a = dict(d["algo"])
            a["dynamics"] = DynamicsConfig(**a.get("dynamics", {}))
            a["traj_opt"] = TrajOptConfig(**a.get("traj_opt", {}))
            d["algo"] = TVLGConfig(**a)
        return cls(**d)


# ----------------------------------------------------------------------------------------------
# Episodes


@dataclass(frozen=True)
class FixedStart:
    """The start every episode resets to: qpos (nq,), qvel (nv,) and the task goal.

    ``reference`` [rad], when finite, is an object angle the goal is unwrapped next to (the end
    angle of a teacher episode, so the cost turns the way the teacher did).
    """

    qpos: Array
    qvel: Array
    goal: dict[str, Array]
    reference: float = math.nan

    def reset_options(self) -> dict[str, Any]:
        return {"qpos": self.qpos, "qvel": self.qvel, "goal": self.goal}

    def to_arrays(self) -> dict[str, Array]:
        out = {"qpos": self.qpos, "qvel": self.qvel, "reference": np.asarray(self.reference)}
        out.update({f"goal/{k}": np.asarray(v) for k, v in self.goal.items()})
        return out

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, Any]) -> FixedStart:
        # Scalars may come back as (1,) arrays from a checkpoint; goals are scalars or vectors.
        goal = {
            k[5:]: np.asarray(v, dtype=np.float64).reshape(())
            if np.size(v) == 1
            else np.asarray(v, float)
            for k, v in arrays.items()
            if k.startswith("goal/")
        }
        reference = float(np.asarray(arrays.get("reference", math.nan)).reshape(()))
        return cls(
            np.asarray(arrays["qpos"], float), np.asarray(arrays["qvel"], float), goal, reference
        )


def capture_start(env: gym.Env, seed: int, hand_qpos: Array | None = None) -> FixedStart:
    """Reset once with ``seed`` and record the start state and goal.

    With ``hand_qpos`` (n_hand,) [rad] the hand starts there instead of the task's reset pose
    (the object keeps the task's start); the state recorded is the one the robot reached.
    """
    env.reset(seed=seed)
    base = env.unwrapped
    if hand_qpos is not None:
        qpos = base.data.qpos.copy()
        qpos[base.task.hand_qpos] = np.asarray(hand_qpos, dtype=np.float64)
        env.reset(seed=seed, options={"qpos": qpos, "qvel": np.zeros_like(base.data.qvel)})
    goal = {k: np.array(v, dtype=np.float64) for k, v in getattr(base, "goal", {}).items()}
    return FixedStart(base.data.qpos.copy(), base.data.qvel.copy(), goal)


def offset_start(env: gym.Env, start: FixedStart, offset: float) -> FixedStart:
    """``start`` with the object angle and the goal both turned by ``offset`` [rad] (e.g. to
    record a demonstration from a slightly different valve position than the fixed start)."""
    task = env.unwrapped.task
    qpos = start.qpos.copy()
    qpos[task.obj_qpos] += offset
    goal = {**start.goal, "angle": np.asarray(float(start.goal["angle"]) + offset)}
    return dataclasses.replace(start, qpos=qpos, goal=goal)


def controller_state(env: gym.Env, last_action: Array | None) -> Array:
    """The controller's state: ``state_vector()`` and, if given, the last applied action."""
    x = np.asarray(env.unwrapped.state_vector(), dtype=np.float64)
    return x if last_action is None else np.concatenate([x, last_action])


def hold_action(env: gym.Env, start: FixedStart) -> Array:
    """Normalised action (dU,) whose joint goals are the start pose of the hand."""
    from lowcostdex.sim.envs import goal_to_action

    task = env.unwrapped.task
    return goal_to_action(start.qpos[task.hand_qpos], task.hand_low, task.hand_high)


@dataclass(frozen=True)
class Episode:
    """One episode of a TVLG controller.

    Attributes:
      X: (H+1, dX) controller states x_0..x_H.
      U: (H+1, dU) commanded actions (the last one is not executed).
      rewards: (H,) env rewards.
      successes: (H,) ``info["success"]`` after each step.
      final_error: ``info["goal_error"]`` after the last step (nan if absent).
      robot_seconds: robot time [s]: steps x control period plus reported reset/pause time.
    """

    X: Array
    U: Array
    rewards: Array
    successes: NDArray[np.bool_]
    final_error: float
    robot_seconds: float

    def success(self, mode: str) -> bool:
        return bool(self.successes[-1]) if mode == "final" else bool(self.successes.any())


def run_episode(
    env: gym.Env,
    controller: LinearGaussianController,
    start: FixedStart,
    job: RolloutJob,
    include_last_action: bool,
    hold: Array,
    smooth_noise: float,
) -> Episode:
    """Run ``controller`` for one episode from ``start``; noise-free if ``job.deterministic``.

    An episode that terminates early is padded with its last state (an absorbing state).
    """
    T, dU = controller.T, controller.dU
    noise = None if job.deterministic else exploration_noise(job.noise_rng(), T, dU, smooth_noise)
    _, info = env.reset(seed=job.env_seed(), options=start.reset_options())
    extra = float(info.get("reset_time", 0.0)) + float(info.get("thermal_pause_time", 0.0))
    last = hold.copy() if include_last_action else None
    X, U = np.zeros((T, controller.dX)), np.zeros((T, dU))
    rewards, successes = [], []
    done, error = False, math.nan
    for t in range(T):
        X[t] = controller_state(env, last) if not done else X[t - 1]
        U[t] = controller.act(t, X[t], None if noise is None else noise[t])
        if t == T - 1 or done:
            continue
        applied = np.clip(U[t], -1.0, 1.0)
        _, reward, terminated, truncated, info = env.step(applied.astype(np.float32))
        rewards.append(float(reward))
        successes.append(bool(info.get("success", False)))
        error = float(info.get("goal_error", math.nan))
        last = applied if include_last_action else None
        done = bool(terminated or (truncated and t < T - 2))
    n = len(rewards)
    return Episode(
        X, U, np.asarray(rewards), np.asarray(successes, dtype=bool), error,
        n * control_period(env) + extra,
    )  # fmt: skip


# ----------------------------------------------------------------------------------------------
# Cost and initial controller


HALF_TURN_TOLERANCE = 0.25
"""Goals within this angle [rad] of a half turn from the start are reached turning positively."""


def object_target(theta0: float, goal: float, reference: float = math.nan) -> float:
    """The copy goal + 2 pi n [rad] the cost pulls the object angle to.

    Nearest to ``reference`` when it is finite; otherwise nearest to the start angle ``theta0``,
    except that a goal within HALF_TURN_TOLERANCE of a half turn is taken in the positive
    direction (a measured start angle a hair off zero must not flip a 180 deg goal).
    """
    if math.isfinite(reference):
        return reference + (goal - reference + math.pi) % (2 * math.pi) - math.pi
    d = (goal - theta0 + math.pi) % (2 * math.pi) - math.pi  # [-pi, pi)
    if d < -math.pi + HALF_TURN_TOLERANCE:
        d += 2 * math.pi
    return theta0 + d


def task_cost(
    env: gym.Env,
    start: FixedStart,
    hold: Array,
    cfg: TaskCostConfig,
    T: int,
    dX: int,
    demo_actions: Array | None = None,
) -> SumCost:
    """Quadratic cost of a goal-angle task over T steps, for states of size dX.

    The object target is the goal angle unwrapped by :func:`object_target` (for a moving goal,
    one target per step from ``task.advance_goal``, unwrapped continuously). The hand is kept near
    its start pose and the action near the one holding it; when ``cfg.hand_reference`` is "demo",
    near the demonstrated joint targets (:func:`demo_hand_reference`) and the mean demonstrated
    action instead.

    Args:
      demo_actions: (M, T, dU) demonstrated actions (NaN where an episode has ended), needed when
        ``cfg.hand_reference`` is "demo".

    Raises:
      ConfigError: if the task has no goal angle, or the demonstration is missing or misshaped.
    """
    base = env.unwrapped
    task = base.task
    if "angle" not in start.goal or not hasattr(task, "obj_qpos"):
        raise ConfigError(
            f"tvlg needs a goal-angle task (valve or screw); {env.spec.id if env.spec else env} has "
            f"goal keys {sorted(start.goal)}"
        )
    n_hand = len(task.hand_qpos)
    obj = 2 * n_hand  # state_vector: hand qpos, hand qvel, object qpos, object qvel
    goals = np.unwrap([float(task.advance_goal(start.goal, t)["angle"]) for t in range(T)])
    target = np.tile(np.concatenate([start.qpos[task.hand_qpos], np.zeros(dX - n_hand)]), (T, 1))
    action_target = hold
    if cfg.hand_reference == "demo":
        if demo_actions is None or demo_actions.shape[1:] != (T, len(hold)):
            raise ConfigError(
                f"cost hand_reference 'demo' needs demonstrated actions (M, T={T}, {len(hold)}), "
                f"got {None if demo_actions is None else demo_actions.shape}"
            )
        target[:, :n_hand] = demo_hand_reference(env, start, demo_actions)
        action_target = np.nanmean(np.clip(demo_actions, -1.0, 1.0), axis=0)
    target[:, obj] = (
        goals
        + object_target(float(start.qpos[task.obj_qpos]), goals[0], start.reference)
        - goals[0]
    )
    w_obj = np.zeros(dX)
    w_obj[obj] = 1.0
    w_hand = np.zeros(dX)
    w_hand[:n_hand] = cfg.pose_weight
    w_hand[n_hand : 2 * n_hand] = cfg.velocity_weight
    w_hand[obj + 1] = cfg.velocity_weight  # object velocity
    terms = [
        StateCost(target, w_hand, final_multiplier=cfg.final_multiplier),
        StateCost(
            target, w_obj, l2=cfg.object_weight, l1=cfg.object_l1, alpha=1e-2, ramp=cfg.ramp,
            final_multiplier=cfg.final_multiplier, final_steps=min(cfg.final_steps, T),
        ),
        ActionCost(cfg.action_weight * np.ones(len(hold)), target=action_target),
    ]  # fmt: skip
    return SumCost(terms)


def demo_hand_reference(env: gym.Env, start: FixedStart, demo_actions: Array) -> Array:
    """Hand joint reference (T, n_hand) [rad] from demonstrated actions (M, T, dU).

    The start pose at t = 0, then the joint targets of the mean demonstrated action of the step
    before (servos reach their targets within a control period unless a contact stops them).
    Steps no demonstration reaches (NaN) repeat the last reference.
    """
    task = env.unwrapped.task
    mean = np.nanmean(np.clip(demo_actions, -1.0, 1.0), axis=0)  # (T, dU)
    mid, half = 0.5 * (task.hand_high + task.hand_low), 0.5 * (task.hand_high - task.hand_low)
    ref = np.empty((mean.shape[0], len(task.hand_qpos)))
    ref[0] = start.qpos[task.hand_qpos]
    ref[1:] = mid + half * mean[:-1]
    for t in range(1, ref.shape[0]):
        if not np.all(np.isfinite(ref[t])):
            ref[t] = ref[t - 1]
    return ref


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
        demo_actions = _demo_actions(config.demos, T)
    k = ctl.k + np.nanmean(demo_actions, axis=0) - hold
    return LinearGaussianController.from_cov(ctl.K, k, ctl.cov)


def _demo_actions(path: str | None, T: int) -> Array:
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
        from lowcostdex.demonstrations.teachers.valve import ValveTurnTeacher
    except ImportError as exc:
        raise ConfigError(
            "init 'teacher' needs lowcostdex.demonstrations.teachers.valve (the valve teacher)"
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
    ex.Run.check(out_dir, dataclasses.asdict(config), resume=resume,
                 mutable_keys=MUTABLE_ON_RESUME)
    env = (env_factory or default_env_factory(config))()  # fails before anything is written
    run: ex.Run | None = None
    try:
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
                demo_actions = _demo_actions(config.demos, T)
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
    ex.atomic_write_bytes(path, buf.getvalue())


def load_controller(
    run_dir: str | Path,
) -> tuple[LinearGaussianController, FixedStart, TVLGTrainConfig]:
    """The final controller of a run directory, its start state and the run's config."""
    run_dir = Path(run_dir)
    config = TVLGTrainConfig.from_dict(ex.read_json(run_dir / ex.CONFIG_FILE))
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
    p.add_argument("--backend", choices=BACKENDS, default=d.backend)
    p.add_argument("--port", default=None, help="serial port of a real robot (hardware backend)")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its last checkpoint"
    )
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--n-iter", type=int, default=d.n_iter)
    p.add_argument("--n-rollouts", type=int, default=d.n_rollouts, help="episodes per iteration")
    p.add_argument("--init", choices=INITS, default=d.init)
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
    p.add_argument("--prior-strength", type=float, default=d.algo.dynamics.prior_strength)
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
    p.add_argument("--eval-every", type=int, default=d.eval_every)
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_run_command, parser=p)


def config_from_args(args: argparse.Namespace) -> TVLGTrainConfig:
    """Build a config from parsed ``lowcostdex train tvlg`` arguments."""
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
        backend=args.backend,
        env_kwargs={"port": args.port} if args.port else {},
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
    config = config_from_args(args)
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
    return 0
