"""Condition (c) trained in the model a valve log fitted (issue 14, transfer15): DAPG as condition
"identified" (the robot's identified servo effects held fixed, ``FOLDER/identify/ROBOT``) in a sim
whose D'Claw carries the parameters ``bench/transfer_tilt_joint.py`` fitted (a finger base's
tilt, the valve's friction / damping / inertia, the link lengths; its ``--out`` JSON, first fit
or ``--finger``). No robot definition is read. The edit reaches the training envs as the
task's ``model_edit`` (in the run's config, as ``lowcostdex transfer`` passes it); evaluate with:

    python bench/transfer_tilt_train.py RUN_FOLDER C fits.json OUT identified_fit_C_seed0
    python bench/transfer_diagnose.py --out OUT --policy dapg/identified_fit_C_seed0 --robot C \\
        --episodes 50 --variants "the whole robot"
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from transfer_tilt_joint import identified_randomize

from lowcostdex.transfer.config import SIZES, TASKS
from lowcostdex.transfer.loop import train_policy
from lowcostdex.transfer.valve_fit import edit_from_params


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="the transfer folder (demos.h5, identify/)")
    p.add_argument("robot", choices=("A", "B", "C"))
    p.add_argument("fits", type=Path, help="transfer_tilt_joint.py --out JSON")
    p.add_argument("out", type=Path, help="a folder of its own (runs/dapg/TAG is written)")
    p.add_argument("tag")
    p.add_argument("--finger", help="which finger's fit (default: the first)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--start-range", type=float, default=0.02)
    p.add_argument("--narrow", action="store_true",
                   help="condition (d): narrow randomization around the identified effects "
                        "(the fitted edit held fixed, as `lowcostdex transfer` does)")
    p.add_argument("--valve", action="store_true",
                   help="with --narrow: also draw the valve's friction and damping per episode "
                        "around the fit (valve_fit.randomized_valve: its intervals, at least "
                        "+-VALVE_PAD), as `lowcostdex transfer`'s identified_randomized does")
    p.add_argument("--valve-pad", type=float,
                   help="with --valve: the valve ranges' pad (default valve_fit.VALVE_PAD)")
    p.add_argument("--valve-pad-only", action="store_true",
                   help="with --valve: ranges +-pad of the fitted values, the fit's intervals "
                        "left out")
    p.add_argument("--friction-from-zero", action="store_true",
                   help="with --valve: the valve's added friction drawn from 0 (valve_fit.LOWER) "
                        "to the range's high end: the parameter the log cannot pin down "
                        "(friction and damping trade along b v + F, transfer17; the intervals "
                        "missed A's and C's friction, transfer17/19)")
    p.add_argument("--n-iter", type=int, help="iterations (default: the default size's; "
                                              "the sample budget is n_iter x 40 x 40)")
    args = p.parse_args()
    rows = json.loads(args.fits.read_text())["fits"]
    row = next(r for r in rows if args.finger in (None, r["finger"]))
    x = np.asarray(row["values"], float)
    print(f"training in the model edited by the {row['finger']} fit {x.round(4).tolist()}",
          flush=True)
    edit = edit_from_params(row["finger"], x).to_dict()
    randomize = identified_randomize(args.folder, args.robot,
                                     "identified_randomized" if args.narrow else "identified")
    if args.valve:
        from lowcostdex.sim.envs.dclaw_tasks import TurnValve
        from lowcostdex.transfer import valve_fit
        from lowcostdex.transfer.valve_fit import randomized_valve, valve_ranges

        if args.valve_pad is not None:
            valve_fit.VALVE_PAD = args.valve_pad
        drawn = ({**row, "intervals": [[v, v] for v in row["values"]]} if args.valve_pad_only
                 else row)
        if args.friction_from_zero:
            intervals = [list(iv) for iv in drawn["intervals"]]
            intervals[2][0] = valve_fit.LOWER[2]
            drawn = {**drawn, "intervals": intervals}
        fit = {"fits": [drawn], "used_finger": row["finger"], "model_edit": edit}
        nominal = float(TurnValve().build_spec().joint("valve").damping[0])
        randomize, edit = randomized_valve(randomize, fit, nominal)
        print(f"valve drawn per episode: {valve_ranges(fit)}", flush=True)
    print(train_policy(args.out / "runs" / "dapg" / args.tag, "dapg",
                       TASKS["valve"].training(args.start_range), randomize,
                       args.folder / "demos.h5",
                       replace(SIZES["default"], n_iter=args.n_iter or SIZES["default"].n_iter),
                       args.seed, model_edit=edit))


if __name__ == "__main__":
    main()
