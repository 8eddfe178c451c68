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

__all__ = ["effect_size", "replace_standins", "switch_pays"]

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
