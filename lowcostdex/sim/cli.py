"""Sim subcommands: ``lowcostdex envs`` lists the environments; ``lowcostdex model`` writes an
MJCF (e.g. the nominal model for ``lowcostdex gap analyze``)."""

from __future__ import annotations

import argparse

from lowcostdex.argtypes import JoinRepeats


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("envs", help="list the registered gymnasium environments")
    p.set_defaults(func=_list_envs)

    p = sub.add_parser("model", help="write a lowcostdex MJCF model (D'Claw, Allegro, bench)")
    p.add_argument("hand", choices=("dclaw", "allegro", "bench"))
    p.add_argument("--station", default=None,
                   help="dclaw: valve, foam_valve, screw, block, none; allegro: valve, none")
    p.add_argument("--fingers", default=None, action=JoinRepeats,
                   help="comma-separated subset of the fingers: dclaw ff,mf,th; allegro "
                        "index,middle,ring,thumb (a model of the fingers a log moved, for "
                        "`lowcostdex gap analyze`)")
    p.add_argument("--motor", default=None, help="servo model, e.g. XM430-W350 (dclaw, bench)")
    p.add_argument("--no-thermal", action="store_true", help="no winding-temperature state")
    p.add_argument("--out", required=True, help="MJCF file to write (a new file)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=_write_model)


def _list_envs(args: argparse.Namespace) -> int:
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the ids)
    from lowcostdex.sim.registry import env_ids

    for env_id in env_ids():
        spec = gym.spec(env_id)
        print(f"{env_id:45s} max_episode_steps={spec.max_episode_steps}")
    return 0


def _write_model(args: argparse.Namespace) -> int:
    from lowcostdex.argtypes import names
    from lowcostdex.errors import ConfigError
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.outdir import check_out_file, write_text_atomic

    out = check_out_file(args.out, overwrite=args.overwrite)
    if out.suffix.lower() in (".urdf", ".sdf", ".mjb", ".usd", ".json"):  # another format
        raise ConfigError(f"--out {out}: `lowcostdex model` writes MJCF XML, not "
                          f"{out.suffix[1:].upper()}; name the file {out.with_suffix('.xml')} "
                          "(MuJoCo and `gap analyze --model` read it)")
    if out.exists() and not _is_mjcf(out):  # --overwrite replaces a model, nothing else
        raise ConfigError(f"--out {out} is not an MJCF model (no <mujoco> root); --overwrite "
                          "replaces a model file only, and this file is left untouched. Give "
                          "a new file name")
    if args.fingers is not None and not args.fingers.strip():
        raise ConfigError("--fingers is empty; name the fingers (e.g. --fingers ff), or leave "
                          "it out for the whole hand")
    if args.motor and args.hand == "allegro":
        raise ConfigError(f"--motor {args.motor}: the Allegro's joints are torque-driven on CAN "
                          "(no servo model); --motor is for dclaw and bench")
    if args.hand == "dclaw":
        from lowcostdex.sim.models.dclaw import build_dclaw

        kwargs = {"fingers": names(args.fingers, "--fingers")} if args.fingers else {}
        spec = build_dclaw(args.station or "valve",
                           dclaw_spec(args.motor) if args.motor else dclaw_spec(),
                           thermal=not args.no_thermal, **kwargs)
    elif args.hand == "allegro":
        from lowcostdex.sim.models.allegro import build_allegro

        kwargs = {"fingers": names(args.fingers, "--fingers")} if args.fingers else {}
        spec = build_allegro(args.station or "valve", **kwargs)
    else:
        from lowcostdex.sim.models.bench import BenchConfig, build_bench

        if args.fingers:
            raise ConfigError("--fingers is for dclaw and allegro; the bench has one joint")
        if args.station is not None:  # before: ignored, a bench model written without a word
            raise ConfigError(f"--station {args.station}: the bench has no station (one servo "
                              "and its arm); --station is for dclaw and allegro")

        spec = build_bench(BenchConfig(motor=args.motor or "XL330-M288",
                                       thermal=not args.no_thermal))
    spec.compile()  # fail here, not in the user's tool
    write_text_atomic(out, spec.to_xml())
    print(f"wrote {out}")
    return 0


def _is_mjcf(path) -> bool:
    """True if ``path`` is an XML file whose root element is ``<mujoco>`` (a model)."""
    import xml.etree.ElementTree as ET

    try:
        return ET.parse(path).getroot().tag == "mujoco"
    except (ET.ParseError, OSError, ValueError):
        return False
