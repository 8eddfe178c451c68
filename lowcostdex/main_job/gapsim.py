"""DAPG's validation in the simulation the gap stage identified.

DAPG trains in the catalogue-randomized simulation and keeps the iterate that validates best
(``SimTraining.dense_from``: every late iterate competes). Which iterate wins depends on the
validation sim: one that behaves like the robot ranks the iterates as the robot would. The gap
stage has measured the robot's servos (identification logs, then ``gap.analyze``) and wrote the
effects it identified into ``gap/report/extended/effects.json``; this module turns them into the
validation sim: the task's nominal MuJoCo model with exactly those effects on every hand joint,
each parameter drawn per episode from the range the gap stage fitted (``gap.extension.dr_ranges``:
its 95 % interval widened to at least +-10 % of the value); a parameter the analysis held at a
value (an unbounded interval) stays at that value. Nothing here reads the emulated robot's
definition: only what the gap stage wrote.

Measured (bench/RESULTS.md, "DAPG's iterate chosen in the gap-identified simulation"; the main
job's DAPG stage on seeds 0-2, the same iterates, chosen on the same 100 validation episodes;
judged on the 100 held-out robot episodes against the clone): validated in the catalogue-
randomized training sim 40 -> 49, 39 -> 52, 20 -> 37 (McNemar p 0.054, 0.0022, 0.0017); in this
sim 40 -> 54, 39 -> 53, 20 -> 37 (p 0.0047, 0.0007, 0.0017). With every parameter held at its
identified value instead (``spread=False``): 54, 53, 32 (seed 2 chose another iterate).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lowcostdex.main_job.setup import Context

GAP_EXTENDED = Path("gap") / "report" / "extended"
"""Where the gap stage's identified model lies in the main job's ``--out``."""


def identified_randomization(extended: str | Path, joints: Sequence[str],
                             spread: bool = True) -> dict[str, Any] | None:
    """The ``DomainRandomization`` dict (``to_dict`` form: an env's ``randomize`` keyword) of
    the simulation with the effects of the extended-model folder ``extended``
    (``gap.extension.save_extended``) on each of ``joints``. ``spread``: each parameter drawn
    per episode from the folder's fitted range (its ``domain_randomization``), one range for
    every joint; a parameter the analysis held (its interval unbounded) at its identified
    values' span. Else every parameter fixed (low == high) at its identified value, a joint of
    another finger taking the value identified in its place (``ff_top`` -> ``mf_top``). None
    when the folder names no effect (the gap analysis found the nominal model good enough).

    Raises:
      ConfigError: ``extended`` is not an extended-model folder.
    """
    import numpy as np

    from lowcostdex.gap.extension import load_extended
    from lowcostdex.sim.effects import DomainRandomization, effect

    ext = load_extended(extended)
    if not ext.effects:
        return None
    if spread:
        import json

        folder = Path(extended)
        raw = json.loads((folder / "effects.json").read_text()
                         if (folder / "effects.json").is_file()
                         else (folder / "extended" / "effects.json").read_text())
        spans = {k: dict(v) for k, v in ext.ranges.items()}
        for e in raw["effects"]:
            for p, iv in (e.get("interval") or {}).items():
                if not np.all(np.isfinite(np.asarray(iv, float))):
                    v = np.asarray(e["params"][p], float)
                    spans[e["effect"]][p] = (float(v.min()), float(v.max()))
        return DomainRandomization(tuple(spans), tuple(joints), spans).to_dict()
    # effect -> parameter -> place on the finger -> identified value (entries merged)
    found: dict[str, dict[str, dict[str, float]]] = {}
    for e in ext.effects:
        for p, v in e.values.items():
            v = np.broadcast_to(np.asarray(v, float), (len(e.joints),))
            at = found.setdefault(e.name, {}).setdefault(p, {})
            for j, x in zip(e.joints, v, strict=True):
                at[_place(j)] = float(x)
    ranges: dict[str, dict[str, tuple[list[float], list[float]]]] = {}
    for name, params in found.items():
        for p, at in params.items():
            low, high = effect(name).param(p).hard
            mean = float(np.mean(list(at.values())))
            # a parameter at an infinite null (absent) is held at its hard limit instead
            fixed = [float(np.clip(at.get(_place(j), mean), low, high)) for j in joints]
            ranges.setdefault(name, {})[p] = (fixed, fixed)
    return DomainRandomization(tuple(found), tuple(joints), ranges).to_dict()


def validation_sim(ctx: Context) -> dict[str, Any]:
    """Where DAPG's iterates (and the clone) are validated when DAPG trains in simulation: the
    simulation the gap stage identified (``main_job.gapsim``: the task's model with the effects
    the gap stage found on the robot, at their identified values) when the gap stage finished
    in ``ctx.out``, else the training simulation itself (the catalogue's randomization).

    Why: DAPG's late iterates differ by up to 14 of 100 episodes from one iteration to the next,
    so the validation sim's ranking decides the gain; one that behaves like the robot ranks
    them as the robot does (bench/RESULTS.md, "DAPG's iterate chosen in the gap-identified
    simulation"). Returns ``{"sim": "gap-identified" | "training", "why": words,
    "effects": [...], "env_kwargs": the evaluations' gym.make kwargs or None}``."""
    from lowcostdex.hands import dclaw_spec

    folder = ctx.out / GAP_EXTENDED
    if "gap" not in ctx.results or not (folder / "effects.json").is_file():
        return {"sim": "training", "effects": [], "env_kwargs": None,
                "why": "the gap stage has not run in this output folder (it runs before train "
                       "in a full main job), so DAPG's iterates were validated in the "
                       "simulation they trained in"}
    dr = identified_randomization(folder, dclaw_spec().joint_names)
    if dr is None:
        return {"sim": "training", "effects": [], "env_kwargs": None,
                "why": "the gap stage identified no effect, so DAPG's iterates were validated "
                       "in the simulation they trained in"}
    return {"sim": "gap-identified", "effects": list(dr["effects"]),
            "env_kwargs": {**ctx.setup.env_overrides, "randomize": dr},
            "why": "the gap stage's identified model: the task's MuJoCo model with the effects "
                   f"it found on the robot ({', '.join(dr['effects'])}), each parameter drawn "
                   "per episode from the range the gap stage fitted "
                   f"({GAP_EXTENDED.as_posix()}/effects.json)"}


def _place(joint: str) -> str:
    """A joint's place on its finger (``ff_top`` -> ``top``)."""
    return joint.split("_", 1)[-1]
