"""Red-team benchmark of ``lowcostdex gap analyze`` on a THIRD independently written truth
simulator (issue 11 item 4): ``tests/gap_truth_sim3.py`` (mujoco + numpy only: a D'Claw-like
3-joint finger on plain ``position`` actuators with an effect on one joint or a pair on two, and
a one-joint servo whose truth is a ``motor`` driven by its own 1 kHz integer-tick P-D firmware;
effects at the ends and middles of the issue's ranges). Every case goes through the CLI as a
user would run it:

    lowcostdex gap analyze --model model.xml --log log0.csv log1.csv ... --out report/ --seed 0

and its report.json is scored per (effect, joint) pair: exact (the hidden pairs named and
nothing else), extra (named plus others), family (a confusable neighbour on that joint), miss
(a hidden pair neither named nor a neighbour), false discovery (clean case, something named),
crash (non-zero exit: the command is printed); each documented parameter inside its 95 %
interval or not; wall time. Prints progress lines, a table and a summary line.

    nice -n 10 python bench/gap_redteam3.py               # every case (~2 h on a shared VM)
    python bench/gap_redteam3.py --quick                  # a subset
    python bench/gap_redteam3.py --cases fin_latency60_prox --keep /tmp/rt3 --json out.json
    python bench/gap_redteam3.py --rescore out.json more.json  # re-score kept reports, one table
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim3")

QUICK = ("fin_latency60_prox", "srv_stribeck", "fin_gain035_abd_50hz_posonly",
         "fin_clean_noisy", "srv_backlash_output", "fin_backlash080_dist")


def main(argv: list[str] | None = None) -> int:
    return harness.main(sim, "redteam3", QUICK, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
