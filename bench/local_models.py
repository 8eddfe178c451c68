"""Sample efficiency of learned local models (TVLG + KL-constrained iLQG) vs NPG.

Two fixed-start tasks, both measured in episodes (rollouts) used for learning; evaluation
episodes (one noise-free episode per iteration) are not counted for either method.

1. Pendulum swing (``lowcostdex.algos.local_models.pendulum``): the task class local models are
   made for. Solved when the noise-free episode's cost is within 5 % of the converged TVLG cost
   (reference 03: 34.4 at N = 20; threshold 36.1). NPG runs the NPG/DAPG trainer on the same
   task as a gymnasium env whose return is minus the same cost.
2. D'Claw valve turn, fixed start (``lowcostdex/DClawTurnValve-v0``, sim): solved when the
   noise-free episode ends within 0.1 rad of the 180 deg goal (``info["success"]``) -- the ADROIT
   figure to beat is about 60 trials. TVLG starts from the PD hold controller (``init="pd"``)
   and, when the scripted teacher exists (``lowcostdex.sim.scripted``), from one teacher
   episode replayed open loop with exploration noise (``init="teacher"``); for the latter the
   rollouts until >= 80 % of the noisy training episodes succeed are also reported.

Usage::

    python bench/local_models.py            # full: ~10-20 min on 2 cores
    python bench/local_models.py --quick    # smaller budgets, a few minutes
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.pendulum import (
    PendulumParams,
    PendulumSwingEnv,
    pendulum_cost,
    pendulum_rollouts,
)
from lowcostdex.algos.local_models.tvlg import TVLGConfig, TVLGState, tvlg_iteration

PENDULUM_THRESHOLD = 1.05 * 34.4


def pendulum_episode_cost(ctl: LinearGaussianController, p: PendulumParams) -> float:
    """Cost of the noise-free episode of ``ctl`` in the gym pendulum (minus its return)."""
    env = PendulumSwingEnv(p)
    obs, _ = env.reset(seed=0)
    total, done, t = 0.0, False, 0
    while not done:
        tau = ctl.act(t, obs[:2])[0]
        obs, reward, terminated, truncated, _ = env.step(np.array([tau / p.max_torque]))
        total += reward
        done, t = terminated or truncated, t + 1
    return -total


def pendulum_tvlg(seed: int, n_iter: int, n_rollouts: int = 5) -> list[tuple[int, float]]:
    """(cumulative rollouts, noise-free episode cost) after each TVLG iteration."""
    p = PendulumParams()
    cfg = TVLGConfig()
    ctl = LinearGaussianController.from_cov(
        np.zeros((p.T, 1, 2)), np.zeros((p.T, 1)), np.ones((p.T, 1, 1))
    )
    state, rng, out = TVLGState.initial(ctl, cfg), np.random.default_rng(seed), []
    for k in range(n_iter):
        X, U = pendulum_rollouts(state.controller, n_rollouts, rng, p)
        state, _ = tvlg_iteration(state, X, U, pendulum_cost(p), cfg, rng)
        out.append(((k + 1) * n_rollouts, pendulum_episode_cost(state.controller, p)))
    return out


def npg_curve(
    env_factory, env_id: str, seed: int, n_traj: int, n_iter: int, **kw
) -> dict[str, np.ndarray]:
    """Run the NPG trainer with one noise-free evaluation episode per iteration; its metrics."""
    from lowcostdex.algos.train import TrainConfig, train

    cfg = TrainConfig(
        algo="npg", env_id=env_id, seed=seed, n_iter=n_iter, n_traj=n_traj, eval_every=1,
        eval_episodes=1, progress=False, **kw,
    )  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        return train(cfg, Path(tmp) / "npg", env_factory=env_factory).read_metrics()


def first_solved(rollouts: np.ndarray, solved: np.ndarray) -> float:
    """Rollouts used when ``solved`` first holds (nan if never)."""
    idx = np.flatnonzero(solved)
    return float(rollouts[idx[0]]) if idx.size else math.nan


def valve_tvlg(seed: int, n_iter: int, init: str, demos: str | None, **kw) -> dict[str, np.ndarray]:
    from lowcostdex.algos.local_models.train import TVLGTrainConfig, train

    cfg = TVLGTrainConfig(seed=seed, n_iter=n_iter, init=init, demos=demos, progress=False, **kw)
    with tempfile.TemporaryDirectory() as tmp:
        return train(cfg, Path(tmp) / "tvlg").read_metrics()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="smaller budgets")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--skip-npg", action="store_true")
    args = parser.parse_args()
    seeds = args.seeds[:1] if args.quick else args.seeds
    print(
        f"# bench/local_models.py  {time.strftime('%Y-%m-%d %H:%M')}  {platform.node()}  "
        f"{platform.processor() or platform.machine()}"
    )

    # ---------------------------------------------------------------- pendulum
    print(
        "\n## Pendulum swing, fixed start, solved: noise-free episode cost <= "
        f"{PENDULUM_THRESHOLD:.1f}"
    )
    tvlg_p = []
    for s in seeds:
        curve = pendulum_tvlg(s, n_iter=12)
        r = np.array([c[0] for c in curve])
        cost = np.array([c[1] for c in curve])
        tvlg_p.append(first_solved(r, cost <= PENDULUM_THRESHOLD))
        print(
            f"TVLG seed {s}: rollouts to solve {tvlg_p[-1]:.0f}; cost per iteration {np.round(cost, 1).tolist()}"
        )
    if not args.skip_npg:
        npg_p = []
        n_traj, n_iter = (10, 60) if args.quick else (10, 300)
        for s in seeds:
            m = npg_curve(PendulumSwingEnv, "pendulum", s, n_traj, n_iter, gamma=1.0)
            episodes = (m["iteration"] + 1) * n_traj
            npg_p.append(first_solved(episodes, -m["eval_return_mean"] <= PENDULUM_THRESHOLD))
            print(
                f"NPG  seed {s} ({n_traj} episodes/iteration, budget {n_iter * n_traj}): episodes to solve "
                f"{npg_p[-1]:.0f}; best noise-free cost {np.min(-m['eval_return_mean']):.1f}"
            )
        ratio = (
            np.nanmedian(npg_p) / np.nanmedian(tvlg_p) if np.any(np.isfinite(npg_p)) else math.nan
        )
        print(
            f"pendulum: median TVLG {np.nanmedian(tvlg_p):.0f} rollouts, median NPG "
            f"{np.nanmedian(npg_p) if np.any(np.isfinite(npg_p)) else math.nan:.0f} episodes -> NPG/TVLG = {ratio:.1f}x"
            + (
                ""
                if np.all(np.isfinite(npg_p))
                else f" (NPG unsolved in some seeds within {n_iter * n_traj})"
            )
        )

    # ---------------------------------------------------------------- valve
    env_id = "lowcostdex/DClawTurnValve-v0"
    print(
        f"\n## D'Claw valve turn 180 deg, fixed start ({env_id}, sim), solved: noise-free "
        "episode ends with |error| < 0.1 rad"
    )
    inits = ["pd"] + (["teacher"] if importlib.util.find_spec("lowcostdex.sim.scripted") else [])
    tvlg_v: dict[str, list[float]] = {}
    for init in inits:
        n_iter = (6 if args.quick else 12) if init == "pd" else (4 if args.quick else 8)
        noise = 0.3 if init == "pd" else 0.05
        for s in seeds:
            m = valve_tvlg(s, n_iter, init, None, init_noise=noise)
            solved = first_solved(m["rollouts"], m["eval_success_rate"] == 1.0)
            robust = first_solved(
                m["rollouts"], (m["eval_success_rate"] == 1.0) & (m["success_rate"] >= 0.8)
            )
            tvlg_v.setdefault(init, []).append(solved)
            print(
                f"TVLG init={init} (noise {noise}) seed {s}: rollouts to noise-free success {solved:.0f}, "
                f"to >= 80 % noisy success {robust:.0f} (budget {n_iter * 5}); noise-free final |error| "
                f"{np.round(m['eval_final_abs_error'], 2).tolist()}; training success "
                f"{np.round(m['success_rate'], 1).tolist()}"
            )
    if not args.skip_npg:
        from lowcostdex.algos.samplers import EnvFactory

        n_traj, n_iter = (20, 20) if args.quick else (50, 150)
        for s in seeds[:1]:
            m = npg_curve(EnvFactory(env_id, {}), env_id, s, n_traj, n_iter)
            episodes = (m["iteration"] + 1) * n_traj
            solved = first_solved(episodes, m["eval_success_rate"] == 1.0)
            print(
                f"NPG seed {s} ({n_traj} episodes/iteration, budget {n_iter * n_traj}): episodes to solve "
                f"{solved:.0f}; best eval return {np.max(m['eval_return_mean']):.1f}, best training "
                f"success {np.max(m['success_rate']):.2f}"
            )
            for init, values in tvlg_v.items():
                tv = np.nanmedian(values) if np.any(np.isfinite(values)) else math.nan
                print(
                    f"valve: NPG/TVLG(init={init}) = {solved / tv:.1f}x"
                    if np.isfinite(solved / tv)
                    else f"valve: NPG {solved:.0f} episodes vs TVLG(init={init}) {tv:.0f} rollouts: no ratio "
                    "(a run did not solve within its budget)"
                )


if __name__ == "__main__":
    main()
