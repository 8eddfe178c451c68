"""Robot subcommands: ``lowcostdex reset-test`` and ``record-log`` (``record-demos`` lives in
``lowcostdex.demonstrations.cli``).

    lowcostdex reset-test --port emulated --trials 50            # emulated D'Claw, virtual time
    lowcostdex reset-test --port /dev/ttyUSB0 --trials 20        # the real one
    lowcostdex record-log --port /dev/ttyUSB0 --joints ff_top,ff_middle,ff_bottom --logs 6 \
        --out logs/                                              # for `lowcostdex gap analyze`
    lowcostdex record-log --hand allegro --port can0 --out logs/  # the Allegro's index finger
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys

from lowcostdex.argtypes import SEED, JoinRepeats, bit_rate, names, number
from lowcostdex.options import (
    add_latency_option,
    add_robot_port_options,
    latency_kwargs,
    robot_port,
)

LOG_JOINTS = {"dclaw": "ff_top,ff_middle,ff_bottom", "allegro": "index_0,index_1,index_2,index_3"}
"""``record-log``'s default joints per hand: one finger."""


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reset-test",
                       help="tangle the D'Claw N times and auto-reset it: success rate and time")
    add_robot_port_options(p)
    p.add_argument("--trials", type=int, default=20, help="tangle + reset trials")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the tangles and valve angles")
    p.add_argument("--spec", default=None, help="hand spec JSON (calibration); default built-in")
    p.add_argument("--baud", type=bit_rate, default=1_000_000, help="bit rate [bit/s]")
    add_latency_option(p)
    p.add_argument("--no-effects", action="store_true",
                   help="emulated robot without the default servo effects")
    p.add_argument("--procedure", default="lowcostdex", choices=("lowcostdex", "robel"),
                   help="the staged, verified reset or ROBEL's sequence (the baseline)")
    p.add_argument("--json", default=None, help="also write the summary to this JSON file")
    p.set_defaults(func=_reset_test)

    p = sub.add_parser("record-log",
                       help="record identification logs (steps, ramps, chirps) in the project's "
                            "log format, for `lowcostdex gap analyze`")
    p.add_argument("--hand", default="dclaw", choices=tuple(LOG_JOINTS),
                   help="the D'Claw (Dynamixel, --port a serial device) or the Allegro (CAN, "
                        "--port a CAN channel such as can0)")
    add_robot_port_options(p, port_help="D'Claw: serial device or pty path; Allegro: CAN "
                                        "channel (e.g. can0); hardware backend")
    p.add_argument("--joints", default=None, action=JoinRepeats,
                   help="comma-separated joints to excite (the others hold still); default "
                        + "; ".join(f"{h}: {j}" for h, j in LOG_JOINTS.items()))
    p.add_argument("--logs", type=int, default=6, help="number of logs (trajectories)")
    p.add_argument("--seconds", type=number(0, 3600, open_low=True), default=15.0,
                   help="length of each log [s]")
    p.add_argument("--rate", type=number(1, 1000), default=50.0, help="command/read rate [Hz]")
    p.add_argument("--out", required=True, help="folder for log_<k>.csv")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the excitation")
    p.add_argument("--spec", default=None, help="hand spec JSON (calibration); default built-in")
    p.add_argument("--baud", type=bit_rate, default=None,
                   help="the D'Claw's Dynamixel bit rate [bit/s] (default 1000000)")
    add_latency_option(p)
    p.add_argument("--effects", default=None,
                   help="emulated robot only: JSON list of AppliedEffect dicts it carries "
                        "(default: lowcostdex.hardware.robot.backend.default_effects)")
    p.set_defaults(func=_record_log)


# ------------------------------------------------------------------------------------------------


def _hand(spec_path: str | None, name: str = "dclaw"):
    from lowcostdex.errors import ConfigError
    from lowcostdex.hands import hand_spec, load_spec

    hand = load_spec(spec_path) if spec_path else hand_spec(name)
    if hand.name != name:
        raise ConfigError(f"--spec {spec_path} is the {hand.name} hand spec, not {name}'s "
                          f"(--hand {name})")
    return hand


def _check_dynamixel_port(port: str) -> None:
    from lowcostdex.hardware.dynamixel.ports import check_port

    check_port(port)


MAX_RUNS = 10_000
"""Most logs / reset trials one command records."""
RESET_TEST_KEYS = ("trials", "successes", "success_rate", "failures", "port", "seed")
"""Keys of the file ``reset-test --json`` writes: a file with them may be replaced."""


def _reset_test(args: argparse.Namespace) -> int:
    args.port = robot_port(args.backend, args.port)
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.robot.backend import default_effects, make_dynamixel_bus
    from lowcostdex.hardware.robot.reset_dclaw import DClawReset
    from lowcostdex.hardware.robot.reset_robel import RobelReset
    from lowcostdex.hardware.robot.reset_trials import reset_trials
    from lowcostdex.hardware.robot.robot import Robot
    from lowcostdex.outdir import check_json_out, write_text_atomic
    from lowcostdex.progress import tasks as progress_tasks
    from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE
    from lowcostdex.sim.models.dclaw import build_dclaw

    if args.trials < 1:
        raise ConfigError("--trials must be >= 1")
    if args.trials > MAX_RUNS:
        raise ConfigError(f"--trials {args.trials} is above {MAX_RUNS}: each trial tangles and "
                          "resets the robot (split a campaign into runs)")
    if args.json:  # before minutes of trials
        check_json_out(args.json, "lowcostdex reset-test", RESET_TEST_KEYS)
    if args.latency_ms is not None and args.port == "emulated":
        raise ConfigError("--latency-ms is the serial adapter's latency timer: it needs "
                          "--backend hardware --port DEVICE")
    if args.no_effects and args.port != "emulated":  # before: dropped unsaid
        raise ConfigError(f"--no-effects is for --port emulated (its default servo effects); "
                          f"the robot on {args.port} has its own: leave out --no-effects")
    _check_dynamixel_port(args.port)
    hand = _hand(args.spec)
    model = build_dclaw("valve", hand).compile()
    if args.port == "emulated":
        from lowcostdex.hardware.emulated.chain import emulated_dclaw

        effects = [] if args.no_effects else default_effects(hand.joint_names)
        chain = emulated_dclaw("valve", hand=hand, effects=effects,
                               rng=np.random.default_rng(args.seed))
        port = chain.port()
    else:
        port = args.port
    robot = Robot(hand, make_dynamixel_bus(hand, port, model, baudrate=args.baud,
                                             **latency_kwargs(args.latency_ms)))
    console = Console(stderr=True)
    where = ("the emulated D'Claw (virtual time, "
             + ("no servo effects)" if args.no_effects else "the default servo effects)")
             if args.port == "emulated" else f"the D'Claw on {args.port} (it will move)")
    # before: a bare reset-test started 20 emulated trials with no word of what or where
    console.print(f"lowcostdex reset-test: {args.trials} trials of the {args.procedure} reset "
                  f"(tangle the fingers, then reset) on {where}, seed {args.seed}; --trials N, "
                  "--backend hardware --port DEVICE for your D'Claw", soft_wrap=True,
                  markup=False, highlight=False)
    with robot, progress_tasks(transient=False, console=console) as progress:
        task = progress.add_task("reset trials", total=args.trials)
        procedure = (DClawReset if args.procedure == "lowcostdex" else RobelReset)(robot)
        stats = reset_trials(robot, procedure, RESET_POSE, args.trials,
                             np.random.default_rng(args.seed),
                             on_trial=lambda k, ok, t: progress.advance(task))
    summary = stats.summary()
    keys = ("trials", "successes", "success_rate", "time_mean", "time_median", "time_max",
            "retried")
    table = Table(title=f"D'Claw auto-reset ({args.procedure}) on {args.port} "
                        "(times in robot-clock seconds)")
    for key in keys:
        table.add_column(key)
    table.add_row(*(f"{summary[k]:.3g}" if isinstance(summary[k], float) else str(summary[k])
                    for k in keys))
    out = Console()
    out.print(table)
    out.print(f"success rate {stats.successes}/{stats.trials} = {100 * stats.success_rate:.0f}%; "
              f"reset time mean {summary['time_mean']:.2f} s, median "
              f"{summary['time_median']:.2f} s, max {summary['time_max']:.2f} s")
    for message in stats.failures:
        console.print(f"[red]failed:[/red] {message}")
    if args.json:
        write_text_atomic(args.json, json.dumps({**summary, "failures": stats.failures,
                                                 "port": args.port, "seed": args.seed}, indent=2))
    return 0 if stats.successes == stats.trials else 1


def _short_log_note(seconds: float, rate: float) -> str | None:
    """The note for logs too short for ``gap analyze`` (None when long enough); ConfigError
    when a log would hold no row (before: a traceback from the excitation). The bound is twice
    the analysis' shortest log (``MIN_DURATION``: a robot's rows drift, 0.52 s at 50 Hz spanned
    0.497 s on the emulated D'Claw) and ``MIN_SAMPLES`` + 1 rows."""
    import math

    from lowcostdex.errors import ConfigError
    from lowcostdex.gap.log_checks import MIN_DURATION, MIN_SAMPLES

    least = max(2 * MIN_DURATION, (MIN_SAMPLES + 1) / rate)
    rows = round(seconds * rate)
    said = (f"--seconds {seconds:g} at --rate {rate:g} Hz is {rows} row(s) a log; `gap "
            f"analyze` reads logs of at least {MIN_SAMPLES} rows over {MIN_DURATION:g} s: "
            f"give --seconds {math.ceil(least * 100) / 100:g} or more (default 15)")
    if rows < 1:
        raise ConfigError(said)
    return f"lowcostdex record-log: note: {said} to analyse them" if seconds < least else None


def _record_log(args: argparse.Namespace) -> int:
    args.port = robot_port(args.backend, args.port, args.hand)
    from pathlib import Path

    from rich.console import Console

    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.robot.backend import default_effects
    from lowcostdex.outdir import MARKER, PREVIOUS, archive, check_out, claim, write_marker
    from lowcostdex.sim.effects.randomization import read_effects

    if args.logs < 1 or args.seconds <= 0 or args.rate <= 0:
        raise ConfigError("--logs, --seconds and --rate must be positive")
    short = _short_log_note(args.seconds, args.rate)
    if args.logs > MAX_RUNS:
        raise ConfigError(f"--logs {args.logs} is above {MAX_RUNS}: each log is a file of "
                          "--seconds of robot time (split a campaign into runs)")
    emulated = args.port == "emulated"
    if args.hand == "allegro":
        if args.latency_ms is not None:
            raise ConfigError("--latency-ms is a serial adapter's latency timer (D'Claw); the "
                              "Allegro hand is on CAN")
        if args.baud is not None:  # before: dropped unsaid
            raise ConfigError(f"--baud {args.baud} is the D'Claw's Dynamixel bit rate; the "
                              "Allegro's CAN bit rate is set on its interface (ip link set can0 "
                              "type can bitrate 1000000): leave out --baud")
        if not emulated:  # before anything is written
            from lowcostdex.hardware.allegro.driver import check_can_channel

            check_can_channel(args.port)
    else:
        _check_dynamixel_port(args.port)
        if args.baud is not None:  # before: --baud 0 recorded at 1 Mbit/s (0 read as unset)
            from lowcostdex.hardware.dynamixel.ports import check_baud

            check_baud(args.baud, emulated=emulated)
    hand = _hand(args.spec, args.hand)
    if args.joints is not None and not args.joints.strip():  # an unset variable, not a default
        raise ConfigError("--joints is empty; name the joints to excite (e.g. --joints ff_top), "
                          "or leave it out")
    joints = tuple(j.strip() for j in (args.joints or LOG_JOINTS[args.hand]).split(",")
                   if j.strip())
    if not joints:
        raise ConfigError("--joints names no joint")
    twice = sorted({j for j in joints if joints.count(j) > 1})
    if twice:  # each joint is excited once: a repeat is a typo for another joint
        raise ConfigError(f"--joints {args.joints} names {', '.join(twice)} more than once; "
                          "name each joint to excite once")
    joints = names(args.joints or LOG_JOINTS[args.hand], "--joints")  # "ff_top,,ff_middle"
    for j in joints:
        hand.joint(j)  # raises with the valid names
    fingers = {j.split("_")[0] for j in joints}
    whole = [n for n in hand.joint_names if n.split("_")[0] in fingers]
    if len(whole) > len(joints):  # before: recorded, then refused by gap analyze's model
        raise ConfigError(f"--joints {','.join(joints)} leaves out "
                          f"{', '.join(n for n in whole if n not in joints)} of the same finger: "
                          "the gap analysis replays whole fingers (`lowcostdex model --fingers`) "
                          "and needs each of their joints commanded and read; give --joints "
                          f"{','.join(whole)}")
    effects = []
    if emulated:
        if args.effects:
            effects = read_effects(args.effects)
        elif args.hand == "dclaw":
            effects = default_effects(hand.joint_names)
    elif args.effects:
        raise ConfigError("--effects is for the emulated robot (a real robot has its own)")
    steps = int(round(args.seconds * args.rate))
    console = Console(stderr=True)
    out = Path(args.out)
    earlier = check_out(out, "record-log")
    out.mkdir(parents=True, exist_ok=True)
    claim(out, "record-log", " (Ctrl-C keeps its finished logs), or give another --out")
    if earlier:  # an earlier recording here: keep it in previous/
        kept = archive(out, [p.name for p in out.iterdir() if p.name not in (MARKER, PREVIOUS)])
        if kept is not None:
            console.print(f"the earlier logs in {out} are kept in {kept}")
    write_marker(out, "record-log", {"hand": args.hand, "joints": list(joints),
                                     "seed": args.seed})
    try:
        paths = _record_logs(args, hand, joints, effects, emulated, steps, console)
    except KeyboardInterrupt:  # the finished logs are in --out; say so
        from lowcostdex.errors import INTERRUPTED

        done = sorted(p.name for p in out.glob("log_*.csv"))
        console.print(f"lowcostdex record-log: interrupted (Ctrl-C); the {len(done)} finished "
                      f"log(s) ({', '.join(done) or 'none'}) are in {out}; a new run there keeps "
                      f"them in {out / PREVIOUS}/", markup=False, highlight=False, soft_wrap=True)
        return INTERRUPTED
    console.print(f"{len(paths)} logs -> {args.out}; analyse them with "
                  f"`lowcostdex gap analyze --model MODEL.xml --log {shlex.quote(args.out)} --out DIR` "
                  f"(MODEL.xml: `{model_command(args.hand, joints)}`: a model of the fingers "
                  "the logs moved)", soft_wrap=True)  # no line breaks inside the commands
    if short:
        console.print(short, markup=False, highlight=False, soft_wrap=True)
    return 0


def _record_logs(args: argparse.Namespace, hand, joints: tuple[str, ...], effects: list,
                 emulated: bool, steps: int, console) -> list:
    """``record-log``'s recording, with its progress bar: the paths of the logs written."""
    import numpy as np

    from lowcostdex.hardware.robot.trace import (
        allegro_identification_logs,
        dclaw_identification_logs,
    )
    from lowcostdex.progress import tasks as progress_tasks

    with progress_tasks(transient=False, console=console) as progress:
        bar = progress.add_task("identification logs", total=args.logs * steps)
        common = {"effects": effects, "emulator_rng": np.random.default_rng(args.seed),
                  "rate": args.rate, "on_step": lambda _: progress.advance(bar)}
        if args.hand == "allegro":
            paths = allegro_identification_logs(
                hand, joints, args.out, args.logs, args.seconds,
                np.random.default_rng(args.seed), channel=None if emulated else args.port,
                **common)
        else:
            paths = dclaw_identification_logs(
                hand, joints, args.out, args.logs, args.seconds,
                np.random.default_rng(args.seed), port=None if emulated else args.port,
                baudrate=1_000_000 if args.baud is None else args.baud,
                latency_ms=args.latency_ms, **common)
    return paths


def model_command(hand: str, joints: tuple[str, ...]) -> str:
    """The ``lowcostdex model`` command that writes the MJCF replaying logs of ``joints``: the
    hand without its station, only the fingers those joints belong to (the log commands only
    those actuators; joint names are ``<finger>_<joint>`` on both hands)."""
    fingers = list(dict.fromkeys(j.split("_")[0] for j in joints))
    thermal = " --no-thermal" if hand == "dclaw" else ""  # as the main job's gap stage
    return (f"lowcostdex model {hand} --station none --fingers {','.join(fingers)}{thermal} "
            "--out MODEL.xml")


if __name__ == "__main__":  # pragma: no cover
    from lowcostdex.cli import main

    sys.exit(main())
