"""Replacing a stand-in after the forward selection, and whether a change of model pays.

The forward selection is greedy: each round adds the candidate that best explains what is left,
judged at the model chosen so far. When the first choice is a stand-in (a cause that mimics two
hidden ones at once), later rounds are ranked and fitted around it and the right cause never
wins a round. Seen on the redteam's sim2 ``queue_mass_arm2_posonly`` (a 2-link arm: a 30 ms goal
queue and every link 1.5 x heavier, position-only logs): a torque limit alone took round 1
(select MSE 86 % lower; the heavier arm accelerates as a weaker one does), a backlash round 2
(gravity holds a link at one side of a play, which stands in for the heavier arm's sag) and the
latency round 3, 24 mrad on the select split. The mass ranked 10th at the nominal model (the
30 ms lag dominates its residual) and 3rd to 5th after, where fitted with the torque limit held
it moved by 5 %. Latency + mass refitted from the named model's values: 9.2 mrad, masses 1.52 /
1.50.

``prune_refitted`` is the same step with nothing in an effect's place, judged by whether the
effect is needed rather than whether a change pays: the backward pass (``analyze._backward``)
judges an effect with the others left at the values they took beside it, so an effect the
others were fitted around looks needed (leaving it out alone leaves them wrong). On
``queue_mass_arm2_posonly`` after the exchange: latency + mass + a backlash of 14 / 9 mrad, each
rise far above ``min_gain / 2`` with the others unchanged, while latency + mass refitted without
the play replays as well (held-out 8.32 mrad without it, 8.37 with it).

``replace_standins`` is an exchange step (the replacement algorithm of subset selection): for
each accepted effect, the model without it is ranked (``analyze._rank``), and the model with
the best ``GapConfig.exchange_k`` candidates in its place, or with nothing in its place, is
refitted with every parameter free from the model's values. The best plausible one (no fit at a
parameter bound) replaces the model when the change pays (``switch_pays``: what the backward
search's switch must show). Passes repeat while one exchange is made (at most
``max_effects``); the analysis then prunes with its backward pass.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.gap.results import CandidateResult, GapConfig, bound_flags
from lowcostdex.gap.selection import mse_by_episode, probe_gains, select_gain_ci
from lowcostdex.sim.effects import AppliedEffect

__all__ = ["effect_size", "prune_refitted", "replace_standins", "switch_pays"]

Rank = Callable[[fitmod.Structure, np.ndarray, Sequence[str]], list[CandidateResult]]


def effect_size(predict, eps: Sequence[Window], cur: Sequence[AppliedEffect],
                new: Sequence[AppliedEffect]) -> float:
    """RMS difference between two models' open-loop predictions on ``eps`` [rad]: how visible
    a change of model is (train and select episodes: visibility is not a held-out claim).
    ``predict(windows, columns)`` replays each column of effects (``analyze._Engine.predict``)."""
    a, b = predict(eps, [list(cur), list(new)])
    d = np.concatenate([(x - y).ravel() for x, y in zip(a, b, strict=True)])
    return float(np.sqrt(np.mean(d * d)))


def switch_pays(eng, ds: Dataset, sel_eps: Sequence[Window], vis_eps: Sequence[Window],
                train_segs: Sequence[Window], cur: Sequence[AppliedEffect],
                new: Sequence[AppliedEffect], sse_cur: float, base_sse: np.ndarray,
                cfg: GapConfig, floor_rms: float, rng: np.random.Generator
                ) -> tuple[bool, np.ndarray]:
    """Whether model ``new`` replaces model ``cur`` (effect lists): its select MSE is ``min_gain``
    below ``cur``'s (``sse_cur``, summed) and ``min_gain`` below the nominal model's
    (``base_sse``, per episode), the two models' predictions on ``vis_eps`` differ by
    ``min_effect`` noise floors (effects that cancel each other cannot sneak in), and it lowers
    the training error and the select error with goals a fraction of a step later
    (``GapConfig.probes``) by ``min_gain``. ``eng`` is the analysis' engine (``predict``,
    ``residuals``, ``rep.run``). Returns (pays, ``new``'s per-episode select SSE)."""
    sse_new = mse_by_episode(ds, sel_eps, eng.predict(sel_eps, [list(new)])[0])[0]
    rel_base, _ = select_gain_ci(base_sse, sse_new, rng, cfg.bootstrap)
    switch = effect_size(eng.predict, vis_eps, cur, new)
    better = (sse_new.sum() < (1 - cfg.min_gain) * sse_cur and rel_base >= cfg.min_gain
              and switch >= cfg.min_effect * floor_rms)
    if better:  # ... on the data it was fitted to too
        ra, rc = eng.residuals(train_segs, [list(new), list(cur)])
        better = 1 - float(ra @ ra) / max(float(rc @ rc), 1e-300) >= cfg.min_gain
    if better:  # ... and it pays on the probes too
        probe = probe_gains(eng.rep.run, ds, sel_eps, cur, new, cfg.probes)
        better = min(probe, default=math.inf) >= cfg.min_gain
    return better, sse_new


def replace_standins(eng, ds: Dataset, sel_eps: Sequence[Window], vis_eps: Sequence[Window],
                     train_segs: Sequence[Window], current: fitmod.Structure,
                     cur_x: np.ndarray, cands: Sequence[str], rank: Rank,
                     fit_fn: fitmod.ResidualFn, sse_cur: np.ndarray, base_sse: np.ndarray,
                     cfg: GapConfig, ctx: fitmod.Context, floor_rms: float,
                     rng: np.random.Generator
                     ) -> tuple[fitmod.Structure, np.ndarray, np.ndarray, str]:
    """The exchange step (module docstring) on the model ``current`` (values ``cur_x``, per
    episode select SSE ``sse_cur``); ``rank(structure, values, names)`` scores candidates at a
    model. Returns (structure, values, its select SSE per episode, report line: empty when
    nothing changed)."""
    line = ""
    for _ in range(cfg.max_effects):
        if len(current.effects) < 2:
            break
        effs = current.to_effects(cur_x)
        remaining = [c for c in cands if c not in current.effects]
        alts: list[tuple[str, fitmod.Track]] = []
        for out in current.effects:
            reduced = fitmod.Structure.build(tuple(n for n in current.effects if n != out),
                                             current.joints, ctx)
            red_x = reduced.values_from(effs)
            table = sorted(rank(reduced, red_x, remaining), key=lambda c: -c.score)
            top = [c.effect for c in table if c.score >= cfg.min_gain][:cfg.exchange_k]
            tracks = [fitmod.Track(reduced, reduced.u(red_x), label=f"without {out}")]
            for c in top:
                st = fitmod.Structure.build(reduced.effects + (c,), current.joints, ctx)
                tracks += [fitmod.Track(st, st.u(x0), label=f"{c} for {out}#{k}")
                           for k, x0 in enumerate(st.starts(st.values_from(effs)))]
            fitmod.lockstep_lm(tracks, fit_fn, cfg.max_rounds, prune=fitmod.prune_tracks,
                               jacobian_at_end=False)
            best: dict[tuple[str, ...], fitmod.Track] = {}
            for t in tracks:
                k = t.structure.effects
                if k not in best or t.cost < best[k].cost:
                    best[k] = t
            alts += [(out, t) for t in best.values() if not any(
                bound_flags(t.structure, t.u, n) for n in t.structure.effects)]
        if not alts:
            break
        preds = eng.predict(sel_eps, [t.effects() for _, t in alts])
        sse = [mse_by_episode(ds, sel_eps, p)[0].sum() for p in preds]
        out, t = alts[int(np.argmin(sse))]
        ok, sse_new = switch_pays(eng, ds, sel_eps, vis_eps, train_segs, effs, t.effects(),
                                  float(sse_cur.sum()), base_sse, cfg, floor_rms, rng)
        if not ok:
            break
        added = [n for n in t.structure.effects if n not in current.effects]
        line += (f"; exchange: {' + '.join(added) or 'nothing'} in {out}'s place, refitted "
                 f"(select MSE {100 * (1 - sse_new.sum() / sse_cur.sum()):.0f} % lower)")
        current, cur_x, sse_cur = t.structure, t.x, sse_new
    return current, cur_x, sse_cur, line


def prune_refitted(eng, ds: Dataset, sel_eps: Sequence[Window], train_segs: Sequence[Window],
                   current: fitmod.Structure, cur_x: np.ndarray, fit_fn: fitmod.ResidualFn,
                   cfg: GapConfig, ctx: fitmod.Context) -> tuple[fitmod.Structure, np.ndarray, str]:
    """Drop the effects of ``current`` (values ``cur_x``) that the others, refitted, do without.

    For each effect of a model of two or more: the model without it, every other parameter
    refitted on ``fit_fn`` (the training segments) from the model's values. Its rise is the
    relative rise of the squared error over the model's, the smallest of the select split, each
    goal-shift probe (``GapConfig.probes``) and the training segments, as ``analyze._backward``
    judges an effect, but with the others refitted. The effect with the smallest rise goes when
    that rise is below ``min_gain / 2`` and its reduced refit is plausible (no fit on a
    parameter bound); repeated while one goes. Returns (structure, values, report line: empty
    when nothing was dropped)."""
    line = ""
    while len(current.effects) > 1:
        effs = current.to_effects(cur_x)
        tracks = []
        for out in current.effects:
            s = fitmod.Structure.build(tuple(n for n in current.effects if n != out),
                                       current.joints, ctx)
            tracks.append(fitmod.Track(s, s.u(s.values_from(effs)), label=f"without {out}"))
        fitmod.lockstep_lm(tracks, fit_fn, cfg.max_rounds, jacobian_at_end=False)
        cols = [effs, *(t.effects() for t in tracks)]
        sel = [mse_by_episode(ds, sel_eps, p)[0].sum() for p in eng.predict(sel_eps, cols)]
        rise = [s / max(sel[0], 1e-300) - 1 for s in sel[1:]]
        for f in cfg.probes:
            sp = [mse_by_episode(ds, sel_eps, p)[0].sum()
                  for p in eng.rep.run(sel_eps, cols, goal_shift=f * ds.timestep)[0]]
            rise = [min(r, s / max(sp[0], 1e-300) - 1) for r, s in zip(rise, sp[1:], strict=True)]
        tr = [float(r @ r) for r in eng.residuals(train_segs, cols)]
        rise = [min(r, s / max(tr[0], 1e-300) - 1) for r, s in zip(rise, tr[1:], strict=True)]
        ok = [k for k, t in enumerate(tracks) if rise[k] < 0.5 * cfg.min_gain and not any(
            bound_flags(t.structure, t.u, n) for n in t.structure.effects)]
        if not ok:
            break
        k = min(ok, key=lambda i: rise[i])
        out = current.effects[k]
        line += (f"; {out} dropped: the others refitted without it raise the error by "
                 f"{100 * rise[k]:.1f} % (< {50 * cfg.min_gain:g} %)")
        current, cur_x = tracks[k].structure, tracks[k].x
    return current, cur_x, line
