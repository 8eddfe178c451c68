"""One runner for the red-team benchmarks (``bench/gap_redteam.py``, ``bench/gap_redteam3.py``).

Each benchmark names an independently written truth simulator under ``tests/`` (a module with
``CASES``, ``CASE_BY_NAME``, ``write_case(case, folder)`` -> {"model", "logs", "truth"} (and "args": options the user passes
for the logs' spelling, e.g. ``--units deg``) and
``score(report, truth)``; optionally ``effect_size(case)``). The simulators stay independent of
each other and of the project; only this runner (the CLI call, scoring, table, queue) is shared.
Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log log0.csv log1.csv ... --out report/ --seed 0

and its report.json is scored: exact (the hidden causes named and nothing else), extra (named
plus others), extra_family (a confusable neighbour plus others), family (a confusable
neighbour), miss, false discovery (clean case, something named), crash (non-zero exit: the
command is printed); each documented parameter inside its 95 % interval or not; wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from types import ModuleType

TESTS = pathlib.Path(__file__).resolve().parents[1] / "tests"
ORDER = {"crash": 0, "false": 1, "miss": 2, "extra_family": 3, "extra": 4, "family": 5,
         "exact": 6, "clean": 7}


def truth_module(name: str) -> ModuleType:
    """Import the truth simulator ``tests/<name>.py`` (mujoco + numpy only)."""
    if str(TESTS) not in sys.path:
        sys.path.insert(0, str(TESTS))
    return __import__(name)


def child_cpu() -> float:
    """CPU seconds [s] (user + sys) the finished child processes used so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def analyze_command(files: dict, out: pathlib.Path, threads: int) -> list[str]:
    exe = shutil.which("lowcostdex") or "lowcostdex"
    return [exe, "gap", "analyze", "--model", files["model"], "--log", *files["logs"],
            "--out", str(out), "--seed", "0", "--threads", str(threads),
            *files.get("args", ())]  # the options a user passes for the logs' spelling


def run_case(sim: ModuleType, case, root: pathlib.Path, threads: int = 1) -> dict:
    """Generate ``case`` under ``root/<name>/data``, analyse it into ``root/<name>/report`` and
    score it with ``sim.score``. Returns the row of the table."""
    data, out = root / case.name / "data", root / case.name / "report"
    t0 = time.perf_counter()
    files = sim.write_case(case, data)
    gen_s = time.perf_counter() - t0
    cmd = analyze_command(files, out, threads)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    row = {"case": case.name, "rig": case.rig, "hidden": sorted(case.causes),
           "kinds": [e.kind for e in case.effects], "on": [list(e.joints) for e in case.effects],
           "values": [[e.value, *getattr(e, "extra", ())] for e in case.effects],
           "rate": case.rate, "seconds": sum(case.durations), "qvel": case.qvel,
           "note": case.note, "wall_s": round(wall, 1), "generate_s": round(gen_s, 1),
           "exit": proc.returncode, "command": " ".join(cmd)}
    if proc.returncode != 0:
        row.update(result="crash", named=[], params=[],
                   stderr=(proc.stderr or proc.stdout)[-2000:])
        return row
    report = json.loads((out / "report.json").read_text())
    row.update(sim.score(report, files["truth"]))
    row["verdict"] = report.get("verdict")
    g = report.get("gain") or {}
    row["heldout_rmse"] = [g.get("baseline_rmse"), g.get("extended_rmse")]
    row["causes"] = [{"effect": c["effect"], "joints": c["joints"],
                      "params": {k: v["value"] for k, v in c["params"].items()},
                      "widened": bool(c.get("widened"))} for c in report.get("causes", [])]
    return row


def rescore(sim: ModuleType, row: dict) -> dict:
    """``row`` re-scored from its kept report (``--keep``) with the current scorer. A case the
    simulator marks not ``observable`` (its effects change nothing the logs show) is scored
    clean."""
    if row["result"] == "crash":
        return row
    out = pathlib.Path(row["command"].split(" --out ")[1].split(" ")[0])
    truth = json.loads((out.parent / "data" / "truth.json").read_text())
    case = sim.CASE_BY_NAME.get(row["case"])
    if case is not None and not getattr(case, "observable", True):
        truth = {**truth, "causes": [], "expected_params": []}
        row = {**row, "hidden": []}
    return {**row, **sim.score(json.loads((out / "report.json").read_text()), truth)}


def table(rows: list[dict]) -> str:
    lines = ["| case | rig | hidden | named | result | params (truth / fit [95 %]) | wall s |",
             "|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (ORDER[r["result"]], r["case"])):
        ps = "; ".join(f"{p['effect'][:8]}.{p['param']}[{p['joint']}] {p['truth']:.4g} / "
                       f"{p['value']:.4g} [{p['interval'][0]:.4g}, {p['interval'][1]:.4g}]"
                       f"{'' if p['inside'] else ' OUT'}" for p in r["params"])
        named = ", ".join(r["named"]) or "-"
        if r.get("idle"):
            named += f" (also listed, every interval holding no effect: {', '.join(r['idle'])})"
        on = r.get("on") or [[] for _ in r["kinds"]]
        kinds = ", ".join(f"{k}[{','.join(j)}]" if j else k
                          for k, j in zip(r["kinds"], on, strict=True)) or "clean"
        lines.append(f"| {r['case']} | {r['rig']} | {kinds} | {named} | {r['result']} | "
                     f"{ps or '-'} | {r['wall_s']:.0f} |")
    return "\n".join(lines)


def summary(label: str, rows: list[dict]) -> str:
    eff = [r for r in rows if r["hidden"]]
    clean = [r for r in rows if not r["hidden"]]
    n = {k: sum(r["result"] == k for r in rows) for k in ORDER}
    ps = [p for r in rows for p in r["params"]]
    inside = sum(p["inside"] for p in ps)
    wall = sum(r["wall_s"] for r in rows)
    return (f"{label}: exact {n['exact']}/{len(eff)}, up to family {n['exact'] + n['family']}/"
            f"{len(eff)}, hidden named plus more {n['extra']}, a neighbour plus more "
            f"{n['extra_family']}, miss {n['miss']}, false discoveries {n['false']}/{len(clean)}, "
            f"crashes {n['crash']}; parameters inside their 95 % interval {inside}/{len(ps)}; "
            f"analysis wall time {wall:.0f} s ({wall / max(len(rows), 1):.0f} s/case)")


def run_named(sim: ModuleType, name: str, root: pathlib.Path, threads: int = 1) -> dict:
    """Case ``name`` of a truth set whose cases carry only effects (sim11, sim12): written under
    ``root/<name>/data``, analysed through the CLI, graded by ``sim.score``; the row keeps the
    analysis' CPU seconds (the child's user + sys), the named causes and the verdict."""
    files = sim.write_case(sim.CASE_BY_NAME[name], root / name / "data")
    out = root / name / "report"
    cmd = analyze_command(files, out, threads)
    cpu0 = child_cpu()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    row = {"case": name, "command": " ".join(cmd), "cpu_s": round(child_cpu() - cpu0, 1),
           "exit": proc.returncode}
    if proc.returncode:
        return row | {"result": "crash", "stderr": (proc.stderr or proc.stdout)[-2000:]}
    report = json.loads((out / "report.json").read_text())
    row |= sim.score(report, files["truth"])
    row["causes"] = [{"effect": c["effect"], "joints": c["joints"],
                      "params": {k: v["value"] for k, v in c["params"].items()}}
                     for c in report.get("causes", [])]
    row["verdict"] = report.get("verdict")
    return row


def case_line(r: dict, digits: int = 2, unit: str = "") -> str:
    """One markdown row of a per-case sweep (``sweep``): the causes named (effect[joints]), the
    grade, each graded parameter as truth / fit [95 % interval] (OUT when the truth is outside),
    the held-out RMSE x1e3 (before -> after when something was named; ``digits`` decimals, then
    ``unit``) and the analysis's CPU seconds."""
    if r["result"] == "crash":
        return f"| {r['case']} | crash | - | - | {r['cpu_s']:.0f} |"
    named = ", ".join(f"{c['effect']}[{','.join(c['joints'])}]" for c in r["causes"]) or "-"
    ps = "; ".join(f"{p['effect']}.{p['param']}[{p['joint']}] {p['truth']:.4g} / {p['value']:.4g}"
                   f" [{p['interval'][0]:.4g}, {p['interval'][1]:.4g}]"
                   f"{'' if p['inside'] else ' OUT'}" for p in r["params"]) or "-"
    before, after = r["heldout"]
    held = "-" if before is None else (f"{1e3 * before:.{digits}f} -> {1e3 * after:.{digits}f}"
                                       if r["named"] and after is not None
                                       else f"{1e3 * before:.{digits}f}")
    return f"| {r['case']} | {named} | {r['result']} | {ps} | {held}{unit} | {r['cpu_s']:.0f} |"


def sweep_named(sim: ModuleType, doc: str, keep: str, header: str, argv: list[str] | None = None,
                digits: int = 2, unit: str = "") -> int:
    """``sweep`` with each case run by ``run_named`` and printed by ``case_line``."""
    return sweep(sim, doc, keep, header,
                 lambda name, root, threads: run_named(sim, name, root, threads),
                 lambda r: case_line(r, digits, unit), argv)


def sweep(sim: ModuleType, doc: str, keep: str, header: str, run, line,
          argv: list[str] | None = None) -> int:
    """The plain command line of a per-case sweep (gap_redteam10/11): --cases, --keep, --json,
    --threads; ``run(name, root, threads)`` makes a row, ``line(row)`` prints it under
    ``header`` (a markdown table head), rows written to --json as they come."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", help="case names (default: all)")
    ap.add_argument("--keep", default=keep, help="folder for data and reports")
    ap.add_argument("--json", help="write the rows to this file as they come")
    ap.add_argument("--threads", type=int, default=1, help="gap analyze --threads")
    args = ap.parse_args(argv)
    names = args.cases or [c.name for c in sim.CASES]
    unknown = [n for n in names if n not in sim.CASE_BY_NAME]
    if unknown:
        ap.error(f"unknown case(s) {unknown}; valid: {sorted(sim.CASE_BY_NAME)}")
    rows: list[dict] = []
    print(header, flush=True)
    for name in names:
        rows.append(run(name, pathlib.Path(args.keep), args.threads))
        print(line(rows[-1]), flush=True)
        if args.json:
            pathlib.Path(args.json).write_text(json.dumps({"rows": rows}, indent=1))
    return 0


def main(sim: ModuleType, label: str, quick: tuple[str, ...], doc: str,
         argv: list[str] | None = None) -> int:
    """The command line of a red-team benchmark on truth simulator ``sim``."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(quick)}")
    ap.add_argument("--cases", nargs="+", help="case names (default: all)")
    ap.add_argument("--json", help="write the rows and summary to this file")
    ap.add_argument("--keep", help="folder for data and reports (default: a temporary one)")
    ap.add_argument("--threads", type=int, default=2, help="gap analyze --threads")
    ap.add_argument("--skip", nargs="+", default=[], help="case names to leave out")
    ap.add_argument("--rescore", nargs="+", help="previous --json outputs: re-score their "
                    "kept reports and print one table (no analysis runs)")
    if hasattr(sim, "effect_size"):
        ap.add_argument("--sizes", action="store_true", help="only print each case's effect "
                        "size: RMS / max of (logged reading - the user's model replayed in "
                        "plain mujoco) per joint, mrad (no analysis; a few s per case)")
    args = ap.parse_args(argv)
    if getattr(args, "sizes", False):
        for case in sim.CASES:
            if args.cases and case.name not in args.cases:
                continue
            s = sim.effect_size(case)
            print(f"{case.name:45s} rms " + " ".join(f"{1e3 * x:7.2f}" for x in s["rms"])
                  + "  max " + " ".join(f"{1e3 * x:7.1f}" for x in s["max"]) + " mrad",
                  flush=True)
        return 0
    if args.rescore:
        rows = [rescore(sim, r) for f in args.rescore for r in json.loads(
            pathlib.Path(f).read_text())["rows"]]
        print(table(rows))
        print(summary(label, rows))
        return 0
    names = args.cases or (quick if args.quick else [c.name for c in sim.CASES])
    names = [n for n in names if n not in args.skip]
    unknown = [n for n in names if n not in sim.CASE_BY_NAME]
    if unknown:
        ap.error(f"unknown case(s) {unknown}; valid: {sorted(sim.CASE_BY_NAME)}")
    root = pathlib.Path(args.keep or tempfile.mkdtemp(prefix=f"{label}_"))
    root.mkdir(parents=True, exist_ok=True)
    print(f"{len(names)} cases in {root}; load {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    for i, name in enumerate(names, 1):
        r = run_case(sim, sim.CASE_BY_NAME[name], root, args.threads)
        rows.append(r)
        extra = f" ({r['stderr'].strip().splitlines()[-1]})" if r["result"] == "crash" else ""
        print(f"[{i}/{len(names)}] {name}: {r['result']}; hidden {r['hidden'] or '-'}, named "
              f"{r['named'] or '-'}; {r['wall_s']:.0f} s{extra}", flush=True)
        if args.json:  # written as it goes: a long run stopped halfway keeps its rows
            pathlib.Path(args.json).write_text(json.dumps({"rows": rows}, indent=1))
    print(table(rows))
    line = summary(label, rows)
    print(line)
    print(f"load {os.getloadavg()[0]:.1f}")
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps({"rows": rows, "summary": line},
                                                      indent=1))
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0
