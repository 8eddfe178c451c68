"""The transfer loop's pieces: the policies one algorithm and seed makes (``jobs``), their run
folders' tags (``run_tag``) and the file that marks each piece of a run done (``piece_files``:
the progress total, and what a resume finds done). The loop is ``lowcostdex.transfer.loop``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lowcostdex.transfer.config import PER_ROBOT, VALVE_FIT_FILE, Size


def jobs(conditions: tuple[str, ...], robots: list[Any],
         made_for: tuple[str, ...] | None = None) -> list[tuple[str, Any]]:
    """The policies of one algorithm and seed, in run order: (condition, the robot it is made
    for, or None); ``made_for``: the robots (names) the per-robot conditions make policies for
    (None: every robot)."""
    first = [(c, None) for c in conditions if c not in PER_ROBOT]
    return first + [(c, r) for c in conditions if c in PER_ROBOT for r in robots
                    if made_for is None or r.name in made_for]


def run_tag(condition: str, made_for: Any) -> str:
    return condition if made_for is None else f"{condition}_{made_for.name}"


def piece_files(out: Path, size: Size, robots: list[Any],
                made_for: tuple[str, ...] | None = None, starts: bool = False,
                seeds: Any = None, identification: bool = True) -> list[Path]:
    """The file that marks each piece of the run done (identified fingers, trainings,
    evaluation cells): the progress total, and the pieces a resume will find done.
    ``starts``: the policies train from wider starts than the task's (``--start-range``), and
    each simulated one is also evaluated in its training sim from those starts. ``seeds``:
    the training seeds (None: 0 .. size.seeds - 1); ``identification``: False leaves the
    identified fingers out (the pieces of the seeds alone)."""
    files = []
    if identification and {"identified", "identified_randomized"} & set(size.conditions):
        files += [out / "identify" / r.name / f / "finger.json" for r in robots
                  if made_for is None or r.name in made_for for f in size.fingers]
        if size.valve_episodes:
            files += [out / "identify" / r.name / VALVE_FIT_FILE for r in robots
                      if made_for is None or r.name in made_for]
    for algo in size.algos:
        for seed in range(size.seeds) if seeds is None else seeds:
            for condition, policy_robot in jobs(size.conditions, robots, made_for):
                stem = out / "runs" / algo / f"{run_tag(condition, policy_robot)}_seed{seed}"
                files.append(stem / "summary.json")
                files += [stem.parent / f"{stem.name}.on_{t.name}.json" for t in robots]
                if condition != "on_robot":  # its training environment is the robot
                    files.append(stem.parent / f"{stem.name}.sim.json")
                    if starts:
                        files.append(stem.parent / f"{stem.name}.sim_starts.json")
    return files
