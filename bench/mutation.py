"""Mutation score of one group of modules, one command: mutmut + module-constant mutation.

Mutation testing asks how much the tests would notice if the code were wrong: mutmut changes one
small thing at a time inside a function (``<`` -> ``<=``, a dropped argument, a number + 1, ...),
runs the tests that cover that function, and calls the mutant *killed* when a test fails (a
timeout counts as killed), *survived* when every test still passes, *no tests* when no test runs
the function at all (counted as not killed). mutmut 3 does not mutate module-level constants, so
``bench/mutate_constants.py`` changes each number of a module's top-level assignments by +1 and
runs the group's tests once per change.

    nice -n 15 python bench/mutation.py safety
    nice -n 15 python bench/mutation.py gap --sample 100 --seed 1 --no-constants
    nice -n 19 python bench/mutation.py gap-pure --no-constants

Everything runs on a ``git archive`` copy of a commit (``--rev``, default HEAD; uncommitted
changes are not measured, the working tree is never touched): the copy's ``pyproject.toml`` gets
the group's ``only_mutate`` and test files added to its ``[tool.mutmut]`` table, mutmut
generates the mutants (``mutmut run`` with a name matching nothing), the runner picks all of them
or a seeded sample (``random.Random(seed).sample(sorted(names), n)``) and runs them with
``--max-children`` (default 1), reads mutmut's per-module ``.meta`` results and prints (and
writes, ``--out``) a Markdown block for bench/RESULTS.md: the score per module, each surviving
mutant with its one-line diff (from ``mutmut show``), and the constants no test noticed.
``--report WORKDIR`` prints that block again for an earlier copy, also of a run stopped halfway
(mutmut saves each mutant's result as it goes; the unchecked ones are left out of the score).

Time (2-core VM shared by ~7 people, load ~10, 2026-11-26): generating the safety group's 459
mutants (and mutmut's one run of its tests) 166 s, then ~0.1-0.2 mutants/s; the gap group's
tests run whole analyses, 0.02-0.04 mutants/s: its 2227 mutants would take 15-30 h, hence
``--sample``. The ``gap-pure`` group judges the same decision code (3331 mutants with
significance.py) by tests without a MuJoCo replay (stand-in engine, hand-computed inputs):
1.2 mutants/s measured at load ~10, so the whole population is ~40 min of an idle core
(bench/RESULTS.md; at nice 19 under a full-suite load it gets almost no CPU). The constants add one run of the group's tests per number. mutmut must be
installed (the dev extra pins it).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import random
import re
import shutil
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import mutate_constants  # noqa: E402  (bench/ is not a package)


@dataclass(frozen=True)
class Group:
    """Modules mutated together and the test files that judge them."""

    modules: tuple[str, ...]
    tests: tuple[str, ...]
    deselect: tuple[str, ...] = ()
    note: str = ""


GROUPS = {
    "safety": Group(
        modules=("lowcostdex/hardware/robot/guards.py", "lowcostdex/hardware/robot/safety.py",
                 "lowcostdex/motion.py"),
        tests=("tests/test_robot_guards.py", "tests/test_robot_faults.py",
               "tests/test_robot_dynamixel.py", "tests/test_dxl_thermal.py",
               "tests/test_dxl_soak.py", "tests/test_dxl_driver.py", "tests/test_dxl_protocol.py",
               "tests/test_motion.py", "tests/test_safety_constants.py",
               "tests/test_backend_emulated.py::"
               "test_sim_and_emulated_robot_apply_the_same_narrowed_motion_bound"),
        # the fault soaks (22-33 s each at idle, all parametrizations) would make every
        # surviving guard mutant cost minutes; they stay in the default test run
        deselect=("tests/test_robot_faults.py::"
                  "test_soak_2000_cycles_no_goal_beyond_the_bound_or_limits_reaches_a_motor",
                  "tests/test_dxl_soak.py::test_soak_10k_cycles_with_2_percent_faults_each"),
        note="limits, motion bound and its in-flight narrowing, thermal and current guards; the "
             "two fault soaks are deselected (a mutant only they would kill counts as survived)"),
    "codec": Group(
        modules=("lowcostdex/hardware/allegro/protocol.py",
                 "lowcostdex/hardware/dynamixel/protocol.py"),
        tests=("tests/test_allegro_can.py", "tests/test_hardware_acceptance_allegro.py",
               "tests/test_dxl_protocol.py", "tests/test_dxl_codec_edges.py",
               "tests/test_codec_constants.py"),
        # real time: fails mutmut's clean run on a loaded machine (bench/RESULTS.md)
        deselect=("tests/test_allegro_can.py::"
                  "test_threaded_driver_against_a_real_time_emulated_hand",),
        note="Allegro CAN frames and the Dynamixel Protocol 2.0 packets the emulator speaks"),
    "algos": Group(
        modules=("lowcostdex/algos/npg.py", "lowcostdex/algos/dapg.py"),
        tests=("tests/test_npg.py", "tests/test_dapg.py", "tests/test_algos_constants.py"),
        note="NPG and DAPG updates"),
    "gap": Group(
        modules=("lowcostdex/gap/analyze.py", "lowcostdex/gap/selection.py",
                 "lowcostdex/gap/results.py", "lowcostdex/gap/gain.py"),
        tests=("tests/test_gap_gain.py", "tests/test_gap_units.py",
               "tests/test_gap_decisions.py"),
        note="gap analysis verdicts, candidate selection, results, held-out gain; the slow "
             "analysis tests (test_gap_hidden/independent/cli) are not in the selection"),
    "gap-pure": Group(
        modules=("lowcostdex/gap/analyze.py", "lowcostdex/gap/selection.py",
                 "lowcostdex/gap/significance.py", "lowcostdex/gap/gain.py",
                 "lowcostdex/gap/results.py"),
        tests=("tests/test_gap_decisions_pure.py", "tests/test_gap_decisions_backward.py",
               "tests/test_gap_decisions_loop.py", "tests/test_gap_decisions_config.py",
               "tests/test_gap_gain.py", "tests/test_gap_significance.py",
               "tests/test_gap_decisions_stages.py", "tests/test_gap_decisions_wiring.py",
               "tests/test_gap_decisions_intervals.py", "tests/test_gap_decisions_rank.py",
               "tests/test_gap_decisions_significance.py", "tests/test_gap_decisions_report.py",
               "tests/test_gap_decisions_defaults.py", "tests/test_gap_profile.py",
               "tests/test_gap_profile_widens.py"),
        note="the gap decision code judged by its fast tests only: hand-computed inputs, and "
             "analyze's loop and backward pass on a stand-in engine (no MuJoCo replay), so the "
             "whole population is measurable here; code only a real replay reaches (the "
             "ranking's probes, intervals, step refinement, traces) shows as survived or "
             "\"no tests\" (the `gap` group's analyses judge it)"),
}

# mutmut 3.8.1's exit code -> status (mutmut/stats.py status_by_exit_code); anything else is
# "suspicious" there too.
STATUS_BY_EXIT_CODE = {
    1: "killed", 3: "killed", 0: "survived", 5: "no tests", 33: "no tests", 2: "interrupted",
    None: "not checked", 34: "skipped", 35: "suspicious", 36: "timeout",
    37: "caught by type check", -24: "timeout", 24: "timeout", 152: "timeout", 255: "timeout",
    -11: "segfault", -9: "segfault",
}
KILLED = ("killed", "timeout")          # counted as killed (timeouts too, as mutmut's score)
NOT_SCORED = ("not checked", "skipped", "interrupted")  # left out of the denominator


def status(exit_code: int | None) -> str:
    return STATUS_BY_EXIT_CODE.get(exit_code, "suspicious")


def module_name(path: str) -> str:
    """``lowcostdex/gap/gain.py`` -> ``lowcostdex.gap.gain`` (the prefix of its mutant names)."""
    return path.removesuffix(".py").replace("/", ".")


def meta_results(meta: dict) -> dict[str, str]:
    """mutant name -> status from one mutmut ``.meta`` file's JSON."""
    return {name: status(code) for name, code in meta["exit_code_by_key"].items()}


def sample_names(names, n: int | None, seed: int) -> list[str]:
    """A seeded random sample of mutant names, independent of the order they are given in.

    ``random.Random(seed).sample(sorted(names), n)``; all names (sorted) when ``n`` is None or at
    least their number."""
    names = sorted(set(names))
    if n is None or n >= len(names):
        return names
    return random.Random(seed).sample(names, n)


@dataclass
class ModuleScore:
    module: str
    counts: Counter = field(default_factory=Counter)

    @property
    def killed(self) -> int:
        return sum(self.counts[s] for s in KILLED)

    @property
    def scored(self) -> int:
        return sum(v for k, v in self.counts.items() if k not in NOT_SCORED)

    @property
    def not_killed(self) -> int:
        return self.scored - self.killed

    @property
    def score(self) -> float | None:
        return 100.0 * self.killed / self.scored if self.scored else None


def score_by_module(results: dict[str, str], modules) -> list[ModuleScore]:
    """Per-module counts of the given results (name -> status); names are matched to modules by
    their dotted prefix."""
    scores = [ModuleScore(m) for m in modules]
    for name, st in results.items():
        for s in scores:
            if name.startswith(module_name(s.module) + "."):
                s.counts[st] += 1
                break
        else:
            raise ValueError(f"mutant {name} belongs to none of {list(modules)}")
    return scores


def one_line_diff(show_output: str, width: int = 140) -> str:
    """The change of a mutant as ``old`` -> ``new`` from ``mutmut show``'s unified diff."""
    old, new = [], []
    for line in show_output.splitlines():
        if line.startswith(("---", "+++", "#")):
            continue
        if line.startswith("-"):
            old.append(line[1:].strip())
        elif line.startswith("+"):
            new.append(line[1:].strip())
    a, b = " ".join(old), " ".join(new)
    if len(a) > width:
        a = a[:width - 3] + "..."
    if len(b) > width:
        b = b[:width - 3] + "..."
    a = f"`{a}`" if a else "(nothing)"
    b = f"`{b}`" if b else "(removed)"
    return f"{a} -> {b}"


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f} %"


def markdown(group: str, commit: str, scores: list[ModuleScore], survivors: dict[str, str],
             constants: list[tuple[str, int, list[str]]] | None, *, header: str,
             sampled: str) -> str:
    """The block for bench/RESULTS.md.

    survivors: name -> one-line diff of every mutant not killed (survived, no tests, ...);
    constants: (module, number of constants, survivor descriptions) per module, or None."""
    out = [f"#### `python bench/mutation.py {group}` at {commit}", "", header, "",
           f"mutmut 3.8.1, {sampled}; timeouts count as killed, \"no tests\" as not killed.", "",
           "| module | mutants | killed (timeout) | survived | no tests | other | score |",
           "|---|---|---|---|---|---|---|"]
    total = ModuleScore("total")
    for s in scores:
        total.counts.update(s.counts)
    for s in [*scores, total] if len(scores) > 1 else scores:
        c = s.counts
        other = s.scored - s.killed - c["survived"] - c["no tests"]
        name = f"`{s.module}`" if s is not total else "**total**"
        out.append(f"| {name} | {s.scored} | {s.killed} ({c['timeout']}) | {c['survived']} | "
                   f"{c['no tests']} | {other} | {_pct(s.score)} |")
    if survivors:
        out += ["", "Not killed:", ""]
        out += [f"- `{name.split('.')[-1]}` ({name.rsplit('.', 2)[-2]}.py): {diff}"
                for name, diff in sorted(survivors.items())]
    if constants is not None:
        out += ["", "Module constants (+1 each, `bench/mutate_constants.py`):", "",
                "| module | constants | killed | score | not noticed |", "|---|---|---|---|---|"]
        for module, n, surv in constants:
            killed = n - len(surv)
            out.append(f"| `{module}` | {n} | {killed} | {_pct(100 * killed / n if n else None)}"
                       f" | {', '.join(surv) or '-'} |")
    return "\n".join(out) + "\n"


def group_pyproject(text: str, group: Group) -> str:
    """The copy's pyproject.toml: the repository's ``[tool.mutmut]`` table plus the group's
    ``only_mutate`` and test selection (deselected tests as ``--deselect`` arguments there: a
    test left out of the stats run is never run against a mutant)."""
    if "[tool.mutmut]" not in text:
        raise ValueError("pyproject.toml has no [tool.mutmut] table")
    for key in ("only_mutate", "pytest_add_cli_args_test_selection"):
        if re.search(rf"^{key}\s*=", text, re.M):
            raise ValueError(f"pyproject.toml's [tool.mutmut] sets {key}: the group sets it")
    selection = list(group.tests)
    for test_id in group.deselect:
        selection += ["--deselect", test_id]
    lines = (f"only_mutate = {json.dumps(list(group.modules))}\n"
             f"pytest_add_cli_args_test_selection = {json.dumps(selection)}\n")
    return text.replace("[tool.mutmut]\n", "[tool.mutmut]\n" + lines, 1)


def _run(cmd, cwd, log, check=True) -> subprocess.CompletedProcess:
    print("+", " ".join(cmd[:6]), "..." if len(cmd) > 6 else "", flush=True)
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    spinner = re.compile("^[\u2800-\u28ff] ")  # mutmut's progress spinner, one line a frame
    text = "\n".join(line for line in (r.stdout + "\n" + r.stderr).splitlines()
                     if not spinner.match(line))
    with open(log, "a") as f:
        f.write(f"$ {' '.join(cmd)}\n{text}\nEXIT {r.returncode}\n")
    if check and r.returncode != 0:
        raise SystemExit(f"{cmd[:3]} failed (exit {r.returncode}); see {log}")
    return r


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("group", choices=sorted(GROUPS))
    ap.add_argument("--rev", default="HEAD", help="commit to measure (default HEAD)")
    ap.add_argument("--sample", type=int, help="run a seeded random sample of N mutants")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sample (default 0)")
    ap.add_argument("--names", type=Path,
                    help="run the mutant names listed in this file (one a line) instead")
    ap.add_argument("--max-children", type=int, default=1)
    ap.add_argument("--workdir", type=Path,
                    help="where the git-archive copy goes (default /tmp/mutation-<group>-<rev>); "
                         "kept afterwards for mutmut show/browse")
    ap.add_argument("--no-constants", action="store_true",
                    help="skip bench/mutate_constants.py on the group's modules")
    ap.add_argument("--mutmut", default=str(Path(sys.executable).with_name("mutmut")),
                    help="the mutmut executable (default: next to this Python)")
    ap.add_argument("--out", type=Path, help="also write the Markdown block to this file")
    ap.add_argument("--report", type=Path, metavar="WORKDIR",
                    help="only print the block for an earlier run's copy (finished or stopped; "
                         "unchecked mutants are left out of the score)")
    args = ap.parse_args(argv)
    group = GROUPS[args.group]
    if args.report:
        return report(args.group, args.report, args.mutmut, "see the run's log", None,
                      args.max_children, args.out)
    if not Path(args.mutmut).exists() and shutil.which(args.mutmut) is None:
        raise SystemExit(f"mutmut not found at {args.mutmut}: pip install -e '.[dev]'")
    root = Path(subprocess.check_output(["git", "rev-parse", "--show-toplevel"], text=True)
                .strip())
    commit = subprocess.check_output(["git", "-C", str(root), "rev-parse", "--short", args.rev],
                                     text=True).strip()
    work = args.workdir or Path(f"/tmp/mutation-{args.group}-{commit}")
    if work.exists() and any(work.iterdir()):
        raise SystemExit(f"{work} is not empty: give another --workdir or remove it")
    work.mkdir(parents=True, exist_ok=True)
    log = work / "mutation.log"
    t0 = time.monotonic()
    archive = subprocess.run(["git", "-C", str(root), "archive", commit], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(work)], input=archive, check=True)
    pp = work / "pyproject.toml"
    pp.write_text(group_pyproject(pp.read_text(), group))

    # generate the mutants (and mutmut's test stats) by asking for a name that matches none
    r = _run([args.mutmut, "run", "--max-children", str(args.max_children),
              "no.such.mutant.for.listing*"], work, log, check=False)
    if "nothing matches" not in r.stdout + r.stderr:
        raise SystemExit(f"mutant generation failed (exit {r.returncode}); see {log}")
    metas = {m: work / "mutants" / (m + ".meta") for m in group.modules}
    names = [n for path in metas.values() for n in json.loads(path.read_text())["exit_code_by_key"]]
    t_gen = time.monotonic() - t0
    if args.names:
        chosen = [n.strip() for n in args.names.read_text().splitlines() if n.strip()]
        unknown = sorted(set(chosen) - set(names))
        if unknown:
            raise SystemExit(f"{len(unknown)} names are not mutants of this code, e.g. {unknown[0]}")
        sampled = f"the {len(chosen)} mutants named in {args.names.name} of {len(names)}"
    else:
        chosen = sample_names(names, args.sample, args.seed)
        sampled = (f"all {len(names)} mutants" if len(chosen) == len(names) else
                   f"`random.Random({args.seed}).sample(sorted(names), {args.sample})` "
                   f"of {len(names)} mutants")
    (work / "mutants_chosen.txt").write_text("\n".join(chosen) + "\n")
    (work / "run.json").write_text(json.dumps({"commit": commit, "sampled": sampled,
                                               "group": dataclasses.asdict(group)}))
    print(f"{len(names)} mutants in {t_gen:.0f} s; running {len(chosen)}", flush=True)
    t1 = time.monotonic()
    run_cmd = [args.mutmut, "run", "--max-children", str(args.max_children)]
    _run(run_cmd + ([] if len(chosen) == len(names) else chosen), work, log)
    t_run = time.monotonic() - t1
    constants = None
    t2 = time.monotonic()
    if not args.no_constants:
        constants = []
        for module in group.modules:
            lits, surv, _ = mutate_constants.measure(
                root, module, list(group.tests), rev=commit, deselect=list(group.deselect))
            constants.append((module, len(lits), [
                f"`{lit.name}` {lit.value!r} (line {lit.line})" for lit in surv]))
    t_const = time.monotonic() - t2
    timing = (f"generation {t_gen:.0f} s, {len(chosen)} mutants {t_run:.0f} s "
              f"({len(chosen) / max(t_run, 1e-9):.3f} mutants/s)"
              + ("" if constants is None else f", constants {t_const:.0f} s"))
    return report(args.group, work, args.mutmut, timing, constants, args.max_children, args.out)


def report(group_name: str, work: Path, mutmut: str, timing: str, constants,
           max_children: int, out: Path | None) -> int:
    """Read the results of a run in ``work`` (finished or stopped) and print the Markdown."""
    run = json.loads((work / "run.json").read_text())
    # the group as that run defined it (tests may have been added since)
    group = Group(**{k: tuple(v) if isinstance(v, list) else v
                     for k, v in run["group"].items()}) if "group" in run else GROUPS[group_name]
    chosen = (work / "mutants_chosen.txt").read_text().split()
    results = {}
    for m in group.modules:
        results.update(meta_results(json.loads((work / "mutants" / (m + ".meta")).read_text())))
    results = {n: results[n] for n in chosen}
    scores = score_by_module(results, group.modules)
    log = work / "mutation.log"
    survivors = {}
    for name, st in results.items():
        if st in KILLED or st in NOT_SCORED:
            continue
        shown = _run([mutmut, "show", name], work, log, check=False).stdout
        survivors[name] = one_line_diff(shown) + ("" if st == "survived" else f" ({st})")
    unchecked = sum(st in NOT_SCORED for st in results.values())
    sampled = run["sampled"] + ("" if not unchecked else
                                f" ({len(chosen) - unchecked} of the {len(chosen)} checked: "
                                "the run was stopped)")
    load = os.getloadavg()[0]
    header = (f"{time.strftime('%Y-%m-%d')}, 2-core VM (shared, load {load:.0f} at the end), "
              f"`--max-children {max_children}`; {group.note}. Tests (`-m \"not slow\"`): "
              + ", ".join(f"`{t.removeprefix('tests/')}`" for t in group.tests)
              + (f" (deselected: {', '.join(f'`{t}`' for t in group.deselect)})"
                 if group.deselect else "")
              + f". Time: {timing}.")
    block = markdown(group_name, run["commit"], scores, survivors, constants, header=header,
                     sampled=sampled)
    print("\n" + block)
    (work / "mutation.md").write_text(block)
    if out:
        out.write_text(block)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
