"""Running the main job: stages that compose in one output folder, and its command line."""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lowcostdex.argtypes import SEED, JoinRepeats, names
from lowcostdex.errors import Interrupted
from lowcostdex.main_job.report import markdown_report, stage_summary, write_html
from lowcostdex.main_job.setup import DEFAULT_TASK, SIZES, TASKS, Context
from lowcostdex.main_job.stages import (
    stage_bus,
    stage_demos,
    stage_gap,
    stage_report,
    stage_train,
)
from lowcostdex.options import add_robot_port_options, robot_port

STAGES: tuple[tuple[str, Callable[[Context], dict[str, Any]]], ...] = (
    ("bus", stage_bus),
    ("demos", stage_demos),
    # the gap stage before train: DAPG's iterates are validated in the simulation it
    # identified (``gapsim.validation_sim``); train without it validates in its own sim
    ("gap", stage_gap),
    ("train", stage_train),
    ("report", stage_report),
)


DEPENDS: dict[str, tuple[str, ...]] = {"train": ("demos",)}
"""Stages whose results a stage reads from ``--out`` (``train`` learns from ``demos.h5``)."""
OUTPUTS: dict[str, tuple[str, ...]] = {
    "bus": ("hand.json",),
    "demos": ("demos.h5",),
    "train": ("train_dapg", "train_npg", "learning_curves.png", "flip_rollout.png",
              "flip_rollout.npz"),
    "gap": ("gap",),
    "report": ("robot_health.png",),
}
"""What each stage writes into ``--out``; a re-run moves them into ``previous/<time>/`` first."""
COMMAND = "main"
RESULTS = "results.json"


def _settings(ctx: Context) -> dict[str, Any]:
    return {"task": ctx.task, "size": ctx.size, "seed": ctx.seed, "port": ctx.port}


def open_job(ctx: Context, stages: tuple[str, ...]) -> None:
    """Check ``ctx.out`` and load what earlier stages left there into ``ctx.results``.

    Raises:
      OutputRefused: ``ctx.out`` holds files the main job did not write, or a run with another
        task, size, seed or port (its stages cannot build on each other).
      ConfigError: a requested stage needs a stage that neither runs now nor finished earlier in
        ``ctx.out``; the message names it and the command that provides it.
    """
    from lowcostdex.errors import ConfigError
    from lowcostdex.outdir import check_out

    settings = _settings(ctx)
    previous = check_out(ctx.out, COMMAND, settings, must_match=tuple(settings))
    if previous and (ctx.out / RESULTS).exists():
        try:
            loaded = json.loads((ctx.out / RESULTS).read_text())
        except ValueError as exc:
            raise ConfigError(f"{ctx.out / RESULTS} is not readable JSON ({exc}); move it "
                              "away or use another --out") from exc
        ctx.results.update({k: v for k, v in loaded.items() if k in dict(STAGES)})
    for name in stages:
        for need in DEPENDS.get(name, ()):
            if need in stages:
                continue
            done = ctx.results.get(need)
            missing = done is None or not (ctx.out / done.get("file", "")).is_file()
            if missing:
                raise ConfigError(
                    f"stage '{name}' needs the results of stage '{need}', which neither runs "
                    f"now nor finished earlier in {ctx.out}; run "
                    f"`lowcostdex main --out {shlex.quote(str(ctx.out))} --stages {need},{name}` "
                    "(plus the same "
                    "--task/--size/--seed)")
    reported = [n for n, _ in STAGES if n != "report" and (n in stages or n in ctx.results)]
    if "report" in stages and not reported:
        raise ConfigError(
            f"stage 'report' has nothing to report: no stage ran now or finished earlier in "
            f"{ctx.out}; run `lowcostdex main --out {shlex.quote(str(ctx.out))}` (all stages) "
            "or a subset of "
            "--stages bus,demos,gap,train first (plus the same --task/--size/--seed)")


def _write_results(ctx: Context) -> None:
    from lowcostdex.outdir import write_text_atomic

    write_text_atomic(ctx.out / RESULTS, json.dumps(ctx.results, indent=2, default=float))


def run(ctx: Context, stages: tuple[str, ...] | None = None) -> Path:
    """Run the stages, write results.json, report.md and report.html; return report.md.

    Stages compose: results of stages that do not run now are read from ``ctx.out`` (a previous
    run with the same task, size, seed and port), and a stage whose input is missing stops before
    anything is written. A stage that runs again first moves its old outputs and the old
    results.json into ``previous/<time>/``; nothing finished is ever overwritten.
    """
    from rich.console import Console

    from lowcostdex.outdir import archive, write_marker

    console = Console(stderr=True)
    order = tuple(name for name, _ in STAGES)
    _check_stages(stages, order)
    chosen = order if stages is None else tuple(n for n in order if n in stages)
    open_job(ctx, chosen)
    console.print(_plan(ctx, chosen), soft_wrap=True, markup=False, highlight=False)
    ctx.out.mkdir(parents=True, exist_ok=True)
    write_marker(ctx.out, COMMAND, _settings(ctx))
    for name, fn in STAGES:
        if name not in chosen:
            continue
        old = [n for n in OUTPUTS[name] if (ctx.out / n).exists()]
        if old or name in ctx.results:
            target = archive(ctx.out, [*old, "report.md", "report.html"])
            if target is not None and (ctx.out / RESULTS).exists():
                shutil.copy2(ctx.out / RESULTS, target / RESULTS)
            if target is not None:
                console.print(f"{name}: the previous outputs are kept in "
                              f"{target.relative_to(ctx.out)}/")
        console.rule(f"[bold]{name}[/bold]: {fn.__doc__.splitlines()[0]}")
        t0 = time.perf_counter()
        try:
            result = fn(ctx)
        except KeyboardInterrupt:
            raise _interrupted(ctx, name, chosen) from None
        result["seconds"] = round(time.perf_counter() - t0, 1)
        result["finished"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        ctx.results[name] = result
        console.print(stage_summary(name, result))
        _write_results(ctx)
    report = ctx.out / "report.md"
    text = markdown_report(ctx)
    report.write_text(text)
    write_html(text, ctx.out / "report.html")
    return report


def _check_stages(stages: object, order: tuple[str, ...]) -> None:
    """``run``'s stages: None or a non-empty sequence of stage names (before: an unknown name
    ran no stage and wrote an empty report; a str was matched by substring)."""
    from lowcostdex.errors import ConfigError, check_choice

    if stages is None:
        return
    if isinstance(stages, str) or not isinstance(stages, (tuple, list)) or not stages:
        raise ConfigError(f"stages={stages!r:.60} must be None (every stage) or a non-empty "
                          f"tuple of stage names, e.g. ('gap',); valid: {', '.join(order)}")
    for s in stages:
        check_choice("stage", s, order)


CPU = {"smoke": "~4 min of CPU", "default": "~25 min of CPU on one core",
       "long": "longer than default: 60 DAPG and 60 NPG iterations, not timed"}
"""What a size costs, said before the job starts (README's timings)."""


def _plan(ctx: Context, chosen: tuple[str, ...]) -> str:
    """What the job is about to do and where it writes, said first (a bare ``lowcostdex main``
    starts the whole default job)."""
    robot = f"the D'Claw on {ctx.port}" if ctx.port else "the emulated D'Claw"
    smoke = "; --size smoke checks every stage in ~4 min" if ctx.size != "smoke" else ""
    return (f"lowcostdex main: stages {', '.join(chosen)}; task {ctx.task}, size {ctx.size} "
            f"({CPU.get(ctx.size, '')}), seed {ctx.seed}, on {robot}; writing into "
            f"{ctx.out.resolve()}/ (--out). Ctrl-C stops it and prints the command that "
            f"continues{smoke}.")


def _interrupted(ctx: Context, name: str, chosen: tuple[str, ...]) -> Interrupted:
    """Ctrl-C in stage ``name``: what results.json holds and the command that continues."""
    rest = chosen[chosen.index(name):]
    words = ["lowcostdex", "main", "--out", str(ctx.out), "--size", ctx.size, "--seed",
             str(ctx.seed), "--task", ctx.task]
    if ctx.port is not None:
        words += ["--port", ctx.port]
    done = [n for n, _ in STAGES if n in ctx.results]
    kept = (f"{ctx.out / RESULTS} holds the finished stages ({', '.join(done)})" if done
            else "no stage finished")
    return Interrupted(f"stage {name} did not finish (its partial outputs go to previous/ when "
                       f"it runs again); {kept}. Continue with: "
                       f"{shlex.join([*words, '--stages', ','.join(rest)])}")


def _overview() -> str:
    import lowcostdex.main_job as package

    return (package.__doc__ or "").split("\n\n")[0]


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("main", help="run the main job end to end (emulated D'Claw by default)",
                       description=_overview())
    p.add_argument("--out", default="runs/main", help="output folder (default: runs/main)")
    p.add_argument("--size", choices=SIZES, default="default",
                   help="budget: smoke (every stage checked, ~4 min of CPU), default (~25 min "
                        "of CPU on one core; more wall under load), long")
    p.add_argument("--seed", type=SEED, default=0, help="seed of every stage (default %(default)s)")
    p.add_argument("--task", choices=sorted(TASKS), default=DEFAULT_TASK,
                   help="valve-target: turn the valve from 0 to a random target in 180 +- 29 "
                   "deg; valve: turn it 180 deg; valve-random: random start and target "
                   "angles; flip: flip the block 180 deg")
    add_robot_port_options(p, port_help="serial port of a real D'Claw, e.g. /dev/ttyUSB0 "
                                        "(default: the emulated D'Claw)")
    p.add_argument("--stages", default=None, action=JoinRepeats,
                   help=f"comma-separated subset of: {', '.join(n for n, _ in STAGES)}")
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    from lowcostdex.errors import ConfigError, check_choice

    stages = None
    if args.stages is not None:  # '--stages ""' is not "every stage"
        stages = names(args.stages, "--stages")
        if not stages:
            raise ConfigError(f"--stages {args.stages!r} names no stage; give a comma-separated "
                              f"subset of {', '.join(n for n, _ in STAGES)}")
        for s in stages:
            check_choice("stage", s, [n for n, _ in STAGES])
    # --backend/--port as every robot command spells them, resolved before --out is opened
    port = robot_port(args.backend, args.port)
    device = None if port == "emulated" else port
    if device is not None:
        from lowcostdex.hardware.dynamixel.ports import check_port

        check_port(device)
    ctx = Context(out=Path(args.out), size=args.size, seed=args.seed, port=device, task=args.task)
    report = run(ctx, stages)
    print(f"REPORT {report.resolve()}")
    return 0
