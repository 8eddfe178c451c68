"""Sample efficiency of learned local models (TVLG + KL-constrained iLQG) vs NPG.

Fixed-start tasks, measured in episodes (rollouts) used for learning; evaluation episodes are
not counted for either method (they are reported separately).

1. ``pendulum``: pendulum swing (``lowcostdex.algos.local_models.pendulum``), the task class local
   models are made for. Solved when the noise-free episode's cost is within 5 % (also reported:
   20 %) of the converged cost (reference 03: 34.4 at N = 20; thresholds 36.1 and 41.3). NPG runs
   the NPG/DAPG trainer on the same task as a gymnasium env whose return is minus the same cost.
2. ``valve``: D'Claw valve turn, fixed start (``lowcostdex/DClawTurnValve-v0``, sim), task cost:
   solved when the noise-free episode ends within 0.1 rad of the 180 deg goal
   (``info["success"]``) -- the ADROIT figure to beat is about 60 trials. TVLG starts from the PD
   hold controller (``init="pd"``) and from one teacher episode replayed open loop with
   exploration noise (``init="teacher"``).
3. ``valve-demo``: the same task from ONE demonstration, with the tracking cost (hand near the
   demonstrated joint targets, valve at the goal over the last 5 steps; ``--cost tracking``).
   Three demonstrations of the scripted teacher: recorded from the fixed start ("exact"; replayed
   open loop it succeeds, so exploration noise 0.1 is used, under which it mostly fails), and
   recorded with the valve 0.3 rad behind / ahead of the fixed start ("short" / "long": replayed
   from the fixed start they end 0.31 rad short / 0.29 rad past the goal; noise 0.05). Solved: the
   noise-free episode succeeds AND >= 80 % of 20 held-out noisy episodes (the controller's own
   exploration noise) succeed; the initial controller meets neither. Also reported: the
   iteration criterion (noise-free success and >= 4 of the 5 training rollouts), the final
   controller's noise, and its mean under the initial noise (is it a better mean, or just less
   noise?). ``--dapg``: DAPG (BC, then NPG with the demo term) from the same single demonstration.
4. ``valve-onspoke``: PD-hold start with the fingertips already behind the spokes (the teacher's
   pose just before its first push; ``--start-hand-qpos``), task cost: how far the valve turns.
5. ``valve-model``: why the local models fail where they fail. For the "short" and "long"
   demonstrations: the sensitivity of the final valve angle to each action (steps 10-37, 9
   joints) by central finite differences of the noise-free replay (h = 0.05), against (a) the
   same sensitivity through the TVLG model fitted (GMM prior) on 5 noisy rollouts and (b) a
   least-squares fit of the final angle on the whole noise sequence of 600 noisy rollouts (the
   best any linear model of the outcome can do at that noise): correlations and R^2.

Usage::

    python bench/local_models.py                            # pendulum, valve: ~10-20 min
    python bench/local_models.py --tasks valve-demo valve-onspoke --skip-npg   # ~15 min
    python bench/local_models.py --tasks valve-demo --dapg --seeds 0
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


def fmt_count(value: float, budget: int) -> str:
    """A count, or '> budget' when not reached (nan)."""
    return f"{value:.0f}" if np.isfinite(value) else f"> {budget}"


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
    from lowcostdex.algos.local_models.train import train
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig

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
        "--tasks", nargs="*", choices=("pendulum", "valve", "valve-demo", "valve-onspoke", "valve-model"),
        default=["pendulum", "valve"],
    )  # fmt: skip
    parser.add_argument(
        "--dapg", action="store_true", help="valve-demo: DAPG from the same single demonstration"
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
    if "valve-demo" in args.tasks:
        valve_demo_section(seeds, args.quick, args.dapg)
    if "valve-onspoke" in args.tasks:
        valve_onspoke_section(seeds, args.quick)
    if "valve-model" in args.tasks:
        valve_model_section(args.quick)


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
    inits = ["pd"] + (["teacher"] if importlib.util.find_spec("lowcostdex.teachers.valve") else [])
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


# ----------------------------------------------------------------------------------------------
# Valve from one demonstration (tracking cost)

VALVE_ID = "lowcostdex/DClawTurnValve-v0"
DEMOS = {"exact": (0.0, 0.1), "short": (-0.3, 0.05), "long": (0.3, 0.05)}
"""demo name -> (valve offset of the recording [rad], exploration noise of the TVLG run)."""
HELD_OUT = 20  # noisy held-out episodes per evaluation


def record_demo(offset: float, path: Path) -> Path:
    """One scripted-teacher episode recorded with the valve ``offset`` [rad] from the fixed
    start (goal offset + pi), saved in the DAPG demo format."""
    from lowcostdex.algos.local_models.episodes import capture_start, hold_action, offset_start
    from lowcostdex.algos.local_models.initial import teacher_episodes
    from lowcostdex.algos.local_models.train import default_env_factory
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig

    cfg = TVLGTrainConfig(init="teacher", progress=False)
    env = default_env_factory(cfg)()
    try:
        start = capture_start(env, cfg.seed)
        shifted = offset_start(env, start, offset)
        T = env.spec.max_episode_steps + 1
        teach = teacher_episodes(env, shifted, cfg, hold_action(env, start), T, path)
        if not teach.successes.all():
            raise RuntimeError(f"the teacher failed from valve offset {offset}")
    finally:
        env.close()
    return path


def controller_success(ctl, start, cfg, n: int, noise: float | None, seed: int = 7) -> tuple:
    """(noise-free success, final |error| [rad], success rate of n noisy episodes) of a TVLG
    controller from ``start`` in ``cfg``'s env; ``noise`` replaces its exploration noise (None
    keeps it)."""
    from lowcostdex.algos.local_models.controller import LinearGaussianController
    from lowcostdex.algos.local_models.episodes import hold_action, run_episode
    from lowcostdex.algos.local_models.train import default_env_factory
    from lowcostdex.algos.samplers import RolloutJob

    if noise is not None:
        cov = np.broadcast_to(noise**2 * np.eye(ctl.dU), ctl.cov.shape)
        ctl = LinearGaussianController.from_cov(ctl.K, ctl.k, cov)
    env = default_env_factory(cfg)()
    try:
        hold = hold_action(env, start)

        def episode(job):
            return run_episode(env, ctl, start, job, cfg.include_last_action, hold, 0.0)

        nf = episode(RolloutJob(seed, 5, 0, 0, deterministic=True))
        rate = float(np.mean([episode(RolloutJob(seed, 5, 0, 1 + i)).success("final")
                              for i in range(n)]))  # fmt: skip
    finally:
        env.close()
    return nf.success("final"), abs(nf.final_error), rate


def tvlg_demo_run(demo: Path, noise: float, seed: int, n_iter: int, cost: str, out: Path):
    """A TVLG run from one demonstration; its metrics and run directory."""
    from lowcostdex.algos.local_models.train import train
    from lowcostdex.algos.local_models.train_config import (
        TRACKING_KL_STEP,
        TaskCostConfig,
        TVLGTrainConfig,
    )
    from lowcostdex.algos.local_models.traj_opt import TrajOptConfig
    from lowcostdex.algos.local_models.tvlg import TVLGConfig

    kl_step = TRACKING_KL_STEP if cost == "tracking" else TrajOptConfig().kl_step
    cfg = TVLGTrainConfig(
        seed=seed, n_iter=n_iter, init="demos", demos=str(demo), init_noise=noise,
        cost=TaskCostConfig.preset(cost), eval_noisy_episodes=HELD_OUT, progress=False,
        algo=TVLGConfig(traj_opt=TrajOptConfig(kl_step=kl_step)),
    )  # fmt: skip
    run = train(cfg, out)
    return run.read_metrics(), run.path


def initial_stats(demo: Path, noise: float) -> tuple:
    """``controller_success`` of the replayed demonstration (the iteration-0 controller)."""
    from lowcostdex.algos.local_models.episodes import capture_start, controller_state, hold_action
    from lowcostdex.algos.local_models.initial import initial_controller
    from lowcostdex.algos.local_models.train import default_env_factory
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig

    cfg = TVLGTrainConfig(init="demos", demos=str(demo), init_noise=noise, progress=False)
    env = default_env_factory(cfg)()
    try:
        start = capture_start(env, cfg.seed)
        hold = hold_action(env, start)
        env.reset(options=start.reset_options())
        x0 = controller_state(env, hold)
        ctl = initial_controller(cfg, env, start, x0, hold, env.spec.max_episode_steps + 1)
    finally:
        env.close()
    return controller_success(ctl, start, cfg, HELD_OUT, None)


def valve_demo_section(seeds: list[int], quick: bool, dapg: bool) -> None:
    from lowcostdex.algos.local_models.train import load_controller

    n_iter = 6 if quick else 10
    print(
        f"\n## D'Claw valve 180 deg, fixed start, from ONE demonstration ({VALVE_ID}, sim); "
        f"5 rollouts/iteration, {n_iter} iterations, kl_step 0.5 (tracking) / 0.2 (task); solved: "
        f"noise-free success AND >= 80 % of {HELD_OUT} held-out noisy episodes"
    )
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for name, (offset, noise) in DEMOS.items():
            demo = record_demo(offset, tmp / f"demo_{name}.h5")
            nf_ok, nf_err, rate = initial_stats(demo, noise)
            print(
                f"\n### demo '{name}' (valve {offset:+.1f} rad when recorded), exploration noise "
                f"{noise}: the replayed demo (iteration 0) noise-free |error| {nf_err:.2f} rad "
                f"(success {nf_ok}), noisy success {rate:.2f}"
            )
            costs = ["tracking"] + ([] if quick else ["task"])
            for cost in costs:
                solved_at, iter_at = [], []
                for s in seeds if cost == "tracking" else seeds[:1]:
                    m, path = tvlg_demo_run(
                        demo, noise, s, n_iter, cost, tmp / f"{name}_{cost}_{s}"
                    )
                    solved = first_solved(m["rollouts"], m["solved"] == 1.0)
                    by_iter = first_solved(
                        m["rollouts"], (m["eval_success_rate"] == 1.0) & (m["success_rate"] >= 0.8)
                    )
                    solved_at.append(solved)
                    iter_at.append(by_iter)
                    _, _, mean_rate = controller_success(*load_controller(path), HELD_OUT, noise)
                    std = controller_noise(path)
                    print(
                        f"TVLG cost={cost} seed {s}: rollouts to solved "
                        f"{fmt_count(solved, 5 * n_iter)}, to the iteration criterion "
                        f"{fmt_count(by_iter, 5 * n_iter)}; held-out noisy "
                        f"success per iteration {np.round(m['eval_noisy_success_rate'], 2).tolist()}; "
                        f"noise-free |error| {np.round(m['eval_final_abs_error'], 2).tolist()}; final "
                        f"noise std {std:.3f} (initial {noise}), final mean + noise {noise}: "
                        f"success {mean_rate:.2f}"
                    )
                med = median_rollouts(solved_at)
                print(
                    f"demo '{name}', cost={cost}: median rollouts to solved "
                    f"{fmt_count(med if np.isfinite(med) else math.nan, 5 * n_iter)}"
                )
            if dapg and name in ("exact", "short"):
                dapg_from_demo(demo, seeds[:1], 20, 10 if quick else 30, tmp / f"dapg_{name}")


def controller_noise(run_dir: Path) -> float:
    """Mean exploration std [normalised action] of a run's final controller."""
    from lowcostdex.algos.local_models.train import load_controller

    ctl, _, _ = load_controller(run_dir)
    return float(np.mean(np.sqrt(np.diagonal(ctl.cov, axis1=1, axis2=2))))


def dapg_from_demo(demo: Path, seeds: list[int], n_traj: int, n_iter: int, out: Path) -> None:
    """DAPG (BC with 300 epochs on the 40 pairs, then NPG + demo term) from one demonstration."""
    from lowcostdex.algos.bc import BCConfig
    from lowcostdex.algos.train import TrainConfig, train

    for s in seeds:
        cfg = TrainConfig(
            algo="dapg", demos=str(demo), seed=s, n_traj=n_traj, n_iter=n_iter, eval_every=1,
            eval_episodes=1, progress=False, bc=BCConfig(epochs=300),
        )  # fmt: skip
        m = train(cfg, out / f"seed{s}").read_metrics()
        episodes = (m["iteration"] + 1) * n_traj
        solved = first_solved(
            episodes, (m["eval_success_rate"] == 1.0) & (m["success_rate"] >= 0.8)
        )
        print(
            f"DAPG from the same demonstration, seed {s} ({n_traj} episodes/iteration): episodes "
            f"to eval success and >= 80 % training success {fmt_count(solved, n_iter * n_traj)}; "
            f"best training success {np.max(m['success_rate']):.2f}, best eval return "
            f"{np.max(m['eval_return_mean']):.1f}"
        )


def valve_onspoke_section(seeds: list[int], quick: bool) -> None:
    """PD hold from the teacher's pose just before its first push, task cost."""
    from lowcostdex.algos.local_models.episodes import capture_start, hold_action
    from lowcostdex.algos.local_models.initial import teacher_episodes
    from lowcostdex.algos.local_models.train import default_env_factory, train
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig

    cfg = TVLGTrainConfig(init="teacher", progress=False)
    env = default_env_factory(cfg)()
    try:
        start = capture_start(env, cfg.seed)
        teach = teacher_episodes(env, start, cfg, hold_action(env, start), 41)
    finally:
        env.close()
    theta = teach.X[0, :, 18]
    t_on = int(np.argmax(np.abs(theta) > 1e-3)) - 1
    pose = tuple(float(v) for v in teach.X[0, t_on, :9])
    n_iter = 6 if quick else 12
    print(
        f"\n## D'Claw valve 180 deg, PD hold from fingertips behind the spokes (teacher pose at "
        f"step {t_on}: {np.round(pose, 3).tolist()}), task cost, {n_iter} iterations"
    )
    for noise in (0.1, 0.3):
        for s in seeds:
            c = TVLGTrainConfig(
                seed=s, n_iter=n_iter, init="pd", init_noise=noise, start_hand_qpos=pose,
                progress=False,
            )  # fmt: skip
            with tempfile.TemporaryDirectory() as tmp:
                m = train(c, Path(tmp) / "run").read_metrics()
            turned = np.pi - np.asarray(m["eval_final_abs_error"])
            print(
                f"TVLG on-spoke PD init noise {noise} seed {s}: rollouts to noise-free success "
                f"{fmt_count(first_solved(m['rollouts'], m['eval_success_rate'] == 1.0), 5 * n_iter)}"
                f"; noise-free valve turn per iteration [rad] "
                f"{np.round(turned, 2).tolist()}"
            )


def replay(env, start, hold, actions: np.ndarray, job, noise: float = 1e-3):
    """Episode of the open-loop controller ``actions`` (T, dU) with exploration std ``noise``."""
    from lowcostdex.algos.local_models.controller import LinearGaussianController
    from lowcostdex.algos.local_models.episodes import run_episode

    T, dU = actions.shape
    cov = np.broadcast_to(noise**2 * np.eye(dU), (T, dU, dU))
    ctl = LinearGaussianController.from_cov(np.zeros((T, dU, 29)), actions, cov)
    return run_episode(env, ctl, start, job, True, hold, 0.0)


def valve_model_section(quick: bool) -> None:
    """Final-angle sensitivities: finite differences vs the TVLG model vs a linear fit."""
    from lowcostdex.algos.local_models.dynamics import (
        DynamicsConfig,
        GMMPrior,
        final_sensitivity,
        fit_dynamics,
        update_gmm_prior,
    )
    from lowcostdex.algos.local_models.episodes import capture_start, hold_action
    from lowcostdex.algos.local_models.train import _demo_actions, default_env_factory
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig
    from lowcostdex.algos.samplers import RolloutJob

    steps, h, n_fit, obj = np.arange(10, 38), 0.05, 150 if quick else 600, 18
    det = RolloutJob(0, 5, 0, 0, deterministic=True)
    print(
        f"\n## Why the local models fail: sensitivity of the final valve angle to the actions "
        f"at steps {steps[0]}-{steps[-1]} (9 joints), finite differences (h = {h}) vs the TVLG "
        f"model from 5 rollouts vs a linear fit on {n_fit} noisy rollouts"
    )
    cfg = TVLGTrainConfig(progress=False)
    env = default_env_factory(cfg)()
    try:
        start = capture_start(env, cfg.seed)
        hold = hold_action(env, start)
        with tempfile.TemporaryDirectory() as tmp:
            for name in ("short", "long"):
                demo = record_demo(DEMOS[name][0], Path(tmp) / f"{name}.h5")
                U0 = _demo_actions(str(demo), 41)[0]
                T, dU = U0.shape

                def angle(offsets: np.ndarray, U0: np.ndarray = U0) -> float:
                    return float(replay(env, start, hold, U0 + offsets, det).X[-1, obj])

                fd = np.zeros((len(steps), dU))
                for i, t in enumerate(steps):
                    for j in range(dU):
                        e = np.zeros((T, dU))
                        e[t, j] = h
                        fd[i, j] = (angle(e) - angle(-e)) / (2 * h)
                for noise in (0.05, 0.02):
                    Z = noise * np.random.default_rng(1).standard_normal((n_fit, T, dU))
                    theta = np.array([angle(z) for z in Z])
                    A = np.c_[Z[:, steps].reshape(n_fit, -1), np.ones(n_fit)]
                    coef = np.linalg.lstsq(A, theta, rcond=None)[0]
                    r2 = 1 - np.var(theta - A @ coef) / np.var(theta)
                    r2_adj = 1 - (1 - r2) * (n_fit - 1) / (n_fit - A.shape[1])
                    eps = [replay(env, start, hold, U0, RolloutJob(0, 0, 0, i), noise)
                           for i in range(5)]  # fmt: skip
                    X, U = np.stack([e.X for e in eps]), np.stack([e.U for e in eps])
                    dc = DynamicsConfig()
                    prior = update_gmm_prior(
                        GMMPrior.empty(T, X.shape[2], dU), X, U, dc, np.random.default_rng(0)
                    )
                    model = final_sensitivity(fit_dynamics(X, U, dc, prior.gmm).F, obj)[steps]
                    fit = coef[:-1].reshape(len(steps), dU)
                    print(
                        f"demo '{name}', noise {noise}: final angle {theta.mean():.2f} +- "
                        f"{theta.std():.2f} rad; linear fit R^2 {r2:.2f} in sample, adjusted "
                        f"{r2_adj:.2f} ({A.shape[1] - 1} regressors), corr(fit, "
                        f"FD) {np.corrcoef(fd.ravel(), fit.ravel())[0, 1]:.2f}; corr(TVLG model, "
                        f"FD) {np.corrcoef(fd.ravel(), model.ravel())[0, 1]:.2f}, |model| / |FD| "
                        f"{np.linalg.norm(model) / np.linalg.norm(fd):.1f}"
                    )
    finally:
        env.close()


if __name__ == "__main__":
    main()
