"""The ``lowcostdex`` command: one CLI, subcommands contributed by the package's layers.

Each module in ``COMMAND_MODULES`` exposes ``add_commands(subparsers)``; it adds its
subcommands and sets ``func`` (called with the parsed namespace, returning an exit code).
Modules import heavy dependencies inside their handlers so ``lowcostdex --help`` is fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

COMMAND_MODULES: tuple[str, ...] = (
    "lowcostdex.sim.cli",
    "lowcostdex.sim.gap.cli",
    "lowcostdex.main_job",
    "lowcostdex.algos.cli",
    "lowcostdex.hardware.cli",
    "lowcostdex.hardware.robot_cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lowcostdex",
        description="Learn dexterous skills on low-cost robot hands (D'Claw, Allegro).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_commands(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 2
    from lowcostdex.errors import LowcostdexError

    try:
        return int(args.func(args) or 0)
    except LowcostdexError as exc:
        print(f"lowcostdex {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
