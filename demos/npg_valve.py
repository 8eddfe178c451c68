"""Truncated NPG turns the D'Claw valve 180 deg in simulation.

    python demos/npg_valve.py                        # short run, a few minutes on 2 cores
    python demos/npg_valve.py --iters 400 --out runs/npg_valve
    python demos/npg_valve.py --out runs/npg_valve --resume   # continue after a kill

The same run from the command line:

    lowcostdex train npg --env lowcostdex/DClawTurnValve-v0 --out runs/npg_valve

The run directory holds config.json, metrics.csv, checkpoints/, policy.pt and
learning_curves.png (success rate and return vs samples and vs robot-equivalent hours).
Add ``--backend emulated`` to train on the emulated Dynamixel D'Claw at its real control rate.
"""

from __future__ import annotations

import argparse

from lowcostdex.algos import experiment
from lowcostdex.algos.train import TrainConfig, train


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iters", type=int, default=60)
    parser.add_argument("--n-traj", type=int, default=40, help="trajectories per iteration")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--backend", default="sim", choices=("sim", "emulated", "hardware"))
    parser.add_argument("--out", default="runs/npg_valve")
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()

    config = TrainConfig(
        algo="npg",
        env_id="lowcostdex/DClawTurnValve-v0",
        backend=args.backend,
        seed=args.seed,
        n_iter=args.iters,
        n_traj=args.n_traj,
        eval_every=10,
    )
    run = train(config, args.out, resume=args.resume)
    m = run.read_metrics()
    print(
        f"{int(m[experiment.SAMPLES][-1])} samples, {m[experiment.ROBOT_HOURS][-1]:.2f} robot hours"
    )
    print(
        f"success: training {m[experiment.SUCCESS_RATE][-1]:.2f}, "
        f"evaluation {m[experiment.EVAL_SUCCESS_RATE][-1]:.2f}"
    )
    print(f"learning curves: {run.path / experiment.CURVES_FILE}")


if __name__ == "__main__":
    main()
