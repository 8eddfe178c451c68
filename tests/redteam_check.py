"""One truth-set case run as a user would (``gap analyze`` on the case's files) and scored:
exactly the hidden effect(s) named, or nothing on a clean case, with every true value inside
its 95 % interval. Shared by the truth sets' tests (test_gap_redteam4.py, test_gap_redteam5.py);
the truth simulators themselves stay free of project code."""

from __future__ import annotations

import json
import pathlib
from types import ModuleType

from lowcostdex.cli import main


def assert_named_exactly(sim: ModuleType, name: str, root: pathlib.Path) -> None:
    files = sim.write_case(sim.CASE_BY_NAME[name], root / "data")
    out = root / "report"
    code = main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"],
                 "--out", str(out), "--seed", "0", "--threads", "1", *files.get("args", ())])
    assert code == 0, f"gap analyze exited {code} on {name}"
    s = sim.score(json.loads((out / "report.json").read_text()), files["truth"])
    assert s["result"] in ("exact", "clean"), (
        f"hidden {s['hidden'] or 'nothing'}, named {s['named'] or 'nothing'}")
    outside = [p for p in s["params"] if not p["inside"]]
    assert not outside, f"true values outside their 95 % intervals: {outside}"
