"""Red-team benchmark of ``lowcostdex gap analyze`` on a TENTH independently written truth
simulator (issue 11; gap-sim11, session 24): ``tests/gap_truth_sim10.py`` (mujoco + numpy only),
a user's 3-joint D'Claw-like finger with hidden effects outside the catalogue (a series spring,
an encoder's harmonic error, friction rising over the session, a supply sagging under load, a
tight spot), one catalogue effect at a real-world size (40 ms latency) and a clean case. Every
case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log logs/ --out report/ --seed 0 --threads 1

and is graded by ``gap_truth_sim10.score``: an outside case passes when no confident wrong cause
is named (nothing, the case's nearest catalogue effects, or names the report itself flags as not
explaining the logs) and the residual is reported; the catalogue case when exactly its effect is
named, the clean case when nothing is. Prints the residual (held-out RMSE left in noise floors)
and the CPU seconds of each analysis (the child's user + sys).

    nice -n 5 python bench/gap_redteam10.py --keep /tmp/rt10 --json rt10.json [--cases ...]
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim10")


def run(name: str, root: pathlib.Path, threads: int = 1) -> dict:
    """Write case ``name`` under ``root/<name>/data``, analyse it and grade its report."""
    case = sim.CASE_BY_NAME[name]
    files = sim.write_case(case, root / name / "data")
    out = root / name / "report"
    cmd = harness.analyze_command(files, out, threads)
    cpu0 = harness.child_cpu()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    row = {"case": name, "note": case.note, "command": " ".join(cmd),
           "cpu_s": round(harness.child_cpu() - cpu0, 1), "exit": proc.returncode}
    if proc.returncode:
        return row | {"result": "crash", "grade": "crash",
                      "stderr": (proc.stderr or proc.stdout)[-2000:]}
    report = json.loads((out / "report.json").read_text())
    row |= sim.score(report, files["truth"])
    row["causes"] = [{"effect": c["effect"], "joints": c["joints"],
                      "params": {k: v["value"] for k, v in c["params"].items()}}
                     for c in report.get("causes", [])]
    return row


def line(r: dict) -> str:
    if r["result"] == "crash":
        return f"| {r['case']} | crash | - | - | {r['cpu_s']:.0f} |"
    before, after = r["heldout"]
    named = ", ".join(f"{c['effect']}[{','.join(c['joints'])}]" for c in r["causes"]) or "-"
    floors = f"{r['residual_floors']:.1f}" if r["residual_floors"] is not None else "?"
    held = f"{1e3 * before:.2f} -> {1e3 * after:.2f}" if r["named"] else f"{1e3 * before:.2f}"
    return (f"| {r['case']} | {named} | {r['grade']}{' (flagged)' if r['flagged'] else ''} | "
            f"{held} mrad, {floors} floors left | {r['cpu_s']:.0f} |")


def main(argv: list[str] | None = None) -> int:
    return harness.sweep(sim, __doc__, "/tmp/rt10",
                         "| case | named | grade | held-out RMSE | CPU s |\n|---|---|---|---|---|",
                         run, line, argv)


if __name__ == "__main__":
    sys.exit(main())
