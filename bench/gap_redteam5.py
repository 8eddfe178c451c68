"""Red-team benchmark of ``lowcostdex gap analyze`` on a FIFTH independently written truth
simulator (issue 11 items 2 and 4; gap-judge11, session 16): ``tests/gap_truth_sim5.py``
(mujoco + numpy only): plants and logs as users bring them - a two-link arm whose model already
sets armature and frictionloss (the truth has more), a finger with an unactuated joint on a
passive tendon spring, effects at real-world sizes and in pairs (latency 8-40 ms, 2 deg of
backlash read on the output, a 0.28 rad reading offset, a small servo's Coulomb + viscous), and
logs in degrees, integer-ms or integer-us stamps, 30-1000 Hz, columns in another order, rows
dropped or written twice. Every case goes through the CLI as a user would run it, with the
options that user passes for the spelling of the logs:

    lowcostdex gap analyze --model model.xml --log log0.csv log1.csv --out report/ --seed 0 \\
        [--units deg] [--time-unit ms]

and is scored by ``gap_truth_sim2.score`` (exact / extra / family / miss / clean / false, each
documented parameter inside its 95 % interval or not).

    nice -n 10 python bench/gap_redteam5.py --threads 1          # every case (9)
    python bench/gap_redteam5.py --cases clean_arm2_deg_ms --keep /tmp/rt5 --json out.json
"""

from __future__ import annotations

import pathlib
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import redteam_harness as harness  # noqa: E402

sim = harness.truth_module("gap_truth_sim5")

QUICK = ("clean_arm2_deg_ms", "coulomb_more_arm2", "servo_friction_pendulum")


def main(argv: list[str] | None = None) -> int:
    return harness.main(sim, "redteam5", QUICK, __doc__, argv)


if __name__ == "__main__":
    sys.exit(main())
