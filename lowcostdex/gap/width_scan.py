"""A play's width on a jagged cost: one scan over its whole search range, smoothed along it.

With the servo's loop closed across the play (its encoder on the output shaft), the motor hunts
inside the play, and where it is in that hunt at each sample depends sensitively on the width:
the training cost is jagged in the width at a scale far below the width's size. Measured on the
third truth simulator's srv_backlash_output (play 0.05 rad, loop on the output shaft; sensor 1,
2 ms, RMS residual over the train + select segments): 6.03 mrad at 0.0382, 7.43 at 0.0410, 4.54
at 0.0485, 6.47 at 0.0500, 4.81 at 0.0525, under a trend that falls from 9.5 mrad at 0.025 into a
valley over ~0.045-0.058 and rises to 8-9 mrad past 0.06 (grid of 0.0005, 2026-11-27). Levenberg-
Marquardt stops in whichever dip lies nearest its start, so the fitted width followed the search
path (0.0332 in one code version, 0.0382 in the next, both 'exact' names), and the profile
interval, which ends at the first rise past its threshold, stayed inside that dip ([0.0358,
0.0406]).

The statistics here treat the jaggedness as what it is, noise of the cost along the width:

- ``scan``: each play width over ``POINTS`` values spanning its search range (the others fixed,
  one batched replay), the costs smoothed by a centred moving mean of ``K`` neighbours, and the
  jaggedness: the robust spread of the cost about a local quadratic (a smooth or kinked cost has
  none).
- ``valley``: only where the cost is jagged (the smoothed cost's own 95 % uncertainty, 1.96
  sqrt(2 / K) x the jaggedness for a difference of two means of K, exceeds ``delta``, the
  profile's threshold from the data's noise): the widths whose smoothed cost is within ``delta``
  + that uncertainty of its lowest smoothed value. Smooth and kinked costs keep the profile
  interval as it was.
- ``restart``: the fit restarted at the lowest scanned width inside the valley when the fit
  lies outside the valley or a scanned width is lower, and kept if it ends lower (by more than
  ``TIE``) than the fit it was: a smooth cost's fit is kept as it was.

Costs are 0.5 x the sum of squared residuals (rad^2), widths in the optimizer's coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.diagnostics import effective_n

POINTS = 81   # scanned widths per play (1.25 mrad apart on the catalogue's 0-0.1 rad range)
K = 5         # neighbours in the moving mean (+-2 grid points)
WIDTH = ("backlash", "width")
TIE = 1e-4    # a cost lower by at most this fraction is no lower (``significance.TIE``)


@dataclass(frozen=True)
class Scan:
    """Costs of one width scalar ``index`` over ``grid`` (optimizer coordinates)."""

    index: int
    grid: np.ndarray
    cost: np.ndarray
    smooth: np.ndarray
    jagged: float  # the cost's robust spread about a local quadratic (``smooth``)

    def allowance(self) -> float:
        """95 % uncertainty of a difference of two smoothed costs from the jaggedness."""
        return 1.96 * math.sqrt(2.0 / K) * self.jagged

    def valley(self, delta: float) -> tuple[float, float]:
        """(lo, hi) of the widths whose smoothed cost is within ``delta`` + ``allowance`` of
        its minimum (the hull: a valley with a bump is one); (nan, nan) when the cost is not
        jagged at the scale of ``delta`` (its allowance is at most ``delta``: the profile
        interval's own steps see it)."""
        ok = np.isfinite(self.smooth)
        if not np.any(ok) or not self.allowance() > delta:
            return math.nan, math.nan
        bar = float(np.min(self.smooth[ok])) + delta + self.allowance()
        inside = self.grid[ok & (self.smooth <= bar)]
        return float(inside.min()), float(inside.max())


# a local quadratic's value at the centre of K = 5 points (Savitzky-Golay); white jitter of
# standard deviation sigma leaves a residual of variance SG_VAR sigma^2 about it
_SG = np.array([-3.0, 12.0, 17.0, 12.0, -3.0]) / 35.0
_SG_VAR = float((1 - _SG[2]) ** 2 + np.sum(np.delete(_SG, 2) ** 2))


def smooth(cost: np.ndarray, k: int = K) -> tuple[np.ndarray, float]:
    """Centred moving mean of ``cost`` over ``k`` (= 5) points (truncated at the ends;
    non-finite costs left out), and the cost's jaggedness: the robust standard deviation
    (1.4826 x the median absolute deviation) of the cost about a local quadratic through each
    full window, as white jitter would have it. A piecewise quadratic cost (a smooth cost, a
    kink) has none away from its kinks, and the median ignores those few windows."""
    c = np.asarray(cost, float)
    h = k // 2
    out = np.full(len(c), np.nan)
    dev = []
    for i in range(len(c)):
        w = c[max(0, i - h):i + h + 1]
        fin = w[np.isfinite(w)]
        if len(fin):
            out[i] = float(np.mean(fin))
        if h <= i < len(c) - h and np.all(np.isfinite(w)):
            dev.append(w[h] - float(_SG @ w))
    if len(dev) < 3:
        return out, 0.0
    dev = np.asarray(dev)
    mad = float(np.median(np.abs(dev - np.median(dev))))
    return out, 1.4826 * mad / math.sqrt(_SG_VAR)


def scan(t: fitmod.Track, residual: fitmod.ResidualFn, points: int = POINTS) -> list[Scan]:
    """Each play width of ``t`` scanned over its search range (others at ``t``'s values), all
    in one batched evaluation of ``residual``."""
    s = t.structure
    lo, hi = s.u_bounds()
    idx = [i for i, f in enumerate(s.free) if (f.effect, f.param) == WIDTH and hi[i] > lo[i]]
    if not idx:
        return []
    grids = {i: np.linspace(lo[i], hi[i], points) for i in idx}
    pts = []
    for i in idx:
        for v in grids[i]:
            u = np.array(t.u, float)
            u[i] = v
            pts.append((s, s.x(u)))
    res = residual(pts)
    out, k = [], 0
    for i in idx:
        c = np.array([0.5 * float(r @ r) for r in res[k:k + points]])
        c[~np.isfinite(c)] = np.nan
        k += points
        sm, jag = smooth(c)
        out.append(Scan(i, grids[i], c, sm, jag))
    return out


def delta(t: fitmod.Track, half: np.ndarray, i: int) -> float:
    """The rise of a linear model's cost at the edge of scalar i's 95 % interval of half-width
    ``half[i]`` (``significance.profile_interval``'s threshold): half_i^2 / (2 [(J^T J)^-1]_ii)."""
    ainv = np.linalg.pinv(t.jac.T @ t.jac)
    return 0.5 * float(half[i]) ** 2 / max(float(ainv[i, i]), 1e-300)


def restart(t: fitmod.Track, residual: fitmod.ResidualFn, max_rounds: int, rtol: float = 1e-5
            ) -> fitmod.Track:
    """``t``, or ``t`` refitted from the lowest scanned width inside each play's valley when
    that fit ends at a lower cost (``t`` needs ``r`` and ``jac`` at its optimum; the valley's
    threshold from its residual-noise half-widths)."""
    if t.r is None or t.jac is None:
        return t
    scans = scan(t, residual)
    if not scans:
        return t
    half = fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r))
    u = np.array(t.u, float)
    for sc in scans:
        lo, hi = sc.valley(delta(t, half, sc.index))
        if not math.isfinite(lo):
            continue
        inside = (sc.grid >= lo) & (sc.grid <= hi) & np.isfinite(sc.cost)
        if not np.any(inside):
            continue
        j = int(np.flatnonzero(inside)[np.argmin(sc.cost[inside])])
        if not lo <= t.u[sc.index] <= hi or sc.cost[j] < (1 - TIE) * t.cost:
            u[sc.index] = sc.grid[j]
    if np.array_equal(u, t.u):
        return t
    nt = fitmod.Track(t.structure, u, label=t.label + " width scan")
    fitmod.lockstep_lm([nt], residual, max_rounds, rtol=rtol)
    return nt if nt.r is not None and nt.cost < (1 - TIE) * t.cost else t
