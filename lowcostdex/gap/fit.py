"""Fitting candidate effects: bounded parameter spaces and a lockstep Levenberg-Marquardt.

Every candidate model ("track": a list of effects with free per-joint parameters and one start
point) is fitted by box-bounded Levenberg-Marquardt on the simulation error of multiple-shooting
segments. All tracks advance in lockstep: one batched replay per round evaluates, for every live
track, its trial point and the finite-difference columns around it, so a round costs one pass over
the data whatever the number of candidates and starts. (``mujoco.minimize.least_squares`` solves
one problem at a time; here a dozen non-nested models and their multi-starts share each pass.) A
rejected trial keeps the previous Jacobian and raises the damping.

Parameter spaces come from the effect catalogue (``Param.low/high/start``) made model-aware: the
latency bound starts at one physics step (the native delay is quantized below it, sysid trap 8),
torque limits below and dry friction up to the peak force the baseline model uses, scale factors
and Stribeck velocities are searched in log space, and non-convex parameters get extra starts. A
fit that lands on a search bound may widen that bound toward the parameter's physical hard limit
(``Param.hard``) and refit (``widen``): real-world sizes beyond the usual range are then named with
their value, and only a fit at its hard limit is rejected.

Why one module (over ~500 lines; issue 16 asks for the reason here): the lockstep Levenberg-
Marquardt and the widening of the bounded parameter spaces it steps in share the ``Structure``/
``Track`` state of one algorithm; the loop that calls it is ``analyze``, its results ``results``;
the spaces themselves (``Context``, ``Free``, ``space``) are ``gap.spaces``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import mujoco
import numpy as np

from lowcostdex.gap.spaces import Context, Free, hard_limits, space  # noqa: F401 (fit.space ...)
from lowcostdex.sim.effects import AppliedEffect, effect
from lowcostdex.sim.servo import dcmotor_mask, stall_torque


@dataclass
class Structure:
    """A candidate model: effects on the data set's effect joints with free parameters.

    Attributes:
      effects: canonical effect names, in order of selection.
      joints: joints every effect acts on.
      free: the free scalars (effect, param, joint).
      held: scalars the context holds at one value (a range of one value in ``Context.widened``,
        e.g. a backlash read on the motor side: ``gap.play_side``), (effect, param, joint) ->
        value; ``to_effects`` writes them, ``held_ranges`` rebuilds them.
    """

    effects: tuple[str, ...]
    joints: tuple[str, ...]
    free: list[Free] = field(default_factory=list)
    fixed: tuple[AppliedEffect, ...] = ()
    held: dict[tuple[str, str, int], float] = field(default_factory=dict)

    @classmethod
    def build(cls, effects: Sequence[str], joints: Sequence[str], ctx: Context,
              fixed: Sequence[AppliedEffect] = ()) -> Structure:
        """Free per-joint parameters for ``effects``; ``fixed`` effects ride along unchanged."""
        free = [space(n, p.name, j, ctx) for n in effects for p in effect(n).params
                if p.acts(ctx.is_dcmotor) for j in range(len(joints))]
        held = {k: lo for k, (lo, hi) in ctx.widened.items() if lo == hi and k[0] in effects}
        return cls(tuple(effects), tuple(joints), [f for f in free if f.lo < f.hi], tuple(fixed),
                   held)

    @property
    def held_ranges(self) -> dict[tuple[str, str, int], tuple[float, float]]:
        """The context ranges that hold ``held`` (for a rebuild: ``Context.with_ranges``)."""
        return {k: (v, v) for k, v in self.held.items()}

    @property
    def names(self) -> tuple[str, ...]:
        """All effect names, fixed first."""
        return tuple(e.name for e in self.fixed) + self.effects

    @property
    def n(self) -> int:
        return len(self.free)

    def to_effects(self, values: np.ndarray) -> list[AppliedEffect]:
        """Parameter values (n,) -> AppliedEffects (fixed ones first, then one per effect)."""
        out = list(self.fixed)
        for name in self.effects:
            vals: dict[str, np.ndarray] = {}
            for f, v in zip(self.free, values, strict=True):
                if f.effect == name:
                    null = effect(name).param(f.param).null  # also on joints where it is held
                    v = null if f.at_floor(v) else v
                    vals.setdefault(f.param, np.full(len(self.joints), null))[f.joint] = v
            for (n, param, j), v in self.held.items():
                if n == name:
                    vals.setdefault(param, np.full(len(self.joints), effect(n).param(param).null))[j] = v
            out.append(AppliedEffect(name, self.joints, vals))
        return out

    def values_from(self, effects: Sequence[AppliedEffect]) -> np.ndarray:
        """Current values of the free scalars taken from fitted effects (start when absent)."""
        by_name = {e.name: e for e in effects}
        out = []
        for f in self.free:
            e = by_name.get(f.effect)
            v = f.start if e is None else float(e.values[f.param][f.joint])
            out.append(float(np.clip(v, f.lo, f.hi)))
        return np.array(out)

    def starts(self, base: np.ndarray | None = None) -> list[np.ndarray]:
        """Start points: ``base`` (or the scalars' starts) and one per extra start (its scalars)."""
        x0 = np.array([f.start for f in self.free]) if base is None else np.array(base, float)
        out = [x0]
        n_extra = max((len(f.extra) for f in self.free), default=0)
        for k in range(n_extra):
            x = x0.copy()
            moved = False
            for i, f in enumerate(self.free):
                if len(f.extra) > k and (base is None or f.effect == self.effects[-1]):
                    x[i] = f.extra[k]
                    moved = True
            if moved:
                out.append(x)
        return out

    def u(self, x: np.ndarray) -> np.ndarray:
        return np.array([f.to_u(v) for f, v in zip(self.free, x, strict=True)])

    def x(self, u: np.ndarray) -> np.ndarray:
        return np.array([f.from_u(v) for f, v in zip(self.free, u, strict=True)])

    def u_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        b = np.array([f.u_bounds for f in self.free]).reshape(-1, 2)
        return b[:, 0], b[:, 1]


def at_bounds(s: Structure, u: np.ndarray) -> list[tuple[int, str]]:
    """Free scalars of ``s`` whose value ``u`` (optimizer coordinates) sits on a search bound
    that is not the effect's null (a friction at 0 is absent, not at a bound), or a Coulomb level
    of half the actuator's force or more while its creep is held: (index, "lower" or "upper").

    A bound between the null and the rest of the range (a delay's one-step floor above 0, a
    torque limit's upper bound at the model's peak force) is "as little of the effect as the
    search can express", not an implausible fit (a 60 ms latency on one finger joint was
    rejected because the two clean joints' delays sat at 2 ms)."""
    lo, hi = s.u_bounds()
    out = []
    for i, f in enumerate(s.free):
        p = effect(f.effect).param(f.param)
        if (f.param == "frictionloss" and f.from_u(u[i]) >= 0.5 * f.hi and not any(  # creep held
                (g.param, g.joint) == ("creep", f.joint) for g in s.free)):  # and may matter
            out.append((i, "upper"))  # hi: at least the actuator's force
            continue
        null = p.null  # a share's ends (Param.ends) are values, not a range too narrow
        for b, side in (() if p.ends else ((lo[i], "lower"), (hi[i], "upper"))):
            value = f.from_u(b)
            toward_null = null <= value if side == "lower" else null >= value
            if (abs(u[i] - b) <= 1e-6 * max(1.0, abs(b)) and not math.isclose(value, null)
                    and not toward_null):
                out.append((i, side))
    return out


def widen(s: Structure, u: np.ndarray, ctx: Context
          ) -> tuple[dict[tuple[str, str, int], tuple[float, float]], list[tuple[str, str]]]:
    """Wider search ranges for the scalars of ``s`` sitting on a bound at ``u``.

    The bound moves out by the range's own span (optimizer coordinates), never past the hard
    limit (``hard_limits``); a flagged Coulomb level also frees its ``creep`` (it may stick).
    Returns the new ranges {(effect, param, joint): (low, high)} (empty when every such scalar
    is at its hard limit) and (effect, line) per widened range for the report."""
    ranges: dict[tuple[str, str, int], tuple[float, float]] = {}
    notes: list[tuple[str, str]] = []
    for i, side in at_bounds(s, u):
        f = s.free[i]
        h_lo, h_hi = hard_limits(f.effect, f.param, f.joint, ctx)
        lo_u, hi_u = f.u_bounds
        span = hi_u - lo_u
        lo, hi = f.lo, f.hi
        if (f.effect, f.param, side) == ("coulomb_friction", "frictionloss", "upper"):
            ranges[(f.effect, "creep", f.joint)] = (0.0, 1.0)  # soft may not hold: may stick
        if side == "lower" and f.lo > h_lo:
            lo = max(f.from_u(lo_u - span), h_lo) if not f.log or h_lo > 0 else h_lo
        elif side == "upper" and f.hi < h_hi:
            hi = min(f.from_u(hi_u + span), h_hi)
        if (lo, hi) == (f.lo, f.hi):
            continue
        ranges[(f.effect, f.param, f.joint)] = (lo, hi)
        unit = effect(f.effect).param(f.param).unit
        unit = "" if unit == "1" else " " + unit
        notes.append((f.effect, f"{f.param}[{s.joints[f.joint]}] reached its {side} search "
                      f"bound {f.lo if side == 'lower' else f.hi:.4g}{unit}: range widened to "
                      f"[{lo:.4g}, {hi:.4g}]{unit} (hard limit [{h_lo:.4g}, {h_hi:.4g}])"))
    return ranges, notes


def widen_and_refit(t: Track, residual: ResidualFn, ctx: Context, max_rounds: int,
                    passes: int = 3) -> tuple[Track, dict, list[tuple[str, str]]]:
    """Refit a track whose fit landed on search bounds in wider ranges (``widen``), up to
    ``passes`` times or until no scalar is on a bound it may leave.

    Returns the (possibly new) track, the ranges widened for it and the report lines; the new
    track replaces ``t`` only if it fits at least as well.
    """
    ranges: dict[tuple[str, str, int], tuple[float, float]] = {}
    notes: list[tuple[str, str]] = []
    for _ in range(passes):
        if t.r is None:
            break
        new, lines = widen(t.structure, t.u, ctx.with_ranges(ranges))
        if not new:
            break
        trial_ranges = {**ranges, **new}
        s = Structure.build(t.structure.effects, t.structure.joints, ctx.with_ranges(
            {**t.structure.held_ranges, **trial_ranges}), fixed=t.structure.fixed)
        nt = Track(s, s.u(s.values_from(t.effects())), label=t.label + "+widened")
        lockstep_lm([nt], residual, max_rounds)
        if not nt.cost <= t.cost:
            break
        t, ranges, notes = nt, trial_ranges, notes + lines
    return t, ranges, notes


ResidualFn = Callable[[list[tuple[Structure, np.ndarray]]], list[np.ndarray]]


@dataclass
class Track:
    """One Levenberg-Marquardt run (a structure from one start) in the lockstep fit."""

    structure: Structure
    u: np.ndarray
    label: str = ""
    mu: float = 1e-2
    cost: float = math.inf
    r: np.ndarray | None = None
    jac: np.ndarray | None = None
    trial: np.ndarray | None = None
    done: bool = False
    rounds: int = 0
    rejects: int = 0
    history: list[float] = field(default_factory=list)
    fd_scale: float = 1.0  # finite-difference steps x this (10 after a stall, see lockstep_lm)
    evals: int = 0  # residual evaluations (replays of the fitted windows) spent on this track

    @property
    def x(self) -> np.ndarray:
        return self.structure.x(self.u)

    def effects(self) -> list[AppliedEffect]:
        return self.structure.to_effects(self.x)


def lockstep_lm(tracks: Sequence[Track], residual: ResidualFn, max_rounds: int = 20,
                rtol: float = 1e-3, on_round: Callable[[int, int], None] | None = None,
                prune: Callable[[int, Sequence[Track]], None] | None = None,
                max_rejects: int = 5, jacobian_at_end: bool = True) -> None:
    """Fit all tracks by bounded Levenberg-Marquardt, two batched evaluations per round.

    Each round first evaluates every live track's trial point (one batched pass); only the
    tracks that accept it and go on get their finite-difference columns there (a second pass).
    A rejected trial keeps the previous Jacobian, so its columns would be thrown away: the
    fits take the same steps as with the columns evaluated beside every trial, for fewer
    replays (``Track.evals`` counts them).

    Args:
      tracks: tracks with ``u`` at their start; updated in place (``u``, ``cost``, ``r``,
        ``jac`` at the accepted point).
      residual: batched residual function.
      max_rounds: rounds at most.
      rtol: stop when an accepted step lowers the cost by less than this fraction.
      on_round: progress callback (round, live tracks).
      prune: called after each round's trial pass with (round, tracks); may end tracks
        (``done = True``).
      max_rejects: a track ends after this many rejected trials in a row, unless its
        Jacobian came from the fine finite-difference steps: the replayed response has small
        steps of its own (saturation and delay switching at physics steps; seen: a 2.5x gain
        fit stalled at 2.06 because the 1e-3 secant's slope had the wrong sign, the 1e-2 one
        the right sign), so it restarts there once with steps 10x wider.
      jacobian_at_end: also evaluate the Jacobian at a track's last accepted point when the
        fit ends there (``jac`` for intervals); False leaves ``jac`` None then (screening
        fits, which only use the fitted point).
    """
    for t in tracks:
        t.trial = t.u.copy()
    for rnd in range(max_rounds):
        live = [t for t in tracks if not t.done]
        if not live:
            break
        res = residual([(t.structure, t.structure.x(t.trial)) for t in live])
        accepted, stepping = [], []
        for t, r_trial in zip(live, res, strict=True):
            t.evals += 1
            cost = 0.5 * float(r_trial @ r_trial)
            t.rounds += 1
            if not np.isfinite(cost):
                cost = math.inf
            if t.r is None or cost < t.cost:
                improvement = ((t.cost - cost) / t.cost if np.isfinite(t.cost) and t.r is not None
                               else 1.0)
                t.u, t.cost, t.r, t.jac = t.trial.copy(), cost, r_trial, None
                t.mu = max(t.mu / 3.0, 1e-7)
                t.rejects = 0
                if improvement < rtol and t.rounds > 1:
                    t.done = True
                accepted.append(t)
            else:
                # Marquardt damping scales the step by ~1 / (1 + mu): grow mu fast
                t.mu = max(10.0 * t.mu, 0.1)
                t.rejects += 1
                if t.rejects >= max_rejects or t.mu > 1e6:
                    if t.fd_scale == 1.0 and t.jac is not None and t.jac.shape[1]:
                        # the next round re-evaluates the Jacobian here with wider steps
                        t.fd_scale, t.trial, t.r, t.rejects, t.mu = 10.0, t.u.copy(), None, 0, 1e-2
                        t.jac = None
                        t.history.append(t.cost)
                        continue
                    t.done = True
            t.history.append(t.cost)
            if not t.done:
                stepping.append(t)
        if prune is not None:
            prune(rnd, tracks)
        last = rnd == max_rounds - 1  # no next trial: a Jacobian here only for ``jac``
        _jacobians([t for t in accepted if jacobian_at_end or not (t.done or last)], residual)
        for t in stepping if not last else ():
            if not t.done:
                t.trial = _lm_step(t)
                if t.trial is None:
                    t.done = True
        if on_round is not None:
            on_round(rnd, len(live))
    # a track cut off right after its wide-step restart (residual cleared, see above) gets its
    # residual and Jacobian back at its accepted point: one more evaluation, which accepts it
    pending = [t for t in tracks if t.r is None and t.fd_scale != 1.0]
    for t in pending:
        t.trial, t.done = t.u.copy(), False
    if pending:
        lockstep_lm(pending, residual, 1, rtol, max_rejects=max_rejects,
                    jacobian_at_end=jacobian_at_end)
    for t in tracks:
        t.done = True


def _jacobians(tracks: Sequence[Track], residual: ResidualFn) -> None:
    """Forward-difference Jacobians of ``tracks`` at their accepted points (one batched pass)."""
    points, owners = [], []
    for t in tracks:
        t.trial = t.u.copy()
        cols = _fd_points(t)[1:]
        points += [(t.structure, t.structure.x(u)) for u in cols]
        owners.append((t, cols))
    res = residual(points) if points else []
    k = 0
    for t, cols in owners:
        fd_r = res[k:k + len(cols)]
        k += len(cols)
        t.evals += len(cols)
        t.jac = np.stack([(fr - t.r) / (c - t.u)[i]
                          for i, (fr, c) in enumerate(zip(fd_r, cols, strict=True))],
                         axis=1) if cols else np.zeros((len(t.r), 0))


# Parameters whose response is piecewise smooth at the physics-step scale (the native actuator
# delay interpolates its history buffer with flat stretches): a batched 1-D scan polishes them.
_SCAN = {("latency", "delay")}


def _scan(t: Track, residual: ResidualFn, grids: dict[int, np.ndarray]) -> bool:
    """One batched evaluation of each scalar ``i`` over ``grids[i]`` (others at the track's
    values); the best value per scalar where it beats the track's cost, combined. If that point
    is new and lowers the cost the track restarts there (``restart``); returns whether."""
    if not grids or t.r is None:
        return False
    x0 = t.x
    points = []
    for i, grid in grids.items():
        for v in grid:
            x = x0.copy()
            x[i] = float(v)
            points.append((t.structure, x))
    costs = [0.5 * float(r @ r) for r in residual(points)]
    x, k = x0.copy(), 0
    for i, grid in grids.items():
        j = int(np.argmin(costs[k:k + len(grid)]))
        if costs[k + j] < t.cost:
            x[i] = float(grid[j])
        k += len(grid)
    if np.array_equal(x, x0):
        return False
    r = residual([(t.structure, x)])[0]
    if not 0.5 * float(r @ r) < t.cost:
        return False
    restart(t, x)
    return True


def polish(t: Track, residual: ResidualFn, dt: float, n: int = 9) -> bool:
    """Scan each piecewise-smooth scalar of a fitted track over +-1 physics step (others fixed,
    one batched evaluation) and move the track to the best values; returns whether it moved
    (its residual, cost and Jacobian are then to be re-evaluated: ``restart``)."""
    free = t.structure.free
    grids = {i: np.clip(t.x[i] + np.linspace(-dt, dt, n), f.lo, f.hi)
             for i, f in enumerate(free) if (f.effect, f.param) in _SCAN}
    return _scan(t, residual, grids)


_LIMITS, _LOG_LIMITS = {("torque_limit", "torque")}, {("velocity_limit", "speed")}


def scan_limits(t: Track, residual: ResidualFn, n: int = 25) -> bool:
    """Rescue a fitted limit parameter from the flat side of its cost.

    A saturation limit above every load it sees has zero gradient, so Levenberg-Marquardt
    leaves a joint's limit wherever it stopped binding (seen: a finger's torque limits fitted
    to 1.73 / 1.74 / 2.08 N m, truth 1.78 / 1.76 / 1.82, train cost 58 % above the truth's).
    Each limit scalar is scanned over its range (``n`` evenly spaced values, the others fixed,
    one batched evaluation) and the best value per scalar kept if it lowers the cost; the track
    then restarts there so more LM rounds refine it (the cost rises steeply just above a
    barely binding limit and gently below it). Returns whether it moved.
    """
    grids = {i: (np.geomspace if (f.effect, f.param) in _LOG_LIMITS else np.linspace)(
        f.lo, f.hi, n) for i, f in enumerate(t.structure.free)
        if (f.effect, f.param) in _LIMITS | _LOG_LIMITS}
    return _scan(t, residual, grids)


_SCALES = {("gain_error", "scale")}


def scan_scales(t: Track, residual: ResidualFn, n: int = 17, fine: int = 9) -> bool:
    """Rescue a fitted scale factor that Levenberg-Marquardt left where it started.

    On a rig where one joint's replay error is jagged in every parameter (a finger riding on a
    gripper's jaw, its fingertip sticking and slipping on the table: the pooled cost moves by
    +-10 % between neighbouring gains), the joint fit's steps are rejected one after another
    and a kp off by x0.546 on the jaw stayed at 1.000 (gap-sim15's grip_gain; from a start at
    0.5 the fit stayed at 0.506, the jaw's own error being a smooth valley at 0.546). Each scale
    scalar, one at a time (the others at their current values), is scanned over its range
    (``n`` log-spaced values, one batched evaluation) and then over one grid step either side
    of the best (``fine`` values); a value is kept only where it lowers the cost. The track
    then restarts there (``restart``). Returns whether it moved."""
    idx = [i for i, f in enumerate(t.structure.free) if (f.effect, f.param) in _SCALES]
    if not idx or t.r is None:
        return False
    x, cost = t.x.copy(), t.cost
    for i in idx:
        f = t.structure.free[i]
        ratio = (f.hi / f.lo) ** (1.0 / (n - 1))
        for finer in (False, True):
            grid = (np.clip(x[i] * np.geomspace(1 / ratio, ratio, fine), f.lo, f.hi) if finer
                    else np.geomspace(f.lo, f.hi, n))
            points = []
            for v in grid:
                p = x.copy()
                p[i] = float(v)
                points.append((t.structure, p))
            costs = [0.5 * float(r @ r) for r in residual(points)]
            k = int(np.argmin(costs))
            if costs[k] < cost:
                x, cost = points[k][1], costs[k]
    if np.array_equal(x, t.x):
        return False
    restart(t, x)
    return True


def restart(t: Track, x: np.ndarray) -> None:
    """Move a track to ``x`` and make it live: the next LM round re-evaluates its residual and
    Jacobian there (and accepts it as its start)."""
    t.u, t.cost, t.r, t.jac, t.trial = t.structure.u(x), math.inf, None, None, None
    t.done, t.rejects, t.mu = False, 0, 1e-2


def prune_tracks(rnd: int, tracks: Sequence[Track], after: int = 4) -> None:
    """End tracks that cannot win: from round ``after`` on, starts of one structure that trail
    its best start, and structures whose cost reduction is below a tenth of the best one's
    unless theirs is the lowest cost (a start near the optimum barely moves: a 2.5x gain
    started at 2.0 led, a velocity limit started far off 'dropped' more and ended it)."""
    if rnd + 1 < after or not tracks:
        return
    first = {id(t): t.history[0] for t in tracks if t.history}
    best_by: dict[tuple, float] = {}
    for t in tracks:
        key = t.structure.names
        best_by[key] = min(best_by.get(key, math.inf), t.cost)
    lowest = min(best_by.values())
    top = max([first[id(t)] - t.cost for t in tracks if id(t) in first] + [0.0])
    for t in tracks:
        if t.done:
            continue
        if t.cost > 1.02 * best_by[t.structure.names]:
            t.done = True
        elif id(t) in first and first[id(t)] - t.cost < 0.1 * top and t.cost > lowest:
            t.done = True


def _fd_points(t: Track) -> list[np.ndarray]:
    u = t.trial
    lo, hi = t.structure.u_bounds()
    cols = [u.copy()]
    for i, f in enumerate(t.structure.free):
        step = f.fd * t.fd_scale
        if u[i] + step > hi[i]:
            step = -step
        c = u.copy()
        c[i] += step
        cols.append(c)
    return cols


def _lm_step(t: Track) -> np.ndarray | None:
    """Next trial point: a bounded LM step, pinning dimensions at bounds (active set).

    ``t.jac`` is d(residual)/du: the step solves (J^T J + mu diag(J^T J)) du = -J^T r."""
    jac, r = t.jac, t.r
    n = jac.shape[1]
    if n == 0:
        return None
    lo, hi = t.structure.u_bounds()
    jtj = jac.T @ jac
    desc = -(jac.T @ r)
    diag = np.maximum(np.diag(jtj), 1e-12 * max(float(np.max(np.diag(jtj))), 1e-30))
    free = ~((t.u <= lo + 1e-12) & (desc < 0)) & ~((t.u >= hi - 1e-12) & (desc > 0))
    du = np.zeros(n)
    for _ in range(n + 1):
        idx = np.flatnonzero(free)
        if len(idx) == 0:
            break
        pinned = ~free
        rhs = desc[idx] - jtj[np.ix_(idx, np.flatnonzero(pinned))] @ du[pinned]
        a = jtj[np.ix_(idx, idx)] + t.mu * np.diag(diag[idx])
        try:
            du[idx] = np.linalg.solve(a, rhs)
        except np.linalg.LinAlgError:
            return None
        new = t.u + du
        out = free & ((new < lo) | (new > hi))
        if not out.any():
            break
        du[out] = np.clip(new, lo, hi)[out] - t.u[out]
        free &= ~out
    trial = np.clip(t.u + du, lo, hi)
    if np.allclose(trial, t.u, rtol=0, atol=1e-12):
        return None
    return trial


def interval_halfwidths(r: np.ndarray, jac: np.ndarray, n_eff: float) -> np.ndarray:
    """95 % half-widths in optimizer coordinates from the Jacobian, for autocorrelated residuals.

    The formula of ``mujoco.sysid.calculate_intervals`` (s^2 = r.r / (n - p), diag of (J^T J)^-1
    by eigendecomposition with null directions infinite, Student-t quantile; importing
    ``mujoco.sysid`` costs seconds, so it is restated here and checked against it in the tests),
    inflated by sqrt(n / n_eff) because time-series residuals are not i.i.d. (04-sysid.md 4.3).
    """
    from scipy import special

    n, p = jac.shape
    if p == 0:
        return np.zeros(0)
    s2 = float(r @ r) / max(n - p, 1)
    lam, v = np.linalg.eigh(jac.T @ jac)
    lam_max = float(np.max(lam))
    null = lam / lam_max < 1e-15 if lam_max > 0 else np.ones(p, bool)
    vmax = np.max(np.abs(v), axis=1, keepdims=True)
    vv = np.where(np.abs(v / vmax) < 1e-8, 0.0, v)
    with np.errstate(divide="ignore"):
        inv_diag = np.where(np.any((vv != 0) & null[None, :], axis=1), np.inf,
                            np.sum(np.where(null[None, :], 0.0, vv ** 2 / np.where(null, 1.0, lam)),
                                   axis=1))
    half = np.sqrt(inv_diag * s2) * special.stdtrit(max(n - p, 1), 0.975)
    return half * math.sqrt(n / max(n_eff, 1.0))


def block_halfwidths(r: np.ndarray, jac: np.ndarray, blocks: Sequence[slice],
                     bandwidth: float | Callable[[np.ndarray], float] = 0.0) -> np.ndarray:
    """95 % half-widths in optimizer coordinates from how differently stretches of data pull
    on the parameters: the block sandwich covariance A^-1 (sum_b g_b g_b^T) A^-1 with A = J^T J
    and g_b = J_b^T r_b centred over the blocks (a linearized jackknife over blocks), times
    nb / (nb - p), Student-t with nb - p degrees of freedom.

    The residual-noise interval (``interval_halfwidths``) only knows the noise level; when the
    model is slightly wrong, different blocks want different values and this one grows with
    their spread. Null directions and fewer blocks than parameters + 1 give inf.

    ``bandwidth`` L > 0 (in blocks; or a function of the centred block scores (nb, p) giving it)
    adds the Newey-West lags: S = sum_b g_b g_b^T + sum_(l=1..L) (1 - l / (L + 1)) (G_l +
    G_l^T), G_l = sum_b g_b g_(b-l)^T, Student-t with max(nb / (L + 1) - p, 1) degrees of
    freedom (``significance.hac_halfwidths``).
    """
    from scipy import special

    n, p = jac.shape
    nb = len(blocks)
    if p == 0:
        return np.zeros(0)
    if nb <= p:
        return np.full(p, np.inf)
    lam, v = np.linalg.eigh(jac.T @ jac)
    lam_max = float(np.max(lam))
    null = lam / lam_max < 1e-15 if lam_max > 0 else np.ones(p, bool)
    ainv = (v[:, ~null] / lam[~null]) @ v[:, ~null].T
    g = np.stack([jac[b].T @ r[b] for b in blocks])
    g = g - g.mean(axis=0)
    L = float(bandwidth(g)) if callable(bandwidth) else float(bandwidth)
    s = g.T @ g
    for lag in range(1, int(math.floor(L)) + 1):
        gl = g[lag:].T @ g[:-lag]
        s += (1 - lag / (L + 1)) * (gl + gl.T)
    cov = ainv @ s @ ainv * nb / (nb - p)
    dof = max(nb / (L + 1) - p, 1.0)
    half = np.sqrt(np.maximum(np.diag(cov), 0.0)) * special.stdtrit(dof, 0.975)
    touches_null = np.any(np.abs(v[:, null]) > 1e-8, axis=1) if null.any() else np.zeros(p, bool)
    return np.where(touches_null, np.inf, half)


def step_shift(t: Track, residual: ResidualFn, max_rounds: int, rtol: float = 1e-4) -> np.ndarray:
    """How far a fitted track moves (optimizer coordinates) when the same data are replayed
    at a finer physics step: a copy of it refitted on ``residual`` (the finer replay's),
    starting from its optimum. The replay's own discretisation (step-mean goals, the delay's
    step phase, the integrator) biases every fitted value alike; no resampling of the data can
    see such a bias, but the move between two steps sizes it."""
    nt = Track(t.structure, t.u.copy(), label=t.label + "+finer step")
    lockstep_lm([nt], residual, max_rounds, rtol=rtol, jacobian_at_end=False)
    return nt.u - t.u


def servo_facts(model, actuators: np.ndarray) -> dict[str, np.ndarray]:  # Context's keywords
    jnt = model.actuator_trnid[actuators, 0]
    slide = (model.actuator_trntype[actuators] == int(mujoco.mjtTrn.mjTRN_JOINT)) & (
        model.jnt_type[np.maximum(jnt, 0)] == int(mujoco.mjtJoint.mjJNT_SLIDE))
    shared = np.array([a in actuators[:i] for i, a in enumerate(actuators)], bool)
    return {"stall": stall_torque(model, actuators), "dcmotor": dcmotor_mask(model, actuators),
            "slide": slide, "shared": shared if shared.any() else None}
