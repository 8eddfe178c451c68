"""Fitted values of an identification on a search bound: which (``_at_bound``, reported in
``Identified.at_bound``) and the note that says they are no measurement (``bound_notes``)."""

from __future__ import annotations

import math

from lowcostdex.gap import fit as fitmod
from lowcostdex.sim.effects import EFFECTS


def _bound_hits(t: fitmod.Track) -> list[tuple[int, str]]:
    """(free index, "lower" / "upper") of the fitted values on a search bound that is not the
    parameter's null (a friction at 0 is absent, not at a bound), nor the Stribeck velocity of
    a breakaway share, or the back-driven share of a gear friction, whose levels are within 0.1 %
    of their ranges from their nulls of 0 (they shape next to nothing)."""
    lo, hi = t.structure.u_bounds()
    x = t.structure.x(t.u)
    out = []
    for i, f in enumerate(t.structure.free):
        null = EFFECTS[f.effect].param(f.param).null
        absent = {g.param: x[k] <= 1e-3 * (g.hi - g.lo) for k, g in enumerate(t.structure.free)
                  if (g.effect, g.joint) == (f.effect, f.joint)}
        if (f.param == "velocity" and absent.get("static")) or EFFECTS[f.effect].param(
                f.param).ends or (f.param == "backdrive" and absent.get("mu")
                                  and absent.get("static")):
            continue
        for b, side in ((lo[i], "lower"), (hi[i], "upper")):
            if abs(t.u[i] - b) <= 1e-6 * max(1.0, abs(b)) and not math.isclose(f.from_u(b), null):
                out.append((i, side))
    return out


def _at_bound(t: fitmod.Track) -> list[str]:
    return [f"{t.structure.free[i].effect}.{t.structure.free[i].param}"
            for i, _ in _bound_hits(t)]


def bound_notes(t: fitmod.Track) -> list[str]:
    """One line per fitted value on a search bound (``_bound_hits``): value, bound, range, and
    that it is no measurement (Pham XL330's mounting offset at +0.3 rad, Rhoban's voltage weight
    at 1.5, 2026-11-26). Not widened: a bench 17 degrees off its hanging zero or a supply term
    beyond 1.5x the measured sag is a sign of an effect the structure lacks."""
    out = []
    for i, side in _bound_hits(t):
        f = t.structure.free[i]
        unit = EFFECTS[f.effect].param(f.param).unit
        unit = "" if unit == "1" else f" {unit}"
        joint = t.structure.joints[f.joint]
        out.append(f"{f.effect}.{f.param} on {joint} fitted {f.from_u(t.u[i]):.4g}{unit}, at its "
                   f"{side} search bound (range {f.lo:.4g} to {f.hi:.4g}{unit}): the logs pull it "
                   "further, so the value is not a measurement of it; it may stand in for an "
                   "effect the structure lacks (see the held-out ablation)")
    return out
