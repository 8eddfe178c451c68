"""Fit a finger base's mounting tilt JOINTLY with the valve's friction, damping and inertia on the
identified model, from a valve-turning log (issue 14, transfer15; ``transfer.tilt_joint``).

Recording (evaluation side): the hidden robot plays the goals of a transfer folder's first N
playback demonstrations (4 s each) and its valve encoder is logged; the robot's definition only
builds the emulator. Fit (training side): the simulation that condition (c) trains in - the
nominal D'Claw plus the servo effects ``gap analyze`` identified from the robot's identification
logs (``FOLDER/identify/ROBOT/<finger>/finger.json``; ``--no-identified``: nominal) - with the
finger's base tilted (``tilt.tilt_body``), the valve hinge's frictionloss (added [N m]),
damping (factor) and inertia (factor on its armature and masses), and each finger's link lengths
(a factor on its joint-to-joint and tip distances: a few % of manufacturing tolerance moves
where a fingertip meets a spoke as much as the tilt does) as parameters. The truth is
printed after the fits, for comparison only. The profile intervals are the paired test across
the episodes (``groups``); the likelihood-ratio ones are printed beside them.

    python bench/transfer_tilt_joint.py RUN_FOLDER C --fingers th ff mf --episodes 8
    python bench/transfer_tilt_joint.py RUN_FOLDER C --fingers th --episodes 5 --varied

``--varied``: the product's valve log (``valve_fit.valve_episodes``: the k-th playback played as
``valve_fit.DESIGNS[k % 5]``: as recorded, fast, slow, stop-and-go, twice) instead of the
playbacks as recorded (transfer15/16's 8 near-duplicates).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import lowcostdex.sim  # noqa: F401
from lowcostdex.transfer.tilt_joint import fit_tilt_jointly
from lowcostdex.transfer.valve_fit import (  # the product's fit pieces
    FINGERS,
    LOWER,
    NAMES,
    STEP,
    UPPER,
    X0,
    edit_from_params,
    episode_sse,
    pick_finger,
    valve_episodes,
)


def edit_model(finger: str, x: np.ndarray):
    """The training side's edit of a D'Claw valve spec for parameters ``x`` (NAMES)."""
    return edit_from_params(finger, x).apply


def lr_hull(grid: np.ndarray, sse: np.ndarray, threshold: float) -> list[float]:
    """The likelihood-ratio interval of a profile (``tilt_joint``'s rule without groups)."""
    from lowcostdex.transfer.tilt_joint import _hull

    return list(_hull(grid, sse, sse <= threshold))


def identified_randomize(folder: Path, robot: str, condition: str = "identified"
                         ) -> dict | None:
    """Condition (c)'s model of the robot: its identified causes held fixed (``condition``
    "identified_randomized": (d)'s narrow ranges around them)."""
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.transfer.conditions import condition_randomize

    fingers = {f: json.loads((folder / "identify" / robot / f / "finger.json").read_text())
               for f in ("ff", "mf", "th")}
    return condition_randomize(condition, {"fingers": fingers}, dclaw_spec().joint_names)


def sim_trace(eps, edit, randomize) -> np.ndarray:
    """The valve encoder of the episodes replayed in the simulation (sim backend)."""
    from lowcostdex.sim.effects import DomainRandomization
    from lowcostdex.sim.envs.dclaw_tasks import TurnValve
    from lowcostdex.sim.envs.hand_env import HandEnv

    class Edited(TurnValve):
        def build_spec(self):
            spec = super().build_spec()
            edit(spec)
            return spec

    dr = None if randomize is None else DomainRandomization.from_dict(randomize)
    env = HandEnv(Edited(), randomization=dr)
    out = []
    for seed, actions in eps:
        env.reset(seed=seed)
        for a in actions:
            env.step(a)
            out.append(env.backend.observed_qpos()[9])
    env.close()
    return np.unwrap(np.asarray(out, float))


def main() -> None:
    from transfer_tilt import playback_goals, valve_trace

    from lowcostdex.hardware.emulated.hidden_robots import hidden_robot

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="a transfer run folder with demos.h5 (+ identify/)")
    p.add_argument("robot", choices=("A", "B", "C"))
    p.add_argument("--fingers", nargs="+", default=["th", "ff", "mf"])
    p.add_argument("--episodes", type=int, default=8)
    p.add_argument("--no-identified", action="store_true", help="fit on the nominal model")
    p.add_argument("--grid", type=int, default=9, help="tilt grid points per axis over +-0.1")
    p.add_argument("--profile-points", type=int, default=13)
    p.add_argument("--profile-iterations", type=int, default=2)
    p.add_argument("--varied", action="store_true",
                   help="the episodes of valve_fit.DESIGNS (default: playbacks as recorded)")
    p.add_argument("--out", type=Path, help="write the fits as JSON here")
    args = p.parse_args()
    eps = (valve_episodes(args.folder / "demos.h5", args.episodes) if args.varied
           else playback_goals(str(args.folder), args.episodes))
    robot = hidden_robot("ABC".index(args.robot), args.robot)
    kwargs = {k: v for k, v in robot.env_kwargs().items() if k != "backend"}
    observed = valve_trace(eps, **kwargs)  # evaluation side: the robot records
    randomize = None if args.no_identified else identified_randomize(args.folder, args.robot)
    rows = []
    lengths = [len(a) for _, a in eps]
    for finger in args.fingers:
        t0 = time.process_time()
        fit = fit_tilt_jointly(
            lambda x, f=finger: sim_trace(eps, edit_model(f, x), randomize), observed,
            X0, LOWER, UPPER, STEP, grid=np.linspace(-0.1, 0.1, args.grid),
            profile_points=args.profile_points, profile_iterations=args.profile_iterations,
            groups=np.repeat(np.arange(len(eps)), [len(a) for _, a in eps]))
        cpu = time.process_time() - t0
        row = {"robot": args.robot, "finger": finger, "identified": randomize is not None,
               "values": fit.values.tolist(), "intervals": fit.intervals.tolist(),
               "named": fit.named, "rms_start_mrad": 1e3 * fit.rms_start,
               "rms_fit_mrad": 1e3 * fit.rms_fit, "n_eff": fit.n_eff,
               "grid_best": fit.grid_best.tolist(), "evaluations": fit.evaluations,
               "cpu_seconds": round(cpu, 1),
               "profiles": [[g.tolist(), (1e3 * np.sqrt(s / observed.size)).tolist()]
                            for g, s in fit.profiles],
               "threshold_rms_mrad": 1e3 * float(np.sqrt(fit.threshold / observed.size)),
               "paired_inside": [m.tolist() for m in fit.inside],
               # the likelihood-ratio intervals (samples counted as n_eff), for comparison
               "lr_intervals": [lr_hull(g, s, fit.threshold) for g, s in fit.profiles]}
        fitted = sim_trace(eps, edit_model(finger, fit.values), randomize)
        row["episode_sse"] = episode_sse(fitted, observed, lengths)
        rows.append(row)
        print(f"{args.robot} {finger}: " + ", ".join(
            f"{n} {v:.4f} [{lo:.4f}, {hi:.4f}]" for n, v, (lo, hi)
            in zip(NAMES, fit.values, fit.intervals, strict=True))
            + f"; LR intervals {np.round(row['lr_intervals'], 4).tolist()}"
            + f"; named {fit.named}; valve RMS {1e3 * fit.rms_start:.1f} -> "
            f"{1e3 * fit.rms_fit:.1f} mrad (n_eff {fit.n_eff:.0f}); {fit.evaluations} replays, "
            f"CPU {cpu:.0f} s", flush=True)
    choice = pick_finger(rows)
    print(f"{args.robot}: the valve log names a tilt of: {choice}")
    truth = robot.model  # evaluation only, after the fits
    tilts = {f: (np.asarray(a)[:2] * t).round(4).tolist() for f, (a, t) in truth.base_tilt.items()}
    print(f"truth (evaluation only): tilt {tilts} rad; valve frictionloss + "
          f"{truth.valve_frictionloss:.4f} N m, damping x {truth.valve_damping:.3f}, inertia x "
          f"{truth.valve_inertia:.3f}; link lengths x "
          f"{ {f: round(v, 4) for f, v in truth.link_length.items()} }")
    for row in rows:  # the fit side's cost at the truth (evaluation only)
        f = row["finger"]
        axis, angle = truth.base_tilt.get(f, ((0.0, 0.0, 0.0), 0.0))
        xt = np.array([*(np.asarray(axis)[:2] * angle), truth.valve_frictionloss,
                       truth.valve_damping, truth.valve_inertia,
                       *(truth.link_length[g] for g in FINGERS)])
        at = sim_trace(eps, edit_model(f, xt), randomize)
        row["rms_truth_mrad"] = 1e3 * float(np.sqrt(np.mean((at - observed) ** 2)))
        row["episode_sse_truth"] = episode_sse(at, observed, lengths)
        print(f"{args.robot} {f}: valve RMS at the truth {row['rms_truth_mrad']:.1f} mrad "
              f"(fit {row['rms_fit_mrad']:.1f})")
    if args.out:
        args.out.write_text(json.dumps({"fits": rows, "named_finger": choice, "truth": {
            "tilt": tilts, "valve_frictionloss": truth.valve_frictionloss,
            "valve_damping": truth.valve_damping, "valve_inertia": truth.valve_inertia,
            "link_length": truth.link_length}},
            indent=1))


if __name__ == "__main__":
    main()
