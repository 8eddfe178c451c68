"""Module-constant mutation: does any test notice when a module-level number changes by +1?

mutmut 3 mutates code inside functions only, so a constant such as ``SET_TORQUE = 0x60``, a
per-joint clamp table or a config dataclass's default threshold is never changed by it. This
script changes each numeric literal of the module's top-level assignments and class-body defaults
(``ThermalConfig.warn_margin``) by +1, one at a time, in a throw-away copy of the repository
(``git archive`` of HEAD or ``--rev``; the working tree is never touched), runs the given test files there and
reports which changes no test noticed. Uncommitted changes are not measured.

    python bench/mutate_constants.py lowcostdex/hardware/allegro/protocol.py \
        tests/test_allegro_can.py

Prints one line per constant (killed / survived) and the score; ``--markdown`` prints the
survivors as a table row for bench/RESULTS.md. Run it with ``nice -n 10`` on a shared machine.
"""

from __future__ import annotations

import argparse
import ast
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Literal:
    """One numeric literal of a top-level assignment: where it is and what it names."""

    name: str  # the assigned name(s)
    line: int  # 1-based
    col: int
    end_col: int
    value: int | float

    def mutated(self) -> str:
        return repr(self.value + 1)


def _assignments(body, prefix: str = ""):
    """(name, value node) of the assignments in ``body``, and of the class bodies in it (a
    dataclass's defaults, named ``Class.field``)."""
    for node in body:
        if isinstance(node, ast.ClassDef):
            yield from _assignments(node.body, f"{prefix}{node.name}.")
        elif isinstance(node, ast.Assign):
            yield prefix + ", ".join(ast.unparse(t) for t in node.targets), node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            yield prefix + ast.unparse(node.target), node.value


def module_literals(source: str) -> list[Literal]:
    """Numeric literals (not bools) inside the module's top-level assignments and class-body
    defaults (mutmut mutates neither), in source order."""
    out = []
    for name, value in _assignments(ast.parse(source).body):
        for sub in ast.walk(value):
            if (isinstance(sub, ast.Constant) and isinstance(sub.value, (int, float))
                    and not isinstance(sub.value, bool) and sub.lineno == sub.end_lineno):
                out.append(Literal(name, sub.lineno, sub.col_offset, sub.end_col_offset,
                                   sub.value))
    return out


def chosen(literals: list[Literal], only=()) -> list[Literal]:
    """The literals whose name starts with one of ``only`` (all when it is empty)."""
    return [lit for lit in literals if not only or lit.name.startswith(tuple(only))]


def apply(source: str, lit: Literal) -> str:
    lines = source.splitlines(keepends=True)
    text = lines[lit.line - 1]
    # col offsets are in UTF-8 bytes
    raw = text.encode()
    raw = raw[:lit.col] + lit.mutated().encode() + raw[lit.end_col:]
    lines[lit.line - 1] = raw.decode()
    return "".join(lines)


def measure(root: Path, module: str, tests: list[str], *, rev: str = "HEAD",
            deselect: list[str] = (), verbose: bool = True, only: list[str] = ()
            ) -> tuple[list[Literal], list[Literal], float]:
    """Mutate each numeric constant of ``module`` by +1 in a ``git archive`` copy of ``rev`` and
    run ``tests`` (``-m "not slow" -x``) once per change; ``only``: just the constants whose name
    starts with one of these (``NPGConfig.``, ``UNIT_MARGIN``).

    Returns (all literals, the ones no test noticed, seconds)."""
    work = Path(tempfile.mkdtemp(prefix="mutate_constants_"))
    try:
        archive = subprocess.run(["git", "-C", str(root), "archive", rev], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(work)], input=archive, check=True)
        target = work / module
        original = target.read_text()
        literals = chosen(module_literals(original), only)
        cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
               "-m", "not slow", *tests]
        for test_id in deselect:
            cmd += ["--deselect", test_id]
        survivors = []
        t0 = time.monotonic()
        for k, lit in enumerate(literals, 1):
            target.write_text(apply(original, lit))
            r = subprocess.run(cmd, cwd=work, capture_output=True, text=True)
            killed = r.returncode != 0
            if not killed:
                survivors.append(lit)
            if verbose:
                print(f"[{k}/{len(literals)}] {module} line {lit.line} {lit.name}: {lit.value!r}"
                      f" -> {lit.mutated()}: {'killed' if killed else 'SURVIVED'}", flush=True)
        return literals, survivors, time.monotonic() - t0
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("module", help="module file to mutate, relative to the repository root")
    ap.add_argument("tests", nargs="+", help="test files to run")
    ap.add_argument("--rev", default="HEAD", help="commit to measure (default HEAD)")
    ap.add_argument("--deselect", action="append", default=[],
                    help="test id to leave out (e.g. a real-time test that fails under load)")
    ap.add_argument("--only", action="append", default=[], metavar="PREFIX",
                    help="mutate only the constants whose name starts with this (repeatable), "
                         "e.g. NPGConfig. of lowcostdex/algos/configs.py")
    ap.add_argument("--markdown", action="store_true", help="print the survivors as Markdown")
    args = ap.parse_args(argv)
    root = Path(subprocess.check_output(["git", "rev-parse", "--show-toplevel"], text=True)
                .strip())
    commit = subprocess.check_output(["git", "-C", str(root), "rev-parse", "--short", args.rev],
                                     text=True).strip()
    literals, survivors, seconds = measure(root, args.module, args.tests, rev=commit,
                                           deselect=args.deselect, only=args.only)
    n = len(literals)
    print(f"\n{args.module} @ {commit}: {n - len(survivors)}/{n} constant mutants killed "
          f"({100 * (n - len(survivors)) / max(n, 1):.1f} %), {seconds:.0f} s")
    if args.markdown and survivors:
        print("| line | constant | +1 |\n|---|---|---|")
        for lit in survivors:
            print(f"| {lit.line} | `{lit.name}` | {lit.value!r} -> {lit.mutated()} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
