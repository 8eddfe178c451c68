"""Red-team benchmark of ``lowcostdex gap analyze`` on a THIRTEENTH independently written truth
simulator (issue 11; gap-sim17, session 28): ``tests/gap_truth_sim13.py`` (mujoco + numpy only),
a user's underactuated TENDON-driven finger: one servo, written as a ``position`` actuator on a
fixed tendon (gear 1 / horn radius: the goal is the servo's angle), pulls a cable over the mcp
and pip joints against return springs; the dip is coupled to the pip by a joint equality.
Hidden effects: a latency, a play at the servo's horn, a kp off, an mcp encoder off its zero,
dry friction on the pip pin, a heavier distal phalanx, one pair, an elastic cable (outside the
catalogue) and two clean cases. Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log logs/ --out report/ --seed 0 --threads 1

and is graded by ``gap_truth_sim13.score`` (``redteam_grade.grade`` with the set's FAMILIES):
exact, extra, family, miss, clean, false; each parameter's truth inside its 95 % interval or
not. Prints one row per case with the CPU seconds of the analysis (the child's user + sys).

    OMP_NUM_THREADS=1 nice -n 5 python bench/gap_redteam13.py --keep /tmp/rt13 --json rt13.json
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim13")


def run(name: str, root: pathlib.Path, threads: int = 1) -> dict:
    """Write case ``name`` under ``root/<name>/data``, analyse it and grade its report."""
    return harness.run_named(sim, name, root, threads)


def line(r: dict) -> str:
    """One table row (radians; the servo's effects at the horn)."""
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
    return f"| {r['case']} | {named} | {r['result']} | {ps} | {held} | {r['cpu_s']:.0f} |"


def main(argv: list[str] | None = None) -> int:
    return harness.sweep(sim, __doc__, "/tmp/rt13",
                         ("| case | named | result | params (truth / fit [95 %]) | "
                          "held-out RMSE (mrad) | CPU s |\n|---|---|---|---|---|---|"),
                         run, line, argv)


if __name__ == "__main__":
    sys.exit(main())
