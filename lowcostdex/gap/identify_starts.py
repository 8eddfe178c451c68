"""Where ``identify``'s least-squares fits start (the catalogue's starts, the extra ones, a
jitter around them and values measured otherwise, e.g. the armature of the torque-off swings).

``identify`` fits a fixed servo structure from the catalogue's starts and its own extra starts
(``IdentifyConfig.starts``, e.g. a large breakaway share). The effect search of ``gap analyze``
(``fit.space``) adds probes/starts of its own for ranking candidate effects on simulated cases;
one of them is not ``identify``'s to take: the Coulomb level at half the actuator's force (added
2026-11-26 for redteam3's srv_coulomb_stall_50hz, a Coulomb level at 80 % of a position servo's
force, 2c9e98a). On real servo logs that start wins on the training logs and extrapolates worse:
Rhoban XL330, BAM's split (fit kp 100 + 400, held out kp 200 + 800), held out 45.5 -> 54.2 mrad
(kp 800 51.7 -> 67.3; BAM's refit M6 59.9); measured 2026-11-27, bench/RESULTS.md (gap-real3).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.sim.effects import EFFECTS

# (effect, param) whose analysis-only extra starts identify leaves out
ANALYSIS_ONLY = frozenset({("coulomb_friction", "frictionloss")})


def own(st: fitmod.Structure) -> fitmod.Structure:
    """``st`` without the extra starts of ``ANALYSIS_ONLY`` scalars (same free scalars, bounds
    and catalogue starts, the held scalars kept)."""
    free = [replace(f, extra=()) if (f.effect, f.param) in ANALYSIS_ONLY else f for f in st.free]
    return replace(st, free=free)


def starts(st: fitmod.Structure, extra: Sequence[dict], base: np.ndarray | None = None
           ) -> list[np.ndarray]:
    """The structure's catalogue starts (or ``base`` alone) plus one per ``extra`` override
    (applied to the first start); the analysis-only extra starts left out (module doc)."""
    out = own(st).starts() if base is None else [np.asarray(base, float)]
    for over in extra:
        x = out[0].copy()
        hit = False
        for i, f in enumerate(st.free):
            if (f.effect, f.param) in over:
                x[i] = float(np.clip(over[(f.effect, f.param)], f.lo, f.hi))
                hit = True
        if hit:
            out.append(x)
    return out


def widened(t: fitmod.Track, st: fitmod.Structure) -> fitmod.Track:
    """An earlier stage's fit ``t`` as a track of the later stage's structure ``st``: its fitted
    values, the scalars it did not fit at their nulls (within their bounds: the same model, its
    cost and residual kept), so that the identified model always names ``st``'s effects."""
    names = {e.name for e in t.effects()}
    x = st.values_from(t.effects())
    for i, f in enumerate(st.free):
        if f.effect not in names:
            x[i] = float(np.clip(EFFECTS[f.effect].param(f.param).null, f.lo, f.hi))
    return fitmod.Track(st, st.u(x), label=t.label, cost=t.cost, r=t.r, rounds=t.rounds,
                        history=list(t.history))


def jittered(st: fitmod.Structure, x: np.ndarray, rel: float, rng: np.random.Generator
             ) -> np.ndarray:
    """``x`` with each value times 1 + rel N(0, 1), clipped to its search bounds."""
    lo = np.array([f.lo for f in st.free])
    hi = np.array([f.hi for f in st.free])
    return np.clip(np.asarray(x, float) * (1.0 + rel * rng.standard_normal(len(x))), lo, hi)


def seeded(st: fitmod.Structure, x: np.ndarray, seed: dict) -> np.ndarray:
    """``x`` with the free scalars ``seed`` names ({(effect, param): value}, every joint) set to
    its values, clipped to their search bounds (e.g. the armature the torque-off swings say:
    ``torque_off.armature_seed``)."""
    x = np.array(x, float)
    for i, f in enumerate(st.free):
        if (f.effect, f.param) in seed:
            x[i] = float(np.clip(seed[(f.effect, f.param)], f.lo, f.hi))
    return x
