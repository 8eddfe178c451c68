"""Red-team benchmark of ``lowcostdex gap analyze`` on an ELEVENTH independently written truth
simulator (issue 11; gap-sim13, session 26): ``tests/gap_truth_sim11.py`` (mujoco + numpy only),
a user's pan-tilt camera head on two servos in velocity mode under the user's own 100 Hz python
position loop, logged in degrees and integer ms with failed reads' rows absent and a logger
pause; hidden effects at real-world sizes (latency, a play, dry friction, a speed limit, a loop
gain, a reading offset, a heavier camera, a rotor inertia), single and paired, and two clean
cases. Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log logs/ --out report/ --seed 0 --threads 1 \\
        --units deg --time-unit ms

and is graded by ``gap_truth_sim11.score`` (``redteam_grade.grade`` with the set's FAMILIES):
exact, extra, family, miss, clean, false; each parameter's truth inside its 95 % interval or
not. Prints one row per case with the CPU seconds of the analysis (the child's user + sys).

    OMP_NUM_THREADS=1 nice -n 5 python bench/gap_redteam11.py --keep /tmp/rt11 --json rt11.json
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim11")


def run(name: str, root: pathlib.Path, threads: int = 1) -> dict:
    """Write case ``name`` under ``root/<name>/data``, analyse it and grade its report."""
    return harness.run_named(sim, name, root, threads)


def line(r: dict) -> str:
    if r["result"] == "crash":
        return f"| {r['case']} | crash | - | - | {r['cpu_s']:.0f} |"
    named = ", ".join(f"{c['effect']}[{','.join(c['joints'])}]" for c in r["causes"]) or "-"
    ps = "; ".join(f"{p['effect']}.{p['param']}[{p['joint']}] {p['truth']:.4g} / {p['value']:.4g}"
                   f" [{p['interval'][0]:.4g}, {p['interval'][1]:.4g}]"
                   f"{'' if p['inside'] else ' OUT'}" for p in r["params"]) or "-"
    before, after = r["heldout"]
    held = "-" if before is None else (f"{1e3 * before:.2f} -> {1e3 * after:.2f}"
                                       if r["named"] and after is not None
                                       else f"{1e3 * before:.2f}")
    return f"| {r['case']} | {named} | {r['result']} | {ps} | {held} mrad | {r['cpu_s']:.0f} |"


def main(argv: list[str] | None = None) -> int:
    return harness.sweep(sim, __doc__, "/tmp/rt11",
                         ("| case | named | result | params (truth / fit [95 %]) | held-out RMSE | CPU s |\n"
                         "|---|---|---|---|---|---|"),
                         run, line, argv)


if __name__ == "__main__":
    sys.exit(main())
