"""The gap analysis: replay, show what is wrong, name the cause(s), extend the model, measure gain.

``analyze(dataset, config)`` runs the whole loop:

1. Episodes (whole logs, or chunks of long ones) are split into train / select / test.
2. The nominal model replays every episode open loop; residual diagnostics and the noise floor
   describe what it gets wrong.
3. Forward selection (what a round fits and how the select split judges it:
   ``gap.selection``). Each round ranks the remaining candidate effects by their score statistic
   (the share of the training residual their sensitivity explains), fits the best ``top_k`` (and
   any whose score ties the best's) jointly with the effects already chosen (lockstep bounded LM on multiple-shooting training segments,
   multi-start where non-convex), and replays the fitted candidates open loop on the *select*
   episodes. A candidate whose fit lands on a search bound and would otherwise beat the best
   in-range one is refitted in a range widened toward the parameter's physical hard limit
   (``fit.widen``; the report says so). The best one is accepted only if it lowers the select
   error by at least ``min_gain`` (relative MSE), the bootstrap over select episodes does not show
   it clearly worse (5th percentile of the gain above -``min_gain``), it changes the predictions
   by more than ``min_effect`` noise floors, its fit is not at a parameter bound it may not
   leave, and the current train or select error is above the noise floor. The gain must be
   robust too: ``min_gain`` on the training segments it was fitted to (a fit's in-sample gain
   is, in expectation, at least its held-out one) and on the select split replayed with every
   goal a fraction of a physics step later (``GapConfig.probes``; a chaotic replay, a light link
   swinging inside a play, rewards lucky alignments of its impacts). Otherwise the analysis
   stops; with no accepted effect the answer is "no significant discrepancy" (nothing is sought
   when the nominal model, or later the model with its accepted causes, is within
   ``explain_above`` noise floors; after the first accepted cause the physics step is refined when
   that model, refitted, gets much closer at a finer step, and the first cause is then chosen
   again at that step: ``stepsize``; a round that does not accept the play its backlash fit
   finds, one its joint's motion crosses within a step, is tried once more at a finer step
   (``GapConfig.play_step``: ``stepsize.play_factor``; then no backward search). A change of model must pay
   over consecutive blocks of select data too (``significance``: paired block bootstrap > 0).
4. An effect the others, refitted, do as well without is dropped (``exchange.prune_refitted``).
   The chosen structure is refitted on train + select; an effect whose every 95 % interval
   (misfit-aware: ``_intervals``) holds "no effect" is dropped and the rest refitted. The model
   is then scored once on the untouched *test* episodes: error before and after with a
   bootstrap interval over episodes, the noise floor and the fraction of reducible error
   explained.

Why one module: these stages are one loop over one analysis' state (the split, the engine's
replays, the current structure and its select error, the stop reason); the helpers below are the
loop's own steps (ranking, backward pass and search, effect size, interval blocks). What a round
fits and how the select split judges a candidate live in ``gap.selection``, the fits in
``gap.fit``, the report in ``gap.results``.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from lowcostdex.gap import chaos, gates, play_side, significance, standin, stepsize, width_scan
from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.dataset import Dataset, Window, episodes, segments, split_episodes
from lowcostdex.gap.dataset import actuator_columns as _act_cols
from lowcostdex.gap.dataset import subset as _subset
from lowcostdex.gap.dataset import traces as _traces
from lowcostdex.gap.diagnostics import (
    effective_n,
    noise_floor,
    per_log,
    residual_diagnostics,
    score_fraction,
    session_drift,
)
from lowcostdex.gap.exchange import effect_size, prune_refitted, replace_standins, switch_pays
from lowcostdex.gap.gain import episode_errors, gain_with_ci
from lowcostdex.gap.gates import drop_weak, free_asymmetry, hold_sensor, swap_equivalent
from lowcostdex.gap.offer import available_candidates
from lowcostdex.gap.ramps import uncapped_velocity
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.results import (
    UNEXPLAINED,
    CandidateResult,
    Cause,
    GapConfig,
    GapResult,
    bound_flags,
    param_report,
    servo_keyed,
)
from lowcostdex.gap.selection import fit_batches, mse_by_episode, probe_gains, select_results
from lowcostdex.gap.selection import nothing_to_explain as _nothing_left
from lowcostdex.gap.stepsize import refine as _refine_step
from lowcostdex.sim.effects import CAUSES, AppliedEffect, Targets, effect
from lowcostdex.sim.mjwarnings import collect_mujoco_warnings

__all__ = ["UNEXPLAINED", "CandidateResult", "Cause", "GapConfig", "GapResult", "analyze",
           "available_candidates"]

Progress = Callable[[str, float], None]

class _Engine:
    """Replays and residuals shared by the stages of one analysis."""

    def __init__(self, ds: Dataset, cfg: GapConfig, candidates: Sequence[str]):
        self.ds, self.cfg = ds, cfg
        self.rep = Replayer(ds, candidates, nthread=cfg.nthread)
        self.joints = ds.effect_joints

    def predict(self, windows: Sequence[Window], columns: Sequence[Sequence[AppliedEffect]]
                ) -> list[list[np.ndarray]]:
        return self.rep.run(windows, columns)[0]

    def residuals(self, windows: Sequence[Window], columns, goal_shift: float = 0.0) -> list:
        """Scored residual vectors (measured - predicted), one per column (goals shifted [s])."""
        pred = self.rep.run(windows, columns, goal_shift=goal_shift)[0]
        out = []
        for col in pred:
            parts = []
            for w, p in zip(windows, col, strict=True):
                tr = self.ds.trajectories[w.traj]
                off = w.score_from - w.start
                parts.append((tr.qpos[w.score_from:w.stop] - p[off:]).ravel())
            out.append(np.concatenate(parts))
        return out

    def residual_fn(self, windows: Sequence[Window], goal_shift: float = 0.0) -> fitmod.ResidualFn:
        def fn(points):
            cols = [s.to_effects(x) for s, x in points]
            return self.residuals(windows, cols, goal_shift)
        return fn


def analyze(ds: Dataset, config: GapConfig | None = None, progress: Progress | None = None
            ) -> GapResult:
    """Run the gap analysis on a data set (see the module docstring).

    Args:
      ds: nominal model(s) and measured trajectories (``load_dataset(logs, model=...)``).
      config: settings (None: ``GapConfig()``).
      progress: optional callback (stage description, fraction done in [0, 1]).
    """
    if not isinstance(ds, Dataset):
        raise TypeError(f"analyze takes a Dataset, not {type(ds).__name__}: read the logs "
                        "first, e.g. analyze(load_dataset(['log_0.csv', ...], "
                        "model='model.xml'))")
    if config is not None and not isinstance(config, GapConfig):
        raise TypeError(f"config must be a GapConfig, not {type(config).__name__}")
    with collect_mujoco_warnings() as warned:  # counted for the report, not printed
        result = _analyze(ds, config if config is not None else GapConfig(),
                          progress or (lambda s, f: None))
    result.mujoco_warnings = warned.as_dict()
    return result


def _analyze(ds: Dataset, cfg: GapConfig, prog: Progress) -> GapResult:
    t_start = time.perf_counter()
    timing: dict[str, float] = {}
    rng = np.random.default_rng(cfg.seed)
    blk_rng = np.random.default_rng([cfg.seed, 1])  # block bootstraps (leave ``rng`` as it was)
    eps = episodes(ds, cfg.chunk)
    split = split_episodes(ds, eps, rng, cfg.test_logs)
    timestep = {"model": ds.timestep, "used": ds.timestep, "rmse": []}
    if cfg.refine_step:
        ds, timestep = _refine_step(ds, [eps[i] for i in split.train + split.select], cfg)
    cands = available_candidates(ds, cfg.candidates)
    eng = _Engine(ds, cfg, cands)
    joints = eng.joints
    m0 = eng.rep.models[ds.trajectories[0].model]
    targets = Targets.resolve(m0, joints)
    train_eps = [eps[i] for i in split.train]
    sel_eps = [eps[i] for i in split.select]
    test_eps = [eps[i] for i in split.test]
    train_segs = segments(ds, train_eps, cfg.segment, cfg.burn_in)

    # ---- 1. baseline replay and diagnostics --------------------------------------------------
    prog("baseline replay", 0.02)
    base_pred, peaks = eng.rep.run(eps, [[]], force_peak=True)
    base_pred = base_pred[0]
    floor = noise_floor(ds.trajectories)
    floor_mse = float(np.mean(floor ** 2))
    split, sel_eps = chaos.scored_select(eng.rep.run, ds, eps, split, base_pred, floor_mse)
    jcols = [list(ds.joints).index(j) for j in joints]
    diagnostics = {j: residual_diagnostics(ds.trajectories, eps, base_pred, c)
                   for j, c in zip(joints, jcols, strict=True)}
    timing["baseline"] = time.perf_counter() - t_start
    ctx = fitmod.Context(
        dt=ds.timestep,
        peak_force=np.asarray(peaks[0])[_act_cols(ds, targets, m0)],
        **fitmod.servo_facts(m0, targets.actuators),
        damping=m0.dof_damping[targets.dofs].copy())

    # ---- 2. forward selection ------------------------------------------------------------------
    current, cur_x = fitmod.Structure((), joints), np.zeros(0)
    sel_cur = mse_by_episode(ds, sel_eps, [base_pred[i] for i in split.select])
    floor_rms = math.sqrt(floor_mse)
    def judged_quiet(ds, base_pred) -> bool:  # the nominal within explain_above floors
        return _nothing_left(ds, train_eps + sel_eps, [base_pred[i] for i in split.train
                             + split.select], floor, cfg.explain_above, m0)
    quiet = judged_quiet(ds, base_pred)  # no cause
    rounds: list[list[CandidateResult]] = []
    fit_fn = eng.residual_fn(train_segs)
    stop_reason = "max_effects reached"
    equivalents: dict[str, list[str]] = {}
    widened_notes: dict[str, list[str]] = {}  # accepted effect -> widened-range report lines
    step, reselect, warm = 0, cfg.refine_step, {}  # the first cause chosen again at a finer step
    play_fit, play_try = None, None  # a round's backlash fit; a round tried again for its play
    while step < cfg.max_effects:
        remaining = [c for c in cands if c not in current.effects]
        if not remaining:
            stop_reason = "no candidates left"
            break
        t0 = time.perf_counter()
        prog(f"round {step + 1}: ranking {len(remaining)} candidates", 0.1 + 0.25 * step)
        if play_try:  # the round again at a finer step for its play: ranked as it was
            table, train_rms = [copy.copy(c) for c in play_try[8]], play_try[9]
        else:
            table, train_rms = _rank(eng, _subset(ds, train_segs, cfg.rank_seconds), current,
                                     cur_x, remaining, ctx)
            table.sort(key=lambda c: -c.score)
        rounds.append(table)
        cur_mse = sel_cur[0].sum() / sel_cur[2].sum()
        near = (cfg.floor_margin ** 2) * floor_mse
        if not play_try and ((cur_mse <= near and train_rms ** 2 <= near) or (step == 0 and quiet)):
            stop_reason = (f"the nominal model's train + select RMSE is within {cfg.explain_above:g}"
                           " noise floors: nothing to explain" if step == 0 and quiet else
                           "train and select errors at the noise floor")
            break
        if table[0].score < cfg.min_gain:
            stop_reason = "no candidate signature explains the residual"
            break
        fixed = current.to_effects(cur_x) if current.effects else []
        r_cur = eng.residuals(train_segs, [list(fixed)])[0]
        train_sse = float(r_cur @ r_cur)
        if step and not play_try and (sel_cur[0].sum() + train_sse) <= (
                cfg.explain_above ** 2 * floor_mse * (sel_cur[2].sum() + len(r_cur))):
            stop_reason = (f"the model with {', '.join(current.effects)} is within "
                           f"{cfg.explain_above:g} noise floors on train + select: nothing more "
                           "to explain")
            quiet = True  # ... and no backward search either (its switch would be as small)
            break
        stop, play_fit = "", None
        for pool in (fit_batches(table, cfg) if not play_try else  # a structural play: it and
                     [[c for c in table if c.effect in warm]]):  # the round's winner, finer step
            if not pool:
                break
            tracks = [t for c in pool for t in play_side.tracks(  # (a round chosen again starts
                c.effect, joints, ctx, fixed, warm.get(c.effect), cfg.play_step)]  # from its fits)

            def on_round(r, live, step=step):
                prog(f"round {step + 1}: fitting {live} tracks (LM round {r + 1})",
                     0.1 + 0.25 * step + 0.2 * (r + 1) / cfg.max_rounds)

            fitmod.lockstep_lm(tracks, fit_fn, cfg.max_rounds, on_round=on_round,
                               prune=fitmod.prune_tracks, jacobian_at_end=False)
            best_track: dict[str, fitmod.Track] = {}
            for t in tracks:
                name = t.structure.effects[-1]
                if name not in best_track or t.cost < best_track[name].cost:
                    best_track[name] = t
            # limits from the flat side of their cost, delays to the best physics-step phase (the
            # cost is piecewise smooth in a delay: LM stops at a kink, seen 22.7 ms for 18.8 ms)
            rescued = [t for t in best_track.values()
                       if fitmod.scan_limits(t, fit_fn) | fitmod.scan_scales(t, fit_fn)
                       | fitmod.polish(t, fit_fn, ds.timestep)]
            if rescued:
                fitmod.lockstep_lm(rescued, fit_fn, cfg.max_rounds // 2, jacobian_at_end=False)
            if current.effects:
                # joint refits (earlier effects free again) of the most promising candidates
                joint_tracks = []
                for n in sorted(best_track, key=lambda n: best_track[n].cost)[:cfg.joint_k]:
                    js = fitmod.Structure.build(current.effects + (n,), joints,
                                                ctx.with_ranges(best_track[n].structure.held_ranges))
                    x0 = js.values_from(best_track[n].effects())
                    joint_tracks.append(fitmod.Track(js, js.u(x0), label=f"{n}+joint"))
                prog(f"round {step + 1}: joint refit of {len(joint_tracks)} candidates",
                     0.1 + 0.25 * step + 0.2)
                fitmod.lockstep_lm(joint_tracks, fit_fn, cfg.max_rounds, jacobian_at_end=False)
                for t in joint_tracks:
                    n = t.structure.effects[-1]
                    if t.cost < best_track[n].cost:
                        best_track[n] = t
            play_side.settle_sensor(play_fit := best_track.get("backlash", play_fit), fit_fn)
            gates.settle_untold(best_track, fit_fn, cfg.min_gain)  # a bound no data ask for
            widened = free_asymmetry(best_track, fit_fn, ctx, cfg)  # held terms data need
            names = list(best_track)
            results = select_results(eng.predict, ds, sel_eps, best_track, names, sel_cur,
                                     rng, cfg)
            # a fit on a bound beating every in-range fit (real sizes lie beyond): widen, refit
            top_in = max((results[n][0] for n in names
                          if not bound_flags(best_track[n].structure, best_track[n].u, n)),
                         default=-math.inf)
            for n in names:
                t = best_track[n]
                if results[n][0] > top_in and bound_flags(t.structure, t.u, n):
                    prog(f"round {step + 1}: {n} on a bound, refit in a wider range",
                         0.1 + 0.25 * step + 0.22)
                    t, ranges, notes = fitmod.widen_and_refit(t, fit_fn, ctx, cfg.max_rounds)
                    if ranges:
                        best_track[n], widened[n] = t, (ranges, notes)
            if widened:
                results.update(select_results(eng.predict, ds, sel_eps, best_track,
                                              list(widened), sel_cur, rng, cfg))
            play_side.keep(best_track, widened)  # a play read on the motor side stays there
            by_name = {c.effect: c for c in table}
            for n in names:
                rel, low, sse = results[n]
                c, t = by_name[n], best_track[n]
                c.widened = [line for _, line in widened.get(n, ({}, []))[1]]
                c.fitted = True
                c.train_rmse = math.sqrt(2 * t.cost / max(len(t.r), 1))
                c.select_rmse = math.sqrt(sse.sum() / sel_cur[2].sum())
                c.select_gain = rel
                c.params = {p: v.tolist() for e in t.effects() if e.name == n
                            for p, v in e.values.items()}
            # candidates the select split cannot tell apart from the best (within ``tie`` of its
            # MSE) are equivalent: the earliest in the canonical list is named, the rest reported
            # a fit that ends at a (non-null) bound is not a plausible explanation (04-sysid.md
            # 4.3 (b)): it compensates for something else; such candidates are not named
            plausible = {n: r for n, r in results.items()
                         if not bound_flags(best_track[n].structure, best_track[n].u, n)}
            for n in set(results) - set(plausible):
                by_name[n].at_bound = True
            if not plausible:
                stop = ("every fitted candidate ended at a parameter bound (at its hard "
                        "limit, or not the best fit)")
                continue
            top_gain = max(r[0] for r in plausible.values())
            tied = [n for n in plausible
                    if (1 - plausible[n][0]) <= (1 - top_gain) * (1 + cfg.tie) + 1e-12]
            n_best = min(tied, key=lambda n: CAUSES.index(n))
            rel, low, sse = results[n_best]
            size = effect_size(eng.predict, train_eps + sel_eps, current.to_effects(cur_x)
                               if current.effects else [], best_track[n_best].effects())
            by_name[n_best].effect_rms = size
            significant = rel >= cfg.min_gain and low > -cfg.min_gain
            if significant:  # ... and over consecutive blocks of select data (paired)
                by_name[n_best].select_gain_low = low = significance.paired_low(
                    eng.predict, ds, sel_eps, current.to_effects(cur_x) if current.effects
                    else [], best_track[n_best].effects(), cfg.interval_block, blk_rng,
                    cfg.bootstrap, floor)
                significant = low > 0
            if not significant:
                stop = "no candidate lowers the select error significantly"
                continue
            if size < cfg.min_effect * floor_rms:
                stop = "the best candidate changes predictions by less than the noise floor"
                break
            train_gain = 1 - 2 * best_track[n_best].cost / max(train_sse, 1e-300)
            probe = probe_gains(eng.rep.run, ds, sel_eps, current.to_effects(cur_x)
                                if current.effects else [], best_track[n_best].effects(),
                                cfg.probes)
            if min([train_gain, *probe]) < cfg.min_gain:  # probes may be ()
                stop = (f"the best candidate ({n_best}, select MSE {100 * rel:.0f} % lower) "
                        f"lowers the training error by {100 * train_gain:.1f} % and the select "
                        f"error with goals a fraction of a step later by "
                        f"{', '.join(f'{100 * g:.0f}' for g in probe)} %: not robust")
                continue
            stop = ""
            break
        if cfg.play_step and play_try is None and play_fit is not None and play_fit.cost < (
                (1 - cfg.min_gain) * train_sse / 2 if stop else best_track[n_best].cost) and (
                f := stepsize.play_factor(ds, play_fit.effects()[-1], cfg.min_step)):
            won = None if stop else (n_best, tied, widened, best_track, by_name, sse)
            play_try = (ds, ctx, eng, fit_fn, current, cur_x, sel_cur, stop, rounds.pop(),
                        train_rms, won)  # the round as it was, tried again at a finer step
            (ds, ctx), warm = stepsize.at_factor(ds, ctx, f), {"backlash": play_fit.effects()}
            warm.update({} if stop else {n_best: best_track[n_best].effects()})
            eng = _Engine(ds, cfg, cands)
            fit_fn = eng.residual_fn(train_segs)
            current, cur_x, _ = stepsize.refit(current, cur_x, fit_fn, ctx, cfg)  # at that step
            sel_cur = mse_by_episode(ds, sel_eps, eng.predict(sel_eps, [current.to_effects(cur_x)])[0])
            continue
        if stop and play_try:  # nothing at the finer step either: the round as it was
            fine, timestep["play"], warm = ds.timestep, stop, {}
            (ds, ctx, eng, fit_fn, current, cur_x, sel_cur, stop, rounds[-1], _, won), play_try = (
                play_try, ())
            if won:
                (n_best, tied, widened, best_track, by_name, sse), stop = won, ""
            else:
                stop = f"{stop} (tried again at a {fine:g} s step for its play: {timestep['play']})"
        elif play_try:  # accepted at the finer step: the analysis goes on there
            play_try, timestep["used"], timestep["play"] = (), ds.timestep, "accepted"
            base_pred = eng.rep.run(eps, [[]])[0][0]
        if stop:
            stop_reason, timing[f"round{step + 1}"] = stop, time.perf_counter() - t0
            break
        equivalents[n_best] = [n for n in tied if n != n_best]
        if n_best in widened:
            ctx.widened.update(widened[n_best][0])
            for eff, line in widened[n_best][1]:
                widened_notes.setdefault(eff, []).append(line)
        joint = fitmod.Structure.build(current.effects + (n_best,), joints, ctx)
        by_name[n_best].accepted = True
        current, cur_x, warm = joint, joint.values_from(best_track[n_best].effects()), {}
        sel_cur = (sse, sel_cur[1], sel_cur[2])
        finer = stepsize.refine_fitted(ds, lambda d: _Engine(d, cfg, cands).residual_fn(
            train_segs), current, cur_x, ctx, cfg, floor_mse) if reselect and not step else None
        timing[f"round{step + 1}"], step = time.perf_counter() - t0, step + 1
        if finer is not None:  # the step's own error, hidden by the first cause until now
            ds, ctx, _, _, timestep["fitted"] = finer
            timestep["used"], timestep["servo_period"] = ds.timestep, ds.servo_period
            eng = _Engine(ds, cfg, cands)
            fit_fn, base_pred = eng.residual_fn(train_segs), eng.rep.run(eps, [[]])[0][0]
            # ... and the first cause was chosen at a step now shown too coarse: choose it again
            # (a 0.2 rad mounting offset lost to a 4 mrad reading offset at 2 ms, won at 1 ms)
            timestep["first_at_coarse_step"] = current.effects[0]
            timing["round1_coarse_step"] = timing.pop("round1")
            step, reselect, current, cur_x = 0, False, fitmod.Structure((), joints), np.zeros(0)
            warm = {c.effect: [AppliedEffect(c.effect, joints, {p: np.asarray(v) for p, v in
                    c.params.items()})] for c in rounds.pop() if c.fitted and c.params}
            equivalents, widened_notes = {}, {}
            sel_cur = mse_by_episode(ds, sel_eps, [base_pred[i] for i in split.select])
            quiet = judged_quiet(ds, base_pred)

    # ---- backward pass: drop accepted effects the final model no longer needs ---------------
    if len(current.effects) > 1:
        current, cur_x = _backward(eng, ds, sel_eps, current, cur_x, cfg, floor_rms, ctx,
                                   fit_fn, dropped := [], train_segs, rng=blk_rng)
        if dropped:
            stop_reason += f"; dropped by the backward pass: {', '.join(dropped)}"
            sel_cur = (mse_by_episode(ds, sel_eps, eng.predict(
                sel_eps, [current.to_effects(cur_x)])[0])[0], sel_cur[1], sel_cur[2])

    # ---- backward search: the top-ranked candidates fitted together, then pruned ------------
    # Effects only helping together (a friction model needs the right inertia) are invisible to
    # forward steps; the pruned joint model replaces the forward one if it gains ``min_gain``.
    fwd_rmse = math.sqrt(sel_cur[0].sum() / sel_cur[2].sum())
    searches = cfg.search == "both" and timestep.get("play") != "accepted"  # (cost at its step)
    if searches and rounds and not quiet and fwd_rmse > cfg.backward_above * floor_rms:
        t0 = time.perf_counter()
        prog("backward search from the top candidates", 0.8)
        big = tuple(dict.fromkeys(current.effects + tuple(
            c.effect for c in rounds[0][:cfg.top_k] if c.score >= cfg.min_gain)))
        if len(big) > max(len(current.effects), 1):
            alt, alt_x = _joint_then_prune(eng, ds, sel_eps, big, current, cur_x, cfg,
                                           floor_rms, ctx, fit_fn, train_segs, blk_rng)
            base_sse = mse_by_episode(ds, sel_eps, [base_pred[i] for i in split.select])[0]
            better, sse_alt = switch_pays(
                eng, ds, sel_eps, train_eps + sel_eps, train_segs, current.to_effects(cur_x),
                alt.to_effects(alt_x), sel_cur[0].sum(), base_sse, cfg, floor_rms, rng
            ) if alt.effects else (False, None)
            if better:
                stop_reason += (f"; backward search from {', '.join(big)} kept "
                                f"{', '.join(alt.effects)} (select MSE "
                                f"{100 * (1 - sse_alt.sum() / sel_cur[0].sum()):.0f} % below "
                                "the forward model's)")
                current, cur_x = alt, alt_x
                sel_cur = (sse_alt, sel_cur[1], sel_cur[2])
        timing["backward_search"] = time.perf_counter() - t0

    # ---- exchange: an accepted stand-in replaced by what the model without it needs ------
    if (searches and cfg.exchange_k and rounds and not quiet and len(current.effects) > 1
            and math.sqrt(sel_cur[0].sum() / sel_cur[2].sum()) > cfg.backward_above * floor_rms):
        t0, rsegs = time.perf_counter(), _subset(ds, train_segs, cfg.rank_seconds)
        prog("exchange: each accepted cause against what the model without it needs", 0.82)
        current, cur_x, sse, why = replace_standins(
            eng, ds, sel_eps, train_eps + sel_eps, train_segs, current, cur_x, cands,
            lambda st, x, names: _rank(eng, rsegs, st, x, names, ctx)[0], fit_fn, sel_cur[0],
            mse_by_episode(ds, sel_eps, [base_pred[i] for i in split.select])[0], cfg, ctx,
            floor_rms, np.random.default_rng([cfg.seed, 2]))
        if why:  # ... and what the exchange left redundant pruned
            sel_cur, stop_reason = (sse, sel_cur[1], sel_cur[2]), stop_reason + why
            current, cur_x = _backward(eng, ds, sel_eps, current, cur_x, cfg, floor_rms, ctx,
                                       fit_fn, dropped := [], train_segs, rng=blk_rng)
            stop_reason += f"; then dropped: {', '.join(dropped)}" if dropped else ""
        timing["exchange"] = time.perf_counter() - t0

    if len(current.effects) > 1:  # ... and an effect the others, refitted, do without
        current, cur_x, why = prune_refitted(eng, ds, sel_eps, train_segs, current, cur_x,
                                             fit_fn, cfg, ctx)
        stop_reason += why
    current, cur_x, why = swap_equivalent(current, cur_x, fit_fn, lambda ms: [mse_by_episode(
        ds, sel_eps, p)[0].sum() for p in eng.predict(sel_eps, ms)], cfg, ctx, equivalents)
    stop_reason += why  # (an effect another stands in for exactly: named by catalogue order)
    # ---- 3. final refit on train + select, intervals, significance, test once -------------
    # An effect whose every 95 % interval (misfit-aware: ``_intervals``) holds "no effect" is
    # not shown by the data: it soaks up what the model gets slightly wrong. It is dropped, the
    # rest refitted, until every kept effect is away from "no effect".
    causes: list[Cause] = []
    effects: list[AppliedEffect] = []
    final_track = None
    if current.effects:
        t0 = time.perf_counter()
        prog("final refit on train + select", 0.85)
        all_segs = segments(ds, train_eps + sel_eps, cfg.segment, cfg.burn_in)
        final_fn = eng.residual_fn(all_segs)
        while True:
            final_track = _final_fit(current, cur_x, final_fn, cfg, ctx, widened_notes, ds.timestep,
                                     lambda f=1.0, c=current.names: (eng if f == 1 else _Engine(
                                         ds.with_timestep(f), cfg, c)).residual_fn(all_segs, f * ds.timestep / 2))
            mid, half, noise, data, shift = _intervals(ds, final_track, all_segs, cfg, prog,
                                                       timing)
            margin = significance.null_margins(final_track.structure, mid, half, ctx)
            weak = [n for n in final_track.structure.effects if margin[n] <= 1]
            weak, why = gates.profile_shown(weak, final_track, final_fn, ds, all_segs, cfg, ctx)
            stop_reason += why
            if not weak:
                break
            current, cur_x, why = drop_weak(final_track, min(weak, key=margin.get), mid, half, ctx)
            stop_reason += why
            if not current.effects:
                final_track = None
                break
        effects = final_track.effects() if final_track is not None else []
        timing["final_fit"] = time.perf_counter() - t0
    prog("held-out test", 0.95)
    prefixes = [effects[:k] for k in range(1, len(effects) + 1)]
    test_pred = eng.predict(test_eps, prefixes) if prefixes else []
    base_test = [base_pred[i] for i in split.test]
    b_sse, b_sae, b_n = mse_by_episode(ds, test_eps, base_test)
    ext_pred = test_pred[-1] if test_pred else base_test
    e_sse, e_sae, e_n = mse_by_episode(ds, test_eps, ext_pred)
    gain = gain_with_ci(b_sse, e_sse, b_n, b_sae, e_sae, floor_mse, rng, cfg.bootstrap)
    baseline = episode_errors(ds, test_eps, base_test, joints=list(ds.joints))
    extended = episode_errors(ds, test_eps, ext_pred, joints=list(ds.joints))
    baseline.update(select_rmse=float(math.sqrt(
        mse_by_episode(ds, sel_eps, [base_pred[i] for i in split.select])[0].sum()
        / max(sel_cur[2].sum(), 1))))
    if final_track is not None:
        for k, e in enumerate(effects):
            c = Cause(e.name, e.joints, param_report(
                final_track.structure, final_track.u, half, e.name,
                {"interval_noise": noise, "interval_data": data}, shift, mid, ctx.slide))
            sse, sae, n = mse_by_episode(ds, test_eps, test_pred[k])
            c.heldout_rmse_after = float(math.sqrt(sse.sum() / n.sum()))
            c.heldout_mae_after = float(sae.sum() / n.sum())
            c.flags = bound_flags(final_track.structure, final_track.u, e.name)
            if e.name == "goal_profile":  # a velocity no move reaches: a lower bound only
                c.flags += uncapped_velocity(ds, e.joints, c.params)
            c.equivalent = equivalents.get(e.name, [])
            c.widened = widened_notes.get(e.name) or gates.widened_lines(ctx, e.name, joints)
            causes.append(c if ctx.shared is None else servo_keyed(c, m0, targets))
    final = eng.predict(eps, [effects])[0] if effects else base_pred  # every log, for a drift
    drift = session_drift(per_log(ds, eps, final), floor_rms, cfg.explain_above)
    verdict = standin.judge(causes, final_track, gain, stop_reason, int(np.sum(e_sse > b_sse)),
                            cfg.explain_above, drift["note"], standin.per_joint_text(
                                joints, ctx.slide, baseline, extended, ds.joints, floor))
    standin.rival_notes(causes, rounds)
    timing["total"] = time.perf_counter() - t_start
    traces = _traces(ds, test_eps, base_test, ext_pred)
    prog("done", 1.0)
    return GapResult(cfg, ds.sources or [tr.name for tr in ds.trajectories], ds.joints, split, eps,
                     floor, baseline, extended, causes, rounds, diagnostics, gain, effects,
                     verdict, timing, traces, dict(ds.models), stop_reason,
                     timestep=timestep, drift=drift,
                     residual=standin.residual_left(gain, cfg.explain_above))


def _final_fit(current: fitmod.Structure, cur_x: np.ndarray, fn, cfg: GapConfig,
               ctx: fitmod.Context, widened_notes: dict, dt: float, late=None) -> fitmod.Track:
    """``current`` refitted on ``fn`` (train + select), tighter than the screening fits (a lag's
    play sensor held at 0, ``late``; a jagged width in its valley, ``width_scan``; a bound widened)."""
    t, n = fitmod.Track(current, current.u(cur_x), label="final"), 2 * cfg.max_rounds
    fitmod.lockstep_lm([t], fn, n, rtol=1e-5)
    t = width_scan.restart(hold_sensor(t, fn, ctx, cfg, widened_notes, late, finer=True), fn, n)
    if fitmod.polish(t, fn, dt):
        fitmod.lockstep_lm([t], fn, 1)  # residual and Jacobian at the polished point (intervals)
    if fitmod.at_bounds(t.structure, t.u):
        t, ranges, notes = fitmod.widen_and_refit(t, fn, ctx, 2 * cfg.max_rounds)
        ctx.widened.update(ranges)
        for eff, line in notes:
            widened_notes.setdefault(eff, []).append(line)
    return t


def _intervals(ds: Dataset, t: fitmod.Track, segs: Sequence[Window], cfg: GapConfig,
               prog: Progress, timing: dict) -> tuple[np.ndarray, ...]:
    """95 % intervals of ``t``'s parameters in optimizer coordinates as (centre, half-width)
    and their parts: (centre, half, residual noise, data, step shift or None). Data: the
    widest of the residual-noise interval, the block spread and the autocorrelation-consistent
    sandwich over blocks; a play's width also where its cost's profile stays as low. The
    replay's discretisation: the fit moves by ``shift`` at ``interval_step`` of the step; at a
    zero step a first-order integrator's value is 1 / (1 - ``interval_step``) times that move
    away (Richardson), on either side; goals up to a step late (``stepsize.goal_timing``)."""
    noise = fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r))
    data = significance.data_halfwidths(t, significance.residual_blocks(ds, segs,
                                                                         cfg.interval_block))
    u, data = significance.profile_interval(t, lambda: _Engine(ds, cfg, t.structure.names)
                                            .residual_fn(segs), data, scan=True)
    late = _Engine(ds, cfg, t.structure.names).residual_fn(segs, ds.timestep / 2)  # goal timing
    if not cfg.interval_step:
        return (*stepsize.goal_timing(t, late, u, data), noise, data, None)
    t0 = time.perf_counter()
    prog("interval: refit at a finer physics step", 0.97)
    fine = _Engine(ds.with_timestep(cfg.interval_step), cfg, t.structure.names)
    shift = significance.step_shift(t, fine.residual_fn(segs), cfg.max_rounds, fine.ds.timestep)
    timing["interval_step"] = timing.get("interval_step", 0.0) + time.perf_counter() - t0
    return (*stepsize.goal_timing(t, late, *significance.step_interval(
        u, data, shift, cfg.interval_step)), noise, data, shift)

def _rank(eng: _Engine, segs: Sequence[Window], current: fitmod.Structure, cur_x: np.ndarray,
          remaining: Sequence[str], ctx: fitmod.Context
          ) -> tuple[list[CandidateResult], float]:
    """Score statistic of every remaining candidate at the current model (one batched pass),
    and the current model's RMS residual on these training segments [rad]."""
    cur_eff = current.to_effects(cur_x) if current.effects else []
    cols: list[list[AppliedEffect]] = [cur_eff]
    owner: list[str] = []
    nj = len(eng.joints)
    for name in remaining:
        for p in effect(name).params:
            if not p.acts(ctx.is_dcmotor):  # fitted where it acts (Structure.build)
                continue
            for j in range(nj):
                f = fitmod.space(name, p.name, j, ctx)
                null = p.null if math.isfinite(p.null) else f.hi
                probe = f.start if not math.isclose(f.start, null) else (
                    f.from_u(f.to_u(null) + 10 * f.fd) if f.log else null + 10 * f.fd)
                # secants to the start and to every extra start: their span follows the shape
                # of strongly nonlinear effects (a torque limit, a delay) better than one column
                for v in (probe, *f.extra) if f.lo < f.hi else ():  # else held at its null
                    vals = {q.name: np.full(nj, q.null) for q in effect(name).params}
                    vals[p.name][j] = v
                    amp = {"stribeck_friction": ("velocity", "static"),
                           "backlash": ("sensor", "width")}.get(name, ("", ""))
                    if p.name == amp[0]:  # a shape parameter probed with its amplitude on
                        vals[amp[1]][j] = fitmod.space(name, amp[1], j, ctx).start
                    cols.append(cur_eff + [AppliedEffect(name, eng.joints, vals)])
                    owner.append(name)
    res = eng.residuals(segs, cols)
    r0 = res[0]
    table = []
    for name in remaining:
        g = [res[i + 1] - r0 for i, o in enumerate(owner) if o == name]  # none: all held null
        table.append(CandidateResult(name, score_fraction(r0, np.stack(g, 1)) if g else 0.0))
    return table, float(np.sqrt(np.mean(r0 * r0)))


def _backward(eng: _Engine, ds: Dataset, sel_eps: Sequence[Window],
              current: fitmod.Structure, cur_x: np.ndarray, cfg: GapConfig, floor_rms: float,
              ctx: fitmod.Context, fit_fn, dropped: list[str], train_segs: Sequence[Window],
              min_size: int = 1, rng: np.random.Generator | None = None
              ) -> tuple[fitmod.Structure, np.ndarray]:
    """Remove accepted effects that a later one made redundant, then order by importance.

    An effect is redundant when leaving it out of the current model (others unchanged) raises
    the select MSE by less than ``min_gain / 2`` (on the select split, on each of its goal-shift
    probes, or on the training segments) or changes the predictions by less than
    ``min_effect`` noise floors; an effect whose fit sits at a parameter bound after widening
    (``gates.widen_at_bounds``) is implausible and goes first; so is one whose absence does not
    raise the select error significantly (the 5 % bound of the paired block bootstrap,
    ``significance.paired_gain_bound``, at or below 0). The rest are ordered by the smallest of
    those rises without them."""
    rng, tried = rng if rng is not None else np.random.default_rng([cfg.seed, 1]), set()
    while len(current.effects) > min_size:
        current, cur_x, edge = gates.widen_at_bounds(current, cur_x, fit_fn, ctx, cfg.max_rounds,
                                                     tried)
        tried |= edge
        effs = current.to_effects(cur_x)
        full = eng.predict(sel_eps, [effs])[0]
        sse_full = mse_by_episode(ds, sel_eps, full)[0].sum()
        cols = [[e for e in effs if e.name != n] for n in current.effects]
        preds = eng.predict(sel_eps, cols)
        rise, size = {}, {}
        for n, pr in zip(current.effects, preds, strict=True):
            rise[n] = mse_by_episode(ds, sel_eps, pr)[0].sum() / max(sse_full, 1e-300) - 1
            d = np.concatenate([(a - b).ravel() for a, b in zip(pr, full, strict=True)])
            size[n] = float(np.sqrt(np.mean(d * d)))
        at_bound = {f.effect for f in current.free if bound_flags(current, current.u(cur_x), f.effect)}
        # paired over consecutive blocks of select data: leaving it out must raise the error
        blk = significance.block_sse(ds, sel_eps, full, cfg.interval_block)
        low = {n: significance.paired_gain_bound(significance.block_sse(
            ds, sel_eps, pr, cfg.interval_block), blk, rng, cfg.bootstrap)
            for n, pr in zip(current.effects, preds, strict=True)}
        # ... also when every goal arrives a fraction of a step later, and on the training data
        for f in cfg.probes:
            sse_p = [mse_by_episode(ds, sel_eps, p)[0].sum() for p in eng.rep.run(
                sel_eps, [effs, *cols], goal_shift=f * ds.timestep)[0]]
            rise = {n: min(rise[n], s / max(sse_p[0], 1e-300) - 1)
                    for n, s in zip(current.effects, sse_p[1:], strict=True)}
        tr = [float(r @ r) for r in eng.residuals(train_segs, [effs, *cols])]
        rise = {n: min(rise[n], s / max(tr[0], 1e-300) - 1)
                for n, s in zip(current.effects, tr[1:], strict=True)}
        weak = [n for n in current.effects
                if rise[n] < 0.5 * cfg.min_gain or size[n] < cfg.min_effect * floor_rms
                or n in at_bound or low[n] <= 0]
        if not weak:
            order = sorted(current.effects, key=lambda n: -rise[n])
            if list(order) != list(current.effects):
                s = fitmod.Structure.build(tuple(order), current.joints, ctx)
                return s, s.values_from(effs)
            return current, cur_x
        drop = min(weak, key=lambda n: (n not in at_bound, rise[n]))
        dropped.append(drop)
        keep = tuple(n for n in current.effects if n != drop)
        s = fitmod.Structure.build(keep, current.joints, ctx)
        t = fitmod.Track(s, s.u(s.values_from(effs)), label="backward")
        fitmod.lockstep_lm([t], fit_fn, cfg.max_rounds, jacobian_at_end=False)
        current, cur_x = s, t.x
    return current, cur_x


def _joint_then_prune(eng: _Engine, ds: Dataset, sel_eps: Sequence[Window], names: tuple,
                      current: fitmod.Structure, cur_x: np.ndarray, cfg: GapConfig,
                      floor_rms: float, ctx: fitmod.Context, fit_fn, train_segs: Sequence[Window],
                      rng: np.random.Generator) -> tuple[fitmod.Structure, np.ndarray]:
    """Fit ``names`` jointly (from the forward model's values), then prune with ``_backward``."""
    big = fitmod.Structure.build(names, current.joints, ctx)
    base = big.values_from(current.to_effects(cur_x)) if current.effects else None
    tracks = [fitmod.Track(big, big.u(x0), label="big") for x0 in big.starts(base)]
    fitmod.lockstep_lm(tracks, fit_fn, 2 * cfg.max_rounds, prune=fitmod.prune_tracks,
                       jacobian_at_end=False)
    best = min(tracks, key=lambda t: t.cost)
    return _backward(eng, ds, sel_eps, best.structure, best.x, cfg, floor_rms, ctx, fit_fn, [],
                     train_segs, min_size=1, rng=rng)
