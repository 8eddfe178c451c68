"""Why does identified + narrow DR (d) end farther from the goal than identified (c)? (issue 14)

On a ``lowcostdex transfer`` folder whose identified (c) and identified_randomized (d) policies of
one robot and seed are trained, this prints:

1. the narrow ranges (d) trains in, per named effect, parameter and joint: the identified value,
   its 95 % interval, the range drawn from and its relative width, and whether the interval or
   the +-10 % floor (``NARROW_PAD``) set it;
2. each of the two policies in each of the two training sims (c's fixed values, d's ranges) and
   on the robot (the folder's cells): does (c)'s policy fail under (d)'s randomization, does
   (d)'s policy end off the goal in (c)'s sim already?
3. with ``--variants``: (d) retrained (same seed, demonstrations and budget) with the ranges
   scaled about the identified value (``scale0.5``: half as wide) and with one named effect
   randomized at a time (the others fixed at their identified values) and with the fitted
   intervals alone (``intervals``: no +-10 % floor), each evaluated on the
   robot and in (c)'s sim.

    python bench/transfer_narrow.py --out bench_runs/sr002 --robot A --seed 0 \\
        --scratch /tmp/narrow --variants scale0.5,only_latency,only_gain_error

Trainings go to ``--scratch`` (the transfer folder refuses files it did not write); a variant
found trained there is only evaluated. Record findings in bench/RESULTS.md ("Transfer table").
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np


def scaled(randomize: dict, values: dict, scale: float | None, only: str | None,
           intervals: bool = False) -> dict:
    """(d)'s ranges scaled by ``scale`` about the identified value, or every effect but
    ``only`` held at its identified value, or (``intervals``) the fitted 95 % intervals alone
    (no +-10 % floor)."""
    out = json.loads(json.dumps(randomize))
    for name, params in out["ranges"].items():
        for p, (lo, hi) in params.items():
            v = np.asarray(values[name][p][0], float)
            lo, hi = np.asarray(lo, float), np.asarray(hi, float)
            if intervals:
                a, b = (np.asarray(x, float) for x in values[name][p][1:])
                a, b = np.where(np.isfinite(a), a, v), np.where(np.isfinite(b), b, v)
                lo, hi = np.minimum(a, v), np.maximum(b, v)
            elif only is not None and name != only:
                lo, hi = v, v
            elif scale is not None:
                lo, hi = v - scale * (v - lo), v + scale * (hi - v)
            params[p] = [lo.tolist(), hi.tolist()]
    return out


def ranges_lines(ident: dict, joints: tuple[str, ...]) -> list[str]:
    from lowcostdex.sim.effects import effect
    from lowcostdex.transfer.conditions import condition_randomize, identified_effects
    from lowcostdex.transfer.config import NARROW_PAD

    table = identified_effects(ident, joints)
    d = condition_randomize("identified_randomized", ident, joints)
    lines = []
    for name, params in table.items():
        for p, (value, lo, hi) in params.items():
            null = effect(name).param(p).null
            low, high = d["ranges"][name][p]
            for k, j in enumerate(joints):
                if value[k] == null:
                    continue
                width = (high[k] - low[k]) / max(abs(value[k]), 1e-12)
                source = ("interval" if (lo[k] < value[k] - NARROW_PAD * abs(value[k]) or
                                         hi[k] > value[k] + NARROW_PAD * abs(value[k]))
                          else "10 % floor")
                lines.append(f"{name:22s} {p:10s} {j:10s} value {value[k]:9.4g}  interval "
                             f"[{lo[k]:.4g}, {hi[k]:.4g}]  drawn from [{low[k]:.4g}, "
                             f"{high[k]:.4g}] (width {100 * width:.0f} % of the value; "
                             f"{source})")
    return lines


def main() -> None:
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.transfer.conditions import condition_randomize, identified_effects
    from lowcostdex.transfer.loop import (
        TASKS,
        evaluate,
        make_robots,
        read_json,
        size_with,
        train_policy,
    )

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="a lowcostdex transfer folder")
    p.add_argument("--robot", default="A")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--scratch", default=None, help="folder for the variants' trainings")
    p.add_argument("--variants", default="",
                   help="comma-separated: scaleS (ranges x S about the value), intervals (the "
                        "fitted intervals without the 10 %% floor), only_EFFECT (the others "
                        "fixed)")
    p.add_argument("--json", default=None, help="write the results here")
    args = p.parse_args()
    out = Path(args.out)
    settings = read_json(out / ".lowcostdex.json")["settings"]
    task = TASKS[settings["task"]]
    train_task = task.training(settings.get("start_range", 0.0))
    joints = dclaw_spec().joint_names
    fingers = {f.name: read_json(f / "finger.json")
               for f in sorted((out / "identify" / args.robot).iterdir()) if f.is_dir()}
    ident = {"fingers": fingers}
    c_sim = condition_randomize("identified", ident, joints)
    d_sim = condition_randomize("identified_randomized", ident, joints)
    robot = make_robots(ord(args.robot) - ord("A") + 1, settings.get("robot_seed") or 0)[-1]
    t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
    print(f"narrow ranges of robot {args.robot}:")
    for line in ranges_lines(ident, joints):
        print("  " + line)
    results: dict[str, dict] = {}

    def show(label: str, cell: dict) -> None:
        e = np.array(cell["final_error"])
        results[label] = cell
        print(f"{label:58s} {cell['successes']:3d}/{cell['episodes']}  final error median "
              f"{np.median(e):.4f} rad [{e.min():.4f}, {e.max():.4f}]", flush=True)

    runs = out / "runs" / "dapg"
    for cond in ("identified", "identified_randomized"):
        run = runs / f"{cond}_{args.robot}_seed{args.seed}"
        on = runs / f"{run.name}.on_{args.robot}.json"
        if on.exists():
            show(f"({cond}) on robot {args.robot} (the folder's cell)", read_json(on))
        for sim_name, sim in (("c's sim (fixed values)", c_sim), ("d's sim (narrow DR)", d_sim)):
            show(f"({cond}) in {sim_name}",
                 evaluate(run, task, {"randomize": sim}, args.episodes))
    variants = [v for v in args.variants.split(",") if v]
    if variants:
        if args.scratch is None:
            p.error("--variants needs --scratch")
        values = identified_effects(ident, joints)
        marker = settings["budget"]
        size = size_with("default", **{k: (tuple(v) if isinstance(v, list) else v)
                                       for k, v in marker.items() if k != "gap"})
        demos = out / "demos.h5"
        for v in variants:
            if v.startswith("scale"):
                r = scaled(d_sim, values, float(v[5:]), None)
            elif v == "intervals":
                r = scaled(d_sim, values, None, None, intervals=True)
            elif v.startswith("only_"):
                if v[5:] not in values:
                    p.error(f"{v}: {v[5:]} was not named on robot {args.robot} "
                            f"(named: {sorted(values)})")
                r = scaled(d_sim, values, None, v[5:])
            else:
                p.error(f"unknown variant {v!r} (scaleS, intervals, only_EFFECT)")
            run = Path(args.scratch) / f"{v}_{args.robot}_seed{args.seed}"
            trained = train_policy(run, "dapg", train_task, r, demos, size, args.seed)
            show(f"(d {v}) on robot {args.robot} [trained {trained['wall_seconds']:.0f} s]",
                 evaluate(run, task, robot.env_kwargs(), args.episodes))
            show(f"(d {v}) in c's sim (fixed values)",
                 evaluate(run, task, {"randomize": c_sim}, args.episodes))
    cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime - c0
    print(f"{time.perf_counter() - t0:.0f} s wall, {cpu:.0f} s CPU")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
