"""Flip a block 180 deg with NPG: keypoint vs position+quaternion observations and rewards.

    python demos/flip_keypoints_vs_quaternion.py --n-iter 100 --out runs/flip
    python demos/flip_keypoints_vs_quaternion.py --backend emulated   # on the emulated D'Claw

Trains the same NPG configuration (same seed, same budget) on ``DClawFlipBlock-v0`` (8 cube-corner
keypoints in the observation and the reward) and ``DClawFlipBlockQuaternion-v0`` (position and
quaternion), then plots success rate and final orientation error (the returns of the two reward
definitions are not comparable) in ``<out>/keypoints_vs_quaternion.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from lowcostdex.algos import experiment
from lowcostdex.algos.train import TrainConfig, train
from lowcostdex.cli import run_script
from lowcostdex.options import add_robot_options, add_run_options, robot_selection

VARIANTS = {
    "keypoints": "lowcostdex/DClawFlipBlock-v0",
    "quaternion": "lowcostdex/DClawFlipBlockQuaternion-v0",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_robot_options(parser, default_backend="sim")
    add_run_options(parser, out="runs/flip", n_iter=40, n_traj=40)
    args = parser.parse_args()
    backend, env_kwargs = robot_selection(args.backend, args.port)

    out = Path(args.out)
    curves = {}
    for name, env_id in VARIANTS.items():
        config = TrainConfig(
            env_id=env_id, backend=backend, env_kwargs=env_kwargs, seed=args.seed,
            n_iter=args.n_iter, n_traj=args.n_traj, eval_every=10,
        )
        curves[name] = train(
            config, out / name, resume=(out / name / "config.json").exists()
        ).read_metrics()

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, m in curves.items():
        axes[0].plot(m[experiment.SAMPLES], m[experiment.SUCCESS_RATE], label=name)
        axes[1].plot(m[experiment.SAMPLES], m["goal_error_final"], label=name)
        print(
            f"{name:>10}: final training success {m[experiment.SUCCESS_RATE][-1]:.2f}, "
            f"eval success {m[experiment.EVAL_SUCCESS_RATE][-1]:.2f}"
        )
    axes[0].set_ylabel("success rate (training)")
    axes[1].set_ylabel("final orientation error [rad]")
    for ax in axes:
        ax.set_xlabel("samples (env steps)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper left")
    axes[1].legend(loc="upper right")
    fig.suptitle("NPG on the D'Claw block flip: observation representation")
    fig.tight_layout()
    fig.savefig(out / "keypoints_vs_quaternion.png", dpi=100)
    print(f"plot: {out / 'keypoints_vs_quaternion.png'}")


if __name__ == "__main__":
    run_script(main, on_interrupt="the same command continues it (it resumes the runs in --out)")
