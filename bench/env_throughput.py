"""Env throughput vs the physics limit, single and batched (one run, side by side).

ratio = env steps/s x frame_skip / raw MuJoCo steps/s of the same model, same control pattern
(goals written once per control step). Targets: batched >= 0.85 (issue 2).

  python bench/env_throughput.py [--env lowcostdex/DClawTurnValve-v0] [--num-envs 64] [--seconds 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import gymnasium as gym
import mujoco
import numpy as np
from mujoco import batch as mjbatch

import lowcostdex  # noqa: F401
from lowcostdex.sim.vector import make_vec


def timed(fn, seconds: float) -> float:
    """Calls per second of fn over at least ``seconds``."""
    fn()  # warm up
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        fn()
        n += 1
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="lowcostdex/DClawTurnValve-v0")
    ap.add_argument("--num-envs", type=int, default=64)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()
    rng = np.random.default_rng(0)

    env = gym.make(args.env).unwrapped
    env.reset(seed=0)
    skip = env.task.timing.frame_skip
    model = env.model
    nu = len(env.task.hand_act)
    actions = rng.uniform(-1, 1, (256, nu))
    k = [0]

    def env_step():
        env.step(actions[k[0] % 256])
        k[0] += 1
        if k[0] % 40 == 0:
            env.reset()

    data = mujoco.MjData(model)
    data.qpos[:] = env.data.qpos

    def raw_step():
        data.ctrl[:] = rng.uniform(-0.5, 0.5, model.nu)
        mujoco.mj_step(model, data, nstep=skip)

    single_env = timed(env_step, args.seconds) * skip
    single_raw = timed(raw_step, args.seconds) * skip

    n = args.num_envs
    vec = make_vec(args.env, n, nthread=args.threads)
    vec.reset(seed=0)
    vactions = rng.uniform(-1, 1, (256, n, nu))

    def vec_step():
        vec.step(vactions[k[0] % 256])
        k[0] += 1

    batch = mjbatch.Batch(vec.plant.model, nsim=n, nthread=args.threads)
    batch.qpos[:] = vec.plant.qpos
    ctrl = rng.uniform(-0.5, 0.5, (256, n, model.nu))

    def batch_step():
        batch.ctrl[:] = ctrl[k[0] % 256]
        batch.step(nstep=skip)
        k[0] += 1

    batched_env = timed(vec_step, args.seconds) * skip * n
    batched_raw = timed(batch_step, args.seconds) * skip * n

    print(f"machine: {platform.machine()} {os.cpu_count()} cpus, {platform.python_version()}, "
          f"mujoco {mujoco.__version__}")
    print(f"env {args.env}, frame_skip {skip}, batch {n} sims on {args.threads} threads")
    print(f"{'':10s}{'env phys steps/s':>18s}{'raw MuJoCo steps/s':>20s}{'ratio':>8s}")
    print(f"{'single':10s}{single_env:18,.0f}{single_raw:20,.0f}{single_env / single_raw:8.2f}")
    print(f"{'batched':10s}{batched_env:18,.0f}{batched_raw:20,.0f}{batched_env / batched_raw:8.2f}"
          f"   (target >= 0.85)")


if __name__ == "__main__":
    main()
