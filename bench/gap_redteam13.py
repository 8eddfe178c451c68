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


def main(argv: list[str] | None = None) -> int:
    return harness.sweep_named(sim, __doc__, "/tmp/rt13",
                               ("| case | named | result | params (truth / fit [95 %]) | "
                                "held-out RMSE (mrad) | CPU s |\n|---|---|---|---|---|---|"),
                               argv)


if __name__ == "__main__":
    sys.exit(main())
