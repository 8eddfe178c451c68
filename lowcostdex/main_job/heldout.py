"""Several policies on the same held-out robot episodes, each from the same robot state.

A robot carries state from one episode into the next: its auto-reset stops each finger within
its precision of the start pose, at a place that depends on where the finger came from (gear
backlash, friction), and its motors' windings warm as it works. So on one robot "the same
episode" (the same reset seed: start and goal) starts a little differently for a policy that
runs after another policy than for one that runs first. Measured on the emulated D'Claw
(valve-target, seed 0, bench/RESULTS.md "Paired evaluations that do not depend on order"): the
first episode of a policy that followed four episodes of another started with the fingers up
to 0.023 rad elsewhere and the windings 0.1-0.3 K warmer, and the same policy's held-out count
on 100 episodes moved by one with what ran before it. The emulator itself is deterministic
(its virtual clock; the env re-seeds the noise at every reset): the carried state is physical,
not an emulator bug.

A paired comparison must not depend on that order. On the emulated robot ``evaluate`` gives
every policy a freshly started robot (``fresh=True``: a new env from the factory, powered up at
the same pose with the motors at ambient), so a policy's per-episode results are the same
whatever ran before it, and the policies' episodes differ only by what each policy did. A real
robot cannot be started afresh: there (``fresh=False``) the policies run one after another on
the one robot, and the report says so.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np


class UniformActions:
    """Uniformly random actions in [``low``, ``high``] drawn from ``rng``: the random-policy
    baseline, as a rollout policy (``act(obs, noise)``; the observation is ignored)."""

    def __init__(self, low: np.ndarray, high: np.ndarray, rng: np.random.Generator):
        self.low, self.high, self.rng = np.asarray(low), np.asarray(high), rng

    @property
    def act_dim(self) -> int:
        return int(self.low.shape[0])

    def act(self, obs: np.ndarray, noise: np.ndarray | None = None) -> np.ndarray:
        return self.rng.uniform(self.low, self.high)


def evaluate(make_env: Callable[[], Any], policies: Mapping[str, Any],
             jobs: Sequence[Any], *, fresh: bool,
             on_episode: Callable[[str], None] | None = None) -> dict[str, list[Any]]:
    """Each of ``policies`` (name -> rollout policy: a ``PolicySnapshot``, ``UniformActions``,
    or a callable ``env -> policy`` for one that needs the env's spaces) on every job of
    ``jobs`` in order (``samplers.rollout``: reset with the job's seed, the mean action for a
    deterministic job).

    ``fresh``: each policy on its own env from ``make_env`` (on the emulated robot: a newly
    started robot, so the policy's results do not depend on what ran before it); otherwise all
    on one env, in the order of ``policies`` (a real robot). ``on_episode(name)`` after each
    episode. Returns name -> trajectories (``samplers.Trajectory``) in the order of ``jobs``.
    """
    from lowcostdex.algos.samplers import SerialSampler

    out: dict[str, list[Any]] = {}
    shared = None if fresh else SerialSampler(make_env)
    try:
        for name, policy in policies.items():
            sampler = shared or SerialSampler(make_env)
            try:
                if callable(policy) and not hasattr(policy, "act"):
                    policy = policy(sampler.env)
                paths = []
                for job in jobs:
                    paths += sampler.sample(policy, [job])
                    if on_episode is not None:
                        on_episode(name)
                out[name] = paths
            finally:
                if sampler is not shared:
                    sampler.close()
    finally:
        if shared is not None:
            shared.close()
    return out


def uniform_actions(rng: np.random.Generator) -> Callable[[Any], UniformActions]:
    """``UniformActions`` over an env's action space (for ``evaluate``)."""

    def make(env: Any) -> UniformActions:
        space = env.action_space
        return UniformActions(space.low, space.high, rng)

    return make
