"""Hardware subcommands: ``lowcostdex scan``, ``lowcostdex emulate``, ``lowcostdex calibrate``.

    lowcostdex scan                                # candidate ports: USB ids, by-id names, problems
    lowcostdex scan --port /dev/ttyUSB0            # ping, models, firmware, temperatures, errors
    lowcostdex scan --port emulated --hand dclaw   # the same against an in-process emulated D'Claw
    lowcostdex emulate dclaw                       # prints "PORT /dev/pts/N", serves until Ctrl-C
    lowcostdex emulate bench --clock virtual       # single servo; bus time instead of wall time
    lowcostdex calibrate --hand dclaw --port /dev/ttyUSB0 --out dclaw_calibrated.json
    lowcostdex setup-motors --hand dclaw           # new motors: ids and baud, one at a time
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from lowcostdex.argtypes import SEED, bit_rate, integer, number
from lowcostdex.errors import ConfigError, InputError
from lowcostdex.hands import load_spec
from lowcostdex.hardware.dynamixel.ports import check_baud
from lowcostdex.options import add_latency_option, latency_kwargs


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scan", help="find Dynamixel motors: models, firmware, temperature, errors")
    p.add_argument("--port", default=None,
                   help="serial device, pty path, or 'emulated'; without it, list the candidate "
                        "ports (USB id, serial number, /dev/serial/by-id names) and their problems")
    p.add_argument("--baud", type=bit_rate, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--ids", default=None,
                   help="comma-separated ids or ranges (e.g. 10-12,50); default broadcast ping")
    p.add_argument("--hand", default="dclaw", choices=("dclaw", "bench"),
                   help="hand to emulate with --port emulated")
    p.set_defaults(func=_scan)

    p = sub.add_parser("emulate", help="serve an emulated Dynamixel hand on a pty")
    p.add_argument("hand", choices=("dclaw", "bench"))
    p.add_argument("--motor", default=None, help="servo model (default: the hand's)")
    p.add_argument("--station", default=None,
                   help="D'Claw station (valve, foam_valve, screw, block, none = 9 motors; "
                        "default valve)")
    p.add_argument("--baud", type=bit_rate, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--clock", default="realtime", choices=("realtime", "virtual"),
                   help="physics on wall time, or on bus time (advances with the bytes only)")
    p.add_argument("--wire-time", action="store_true",
                   help="delay replies by their wire time (bytes x 10 / baud + return delay)")
    p.add_argument("--drop", type=number(0, 1, unit="fraction"), default=0.0,
                   help="status packet drop probability")
    p.add_argument("--corrupt", type=number(0, 1, unit="fraction"), default=0.0,
                   help="status packet corruption prob.")
    p.add_argument("--late", type=number(0, 1, unit="fraction"), default=0.0,
                   help="late status packet probability")
    p.add_argument("--no-fast-read", action="store_true", help="firmware without Fast Sync Read")
    p.add_argument("--effects", default=None,
                   help="JSON file: a list of AppliedEffect dicts the emulated robot carries")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the fault generator")
    p.add_argument("--quiet", action="store_true", help="do not print motor events")
    p.set_defaults(func=_emulate)

    p = sub.add_parser("calibrate",
                       help="record per-joint offsets (hand in its zero pose) into a hand spec")
    p.add_argument("--hand", default="dclaw", choices=("dclaw", "bench"),
                   help="the D'Claw or the one-servo bench (default %(default)s)")
    p.add_argument("--spec", default=None, help="hand spec JSON to start from (default: built-in)")
    p.add_argument("--port", required=True, help="serial device, pty path, or 'emulated'")
    p.add_argument("--baud", type=bit_rate, default=1_000_000, help="bit rate [bit/s] (default %(default)s)")
    p.add_argument("--out", required=True, help="where to write the calibrated hand spec JSON")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier calibration at --out (a hand spec, nothing else)")
    p.add_argument("--samples", type=integer(1, 100_000), default=20,
                   help="reads averaged per joint")
    p.add_argument("--yes", action="store_true", help="do not wait for Enter")
    add_latency_option(p)
    p.set_defaults(func=_calibrate)

    p = sub.add_parser("setup-motors",
                       help="new motors (id 1, 57600 bps): give each its id and baud rate, one "
                            "motor at a time, then scan the hand")
    p.add_argument("--hand", default="dclaw", choices=("dclaw", "bench"),
                   help="the D'Claw or the one-servo bench (default %(default)s)")
    p.add_argument("--spec", default=None, help="hand spec JSON (default: built-in)")
    p.add_argument("--port", default=None,
                   help="serial device or pty path (default: the one USB serial port found)")
    p.add_argument("--baud", type=bit_rate, default=1_000_000, help="rate to set [bit/s]")
    p.add_argument("--ids", default=None, help="set up only these of the hand's ids (e.g. 21)")
    p.add_argument("--reassign", action="store_true",
                   help="accept a motor that has another of the hand's ids")
    p.set_defaults(func=_setup_motors)


def parse_ids(text: str) -> list[int]:
    """"10-12,50" -> [10, 11, 12, 50]; InputError naming the part that is not an id (0-252)."""
    out: list[int] = []
    parts = [part.strip() for part in text.split(",")]
    while len(parts) > 1 and not parts[-1]:
        parts.pop()  # "10,11," is 10 and 11
    if "" in parts and any(parts):  # before: "10,,12" scanned 10 and 12 without a word
        raise InputError(f"--ids {text!r} has an empty item (two commas together: an id left "
                         f"out?); type --ids {','.join(p for p in parts if p)}")
    for part in parts:
        try:
            if "-" in part:
                a, b = (int(x) for x in part.split("-"))
                ids = list(range(a, b + 1))
                if not ids:
                    raise ValueError
            else:
                ids = [int(part)] if part else []
        except ValueError:
            raise InputError(f"--ids {text!r}: {part!r} is not an id or a range like 10-12"
                             ) from None
        bad = [i for i in ids if not 0 <= i <= 252]
        if bad:
            raise InputError(f"--ids {text!r}: Dynamixel ids are 0-252, got {bad[0]}")
        out += ids
    return out


def _emulated_chain(hand: str, clock: str = "virtual", **kwargs):
    from lowcostdex.hardware.emulated.chain import emulated_bench, emulated_dclaw

    if hand == "dclaw":
        return emulated_dclaw(clock=clock, **kwargs)
    return emulated_bench(clock=clock, **kwargs)


def _port(args: argparse.Namespace):
    from lowcostdex.hardware.dynamixel.ports import check_port

    check_baud(args.baud, emulated=args.port == "emulated")
    if args.port == "emulated":
        return _emulated_chain(args.hand, baudrate=args.baud).port()
    check_port(args.port)
    return args.port


def _list_ports() -> int:
    from lowcostdex.hardware.dynamixel.ports import format_ports, list_serial_ports

    ports = list_serial_ports()
    print(format_ports(ports))
    if ports:
        print("scan one with: lowcostdex scan --port PORT (a /dev/serial/by-id name stays the "
              "same when the adapter is replugged)")
    return 0 if ports else 1


def _scan(args: argparse.Namespace) -> int:
    from lowcostdex.hardware.dynamixel.scan import scan

    if args.port is None:
        return _list_ports()
    if args.ids is not None and not args.ids.strip():  # an unset variable: not "every id"
        raise InputError("--ids is empty; name the ids (e.g. --ids 10-12,50), or leave it out")
    ids = parse_ids(args.ids) if args.ids else None
    try:
        found = scan(_port(args), args.baud, ids)
    except OSError as exc:  # pyserial: a path that is not a serial port, a device gone
        raise InputError(f"--port {args.port}: cannot open it as a serial port ({exc})") from None
    if not found:
        print(f"no motors answered on {args.port} at {args.baud} bps")
        return 1
    print(f"{'id':>3}  {'model':<12} {'number':>6} {'fw':>3} {'temp':>5} {'volt':>5} "
          f"{'torque':>6}  errors")
    for m in found:
        temp = "-" if m.temperature is None else f"{m.temperature}C"
        volt = "-" if m.voltage is None else f"{m.voltage:.1f}V"
        torque = "-" if m.torque_enabled is None else ("on" if m.torque_enabled else "off")
        fw = "-" if m.firmware is None else str(m.firmware)
        print(f"{m.motor_id:>3}  {m.model:<12} {m.model_number:>6} {fw:>3} {temp:>5} {volt:>5} "
              f"{torque:>6}  {', '.join(m.hardware_error) or '-'}")
    return 0


def _emulate(args: argparse.Namespace) -> int:
    import signal
    import time

    import numpy as np


    check_baud(args.baud, emulated=True)

    from lowcostdex.hardware.emulated.chain import FaultConfig
    from lowcostdex.hardware.emulated.firmware import FirmwareOptions
    from lowcostdex.hardware.emulated.pty_server import PtyServer
    from lowcostdex.sim.effects.randomization import read_effects

    effects = read_effects(args.effects) if args.effects else []
    kwargs = dict(faults=FaultConfig(drop=args.drop, corrupt=args.corrupt, late=args.late),
                  options=FirmwareOptions(fast_read=not args.no_fast_read), baudrate=args.baud,
                  wire_time=args.wire_time, effects=effects, rng=np.random.default_rng(args.seed))
    if args.hand == "dclaw":
        kwargs["station"] = args.station or "valve"
    elif args.station is not None:  # before: served the bench, the station dropped unsaid
        raise InputError(f"--station {args.station}: the bench is one servo and its arm, with "
                         "no station; leave out --station, or emulate dclaw")
    if args.motor:
        kwargs["motor"] = args.motor
    chain = _emulated_chain(args.hand, clock=args.clock, **kwargs)
    server = PtyServer(chain)
    if not args.quiet:
        def report(ev):  # wall = time.monotonic(), comparable across processes
            print(f"EVENT {ev.kind} id={ev.motor_id} t={ev.time:.4f} wall={time.monotonic():.4f}"
                  f" {ev.detail}".rstrip(), flush=True)

        chain.event_callbacks.append(report)

    def stop(signum, frame):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)
    print(f"PORT {server.path}", flush=True)
    print(f"# {args.hand}: ids {sorted(chain.motors)} ({chain.hand.motor}) at {args.baud} bps, "
          f"{args.clock} clock", file=sys.stderr, flush=True)
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
    return 0


def _dynamixel_hand(args: argparse.Namespace, command: str):
    """The hand of ``--spec`` (or ``--hand``), refused when its motors are not Dynamixels (the
    Allegro's spec: its joints are on a CAN bus, which these commands do not talk to)."""
    from lowcostdex.hands import hand_spec
    from lowcostdex.hardware.dynamixel.control_table import load_control_table

    hand = load_spec(args.spec) if args.spec else hand_spec(args.hand)
    try:
        load_control_table(hand.motor)
    except ConfigError:
        raise InputError(f"--spec {args.spec} is the {hand.name} hand spec, whose motors "
                         f"('{hand.motor}') are not Dynamixel servos: {command} works on "
                         "Dynamixel hands (the D'Claw); give a D'Claw spec") from None
    if getattr(args, "port", None) == "emulated" and hand.name != args.hand:
        # the emulator serves --hand: a bench spec on the emulated D'Claw was "motor check
        # failed ... id 1 no reply", with no word of the hands not matching
        raise InputError(f"--spec {args.spec} is the {hand.name} hand spec, not {args.hand}'s: "
                         f"--port emulated serves --hand {args.hand}"
                         + (f"; give --hand {hand.name}" if hand.name in ("dclaw", "bench")
                            else ""))
    return hand


def _calibrate(args: argparse.Namespace) -> int:
    from lowcostdex.hands import HandSpec
    from lowcostdex.hardware.dynamixel.driver import DynamixelBus
    from lowcostdex.hardware.robot.calibration import calibrate_offsets, format_report
    from lowcostdex.outdir import check_out_file

    out = check_out_file(args.out, overwrite=True)  # a folder or a missing folder is refused
    if args.spec and out.exists() and Path(args.spec).exists() and out.samefile(args.spec):
        raise InputError(f"--out {args.out} is the --spec file itself: calibrating would "
                         "replace the spec it starts from (kept nowhere else); give a new file "
                         f"name, e.g. --out {shlex.quote(str(out.with_name(out.stem + '_calibrated.json')))}")
    if out.exists():  # replaced only with --overwrite, and only a hand spec
        try:
            HandSpec.load(out)
        except Exception:  # not a hand spec: the user's file, not ours to replace
            raise InputError(f"--out {out} exists and is not a hand spec; it is left untouched "
                             "(give a new file name)") from None
        if not args.overwrite:  # an earlier calibration: measured offsets, kept nowhere else
            raise InputError(f"--out {out} already holds a hand spec (an earlier calibration?) "
                             "and is left untouched; give a new file name, or --overwrite to "
                             "replace it")
    hand = _dynamixel_hand(args, "calibrate")
    if args.latency_ms is not None and args.port == "emulated":
        raise InputError("--latency-ms is the serial adapter's latency timer: it needs --port "
                         "DEVICE (a serial device or a pty), not emulated")
    bus = DynamixelBus.from_hand(hand, _port(args), baudrate=args.baud, position_limits=None,
                                 **latency_kwargs(args.latency_ms))
    with bus:
        bus.set_torque(False)
        if not args.yes:
            _wait_for_enter(f"Torque is off. Put the {hand.name} in its zero pose (every joint at "
                            "0 rad) and press Enter... ", "calibrate",
                            "; with the hand in its zero pose, pass --yes to read it at once")
        new = calibrate_offsets(bus, hand, samples=args.samples)
    tmp = out.with_name(f".{out.name}.tmp")
    new.save(tmp)
    os.replace(tmp, out)  # a previous spec is replaced whole or not at all
    print(format_report(hand, new))
    print(f"wrote {args.out}")
    return 0


def _setup_motors(args: argparse.Namespace) -> int:
    from lowcostdex.hardware.dynamixel.ports import pick_port
    from lowcostdex.hardware.dynamixel.scan import scan
    from lowcostdex.hardware.dynamixel.setup_motors import check_hand, setup_motors

    check_baud(args.baud)
    hand = _dynamixel_hand(args, "setup-motors")
    if args.ids is not None and not args.ids.strip():  # an unset variable: not "every id"
        raise InputError("--ids is empty; name the ids (e.g. --ids 10-12,50), or leave it out")
    ids = parse_ids(args.ids) if args.ids else None
    port = pick_port(args.port)

    def ask(joint) -> None:
        _wait_for_enter(f"Connect ONLY the motor for {joint.name} (id {joint.motor_id}) to the "
                        "adapter, power it, then press Enter... ")

    results = setup_motors(port, hand, baudrate=args.baud, ids=ids, prompt=ask,
                           reassign=args.reassign)
    print(f"{len(results)} motors set to their ids at {args.baud} bps.")
    _wait_for_enter("Now connect all the hand's motors in a chain, power them, then press "
                    "Enter to scan... ")
    found = scan(port, args.baud)
    for m in found:
        print(f"  id {m.motor_id:>3}  {m.model:<12} fw {m.firmware}")
    problems = check_hand(found, hand, ids)
    for problem in problems:
        print(f"  ! {problem}")
    if problems:
        print("the hand is not complete; set up the motors named above with --ids")
        return 1
    print(f"all {len(found)} motors of the {hand.name} answer at {args.baud} bps")
    return 0


def _wait_for_enter(text: str, command: str = "setup-motors", fix: str = "") -> None:
    try:
        input(text)
    except EOFError:  # run from a script, a pipe or nohup: nobody to press Enter
        raise InputError(f"{command} needs a person at the keyboard (stdin is closed){fix}"
                         ) from None
