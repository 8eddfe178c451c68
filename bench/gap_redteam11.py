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


def main(argv: list[str] | None = None) -> int:
    return harness.sweep_named(sim, __doc__, "/tmp/rt11",
                               ("| case | named | result | params (truth / fit [95 %]) | held-out RMSE | CPU s |\n"
                                "|---|---|---|---|---|---|"),
                               argv, unit=" mrad")


if __name__ == "__main__":
    sys.exit(main())
