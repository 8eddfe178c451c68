"""Fit a finger base's mounting tilt from a valve-turning log (issue 14, transfer14).

Recording (evaluation side): the hidden robot plays the goals of a transfer folder's first N
playback demonstrations (4 s each) and its valve encoder is logged; the robot's definition only
builds the emulator. Fit (training side): the nominal emulated D'Claw, no effects, the finger's
base tilted by ``lowcostdex.transfer.tilt.tilt_body``, fitted by ``fit_tilt``. The truth is
printed after the fit for comparison.

    python bench/transfer_tilt.py RUN_FOLDER C th 8
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import lowcostdex.sim  # noqa: F401
from lowcostdex.transfer import valve_fit
from lowcostdex.transfer.tilt import fit_tilt, tilt_body


def playback_goals(folder: str, n: int) -> list[tuple[int, np.ndarray]]:
    """The first ``n`` playback demonstrations of ``folder``'s demos.h5 (one per seed)."""
    return valve_fit.playback_goals(Path(folder) / "demos.h5", n)


def valve_trace(eps: list[tuple[int, np.ndarray]], **env_kwargs) -> np.ndarray:
    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated", **env_kwargs)
    out = []
    for seed, actions in eps:
        env.reset(seed=seed)
        for a in actions:
            env.step(a)
            out.append(env.unwrapped.backend.observed_qpos()[9])  # the valve's encoder [rad]
    env.close()
    return np.unwrap(np.asarray(out, float))


def main() -> None:
    from lowcostdex.hardware.emulated.hidden_robots import hidden_robot

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", help="a transfer run folder with demos.h5")
    p.add_argument("robot", choices=("A", "B", "C"))
    p.add_argument("finger", choices=("ff", "mf", "th"))
    p.add_argument("episodes", type=int, nargs="?", default=8)
    p.add_argument("--iterations", type=int, default=6)
    args = p.parse_args()
    eps = playback_goals(args.folder, args.episodes)
    robot = hidden_robot("ABC".index(args.robot), args.robot)
    observed = valve_trace(eps, motor=robot.motor, effects=list(robot.effects),
                           imperfection=robot.firmware, modify_model=robot.model.apply)
    t0 = time.process_time()
    fit = fit_tilt(lambda a: valve_trace(eps, motor=robot.motor, modify_model=lambda spec: tilt_body(
        spec, f"{args.finger}_base", a)), observed, iterations=args.iterations, step=5e-3)
    print(f"{args.robot} {args.finger}: tilt {fit.angles.round(4).tolist()} rad, 95 % "
          f"{fit.intervals.round(4).tolist()}, named {fit.named}, valve RMS "
          f"{1e3 * fit.rms_before:.1f} -> {1e3 * fit.rms_after:.1f} mrad, "
          f"CPU {time.process_time() - t0:.0f} s")
    truth = robot.model.base_tilt.get(args.finger)  # evaluation only
    vec = (np.asarray(truth[0])[:2] * truth[1]).round(4).tolist() if truth else [0.0, 0.0]
    print(f"truth (evaluation only): {vec} rad")


if __name__ == "__main__":
    main()
