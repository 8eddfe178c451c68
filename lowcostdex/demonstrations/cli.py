"""The ``lowcostdex record-demos`` command: kinesthetic demonstrations into an HDF5 demo file.

    lowcostdex record-demos --hand dclaw --task turn-valve --backend emulated --episodes 25 \\
        --out demos/valve.h5                                     # virtual teacher
    lowcostdex record-demos --task flip --backend emulated --successes 10 --episodes 30 \\
        --out demos/flip.h5                                      # until 10 flipped the block
    lowcostdex record-demos --hand allegro --task turn-valve --backend emulated --episodes 10 \\
        --out demos/allegro_valve.h5                             # the emulated Allegro
    lowcostdex record-demos --hand dclaw --task turn-valve --port /dev/ttyUSB0 --episodes 25 \\
        --out demos/valve.h5                                     # a person moves the fingers
"""

from __future__ import annotations

import argparse

from lowcostdex.argtypes import SEED, bit_rate, integer, number
from lowcostdex.options import (
    add_latency_option,
    add_robot_port_options,
    latency_kwargs,
    robot_port,
)

# hand -> task name on the command line -> (registered env id, scripted solver for the virtual
# teacher)
TASKS: dict[str, dict[str, tuple[str, str]]] = {
    "dclaw": {
        "turn-valve": ("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher"),
        "turn-valve-random": ("lowcostdex/DClawTurnValveRandom-v0", "ValveTurnTeacher"),
        "turn-foam-valve": ("lowcostdex/DClawTurnFoamValve-v0", "ValveTurnTeacher"),
        "screw": ("lowcostdex/DClawScrew-v0", "ScrewTrackTeacher"),
        "screw-random": ("lowcostdex/DClawScrewRandom-v0", "ScrewTrackTeacher"),
        "flip": ("lowcostdex/DClawFlipBlock-v0", "PinchFlipTeacher"),
        "flip-quaternion": ("lowcostdex/DClawFlipBlockQuaternion-v0", "PinchFlipTeacher"),
    },
    "allegro": {
        "turn-valve": ("lowcostdex/AllegroTurnValve-v0", "AllegroValveTeacher"),
        "turn-valve-random": ("lowcostdex/AllegroTurnValveRandom-v0", "AllegroValveTeacher"),
    },
}
MAX_EPISODES = 10_000
"""Most episodes one record-demos run tries."""
DEFAULT_PLAYBACKS = {"flip": 0, "flip-quaternion": 0}
"""Tasks whose noisy open-loop playbacks do not reproduce the demonstration (the block's outcome
is too sensitive to the finger motion: 0 of 6 succeeded on the emulated D'Claw); 2 otherwise."""


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("record-demos",
                       help="record kinesthetic demonstrations (a person, or the emulator's "
                            "virtual teacher) into an HDF5 demo file")
    p.add_argument("--hand", default="dclaw", choices=sorted(TASKS),
                   help="the hand recorded (default %(default)s)")
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
    p.add_argument("--baud", type=bit_rate, default=None,
                   help="bit rate [bit/s] of a real D'Claw (default 1000000)")
    add_latency_option(p)
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


# ------------------------------------------------------------------------------------------------


def _file_seeds(path) -> list[int]:
    """The seeds of the episodes in the demo file ``path`` (its groups' ``seed`` attributes)."""
    import h5py

    with h5py.File(path, "r") as f:
        return sorted({int(g.attrs["seed"]) for g in f.values()
                       if isinstance(g, h5py.Group) and "seed" in g.attrs})


def _next_seed(args: argparse.Namespace) -> int:
    """The ``--seed`` whose episodes the file ``args.out`` does not hold yet."""
    try:
        used = _file_seeds(args.out)
    except OSError:
        used = []
    return max([args.seed - 1, *used]) + 1


def _check_demo_out(out: str, env_id: str, seed: int = 0, episodes: int = 0) -> None:
    """Refuse an ``--out`` that is not a demo file of ``env_id`` (a user's file, a folder,
    another task's demos) before anything is recorded; a new path is fine. A demo file that
    already holds episodes of the seeds this run would record (``seed`` .. ``seed + episodes -
    1``: the same command run again after Ctrl-C) is refused naming the ``--seed`` that adds
    new ones: the same seeds are the same starts, and with the virtual teacher the same
    demonstrations again, which BC and DAPG would count twice."""
    from lowcostdex.demonstrations.file import read_info
    from lowcostdex.errors import InputError
    from lowcostdex.outdir import check_out_file

    path = check_out_file(out, overwrite=True)  # appended to when it is a demo file
    if path.exists():
        info = read_info(path)[0]  # raises, naming the file, when it is not a demo file
        if info.env_id and info.env_id != env_id:
            raise InputError(f"--out {path} holds demonstrations of {info.env_id}, not "
                             f"{env_id}; it is left untouched (give a new file)")
        used = _file_seeds(path)
        again = [s for s in used if seed <= s < seed + episodes]
        if again:
            raise InputError(
                f"--out {path} already holds episodes of seeds {used[0]}-{used[-1]} (an earlier "
                f"run, stopped with Ctrl-C?); --seed {seed} would record {len(again)} of them "
                "again (the same starts; with the virtual teacher the same demonstrations): "
                f"pass --seed {used[-1] + 1} to add new ones")


def _record_demos(args: argparse.Namespace) -> int:
    args.port = robot_port(args.backend, args.port, args.hand)
    import gymnasium as gym
    import numpy as np
    from rich.console import Console

    from lowcostdex.demonstrations.kinesthetic import (
        KinestheticRecorder,
        VirtualTeacher,
        identify_servo_response,
        virtual_teacher_config,
    )
    from lowcostdex.errors import ConfigError
    from lowcostdex.hands import load_spec
    from lowcostdex.hardware.dynamixel.ports import check_port
    from lowcostdex.progress import tasks as progress_tasks
    from lowcostdex.sim.registry import register_envs
    from lowcostdex.teachers import AllegroTeacherConfig, teacher_class

    if args.episodes < 1 or (args.successes is not None and args.successes < 1):
        raise ConfigError("--episodes and --successes must be >= 1")
    if args.episodes > MAX_EPISODES:
        raise ConfigError(f"--episodes {args.episodes} is above {MAX_EPISODES}: each is an "
                          "episode on the robot, appended to --out (split a campaign into runs)")
    if args.successes is not None and args.successes > args.episodes:
        raise ConfigError(f"--successes {args.successes} can never be reached: --episodes "
                          f"{args.episodes} is the most episodes tried; give --episodes >= "
                          f"{args.successes}")
    tasks = TASKS[args.hand]
    if args.task not in tasks:
        raise ConfigError(f"--task {args.task!r} is not a task of --hand {args.hand}; valid: "
                          f"{', '.join(tasks)}")
    if args.labels != "servo_goal" and args.playbacks:
        raise ConfigError(f"--playbacks {args.playbacks}: playbacks are labelled by the servo "
                          f"response (--labels servo_goal), not with --labels {args.labels}; "
                          "leave out --playbacks, or use --labels servo_goal")
    if args.playbacks is None:
        args.playbacks = DEFAULT_PLAYBACKS.get(args.task, 2)
    if args.labels != "servo_goal":
        args.playbacks = 0
    emulated = args.port == "emulated"
    for option, value in (("--baud", args.baud), ("--latency-ms", args.latency_ms)):
        if value is not None and emulated:  # not silently ignored
            raise ConfigError(f"{option} {value} is for a real robot's serial adapter "
                              "(--port DEVICE); the emulated hand has none. Leave it out, or "
                              "give --port")
    if args.baud is None:
        args.baud = 1_000_000
    if args.baud <= 0:
        raise ConfigError(f"--baud {args.baud}: the bit rate must be positive (Dynamixel "
                          "default 1000000, factory 57600)")
    if args.hand == "dclaw":
        check_port(args.port)
    register_envs()
    env_id, solver = tasks[args.task]
    # before the robot moves: the file is appended to
    _check_demo_out(args.out, env_id, args.seed, args.episodes)
    console = Console(stderr=True)
    if args.hand == "allegro":
        if args.latency_ms is not None:
            raise ConfigError("--latency-ms is a serial adapter's latency timer (D'Claw); the "
                              "Allegro hand is on CAN")
        kwargs = {} if emulated else {"channel": args.port}
    else:
        kwargs = {} if emulated else {"port": args.port, "baudrate": args.baud,
                                      **latency_kwargs(args.latency_ms)}
    if args.spec and emulated:  # not silently ignored: the emulated hand has its own spec
        raise ConfigError(f"--spec {args.spec}: a hand spec (calibration) is for a real robot "
                          "(--port DEVICE); the emulated hand is built from the built-in spec. "
                          "Leave out --spec, or give --port")
    if args.spec:
        kwargs["hand"] = load_spec(args.spec)
        if kwargs["hand"].name != args.hand:
            raise ConfigError(f"--spec {args.spec} is the {kwargs['hand'].name} hand spec, not "
                              f"{args.hand}'s (--hand {args.hand})")
    env = gym.make(env_id, backend="emulated" if emulated else "hardware", **kwargs)
    teacher = None
    if emulated:
        backend = env.unwrapped.backend
        device = backend.chain if args.hand == "dclaw" else backend.emulator
        cls = teacher_class(solver)
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
            try:
                _record(args, recorder, robot, progress, env, emulated)
            except KeyboardInterrupt:  # the episodes recorded are in the file; say so
                from lowcostdex.errors import INTERRUPTED

                s = recorder.stats
                console.print(f"lowcostdex record-demos: interrupted (Ctrl-C); the {s.episodes} "
                              f"demonstration(s) this run finished ({s.successes} successful, "
                              f"{s.playbacks} playbacks) are in {args.out}; run the command "
                              f"again with --seed {_next_seed(args)} to add more (it appends)",
                              markup=False, highlight=False,
                              soft_wrap=True)
                return INTERRUPTED
    finally:
        env.close()
    s = recorder.stats
    console.print(f"{s.episodes} demonstrations ({s.successes} successful), {s.steps} steps, "
                  f"{s.playbacks} playbacks ({s.playback_successes} successful) -> {args.out}; "
                  f"reset {s.reset_time:.1f} s, recording {s.record_time:.1f} s, playbacks "
                  f"{s.playback_time:.1f} s")
    return 0


def _record(args: argparse.Namespace, recorder, robot, progress, env, emulated: bool) -> None:
    """The episodes, each appended to the file when it ends (Ctrl-C loses the one under way)."""
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
