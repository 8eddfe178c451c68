"""Env throughput vs the physics limit, single and batched (one run, side by side).

ratio = env steps/s x frame_skip / raw MuJoCo steps/s of the same model doing the same physics:
the raw loop replays the exact goals the env sent, from the same start states, with
``mj_step(nstep=frame_skip)`` (single) or ``mujoco.batch.Batch.step`` (batched). Env and raw runs
alternate and the best of ``--repeats`` is kept, which tames a noisy shared machine.
Target (issue 2): batched >= 0.85.

  python bench/env_throughput.py [--env lowcostdex/DClawTurnValve-v0] [--num-envs 64]
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


def best_rate(fn, repeats: int) -> float:
    """Best physics steps/s over repeats of fn (fn returns the physics steps it ran)."""
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        steps = fn()
        best = max(best, steps / (time.perf_counter() - t0))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--env", default="lowcostdex/DClawTurnValve-v0")
    ap.add_argument("--num-envs", type=int, default=64)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--episodes", type=int, default=5, help="single-env episodes per repeat")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)

    # ---- single env vs mj_step on the same goals ------------------------------------------
    env = gym.make(args.env)
    u = env.unwrapped
    skip, steps = u.task.timing.frame_skip, u.task.timing.episode_steps
    nu = env.action_space.shape[0]
    actions = rng.uniform(-1, 1, (args.episodes, steps, nu))
    starts, ctrls = [], []
    for ep in range(args.episodes):  # record what the env sends
        env.reset(seed=ep)
        starts.append((u.data.qpos.copy(), u.data.qvel.copy(), u.data.act.copy()))
        ep_ctrl = []
        for k in range(steps):
            env.step(actions[ep, k])
            ep_ctrl.append(u.data.ctrl.copy())
        ctrls.append(ep_ctrl)

    def env_run() -> int:
        for ep in range(args.episodes):
            env.reset(seed=ep)
            for k in range(steps):
                env.step(actions[ep, k])
        return args.episodes * steps * skip

    model = u.model
    data = mujoco.MjData(model)

    def raw_run() -> int:
        for ep in range(args.episodes):
            mujoco.mj_resetData(model, data)
            data.qpos[:], data.qvel[:], data.act[:] = starts[ep]
            mujoco.mj_forward(model, data)
            for c in ctrls[ep]:
                data.ctrl[:] = c
                mujoco.mj_step(model, data, nstep=skip)
        return args.episodes * steps * skip

    single_env = single_raw = 0.0
    for _ in range(args.repeats):  # alternate so load spikes hit both
        single_env = max(single_env, best_rate(env_run, 1))
        single_raw = max(single_raw, best_rate(raw_run, 1))

    # ---- batched vector env vs Batch.step on the same goals --------------------------------
    n = args.num_envs
    vec = make_vec(args.env, n, nthread=args.threads)
    vactions = rng.uniform(-1, 1, (steps, n, nu))
    vec.reset(seed=0)
    vstart = (vec.plant.qpos.copy(), vec.plant.qvel.copy(), vec.plant.act.copy())
    vctrl = []
    for k in range(steps):
        vec.step(vactions[k])
        vctrl.append(vec.plant.ctrl.copy())

    def vec_run() -> int:
        vec.reset(seed=0)
        for k in range(steps):
            vec.step(vactions[k])
        return n * steps * skip

    batch = mjbatch.Batch(vec.plant.model, nsim=n, nthread=args.threads)

    def batch_run() -> int:
        batch.reset()
        batch.qpos[:], batch.qvel[:], batch.act[:] = vstart
        batch.forward()
        for c in vctrl:
            batch.ctrl[:] = c
            batch.step(nstep=skip)
        return n * steps * skip

    batched_env = batched_raw = 0.0
    for _ in range(args.repeats):
        batched_env = max(batched_env, best_rate(vec_run, 1))
        batched_raw = max(batched_raw, best_rate(batch_run, 1))

    print(f"machine: {platform.machine()}, {os.cpu_count()} cpus, Python "
          f"{platform.python_version()}, mujoco {mujoco.__version__}")
    print(f"env {args.env}: frame_skip {skip}; batch of {n} sims on {args.threads} threads")
    print(f"{'':10s}{'env phys steps/s':>18s}{'raw MuJoCo steps/s':>20s}{'ratio':>8s}")
    print(f"{'single':10s}{single_env:18,.0f}{single_raw:20,.0f}{single_env / single_raw:8.2f}")
    print(f"{'batched':10s}{batched_env:18,.0f}{batched_raw:20,.0f}"
          f"{batched_env / batched_raw:8.2f}   (target >= 0.85)")


if __name__ == "__main__":
    main()
