"""Red-team benchmark of ``lowcostdex gap analyze`` on a TWELFTH independently written truth
simulator (issue 11; gap-sim15, session 27): ``tests/gap_truth_sim12.py`` (mujoco + numpy only),
a user's low-cost gripper whose jaw runs on a SLIDE joint in metres (a linear servo or a rack:
``position`` kp 2500 N/m, 40 N) with a finger on a hinge riding on it, logged while the gripper
squeezes a clamped block and presses its fingertip on the table (both in the user's MJCF); hidden
effects in each joint's own units (a mm offset, a rack's mm play, newtons of rail friction, a kp
off, a latency; the finger's offset, friction, play), single and paired, and two clean cases (no
contact, contact). Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log logs/ --out report/ --seed 0 --threads 1

and is graded by ``gap_truth_sim12.score`` (``redteam_grade.grade`` with the set's FAMILIES):
exact, extra, family, miss, clean, false; each parameter's truth inside its 95 % interval or
not. Prints one row per case with the CPU seconds of the analysis (the child's user + sys).

    OMP_NUM_THREADS=1 nice -n 5 python bench/gap_redteam12.py --keep /tmp/rt12 --json rt12.json
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim12")


def run(name: str, root: pathlib.Path, threads: int = 1) -> dict:
    """Write case ``name`` under ``root/<name>/data``, analyse it and grade its report."""
    return harness.run_named(sim, name, root, threads)


def line(r: dict) -> str:
    """One table row; values in the joint's own units (m, N on the slide; rad, N m on the
    finger); the held-out RMSE mixes both joints' units as the report does."""
    if r["result"] == "crash":
        return f"| {r['case']} | crash | - | - | {r['cpu_s']:.0f} |"
    named = ", ".join(f"{c['effect']}[{','.join(c['joints'])}]" for c in r["causes"]) or "-"
    ps = "; ".join(f"{p['effect']}.{p['param']}[{p['joint']}] {p['truth']:.4g} / {p['value']:.4g}"
                   f" [{p['interval'][0]:.4g}, {p['interval'][1]:.4g}]"
                   f"{'' if p['inside'] else ' OUT'}" for p in r["params"]) or "-"
    before, after = r["heldout"]
    held = "-" if before is None else (f"{1e3 * before:.3f} -> {1e3 * after:.3f}"
                                       if r["named"] and after is not None
                                       else f"{1e3 * before:.3f}")
    return f"| {r['case']} | {named} | {r['result']} | {ps} | {held} | {r['cpu_s']:.0f} |"


def main(argv: list[str] | None = None) -> int:
    return harness.sweep(sim, __doc__, "/tmp/rt12",
                         ("| case | named | result | params (truth / fit [95 %]) | "
                          "held-out RMSE (x1e-3: mm / mrad) | CPU s |\n|---|---|---|---|---|---|"),
                         run, line, argv)


if __name__ == "__main__":
    sys.exit(main())
