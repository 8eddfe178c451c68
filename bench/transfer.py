"""Does the identified model make policies that work on the robot? The transfer table (issue 14).

A thin wrapper of ``lowcostdex transfer`` (``lowcostdex/transfer/loop.py`` holds the loop); the
arguments are the command's:

    python bench/transfer.py --out bench_runs/transfer --size smoke     # checks the loop
    python bench/transfer.py --out bench_runs/transfer                  # 3 robots, 1 seed, DAPG
    python bench/transfer.py --out bench_runs/transfer --seeds 3 --algos dapg,npg   # full table
    python bench/transfer.py --out bench_runs/transfer --task valve-near
    python bench/transfer.py --out bench_runs/transfer --conditions on_robot --made-for B
    python bench/transfer.py --out bench_runs/sr --start-range 0.02   # starts and goals +-0.02 rad

``--made-for B`` makes the per-robot policies (identified, identified_randomized, on_robot) for
robot B only (on_robot takes hours per robot); a later run on the folder adds the others. Why a
policy fails on a hidden robot: ``bench/transfer_diagnose.py`` (one part of the robot at a time);
why identified + narrow DR ends off where identified does not: ``bench/transfer_narrow.py`` (its
ranges, each policy in each training sim, retrained with narrower ranges).

Record measured tables in bench/RESULTS.md ("Transfer table") with date, machine, load and the
command line.
"""

from __future__ import annotations

import sys

from lowcostdex.cli import main

if __name__ == "__main__":
    raise SystemExit(main(["transfer", *sys.argv[1:]]))
