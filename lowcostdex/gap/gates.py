"""Catalogue parameters a fit holds at their null until the data show they are needed.

A parameter free everywhere is fitted where the data cannot tell it (session 8: a creep share of
0.0 for a soft truth under a small friction level). Such parameters are held at their null
(``fit.space``) and freed on one joint by a test:

- ``coulomb_friction.creep`` when the fitted level reaches half its search range's top, at least
  the actuator's force (``fit.at_bounds`` / ``fit.widen``): there MuJoCo's soft friction lets a
  held joint creep (~F R / b) where a gearbox sticks.
- ``coulomb_friction.asymmetry`` (levels F (1 + a) moving positive, F (1 - a) negative) when
  freeing it lowers the training cost of a promising Coulomb fit by ``min_gain``, the bar a new
  effect must pass (``free_asymmetry``). A P servo (stiffness kp) stops at goal - s F (1 + a s) /
  kp, the symmetric level's stops shifted by -F a / kp: held symmetric, a direction-dependent
  level is named an offset (redteam3 srv_dirfric_50hz, 0.15 / 0.05 N m: position_offset alone).
"""

from __future__ import annotations

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.results import GapConfig
from lowcostdex.sim.effects import effect

ASYMMETRY = ("coulomb_friction", "asymmetry")


def free_asymmetry(best: dict[str, fitmod.Track], residual: fitmod.ResidualFn,
                   ctx: fitmod.Context, cfg: GapConfig) -> dict[str, tuple[dict, list]]:
    """Refit the Coulomb track of ``best`` (candidate name -> fitted track) with its asymmetry
    freed on every joint with a level above 0, if it is among the ``cfg.joint_k`` lowest costs;
    the refit replaces it in ``best`` when its training cost is ``cfg.min_gain`` lower.

    Returns {name: (ranges that free it, [(effect, report line)])} for ``analyze``'s widened
    ranges (kept in the context once the cause is accepted), empty when nothing was freed."""
    t = best.get(ASYMMETRY[0])
    if t is None or t.r is None or sum(x.cost < t.cost for x in best.values()) >= cfg.joint_k:
        return {}  # (not ``t in list``: a Track compares its arrays)
    s = t.structure
    held = {f.joint for f in s.free if (f.effect, f.param) == ASYMMETRY}
    ranges = {(*ASYMMETRY, f.joint): effect(ASYMMETRY[0]).param(ASYMMETRY[1]).hard
              for f, x in zip(s.free, t.x, strict=True)
              if (f.effect, f.param) == (ASYMMETRY[0], "frictionloss") and x > 0
              and f.joint not in held}
    if not ranges:
        return {}
    ns = fitmod.Structure.build(s.effects, s.joints, ctx.with_ranges(ranges), fixed=s.fixed)
    nt = fitmod.Track(ns, ns.u(ns.values_from(t.effects())), label=t.label + "+asymmetry")
    fitmod.lockstep_lm([nt], residual, cfg.max_rounds, jacobian_at_end=False)
    if not nt.cost <= (1 - cfg.min_gain) * t.cost:
        return {}
    best[ASYMMETRY[0]] = nt
    lines = [(ASYMMETRY[0], f"asymmetry[{s.joints[j]}] freed: training error "
              f"{100 * (1 - nt.cost / t.cost):.0f} % lower than a symmetric level")
             for *_, j in ranges]
    return {ASYMMETRY[0]: (ranges, lines)}
