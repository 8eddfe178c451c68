"""One truth-set case run as a user would (``gap analyze`` on the case's files) and scored:
exactly the hidden effect(s) named, or nothing on a clean case, with every true value inside
its 95 % interval. Shared by the truth sets' tests (test_gap_redteam4.py to test_gap_redteam8.py);
the truth simulators themselves stay free of project code. ``grade`` (``redteam_grade``'s, the
one grader) scores a report against a truth set's ``FAMILIES`` for the sets that carry no scorer
of their own (sim7, sim8, sim9)."""

from __future__ import annotations

import ast
import json
import pathlib
from types import ModuleType

import pytest
from redteam_grade import grade  # noqa: F401  (the one grader; sim7-9's tests call it here)

from lowcostdex.cli import main


def case_params(sim: ModuleType, fast: set[str] | frozenset[str], misses: dict[str, str]) -> list:
    """One pytest param per case of ``sim.CASES``: ``slow`` unless in ``fast``, a strict xfail
    (its reason) for each case in ``misses``. A slow case may take longer than the suite's
    600 s timeout (sim9 limit_play_offset: 691 s CPU, ~26 min wall on the shared VM), so it gets
    an hour."""
    out = []
    for case in sim.CASES:
        marks = [] if case.name in fast else [pytest.mark.slow, pytest.mark.timeout(3600)]
        if case.name in misses:
            marks.append(pytest.mark.xfail(strict=True, reason=misses[case.name]))
        out.append(pytest.param(case.name, marks=marks, id=case.name))
    return out


def imported_top_modules(path: pathlib.Path) -> set[str]:
    """The top-level module names a Python file imports (a truth simulator must import no
    project code)."""
    tree = ast.parse(path.read_text())
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
             for a in n.names}
    return names | {n.module.split(".")[0] for n in ast.walk(tree)
                    if isinstance(n, ast.ImportFrom) and n.module}


def assert_named_exactly(sim: ModuleType, name: str, root: pathlib.Path) -> None:
    files = sim.write_case(sim.CASE_BY_NAME[name], root / "data")
    out = root / "report"
    code = main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"],
                 "--out", str(out), "--seed", "0", "--threads", "1", *files.get("args", ())])
    assert code == 0, f"gap analyze exited {code} on {name}"
    rep = json.loads((out / "report.json").read_text())
    s = sim.score(rep, files["truth"]) if hasattr(sim, "score") else grade(
        rep, files["truth"], sim.FAMILIES)
    assert s["result"] in ("exact", "clean"), (
        f"hidden {s['hidden'] or 'nothing'}, named {s['named'] or 'nothing'}")
    outside = [p for p in s["params"] if not p["inside"]]
    assert not outside, f"true values outside their 95 % intervals: {outside}"
