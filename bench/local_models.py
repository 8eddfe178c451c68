"""Sample efficiency of learned local models (TVLG + KL-constrained iLQG) vs NPG.

Two fixed-start tasks, both measured in episodes (rollouts) used for learning; evaluation
episodes (one noise-free episode per iteration) are not counted for either method.

1. Pendulum swing (``lowcostdex.algos.local_models.pendulum``): the task class local models are
   made for. Solved when the noise-free episode's cost is within 5 % (also reported: 20 %) of
   the converged cost (reference 03: 34.4 at N = 20; thresholds 36.1 and 41.3). NPG runs the NPG/DAPG trainer on the same
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

PENDULUM_CONVERGED = 34.4  # reference 03, N = 20
PENDULUM_THRESHOLD = 1.05 * PENDULUM_CONVERGED


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


def median_rollouts(values: list[float]) -> float:
    """Median with unsolved runs (nan) counted as infinitely many rollouts."""
    return float(np.median([v if np.isfinite(v) else math.inf for v in values]))


def compare(
    npg: list[float], npg_budget: int, tvlg: list[float], tvlg_budget: int, name: str
) -> str:
    """'median NPG episodes / median TVLG rollouts' with budgets when a median is unsolved."""
    a, b = median_rollouts(npg), median_rollouts(tvlg)
    a_txt = f"{a:.0f}" if np.isfinite(a) else f"> {npg_budget}"
    b_txt = f"{b:.0f}" if np.isfinite(b) else f"> {tvlg_budget}"
    if np.isfinite(a) and np.isfinite(b):
        ratio = f"NPG/{name} = {a / b:.1f}x"
    elif np.isfinite(b):
        ratio = f"NPG/{name} > {npg_budget / b:.0f}x"
    elif np.isfinite(a):
        ratio = f"NPG/{name} < {a / tvlg_budget:.1f}x"
    else:
        ratio = "no ratio: neither solved within its budget"
    return f"median NPG {a_txt} episodes, median {name} {b_txt} rollouts -> {ratio}"


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
    parser.add_argument(
        "--tasks", nargs="*", choices=("pendulum", "valve"), default=["pendulum", "valve"]
    )
    args = parser.parse_args()
    seeds = args.seeds[:1] if args.quick else args.seeds
    print(
        f"# bench/local_models.py  {time.strftime('%Y-%m-%d %H:%M')}  {platform.node()}  "
        f"{platform.processor() or platform.machine()}"
    )

    if "pendulum" in args.tasks:
        pendulum_section(seeds, args.quick, args.skip_npg)
    if "valve" in args.tasks:
        valve_section(seeds, args.quick, args.skip_npg)


def pendulum_section(seeds: list[int], quick: bool, skip_npg: bool) -> None:
    thresholds = {"5 %": PENDULUM_THRESHOLD, "20 %": 1.2 * PENDULUM_CONVERGED}
    print(
        "\n## Pendulum swing, fixed start, solved: noise-free episode cost within 5 % (<= "
        f"{thresholds['5 %']:.1f}) or 20 % (<= {thresholds['20 %']:.1f}) of the converged cost"
    )
    tvlg_p: dict[str, list[float]] = {k: [] for k in thresholds}
    for s in seeds:
        curve = pendulum_tvlg(s, n_iter=12)
        r = np.array([c[0] for c in curve])
        cost = np.array([c[1] for c in curve])
        for k, v in thresholds.items():
            tvlg_p[k].append(first_solved(r, cost <= v))
        print(
            f"TVLG seed {s}: rollouts to 5 % {tvlg_p['5 %'][-1]:.0f}, to 20 % {tvlg_p['20 %'][-1]:.0f}; "
            f"cost per iteration {np.round(cost, 1).tolist()}"
        )
    if not skip_npg:
        npg_p: dict[str, list[float]] = {k: [] for k in thresholds}
        n_traj, n_iter = (10, 60) if quick else (10, 300)
        for s in seeds:
            m = npg_curve(PendulumSwingEnv, "pendulum", s, n_traj, n_iter, gamma=1.0)
            episodes = (m["iteration"] + 1) * n_traj
            for k, v in thresholds.items():
                npg_p[k].append(first_solved(episodes, -m["eval_return_mean"] <= v))
            print(
                f"NPG  seed {s} ({n_traj} episodes per iteration, budget {n_iter * n_traj}): episodes "
                f"to 5 % {npg_p['5 %'][-1]:.0f}, to 20 % {npg_p['20 %'][-1]:.0f}; best noise-free "
                f"cost {np.min(-m['eval_return_mean']):.1f}"
            )
        for k in thresholds:
            print(f"pendulum ({k}): " + compare(npg_p[k], n_iter * n_traj, tvlg_p[k], 60, "TVLG"))


def valve_section(seeds: list[int], quick: bool, skip_npg: bool) -> None:
    env_id = "lowcostdex/DClawTurnValve-v0"
    print(
        f"\n## D'Claw valve turn 180 deg, fixed start ({env_id}, sim), solved: noise-free "
        "episode ends with |error| < 0.1 rad"
    )
    inits = ["pd"] + (["teacher"] if importlib.util.find_spec("lowcostdex.sim.scripted") else [])
    tvlg_v: dict[str, list[float]] = {}
    for init in inits:
        n_iter = (6 if quick else 12) if init == "pd" else (4 if quick else 8)
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
    if not skip_npg:
        from lowcostdex.algos.samplers import EnvFactory

        n_traj, n_iter = (20, 20) if quick else (50, 150)
        for s in seeds[:1]:
            m = npg_curve(EnvFactory(env_id, {}), env_id, s, n_traj, n_iter)
            episodes = (m["iteration"] + 1) * n_traj
            solved = first_solved(episodes, m["eval_success_rate"] == 1.0)
            print(
                f"NPG seed {s} ({n_traj} episodes per iteration, budget {n_iter * n_traj}): episodes to solve "
                f"{solved:.0f}; best eval return {np.max(m['eval_return_mean']):.1f}, best training "
                f"success {np.max(m['success_rate']):.2f}"
            )
            for init, values in tvlg_v.items():
                budget = (6 if quick else 12) * 5 if init == "pd" else (4 if quick else 8) * 5
                print(
                    "valve: "
                    + compare([solved], n_iter * n_traj, values, budget, f"TVLG(init={init})")
                )


if __name__ == "__main__":
    main()
