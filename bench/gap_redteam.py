"""Red-team benchmark of ``lowcostdex gap analyze`` on a second, independently written truth
simulator (issue 11): ``tests/gap_truth_sim2.py`` (mujoco + numpy only; its own rigs, actuator
kinds, hidden effects and logs). Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log log0.csv log1.csv ... --out report/ --seed 0

and its report.json is scored: exact (named exactly the hidden causes, catalogue names), family
(a confusable neighbour), extra (the hidden causes and more), miss, false discovery (clean case,
something named), crash (non-zero exit: the command is printed); each expected parameter inside its 95 % interval or not; wall
time. Prints progress lines, a table and a summary line.

    nice -n 10 python bench/gap_redteam.py                # every case (~30-60 min on a shared VM)
    python bench/gap_redteam.py --quick                   # a subset
    python bench/gap_redteam.py --cases latency_queue_pendulum --keep /tmp/rt --json out.json
    python bench/gap_redteam.py --rescore out.json more.json   # re-score kept reports, one table
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim2")

QUICK = ("clean_pendulum", "latency_queue_pendulum", "coulomb_mj_turntable",
         "gain_low_pendulum_posonly", "reading_offset_arm2", "backlash_body_pendulum")


def main(argv: list[str] | None = None) -> int:
    return harness.main(sim, "redteam", QUICK, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
