"""Kinesthetic demonstrations, recorded the way the BAIR D'Claw work did.

Per episode: the env's auto-reset brings the hand and the valve to the episode's start (verified,
bounded); the finger servos go torque-off; a person moves the fingers through the task while the
joint angles are read at the control rate; the episode is converted to (observation, action)
pairs for BC/DAPG and appended to the demonstration dataset (``lowcostdex.demo_file``), one
finished episode at a time.

The action paired with the observation at step t is the next joint position as a target,
normalized as the env's actions are: ``a_t = goal_to_action(q_{t+1})``; the observation is
the task's own, built from the mirror (hand joints, valve angle, goal, previous action).

On the emulated D'Claw a ``VirtualTeacher`` stands in for the person: it moves the limp fingers
with external joint torques (a PD on ``qfrc_applied``, applied before every physics step of the
emulator) along a scripted solving motion (``lowcostdex.sim.scripted.ValveTurnTeacher``), so the
same recorder code path produces demonstrations without a human.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.demo_file import (
    DatasetInfo,
    DemoWriter,
    Episode,
    read_demo_pairs,
    read_episodes,
)
from lowcostdex.sim.envs.hand_env import goal_to_action

log = logging.getLogger(__name__)

__all__ = ["KinestheticRecorder", "RecordingStats", "VirtualTeacher", "VirtualTeacherConfig",
           "episode_from_states", "read_demo_pairs", "read_episodes"]


# ------------------------------------------------------------------------------------------------
# conversion


def episode_from_states(task: Any, qpos: np.ndarray, qvel: np.ndarray, goal: dict,
                        time: np.ndarray, **meta: Any) -> Episode:
    """Turn recorded states into an ``Episode`` of (observation, action) pairs.

    Args:
      task: the bound task (observation, reward, success, goal schedule).
      qpos: (T+1, nq) mirror states at the control ticks [rad].
      qvel: (T+1, nv).
      goal: the episode's goal at step 0 (moving goals advance with ``task.advance_goal``).
      time: (T+1,) clock times [s].
      meta: ``Episode`` fields (seed, reset_time, reset_attempts).

    Returns:
      Episode with a_t = goal_to_action(q_{t+1}), o_t = observation(state_t, goal_t, a_{t-1})
      (a_{-1} = 0, as after an env reset), r_t and success_t of the state after the action.
    """
    qpos, qvel = np.asarray(qpos, float), np.asarray(qvel, float)
    steps = len(qpos) - 1
    q = qpos[:, task.hand_qpos]
    actions = goal_to_action(q[1:], task.hand_low, task.hand_high)  # (T, n)
    goals = [goal]
    for t in range(1, steps + 1):
        goals.append(task.advance_goal(goal, t))
    prev = np.vstack([np.zeros((1, actions.shape[1])), actions])  # a_{t-1}, (T+1, n)
    obs = np.stack([task.observation(qpos[t], qvel[t], goals[t], prev[t])
                    for t in range(steps + 1)])
    rewards = np.array([sum(float(v) for v in task.reward_terms(
        qpos[t + 1], qvel[t + 1], goals[t + 1], actions[t]).values()) for t in range(steps)])
    success = np.array([bool(task.success(qpos[t + 1], goals[t + 1])) for t in range(steps)],
                       dtype=bool)
    terminated = bool(steps and task.terminated(qpos[-1], goals[-1]))
    return Episode(obs, actions, rewards, qpos, qvel, np.asarray(time, float), success,
                   goal={k: np.asarray(v, float) for k, v in goal.items()},
                   terminated=terminated, **meta)


# ------------------------------------------------------------------------------------------------
# virtual teacher (emulated robot only)


@dataclass(frozen=True)
class VirtualTeacherConfig:
    """The virtual person's hand on the emulated fingers.

    Attributes:
      kp: stiffness of the pull toward the solving motion [N m/rad].
      kd: damping [N m s/rad].
      max_torque: largest torque a finger joint receives [N m].
      plan_period: how often the solving motion is re-planned from the true state [s].
      motion_bound: keep each planned target within the env's per-step motion bound of the
        present joint positions (joint ``max_velocity`` x ``plan_period``) and the joint limits,
        as the env does with actions. A person can move the fingers faster than a policy may,
        and a transition no action can produce cannot be cloned (unbounded, the teacher moved
        middle joints 0.33 rad in one 0.1 s step where the env allows 0.21).
      target_noise: std of Gaussian noise added to each planned target [rad], like a person's
        imprecision: the demonstrations then visit states around the solving motion and show
        the teacher recovering from them (the data DART and the DAPG authors' actuator noise
        give a behaviour clone). The recorded actions are the executed motion, noise included.
    """

    kp: float = 3.0
    kd: float = 0.15
    max_torque: float = 1.5
    plan_period: float = 0.1
    motion_bound: bool = True
    target_noise: float = 0.0

    def __post_init__(self) -> None:
        for name in ("kp", "kd", "max_torque", "plan_period"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"VirtualTeacherConfig.{name} must be > 0")
        if self.target_noise < 0:
            raise ConfigError("VirtualTeacherConfig.target_noise must be >= 0")


class VirtualTeacher:
    """Moves an emulated D'Claw's fingers with external torques along a scripted motion.

    Args:
      chain: the ``EmulatedChain`` (its plant gets the torques; registered as a step hook).
      task: the bound task (its model has the chain's qpos layout).
      solver: (qpos (nq,), goal) -> finger joint targets (9,) [rad]; ``reset(task)`` is called at
        every episode start if it has one. Default: ``ValveTurnTeacher``.
      config: PD gains, re-planning period, motion bound, imprecision.
      rng: generator of the imprecision noise (seeded by the caller).
    """

    def __init__(self, chain: Any, task: Any, solver: Any = None,
                 config: VirtualTeacherConfig = VirtualTeacherConfig(),
                 rng: np.random.Generator | None = None):
        plant = chain.plant
        if plant.model.nq != task.model.nq:
            raise ConfigError("the emulator's model and the task's model differ in qpos layout")
        if solver is None:
            from lowcostdex.sim.scripted import ValveTurnTeacher

            solver = ValveTurnTeacher()
        self.chain, self.task, self.solver, self.config = chain, task, solver, config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        m = plant.model
        self.dofs = np.array([m.jnt_dofadr[m.joint(n).id] for n in task.hand.joint_names])
        self.qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in task.hand.joint_names])
        joints = task.hand.joints
        self.low = np.array([j.low for j in joints])
        self.high = np.array([j.high for j in joints])
        self.max_step = np.array([j.max_velocity for j in joints]) * config.plan_period
        self.goal: dict | None = None
        self.target: np.ndarray | None = None
        self._next_plan = -math.inf
        chain.add_step_hook(self._hook)

    def start(self, goal: dict) -> None:
        """Begin demonstrating toward ``goal`` (the episode's task goal)."""
        if hasattr(self.solver, "reset"):
            self.solver.reset(self.task)
        self.goal = {k: np.asarray(v, float) for k, v in goal.items()}
        self.target = None
        self._next_plan = -math.inf

    def stop(self) -> None:
        """Let go of the fingers."""
        self.goal = None
        self.chain.plant.data.qfrc_applied[self.dofs] = 0.0

    def _hook(self, chain: Any) -> None:
        if self.goal is None:
            return
        d = chain.plant.data
        t = chain.physics_time
        if t >= self._next_plan - 1e-12:
            target = np.asarray(self.solver(d.qpos.copy(), self.goal), float)
            if self.config.target_noise > 0:
                target = target + self.config.target_noise * self.rng.normal(size=target.shape)
            if self.config.motion_bound:
                present = d.qpos[self.qadr]
                target = np.clip(np.clip(target, present - self.max_step,
                                         present + self.max_step), self.low, self.high)
            self.target = target
            self._next_plan = t + self.config.plan_period
        c = self.config
        tau = c.kp * (self.target - d.qpos[self.qadr]) - c.kd * d.qvel[self.dofs]
        d.qfrc_applied[self.dofs] = np.clip(tau, -c.max_torque, c.max_torque)


# ------------------------------------------------------------------------------------------------
# recorder


@dataclass
class RecordingStats:
    """Totals of a recording session.

    Attributes:
      episodes: episodes written.
      successes: of which ended in task success.
      steps: transitions written.
      reset_time: total auto-reset time [s].
      record_time: total demonstration time [s].
    """

    episodes: int = 0
    successes: int = 0
    steps: int = 0
    reset_time: float = 0.0
    record_time: float = 0.0


class KinestheticRecorder:
    """Records demonstrations on a robot-backed ``HandEnv`` (``backend="emulated"`` or
    ``"hardware"``) into a demo file.

    Args:
      env: the env (``gym.make(..., backend=...)``; wrappers are looked through).
      path: the HDF5 file (appended to if it exists).
      env_id: the gymnasium id, stored in the file.
      teacher: a ``VirtualTeacher`` on the emulated robot; None for a person.
      steps: recorded control steps per episode (default the task's episode length).
      on_episode: called with (episode index, Episode) after each write (progress display).
    """

    def __init__(self, env: Any, path: str | Path, env_id: str,
                 teacher: VirtualTeacher | None = None, steps: int | None = None,
                 on_episode: Callable[[int, Episode], None] | None = None):
        self.env = env
        self.henv = env.unwrapped
        backend = self.henv.backend
        if not getattr(backend, "real_time", False) or not hasattr(backend, "robot"):
            raise ConfigError("kinesthetic recording needs a robot backend ('emulated' or "
                              f"'hardware'), got {type(backend).__name__}")
        self.backend = backend
        self.task = self.henv.task
        self.teacher = teacher
        self.steps = steps or self.task.timing.episode_steps
        source = "virtual_teacher" if teacher is not None else "kinesthetic"
        self.writer = DemoWriter(path, DatasetInfo.from_env(env, source, env_id=env_id))
        self.on_episode = on_episode
        self.stats = RecordingStats()

    def record_episode(self, seed: int) -> Episode:
        """Auto-reset, record one demonstration, append it to the file; returns it."""
        robot = self.backend.robot
        self.env.reset(seed=seed)
        goal = {k: np.asarray(v, float) for k, v in self.henv.goal.items()}
        report = self.backend.last_reset
        robot.torque(False, self.task.hand.joint_names)  # the fingers are the teacher's now
        if self.teacher is not None:
            self.teacher.start(goal)
        qpos, qvel, times = [self.henv.data.qpos.copy()], [self.henv.data.qvel.copy()], \
            [robot.clock.now()]
        start = robot.clock.now()
        robot.rate.restart()
        try:
            for _ in range(self.steps):
                self.backend.passive_step()
                qpos.append(self.henv.data.qpos.copy())
                qvel.append(self.henv.data.qvel.copy())
                times.append(robot.clock.now())
        finally:
            if self.teacher is not None:
                self.teacher.stop()
        ep = episode_from_states(self.task, np.array(qpos), np.array(qvel), goal,
                                 np.array(times), seed=seed,
                                 reset_time=report.duration if report else float("nan"),
                                 reset_attempts=report.attempts if report else 0)
        k = self.writer.append(ep)
        s = self.stats
        s.episodes += 1
        s.successes += int(ep.success[-1]) if ep.length else 0
        s.steps += ep.length
        s.reset_time += report.duration if report else 0.0
        s.record_time += robot.clock.now() - start
        if self.on_episode is not None:
            self.on_episode(k, ep)
        return ep

    def record(self, episodes: int, seed: int = 0) -> RecordingStats:
        """Record ``episodes`` demonstrations with seeds seed, seed + 1, ..."""
        for k in range(episodes):
            self.record_episode(seed + k)
        return self.stats
