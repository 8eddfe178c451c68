"""``lowcostdex gap``: analyze measured logs against a model; generate hidden-effect demo data.

    lowcostdex gap analyze --model MODEL.xml --log a.csv b.csv --out report/
    lowcostdex gap analyze --bench --log ../shared/data/measured/rhoban-bam-xl330/*.json --out r/
    lowcostdex gap generate --rig bench --effect latency --seed 1 --out demo/
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lowcostdex.argtypes import SEED, integer, number


def add_commands(sub: argparse._SubParsersAction) -> None:
    gap = sub.add_parser("gap", help="reality-gap analysis of measured servo logs")
    gsub = gap.add_subparsers(dest="gap_command", metavar="SUBCOMMAND")
    gap.set_defaults(func=lambda a: (gap.print_help(), 2)[1])

    a = gsub.add_parser("analyze", help="show what the model gets wrong, name the causes, "
                        "extend the model and measure the gain")
    a.add_argument("--model", help="MJCF of the nominal model (project-format logs)")
    a.add_argument("--log", nargs="+", required=True, metavar="FILE",
                   help="logs: CSV/NPZ in the project format, or BAM raw-log JSON; a folder "
                        "means every log in it, a quoted pattern ('logs/*.csv') its matches")
    a.add_argument("--out", required=True, help="output folder: new or empty, or a previous report (kept in previous/)")
    a.add_argument("--bench", action="store_true",
                   help="logs are BAM JSON mapped onto the servo bench (default: auto-detect)")
    a.add_argument("--holdout", nargs="+", metavar="FILE", default=None,
                   help="logs held out for the test (default: random episodes)")
    a.add_argument("--candidates", default=None,
                   help="comma-separated effects to consider (default: all with logged channels)")
    a.add_argument("--max-effects", type=integer(1, 20), default=3)
    a.add_argument("--top-k", type=integer(1, 50), default=6, help="candidates fitted per round")
    a.add_argument("--min-gain", type=number(0, 1, open_low=True, open_high=True), default=0.05,
                   help="smallest relative select-MSE reduction to accept an effect")
    a.add_argument("--seed", type=SEED, default=0)
    a.add_argument("--threads", type=integer(0, 1024), default=0,
                   help="simulation threads (0: all CPUs)")
    a.set_defaults(func=_analyze)

    g = gsub.add_parser("generate", help="write synthetic logs with hidden effects (demo/tests)")
    g.add_argument("--rig", choices=("bench", "finger"), default="bench")
    g.add_argument("--effect", action="append", default=[],
                   help="effect to hide (repeat for several; 'random' draws one; none: clean)")
    g.add_argument("--seed", type=SEED, default=0)
    g.add_argument("--logs", type=integer(1, 1000), default=4)
    g.add_argument("--duration", type=number(1.0, 3600.0), default=8.0,
                   help="seconds per log")
    g.add_argument("--rate", type=number(2.0, 10_000.0), default=100.0, help="log rate [Hz]")
    g.add_argument("--format", choices=("csv", "npz"), default="csv")
    g.add_argument("--out", required=True, help="output folder: new or empty, or a previous "
                   "generate output (kept in previous/)")
    g.set_defaults(func=_generate)


@contextmanager
def analysis_progress(console: Any) -> Iterator[Callable[[str, float], None]]:
    """A transient progress bar for ``analyze``; yields its ``progress(stage, fraction)``."""
    from lowcostdex.progress import tasks

    with tasks(console=console) as bar:
        task = bar.add_task("gap analysis", total=100)
        yield lambda stage, frac: bar.update(task, completed=round(100 * frac),
                                             description=f"gap analysis: {stage}")


def _analyze(args: argparse.Namespace) -> int:
    from rich.console import Console

    from lowcostdex.errors import ConfigError
    from lowcostdex.gap.analyze import GapConfig, analyze
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.report import summary, write_report
    from lowcostdex.outdir import check_out
    from lowcostdex.sim.mjwarnings import describe_warnings

    console = Console(stderr=True)
    check_out(args.out, "gap analyze")  # refuse a user's folder before minutes of work
    logs = [str(p) for p in args.log]
    ds = load_dataset(logs, model=args.model, bench=True if args.bench else None)
    for note in ds.notes:
        console.print(f"lowcostdex gap analyze: note: {note}", markup=False, highlight=False)
    test = None
    if args.holdout:
        resolved = {str(Path(p).resolve()) for p in args.holdout}
        if not resolved <= {str(Path(p).resolve()) for p in logs}:
            raise ConfigError("every --holdout file must also be given with --log")
        # a log split at a gap is held out whole
        test = tuple(i for i, p in enumerate(ds.sources) if str(Path(p).resolve()) in resolved)
    cands = tuple(c.strip() for c in args.candidates.split(",")) if args.candidates else None
    cfg = GapConfig(candidates=cands, max_effects=args.max_effects, top_k=args.top_k,
                    min_gain=args.min_gain, seed=args.seed, test_logs=test,
                    nthread=args.threads)
    with analysis_progress(console) as progress:
        result = analyze(ds, cfg, progress)
    out = write_report(result, args.out)
    print(summary(result))
    if result.mujoco_warnings:
        print(describe_warnings(result.mujoco_warnings, 1) + " (all in report.md)")
    print(f"report: {out / 'report.md'} (json: {out / 'report.json'}; extended model: "
          f"{out / 'extended'})")
    return 0


def _generate(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from lowcostdex.gap.generate import LogSettings, generate
    from lowcostdex.gap.logs import write_log
    from lowcostdex.outdir import check_out, staged_output

    out = Path(args.out)
    check_out(out, "gap generate")
    effects = [e for e in args.effect if e != "none"]
    syn = generate(args.rig, effects, np.random.default_rng(args.seed), n_logs=args.logs,
                   duration=args.duration, settings=LogSettings(rate=args.rate))
    with staged_output(out, "gap generate", {"rig": args.rig, "seed": args.seed}) as tmp:
        (tmp / "model.xml").write_text(syn.xml)
        paths = [write_log(tmp / f"{tr.name}.{args.format}", tr) for tr in syn.trajectories]
        truth = {"hidden": [e.to_dict() for e in syn.hidden], "noise_floor": syn.settings.floor,
                 "seed": args.seed, "rig": args.rig}
        (tmp / "truth.json").write_text(json.dumps(truth, indent=2))
    print(f"wrote {len(paths)} logs and model.xml to {out} (truth in truth.json: "
          f"{[e.name for e in syn.hidden] or 'no hidden effect'})")
    return 0
