"""A finger base's mounting tilt fitted JOINTLY with the other parameters a valve-turning log
sees (the valve's dry friction, damping, inertia), on the identified model, with a global start
and intervals from a profile of the cost (issue 14, transfer15).

Why not ``tilt.fit_tilt`` alone: on robot C the tilt fitted on the nominal model absorbed C's
other differences (valve friction, servo effects) and landed on the wrong sign; and the valve
trace is only piecewise smooth in the tilt (a fingertip on one or the other side of a spoke), so
Gauss-Newton from 0 stalls and Jacobian intervals are far too narrow at contact switches.

``fit_tilt_jointly(simulate, observed, x0, lower, upper, step)``: the parameter vector is
``x = (ax, ay, p_1, ..., p_m)``: the tilt's rotation vector about the base's x and y axes [rad]
(``tilt.tilt_body``'s convention) then any other parameters the caller's ``simulate(x) -> trace``
applies (e.g. the valve's frictionloss [N m]). Stages:

1. global start: a grid of tilts (``grid`` x ``grid``, others at ``x0``); the ``starts`` best
   points go on;
2. local refinement: bounded Gauss-Newton over every parameter from each start (forward
   differences, steps capped by ``max_step``, a halved step tried before stopping); the best wins;
3. profile intervals of the two tilt angles: each angle fixed on a 1-D grid around the fit and the
   other parameters re-fitted (``profile_iterations`` Gauss-Newton steps; a profile point better
   than the fit becomes the fit and the profiles are made again around it); the 95 % interval is
   the hull of the profile points whose cost passes the likelihood-ratio test
   ``n_eff log(SSE / SSE_min) <= 3.84`` (Gaussian residuals; ``n_eff`` = samples over the
   residual's integrated autocorrelation time, so a trace's correlated samples are not counted as
   independent), widened by half a grid spacing; a hull touching the profile's end is unbounded
   on that side (the cost was not looked at beyond). With ``groups`` (the episode of every
   sample: episodes are independent, samples inside one are not, and the model's own error
   differs from episode to episode), a profile point is inside instead when the episodes do not
   show it worse than the best point: the mean over episodes of the per-episode SSE increase is
   at most t(0.975, E - 1) times its standard error (a paired test across the E episodes). A
   tilt is named only when an angle's
   interval excludes 0. The other parameters' intervals are from the Jacobian of every parameter
   at the fit (marginal), with the same ``n_eff`` (reported, not used to name anything).

The caller's ``simulate`` never needs a robot's definition; the fit never reads one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

CHI2_95_1DOF = 3.841458820694124  # 95 % quantile of chi-square with 1 degree of freedom


@dataclass(frozen=True)
class JointTiltFit:
    values: np.ndarray      # (2 + m,) the fit: tilt angles [rad], then the other parameters
    intervals: np.ndarray   # (2 + m, 2) 95 %: profile (tilt angles), Jacobian (the others)
    rms_start: float        # RMS residual at zero tilt, the others at x0
    rms_fit: float          # RMS residual at the fit
    profiles: tuple[tuple[np.ndarray, np.ndarray], ...]  # per tilt angle: (angle grid, SSE)
    inside: tuple[np.ndarray, ...]  # per tilt angle: which profile points passed the test
    threshold: float        # profile SSE at or under which an angle is inside (no groups)
    n_eff: float            # effective number of independent residual samples
    grid_best: np.ndarray   # the best tilt of the global grid
    evaluations: int        # calls of simulate

    @property
    def named(self) -> bool:
        """A tilt is named when an angle's 95 % profile interval excludes 0."""
        iv = self.intervals[:2]
        return bool(np.any((iv[:, 0] > 0) | (iv[:, 1] < 0)))


def effective_samples(r: np.ndarray) -> float:
    """``len(r)`` over the integrated autocorrelation time of ``r`` (1 + 2 sum of the
    autocorrelations up to the first non-positive one; Geyer's initial positive sequence)."""
    r = np.asarray(r, float).ravel()
    n = r.size
    r = r - r.mean()
    var = float(np.dot(r, r)) / n
    if n < 3 or var == 0.0:
        return float(max(n, 1))
    tau = 1.0
    for lag in range(1, n // 2):
        rho = float(np.dot(r[:-lag], r[lag:])) / (n * var)
        if rho <= 0:
            break
        tau += 2 * rho
    return max(n / tau, 1.0)


class _Cost:
    """The residual of ``simulate`` against ``observed``, counting calls."""

    def __init__(self, simulate: Callable[[np.ndarray], np.ndarray], observed: np.ndarray):
        self.simulate = simulate
        self.observed = np.asarray(observed, float).ravel()
        self.calls = 0

    def residual(self, x: np.ndarray) -> np.ndarray:
        self.calls += 1
        out = np.asarray(self.simulate(np.asarray(x, float)), float).ravel()
        if out.shape != self.observed.shape:
            raise ValueError(f"simulate returned {out.size} samples; the observed trace has "
                             f"{self.observed.size}")
        return out - self.observed


def _jacobian(cost: _Cost, x: np.ndarray, r: np.ndarray, free: np.ndarray, step: np.ndarray,
              upper: np.ndarray) -> np.ndarray:
    jac = np.zeros((r.size, free.size))
    for col, k in enumerate(free):
        h = step[k] if x[k] + step[k] <= upper[k] else -step[k]  # stay inside the bounds
        d = np.zeros_like(x)
        d[k] = h
        jac[:, col] = (cost.residual(x + d) - r) / h
    return jac


def _refine(cost: _Cost, x: np.ndarray, r: np.ndarray, free: np.ndarray, lower: np.ndarray,
            upper: np.ndarray, step: np.ndarray, max_step: np.ndarray, iterations: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Bounded Gauss-Newton over the ``free`` parameters from ``x`` (residual ``r`` there)."""
    for _ in range(iterations):
        jac = _jacobian(cost, x, r, free, step, upper)
        scale = np.maximum(np.linalg.norm(jac, axis=0), 1e-12)  # columns of unlike units
        delta_s, *_ = np.linalg.lstsq(jac / scale, -r, rcond=None)
        delta = delta_s / scale
        ratio = np.max(np.abs(delta) / max_step[free])
        if ratio > 1:
            delta = delta / ratio
        improved = False
        for shrink in (1.0, 0.5, 0.25):
            trial = x.copy()
            trial[free] = np.clip(x[free] + shrink * delta, lower[free], upper[free])
            r_trial = cost.residual(trial)
            if np.sum(r_trial ** 2) < np.sum(r ** 2):
                x, r, improved = trial, r_trial, True
                break
        if not improved or np.max(np.abs(delta) / step[free]) < 1e-3:
            break
    return x, r


def _paired_inside(residuals: list[np.ndarray], best: np.ndarray, groups: np.ndarray
                   ) -> np.ndarray:
    """Profile points the episodes do not show worse than ``best`` (paired t across them)."""
    from scipy.stats import t as student

    labels, index = np.unique(groups, return_inverse=True)
    e = labels.size
    if e < 2:
        raise ValueError("groups: need at least 2 episodes for the paired test")
    base = np.bincount(index, best ** 2, minlength=e)
    crit = float(student.ppf(0.975, e - 1))
    out = []
    for r in residuals:
        d = np.bincount(index, r ** 2, minlength=e) - base
        out.append(d.mean() <= crit * d.std(ddof=1) / np.sqrt(e))
    return np.asarray(out, bool)


def _hull(grid: np.ndarray, sse: np.ndarray, inside_mask: np.ndarray) -> tuple[float, float]:
    inside = np.flatnonzero(inside_mask)
    if inside.size == 0:  # the profile's minimum itself: the fit's own point is inside
        inside = np.array([int(np.argmin(sse))])
    half = 0.5 * (grid[1] - grid[0]) if grid.size > 1 else 0.0
    lo = -np.inf if inside[0] == 0 else grid[inside[0]] - half
    hi = np.inf if inside[-1] == grid.size - 1 else grid[inside[-1]] + half
    return float(lo), float(hi)


def fit_tilt_jointly(simulate: Callable[[np.ndarray], np.ndarray], observed: np.ndarray,
                     x0: Sequence[float], lower: Sequence[float], upper: Sequence[float],
                     step: Sequence[float], max_step: Sequence[float] | None = None,
                     grid: Sequence[float] = tuple(np.linspace(-0.1, 0.1, 9)), starts: int = 2,
                     iterations: int = 8, profile_half: float = 0.06, profile_points: int = 13,
                     profile_iterations: int = 2, groups: Sequence[int] | None = None
                     ) -> JointTiltFit:
    """Fit ``x = (ax, ay, others...)`` (module docstring). ``x0``: the start of the others (its
    first two entries, the tilt, are ignored: the grid sets them); ``lower``/``upper``: bounds of
    every parameter; ``step``: finite-difference steps; ``max_step``: largest Gauss-Newton step
    per parameter (default 10 x ``step``); ``groups``: the episode of every sample of the
    trace (the paired profile test; default: the likelihood ratio over ``n_eff``)."""
    x0 = np.asarray(x0, float).copy()
    lower, upper, step = (np.asarray(v, float) for v in (lower, upper, step))
    n = x0.size
    if n < 2 or not (lower.size == upper.size == step.size == n):
        raise ValueError(f"x0, lower, upper, step need the same length >= 2 (tilt first); got "
                         f"{n}, {lower.size}, {upper.size}, {step.size}")
    if np.any(lower > upper) or np.any(step <= 0):
        raise ValueError("need lower <= upper and step > 0 for every parameter")
    max_step = 10 * step if max_step is None else np.asarray(max_step, float)
    cost = _Cost(simulate, observed)
    everything = np.arange(n)

    x_start = x0.copy()
    x_start[:2] = 0.0
    r_start = cost.residual(np.clip(x_start, lower, upper))
    # 1. the global start: a grid over the tilt
    grid = np.asarray(grid, float)
    points = []
    for ax in grid:
        for ay in grid:
            x = x0.copy()
            x[:2] = ax, ay
            x = np.clip(x, lower, upper)
            r = cost.residual(x)
            points.append((float(np.sum(r ** 2)), x, r))
    points.sort(key=lambda p: p[0])
    grid_best = points[0][1][:2].copy()
    # 2. local refinement from the best grid points
    best_x, best_r = points[0][1], points[0][2]
    for _, x, r in points[:starts]:
        x, r = _refine(cost, x, r, everything, lower, upper, step, max_step, iterations)
        if np.sum(r ** 2) < np.sum(best_r ** 2):
            best_x, best_r = x, r
    # 3. profiles of the two tilt angles, around the best point; a profile point better than it
    # becomes the best and the profiles are made again around it (at most 3 rounds)
    for _ in range(3):
        start_sse = float(np.sum(best_r ** 2))
        profiles, profile_r = [], []
        for k in range(2):
            others = np.setdiff1d(everything, [k])
            g = np.unique(np.clip(best_x[k] + np.linspace(-profile_half, profile_half,
                                                          profile_points), lower[k], upper[k]))
            sse = np.zeros(g.size)
            kept = []
            for i, value in enumerate(g):
                x = best_x.copy()
                x[k] = value
                r = cost.residual(x)
                x, r = _refine(cost, x, r, others, lower, upper, step, max_step,
                               profile_iterations)
                sse[i] = float(np.sum(r ** 2))
                kept.append(r)
                if sse[i] < np.sum(best_r ** 2):  # the profile found a better point
                    best_x, best_r = x, r
            profiles.append((g, sse))
            profile_r.append(kept)
        if float(np.sum(best_r ** 2)) >= start_sse:
            break
    sse_min = float(np.sum(best_r ** 2))
    n_eff = effective_samples(best_r)
    threshold = sse_min * float(np.exp(CHI2_95_1DOF / n_eff))
    if groups is not None:
        groups = np.asarray(groups).ravel()
        if groups.size != best_r.size:
            raise ValueError(f"groups has {groups.size} labels for {best_r.size} samples")
        inside = tuple(_paired_inside(profile_r[k], best_r, groups) for k in range(2))
    else:
        inside = tuple(profiles[k][1] <= threshold for k in range(2))
    intervals = np.zeros((n, 2))
    for k in range(2):
        lo, hi = _hull(profiles[k][0], profiles[k][1], inside[k])
        intervals[k] = min(lo, best_x[k]), max(hi, best_x[k])  # after 3 rounds: hold the fit
    if n > 2:  # the others: Jacobian intervals at the fit (marginal over every parameter)
        jac = _jacobian(cost, best_x, best_r, everything, step, upper)
        sigma2 = sse_min / max(best_r.size - n, 1)  # per-sample variance
        info = jac.T @ jac * (n_eff / best_r.size)  # correlated samples count as n_eff
        if np.linalg.cond(info) > 1e12:
            half = np.full(n, np.inf)
        else:
            half = 1.96 * np.sqrt(np.maximum(np.diag(sigma2 * np.linalg.inv(info)), 0.0))
        intervals[2:] = np.stack([best_x[2:] - half[2:], best_x[2:] + half[2:]], axis=1)
    rms = lambda r: float(np.sqrt(np.mean(r ** 2)))  # noqa: E731
    return JointTiltFit(best_x, intervals, rms(r_start), rms(best_r), tuple(profiles), inside,
                        threshold, n_eff, grid_best, cost.calls)
