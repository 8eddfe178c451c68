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
- ``backlash.sensor`` (where the servo's loop reads across the play: 0 an encoder on the motor
  side or a horn's play beyond the servo, 1 on the output shaft) fitted below 0.5 is held at 0 in
  the final fit when it lowers the training cost by ``min_gain`` as replayed but not with every
  goal half a physics step later (``hold_sensor``): it then stands in for a lag, not a play, and
  moves the width with it (redteam sim2 backlash_body_pendulum: the truth's goals act from its
  next 0.25 ms physics step, a 0.125 ms mean lag; replayed noiseless with that lag the true play,
  motor side, fits best, 0.23 mrad RMS; without it width 0.0270 / sensor 0.035 beat it, 0.32 vs
  0.37 mrad. On its training segments freeing the sensor lowered the cost 6.1 %, 0.13 % with
  goals 0.125 ms later, and the width interval [0.02649, 0.02771] excluded the true 0.02618).
  Since the sensor also reads the joint's damping across the play (4fc78c0) it can stand in for
  the step as well: the play's contact is 2 physics steps soft. When the late goals keep the gain
  the pair is refitted at a 4x finer step (``FINE_STEP``) with goals half of it late (redteam sim2
  backlash_offset_pendulum_stall, the truth's contact 1 ms stiff: freeing the sensor lowered the
  cost 8.4 % as replayed, 6.1 % late, 0.1 % at 0.5 ms; held, width 0.0346 for the true 0.03491,
  free 0.0387 [0.0351, 0.0449]; 15.4 % / -0.04 % with that damping term off).

An effect whose interval reaches "no effect" while its cost profiled there rises past the data's
threshold is kept (``profile_shown``): a play's width is not linear (a gravity-loaded link leans
on one stop and shows the play only at reversals; read on the output shaft its cost is jagged),
and its profile and valley intervals reached 0 on sim5 backlash2deg_pendulum_500hz_us although
the play's removal raised the train + select cost from 0.0186 to 0.0666 rad^2.

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

A scalar a fit leaves on a search bound that the data do not need (freeing it from its null lowers
the training cost by less than ``min_gain``, the bar for freeing a held scalar) is held at the null
(``settle_untold``): a bound is a verdict on a fit only where the data ask for the scalar. Without
this one joint's idle scalar vetoed the effect on the joint that shows it (redteam sim11
mass_tilt: a 2x camera on the tilt, mass_error fitted 2.002 there with select RMSE 1.1 mrad, the
offset stand-in's 8.6, but its pan scale, the 60 g yoke, ~0.2 % of the pan's inertia, ran to its
0.1 hard limit and the whole candidate was set aside as at a bound; with the pan at 1 the training
cost rose 0.13 % at the 2 ms step, 0.69 % at 0.5 ms: outside the linear 95 % threshold there,
3.84 / n_eff = 0.50 % with the lag-1 effective n, far inside the 5 % bar).

A fit on a search bound short of its hard limit is refitted in a widened range before the
backward pass may judge it (``widen_at_bounds``), as a forward round's fit is: the pass drops a
fit on a bound as implausible, and a true -0.2 rad offset on its +-0.2 search range was dropped
once the latency beside it was fitted (redteam sim4 latency050_offsetm020_position: latency
alone, held-out 259 -> 200 mrad; widened: both, -0.2000 rad and 50.3 ms, 1.0 mrad).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance
from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.gap.results import GapConfig
from lowcostdex.sim.effects import CAUSES, AppliedEffect, effect

ASYMMETRY = ("coulomb_friction", "asymmetry")
SENSOR = ("backlash", "sensor")
STRIBECK, COULOMB = "stribeck_friction", "coulomb_friction"
EXCHANGEABLE = {"inertia_error": "gain_error", "mass_error": "gain_error"}  # 1 / scale each
FINE_STEP = 0.25  # x the physics step of ``hold_sensor``'s second try: its play contact 4x stiffer


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


def settle_untold(best: dict[str, fitmod.Track], residual: fitmod.ResidualFn, min_gain: float,
                  max_rounds: int = 4) -> list[str]:
    """Hold at its null each scalar of effect ``n`` that its track ``best[n]`` leaves on a search
    bound (``fit.at_bounds``, as ``results.bound_flags`` judges it) where the data do not need
    it: freeing it from the null lowers the training cost by less than ``min_gain`` (the bar a
    new effect must pass, and ``free_asymmetry``'s for freeing a held scalar), its cost's profile
    at the null (that scalar held, the others refitted) below ``best[n].cost / (1 -
    min_gain)``. The profile is first bounded with the others as fitted (one batched replay); a
    scalar within ``UNTOLD_TRY`` times that margin gets the refit (``max_rounds`` rounds of
    lockstep LM from the fit). The scalars of one track that pass one by one are then held
    together and must pass together. A held scalar leaves ``free`` for ``held`` (the track's
    later refits keep it there); a null outside the scalar's search range is left alone.
    Returns the names of the tracks replaced (in place in ``best``)."""
    tries: list[tuple[str, list[int]]] = []
    for n, t in best.items():
        if t.r is None or not math.isfinite(t.cost):
            continue
        s = t.structure
        for i, _ in fitmod.at_bounds(s, t.u):
            f = s.free[i]
            if f.effect == n and f.lo <= _null(f) <= f.hi:
                tries.append((n, [i]))
    alone = _held_tracks(best, tries, residual, min_gain, max_rounds)
    found: dict[str, list[tuple[int, fitmod.Track]]] = {}
    for (n, idx), ok in zip(tries, alone, strict=True):
        if ok is not None:
            found.setdefault(n, []).append((idx[0], ok))
    together = [(n, [i for i, _ in one]) for n, one in found.items() if len(one) > 1]
    both = dict(zip([n for n, _ in together], _held_tracks(best, together, residual, min_gain, max_rounds),
                    strict=True))
    moved = []
    for n, one in found.items():
        t = both[n] if len(one) > 1 else one[0][1]
        if t is not None:
            best[n] = t
            moved.append(n)
    return moved


UNTOLD_TRY = 4.0  # a held scalar whose others-as-fitted rise is within this x the margin is refitted


def _null(f: fitmod.Free) -> float:
    return effect(f.effect).param(f.param).null


def _held_tracks(best: dict[str, fitmod.Track], tries: Sequence[tuple[str, list[int]]],
                 residual: fitmod.ResidualFn, min_gain: float, max_rounds: int
                 ) -> list[fitmod.Track | None]:
    """Per (name, scalar indices) of ``tries``: ``best[name]``'s structure with those scalars
    held at their nulls, fitted, when its cost is within the threshold of ``settle_untold`` of
    ``best[name]``'s (else None)."""
    if not tries:
        return []
    cands = []
    for n, idx in tries:
        t = best[n]
        s = t.structure
        keys = {(s.free[i].effect, s.free[i].param, s.free[i].joint): _null(s.free[i])
                for i in idx}
        hs = replace(s, free=[f for i, f in enumerate(s.free) if i not in idx],
                     held={**s.held, **keys})
        x = np.delete(t.x, idx)
        cands.append(fitmod.Track(hs, hs.u(x), label=f"{n} held"))
    rs = residual([(c.structure, c.structure.x(c.u)) for c in cands])
    costs = [best[n].cost for n, _ in tries]
    limits = [c / (1 - min_gain) for c in costs]
    refit = []
    for c, r, lim, c0 in zip(cands, rs, limits, costs, strict=True):
        c.r = r
        c.cost = 0.5 * float(r @ r) if np.all(np.isfinite(r)) else math.inf
        if lim < c.cost <= c0 + UNTOLD_TRY * (lim - c0):  # near: refitted from here
            c.r, c.cost = None, math.inf
            refit.append(c)
    if refit:
        fitmod.lockstep_lm(refit, residual, max_rounds, jacobian_at_end=False)
    return [c if c.cost <= lim else None for c, lim in zip(cands, limits, strict=True)]


def hold_sensor(t: fitmod.Track, residual: fitmod.ResidualFn, ctx: fitmod.Context,
                cfg: GapConfig, notes: dict[str, list[str]],
                late: Callable[..., fitmod.ResidualFn] | None = None, rtol: float = 1e-5,
                finer: bool = False) -> fitmod.Track:
    """``t`` (a fitted track), or ``t`` refitted with every backlash sensor it fitted below 0.5
    held at 0 (the motor side) when the sensors stand in for a lag: freeing them lowers the
    training cost by ``cfg.min_gain`` on ``residual`` but not on ``late()`` (the same data with
    every goal acting half a physics step later: a servo applies a goal at its next control tick,
    a lag no replay resolves and below the latency's one-step floor). A sensor the data cannot
    tell (less than ``min_gain``) stays free: the width's interval then spans where the loop may
    read. With ``finer``, when the late goals keep the gain, the pair is refitted once more on
    ``late(f)``: the physics step ``ctx.dt`` x f (``FINE_STEP``, not below ``cfg.min_step``),
    goals half that step later; held when the gain is gone there: it stood in for the step
    (``FINE_STEP``). A hold is kept for later refits (``ctx.widened``) and noted in ``notes``."""
    s = t.structure
    low = {f.joint: float(x) for f, x in zip(s.free, t.x, strict=True)
           if (f.effect, f.param) == SENSOR and x < 0.5}
    if not low or t.r is None or late is None:
        return t
    ranges = {(*SENSOR, j): (0.0, 0.0) for j in low}
    ns = fitmod.Structure.build(s.effects, s.joints, ctx.with_ranges(ranges), fixed=s.fixed)
    nt = fitmod.Track(ns, ns.u(ns.values_from(t.effects())), label=t.label + " sensor held")
    fitmod.lockstep_lm([nt], residual, 2 * cfg.max_rounds, rtol=rtol)
    if nt.r is None or not t.cost <= (1 - cfg.min_gain) * nt.cost:
        return t
    pair = [fitmod.Track(s, t.u.copy(), label="late"), fitmod.Track(ns, nt.u.copy())]
    fitmod.lockstep_lm(pair, late(), cfg.max_rounds, rtol=rtol, jacobian_at_end=False)
    gains = [1 - t.cost / nt.cost, 1 - pair[0].cost / max(pair[1].cost, 1e-300)]
    why = f"{100 * gains[1]:.1f} % with goals half a physics step later"
    fine = max(FINE_STEP, cfg.min_step / ctx.dt)
    if gains[1] >= cfg.min_gain and finer and fine < 1:  # ... and at a finer step, as late
        pair = [fitmod.Track(s, t.u.copy(), label="fine"), fitmod.Track(ns, nt.u.copy())]
        fitmod.lockstep_lm(pair, late(fine), cfg.max_rounds, rtol=rtol, jacobian_at_end=False)
        gains[1] = 1 - pair[0].cost / max(pair[1].cost, 1e-300)
        why += f", {100 * gains[1]:.1f} % at a {fine:g}x step with goals half of it later"
    if gains[1] >= cfg.min_gain:
        return t
    ctx.widened.update(ranges)
    notes.setdefault(SENSOR[0], []).extend(
        f"sensor[{s.joints[j]}] held at 0 (motor side): freed ({v:.3g}) it lowers the training "
        f"error {100 * gains[0]:.1f} % as replayed but {why} (< {100 * cfg.min_gain:.0f} %): it "
        "stood in for a lag or the step" for j, v in low.items())
    return nt


def profile_shown(weak: Sequence[str], t: fitmod.Track, residual: fitmod.ResidualFn,
                  ds: Dataset, segs: Sequence[Window], cfg: GapConfig, ctx: fitmod.Context
                  ) -> tuple[list[str], str]:
    """``weak`` (effects of the final track ``t`` whose 95 % intervals hold "no effect") less
    those whose cost, profiled at "no effect", rises past the data's threshold
    (``significance.null_profile_rise`` > 1 on ``residual``, the data of segments ``segs``):
    an interval that reaches the null through a linearisation or a smoothed valley does not
    outweigh the cost measured there. Returns (still weak, report line for those kept)."""
    if not any(f.effect in weak and (f.effect, f.param) in significance.PROFILED
               for f in t.structure.free):
        return list(weak), ""
    data = significance.data_halfwidths(t, significance.residual_blocks(ds, segs,
                                                                         cfg.interval_block))
    rise = significance.null_profile_rise(t, residual, data, ctx, weak)
    shown = [n for n in weak if rise.get(n, 0.0) > 1]
    why = "".join(f"; {n} kept although its 95 % interval reaches no effect: without it the "
                  f"cost rises {rise[n]:.3g} x the data's threshold (its profile at no effect)"
                  for n in shown)
    return [n for n in weak if n not in shown], why


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


def widen_at_bounds(s: fitmod.Structure, x: np.ndarray, residual: fitmod.ResidualFn,
                    ctx: fitmod.Context, max_rounds: int, skip: set[str]
                    ) -> tuple[fitmod.Structure, np.ndarray, set[str]]:
    """``s`` at values ``x`` refitted in ranges widened for its scalars on a search bound
    (``fit.widen_and_refit``; effects in ``skip`` not asked again). Returns the structure, its
    values (``s`` and ``x`` unchanged unless the widened fit is at least as good) and the
    effects that were on a bound; ``ctx.widened`` takes the new ranges."""
    names = {s.free[i].effect for i, _ in fitmod.at_bounds(s, s.u(x))} - skip
    if not names:
        return s, x, names
    t = fitmod.Track(s, s.u(x), label="widen")
    fitmod.lockstep_lm([t], residual, max_rounds, jacobian_at_end=False)
    t, ranges, _ = fitmod.widen_and_refit(t, residual, ctx, max_rounds)
    if not ranges:
        return s, x, names
    ctx.widened.update(ranges)
    return t.structure, t.x, names


def widened_lines(ctx: fitmod.Context, name: str, joints: Sequence[str]) -> list[str]:
    """Report lines for the ranges of effect ``name`` that ``ctx`` holds widened without a line
    of their own (widened in the backward pass, ``widen_at_bounds``)."""
    return [f"{param}[{joints[j]}] reached a search bound in the backward pass: range widened to "
            f"[{lo:.4g}, {hi:.4g}]" for (n, param, j), (lo, hi) in sorted(ctx.widened.items())
            if n == name]
