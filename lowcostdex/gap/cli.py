"""``lowcostdex gap``: analyze measured logs against a model; generate hidden-effect demo data.

    lowcostdex gap analyze --model MODEL.xml --log a.csv b.csv --out report/
    lowcostdex gap analyze --bench --log ../shared/data/measured/rhoban-bam-xl330/*.json --out r/
    lowcostdex gap identify --log ../shared/data/measured/rhoban-bam-xl330/ \
        --holdout held/*.json --out identified/
    lowcostdex gap generate --rig bench --effect latency --seed 1 --out demo/
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lowcostdex.argtypes import SEED, JoinRepeats, integer, names, number


def add_commands(sub: argparse._SubParsersAction) -> None:
    gap = sub.add_parser("gap", help="reality-gap analysis of measured servo logs")
    gsub = gap.add_subparsers(dest="gap_command", metavar="SUBCOMMAND")
    gap.set_defaults(func=lambda a: (gap.print_help(), 2)[1])

    a = gsub.add_parser("analyze", help="show what the model gets wrong, name the causes, "
                        "extend the model and measure the gain")
    a.add_argument("--model", help="MJCF of the nominal model (project-format logs)")
    # "--logs" as record-log spells it (and names the folder): was "required: --log"; given
    # twice (--log a.csv --log b.csv) both count (action extend: was the last one alone)
    a.add_argument("--log", "--logs", nargs="+", action="extend", required=True, metavar="FILE", dest="log",
                   help="logs: CSV/NPZ in the project format, or BAM raw-log JSON; a folder "
                        "means every log in it, a quoted pattern ('logs/*.csv') its matches")
    a.add_argument("--out", required=True, help="output folder: new or empty, or a previous report (kept in previous/)")
    a.add_argument("--bench", action="store_true",
                   help="logs are BAM JSON mapped onto the servo bench (default: auto-detect)")
    a.add_argument("--holdout", nargs="+", action="extend", metavar="FILE", default=None,
                   help="logs held out for the test (default: random episodes)")
    a.add_argument("--candidates", default=None, action=JoinRepeats,
                   help="comma-separated effects to consider (default: all with logged channels)")
    a.add_argument("--max-effects", type=integer(1, 20), default=3,
                   help="most hidden effects named together (default %(default)s)")
    a.add_argument("--top-k", type=integer(1, 50), default=6, help="candidates fitted per round")
    a.add_argument("--min-gain", type=number(0, 1, open_low=True, open_high=True, unit="fraction"),
                   default=0.05,
                   help="smallest relative select-MSE reduction to accept an effect")
    a.add_argument("--seed", type=SEED, default=0,
                   help="seed of the episode split and the fits (default %(default)s)")
    a.add_argument("--threads", type=integer(0, 1024), default=0,
                   help="simulation threads (0: all CPUs)")
    a.add_argument("--servo-period", type=number(0.0, 0.1, unit="s"), default=0.0,
                   metavar="S",
                   help="the servos' firmware update period [s] (0.001: a 1 kHz position loop, "
                        "Dynamixel/Feetech): the position law is sampled and its force held "
                        "between updates; 0 (default): continuous")
    a.add_argument("--units", choices=("rad", "deg"), default="rad",
                   help="the logs' angles: goal and qpos in rad, qvel in rad/s (default), or "
                        "deg and deg/s (as LeRobot records them); time stays in seconds")
    a.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default="s",
                   help="the unit of the logs' 'time' stamps (default s; ms: a logger's "
                        "millis(), us: micros(), ns: time.monotonic_ns()); qvel stays per "
                        "second")
    a.set_defaults(func=_analyze)

    i = gsub.add_parser("identify", help="fit the servo's own parameters (motor constants, "
                        "inertia, friction, mounting offset) on whole BAM bench logs, open loop, "
                        "and score held-out logs with BAM's per-log MAE")
    i.add_argument("--log", "--logs", nargs="+", action="extend", required=True, metavar="FILE", dest="log",
                   help="BAM raw-log JSON files (a folder: every log in it; include the "
                        "--holdout logs here too)")
    i.add_argument("--holdout", nargs="+", action="extend", metavar="FILE", default=None,
                   help="logs scored, not fitted (default: none; every log fitted)")
    i.add_argument("--restarts", type=integer(1, 20), default=3,
                   help="jittered fits per family (identify.IdentifyConfig.restarts)")
    i.add_argument("--threads", type=integer(0, 1024), default=0,
                   help="simulation threads (0: all CPUs)")
    i.add_argument("--prior", type=number(0.0, 10.0), default=0.0, metavar="RAD",
                   help="pull every fitted parameter toward its catalogue value: moving one "
                        "across its whole range costs like this RMS error [rad] on every fitted "
                        "log (identify.IdentifyConfig.prior; default 0: none; measured on "
                        "STS3250 in bench/RESULTS.md)")
    i.add_argument("--select", choices=("inner", "train", "types"), default="inner",
                   help="how the family is chosen: fitted on the training logs but those at "
                        "the smallest gain (or length, ...) and chosen on those (inner, the "
                        "default), on the training logs themselves (train), or by leaving each "
                        "training trajectory type out in turn (types) (identify.IdentifyConfig"
                        ".select)")
    i.add_argument("--json", default=None, metavar="FILE",
                   help="also write the identified parameters and per-log MAE here")
    i.add_argument("--out", default=None, metavar="DIR",
                   help="output folder (new or empty, or a previous identify output, kept in "
                        "previous/): identified.json (as --json) and mae.png, the per-log "
                        "error of the identified and the nominal model")
    i.set_defaults(func=_identify)

    g = gsub.add_parser("generate", help="write synthetic logs with hidden effects (demo/tests)")
    g.add_argument("--rig", choices=("bench", "finger"), default="bench",
                   help="one servo and its arm, or a D'Claw finger (default %(default)s)")
    g.add_argument("--effect", action="append", default=[],
                   help="effect to hide (repeat for several; 'random' draws one; none: clean)")
    g.add_argument("--seed", type=SEED, default=0, help="seed of the excitation and effects (default %(default)s)")
    g.add_argument("--logs", type=integer(1, 1000), default=4, help="number of logs (default %(default)s)")
    g.add_argument("--duration", type=number(1.0, 3600.0), default=8.0,
                   help="seconds per log")
    g.add_argument("--rate", type=number(2.0, 10_000.0), default=100.0, help="log rate [Hz]")
    g.add_argument("--format", choices=("csv", "npz"), default="csv",
                   help="log file format (default %(default)s)")
    g.add_argument("--out", required=True, help="output folder: new or empty, or a previous "
                   "generate output (kept in previous/)")
    g.set_defaults(func=_generate)


@contextmanager
def analysis_progress(console: Any, label: str = "gap analysis"
                      ) -> Iterator[Callable[[str, float], None]]:
    """A transient progress bar for ``analyze`` and ``identify`` (a line every ~10 s when not a
    terminal); yields its ``progress(stage, fraction)``."""
    from lowcostdex.progress import tasks

    with tasks(console=console) as bar:
        task = bar.add_task(label, total=100)
        yield lambda stage, frac: bar.update(task, completed=round(100 * frac),
                                             description=f"{label}: {stage}")


def distinct_logs(given: list[str]) -> tuple[list[str], list[str]]:
    """The log files ``given`` names (folders and patterns expanded), each once: a file named
    twice (``logs/`` and ``logs/a.csv``) or a byte-identical copy under another name would sit
    in the fit and in the held-out test at once. Returns (paths, notes on what was left out)."""
    import hashlib

    from lowcostdex.gap.dataset import expand_log_paths

    out, notes, seen = [], [], {}
    for p in expand_log_paths(given, notes):
        key: object = str(p.resolve())
        try:
            if p.is_file() and p.stat().st_size <= 64 * 2**20:
                key = hashlib.sha256(p.read_bytes()).hexdigest()
        except OSError:
            pass  # unreadable: load_dataset names it
        if key in seen:
            what = ("named twice" if str(p.resolve()) == str(Path(seen[key]).resolve())
                    else f"the same bytes as {seen[key]}")
            notes.append(f"{p}: {what}; used once (a copy would be fitted and tested at once)")
            continue
        seen[key] = str(p)
        out.append(str(p))
    return out, notes


def _analyze(args: argparse.Namespace) -> int:
    import numpy as np
    from rich.console import Console

    from lowcostdex.errors import ConfigError
    from lowcostdex.gap.analyze import GapConfig, analyze
    from lowcostdex.gap.dataset import episodes, expand_log_paths, load_dataset, split_episodes
    from lowcostdex.gap.logs import LogError
    from lowcostdex.gap.report import summary, write_report
    from lowcostdex.gap.results import timestep_note
    from lowcostdex.outdir import check_out
    from lowcostdex.sim.mjwarnings import describe_warnings

    console = Console(stderr=True)
    check_out(args.out, "gap analyze")  # refuse a user's folder before minutes of work
    if args.candidates is not None and not args.candidates.strip(", "):
        # before: "" meant every effect, as if the option were absent
        raise ConfigError("--candidates is empty; name the effects (e.g. --candidates "
                          "latency,backlash), or leave it out for every effect the logs support")
    logs, same = distinct_logs(args.log)
    if args.holdout:  # a folder or a quoted pattern, read as --log reads them (as identify)
        args.holdout = [str(p) for p in expand_log_paths(args.holdout)]
    check_holdout(logs, args.holdout)
    try:
        ds = load_dataset(logs, model=args.model, bench=True if args.bench else None,
                          servo_period=args.servo_period, angle_unit=args.units,
                          time_unit=args.time_unit)
    except LogError as exc:  # a log in degrees or ms: say the option beside the unit's hint
        if args.units == "rad" and ("degrees?" in str(exc) or "deg/s or rpm?" in str(exc)):
            raise LogError(f"{exc}; or pass --units deg") from None
        unit = re.search(r": (ms|us|ns)\? \(", str(exc))
        if args.time_unit == "s" and unit and "column 'time'" in str(exc):
            raise LogError(f"{exc}; or pass --time-unit {unit.group(1)}") from None
        if args.time_unit != "s" and "column 'time' must be in seconds" in str(exc):
            raise LogError(f"{exc}, read as {args.time_unit} (--time-unit {args.time_unit}): if "
                           "'time' is in seconds already, leave out --time-unit") from None
        raise
    for note in same + ds.notes:
        console.print(f"lowcostdex gap analyze: note: {note}", markup=False, highlight=False,
                      soft_wrap=True)
    test = _holdout(logs, args.holdout, ds.sources)  # a log split at a gap is held out whole
    cands = (names(args.candidates, "--candidates")
             if args.candidates else None)  # "latency," (a trailing comma) is latency
    cfg = GapConfig(candidates=cands, max_effects=args.max_effects, top_k=args.top_k,
                    min_gain=args.min_gain, seed=args.seed, test_logs=test,
                    nthread=args.threads)
    # too little data is refused in one line before the progress bar starts (a dry split)
    split_episodes(ds, episodes(ds, cfg.chunk), np.random.default_rng(cfg.seed), test)
    with analysis_progress(console) as progress:
        result = analyze(ds, cfg, progress)
    out = write_report(result, args.out)
    print(summary(result))
    if result.mujoco_warnings:
        print(describe_warnings(result.mujoco_warnings, 1) + " (all in report.md)")
    if timestep_note(result.timestep):
        print("note: " + timestep_note(result.timestep))
    print(f"report: {out / 'report.md'} (json: {out / 'report.json'}; extended model: "
          f"{out / 'extended'})")
    return 0


def _same_bytes(a: str | Path, b: str | Path) -> bool:
    try:
        return Path(a).is_file() and Path(b).is_file() and \
            Path(a).stat().st_size == Path(b).stat().st_size and \
            Path(a).read_bytes() == Path(b).read_bytes()
    except OSError:
        return False


def _holdout(logs: list[str], holdout: list[str] | None, sources: list) -> tuple[int, ...] | None:
    """Indices of the data set's trajectories from the ``holdout`` files (a log split at a
    gap is held out whole); None without ``holdout``."""
    if not holdout:
        return None
    check_holdout(logs, holdout)
    resolved = {str(Path(p).resolve()) for p in holdout}
    return tuple(i for i, p in enumerate(sources) if str(Path(p).resolve()) in resolved)


def check_holdout(logs: list[str], holdout: list[str] | None) -> None:
    """ConfigError for a ``--holdout`` file that is not one of the ``logs`` used (after
    :func:`distinct_logs`): a copy of one of them, or a file not given with ``--log``."""
    from lowcostdex.errors import ConfigError

    kept = {str(Path(p).resolve()) for p in logs}
    for name in holdout or ():
        if str(Path(name).resolve()) in kept:
            continue
        twin = next((p for p in logs if _same_bytes(name, p)), None)
        if twin is not None:  # distinct_logs kept the other copy
            raise ConfigError(f"--holdout {name} holds the same bytes as the log {twin}, which "
                              "is used once (a copy would be fitted and tested at once): hold "
                              f"out {twin} itself, or give only one of the two")
        if not Path(name).exists():
            raise ConfigError(f"--holdout {name}: no such file; every --holdout file must also "
                              "be given with --log")
        raise ConfigError(f"--holdout {name} is not among the logs; every --holdout file must "
                          "also be given with --log")


IDENTIFY_KEYS = ("params", "family", "held_out", "fitted", "nominal")
"""Keys of the file ``gap identify --json`` writes: a file with them may be replaced."""


def _check_json_out(path: Path) -> None:
    """``--json FILE``: a new file in an existing folder, or a previous ``gap identify --json``
    output (replaced); a user's other file is refused untouched."""
    import json

    from lowcostdex.outdir import OutputRefused, check_file_folder

    if path.is_dir():
        raise OutputRefused(f"--json {path} is a folder; give a file path, e.g. "
                            f"--json {path / 'identified.json'}")
    check_file_folder(path, "--json")
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError):
            old = None
        if not (isinstance(old, dict) and all(k in old for k in IDENTIFY_KEYS)):
            raise OutputRefused(f"--json {path} already exists and is not a 'gap identify' "
                                "output; it is left untouched. Give a new file name")


def _identify(args: argparse.Namespace) -> int:
    import json
    import time

    from lowcostdex.errors import ConfigError
    from lowcostdex.gap import bam_measure as bm
    from lowcostdex.gap.dataset import expand_log_paths, load_dataset
    from lowcostdex.gap.identify import IdentifyConfig, identify, servo_structure, torque_off_seen
    from lowcostdex.gap.torque_off import no_swing_warning
    from lowcostdex.outdir import check_out, staged_output, write_text_atomic

    if args.json:
        _check_json_out(Path(args.json))  # before minutes of fitting
    if args.out:
        check_out(args.out, "gap identify")
    logs, same = distinct_logs(args.log)
    if args.holdout:
        args.holdout = [str(p) for p in expand_log_paths(args.holdout)]
    check_holdout(logs, args.holdout)
    ds = load_dataset(logs, bench=True, timestep=bm.BAM_DT)
    for note in same + ds.notes:  # before minutes of fitting: logs cut at gaps, defaults taken
        print(f"lowcostdex gap identify: note: {note}")
    ds = bm.grid_dataset(ds)  # BAM's 5 ms grid, as bam.process
    test = _holdout(logs, args.holdout, ds.sources) or ()
    train = [i for i in range(len(ds.trajectories)) if i not in test]
    if not train:
        raise ConfigError("every log is held out: nothing to fit")
    warn = no_swing_warning(torque_off_seen(ds, train))
    if warn:  # before minutes of fitting
        print(f"lowcostdex gap identify: {warn}")
    cfg = IdentifyConfig(effects=servo_structure(ds), restarts=args.restarts,
                         nthread=args.threads, prior=args.prior, select=args.select)
    from rich.console import Console

    t0 = time.perf_counter()
    with analysis_progress(Console(stderr=True), "gap identify") as progress:
        res = identify(ds, train, list(test), cfg, progress=progress)
    wall = time.perf_counter() - t0
    names = [Path(ds.sources[i]).name for i in range(len(ds.trajectories))]
    print(f"identified on {len(train)} logs ({wall:.0f} s); family {res.family}")
    print("  why: " + _why(res))
    for note in res.notes:
        print(f"  note: {note}")
    for e, ps in res.params().items():
        print(f"  {e}: " + ", ".join(f"{p} {v[0]:.4g}" for p, v in ps.items()))
    for setup, delta in res.setup_offsets.items():
        print(f"  mounting_offset of {setup}: {delta:+.4g} rad from the common one")
    if res.at_bound:
        print("  at a search bound: " + ", ".join(res.at_bound))
    print("per-log MAE [mrad] (BAM's measure: 5 ms grid, open loop from the first state):")
    for part, idx in (("held out", list(test)), ("fitted", train)):
        for i in idx:
            print(f"  {part:8s} {names[i]}: identified {1e3 * res.identified_mae[i]:.1f}, "
                  f"nominal {1e3 * res.nominal_mae[i]:.1f}")
        if idx:
            print(f"  {part} mean: identified {1e3 * res.mean(idx):.1f}, nominal "
                  f"{1e3 * res.mean(idx, identified=False):.1f}")
    if test:
        print(f"verdict: {res.verdict['text']}")
    if args.json or args.out:
        text = json.dumps({
            "params": res.params(), "setup_offsets": res.setup_offsets,
            "family": res.family, "selection": res.selection,
            "why": _why(res), "notes": res.notes,
            "at_bound": res.at_bound, "fit_seconds": res.fit_seconds, "wall_seconds": wall,
            "held_out": {names[i]: res.identified_mae[i] for i in test},
            "fitted": {names[i]: res.identified_mae[i] for i in train},
            "nominal": {names[i]: res.nominal_mae[i] for i in range(len(names))},
            "held_out_mean": res.mean(list(test)) if test else None,
            "verdict": res.verdict,
            "ablation": res.ablation}, indent=1, default=float)
    if args.json:
        write_text_atomic(args.json, text)
        print(f"json: {args.json}")
    if args.out:
        import matplotlib.pyplot as plt

        with staged_output(args.out, "gap identify") as tmp:
            (tmp / "identified.json").write_text(text)
            fig = mae_figure(names, res.identified_mae, res.nominal_mae, list(test), res.family)
            fig.savefig(tmp / "mae.png", dpi=110)
            plt.close(fig)
        print(f"out: {Path(args.out) / 'identified.json'} and {Path(args.out) / 'mae.png'}")
    return 0


def mae_figure(names: list[str], identified: Any, nominal: Any, test: list[int],
               family: str) -> Any:
    """Bars of each log's MAE [mrad] (BAM's measure), identified beside nominal, held-out logs
    first and marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    order = list(test) + [i for i in range(len(names)) if i not in test]
    x = np.arange(len(order))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.35 * len(order) + 2), 4.5))
    ax.bar(x - 0.2, [1e3 * nominal[i] for i in order], 0.4, label="nominal model")
    ax.bar(x + 0.2, [1e3 * identified[i] for i in order], 0.4, label=f"identified (family {family})")
    ax.set_xticks(x, [("held out: " if i in test else "") + names[i] for i in order],
                  rotation=90, fontsize=7)
    ax.set_xlabel("log")
    ax.set_ylabel("MAE, open loop [mrad]")
    ax.set_title("gap identify: per-log error (BAM's measure, 5 ms grid)")
    ax.legend(loc="upper right")
    fig.tight_layout()
    return fig


def _why(res: Any) -> str:
    """One line on how ``identify`` chose the family it returns (``Identified``)."""
    from lowcostdex.gap.identify import INNER_FIELDS

    fam = ", ".join(f"{f} {1e3 * v:.1f}" for f, v in res.family_train_mae.items())
    sel = res.selection
    if sel and "folds" in sel:
        return (f"each training trajectory type ({', '.join(sel['folds'])}) left out in turn, "
                f"every family fitted on the others and scored on it; chosen {sel['chosen']} "
                f"(mean MAE over the left-out types [mrad] per family: {fam}; the fewest free "
                "parameters unless another family is 2 % lower), then fitted on all training "
                "logs")
    if sel:
        return (f"fitted on the training logs but those at the smallest {sel['field']} "
                f"({len(sel['fit_logs'])} fitted, {len(sel['val_logs'])} held back); per family "
                f"the restart with the lowest cost, chosen {sel['chosen']} on the fitted logs "
                f"(mean MAE [mrad] per family: {fam}; the fewest free parameters unless another "
                "family is 2 % lower)" + _stage_why(sel.get("stage")))
    return (f"no header field ({', '.join(INNER_FIELDS)}) varies among the training logs, "
            "so nothing validates the fit: the family was chosen on the training logs' own MAE"
            + (f" [mrad]: {fam}" if fam else "") + "; expect a larger error on logs unlike them")


def _stage_why(st: dict | None) -> str:
    """How the held-back logs chose the chosen fit's stage (``identify_select.choose_stage``)."""
    if not st or len(st.get("val_mae", ())) < 2:
        return ""
    names = ["the first stage (motor constants at their catalogue values)", "the joint fit"]
    vals = " / ".join(f"{1e3 * v:.1f}" for v in st["val_mae"])
    return (f"; kept {names[min(st['chosen'], 2) - 1]} on the held-back logs (MAE first / joint "
            f"stage {vals} mrad; the one of fewer free parameters unless the other is 2 % "
            "lower)")


def _generate(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from lowcostdex.gap.generate import LogSettings, generate
    from lowcostdex.gap.logs import write_log
    from lowcostdex.outdir import check_out, staged_output

    out = Path(args.out)
    check_out(out, "gap generate")
    # "--effect latency,backlash" as --candidates takes names (was "unknown hidden effect
    # 'latency,backlash'")
    effects = [e for given in args.effect for e in names(given, "--effect") if e != "none"]
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
