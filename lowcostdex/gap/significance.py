"""Is a fitted effect real? The statistics behind the gap analysis' keep-or-drop decisions and
the misfit-aware parts of its parameter intervals.

A model that does not fit perfectly (a coarse physics step, an effect implemented a little
differently from the truth's, an estimation error of the main effect) leaves a residual that is
systematic and autocorrelated. A small extra effect can soak some of it up and lower the error
on every stretch of data alike; its fitted value then sits a little away from "no effect" with an
interval that only knows the noise. The tests here are the ones a careful analyst applies:

- ``hac_halfwidths``: 95 % half-widths from a heteroskedasticity and autocorrelation consistent
  (Newey-West) sandwich over the scores of consecutive blocks of data, the bandwidth from the
  scores' own first-order autocorrelation (Andrews 1991, AR(1) plug-in). When the misfit is
  correlated over longer stretches than one block, neighbouring blocks pull the parameter the
  same way and the interval grows with that correlation.
- ``null_margins``: per effect, how far its fitted parameters lie from "no effect" in units of
  their interval half-widths (> 1: some 95 % interval excludes it). "No effect" is the
  parameter's null, except a torque limit, which does nothing at or above the largest force the
  model asks for (the nominal force range where the actuator has one).
- ``block_sse`` and ``paired_gain_bound``: a paired moving-block bootstrap of a change of model
  over consecutive blocks of held-out (select) data: the one-sided 95 % lower bound of the
  relative MSE reduction. Blocks keep the residual's autocorrelation; pairing removes what both
  models share.

Angles in rad, errors in rad^2; parameters in the optimizer's coordinates (``fit.Free``: the log
of scale factors).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import width_scan
from lowcostdex.gap.dataset import Dataset, Window
from lowcostdex.gap.diagnostics import effective_n
from lowcostdex.sim.effects import AppliedEffect, effect

# a change of a model's error by at most this fraction is no change (``paired_gain_bound``): far
# below any gain the analysis acts on (``GapConfig.min_gain`` 5 %, ``tie`` 0.2 %)
TIE = 1e-4
# a block whose predictions two models keep within this many noise floors holds no evidence
# between them (``paired_low``): half ``GapConfig.min_effect``'s default (0.75, the size below
# which the analysis calls a change of model no change), so an effect of min_effect's size is
# still judged by its significance and its size gate, each on its own
RESOLVE = 0.375

__all__ = ["andrews_bandwidth", "block_change", "block_sse", "data_halfwidths", "residual_blocks",
           "hac_halfwidths", "null_margins", "null_profile_rise", "paired_gain_bound",
           "paired_low", "profile_interval", "step_interval", "step_shift"]


def andrews_bandwidth(g: np.ndarray) -> float:
    """Bartlett-kernel bandwidth (in blocks) for the columns of ``g`` (nb, p), from each
    column's AR(1) fit (Andrews 1991, eq. 6.4 with unit weights): 1.1447 (alpha nb)^(1/3)."""
    nb = g.shape[0]
    if nb < 3:
        return 0.0
    num = den = 0.0
    for x in g.T:
        x = x - x.mean()
        d = float(x[:-1] @ x[:-1])
        if d <= 0:
            continue
        rho = float(np.clip(x[1:] @ x[:-1] / d, -0.97, 0.97))
        s2 = float(np.mean((x[1:] - rho * x[:-1]) ** 2))
        num += 4 * rho ** 2 * s2 ** 2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2 ** 2 / (1 - rho) ** 4
    if den <= 0:
        return 0.0
    return float(min(1.1447 * (num / den * nb) ** (1 / 3), nb - 1))


def hac_halfwidths(r: np.ndarray, jac: np.ndarray, blocks: Sequence[slice],
                   bandwidth: float | None = None) -> np.ndarray:
    """95 % half-widths of least-squares parameters from a Newey-West sandwich over blocks.

    With A = J^T J and g_b = J_b^T r_b (the blocks in their time order, centred), the
    covariance is A^-1 S A^-1 with S = sum_l w_l (G_l + G_l^T) / (1 + [l == 0]), G_l = sum_b
    g_b g_(b-l)^T and Bartlett weights w_l = 1 - l / (L + 1), times nb / (nb - p); the quantile
    is Student-t with nb / (L + 1) - p degrees of freedom (fewer independent blocks when they
    are correlated; at least 1). ``bandwidth`` L in blocks (None: ``andrews_bandwidth``).
    L = 0 is the plain block sandwich. Null directions and fewer blocks than parameters + 1
    give inf. Computed by ``fit.block_halfwidths``.
    """
    return fitmod.block_halfwidths(r, jac, blocks,
                                   andrews_bandwidth if bandwidth is None else bandwidth)


def data_halfwidths(t: fitmod.Track, blocks: Sequence[slice]) -> np.ndarray:
    """95 % half-widths of ``t``'s parameters (optimizer coordinates; ``t`` needs ``r`` and
    ``jac`` at its optimum) from the data: the widest of the residual-noise interval, the block
    spread and the autocorrelation-consistent sandwich over ``blocks``."""
    return np.maximum.reduce([fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r)),
                              fitmod.block_halfwidths(t.r, t.jac, blocks),
                              hac_halfwidths(t.r, t.jac, blocks)])


def null_profile_rise(t: fitmod.Track, residual: fitmod.ResidualFn, data: np.ndarray,
                      ctx: fitmod.Context, effects: Sequence[str], rounds: int = 2
                      ) -> dict[str, float]:
    """Per effect of ``effects`` with a ``PROFILED`` scalar that has a null: how far the cost's
    profile at "no effect" lies above ``t``'s optimum, in units of the rise a linear model's
    cost has at the edge of the data's 95 % interval (``data``: ``data_halfwidths``, the
    threshold of ``profile_interval``). The largest over the effect's scalars (any joint).
    > 1: the data exclude "no effect", whatever the linearised or smoothed interval says.

    The profile at the null: that scalar held at its null and the others refitted
    (``_profile_costs``: ``rounds`` Gauss-Newton steps, an upper bound of the profile). For a
    model linear in its parameters this is the interval test itself: the rise at the null is
    d^2 / (2 [(J^T J)^-1]_ii) for a fit d away, over half_i^2 / (2 [(J^T J)^-1]_ii). A play's
    width is not linear: the link leans on one stop under gravity and the play shows only at
    reversals, and with the loop read on the output shaft its cost is jagged in the width
    (``width_scan``). Its profile and valley intervals then reach 0 while the play's removal
    raises the error threefold (sim5 backlash2deg_pendulum_500hz_us: width 0.0299 for a 0.0349
    rad play; train + select cost 0.0186 fitted, 0.0666 without the play, interval [-0.003,
    0.040]). Effects without such a scalar are left out."""
    if t.jac is None or t.r is None:
        return {}
    ainv = np.linalg.pinv(t.jac.T @ t.jac)
    pins, names, deltas = [], [], []
    for i, f in enumerate(t.structure.free):
        if f.effect not in effects or (f.effect, f.param) not in PROFILED:
            continue
        nu = null_u(f, ctx)
        if nu is None or not math.isfinite(data[i]) or not data[i] > 0:
            continue
        pins.append((i, nu[0]))
        names.append(f.effect)
        deltas.append(0.5 * float(data[i]) ** 2 / max(float(ainv[i, i]), 1e-300))
    out: dict[str, float] = {}
    if not pins:
        return out
    for n, d, c in zip(names, deltas, _profile_costs(t, residual, pins, rounds), strict=True):
        r = (c - t.cost) / d if math.isfinite(c) else 0.0
        out[n] = max(out.get(n, -math.inf), r)
    return out


def step_interval(u: np.ndarray, data: np.ndarray, shift: np.ndarray, fraction: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A 95 % interval (centre, half-width) that holds the replay's discretisation bias.

    ``u``: values fitted at the model's physics step h; ``shift``: how far they move when
    refitted at ``fraction`` h; ``data``: the data's half-widths. For a first-order integrator
    the bias is proportional to the step, so the zero-step value is ``shift / (1 - fraction)``
    away (Richardson extrapolation). Its size is trusted, not its direction (a saturating
    servo's step error need not be monotone in the step: the independent bench's torque limit
    moved away from the truth at half the step): the interval is the fitted value +- that
    distance plus the root sum of squares of ``data`` and ``shift`` (the extrapolation's own
    uncertainty)."""
    ext = np.asarray(shift, float) / (1.0 - fraction)
    return np.asarray(u, float), np.abs(ext) + np.hypot(data, shift)


def step_shift(t: fitmod.Track, residual: fitmod.ResidualFn, max_rounds: int, dt: float
               ) -> np.ndarray:
    """``fit.step_shift`` (how far ``t`` moves when refitted on the finer replay ``residual``,
    optimizer coordinates) with its delays first scanned over +-1 finer physics step ``dt``
    [s] (``fit.polish``) and its plays' widths over +-1 and 2 of their residual-noise
    half-widths (``_scan_widths``). Levenberg-Marquardt alone did not move a delay at all
    (shift exactly 0 on redteam3 fin_latency60_prox), although the least-squares optimum moves
    from 60.55 ms at a 2 ms step to 60.20 at 1 ms and 60.00 at 0.5 ms (truth 60 ms,
    2026-11-26): the interval [60.43, 60.58] ms then ignored the integrator's bias. Nor a play's
    width (its cost is kinked, ``profile_interval``): sim2 backlash_body_turntable's width was
    0.01793 [0.01754, 0.01832] at 1 ms with a shift of exactly 0, for a truth of 0.01745, the
    best width on its training segments at the truth's own 0.25 ms step (0.0179 at 1 ms)."""
    free = t.structure.free
    if not any(f.effect == "latency" or (f.effect, f.param) == ("backlash", "width")
               for f in free):
        return fitmod.step_shift(t, residual, max_rounds)
    nt = fitmod.Track(t.structure, t.u.copy(), label=t.label + "+finer step scan")
    moved = False
    for scan in (lambda: _scan_widths(nt, residual, t), lambda: fitmod.polish(nt, residual, dt)):
        if nt.r is None:  # at the start, or restarted by the width scan
            r = residual([(nt.structure, nt.x)])[0]
            nt.r, nt.cost = r, 0.5 * float(r @ r)
        moved = scan() or moved
    if not moved:
        return fitmod.step_shift(t, residual, max_rounds)
    return fitmod.step_shift(nt, residual, max_rounds) + (nt.u - t.u)


def _scan_widths(nt: fitmod.Track, residual: fitmod.ResidualFn, t: fitmod.Track) -> bool:
    """Move ``nt`` to the lowest-cost value of each play width over ``t``'s width +- 1 and 2
    4 of its residual-noise 95 % half-widths (others fixed, one batched evaluation); returns
    whether it moved (then ``fit.restart``-ed there)."""
    idx = [i for i, f in enumerate(nt.structure.free) if (f.effect, f.param) == ("backlash", "width")]
    if not idx or t.jac is None or t.r is None:
        return False
    half = fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r))
    lo, hi = nt.structure.u_bounds()
    points, where = [], []
    for i in idx:
        if not np.isfinite(half[i]) or half[i] <= 0:
            continue
        for k in (-2.0, -1.0, 1.0, 2.0):
            u = nt.u.copy()
            u[i] = float(np.clip(u[i] + k * half[i], lo[i], hi[i]))
            points.append((nt.structure, nt.structure.x(u)))
            where.append((i, u[i]))
    if not points:
        return False
    costs = [0.5 * float(r @ r) for r in residual(points)]
    u = nt.u.copy()
    for i in idx:
        best = [(c, v) for c, (j, v) in zip(costs, where, strict=True) if j == i]
        if best and min(best)[0] < nt.cost:
            u[i] = min(best)[1]
    if np.array_equal(u, nt.u):
        return False
    r = residual([(nt.structure, nt.structure.x(u))])[0]
    if not 0.5 * float(r @ r) < nt.cost:
        return False
    fitmod.restart(nt, nt.structure.x(u))
    return True


def null_u(f: fitmod.Free, ctx: fitmod.Context) -> tuple[float, int] | None:
    """"No effect" of one free parameter in optimizer coordinates and the side on which
    values are an effect (0: both, -1: only below). None: the parameter has no null of its
    own (e.g. a Stribeck velocity)."""
    if (f.effect, f.param) == ("torque_limit", "torque"):
        peak = float(ctx.peak_force[f.joint])
        return (f.to_u(peak), -1) if math.isfinite(peak) and peak > 0 else None
    v = effect(f.effect).param(f.param).null
    if not math.isfinite(v) or (f.log and v <= 0):
        return None
    # a parameter whose null is another's companion (a Stribeck velocity, a backdrive ratio)
    # is "no effect" only with its effect's amplitude at null: judged by the amplitudes
    if f.effect in _AMPLITUDE and f.param != _AMPLITUDE[f.effect]:
        return None
    return f.to_u(v), 0


# the parameter that carries an effect's size, for effects with several parameters
_AMPLITUDE = {"stribeck_friction": "static", "gearbox_friction": "mu", "backlash": "width"}


def null_margins(s: fitmod.Structure, u: np.ndarray, half: np.ndarray, ctx: fitmod.Context
                 ) -> dict[str, float]:
    """Per effect of ``s``: the largest distance of its parameters (any joint) from "no
    effect" (``null_u``) in units of the 95 % half-widths ``half`` of intervals centred on
    ``u`` (optimizer coordinates; an interval's centre, which need not be the fitted value).
    > 1: some interval excludes "no effect". inf: no parameter can be judged (no null, or the
    effect carries no free parameter); 0: every interval is infinite."""
    judged: dict[str, list[float]] = {}
    for i, f in enumerate(s.free):
        nu = null_u(f, ctx)
        if nu is None:
            continue
        u0, side = nu
        d = (u0 - u[i]) if side < 0 else abs(u[i] - u0)
        if not math.isfinite(half[i]):
            m = 0.0
        elif half[i] > 0:
            m = d / half[i]
        else:
            m = math.inf if d > 0 else 0.0
        judged.setdefault(f.effect, []).append(float(m))
    return {n: max(judged[n]) if n in judged else math.inf
            for n in dict.fromkeys(f.effect for f in s.free)}


def _block_edges(t: np.ndarray, seconds: float) -> list[tuple[int, int]]:
    """(start, stop) sample indices of consecutive blocks of about ``seconds`` of times ``t``
    [s] (a short tail joins the block before it)."""
    k = np.searchsorted(t, t[0] + seconds * np.arange(1, int((t[-1] - t[0]) / seconds) + 1))
    edges = [0, *[int(x) for x in k if 0 < x < len(t)], len(t)]
    if len(edges) > 2 and t[-1] - t[edges[-2]] < 0.5 * seconds:
        edges.pop(-2)
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def block_sse(ds: Dataset, eps: Sequence[Window], pred: Sequence[np.ndarray], seconds: float
              ) -> np.ndarray:
    """Sum of squared errors per consecutive block of about ``seconds`` of each episode (a
    short tail joins the block before it), episodes in order [rad^2]."""
    out = []
    for w, p in zip(eps, pred, strict=True):
        tr = ds.trajectories[w.traj]
        r = tr.qpos[w.start:w.stop] - p
        e = (r * r).sum(axis=1)
        out += [float(e[a:b].sum()) for a, b in _block_edges(tr.time[w.start:w.stop], seconds)]
    return np.array(out)


def block_change(ds: Dataset, eps: Sequence[Window], a: Sequence[np.ndarray],
                 b: Sequence[np.ndarray], seconds: float, floor: np.ndarray) -> np.ndarray:
    """Per block of ``block_sse``: how far two models' predictions ``a`` and ``b`` move apart,
    the largest over the joints of the RMS difference in the joint's own noise floors
    (``floor``, per joint: a slide's metres beside a hinge's radians)."""
    floor = np.maximum(np.asarray(floor, float), 1e-300)
    out = []
    for w, pa, pb in zip(eps, a, b, strict=True):
        d = (np.asarray(pb) - np.asarray(pa)) / floor
        out += [float(np.sqrt(np.mean(d[i:j] ** 2, axis=0)).max())
                for i, j in _block_edges(ds.trajectories[w.traj].time[w.start:w.stop], seconds)]
    return np.array(out)


def paired_gain_bound(cur: np.ndarray, new: np.ndarray, rng: np.random.Generator,
                      n_boot: int, level: float = 0.05, length: int | None = None,
                      tie: float = TIE) -> float:
    """One-sided lower ``level`` bound of the relative MSE reduction 1 - sum(new) / sum(cur)
    from a paired moving-block bootstrap over the blocks (``block_sse`` of both models on the
    same data, in time order): runs of ``length`` consecutive blocks (None: ceil(nb^(1/3)))
    drawn with replacement until nb blocks are drawn. Fewer than 2 blocks: -inf.

    Resamples in which the two models' errors differ by at most ``tie`` (relative) are ties
    and left out, as a sign test discards zero differences: they hold none of the blocks where
    the change of model acts, so they say nothing for or against it. An effect that acts in a
    few blocks only (a torque limit saturates during the fast moves: on the independent bench
    99.99 % of its select gain sat in one 0.5 s block of 11) otherwise gets a bound of 0 from the
    resamples that miss those blocks, however large its gain. Every resample a tie: 0."""
    cur, new = np.asarray(cur, float), np.asarray(new, float)
    nb = len(cur)
    if nb < 2:
        return -math.inf
    ell = max(1, min(nb, length if length is not None else math.ceil(nb ** (1 / 3))))
    k = math.ceil(nb / ell)
    starts = rng.integers(0, nb - ell + 1, size=(n_boot, k))
    idx = (starts[:, :, None] + np.arange(ell)).reshape(n_boot, -1)[:, :nb]
    a, b = cur[idx].sum(1), new[idx].sum(1)
    boot = 1.0 - b / np.maximum(a, 1e-300)
    boot = boot[np.abs(boot) > tie]
    return float(np.quantile(boot, level)) if boot.size else 0.0


def paired_low(predict, ds: Dataset, eps: Sequence[Window], cur: Sequence[AppliedEffect],
               new: Sequence[AppliedEffect], seconds: float, rng: np.random.Generator,
               n_boot: int, floor: np.ndarray | None = None, resolve: float = RESOLVE) -> float:
    """Lower 5 % bound of model ``new``'s relative MSE reduction over ``cur`` on ``eps``
    (``paired_gain_bound`` over blocks of ``seconds``); ``predict(windows, columns)`` replays
    each column of effects open loop (``analyze._Engine.predict``).

    With ``floor`` (per joint), a block in which the two models' predictions stay within
    ``resolve`` noise floors of each other on every joint (``block_change``) holds no evidence
    either way: its error difference is the measured residual's cross term with a change the
    readings cannot resolve, of either sign, and the block counts as unchanged (a tie where a
    resample holds only such blocks). The analysis calls a change of model below
    ``GapConfig.min_effect`` floors (default 0.75) no change; ``RESOLVE`` is half that default
    per block (a constant: a larger ``min_effect`` asks more of an effect's size, not of the
    evidence in each block; at 0.75 a 0.707-floor offset that ``min_effect=0.7`` accepts was
    refused as all ties, tests/test_gap_decisions_loop.py). Measured (gap-sim16,
    tests/gap_truth_sim12.py grip_offset): a 2.9 mm jaw offset acts only while the jaw presses
    the block, 2 of the select split's 12 blocks (the predictions 135-195 floors apart, the
    rest <= 0.1); a resample missing both (13 %) kept the other blocks' +-3 % cross terms and
    set the bound of a 55 % gain to -0.17 %."""
    a, b = predict(eps, [list(cur), list(new)])
    sse_a, sse_b = block_sse(ds, eps, a, seconds), block_sse(ds, eps, b, seconds)
    if floor is not None:
        quiet = block_change(ds, eps, a, b, seconds, floor) < resolve
        sse_b = np.where(quiet, sse_a, sse_b)
    return paired_gain_bound(sse_a, sse_b, rng, n_boot)


def residual_blocks(ds: Dataset, segs: Sequence[Window], seconds: float) -> list[slice]:
    """Slices of the residual vector of ``segs`` (``_Engine.residuals`` layout: each segment's
    scored samples x logged joints) in blocks of about ``seconds`` (a short tail joins the
    block before it)."""
    out, pos = [], 0
    nj = len(ds.joints)
    for w in segs:
        t = ds.trajectories[w.traj].time[w.score_from:w.stop]
        out += [slice(pos + nj * a, pos + nj * b) for a, b in _block_edges(t, seconds)]
        pos += nj * len(t)
    return out


# parameters whose cost is not smooth at the scale of their interval (a play's contacts come
# and go with its width: the finite-difference Jacobian measures one side of a kink), so their
# intervals also follow the profile of the cost (``profile_interval``)
PROFILED = frozenset({("backlash", "width")})


def _profile_costs(t: fitmod.Track, residual: fitmod.ResidualFn,
                   pins: Sequence[tuple[int, float]], rounds: int) -> list[float]:
    """Cost of ``t``'s model with scalar i held at u_i (``pins``: (i, u_i), optimizer
    coordinates) and the other scalars refitted by up to ``rounds`` Gauss-Newton (chord) steps
    with the columns of ``t.jac`` at the optimum, from ``t.u``, within their ranges: the lowest
    cost met (every point evaluated is feasible, so an upper bound of the profile). A model
    linear in the others is refitted exactly by the first step, whatever the held scalar does
    (a kink included). One batched replay per round for every pin still improving."""
    s, lo, hi = t.structure, *t.structure.u_bounds()
    pts = []
    for i, ui in pins:
        v = np.array(t.u, float)
        v[i] = ui
        cols = np.delete(np.arange(len(v)), i)
        jo = t.jac[:, cols]
        pts.append((v, cols, np.linalg.pinv(jo, rcond=3e-8) if jo.shape[1] else None))
    best, live = [math.inf] * len(pts), list(range(len(pts)))
    for rnd in range(rounds + 1):
        if not live:
            break
        res = residual([(s, s.x(pts[k][0])) for k in live])
        nxt = []
        for k, r in zip(live, res, strict=True):
            c = 0.5 * float(r @ r)
            if not c < best[k]:  # no further progress (or not finite)
                continue
            best[k] = c
            v, cols, pinv = pts[k]
            if pinv is None or rnd == rounds:
                continue
            w = v.copy()
            w[cols] = np.clip(v[cols] - pinv @ r, lo[cols], hi[cols])
            if not np.allclose(w, v, rtol=0.0, atol=1e-12):
                pts[k] = (w, cols, pinv)
                nxt.append(k)
        live = nxt
    return best


def profile_interval(t: fitmod.Track, residual: Callable[[], fitmod.ResidualFn],
                     half: np.ndarray, rounds: int = 2,
                     steps: Sequence[float] = (1.25, 2.0, 4.0, 8.0), scan: bool = False
                     ) -> tuple[np.ndarray, np.ndarray]:
    """95 % intervals (centre, half-width; optimizer coordinates) of ``t``'s ``PROFILED``
    scalars that also hold the range where the cost's profile stays low; the others as given.

    ``residual()`` makes the batched residual function of ``t``'s data (called only when some
    scalar is profiled). Each such scalar i is held at ``u_i +- s half_i`` for ``s`` in
    ``steps`` (within its search range), the others refitted (``_profile_costs``: ``rounds``
    Gauss-Newton steps with the optimum's Jacobian). For a model linear in its parameters the
    profile is C(u_i) = C_min + (u_i - u^_i)^2 / (2 [(J^T J)^-1]_ii), so the linearised
    interval ``half`` is where it rises by Delta = half_i^2 / (2 [(J^T J)^-1]_ii): the same
    statistics (noise, block spread, autocorrelation: whatever sized ``half``), measured on the
    cost itself. Each side goes outward one step at a time and stops at the first value whose
    rise exceeds Delta (a profile that comes back down past it is not looked for). The profile
    interval runs to the farthest value whose rise is at most Delta (interpolated in
    sqrt(rise) toward the next one); the result is the hull of it and u^_i +- half_i, never
    narrower than the linearised one. With ``scan``, a width whose cost is jagged (a loop
    closed across the play hunting inside it) also holds the valley of its smoothed cost over
    its whole search range (``width_scan``; one more batched replay). ``t`` needs ``r`` and
    ``jac`` at its optimum (``lockstep_lm`` with ``jacobian_at_end``).

    Cost (issue 11, the main job's logs): one or two batched replays per step and side, where
    20 rounds of LM per grid value on 10 values doubled the whole analysis (327 -> 685 s)."""
    s = t.structure
    idx = [i for i, f in enumerate(s.free) if (f.effect, f.param) in PROFILED
           and math.isfinite(half[i]) and half[i] > 0]
    if not idx or t.jac is None or t.r is None:
        return t.u, half  # as given (the same arrays)
    u, half = np.asarray(t.u, float), np.array(half, float)
    centre = u.copy()
    residual = residual()
    ainv = np.linalg.pinv(t.jac.T @ t.jac)
    delta = {i: 0.5 * half[i] ** 2 / max(float(ainv[i, i]), 1e-300) for i in idx}
    lo, hi = s.u_bounds()
    lines = {(i, side): [(0.0, t.cost)] for i in idx for side in (-1.0, 1.0)}
    c_min = {i: t.cost for i in idx}
    going = set(lines)
    for d in steps:
        pins = []
        for i, side in sorted(going):
            ui = float(np.clip(u[i] + side * d * half[i], lo[i], hi[i]))
            if side * (ui - u[i]) > lines[(i, side)][-1][0]:
                pins.append(((i, side), ui))
            else:  # the search range ends here
                going.discard((i, side))
        for (key, ui), c in zip(pins, _profile_costs(t, residual, [(k[0], ui) for k, ui in pins],
                                                     rounds), strict=True):
            i, side = key
            lines[key].append((side * (ui - u[i]), c))
            c_min[i] = min(c_min[i], c)
            if not c - c_min[i] <= delta[i]:  # past Delta (or not finite): this side ends
                going.discard(key)
    valleys = {sc.index: sc.valley(delta[sc.index])
               for sc in width_scan.scan(t, residual, delta)} if scan else {}
    for i in idx:
        lo_e, hi_e = u[i] - half[i], u[i] + half[i]
        if i in valleys and np.all(np.isfinite(valleys[i])):  # a jagged cost's whole valley
            lo_e, hi_e = min(lo_e, valleys[i][0]), max(hi_e, valleys[i][1])
        for side in (-1.0, 1.0):
            line = [(x, c - c_min[i]) for x, c in lines[(i, side)] if math.isfinite(c)]
            inside = [k for k, (_, rise) in enumerate(line) if rise <= delta[i]]
            if not inside:
                continue
            k = inside[-1]
            edge = line[k][0]
            if k + 1 < len(line):  # toward the first value past it, linear in sqrt(rise)
                (d0, c0), (d1, c1) = line[k], line[k + 1]
                a, b = math.sqrt(max(c0, 0.0)), math.sqrt(max(c1, 0.0))
                edge = d0 + (d1 - d0) * (math.sqrt(delta[i]) - a) / max(b - a, 1e-300)
            lo_e, hi_e = (min(lo_e, u[i] - edge), hi_e) if side < 0 else (lo_e,
                                                                          max(hi_e, u[i] + edge))
        centre[i], half[i] = 0.5 * (lo_e + hi_e), 0.5 * (hi_e - lo_e)
    return centre, half
