"""Robot subcommands: ``lowcostdex reset-test``, ``record-demos`` and ``record-log``.

    lowcostdex reset-test --port emulated --trials 50            # emulated D'Claw, virtual time
    lowcostdex reset-test --port /dev/ttyUSB0 --trials 20        # the real one
    lowcostdex record-demos --hand dclaw --task turn-valve --port emulated --episodes 25 \\
        --out demos/valve.h5                                     # virtual teacher
    lowcostdex record-demos --task flip --port emulated --successes 10 --episodes 30 \\
        --out demos/flip.h5                                      # until 10 flipped the block
    lowcostdex record-demos --hand allegro --task turn-valve --port emulated --episodes 10 \\
        --out demos/allegro_valve.h5                             # the emulated Allegro
    lowcostdex record-demos --hand dclaw --task turn-valve --port /dev/ttyUSB0 --episodes 25 \\
        --out demos/valve.h5                                     # a person moves the fingers
    lowcostdex record-log --port /dev/ttyUSB0 --joints ff_top,ff_middle,ff_bottom --logs 6 \
        --out logs/                                              # for `lowcostdex gap analyze`
"""

from __future__ import annotations

import argparse
import json
import sys

from lowcostdex.argtypes import SEED, integer, number
from lowcostdex.options import add_robot_port_options, robot_port

# hand -> task name on the command line -> (registered env id, scripted solver for the virtual
# teacher)
TASKS: dict[str, dict[str, tuple[str, str]]] = {
    "dclaw": {
        "turn-valve": ("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher"),
        "turn-valve-random": ("lowcostdex/DClawTurnValveRandom-v0", "ValveTurnTeacher"),
        "turn-foam-valve": ("lowcostdex/DClawTurnFoamValve-v0", "ValveTurnTeacher"),
        "screw": ("lowcostdex/DClawScrew-v0", "ScrewTrackTeacher"),
        "screw-random": ("lowcostdex/DClawScrewRandom-v0", "ScrewTrackTeacher"),
        "flip": ("lowcostdex/DClawFlipBlock-v0", "FlipBlockTeacher"),
        "flip-quaternion": ("lowcostdex/DClawFlipBlockQuaternion-v0", "FlipBlockTeacher"),
    },
    "allegro": {
        "turn-valve": ("lowcostdex/AllegroTurnValve-v0", "AllegroValveTeacher"),
        "turn-valve-random": ("lowcostdex/AllegroTurnValveRandom-v0", "AllegroValveTeacher"),
    },
}
DEFAULT_PLAYBACKS = {"flip": 0, "flip-quaternion": 0}
"""Tasks whose noisy open-loop playbacks do not reproduce the demonstration (the block's outcome
is too sensitive to the finger motion: 0 of 6 succeeded on the emulated D'Claw); 2 otherwise."""


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reset-test",
                       help="tangle the D'Claw N times and auto-reset it: success rate and time")
    add_robot_port_options(p)
    p.add_argument("--trials", type=int, default=20, help="tangle + reset trials")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the tangles and valve angles")
    p.add_argument("--spec", default=None, help="hand spec JSON (calibration); default built-in")
    p.add_argument("--baud", type=int, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--no-effects", action="store_true",
                   help="emulated robot without the default servo effects")
    p.add_argument("--procedure", default="lowcostdex", choices=("lowcostdex", "robel"),
                   help="the staged, verified reset or ROBEL's sequence (the baseline)")
    p.add_argument("--json", default=None, help="also write the summary to this JSON file")
    p.set_defaults(func=_reset_test)

    p = sub.add_parser("record-demos",
                       help="record kinesthetic demonstrations (a person, or the emulator's "
                            "virtual teacher) into an HDF5 demo file")
    p.add_argument("--hand", default="dclaw", choices=sorted(TASKS))
    p.add_argument("--task", default="turn-valve",
                   choices=sorted({t for tasks in TASKS.values() for t in tasks}),
                   help="D'Claw: " + ", ".join(TASKS["dclaw"]) + "; Allegro: "
                   + ", ".join(TASKS["allegro"]))
    add_robot_port_options(p, port_help="D'Claw: serial device or pty path; Allegro: CAN "
                                        "channel (e.g. can0); hardware backend")
    p.add_argument("--episodes", type=int, required=True,
                   help="demonstrations to record (with --successes: the most to try)")
    p.add_argument("--successes", type=int, default=None,
                   help="stop once this many demonstrations succeeded")
    p.add_argument("--out", required=True, help="HDF5 demo file (appended to if it exists)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the first episode")
    p.add_argument("--spec", default=None, help="hand spec JSON (calibration); default built-in")
    p.add_argument("--baud", type=int, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--countdown", type=number(0, 600), default=3.0,
                   help="seconds announced before each episode on a real robot")
    p.add_argument("--labels", default="servo_goal", choices=("servo_goal", "next_position"),
                   help="servo_goal: identify the servos' response first (a few seconds of "
                        "random goals) and label each step with the goal that reproduces it; "
                        "next_position: the next measured position (BAIR's labels)")
    p.add_argument("--playbacks", type=integer(0, 100), default=None,
                   help="noisy playbacks of each successful demonstration on the robot "
                        "(servo_goal labels only; 0: none; default 2, 0 for the flip)")
    p.add_argument("--playback-noise", type=number(0, 1), default=0.05,
                   help="half-width of the playback goal noise [action units]")
    p.set_defaults(func=_record_demos)

    p = sub.add_parser("record-log",
                       help="record identification logs (steps, ramps, chirps) in the project's "
                            "log format, for `lowcostdex gap analyze`")
    add_robot_port_options(p)
    p.add_argument("--joints", default="ff_top,ff_middle,ff_bottom",
                   help="comma-separated joints to excite (the others hold still)")
    p.add_argument("--logs", type=int, default=6, help="number of logs (trajectories)")
    p.add_argument("--seconds", type=number(0, 3600, open_low=True), default=15.0,
                   help="length of each log [s]")
    p.add_argument("--rate", type=number(1, 1000), default=50.0, help="command/read rate [Hz]")
    p.add_argument("--out", required=True, help="folder for log_<k>.csv")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the excitation")
    p.add_argument("--spec", default=None, help="hand spec JSON (calibration); default built-in")
    p.add_argument("--baud", type=int, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--effects", default=None,
                   help="emulated robot only: JSON list of AppliedEffect dicts it carries "
                        "(default: lowcostdex.hardware.robot.backend.default_effects)")
    p.set_defaults(func=_record_log)


# ------------------------------------------------------------------------------------------------


def _hand(spec_path: str | None):
    from lowcostdex.hardware.cli import load_spec
    from lowcostdex.hardware.hands import dclaw_spec

    return load_spec(spec_path) if spec_path else dclaw_spec()


def _check_dynamixel_port(port: str) -> None:
    from lowcostdex.hardware.cli import check_port

    check_port(port)


def _reset_test(args: argparse.Namespace) -> int:
    args.port = robot_port(args.backend, args.port)
    import numpy as np
    from rich.console import Console
    from rich.table import Table

    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.robot.backend import default_effects, make_dynamixel_bus
    from lowcostdex.hardware.robot.reset import DClawReset, RobelReset
    from lowcostdex.hardware.robot.reset_trials import reset_trials
    from lowcostdex.hardware.robot.robot import Robot
    from lowcostdex.progress import tasks as progress_tasks
    from lowcostdex.sim.envs.dclaw_tasks import RESET_POSE
    from lowcostdex.sim.models.dclaw import build_dclaw

    if args.trials < 1:
        raise ConfigError("--trials must be >= 1")
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
    robot = Robot(hand, make_dynamixel_bus(hand, port, model, baudrate=args.baud))
    console = Console(stderr=True)
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
        with open(args.json, "w") as f:
            json.dump({**summary, "failures": stats.failures, "port": args.port,
                       "seed": args.seed}, f, indent=2)
    return 0 if stats.successes == stats.trials else 1


def _check_demo_out(out: str, env_id: str) -> None:
    """Refuse an ``--out`` that is not a demo file of ``env_id`` (a user's file, a folder,
    another task's demos) before anything is recorded; a new path is fine."""
    from lowcostdex.demo_file import read_info
    from lowcostdex.errors import InputError
    from lowcostdex.outdir import check_out_file

    path = check_out_file(out, overwrite=True)  # appended to when it is a demo file
    if path.exists():
        info = read_info(path)[0]  # raises, naming the file, when it is not a demo file
        if info.env_id and info.env_id != env_id:
            raise InputError(f"--out {path} holds demonstrations of {info.env_id}, not "
                             f"{env_id}; it is left untouched (give a new file)")


def _record_demos(args: argparse.Namespace) -> int:
    args.port = robot_port(args.backend, args.port)
    import gymnasium as gym
    import numpy as np
    from rich.console import Console

    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.demos import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.progress import tasks as progress_tasks
    from lowcostdex.sim import scripted
    from lowcostdex.sim.registry import register_envs
    from lowcostdex.sim.scripted import AllegroTeacherConfig

    if args.episodes < 1 or (args.successes is not None and args.successes < 1):
        raise ConfigError("--episodes and --successes must be >= 1")
    tasks = TASKS[args.hand]
    if args.task not in tasks:
        raise ConfigError(f"--task {args.task!r} is not a {args.hand} task; valid: "
                          f"{', '.join(tasks)}")
    if args.playbacks is None:
        args.playbacks = DEFAULT_PLAYBACKS.get(args.task, 2)
    if args.labels != "servo_goal":
        args.playbacks = 0
    if args.hand == "dclaw":
        _check_dynamixel_port(args.port)
    register_envs()
    env_id, solver = tasks[args.task]
    _check_demo_out(args.out, env_id)  # before the robot moves: the file is appended to
    console = Console(stderr=True)
    emulated = args.port == "emulated"
    if args.hand == "allegro":
        kwargs = {} if emulated else {"channel": args.port}
    else:
        kwargs = {} if emulated else {"port": args.port, "baudrate": args.baud}
    if args.spec and not emulated:
        kwargs["hand"] = _hand(args.spec)
    env = gym.make(env_id, backend="emulated" if emulated else "hardware", **kwargs)
    teacher = None
    if emulated:
        from lowcostdex.sim import flip_teacher

        backend = env.unwrapped.backend
        device = backend.chain if args.hand == "dclaw" else backend.emulator
        cls = getattr(scripted, solver, None) or getattr(flip_teacher, solver)
        solver_obj = cls(AllegroTeacherConfig(gravity_compensation=False)) \
            if args.hand == "allegro" else cls()
        teacher = VirtualTeacher(device, env.unwrapped.task, solver=solver_obj,
                                 config=virtual_teacher_config(solver_obj))
    robot = env.unwrapped.backend.robot
    try:
        with progress_tasks(transient=False, console=console) as progress:
            bar = progress.add_task(f"{args.task} demos", total=args.episodes)

            def done(k: int, ep) -> None:
                if ep.source != "playback":
                    progress.advance(bar)
                what = "playback" if ep.source == "playback" else "demonstration"
                progress.console.print(f"episode {k} ({what}): {ep.length} steps, "
                                       f"{'success' if ep.success[-1] else 'no success'}")

            response = None
            if args.labels == "servo_goal":
                ident = progress.add_task("servo response (random goals)", total=4)
                response, seconds = identify_servo_response(
                    env, episodes=4, seed=args.seed + 1_000_000,
                    on_episode=lambda k: progress.advance(ident))
                progress.console.print(
                    f"servo response in {seconds:.0f} s: alpha "
                    f"{np.round(response.alpha, 2).tolist()}, r2 "
                    f"{np.round(response.r2, 3).tolist()}")
            recorder = KinestheticRecorder(
                env, args.out, env_id, teacher=teacher, on_episode=done, response=response,
                playbacks=args.playbacks, playback_noise=args.playback_noise,
                rng=np.random.default_rng(args.seed))
            for k in range(args.episodes):
                if args.successes is not None and recorder.stats.successes >= args.successes:
                    break
                if not emulated:
                    seconds = recorder.steps * env.unwrapped.control_period
                    progress.console.print(
                        f"[bold]episode {k + 1}/{args.episodes}[/bold]: hands off, auto-reset "
                        f"in {args.countdown:.0f} s; then the fingers go limp: move them "
                        f"through the task for {seconds:.0f} s")
                    robot.clock.sleep(args.countdown)
                recorder.record_episode(args.seed + k)
    finally:
        env.close()
    s = recorder.stats
    console.print(f"{s.episodes} demonstrations ({s.successes} successful), {s.steps} steps, "
                  f"{s.playbacks} playbacks ({s.playback_successes} successful) -> {args.out}; "
                  f"reset {s.reset_time:.1f} s, recording {s.record_time:.1f} s, playbacks "
                  f"{s.playback_time:.1f} s")
    return 0


def _record_log(args: argparse.Namespace) -> int:
    args.port = robot_port(args.backend, args.port)
    from pathlib import Path

    import numpy as np
    from rich.console import Console

    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.robot.backend import default_effects
    from lowcostdex.hardware.robot.trace import dclaw_identification_logs
    from lowcostdex.outdir import MARKER, PREVIOUS, archive, check_out, write_marker
    from lowcostdex.progress import tasks as progress_tasks
    from lowcostdex.sim.effects import AppliedEffect

    if args.logs < 1 or args.seconds <= 0 or args.rate <= 0:
        raise ConfigError("--logs, --seconds and --rate must be positive")
    _check_dynamixel_port(args.port)
    hand = _hand(args.spec)
    joints = tuple(j.strip() for j in args.joints.split(",") if j.strip())
    for j in joints:
        hand.joint(j)  # raises with the valid names
    effects = []
    if args.port == "emulated":
        effects = ([AppliedEffect.from_dict(e) for e in json.loads(open(args.effects).read())]
                   if args.effects else default_effects(hand.joint_names))
    steps = int(round(args.seconds * args.rate))
    console = Console(stderr=True)
    out = Path(args.out)
    if check_out(out, "record-log"):  # an earlier recording here: keep it in previous/
        kept = archive(out, [p.name for p in out.iterdir() if p.name not in (MARKER, PREVIOUS)])
        if kept is not None:
            console.print(f"the earlier logs in {out} are kept in {kept}")
    write_marker(out, "record-log", {"joints": list(joints), "seed": args.seed})
    with progress_tasks(transient=False, console=console) as progress:
        bar = progress.add_task("identification logs", total=args.logs * steps)
        paths = dclaw_identification_logs(
            hand, joints, args.out, args.logs, args.seconds, np.random.default_rng(args.seed),
            port=None if args.port == "emulated" else args.port, effects=effects,
            emulator_rng=np.random.default_rng(args.seed), rate=args.rate, baudrate=args.baud,
            on_step=lambda _: progress.advance(bar))
    console.print(f"{len(paths)} logs -> {args.out}; analyse them with "
                  f"`lowcostdex gap analyze --model MODEL.xml --log {args.out}/*.csv --out DIR` "
                  f"(MODEL.xml: `lowcostdex model dclaw --station none --out MODEL.xml`)")
    return 0


if __name__ == "__main__":  # pragma: no cover
    from lowcostdex.cli import main

    sys.exit(main())
