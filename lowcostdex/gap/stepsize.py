"""The physics step a gap analysis replays at: the model's, or finer when the logs need it.

``refine`` halves the model's step while the NOMINAL replay gets much closer to the data (before
any cause is sought). ``refine_fitted`` asks the same of the model with its accepted effects,
refitted at each finer step: a large hidden effect hides the step's error from the nominal test.
Measured on the third truth simulator (``tests/gap_truth_sim3.py``, 2026-11-26): srv_latency080's
nominal replay RMSE is 300.8 mrad at 2 ms and 299.2 at 1 ms (the 80 ms latency dominates, no
refinement), while with the latency fitted at each step it is 2.69 / 2.07 / 1.79 mrad at 2 / 1 /
0.5 ms (floor 0.82); at 2 ms the analysis accepted a 3 % gain_error as a second cause (select
MSE 56 % lower: it made up for the coarse step), and the fitted delay moves 80.47 -> 80.11 ->
79.92 ms with the step (fin_latency60_prox: 60.55 -> 60.20 -> 60.00 ms, truth 60). With this
test both analyse at 0.5 ms and name the latency alone: 79.92 [79.62, 80.23] ms and 59.99 [59.72,
60.27] ms (held-out 216 -> 1.11 mrad, floor 0.82; 54.0 -> 0.66 mrad, floor 0.68).

A goal's instant is known to the physics step only (``goal_timing``): the replay applies each
goal at its logged time (step means), a servo at its next control tick, up to a tick later; no
replay at step h tells a lag below h (the latency's floor). Measured on the second truth
simulator's gain_viscous_turntable (goals act at the truth's next 0.25 ms step): the fitted gain
moves 0.0043 (0.6 %) per 0.125 ms of goal timing, 3.4 %/ms, while its data interval (+-0.0009)
held the timing to +-0.03 ms and missed the truth 0.7 by 0.0002 (0.6989 [0.6981, 0.6998]).
A play is structural when the joint's fast motion crosses it within one physics step
(``play_factor``): the replay then resolves neither its crossing nor its impacts, and the play
barely pays at the model's step while it pays well at a finer one. Measured (gap-arm19, session
24, sim9's arm: the elbow's 10 mrad play, its 99th percentile speed 11.2 rad/s, 22 mrad per 2 ms
step; the true torque limit and offset held): the true play lowers the select MSE 13.5 / 32.7 /
40.8 % at 2 / 1 / 0.5 ms, and a fit of it at 2 ms (elbow 8.0 mrad, shoulder 4.5) was 7.9 % worse
at 2 ms, 32.4 % better at 0.5 ms. With ``GapConfig.play_step`` (on by default since session 26),
when a round's backlash fit has such a play and the round does not accept it, the analysis tries
the round again at the step where the joint's fast motion
takes a step or more to cross the play (``gap.analyze``; the model it has refitted there: ``refit``).

Errors in rad^2 (mean squares), steps in s.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.gap.diagnostics import noise_floor
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.results import GapConfig
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.servo import ServoClock

__all__ = ["at_factor", "finer_enough", "goal_timing", "on_servo_period", "play_factor", "refine",
           "refine_fitted", "refit", "timing_move"]

FAST = 99.0      # percentile of a joint's logged |velocity| that is its fast motion
RESOLVED = 4.0   # a play narrower than this many noise floors is not one the readings resolve


def finer_enough(mse: float, finer: float, floor_mse: float, cfg: GapConfig) -> bool:
    """Whether a halved step pays: it removes ``refine_gain`` of the MSE above the noise
    floor's (what a model can explain) and ``min_gain`` of all of it (not a wiggle at the
    floor)."""
    return (finer - floor_mse <= (1 - cfg.refine_gain) * (mse - floor_mse)
            and finer <= (1 - cfg.min_gain) * mse)


def on_servo_period(ds: Dataset) -> Dataset:
    """The data set on a step of at most half its servo update period (halving the model's):
    a force held for the period then spans two steps or more (at a step as long as the period
    the hold is one explicit force per step)."""
    f = 1.0
    while ds.servo_period and ds.timestep * f > ds.servo_period / 2 * (1 + 1e-9):
        f /= 2
    return ds if f == 1.0 else ds.with_timestep(f)


def refine(ds: Dataset, eps: Sequence[Window], cfg: GapConfig) -> tuple[Dataset, dict]:
    """The data set on the finest useful physics step (``GapConfig.refine_step``): halve the
    step while the nominal replay of ``eps`` gets closer to the data (``finer_enough``), down
    to ``min_step``. Returns (data set, the timestep record of ``GapResult.timestep``)."""
    floor_mse = float(np.mean(noise_floor(ds.trajectories) ** 2))
    dt_model = ds.timestep
    ds = on_servo_period(ds)
    dt0 = ds.timestep

    def replay(d: Dataset) -> float:
        (pred,), _ = Replayer(d, nthread=cfg.nthread).run(eps, [[]])
        res = np.concatenate([(d.trajectories[w.traj].qpos[w.score_from:w.stop]
                               - p[w.score_from - w.start:]).ravel()
                              for w, p in zip(eps, pred, strict=True)])
        return float(np.mean(res ** 2))

    cur = ds
    mse = replay(ds)
    tried = [(dt0, math.sqrt(mse))]
    while cur.timestep / 2 >= cfg.min_step * (1 - 1e-9):
        finer = ds.with_timestep(cur.timestep / 2 / dt0)
        m2 = replay(finer)
        tried.append((finer.timestep, math.sqrt(m2)))
        if not finer_enough(mse, m2, floor_mse, cfg):
            break
        cur, mse = finer, m2
    return cur, {"model": dt_model, "used": cur.timestep, "rmse": tried,
                 "servo_period": ds.servo_period}


def refine_fitted(ds: Dataset, residual_fn, s: fitmod.Structure, x: np.ndarray,
                  ctx: fitmod.Context, cfg: GapConfig, floor_mse: float
                  ) -> tuple[Dataset, fitmod.Context, fitmod.Structure, np.ndarray, list] | None:
    """The accepted model ``s`` at ``x`` on a finer step when that pays (``finer_enough``,
    halving down to ``min_step``), its effects refitted at each step tried (from their values,
    delays scanned over +-1 step: ``fit.polish``). ``residual_fn(ds)`` gives the fit's residual
    function on data set ``ds`` (the training segments). None when the step stays; else (data
    set, context with its step, structure, values, [(step, RMS)] tried)."""
    def fitted(d: Dataset, c: fitmod.Context, x0: np.ndarray):
        return refit(s, x0, residual_fn(d), c, cfg)

    dt0 = ds.timestep
    best = None
    cur_ds, cur_x = ds, x
    r = residual_fn(ds)([(s, x)])[0]
    mse = float(np.mean(r * r))
    tried = [(dt0, math.sqrt(mse))]
    while cur_ds.timestep / 2 >= cfg.min_step * (1 - 1e-9):
        d2 = ds.with_timestep(cur_ds.timestep / 2 / dt0)
        c2 = replace(ctx, dt=d2.timestep)
        st, x2, m2 = fitted(d2, c2, cur_x)
        tried.append((d2.timestep, math.sqrt(m2)))
        if not finer_enough(mse, m2, floor_mse, cfg):
            break
        cur_ds, cur_x, mse = d2, x2, m2
        best = (d2, c2, st, x2)
    # the servos' update period: a firmware samples its position law and holds the force
    # (``sim.servo.ServoClock``); a continuous law is a stiffer servo whose error the first
    # cause absorbs (srv_gain25_posonly: gain 2.594 [2.573, 2.616] for 2.5 plus a mass error),
    # so the period is tried with the accepted model refitted, and kept when it pays as a
    # finer step must against the continuous law at the same step (a step the period forces
    # finer is not credited to the period)
    for period in cfg.servo_periods if not ds.servo_period and _holds(cur_ds) else ():
        d2 = on_servo_period(dataclasses.replace(cur_ds, servo_period=period))
        c2 = replace(ctx, dt=d2.timestep)
        ref = mse
        if d2.timestep < cur_ds.timestep:
            d_cont = cur_ds.with_timestep(d2.timestep / cur_ds.timestep)
            ref = fitted(d_cont, c2, cur_x)[2]
            tried.append((d2.timestep, math.sqrt(ref)))
        st, x2, m2 = fitted(d2, c2, cur_x)
        tried.append((d2.timestep, math.sqrt(m2)))
        if finer_enough(ref, m2, floor_mse, cfg) and m2 < mse:
            cur_ds, cur_x, mse = d2, x2, m2
            best = (d2, c2, st, x2)
    return None if best is None else (*best, tried)


def refit(s: fitmod.Structure, x: np.ndarray, fn: fitmod.ResidualFn, ctx: fitmod.Context,
          cfg: GapConfig) -> tuple[fitmod.Structure, np.ndarray, float]:
    """The model ``s`` at ``x`` refitted on the residual function ``fn`` of a data set on the
    step ``ctx.dt`` (from its values, delays scanned over +-1 step: ``fit.polish``): (structure
    rebuilt for ``ctx``, values, MSE of ``fn``'s residual; NaN for a model without effects,
    returned as it is)."""
    if not s.effects:
        return s, x, math.nan
    st = fitmod.Structure.build(s.effects, s.joints, ctx)
    t = fitmod.Track(st, st.u(st.values_from(s.to_effects(x))), label="finer step")
    fitmod.lockstep_lm([t], fn, cfg.max_rounds // 2, jacobian_at_end=False)
    if fitmod.polish(t, fn, ctx.dt):
        fitmod.lockstep_lm([t], fn, cfg.max_rounds // 4, jacobian_at_end=False)
    return st, t.x, 2 * t.cost / max(len(t.r), 1)


def play_factor(ds: Dataset, play: AppliedEffect | None, min_step: float) -> float | None:
    """The factor (a power of 1/2) on ``ds``'s step at which every structural play of ``play``
    (a fitted backlash) takes a step or more of its joint's fast motion to cross: width >=
    the ``FAST`` percentile of the logged |velocity| x step, halving down to ``min_step``. A
    play narrower than ``RESOLVED`` noise floors is not counted. None when no play is
    structural at ``ds``'s step (or the step is at ``min_step``)."""
    if play is None:
        return None
    cols = [list(ds.joints).index(j) for j in play.joints]
    v = np.concatenate([np.abs(tr.qvel[:, cols]) for tr in ds.trajectories])
    fast = np.percentile(v, FAST, axis=0)
    floor = noise_floor(ds.trajectories)[cols]
    f = 1.0
    for w, speed, fl in zip(np.asarray(play.values["width"], float), fast, floor, strict=True):
        while (w >= RESOLVED * fl and w < speed * ds.timestep * f
               and ds.timestep * f / 2 >= min_step * (1 - 1e-9)):
            f /= 2
    return None if f == 1.0 else f


def at_factor(ds: Dataset, ctx: fitmod.Context, factor: float
              ) -> tuple[Dataset, fitmod.Context]:
    """``ds`` and ``ctx`` on ``factor`` times ``ds``'s physics step."""
    ds = ds.with_timestep(factor)
    return ds, replace(ctx, dt=ds.timestep)


def _holds(ds: Dataset) -> bool:
    """Whether a logged actuator is one a servo update period acts on."""
    m = ds.compiled(ds.trajectories[0].model)
    acts = [m.actuator(a).id for a in ds.actuators]
    return bool(np.any(ServoClock(m).holdable[acts]))


def timing_move(t: fitmod.Track, late: fitmod.ResidualFn, fraction: float = 0.5) -> np.ndarray:
    """How far the fitted track ``t`` moves (optimizer coordinates) when every goal acts one
    physics step later, linearised: ``late`` is the residual function of ``t``'s data with every
    goal ``fraction`` of a step later; the Gauss-Newton move -J^+ (r_late - r) (J, r: ``t``'s
    Jacobian and residual at its optimum, where J^T r = 0), divided by ``fraction``. One replay,
    no refit. Zeros when ``t`` has no Jacobian or a non-finite residual or Jacobian."""
    zero = np.zeros(len(t.u))
    if t.jac is None or t.r is None or not t.structure.free:
        return zero
    dr = late([(t.structure, t.x)])[0] - t.r
    if not (np.all(np.isfinite(dr)) and np.all(np.isfinite(t.jac))):
        return zero
    du = -np.linalg.lstsq(t.jac, dr, rcond=None)[0]
    return np.where(np.isfinite(du), du, 0.0) / fraction


def goal_timing(t: fitmod.Track, late: fitmod.ResidualFn, mid: np.ndarray, half: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """A 95 % interval (centre ``mid``, half-width ``half``, optimizer coordinates) widened to
    hold every goal lag in [0, one physics step]: the fit moves by ``timing_move`` m over that
    range (linear in the lag), so the interval is the hull of the old one and the old one moved
    by m: centre + m / 2, half-width + |m| / 2. A servo acts on a goal at its next control tick
    (never before the host wrote it), so the lag is one-sided; ``late`` as in ``timing_move``."""
    move = timing_move(t, late)
    return np.asarray(mid, float) + move / 2, np.asarray(half, float) + np.abs(move) / 2
