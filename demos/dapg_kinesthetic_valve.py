"""DAPG on the D'Claw valve from kinesthetic demonstrations recorded on the emulated robot.

    python demos/dapg_kinesthetic_valve.py                     # emulated robot, short budget
    python demos/dapg_kinesthetic_valve.py --n-iter 60 --backend sim --out runs/dapg_valve
    python demos/dapg_kinesthetic_valve.py --backend hardware --port /dev/ttyUSB0  # you teach

1. Record demonstrations the way the BAIR D'Claw work did: the emulated D'Claw comes up on its
   Dynamixel bus, auto-resets before every episode, its fingers go limp, and the emulator's
   virtual teacher moves them through a valve turn while the joint angles are recorded
   (``lowcostdex record-demos --port emulated``; with a real robot a person moves the fingers).
   Each step is labelled with the servo goal that reproduces it, and each successful
   demonstration is played back twice by the servos with noisy goals (the clone's data).
2. Train DAPG: behaviour cloning on the demos, then NPG with the decaying demo term, on the
   emulated robot at its real control rate (auto-reset and thermal guard between episodes), on
   a real D'Claw (``--backend hardware --port PORT``; a person moves the fingers in step 1) or,
   faster, in simulation (demonstrations still recorded on the emulated robot). Progress shows samples, success, robot hours and thermal pauses.

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
from lowcostdex.algos.train import TrainConfig, check_env_id, train
from lowcostdex.argtypes import path
from lowcostdex.cli import main as lowcostdex
from lowcostdex.cli import run_script
from lowcostdex.demonstrations.file import read_episodes
from lowcostdex.options import add_robot_options, add_run_options, robot_selection


def demos_option(text: str) -> int | Path:
    """``--demos``: how many demonstrations to record (an integer >= 1), or your own demo file."""
    if text.strip().lstrip("+-").isdigit():
        count = int(text)
        if count < 1:
            raise argparse.ArgumentTypeError(f"{text!r}: record at least 1 demonstration")
        return count
    return Path(path(text))  # "" is no file (an unset shell variable), not the current folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demos", type=demos_option, default=25,
                        help="demonstrations to record (default %(default)s), or the path of "
                             "your own demonstration file (HDF5, lowcostdex record-demos)")
    add_robot_options(parser, default_backend="emulated", env="lowcostdex/DClawTurnValve-v0")
    add_run_options(parser, out="runs/dapg_kinesthetic_valve", n_iter=10, n_traj=20)
    args = parser.parse_args()
    backend, env_kwargs = robot_selection(args.backend, args.port)

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        parser.error(f"--out {out} is a file; give a folder")
    mine = isinstance(args.demos, Path)
    demos = args.demos if mine else out / "valve_demos.h5"
    if mine and not demos.is_file():
        parser.error(f"--demos {demos}: no such file (give a demonstration file, or a number "
                     "of demonstrations to record)")

    config = TrainConfig(  # checked before minutes of recording
        algo="dapg",
        env_id=args.env,
        backend=backend,
        env_kwargs=env_kwargs,
        demos=str(demos),
        seed=args.seed,
        n_iter=args.n_iter,
        n_traj=args.n_traj,
        eval_every=5,
        eval_bc=True,
        bc=BCConfig(epochs=100, log_std="residual"),  # the main job's: ~1000 pairs
    )
    check_env_id(config.env_id)
    if not demos.exists():
        out.mkdir(parents=True, exist_ok=True)
        code = lowcostdex(["record-demos", "--port", args.port or "emulated", "--task", "turn-valve",
                           "--episodes", str(args.demos), "--out", str(demos)])  # fmt: skip
        if code:
            raise SystemExit(code)

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
    run_script(main, on_interrupt="the same command continues it (it resumes the run in --out)")
