"""Turn the D'Claw valve with learned local models (TVLG dynamics + KL-constrained iLQG).

Trains a time-varying linear-Gaussian controller from a fixed start state with 5 rollouts per
iteration (``lowcostdex train tvlg`` underneath), printing the valve angle each iteration, then
replays the final controller without noise.

Initial controller (``--init``):
  teacher  one episode of the scripted valve teacher, replayed open loop with exploration noise
           (default when ``lowcostdex.sim.scripted`` exists); TVLG then refines it locally.
  pd       hold the start pose with exploration noise. From there local models do not find the
           multi-stroke gait a 180 deg turn needs within ~60 rollouts (see bench/RESULTS.md).

Backends: ``--backend sim`` (default; the valve turns), ``emulated`` (the MuJoCo-emulated
Dynamixel bus: runs, but the first local-model update currently breaks the teacher's turn there,
see bench/RESULTS.md) and ``hardware`` with ``--port``.

    python demos/tvlg_turn_valve.py --out runs/tvlg_valve
    python demos/tvlg_turn_valve.py --init pd --n-iter 12 --out runs/tvlg_valve_pd
"""

from __future__ import annotations

import argparse
import importlib.util
import math

import numpy as np

from lowcostdex.algos.local_models.train import (
    TVLGTrainConfig,
    controller_state,
    default_env_factory,
    hold_action,
    load_controller,
    run_episode,
    train,
)
from lowcostdex.algos.samplers import EVAL_STREAM, RolloutJob


def main() -> None:
    has_teacher = importlib.util.find_spec("lowcostdex.sim.scripted") is not None
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--out", required=True, help="run directory (must not exist, or use --resume)"
    )
    parser.add_argument("--backend", choices=("sim", "emulated", "hardware"), default="sim")
    parser.add_argument("--port", default=None, help="serial port (hardware backend)")
    parser.add_argument(
        "--init", choices=("teacher", "pd"), default="teacher" if has_teacher else "pd"
    )
    parser.add_argument("--n-iter", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()

    config = TVLGTrainConfig(
        backend=args.backend,
        env_kwargs={"port": args.port} if args.port else {},
        seed=args.seed,
        n_iter=args.n_iter,
        init=args.init,
        init_noise=0.05 if args.init == "teacher" else 0.3,
    )
    print(
        f"TVLG on {config.env_id} ({config.backend}), init={config.init}, "
        f"{config.n_rollouts} rollouts/iteration, {config.n_iter} iterations"
    )
    run = train(config, args.out, resume=args.resume)
    m = run.read_metrics()
    for k in range(len(m["iteration"])):
        print(
            f"iteration {int(m['iteration'][k]):2d}  rollouts {int(m['rollouts'][k]):3d}  "
            f"training success {m['success_rate'][k]:.1f}  mean final |error| "
            f"{m['final_abs_error'][k]:.2f} rad  noise-free final |error| {m['eval_final_abs_error'][k]:.2f} rad"
            f"  cost {m['sample_cost'][k]:.1f}  KL {m['kl'][k]:.1f}/{m['epsilon'][k]:.1f}"
        )

    controller, start, cfg = load_controller(run.path)
    env = default_env_factory(cfg)()
    hold = hold_action(env, start)
    episode = run_episode(env, controller, start, RolloutJob(cfg.seed, EVAL_STREAM, 10**6, 0, True),
                          cfg.include_last_action, hold, 0.0)  # fmt: skip
    theta = episode.X[:, 2 * len(hold)]
    env.reset(options=start.reset_options())
    assert np.allclose(
        controller_state(env, hold if cfg.include_last_action else None), episode.X[0]
    )
    env.close()
    print(
        "noise-free replay, valve angle [deg] every 5 steps:",
        np.round(np.degrees(theta[::5])).astype(int).tolist(),
    )
    print(
        f"goal {math.degrees(float(start.goal['angle'])):.0f} deg, final error "
        f"{math.degrees(episode.final_error):.1f} deg, success {episode.success('final')}"
    )
    print(
        f"run directory: {run.path} (metrics.csv, learning_curves.png, checkpoints/, controller.npz)"
    )


if __name__ == "__main__":
    main()
