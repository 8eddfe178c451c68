"""DAPG on the D'Claw valve from kinesthetic demonstrations recorded on the emulated robot.

    python demos/dapg_kinesthetic_valve.py                     # emulated robot, short budget
    python demos/dapg_kinesthetic_valve.py --iters 60 --backend sim --out runs/dapg_valve

1. Record demonstrations the way the BAIR D'Claw work did: the emulated D'Claw comes up on its
   Dynamixel bus, auto-resets before every episode, its fingers go limp, and the emulator's
   virtual teacher moves them through a valve turn while the joint angles are recorded
   (``lowcostdex record-demos --port emulated``; with a real robot a person moves the fingers).
   Each step is labelled with the servo goal that reproduces it, and each successful
   demonstration is played back twice by the servos with noisy goals (the clone's data).
2. Train DAPG: behaviour cloning on the demos, then NPG with the decaying demo term, on the
   emulated robot at its real control rate (auto-reset and thermal guard between episodes) or,
   faster, in simulation. Progress shows samples, success, robot hours and thermal pauses.

The same from the command line:

    lowcostdex record-demos --port emulated --episodes 25 --out runs/valve_demos.h5
    lowcostdex train dapg --env lowcostdex/DClawTurnValve-v0 --backend emulated \\
        --demos runs/valve_demos.h5 --out runs/dapg_valve
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lowcostdex.algos import experiment
from lowcostdex.algos.configs import BCConfig
from lowcostdex.algos.train import TrainConfig, train
from lowcostdex.cli import main as lowcostdex
from lowcostdex.demo_file import read_episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demos", type=int, default=25, help="demonstrations to record")
    parser.add_argument("--iters", type=int, default=10)
    parser.add_argument("--n-traj", type=int, default=20, help="trajectories per iteration")
    parser.add_argument("--backend", default="emulated", choices=("emulated", "sim"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="runs/dapg_kinesthetic_valve")
    args = parser.parse_args()

    out = Path(args.out)
    demos = out / "valve_demos.h5"
    if not demos.exists():
        code = lowcostdex(["record-demos", "--port", "emulated", "--task", "turn-valve",
                           "--episodes", str(args.demos), "--out", str(demos)])  # fmt: skip
        if code:
            raise SystemExit(code)

    config = TrainConfig(
        algo="dapg",
        env_id="lowcostdex/DClawTurnValve-v0",
        backend=args.backend,
        demos=str(demos),
        seed=args.seed,
        n_iter=args.iters,
        n_traj=args.n_traj,
        eval_every=5,
        eval_bc=True,
        bc=BCConfig(epochs=100, log_std="residual"),  # the main job's: ~1000 pairs
    )
    run_dir = out / f"dapg_{args.backend}"
    run = train(config, run_dir, resume=(run_dir / "config.json").exists())
    m = run.read_metrics()
    bc = experiment.read_json(run.path / "bc.json")
    used = read_episodes(demos, only_successful=True)
    played = sum(e.source == "playback" for e in used)
    print(
        f"BC on {len(used) - played} demos + {played} playbacks ({bc['n_pairs']} pairs): loss "
        f"{bc['bc_loss_before']:.3f} -> {bc['bc_loss_after']:.4f}; the clone alone: success "
        f"{bc['eval_success_rate']:.2f}"
    )
    print(
        f"{int(m[experiment.SAMPLES][-1])} samples, {m[experiment.ROBOT_HOURS][-1]:.2f} robot hours "
        f"({m['thermal_pause_hours'][-1]:.2f} h thermal pauses)"
    )
    print(
        f"success: training {m[experiment.SUCCESS_RATE][-1]:.2f}, "
        f"evaluation {m[experiment.EVAL_SUCCESS_RATE][-1]:.2f}"
    )
    print(f"learning curves: {run.path / experiment.CURVES_FILE}")


if __name__ == "__main__":
    main()
