"""``lowcostdex transfer``: the transfer table on your robot or on emulated hidden robots.

    lowcostdex transfer --out runs/transfer --size smoke            # 2 hidden robots, ~1 min CPU
    lowcostdex transfer --out runs/transfer                         # 3 robots, 1 seed, DAPG: 2-4 h
    lowcostdex transfer --out runs/transfer --seeds 3 --algos dapg,npg   # the full table: ~10 h+
    lowcostdex transfer --out runs/transfer --port /dev/ttyUSB0     # your D'Claw (see below)

Times are for a 2-core machine shared with other jobs (bench/RESULTS.md): identification ~4 min
per finger, a policy trained in simulation 1-2 min, on_robot training 21-70 min per robot (48k
samples through the emulated bus), an evaluation cell of 50 episodes ~15 s.

With ``--port`` the identification logs move each finger through its range with the valve off:
the command stops after them; put the valve back on and run the same command again to train
(on_robot trains on your robot: hours of robot time at the default size) and evaluate.
"""

from __future__ import annotations

import argparse

from lowcostdex.argtypes import SEED, integer, names, number


def add_commands(sub: argparse._SubParsersAction) -> None:
    from lowcostdex.options import add_latency_option, add_robot_port_options

    p = sub.add_parser(
        "transfer", help="does a policy trained in simulation work on the robot? identify it, "
        "train under each condition, evaluate on every robot, write the table",
        description=__doc__.split("\n\n")[0] + " Resumes a run cut short in the same --out.")
    p.add_argument("--out", required=True,
                   help="output folder: new or empty, or a previous transfer run to resume "
                        "(same task, robots and size)")
    p.add_argument("--size", choices=("smoke", "default", "long"), default="default",
                   help="budgets: smoke checks the loop (~1 min CPU); default: 48k samples per "
                        "policy, 50 episodes per cell, 3 hidden robots, 1 seed, DAPG, every "
                        "condition: 2-4 h on 2 cores (the full table, --seeds 3 --algos "
                        "dapg,npg: ~10 h or more); long: 160k samples and 100 episodes per cell, "
                        "3 seeds, both learners (estimated 30 h or more)")
    p.add_argument("--task", choices=("valve", "valve-near", "valve-random"), default="valve",
                   help="valve: 180 deg from the fixed start; valve-near: start and goal within "
                        "+-0.25 rad of those; valve-random: +-60 deg (default %(default)s)")
    add_robot_port_options(p, port_help="serial port of your D'Claw (default: emulated hidden "
                                        "robots)")
    p.add_argument("--robots", type=integer(1, 26), default=None,
                   help="hidden robots (default by size)")
    p.add_argument("--robot-seed", type=SEED, default=0, help="the hidden robots' seed")
    p.add_argument("--seeds", type=integer(1, 100), default=None,
                   help="training seeds 0..N-1 (default by size; more seeds resume a run)")
    p.add_argument("--first-seed", type=integer(0, 99), default=0,
                   help="train seeds K..N-1 of --seeds N only, e.g. --seeds 3 --first-seed 2 "
                        "for seed 2 alone (default 0); a lower seed is in the table only "
                        "when the folder holds it whole; the demonstrations stay seed 0's")
    p.add_argument("--algos", default=None,
                   help="comma-separated learners: dapg, npg (default by size: both)")
    p.add_argument("--conditions", default=None,
                   help="comma-separated: nominal, randomized, identified, "
                        "identified_randomized, on_robot (default: all)")
    p.add_argument("--start-range", type=number(0, 3.14159, unit="rad"), default=0.0,
                   help="train every condition from valve starts within +-this [rad] of the "
                        "task's and goals within +-this of their offset from the start "
                        "(evaluation keeps the task's starts; a fixed-start policy can fail "
                        "when the valve starts 0.002 rad past goal - 180 deg); a setting of "
                        "the folder (default 0: the task's own starts)")
    p.add_argument("--made-for", default=None,
                   help="comma-separated hidden robots (A, B, ...) that the per-robot "
                        "conditions (identified, identified_randomized, on_robot) make "
                        "policies for (default: every robot; on_robot takes hours per robot); "
                        "every policy is still evaluated on every robot, and a later run on "
                        "the folder adds the others")
    p.add_argument("--valve-episodes", type=integer(0, 1000), default=None,
                   help="the identified conditions' valve-log fit: valve episodes the robot "
                        "plays with the valve on (demonstrations' goals as recorded, fast, "
                        "slow, stop-and-go, twice: 4-8 s each) to fit a finger base's tilt, "
                        "the valve's friction / damping / inertia and the link lengths in its "
                        "identified model, which those conditions then train in; 0: none, the "
                        "nominal MJCF (default by size: smoke 2, default and long 5; folders "
                        "made before it existed resume with 0)")
    add_latency_option(p)
    p.add_argument("--yes", action="store_true",
                   help="with --port: do not ask before the robot moves")
    p.set_defaults(func=_transfer, parser=p)


def _transfer(args: argparse.Namespace) -> int:
    from lowcostdex.errors import InputError
    from lowcostdex.options import robot_port
    from lowcostdex.transfer.loop import ALGOS, CONDITIONS, parse_list, run, size_with

    device = robot_port(args.backend, args.port)
    port = None if device == "emulated" else device
    if args.latency_ms is not None and port is None:  # else silently unused
        raise InputError("--latency-ms is the serial adapter's latency timer: it needs "
                         "--port DEVICE (your D'Claw); the emulated hidden robots have none")
    if port is not None:
        from lowcostdex.hardware.dynamixel.ports import check_port

        check_port(port)  # a missing device is refused before anything runs
    size = size_with(args.size, robots=args.robots, seeds=args.seeds,
                     algos=parse_list(args.algos, ALGOS, "algo"),
                     conditions=parse_list(args.conditions, CONDITIONS, "condition"),
                     valve_episodes=args.valve_episodes)
    if port is not None and not args.yes:
        try:
            answer = input(f"The robot on {port} will move (identification: valve off; "
                           "training and evaluation: valve on). Continue? [y/N] ")
        except EOFError:  # run from a script, a pipe or nohup: nobody to answer
            raise InputError(f"the robot on {port} will move and nobody can confirm it (stdin "
                             "is closed); pass --yes to run without asking") from None
        if answer.strip().lower() not in ("y", "yes"):
            print("stopped; nothing was written")
            return 1
    try:
        made_for = None if args.made_for is None else names(
            args.made_for, "--made-for")  # run() checks them
        run(args.out, size, args.task, args.robot_seed, port, latency_ms=args.latency_ms,
            start_range=args.start_range, made_for=made_for, first_seed=args.first_seed)
    except KeyboardInterrupt:  # finished pieces are kept: say so and how to resume
        from lowcostdex.algos.train_cli import command_line
        from lowcostdex.errors import Interrupted

        again = command_line(args.parser, args, False)
        raise Interrupted(f"the finished pieces are kept in {args.out} (the table is written "
                          f"when every piece is done); the same command resumes there: {again}"
                          ) from None
    return 0
