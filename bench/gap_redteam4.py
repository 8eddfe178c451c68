"""Red-team benchmark of ``lowcostdex gap analyze`` on a FOURTH independently written truth
simulator (issue 11 items 1, 2, 4; the holes of gap-judge9's coverage audit):
``tests/gap_truth_sim4.py`` (mujoco + numpy only: one pendulum written with a ``velocity``
actuator driven by a host position loop, a ``motor`` driven by a host PD whose torques are
logged, a ``position`` actuator with kp and kv, a ``general`` servo; effects at the range edges
and a pair on one joint). Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log log0.csv log1.csv --out report/ --seed 0

and is scored by ``gap_truth_sim2.score`` (exact / extra / family / miss / clean / false, each
documented parameter inside its 95 % interval or not).

    nice -n 10 python bench/gap_redteam4.py --threads 1          # every case (~8 cases)
    python bench/gap_redteam4.py --cases clean_velocity --keep /tmp/rt4 --json out.json
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim4")

QUICK = ("clean_velocity", "gain04_velocity", "viscous_motor_posonly")


def main(argv: list[str] | None = None) -> int:
    return harness.main(sim, "redteam4", QUICK, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
