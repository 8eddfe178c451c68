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

An effect the final refit finds no evidence for is dropped (``drop_weak``) unless a nested
effect it contains is shown: a ``stribeck_friction`` whose breakaway (static) interval holds 0
but whose sliding level's excludes 0 is a stiff Coulomb, refitted as ``coulomb_friction`` with
its creep freed from stiff (0) rather than dropped with the friction it carries (redteam sim2
torque_coulomb_pendulum: a sticking 0.1 N m Coulomb taken as a static-0 Stribeck, 0.104, then
dropped: "torque_limit alone").

Some effects stand in for others exactly (``swap_equivalent``): J q'' = s kp (g - q) - D q' - m g
l sin q is (J / s) q'' = kp (g - q) - (D / s) q' - (m / s) g l sin q, so a gain error s and an
inertia (or mass) error 1 / s with the damping scaled alike replay one trajectory. The forward
rounds reach whichever comes first (redteam sim2 gain_viscous_turntable: gain 0.7 + viscous 0.08
named inertia_error 1.589 + viscous 0.189); the other is refitted in its place and, when the select
data cannot tell them apart, named by catalogue order as a round's tie is, the pair reported.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.results import GapConfig
from lowcostdex.sim.effects import CAUSES, AppliedEffect, effect

ASYMMETRY = ("coulomb_friction", "asymmetry")
STRIBECK, COULOMB = "stribeck_friction", "coulomb_friction"
EXCHANGEABLE = {"inertia_error": "gain_error", "mass_error": "gain_error"}  # 1 / scale each


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


def drop_weak(t: fitmod.Track, drop: str, mid: np.ndarray, half: np.ndarray,
              ctx: fitmod.Context) -> tuple[fitmod.Structure, np.ndarray, str]:
    """The model after ``drop`` (an effect of the fitted track ``t`` whose 95 % intervals,
    centres ``mid`` and half-widths ``half`` in optimizer coordinates, hold "no effect") is
    taken out: (structure, start values, report line). A Stribeck friction whose sliding level
    (coulomb) excludes 0 on some joint is replaced in place by ``coulomb_friction`` at that
    level, its creep freed (0 = stiff, as the Stribeck's constraint; ``ctx.widened`` keeps the
    range for later refits); otherwise ``drop`` goes."""
    s = t.structure
    x = t.x
    shown = [f.joint for i, f in enumerate(s.free)
             if (f.effect, f.param) == (STRIBECK, "coulomb") and not f.log
             and half[i] > 0 and abs(mid[i] - f.to_u(0.0)) > half[i]]
    if drop != STRIBECK or COULOMB in s.effects or not shown:
        keep = tuple(n for n in s.effects if n != drop)
        cur = fitmod.Structure.build(keep, s.joints, ctx)
        return cur, cur.values_from(t.effects()), f"; {drop} dropped: its 95 % interval holds no effect"
    level = {f.joint: v for f, v in zip(s.free, x, strict=True)
             if (f.effect, f.param) == (STRIBECK, "coulomb")}
    ctx.widened.update({(COULOMB, "creep", j): (0.0, 1.0) for j in shown})
    cur = fitmod.Structure.build(tuple(COULOMB if n == STRIBECK else n for n in s.effects),
                                 s.joints, ctx)
    v = cur.values_from(t.effects())
    for i, f in enumerate(cur.free):
        if f.effect == COULOMB and f.param in ("frictionloss", "creep"):
            v[i] = float(np.clip(level.get(f.joint, 0.0) if f.param == "frictionloss" else 0.0,
                                 f.lo, f.hi))
    lv = ", ".join(f"{level[j]:.4g}" for j in shown)
    return cur, v, (f"; {STRIBECK}'s breakaway interval holds 0: refitted as {COULOMB} at its "
                    f"sliding level {lv} N m, stiff (a Stribeck with no breakaway is a Coulomb)")


def swap_equivalent(cur: fitmod.Structure, x: np.ndarray, fit_fn: fitmod.ResidualFn,
                    select_sse: Callable[[Sequence[Sequence[AppliedEffect]]], Sequence[float]],
                    cfg: GapConfig, ctx: fitmod.Context, equivalents: dict[str, list[str]]
                    ) -> tuple[fitmod.Structure, np.ndarray, str]:
    """For each effect X of the model ``cur`` (values ``x``) with an exchangeable Y
    (``EXCHANGEABLE``) earlier in ``CAUSES`` and not in the model: the model with Y in X's place,
    every parameter refitted on ``fit_fn`` (training data) from the model's values and Y at 1 /
    X's scale or Y's start. When its select SSE (``select_sse``: one per model) is within
    ``cfg.tie`` of the model's or lower, Y replaces X; within the tie either way X is listed in
    ``equivalents[Y]``. Returns (structure, values, report line, empty when nothing changed)."""
    line = ""
    for xn in [n for n in cur.effects if n in EXCHANGEABLE]:
        yn = EXCHANGEABLE[xn]
        if yn in cur.effects or CAUSES.index(yn) > CAUSES.index(xn):
            continue
        alt = fitmod.Structure.build(tuple(yn if n == xn else n for n in cur.effects),
                                     cur.joints, ctx, fixed=cur.fixed)
        old = cur.to_effects(x)
        scale = next(e for e in old if e.name == xn).values["scale"]
        base = alt.values_from(old)
        tracks = []
        for inv in (True, False):
            u = base.copy()
            for i, f in enumerate(alt.free):
                if f.effect == yn:
                    u[i] = float(np.clip(1.0 / scale[f.joint] if inv else f.start, f.lo, f.hi))
            tracks.append(fitmod.Track(alt, alt.u(u), label=f"{yn} for {xn}"))
        fitmod.lockstep_lm(tracks, fit_fn, cfg.max_rounds, jacobian_at_end=False)
        best = min(tracks, key=lambda t: t.cost)
        s_cur, s_alt = select_sse([old, best.effects()])
        if not s_alt <= (1 + cfg.tie) * s_cur:
            continue
        tie = s_alt >= (1 - cfg.tie) * s_cur
        if tie:
            equivalents[yn] = [*equivalents.pop(xn, []), xn]
        fx = ", ".join(f"{e.name} {_vals(e)}" for e in old)
        fy = ", ".join(f"{e.name} {_vals(e)}" for e in best.effects())
        line += (f"; {yn} in {xn}'s place: select SSE {s_alt:.4g} vs {s_cur:.4g} rad^2 ("
                 + ("not identifiable from these logs, named by catalogue order" if tie
                    else "lower") + f"): {fy} or {fx}")
        cur, x = alt, best.x
    return cur, x, line


def _vals(e: AppliedEffect) -> str:
    return " ".join(f"{p}=" + "/".join(f"{float(v):.4g}" for v in np.atleast_1d(a))
                    for p, a in e.values.items())
