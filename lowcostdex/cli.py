"""The ``lowcostdex`` command: one CLI, subcommands contributed by the package's layers.

Each module in ``COMMAND_MODULES`` exposes ``add_commands(subparsers)``; it adds its
subcommands and sets ``func`` (called with the parsed namespace, returning an exit code).
Modules import heavy dependencies inside their handlers so ``lowcostdex --help`` is fast.

One error path: a user's mistake (a ``LowcostdexError``, a file that cannot be opened, a bad
argument) prints ONE line ``lowcostdex CMD: error: ...`` and exits with code 2, without a
traceback (``--debug``, anywhere on the line, shows it); Ctrl-C prints one line and exits with
130; any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import shlex
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

COMMAND_MODULES: tuple[str, ...] = (
    "lowcostdex.sim.cli",
    "lowcostdex.gap.cli",
    "lowcostdex.main_job",
    "lowcostdex.algos.cli",
    "lowcostdex.hardware.cli",
    "lowcostdex.hardware.robot.cli",
    "lowcostdex.transfer.cli",
    "lowcostdex.demonstrations.cli",
)
# the exit codes live in the core (lowcostdex.errors) so that any layer can name them
from lowcostdex.argtypes import home  # noqa: E402
from lowcostdex.errors import INTERRUPTED, USER_ERROR  # noqa: E402

PATH_OPTIONS = ("out", "json", "demos", "spec", "effects", "model", "port", "log", "holdout")
"""Options that name a file, folder or device: an empty one is refused (``Path("")`` is the
working directory, so ``train --out ""`` wrote a run among the user's files), and a leading
``~`` is the home folder (``--out=~/runs`` and ``--out "~/runs"`` reach us unexpanded)."""


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line, and whose every (sub)command takes ``--debug``."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                          help="show the traceback of an error")

    def error(self, message: str):
        self.exit(USER_ERROR, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="lowcostdex",
        description="Learn dexterous skills on low-cost robot hands (D'Claw, Allegro).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_commands(sub)
    return parser


def command_parser(parser: argparse.ArgumentParser,
                   args: argparse.Namespace) -> argparse.ArgumentParser:
    """The (sub)parser of the command ``args`` runs."""
    while True:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        name = getattr(args, subs[0].dest, None) if subs else None
        if name is None or name not in subs[0].choices:
            return parser
        parser = subs[0].choices[name]


def command_prog(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The full name of the command ``args`` runs, e.g. ``"lowcostdex gap analyze"``."""
    return command_parser(parser, args).prog


def unrecognized(parser: argparse.ArgumentParser, extra: Sequence[str],
                 argv: Sequence[str] = ()) -> str:
    """The error for arguments ``parser`` does not take, with the closest options it does, and
    the list to type when a space after a comma in ``argv`` split one (``--stages bus, demos``:
    "unrecognized arguments: demos" alone before)."""
    import difflib

    known = sorted({o for a in parser._actions for o in a.option_strings if o.startswith("--")})
    hints = []
    for arg in extra:
        if arg.startswith("--"):
            close = difflib.get_close_matches(arg.split("=", 1)[0], known, n=3, cutoff=0.6)
            if close:
                hints.append(f"{arg.split('=', 1)[0]}: did you mean {' or '.join(close)}?")
    for i, tok in enumerate(argv):
        words = [tok] if tok.startswith("--") and "=" in tok else argv[i + 1:i + 2]
        if not tok.startswith("--") or not words or not words[0].endswith(","):
            continue
        j = i + len(words) - (tok in words)
        while words[-1].endswith(",") and j + 1 < len(argv) and not argv[j + 1].startswith("-"):
            j += 1
            words.append(argv[j])
        if any(w in extra for w in words[1:]):
            flag = "" if tok in words else f"{tok} "
            hints.append(f"{flag}{' '.join(words)}: a space after a comma ends the list there; "
                         f"type {flag}{''.join(words)}")
    more = f"; {'; '.join(hints)}" if hints else ""
    return f"unrecognized arguments: {' '.join(extra)}{more}"


def main(argv: Sequence[str] | None = None) -> int:
    words = _argv_words(argv)
    if words is not None:
        return _report("lowcostdex", words, False, USER_ERROR)
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:  # named by the subcommand that was given them, not by `lowcostdex`
            sub = command_parser(parser, args)
            sub.error(unrecognized(sub, extra, sys.argv[1:] if argv is None else list(argv)))
    except SystemExit as exc:  # --help (0) or a bad argument (2, its line already printed)
        return exc.code if isinstance(exc.code, int) else USER_ERROR
    if getattr(args, "func", None) is None:
        parser.print_help()
        return USER_ERROR
    prog = command_prog(parser, args)
    debug = getattr(args, "debug", False)
    for dest in PATH_OPTIONS:  # "" is the cwd to pathlib: an unset shell variable, not a path
        value = getattr(args, dest, None)
        if value == "" or (isinstance(value, list) and "" in value):
            what = "is empty" if value == "" else "has an empty path"
            return _report(prog, f"--{dest} {what} (an unset shell variable?); give a path",
                           False, USER_ERROR)
        if isinstance(value, str):
            setattr(args, dest, home(value))
        elif isinstance(value, list):
            setattr(args, dest, [home(v) if isinstance(v, str) else v for v in value])
    return guarded(prog, lambda: args.func(args), debug)


def _argv_words(argv: object) -> str | None:
    """What is wrong with ``main(argv)``'s words from Python, or None: a str was read letter by
    letter ("invalid choice: 's'" for "scan --help"), a number failed in argparse."""
    if argv is None:
        return None
    if isinstance(argv, str):
        try:
            split = shlex.split(argv)
        except ValueError:  # an unclosed quote
            split = argv.split()
        return (f"main(argv) takes the words of a command as a list, e.g. main({split!r:.80}) "
                f"(shlex.split of the line), not one str")
    if not isinstance(argv, Sequence):
        return f"main(argv) takes a list of words, not {type(argv).__name__}"
    for i, w in enumerate(argv):
        if not isinstance(w, str):
            return (f"main(argv): argv[{i}]={w!r:.40} is not a str; give every word as typed "
                    f"in a shell, e.g. {str(w)!r}")
    return None


def guarded(prog: str, call: Callable[[], object], debug: bool = False,
            on_interrupt: str | None = None) -> int:
    """Run ``call()`` under the one error path; its exit code (``None`` is 0).

    A ``LowcostdexError`` or a path that cannot be opened prints ``{prog}: error: ...`` (exit 2),
    Ctrl-C prints one line (exit 130; ``on_interrupt`` is added to it: how to go on);
    ``debug`` adds the traceback. Any other exception is a bug
    and propagates. A ``SystemExit`` (argparse's own one-line errors) passes through.
    """
    from lowcostdex.errors import LowcostdexError
    from lowcostdex.sim.mjwarnings import collect_mujoco_warnings

    try:
        with collect_mujoco_warnings() as warned:  # recorded, not printed or MUJOCO_LOG.TXT
            code = int(call() or 0)
        if warned.messages:
            print(f"{prog}: note: {warned.summary()}", file=sys.stderr)
        return code
    except LowcostdexError as exc:
        return _report(prog, str(exc), debug, USER_ERROR)
    except (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError) as exc:
        if exc.filename is None:  # not about a path the user gave: a bug
            raise
        return _report(prog, f"cannot open {exc.filename}: {exc.strerror}", debug, USER_ERROR)
    except KeyboardInterrupt as exc:  # an Interrupted says what is kept and how to go on
        more = f"; {exc}" if str(exc) else ""  # a trainer's names its run and checkpoint
        if on_interrupt:
            more += f"; {on_interrupt}"
        return _report(prog, f"interrupted (Ctrl-C){more}", debug, INTERRUPTED)


def run_script(script_main: Callable[[], object], on_interrupt: str | None = None) -> NoReturn:
    """The entry point of a script in ``demos/``: ``script_main()`` under the CLI's error path.

    A user's mistake (a bad option value, a missing file, a port that is not there) is one line
    ``<script>: error: ...`` and exit code 2, Ctrl-C one line and 130, as for ``lowcostdex``
    commands; ``--debug`` anywhere on the line is taken out before the script parses its options
    and shows the traceback.
    """
    argv = sys.argv[1:]
    debug = "--debug" in argv
    if debug:
        sys.argv = [sys.argv[0], *(a for a in argv if a != "--debug")]
    prog = Path(sys.argv[0]).name
    sys.exit(guarded(prog, script_main, debug, on_interrupt))


def _report(prog: str, message: str, debug: bool, code: int) -> int:
    if debug:
        traceback.print_exc()
    print(f"{prog}: error: {message}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
