"""Kinesthetic demonstrations, recorded the way the BAIR D'Claw work did, made cloneable.

Per episode: the env's auto-reset brings the hand and the valve to the episode's start (verified,
bounded); the finger servos go torque-off; a person moves the fingers through the task while the
joint angles and velocities are read at the control rate; the episode is converted to
(observation, action) pairs for BC/DAPG and appended to the demonstration dataset
(``lowcostdex.demonstrations.file``), one finished episode at a time.

Labels. The BAIR work paired o_t with the next joint position as a target, a_t = q_{t+1}
(``label="next_position"``). A position servo does not get there in one control period: the
D'Claw's XH430s on the emulated robot cover 30-70 % of a commanded step in 0.1 s.
``ServoResponse`` is a per-joint model of one control period of the servo,
q_{t+1} - q_t = alpha (g_t - q_t) + beta v_t dt + offset, identified on the robot itself in a few
seconds of random goals (``identify_servo_response``); ``servo_goal`` labels invert it,
g_t = q_t + (q_{t+1} - q_t - beta v_t dt - offset) / alpha: the goal that would have produced the
recorded step, from the measured positions and velocities only, clipped to the env's motion bound
and limits.

Playback. A clone of kinesthetic demonstrations alone rarely works, whatever the label: fingers
moved by a hand follow other dynamics than the same fingers driven by their servos, and the
clone's states leave the demonstrated ones at once (bench/RESULTS.md, "Behaviour cloning from
kinesthetic demonstrations": 0 % with next-position labels, ~13 % with servo-goal labels). After a
successful demonstration the recorder therefore plays its goals back ``playbacks`` times on the
robot, torque on, from the same auto-reset start, with uniform noise on every goal
(``playback_noise``, action units): the playbacks are the robot's own dynamics, labelled with the
clean goals that were sent, and the noise shows the clone the states beside the demonstrated path
together with the goal that leads back to it (DART, Laskey et al. 2017; the DAPG authors'
actuator noise). With two playbacks per demonstration the clone turned the valve in ~90 % of
deterministic episodes. Playbacks cost robot time, not the person's.

On the emulated D'Claw a ``VirtualTeacher`` stands in for the person: it moves the limp fingers
with external joint torques (a PD on ``qfrc_applied``, applied before every physics step of the
emulator) along a scripted solving motion (``lowcostdex.teachers.valve.ValveTurnTeacher``) with a
person's imprecision, so the same recorder code path produces demonstrations without a human.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.demonstrations.file import (
    DatasetInfo,
    DemoWriter,
    Episode,
)
from lowcostdex.errors import ConfigError, keyword_hints
from lowcostdex.motion import motion_bound
from lowcostdex.sim.envs.hand_env import goal_to_action

log = logging.getLogger(__name__)

__all__ = ["FIRM_HAND", "KinestheticRecorder", "RecordingStats", "ServoResponse",
           "VirtualTeacher", "VirtualTeacherConfig", "episode_from_states",
           "identify_servo_response", "servo_goal_labels", "virtual_teacher_config"]


# ------------------------------------------------------------------------------------------------
# servo response and labels


@dataclass(frozen=True)
class ServoResponse:
    """One control period of a position servo, per joint, as a linear model:

        q_{t+1} - q_t = alpha * (g_t - q_t) + beta * v_t * period + offset

    with q, v the measured joint position [rad] and velocity [rad/s] at a control tick and g the
    goal sent then [rad]. alpha is the fraction of a commanded step covered in one period, beta
    the carried-over motion, offset a steady bias (gravity, friction).

    Attributes:
      alpha, beta, offset: per joint, in action order (offset [rad]).
      period: control period [s].
      r2: coefficient of determination of each joint's fit (documentation; empty if not fitted).
    """

    alpha: tuple[float, ...]
    beta: tuple[float, ...]
    offset: tuple[float, ...]
    period: float
    r2: tuple[float, ...] = ()

    MIN_ALPHA = 0.05

    def __post_init__(self) -> None:
        n = len(self.alpha)
        if n == 0 or len(self.beta) != n or len(self.offset) != n:
            raise ConfigError(f"ServoResponse needs alpha, beta and offset of one length, got "
                              f"{len(self.alpha)}, {len(self.beta)}, {len(self.offset)}")
        if min(self.alpha) < self.MIN_ALPHA:
            raise ConfigError(f"ServoResponse alpha {self.alpha} must be >= {self.MIN_ALPHA}: the "
                              "servo must cover a share of a commanded step in one period")
        if not self.period > 0:
            raise ConfigError(f"ServoResponse period {self.period} must be > 0 [s]")

    def predict(self, q: np.ndarray, v: np.ndarray, g: np.ndarray) -> np.ndarray:
        """Positions (..., n) [rad] one period after sending goals g from state (q, v)."""
        a, b, c = (np.asarray(x, float) for x in (self.alpha, self.beta, self.offset))
        return q + a * (g - q) + b * v * self.period + c

    def goal(self, q: np.ndarray, v: np.ndarray, q_next: np.ndarray) -> np.ndarray:
        """The goals (..., n) [rad] that move the servo from (q, v) to q_next (the inverse of
        ``predict``; not clipped)."""
        a, b, c = (np.asarray(x, float) for x in (self.alpha, self.beta, self.offset))
        return q + (q_next - q - b * v * self.period - c) / a

    @classmethod
    def fit(cls, q: np.ndarray, v: np.ndarray, g: np.ndarray, q_next: np.ndarray,
            period: float) -> ServoResponse:
        """Least-squares fit per joint from transitions (N, n) each: positions, velocities,
        goals sent, positions one period later.

        Raises:
          ConfigError: too few transitions, or a joint that did not respond (alpha below
            ``MIN_ALPHA``: e.g. torque off or the joint never moved).
        """
        q, v, g, q_next = (np.asarray(x, float) for x in (q, v, g, q_next))
        if q.ndim != 2 or len(q) < 4 * 3:
            raise ConfigError(f"ServoResponse.fit needs (N, n) transitions with N >= 12, got "
                              f"{q.shape}")
        alpha, beta, offset, r2 = [], [], [], []
        for j in range(q.shape[1]):
            x = np.column_stack([g[:, j] - q[:, j], v[:, j] * period, np.ones(len(q))])
            y = q_next[:, j] - q[:, j]
            coef, *_ = np.linalg.lstsq(x, y, rcond=None)
            resid = y - x @ coef
            alpha.append(float(coef[0]))
            beta.append(float(coef[1]))
            offset.append(float(coef[2]))
            r2.append(float(1.0 - resid.var() / max(y.var(), 1e-12)))
        if min(alpha) < cls.MIN_ALPHA:
            raise ConfigError(f"a joint did not follow its goals (alpha {np.round(alpha, 3)}); "
                              "are the servos torque-on and free to move?")
        return cls(tuple(alpha), tuple(beta), tuple(offset), float(period), tuple(r2))

    def to_dict(self) -> dict:
        return {"model": "linear_servo_response", "alpha": list(self.alpha),
                "beta": list(self.beta), "offset": list(self.offset), "period": self.period,
                "r2": list(self.r2)}

    @classmethod
    def from_dict(cls, d: dict) -> ServoResponse:
        return cls(tuple(d["alpha"]), tuple(d["beta"]), tuple(d["offset"]), float(d["period"]),
                   tuple(d.get("r2", ())))


def servo_goal_labels(task: Any, qpos: np.ndarray, qvel: np.ndarray, response: ServoResponse,
                      max_step: np.ndarray) -> np.ndarray:
    """``servo_goal`` actions (T, n) for recorded states: the goals that would have produced the
    recorded motion, clipped as the env clips actions.

    Args:
      task: the bound task (hand joint layout and limits).
      qpos: (T+1, nq) states at the control ticks; qvel: (T+1, nv).
      response: the servo model.
      max_step: (n,) per-step motion bound [rad] (the env's, ``HandEnv.max_step``).
    """
    q = np.asarray(qpos, float)[:, task.hand_qpos]
    v = np.asarray(qvel, float)[:, task.hand_dof]
    g = response.goal(q[:-1], v[:-1], q[1:])
    g = np.clip(g, q[:-1] - max_step, q[:-1] + max_step)
    return goal_to_action(g, task.hand_low, task.hand_high)  # clipped to the limits there


def identify_servo_response(env: Any, episodes: int = 4, seed: int = 0,
                            on_episode: Callable[[int], None] | None = None,
                            limits: tuple[np.ndarray, np.ndarray] | None = None
                            ) -> tuple[ServoResponse, float]:
    """Fit the hand's ``ServoResponse`` on the robot: ``episodes`` episodes of smooth random goals
    (servos on, the env's own safety and motion bound), about 4 s of motion each.

    Args:
      env: a robot-backed hand env (``backend="emulated"`` or ``"hardware"``) or a sim env.
      episodes: excitation episodes.
      seed: seed of the excitation and of the resets (seed, seed + 1, ...).
      on_episode: called with the episode index after each.
      limits: (low, high) joint goals [rad] (n,) each, the box the random goals stay in;
        default the task's ``identification_limits`` (e.g. the flip block's: fingers clear of
        the block, which full-range goals knock away), else the whole action range.

    Returns:
      (the fitted response, robot time spent [s] including the auto-resets; 0 in sim).
    """
    henv = env.unwrapped
    backend = henv.backend
    robot = getattr(backend, "robot", None)
    start = robot.clock.now() if robot is not None else 0.0
    rng = np.random.default_rng(seed)
    n = int(np.prod(env.action_space.shape))
    task = henv.task
    steps = task.timing.episode_steps
    limits = limits if limits is not None else getattr(task, "identification_limits", None)
    low, high = -np.ones(n), np.ones(n)
    if limits is not None:
        low, high = (goal_to_action(np.asarray(x, float), task.hand_low, task.hand_high)
                     for x in limits)
    q, v, g, q_next = [], [], [], []
    for k in range(episodes):
        env.reset(seed=seed + k)
        a = 0.5 * (low + high)
        for _ in range(steps):
            q0 = henv.data.qpos[task.hand_qpos].copy()
            v0 = henv.data.qvel[task.hand_dof].copy()
            jump = (rng.random(n) < 0.2) * rng.uniform(-0.5, 0.5, n) * 0.5 * (high - low)
            a = np.clip(0.7 * a + 0.3 * rng.uniform(low, high) + jump, low, high)
            _, _, terminated, truncated, info = env.step(a.astype(env.action_space.dtype))
            q.append(q0)
            v.append(v0)
            g.append(np.asarray(info["goal"], float))
            q_next.append(henv.data.qpos[task.hand_qpos].copy())
            if terminated or truncated:
                break
        if on_episode is not None:
            on_episode(k)
    seconds = robot.clock.now() - start if robot is not None else 0.0
    return ServoResponse.fit(np.array(q), np.array(v), np.array(g), np.array(q_next),
                             float(henv.control_period)), seconds


# ------------------------------------------------------------------------------------------------
# conversion


def episode_from_states(task: Any, qpos: np.ndarray, qvel: np.ndarray, goal: dict,
                        time: np.ndarray, actions: np.ndarray | None = None,
                        label: str = "next_position", **meta: Any) -> Episode:
    """Turn recorded states into an ``Episode`` of (observation, action) pairs.

    Args:
      task: the bound task (observation, reward, success, goal schedule).
      qpos: (T+1, nq) mirror states at the control ticks [rad].
      qvel: (T+1, nv).
      goal: the episode's goal at step 0 (moving goals advance with ``task.advance_goal``).
      time: (T+1,) clock times [s].
      actions: (T, n) labels in the env's action space; default the next joint positions,
        a_t = goal_to_action(q_{t+1}).
      label: what ``actions`` are (``lowcostdex.demonstrations.file.LABELS``).
      meta: ``Episode`` fields (seed, reset_time, reset_attempts, source).

    Returns:
      Episode with o_t = observation(state_t, goal_t, a_{t-1}) (a_{-1} = 0, as after an env
      reset), r_t and success_t of the state after the action.
    """
    qpos, qvel = np.asarray(qpos, float), np.asarray(qvel, float)
    steps = len(qpos) - 1
    if actions is None:
        q = qpos[:, task.hand_qpos]
        actions = goal_to_action(q[1:], task.hand_low, task.hand_high)  # (T, n)
    actions = np.asarray(actions, float)
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
                   terminated=terminated, label=label, **meta)


# ------------------------------------------------------------------------------------------------
# virtual teacher (emulated robot only)


@keyword_hints
@dataclass(frozen=True)
class VirtualTeacherConfig:
    """The virtual person's hand on the emulated fingers.

    Attributes:
      kp: stiffness of the pull toward the solving motion [N m/rad].
      kd: damping [N m s/rad].
      max_torque: largest torque a finger joint receives [N m].
      plan_period: how often the solving motion is re-planned from the true state [s].
      motion_bound: keep each planned target within the env's per-step motion bound of the
        present joint positions (``motion.motion_bound`` over ``plan_period``) and the limits,
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


FIRM_HAND = VirtualTeacherConfig(kp=10.0, kd=0.5, max_torque=3.0)
"""The virtual person's hand for the D'Claw teachers (valve, screw, block flip). Block flip: with
the soft default (kp 3 N m/rad) the carry crept at 1-2 mm per control step against the emulated
joints' friction and 4 of 10 flips succeeded, with this one 8 of 10. Valve at ROBEL's spoke
phase: one finger pushes at a time for part of the turn, and under the soft hand a single finger
turned the valve ~5-8 deg per step (three fingers ~22): the demonstrations ended 9 deg short
(0/6), with this hand 6/6 (emulated D'Claw, default effects; bench/RESULTS.md)."""

FIRM_SOLVERS = ("FlipBlockTeacher", "PinchFlipTeacher", "ValveTurnTeacher", "ScrewTrackTeacher")
"""Scripted solvers moved by ``FIRM_HAND``; any other (the Allegro's) by the default hand."""


def virtual_teacher_config(solver: Any) -> VirtualTeacherConfig:
    """The virtual person's hand for a scripted solver: ``FIRM_HAND`` for the D'Claw teachers
    (``FIRM_SOLVERS``), the default otherwise."""
    return FIRM_HAND if type(solver).__name__ in FIRM_SOLVERS else VirtualTeacherConfig()


class VirtualTeacher:
    """Moves an emulated D'Claw's fingers with external torques along a scripted motion.

    Args:
      chain: the ``EmulatedChain`` (its plant gets the torques; registered as a step hook).
      task: the bound task (its model has the chain's qpos layout).
      solver: (qpos (nq,), goal) -> finger joint targets (9,) [rad]; ``reset(task)`` is called at
        every episode start if it has one. Default: ``ValveTurnTeacher``.
      config: PD gains, re-planning period, motion bound, imprecision (default:
        ``virtual_teacher_config(solver)``).
      rng: generator of the imprecision noise (seeded by the caller).
    """

    def __init__(self, chain: Any, task: Any, solver: Any = None,
                 config: VirtualTeacherConfig | None = None,
                 rng: np.random.Generator | None = None):
        plant = chain.plant
        if plant.model.nq != task.model.nq:
            raise ConfigError("the emulator's model and the task's model differ in qpos layout")
        if solver is None:
            from lowcostdex.teachers.valve import ValveTurnTeacher

            solver = ValveTurnTeacher()
        if config is None:
            config = virtual_teacher_config(solver)
        self.chain, self.task, self.solver, self.config = chain, task, solver, config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        m = plant.model
        self.dofs = np.array([m.jnt_dofadr[m.joint(n).id] for n in task.hand.joint_names])
        self.qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in task.hand.joint_names])
        joints = task.hand.joints
        self.low = np.array([j.low for j in joints])
        self.high = np.array([j.high for j in joints])
        self.max_step = motion_bound(task.hand, config.plan_period, task.model.nu)
        self.goal: dict | None = None
        self.target: np.ndarray | None = None
        self._next_plan = -math.inf
        self._start_time = 0.0
        # control period [s]: a moving goal (the screw's) advances once per period, as in the env
        self._period = task.timing.frame_skip * task.model.opt.timestep
        chain.add_step_hook(self._hook)

    def start(self, goal: dict) -> None:
        """Begin demonstrating toward ``goal`` (the episode's task goal at step 0; a moving goal
        advances with ``task.advance_goal`` once per control period from now)."""
        if hasattr(self.solver, "reset"):
            self.solver.reset(self.task)
        self.goal = {k: np.asarray(v, float) for k, v in goal.items()}
        self.target = None
        self._next_plan = -math.inf
        self._start_time = self.chain.physics_time

    def goal_at(self, t: float) -> dict:
        """The task goal at physics time ``t`` [s]: the start goal advanced by the whole control
        periods elapsed since ``start``."""
        step = max(0, math.floor((t - self._start_time) / self._period + 1e-9))
        return self.task.advance_goal(self.goal, step)

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
            target = np.asarray(self.solver(d.qpos.copy(), self.goal_at(t)), float)
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
      reset_time: total auto-reset time [s] of the demonstrations.
      record_time: total demonstration time [s].
      playbacks: playback episodes written; playback_successes: of which succeeded.
      playback_time: robot time of the playbacks, their auto-resets included [s].
    """

    episodes: int = 0
    successes: int = 0
    steps: int = 0
    reset_time: float = 0.0
    record_time: float = 0.0
    playbacks: int = 0
    playback_successes: int = 0
    playback_time: float = 0.0


class KinestheticRecorder:
    """Records demonstrations on a robot-backed ``HandEnv`` (``backend="emulated"`` or
    ``"hardware"``) into a demo file.

    Args:
      env: the env (``gym.make(..., backend=...)``; wrappers are looked through).
      path: the HDF5 file (appended to if it exists).
      env_id: the gymnasium id, stored in the file.
      teacher: a ``VirtualTeacher`` on the emulated robot; None for a person.
      steps: recorded control steps per episode (default the task's episode length).
      on_episode: called with (episode index, Episode) after each write (progress display),
        playbacks included.
      response: the robot's ``ServoResponse`` (``identify_servo_response``): demonstrations are
        labelled ``servo_goal`` and the model is stored in the file; None labels them with the
        next position (BAIR's labels) and allows no playbacks.
      playbacks: after each successful demonstration, play its servo goals back on the robot this
        many times (torque on, noisy goals; see the module docstring) and write each playback
        as an episode (source ``playback``, label ``commanded``).
      playback_noise: half-width of the uniform noise on each played-back goal, in action units
        (the DAPG authors' actuator noise was +-0.1 rad, ~0.05-0.1 of the D'Claw's ranges).
      rng: generator of the playback noise (seeded by the caller).
    """

    def __init__(self, env: Any, path: str | Path, env_id: str,
                 teacher: VirtualTeacher | None = None, steps: int | None = None,
                 on_episode: Callable[[int, Episode], None] | None = None,
                 response: ServoResponse | None = None, playbacks: int = 0,
                 playback_noise: float = 0.05, rng: np.random.Generator | None = None):
        self.env = env
        self.henv = env.unwrapped
        backend = self.henv.backend
        if not getattr(backend, "real_time", False) or not hasattr(backend, "robot"):
            raise ConfigError("kinesthetic recording needs a robot backend ('emulated' or "
                              f"'hardware'), got {type(backend).__name__}")
        if playbacks < 0 or playback_noise < 0:
            raise ConfigError(f"playbacks={playbacks} and playback_noise={playback_noise} must "
                              "be >= 0")
        if playbacks and response is None:
            raise ConfigError("playbacks need the servo response (identify_servo_response): "
                              "next-position labels are not goals the servos can play back")
        n = int(np.prod(env.action_space.shape))
        if response is not None and len(response.alpha) != n:
            raise ConfigError(f"the servo response has {len(response.alpha)} joints, the env "
                              f"{n} actions")
        self.backend = backend
        self.task = self.henv.task
        self.teacher = teacher
        self.steps = steps or self.task.timing.episode_steps
        self.response, self.playbacks, self.playback_noise = response, playbacks, playback_noise
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.max_step = self.henv.max_step  # the labels are clipped as the env clips goals
        source = "virtual_teacher" if teacher is not None else "kinesthetic"
        self.writer = DemoWriter(path, DatasetInfo.from_env(env, source, env_id=env_id),
                                 label_model=response.to_dict() if response else None)
        self.on_episode = on_episode
        self.stats = RecordingStats()

    def record_episode(self, seed: int) -> Episode:
        """Auto-reset, record one demonstration, append it to the file, then its playbacks if
        it succeeded; returns the demonstration."""
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
        qpos, qvel = np.array(qpos), np.array(qvel)
        actions, label = None, "next_position"
        if self.response is not None:
            actions = servo_goal_labels(self.task, qpos, qvel, self.response, self.max_step)
            label = "servo_goal"
        ep = episode_from_states(self.task, qpos, qvel, goal, np.array(times), actions=actions,
                                 label=label, seed=seed,
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
        if ep.length and ep.success[-1]:
            for _ in range(self.playbacks):
                self.play_back(ep)
        return ep

    def play_back(self, demo: Episode) -> Episode:
        """Play a demonstration's goals back on the robot (torque on, from the same auto-reset
        start, with ``playback_noise`` on every goal) and append the playback as an episode
        labelled with the clean goals; returns it."""
        from lowcostdex.demonstrations.dataset import EpisodeRecorder

        robot = self.backend.robot
        start = robot.clock.now()
        obs, info = self.env.reset(seed=demo.seed)
        rec = EpisodeRecorder(self.env, obs, info, demo.seed)
        for a in demo.actions:
            noise = self.rng.uniform(-self.playback_noise, self.playback_noise, a.shape)
            executed = np.clip(a + noise, -1.0, 1.0).astype(self.env.action_space.dtype)
            obs, reward, terminated, truncated, info = self.env.step(executed)
            rec.step(a, obs, reward, terminated, info)
            if terminated or truncated:
                break
        ep = dataclasses.replace(rec.episode(), source="playback", label="commanded")
        k = self.writer.append(ep)
        s = self.stats
        s.playbacks += 1
        s.playback_successes += int(ep.success[-1]) if ep.length else 0
        s.playback_time += robot.clock.now() - start
        if self.on_episode is not None:
            self.on_episode(k, ep)
        return ep

    def record(self, episodes: int, seed: int = 0, successes: int | None = None
               ) -> RecordingStats:
        """Record ``episodes`` demonstrations with seeds seed, seed + 1, ...; with
        ``successes``, stop as soon as that many of them succeeded (``episodes`` is then the
        most that are tried)."""
        for k in range(episodes):
            if successes is not None and self.stats.successes >= successes:
                break
            self.record_episode(seed + k)
        return self.stats
