"""``lowcostdex train ...``: one subcommand group whose trainers come from several modules.

Each module in ``TRAINER_MODULES`` exposes ``add_train_commands(train_subparsers)`` and adds
its trainers (``npg``/``dapg`` from :mod:`lowcostdex.algos.train_cli`, ``tvlg`` from the
local-models package). Adding the arguments must not import torch: heavy imports belong in the
handlers (tests/test_cli_startup.py checks this). A listed module that does not exist or does not expose the function yet is skipped;
one that fails to import is skipped with a message on stderr, so the other commands keep
working; ``lowcostdex train --help`` lists what is available.
"""

from __future__ import annotations

import argparse
import importlib
import sys

TRAINER_MODULES: tuple[str, ...] = (
    "lowcostdex.algos.train_cli",
    "lowcostdex.algos.local_models.train",
)


def add_commands(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``train`` group to the top-level ``lowcostdex`` parser."""
    parser = subparsers.add_parser(
        "train",
        help="train a controller (NPG, DAPG, local models) on the sim, emulated or real robot",
        description="Train a controller; each run writes a resumable run directory (--out).",
    )
    train_sub = parser.add_subparsers(dest="trainer", metavar="TRAINER")
    for name in TRAINER_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and name.startswith(exc.name):
                continue  # that trainer's module does not exist (yet)
            _unavailable(name, exc)
            continue
        except Exception as exc:  # a broken trainer must not take the other commands down
            _unavailable(name, exc)
            continue
        add = getattr(module, "add_train_commands", None)
        if add is not None:
            add(train_sub)
    parser.set_defaults(func=lambda args: parser.print_help() or 2)


def _unavailable(name: str, exc: BaseException) -> None:
    print(
        f"lowcostdex train: trainers of {name} unavailable: {type(exc).__name__}: {exc}",
        file=sys.stderr,
    )
