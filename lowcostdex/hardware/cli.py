"""Hardware subcommands: ``lowcostdex scan``, ``lowcostdex emulate``, ``lowcostdex calibrate``.

    lowcostdex scan --port /dev/ttyUSB0            # ping, models, firmware, temperatures, errors
    lowcostdex scan --port emulated --hand dclaw   # the same against an in-process emulated D'Claw
    lowcostdex emulate dclaw                       # prints "PORT /dev/pts/N", serves until Ctrl-C
    lowcostdex emulate bench --clock virtual       # single servo; bus time instead of wall time
    lowcostdex calibrate --hand dclaw --port /dev/ttyUSB0 --out dclaw_calibrated.json
"""

from __future__ import annotations

import argparse
import sys


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scan", help="find Dynamixel motors: models, firmware, temperature, errors")
    p.add_argument("--port", required=True, help="serial device, pty path, or 'emulated'")
    p.add_argument("--baud", type=int, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--ids", default=None,
                   help="comma-separated ids or ranges (e.g. 10-12,50); default broadcast ping")
    p.add_argument("--hand", default="dclaw", choices=("dclaw", "bench"),
                   help="hand to emulate with --port emulated")
    p.set_defaults(func=_scan)

    p = sub.add_parser("emulate", help="serve an emulated Dynamixel hand on a pty")
    p.add_argument("hand", choices=("dclaw", "bench"))
    p.add_argument("--motor", default=None, help="servo model (default: the hand's)")
    p.add_argument("--station", default="valve",
                   help="D'Claw station (valve, foam_valve, screw, block, none = 9 motors)")
    p.add_argument("--baud", type=int, default=1_000_000, help="bit rate [bit/s]")
    p.add_argument("--clock", default="realtime", choices=("realtime", "virtual"),
                   help="physics on wall time, or on bus time (advances with the bytes only)")
    p.add_argument("--wire-time", action="store_true",
                   help="delay replies by their wire time (bytes x 10 / baud + return delay)")
    p.add_argument("--drop", type=float, default=0.0, help="status packet drop probability")
    p.add_argument("--corrupt", type=float, default=0.0, help="status packet corruption prob.")
    p.add_argument("--late", type=float, default=0.0, help="late status packet probability")
    p.add_argument("--no-fast-read", action="store_true", help="firmware without Fast Sync Read")
    p.add_argument("--effects", default=None,
                   help="JSON file: a list of AppliedEffect dicts the emulated robot carries")
    p.add_argument("--seed", type=int, default=0, help="seed of the fault generator")
    p.add_argument("--quiet", action="store_true", help="do not print motor events")
    p.set_defaults(func=_emulate)

    p = sub.add_parser("calibrate",
                       help="record per-joint offsets (hand in its zero pose) into a hand spec")
    p.add_argument("--hand", default="dclaw", choices=("dclaw", "bench"))
    p.add_argument("--spec", default=None, help="hand spec JSON to start from (default: built-in)")
    p.add_argument("--port", required=True, help="serial device, pty path, or 'emulated'")
    p.add_argument("--baud", type=int, default=1_000_000)
    p.add_argument("--out", required=True, help="where to write the calibrated hand spec JSON")
    p.add_argument("--samples", type=int, default=20, help="reads averaged per joint")
    p.add_argument("--yes", action="store_true", help="do not wait for Enter")
    p.set_defaults(func=_calibrate)


def parse_ids(text: str) -> list[int]:
    """"10-12,50" -> [10, 11, 12, 50]."""
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if "-" in part:
            a, b = part.split("-")
            out += range(int(a), int(b) + 1)
        elif part:
            out.append(int(part))
    return out


def _emulated_chain(hand: str, clock: str = "virtual", **kwargs):
    from lowcostdex.hardware.emulator import emulated_bench, emulated_dclaw

    if hand == "dclaw":
        return emulated_dclaw(clock=clock, **kwargs)
    return emulated_bench(clock=clock, **kwargs)


def _port(args: argparse.Namespace):
    if args.port == "emulated":
        return _emulated_chain(args.hand, baudrate=args.baud).port()
    return args.port


def _scan(args: argparse.Namespace) -> int:
    from lowcostdex.hardware.dynamixel import scan

    ids = parse_ids(args.ids) if args.ids else None
    found = scan(_port(args), args.baud, ids)
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
    import json
    import signal
    import time

    import numpy as np

    from lowcostdex.hardware.emulator import FaultConfig
    from lowcostdex.hardware.firmware import FirmwareOptions
    from lowcostdex.hardware.pty_server import PtyServer
    from lowcostdex.sim.effects import AppliedEffect

    effects = []
    if args.effects:
        with open(args.effects) as f:
            effects = [AppliedEffect.from_dict(d) for d in json.load(f)]
    kwargs = dict(faults=FaultConfig(drop=args.drop, corrupt=args.corrupt, late=args.late),
                  options=FirmwareOptions(fast_read=not args.no_fast_read), baudrate=args.baud,
                  wire_time=args.wire_time, effects=effects, rng=np.random.default_rng(args.seed))
    if args.hand == "dclaw":
        kwargs["station"] = args.station
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


def _calibrate(args: argparse.Namespace) -> int:
    from lowcostdex.hardware.calibration import calibrate_offsets, format_report
    from lowcostdex.hardware.dynamixel import DynamixelBus
    from lowcostdex.hardware.hands import HandSpec, hand_spec

    hand = HandSpec.load(args.spec) if args.spec else hand_spec(args.hand)
    bus = DynamixelBus.from_hand(hand, _port(args), baudrate=args.baud, position_limits=None)
    with bus:
        bus.set_torque(False)
        if not args.yes:
            input(f"Torque is off. Put the {hand.name} in its zero pose (every joint at 0 rad) "
                  "and press Enter... ")
        new = calibrate_offsets(bus, hand, samples=args.samples)
    new.save(args.out)
    print(format_report(hand, new))
    print(f"wrote {args.out}")
    return 0
