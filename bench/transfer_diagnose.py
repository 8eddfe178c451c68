"""Which part of a hidden robot's difference breaks a transfer policy? (issue 14)

A policy of a ``lowcostdex transfer`` folder runs on its hidden robot rebuilt with one part of
the robot's difference at a time ("only X": the nominal emulated D'Claw plus X) and with all
parts but one ("all but X"). The parts: the catalogue servo effects, the firmware imperfection
(PWM deadband, encoder nonlinearity), the finger link lengths, the link masses, the finger base
tilt, and the valve (dry friction, damping, inertia); and each catalogue effect alone.
Mean-action episodes with the transfer table's episode seeds, on the task's own start (the
table's evaluation).

    python bench/transfer_diagnose.py --out bench_runs/transfer --policy dapg/nominal_seed0 \\
        --robot C --episodes 5
    python bench/transfer_diagnose.py --out bench_runs/transfer --policy dapg/nominal_seed0 \\
        --robot C --episodes 50 --variants "the whole robot,only base tilt,all but base tilt"

Prints one line per variant: successes, median and range of the final valve error [rad]
(``--json FILE``: the episodes too; not inside the transfer folder, which refuses files it
did not write). Record findings in bench/RESULTS.md
("Transfer table").
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def parts(robot):
    """name -> (effects, firmware, model perturbation) of the robot carrying only that part."""
    from lowcostdex.hardware.emulated.hidden_robots import FirmwareImperfection, ModelPerturbation

    m = robot.model
    none_fw = FirmwareImperfection({}, {}, {})
    return {
        "catalogue effects": (list(robot.effects), none_fw, ModelPerturbation()),
        "firmware": ([], robot.firmware, ModelPerturbation()),
        "link lengths": ([], none_fw, ModelPerturbation(link_length=m.link_length)),
        "link masses": ([], none_fw, ModelPerturbation(link_mass=m.link_mass)),
        "base tilt": ([], none_fw, ModelPerturbation(base_tilt=m.base_tilt)),
        "valve": ([], none_fw, ModelPerturbation(valve_frictionloss=m.valve_frictionloss,
                                                 valve_damping=m.valve_damping,
                                                 valve_inertia=m.valve_inertia)),
    }


def all_but(robot, name):
    from lowcostdex.hardware.emulated.hidden_robots import FirmwareImperfection

    m = robot.model
    effects, fw = list(robot.effects), robot.firmware
    if name == "catalogue effects":
        effects = []
    elif name == "firmware":
        fw = FirmwareImperfection({}, {}, {})
    elif name == "link lengths":
        m = replace(m, link_length={})
    elif name == "link masses":
        m = replace(m, link_mass={})
    elif name == "base tilt":
        m = replace(m, base_tilt={})
    elif name == "valve":
        m = replace(m, valve_frictionloss=0.0, valve_damping=1.0, valve_inertia=1.0)
    return effects, fw, m


def main() -> None:
    from lowcostdex.hardware.emulated.hidden_robots import hidden_robot
    from lowcostdex.transfer.loop import TASKS, evaluate, read_json

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="a lowcostdex transfer folder")
    p.add_argument("--policy", required=True, help="e.g. dapg/nominal_seed0")
    p.add_argument("--robot", required=True, help="hidden robot name (A, B, ...)")
    p.add_argument("--episodes", type=int, default=5)
    p.add_argument("--only", action="store_true", help="'only X' variants (skip 'all but X')")
    p.add_argument("--pairs", action="store_true",
                   help="also every pair of catalogue effects (and no 'all but X' variants)")
    p.add_argument("--variants", default=None,
                   help="comma-separated variant names to run (default: all of them), e.g. "
                        "'the whole robot,only base tilt,all but base tilt': with --episodes "
                        "50 the table's own 50 episodes, paired with its cells")
    p.add_argument("--json", default=None, help="write the results here")
    args = p.parse_args()
    out = Path(args.out)
    marker = read_json(out / ".lowcostdex.json") if (out / ".lowcostdex.json").exists() else {}
    settings = marker.get("settings", {})
    task = TASKS[settings.get("task", "valve")]
    # hidden_robots(n, seed): robot k ("A", "B", ...) is hidden_robot(seed + k)
    robot = hidden_robot((settings.get("robot_seed") or 0) + ord(args.robot) - ord("A"),
                         args.robot)
    run_dir = out / "runs" / args.policy
    variants = {"nominal emulated D'Claw": ([], None, None),
                "the whole robot": (list(robot.effects), robot.firmware, robot.model)}
    variants.update({f"only {k}": v for k, v in parts(robot).items()})
    if len(robot.effects) > 1:  # each catalogue effect alone
        from lowcostdex.hardware.emulated.hidden_robots import (
            FirmwareImperfection,
            ModelPerturbation,
        )

        variants.update({f"only effect {e.name}": ([e], FirmwareImperfection({}, {}, {}),
                                                   ModelPerturbation()) for e in robot.effects})
        if args.pairs:
            from itertools import combinations

            variants.update({f"only effects {a.name} + {b.name}": (
                [a, b], FirmwareImperfection({}, {}, {}), ModelPerturbation())
                for a, b in combinations(robot.effects, 2)})
    if not (args.only or args.pairs):
        variants.update({f"all but {k}": all_but(robot, k) for k in parts(robot)})
    if args.variants is not None:
        from lowcostdex.errors import ConfigError, check_choice

        every = {**variants, **{f"all but {k}": all_but(robot, k) for k in parts(robot)}}
        chosen = [v.strip() for v in args.variants.split(",") if v.strip()]
        if not chosen:
            p.error("--variants: give at least one variant name")
        for name in chosen:
            try:
                check_choice("variant", name, every)
            except ConfigError as e:
                p.error(f"--variants: {e}")
        variants = {name: every[name] for name in chosen}
    results = {}
    t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
    for name, (effects, fw, model) in variants.items():
        kwargs = {"backend": "emulated", "motor": robot.motor, "effects": effects}
        if fw is not None:
            kwargs["imperfection"] = fw
        if model is not None:
            kwargs["modify_model"] = model.apply
        cell = evaluate(run_dir, task, kwargs, args.episodes)
        e = np.array(cell["final_error"])
        results[name] = cell
        print(f"{name:32s} {cell['successes']}/{cell['episodes']}  final error median "
              f"{np.median(e):.3f} rad [{e.min():.3f}, {e.max():.3f}]", flush=True)
    cpu = resource.getrusage(resource.RUSAGE_SELF).ru_utime - c0
    print(f"{time.perf_counter() - t0:.0f} s wall, {cpu:.0f} s CPU")
    if args.json:
        Path(args.json).write_text(json.dumps({"policy": args.policy, "robot": robot.to_dict(),
                                "episodes": args.episodes, "variants": results},
                                         indent=1))


if __name__ == "__main__":
    main()
