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


def main(argv: list[str] | None = None) -> int:
    return harness.sweep_named(sim, __doc__, "/tmp/rt12",
                               ("| case | named | result | params (truth / fit [95 %]) | "
                                "held-out RMSE (x1e-3: mm / mrad) | CPU s |\n|---|---|---|---|---|---|"),
                               argv, digits=3)


if __name__ == "__main__":
    sys.exit(main())
