"""Red-team benchmark of ``lowcostdex gap analyze`` on a SIXTH independently written truth
simulator (issue 11 item 4; gap-sim6, session 18): ``tests/gap_truth_sim6.py`` (mujoco + numpy
only): an Allegro-class 4-joint finger hanging palm down, driven as an Allegro is (a host PD at
333 Hz writing TORQUES to ``motor`` actuators) or by ``position`` servos at 100 Hz, with effects
no earlier set has: a read (sensor) delay, supply-voltage sag shared by the four motors (logged
``voltage:``), thermal derating across logs of one warming session (logged ``temperature:``),
and effects outside any catalogue (a PWM deadband, a series-elastic coupling, a once-per-turn
encoder error, a centre-of-mass offset) where the right answer is no confident wrong name.
Every case goes through the CLI as a user would run it:

    lowcostdex gap analyze --model model.xml --log log0.csv log1.csv log2.csv --out report/ \\
        --seed 0 --threads 1

and is scored by ``gap_truth_sim6.score``: exact / family (confusable) / miss (missed or a
wrong name) / false discovery; for effects outside the catalogue ``clean`` = pass (nothing
named, or the named effects lower the held-out RMSE with the gain's 95 % interval above 0) and
``false`` = fail (the row's ``verdict6`` says which).

    nice -n 10 python bench/gap_redteam6.py --threads 1 --keep /tmp/rt6 --json rt6.json
    python bench/gap_redteam6.py --sizes          # each case's effect size, no analysis
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim6")

QUICK = ("clean_torque_333hz", "read_delay_9ms_torque")


def main(argv: list[str] | None = None) -> int:
    return harness.main(sim, "redteam6", QUICK, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
