"""Truncated NPG turns the D'Claw valve 180 deg in simulation.

    python demos/npg_valve.py                        # short run, a few minutes on 2 cores
    python demos/npg_valve.py --n-iter 400 --out runs/npg_valve
    python demos/npg_valve.py --backend emulated             # the emulated D'Claw on its bus
    python demos/npg_valve.py --backend hardware --port /dev/ttyUSB0
    python demos/npg_valve.py --out runs/npg_valve --resume   # continue after a kill

The same run from the command line:

    lowcostdex train npg --env lowcostdex/DClawTurnValve-v0 --out runs/npg_valve

The run directory holds config.json, metrics.csv, checkpoints/, policy.pt and
learning_curves.png (success rate and return vs samples and vs robot-equivalent hours).
``--backend emulated`` trains on the emulated Dynamixel D'Claw at its real control rate,
``--backend hardware --port PORT`` on a real one.
"""

from __future__ import annotations

import argparse

from lowcostdex.algos import experiment
from lowcostdex.algos.train import TrainConfig, train
from lowcostdex.algos.train_cli import check_resume
from lowcostdex.cli import run_script
from lowcostdex.options import add_robot_options, add_run_options, robot_selection


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_options(parser, default_backend="sim", env="lowcostdex/DClawTurnValve-v0")
    add_run_options(parser, out="runs/npg_valve", n_iter=60, n_traj=40)
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    backend, env_kwargs = robot_selection(args.backend, args.port)
    check_resume(args.out, args.resume)  # --resume of a folder with no run: a typo in --out

    config = TrainConfig(
        algo="npg",
        env_id=args.env,
        backend=backend,
        env_kwargs=env_kwargs,
        seed=args.seed,
        n_iter=args.n_iter,
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
    run_script(main, on_interrupt="the same command with --resume continues it")
