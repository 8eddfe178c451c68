"""A flip teacher that is a function of the observation (issue 15 item 1), measured beside
``FlipBlockTeacher``: its success in simulation and the success of a behaviour clone of 10 of
its demonstrations.

``FlipBlockTeacher`` keeps state between calls (roll count, stage counters, the block's last
position, the start orientation), so a policy, which sees only the observation, cannot copy
it: in the 2026-11-26 morning session the clone of 10 of its demos flipped 2 of 40 against the
teacher's 20-26 of 40. ``MarkovFlipTeacher`` takes the same motions but reads every decision
from the present state: the roll still to go from the goal's orientation (the observation's
goal), the present roll's progress from the block's tilt, push/approach/down from where the
pusher's tip is relative to the block's back face, carry/roll from the block's place along the
roll direction and whether the carriers are low at its front face. It keeps no state that
changes its actions (``rolls`` is for reports only). It is not the package's teacher: it flips
fewer blocks than ``FlipBlockTeacher`` (bench/RESULTS.md, "A Markov flip teacher").

    python bench/flip_markov.py --teacher-episodes 40 --clone-episodes 40
    python bench/flip_markov.py --teachers PlannedFlipTeacher     # the planned teacher (2026-11-27)
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch

import lowcostdex  # noqa: F401  (registers the env ids)
from lowcostdex.algos.bc import behavior_clone, set_from_demos
from lowcostdex.algos.configs import TrainConfig
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.demonstrations.dataset import teacher_episodes
from lowcostdex.hands import DCLAW_FINGERS
from lowcostdex.sim.envs import goal_to_action
from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE, quat_rotate
from lowcostdex.sim.envs.task import Goal
from lowcostdex.sim.kinematics import FingerGeometry
from lowcostdex.sim.models.dclaw import BLOCK_HALF
from lowcostdex.stats import wilson_interval
from lowcostdex.teachers.binding import bound_task, check_call
from lowcostdex.teachers.flip import (
    CARRY,
    DONE,
    ROLL,
    UP,
    FlipBlockTeacher,
    FlipTeacherConfig,
    _conj,
    _mul,
)
from lowcostdex.teachers.flip_plan import PlannedFlipTeacher

ENV = "lowcostdex/DClawFlipBlock-v0"
TRAINER_BC = next(f for f in dataclasses.fields(TrainConfig) if f.name == "bc").default_factory()
"""The DAPG trainer's BC settings (100 epochs, residual log-std), as ``train dapg`` clones."""
HELD_OUT = 50_000  # reset seeds of the clone's evaluation (the demos use 10 000 on)


@dataclass(frozen=True)
class MarkovFlipConfig(FlipTeacherConfig):
    """``FlipTeacherConfig`` plus the thresholds that replace its timers (lengths [m], angles
    [rad]): ``contact_tol`` how far above the back face's top edge the pusher's tip may be and
    still push; ``engaged``/``engaged_high`` the window (along d / in height) in which a carrier's
    tip counts as low at the block's front face; ``carry_angle`` the largest forward tilt at
    which a resting block may be carried; ``carry_center_gain`` the carriers' sideways steer
    per m of the block's offset from home along the axis."""

    carry_tol: float = 0.010
    contact_tol: float = 0.003
    engaged: float = 0.008
    engaged_high: float = 0.02
    carry_angle: float = 0.15
    carry_center_gain: float = 0.5


class MarkovFlipTeacher(FlipBlockTeacher):
    """The flip teacher as a function of (qpos, goal): see the module docstring."""

    def __init__(self, config: MarkovFlipConfig = MarkovFlipConfig()):
        super().__init__(config)

    def reset(self, task_or_env: Any, goal: Goal | None = None) -> None:
        """Bind to a task's model (``goal`` is unused; each call reads its own)."""
        task = bound_task(task_or_env, type(self).__name__, "dclaw",
                          "the D'Claw's flip-block tasks", attributes=("block_pos", "block_quat"))
        self._nq = task.model.nq
        self.hand_qpos = task.hand_qpos
        self.block_pos, self.block_quat = task.block_pos, task.block_quat
        self.low, self.high = task.hand_low.reshape(3, 3), task.hand_high.reshape(3, 3)
        self.fingers = [FingerGeometry.from_model(task.model, f) for f in DCLAW_FINGERS]
        self.pusher = DCLAW_FINGERS.index(self.config.pusher)
        self.carriers = [DCLAW_FINGERS.index(f) for f in self.config.carriers]
        axis = np.asarray(task.config.flip_axis, float)
        self.axis = axis / np.linalg.norm(axis)
        self.d = np.cross(self.axis, UP)
        self.d /= np.linalg.norm(self.d)
        self.h, self.r = BLOCK_HALF, self.fingers[0].tip_radius
        self.flip_quat = np.array([0.0, *self.axis])  # 180 deg about the axis
        self._default_goal: np.ndarray | None = None
        self._rolls_at_start: int | None = None
        self.rolls, self.phase, self.stage = 0, ROLL, "approach"

    @property
    def done(self) -> bool:
        """The last call found the block within ``settle_angle`` of the goal's orientation."""
        return self.phase == DONE

    # -- measurements -----------------------------------------------------------------------
    def remaining(self, quat: np.ndarray, goal_quat: np.ndarray) -> float:
        """Roll [rad] about the flip axis (in the roll direction) still to go from ``quat`` to
        ``goal_quat``, measured on the goal's up face (insensitive to yaw), in
        [-settle_angle, 2 pi - settle_angle)."""
        u = quat_rotate(_mul(quat, _conj(goal_quat)), UP[None])[0]
        rem = (-math.atan2(float(u @ self.d), float(u[2]))) % (2 * math.pi)
        s = self.config.settle_angle
        return rem - 2 * math.pi if rem >= 2 * math.pi - s else rem

    def yaw(self, quat: np.ndarray, goal_quat: np.ndarray) -> float:
        """The block's turn about the vertical from the goal's [rad] (of its flip-axis edge; a
        roll about the axis keeps it)."""
        x = quat_rotate(_mul(quat, _conj(goal_quat)), self.axis[None])[0]
        return math.atan2(float(x @ np.cross(UP, self.axis)), float(x @ self.axis))

    def _goal_quat(self, quat: np.ndarray, goal: Goal | None) -> np.ndarray:
        if goal and "quat" in goal:
            return np.asarray(goal["quat"], float)
        if self._default_goal is None:  # no goal given: flip the block as it was first seen
            self._default_goal = _mul(self.flip_quat, quat)
        return self._default_goal

    # -- policy -----------------------------------------------------------------------------
    def __call__(self, qpos: np.ndarray, goal: Goal | None) -> np.ndarray:
        """Joint goals (9,) [rad] from this state alone (see the class docstring)."""
        c = self.config
        qpos = check_call(self, qpos, goal, ())
        q = qpos[self.hand_qpos]
        pos, quat = qpos[self.block_pos], qpos[self.block_quat]
        gq = self._goal_quat(quat, goal)
        rem = self.remaining(quat, gq)
        left = max(0, math.ceil((rem - c.settle_angle) / (math.pi / 2)))  # rolls not landed
        a = ((c.settle_angle - rem) % (math.pi / 2)) - c.settle_angle  # this roll's progress
        engaged = any(self._at_front(q, i, pos, quat) for i in self.carriers)
        if self._rolls_at_start is None:
            self._rolls_at_start = left
        self.rolls = self._rolls_at_start - left
        goals = np.tile(RESET_POSE[:3], 3)
        p = self._finger(self.pusher)
        tip = self.fingers[self.pusher].forward(q[p])
        if left == 0:  # hold still, the pusher lifted off the block
            self.phase, self.stage = DONE, "hold"
            goals[p] = self._ik(self.pusher, self._above(pos, quat))
            return goals
        carried = (self._carry(q, pos, quat, gq, engaged)
                   if -c.settle_angle < a < c.carry_angle else None)
        if carried is not None:
            self.phase = CARRY
            return carried
        self.phase = ROLL
        if a > c.release:  # the block falls on by itself: lift off
            self.stage = "lift"
            goals[p] = self._ik(self.pusher, self._lift(pos, quat, a))
        else:
            goals[p] = self._push(tip, pos, quat, gq, a)
        if a < c.settle_angle:  # carriers still at the block's front after a carry: back off
            for i in self.carriers:
                if self._at_front(q, i, pos, quat):
                    f = self._front_point(pos, quat, 0.02) + UP * 0.01
                    goals[self._finger(i)] = self._ik(i, f + self._side(i, pos))
        return goals

    def _edges(self, pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The back face's top edge and the front bottom edge (the pivot), (3,) each [m]."""
        w = self._corners(pos, quat)
        z = w[:, 2]
        top = w[np.argsort(-z)[:4]]
        low = w[np.argsort(z)[:4]]
        return (top[np.argsort(top @ self.d)[:2]].mean(axis=0),
                low[np.argsort(-(low @ self.d))[:2]].mean(axis=0))

    def _turn(self, pivot: np.ndarray, rel: np.ndarray, a: float) -> np.ndarray:
        """``pivot + rel`` turned by ``a`` about the axis through ``pivot`` (rolling along d)."""
        rs, rz = float(rel @ self.d), float(rel[2])
        ca, sa = math.cos(a), math.sin(a)
        return (pivot + self.d * (ca * rs + sa * rz) + UP * (-sa * rs + ca * rz)
                + self.axis * float(rel @ self.axis))

    def _push(self, tip: np.ndarray, pos: np.ndarray, quat: np.ndarray, gq: np.ndarray,
              a: float) -> np.ndarray:
        """The pusher's goals, by where its tip is: not behind the back face -> over and behind
        it (approach); behind it but above its top edge -> down behind it; behind and below
        the edge -> push, leading the roll by ``lead``."""
        c, i = self.config, self.pusher
        back, pivot = self._edges(pos, quat)
        n = -self.d * math.cos(a) + UP * math.sin(a)  # the back face's outward normal
        down = -UP * math.cos(a) - self.d * math.sin(a)  # down the back face
        out, below = float((tip - back) @ n), float((tip - back) @ down)
        if out < 0.0:  # the tip's centre over the block, or in front of its back face
            self.stage = "approach"
            return self._ik(i, back + n * (self.r + c.behind) + UP * c.clear)
        if below < -c.contact_tol and a < c.carry_angle:
            self.stage = "down"
            return self._ik(i, back + n * (self.r + c.gap) + down * c.below)
        self.stage = "push"
        steer = float(np.clip(c.push_yaw_gain * self.yaw(quat, gq), -c.push_yaw_max,
                              c.push_yaw_max))
        rel = back + n * (self.r - 0.004) + down * c.below + self.axis * steer - pivot
        return self._ik(i, self._turn(pivot, rel, c.lead))

    def _lift(self, pos: np.ndarray, quat: np.ndarray, a: float) -> np.ndarray:
        """Where the pusher goes once the block falls on: 30 mm above and 10 mm back from
        where it touched the back face at ``release``, about the present pivot."""
        c = self.config
        _, pivot = self._edges(pos, quat)
        edge = -self.d * 2 * self.h + UP * 2 * self.h  # the back top edge from the pivot, upright
        n = -self.d * math.cos(c.release) + UP * math.sin(c.release)
        contact = self._turn(pivot, edge, c.release) + n * self.r
        return contact + UP * 0.03 - self.d * 0.01

    def _above(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """The pusher's place once the flip is done: above and behind the back top edge."""
        back, _ = self._edges(pos, quat)
        return back + UP * 0.03 - self.d * (self.r + 0.01)

    # -- carry ------------------------------------------------------------------------------
    def _front_point(self, pos: np.ndarray, quat: np.ndarray, out: float) -> np.ndarray:
        """A point ``out`` beyond the block's front face (tip centre), ``carry_low`` above
        the table, in line with the block's centre [m]."""
        s = float(pos @ self.d)
        lateral = pos - s * self.d
        lateral[2] = pos[2] - self.h + self.config.carry_low
        return lateral + self.d * (s + self.h + self.r + out)

    def _side(self, i: int, pos: np.ndarray) -> np.ndarray:
        side = 1.0 if float((self.fingers[i].origin - pos) @ self.axis) > 0 else -1.0
        return self.axis * side * self.config.carrier_spread

    def _at_front(self, q: np.ndarray, i: int, pos: np.ndarray, quat: np.ndarray) -> bool:
        """Carrier ``i``'s tip is low at the block's front face (within ``engaged``)."""
        tip = self.fingers[i].forward(q[self._finger(i)])
        rel = tip - self._front_point(pos, quat, 0.0) - self._side(i, pos)
        c = self.config
        return abs(float(rel[2])) < c.engaged_high and (
            -(c.carry_push + c.carry_step + c.engaged) < float(rel @ self.d) < c.behind + c.engaged)

    def _carry(self, q: np.ndarray, pos: np.ndarray, quat: np.ndarray,
               gq: np.ndarray, engaged: bool) -> np.ndarray | None:
        """All fingers' goals while the resting block is carried back against d, or None when
        it needs no carry: it is further along d than ``roll_from + roll_from_tol``, or than
        ``roll_from + carry_tol`` while both carriers are low at its front face (carrying)."""
        c = self.config
        err = self._roll_from() - float(pos @ self.d)
        if not (err < -c.roll_from_tol or (engaged and err < -c.carry_tol)):
            return None
        goals = np.tile(RESET_POSE[:3], 3)
        guard = pos - self.d * (self.h + self.r + c.guard_gap) + UP * c.guard_high
        if engaged:
            self.stage = "carry"
            step = max(err, -c.carry_step)
            home = np.array([*c.home, 0.0])
            side = float((pos - home) @ self.axis)
            shift = -self.axis * float(np.clip(c.carry_center_gain * side, -c.carry_step,
                                               c.carry_step))
            f = self._front_point(pos, quat, -c.carry_push) + self.d * step + shift
            yaw = self.yaw(quat, gq)
            guard = guard + self.d * step
        else:
            self.stage = "descend"
            f = self._front_point(pos, quat, c.behind)
            yaw = 0.0
        for i in self.carriers:
            tip = self.fingers[i].forward(q[self._finger(i)])
            ahead = float((tip - pos) @ self.d) - self.h - self.r
            lift = UP * 0.02 if not engaged and ahead < 0.0 else 0.0
            offset = self._side(i, pos)
            goals[self._finger(i)] = self._ik(
                i, f + lift + offset - self.d * (c.carry_yaw_gain * yaw
                                                 * float(offset @ self.axis)))
        tip = self.fingers[self.pusher].forward(q[self._finger(self.pusher)])
        if float((pos - tip) @ self.d) - self.h < self.r - c.contact_tol:
            # the pusher is not behind the block yet: over and behind its back top edge
            # first, never down onto the edge (that tips the block back against the carriers)
            guard = pos - self.d * (self.h + self.r + c.behind) + UP * (self.h + c.clear)
        goals[self._finger(self.pusher)] = self._ik(self.pusher, guard)
        return goals


def run_teacher(env: gym.Env, teacher: Any, seed: int) -> bool:
    """One noise-free episode of ``teacher`` from reset seed ``seed``; success at its end."""
    u = env.unwrapped
    env.reset(seed=seed)
    teacher.reset(u)
    done, info = False, {}
    while not done:
        a = goal_to_action(teacher(u.backend.observed_qpos(), u.goal), u.task.hand_low,
                           u.task.hand_high)
        _, _, term, trunc, info = env.step(a.astype(np.float32))
        done = term or trunc
    return bool(info["success"])


class _AsPolicy:
    """A teacher as the (env, obs) -> action callable ``teacher_episodes`` records."""

    def __init__(self, teacher: Any) -> None:
        self.teacher = teacher

    def reset(self, env: gym.Env) -> None:
        self.teacher.reset(env.unwrapped)

    def __call__(self, env: gym.Env, obs: np.ndarray) -> np.ndarray:
        u = env.unwrapped
        return goal_to_action(self.teacher(u.backend.observed_qpos(), u.goal),
                              u.task.hand_low, u.task.hand_high)


def clone_success(env: gym.Env, teacher: Any, demos: int, episodes: int, seed: int = 0
                  ) -> tuple[int, int]:
    """Behaviour-clone ``demos`` successful demos of ``teacher`` (recorded with +-0.05 executed
    action noise, clean labels, as bench/npg_dapg.py does) with the DAPG trainer's BC settings
    and run the clone's mean action from ``episodes`` held-out starts and from the demos' own
    starts: (held-out successes, successes on the demo starts)."""
    eps = teacher_episodes(env, _AsPolicy(teacher), seeds=range(10_000, 10_000 + demos),
                           action_noise=0.05, max_tries=40)
    policy = _clone(np.concatenate([e.observations[:-1] for e in eps]),
                    np.concatenate([e.actions for e in eps]), seed)
    held_out = sum(_policy_success(env, policy, HELD_OUT + k) for k in range(episodes))
    return held_out, sum(_policy_success(env, policy, e.seed) for e in eps)


def _clone(obs: np.ndarray, act: np.ndarray, seed: int) -> GaussianMLPPolicy:
    """A fresh policy behaviour-cloned on (obs, act) with the DAPG trainer's BC settings."""
    gen = torch.Generator().manual_seed(seed)
    policy = GaussianMLPPolicy(obs.shape[1], act.shape[1], generator=gen)
    config = TRAINER_BC
    set_from_demos(policy, obs, act, config)
    behavior_clone(policy, obs, act, config, gen)
    return policy


def _policy_success(env: gym.Env, policy: GaussianMLPPolicy, reset_seed: int,
                    teacher: Any = None, labels: list | None = None) -> bool:
    """One episode of the policy's mean action; with ``teacher``, every visited observation is
    appended to ``labels`` with the teacher's action for that state (DAgger)."""
    u = env.unwrapped
    o, _ = env.reset(seed=reset_seed)
    if teacher is not None:
        teacher.reset(u)
    done, info = False, {}
    while not done:
        if teacher is not None and labels is not None:
            goals = teacher(u.backend.observed_qpos(), u.goal)
            labels.append((o, goal_to_action(goals, u.task.hand_low, u.task.hand_high)))
        with torch.no_grad():
            a = policy.act(o, deterministic=True)[0].numpy()
        o, _, term, trunc, info = env.step(a)
        done = term or trunc
    return bool(info.get("success", False))


def dagger(env: gym.Env, make: Any, demos: int, rounds: int, per_round: int,
           episodes: int) -> list[tuple[int, int]]:
    """DAgger (Ross et al. 2011, beta = 0 after the demos): clone the demos, run the clone from
    ``per_round`` new starts, label every state it visits with the teacher's action, clone
    the aggregate again, ``rounds`` times. Per round: (held-out successes of the clone of
    that round, transitions so far)."""
    teacher = make()
    eps = teacher_episodes(env, _AsPolicy(teacher), seeds=range(10_000, 10_000 + demos),
                           action_noise=0.05, max_tries=40)
    obs = [e.observations[:-1] for e in eps]
    act = [e.actions for e in eps]
    out = []
    for r in range(rounds + 1):
        policy = _clone(np.concatenate(obs), np.concatenate(act), seed=r)
        wins = sum(_policy_success(env, policy, HELD_OUT + k) for k in range(episodes))
        out.append((wins, sum(len(a) for a in act)))
        print(f"  round {r}: clone held out {_rate(wins, episodes)}, "
              f"{out[-1][1]} transitions", flush=True)
        if r == rounds:
            break
        labels: list = []
        for k in range(per_round):
            _policy_success(env, policy, 20_000 + 100 * r + k, teacher=make(), labels=labels)
        obs.append(np.array([o for o, _ in labels]))
        act.append(np.array([a for _, a in labels]))
    return out


def _rate(k: int, n: int) -> str:
    lo, hi = wilson_interval(k, n)
    return f"{k}/{n} [{lo:.2f}, {hi:.2f}]"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--teacher-episodes", type=int, default=40)
    p.add_argument("--clone-episodes", type=int, default=40)
    p.add_argument("--demos", type=int, default=10)
    p.add_argument("--teachers", nargs="+", default=["FlipBlockTeacher", "MarkovFlipTeacher"],
                   choices=["FlipBlockTeacher", "MarkovFlipTeacher", "PlannedFlipTeacher"])
    p.add_argument("--dagger", type=int, default=0, help="DAgger rounds (0: none)")
    p.add_argument("--dagger-episodes", type=int, default=10, help="clone episodes per round")
    args = p.parse_args()
    env = gym.make(ENV)
    makers = {"FlipBlockTeacher": FlipBlockTeacher, "MarkovFlipTeacher": MarkovFlipTeacher,
              "PlannedFlipTeacher": PlannedFlipTeacher}
    for name, make in ((n, makers[n]) for n in args.teachers):
        t0 = time.process_time()
        line = f"{name}:"
        if args.teacher_episodes:
            wins = sum(run_teacher(env, make(), s) for s in range(args.teacher_episodes))
            line += f" teacher {_rate(wins, args.teacher_episodes)} (seeds 0..)"
        if args.clone_episodes:
            k, own = clone_success(env, make(), args.demos, args.clone_episodes)
            line += (f"; clone of {args.demos} demos: held out {_rate(k, args.clone_episodes)}"
                     f", from the demos' starts {own}/{args.demos}")
        print(line + f"; {time.process_time() - t0:.0f} s CPU", flush=True)
        if args.dagger:
            print(f"{name}: DAgger, {args.dagger_episodes} clone episodes per round", flush=True)
            dagger(env, make, args.demos, args.dagger, args.dagger_episodes,
                   args.clone_episodes)
    env.close()


if __name__ == "__main__":
    main()
