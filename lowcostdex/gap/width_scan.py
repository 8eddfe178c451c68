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
  batched replays), the costs smoothed by a centred moving mean of ``K`` neighbours, and the
  jaggedness: the robust spread of the cost about a local quadratic (a smooth or kinked cost has
  none). Screened first on every ``COARSE``-th grid width: a cost whose jaggedness there is far
  below the threshold (by ``SCREEN``) has no valley and is not scanned further, so a smooth
  width costs 17 replays instead of 81 (the main job's gap stage paid 81 per width on every
  final fit and interval: 385 -> 570 s).
- ``valley``: only where the cost is jagged (the smoothed cost's own 95 % uncertainty, 1.96
  sqrt(2 / K) x the jaggedness for a difference of two means of K, exceeds ``delta``, the
  profile's threshold from the data's noise): the widths whose smoothed cost is within ``delta``
  + that uncertainty of its lowest smoothed value. Smooth and kinked costs keep the profile
  interval as it was. The interval's valley judges each width with the jaggedness where it
  lies (``local``: the robust spread over +-``LOCAL`` grid widths), the difference of two
  means of K with their own spreads: 1.96 sqrt((s_k^2 + s_min^2) / K). A play hunts only
  where the width lets it: the cost is jagged near the play's size and smooth far below it,
  and one spread for the whole range let a smooth, high cost at small widths into the valley
  (sim5 backlash2deg_pendulum_500hz_us, width 0.0299 for 0.0349: smoothed cost 0.065 at 0
  against 0.044 at its lowest, global allowance 0.030, valley [0, 0.040] although the play's
  removal costs 78.5 x the data's threshold; local spreads 0.0005 near 0 and 0.0012 at the
  lowest smoothed cost: valley [0.0125, 0.0388]). A local spread is capped at the whole
  range's, so the valley is never wider than before: where the cost's jitter grows with the
  cost (far above the play's size) an uncapped local spread let high costs in. The restart
  keeps the global spread (a wider valley there only offers more restarts, each kept only if
  it lowers the cost).
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
COARSE = 5    # the screen scans every 5th of them (17: 6.25 mrad apart)
SCREEN = 4.0  # the full scan runs when the screen's allowance exceeds delta / SCREEN
K = 5         # neighbours in the moving mean (+-2 grid points)
LOCAL = 5     # the valley's local jaggedness: the spread over +-5 grid widths (11 windows)
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

    def valley(self, delta: float, local: bool = True) -> tuple[float, float]:
        """(lo, hi) of the widths whose smoothed cost is within ``delta`` + the allowance of
        its minimum (the hull: a valley with a bump is one); (nan, nan) when the cost is not
        jagged at the scale of ``delta`` (its allowance is at most ``delta``: the profile
        interval's own steps see it). The allowance of width k: with ``local``, 1.96
        sqrt((s_k^2 + s_m^2) / K) from the local spreads s (``local_jaggedness``, each at most
        ``jagged``) at k and at the lowest smoothed cost m; else ``allowance`` (one spread for
        the whole range)."""
        ok = np.isfinite(self.smooth)
        if not np.any(ok) or not self.allowance() > delta:
            return math.nan, math.nan
        m = int(np.flatnonzero(ok)[np.argmin(self.smooth[ok])])
        allow = self.allowance()
        if local:  # never above the whole range's spread: never wider than that valley
            s = np.minimum(local_jaggedness(self.cost, self.jagged), self.jagged)
            allow = 1.96 * np.sqrt((s ** 2 + s[m] ** 2) / K)
        inside = self.grid[ok & (self.smooth <= self.smooth[m] + delta + allow)]
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


def local_jaggedness(cost: np.ndarray, fallback: float, m: int = LOCAL) -> np.ndarray:
    """Per grid width, ``smooth``'s jaggedness from the windows centred within +-``m`` grid
    widths of it only (the robust spread of the cost about a local quadratic, as white jitter
    would have it); ``fallback`` (the whole range's) where fewer than 3 such windows are
    finite. A cost jagged in one band and smooth elsewhere gets its spread where it has it."""
    c = np.asarray(cost, float)
    h = K // 2
    dev = np.full(len(c), np.nan)
    for i in range(h, len(c) - h):
        w = c[i - h:i + h + 1]
        if np.all(np.isfinite(w)):
            dev[i] = w[h] - float(_SG @ w)
    out = np.full(len(c), float(fallback))
    for i in range(len(c)):
        d = dev[max(0, i - m):i + m + 1]
        d = d[np.isfinite(d)]
        if len(d) >= 3:
            out[i] = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(_SG_VAR)
    return out


def scan(t: fitmod.Track, residual: fitmod.ResidualFn, deltas: dict[int, float],
         points: int = POINTS) -> list[Scan]:
    """Each play width ``i`` of ``t`` in ``deltas`` scanned over its search range (others at
    ``t``'s values), screened first: every ``COARSE``-th of the ``points`` grid widths (one
    batched evaluation of ``residual``), and the rest of the grid (one more) only for a width
    whose screen's jaggedness is not well below its threshold ``deltas[i]`` (its allowance
    above ``deltas[i]`` / ``SCREEN``). A screened-out width's ``Scan`` holds the coarse grid:
    no valley at ``deltas[i]``."""
    s = t.structure
    lo, hi = s.u_bounds()
    idx = [i for i, f in enumerate(s.free)
           if (f.effect, f.param) == WIDTH and hi[i] > lo[i] and i in deltas]
    kept = _kept(t, points, deltas)
    if kept is not None and sorted(kept) == idx:
        return [kept[i] for i in idx]
    grids = {i: np.linspace(lo[i], hi[i], points) for i in idx}
    coarse = np.arange(0, points, COARSE)
    cost = {i: np.full(points, np.nan) for i in idx}
    _costs(t, residual, {i: coarse for i in idx}, grids, cost)
    out, full = [], []
    for i in idx:
        sm, jag = smooth(cost[i][coarse])
        sc = Scan(i, grids[i][coarse], cost[i][coarse], sm, jag)
        if sc.allowance() > deltas[i] / SCREEN:
            full.append(i)
        else:
            out.append(sc)
    rest = np.setdiff1d(np.arange(points), coarse)
    _costs(t, residual, {i: rest for i in full}, grids, cost)
    for i in full:
        sm, jag = smooth(cost[i])
        out.append(Scan(i, grids[i], cost[i], sm, jag))
    out = sorted(out, key=lambda sc: sc.index)
    _LAST[:] = [t, np.array(t.u, float), points, out]
    return out


# the last scan: the analysis scans its final fit for the restart and, when the fit stayed
# where it was, again for the interval on the same train + select data (the main job's logs:
# 2 x 243 replays, 38 % of the analysis' wall time, the second identical to the first)
_LAST: list = []


def _kept(t: fitmod.Track, points: int, deltas: dict[int, float]) -> dict[int, Scan] | None:
    """The last ``scan``'s result when it was of this same track (object) at the same values
    and grid, each width screened out only where it still is at ``deltas``; else None."""
    if not _LAST or _LAST[0] is not t or _LAST[2] != points or not np.array_equal(_LAST[1], t.u):
        return None
    kept = {sc.index: sc for sc in _LAST[3] if sc.index in deltas}
    if any(len(sc.grid) < points and sc.allowance() > deltas[i] / SCREEN
           for i, sc in kept.items()):
        return None
    return kept


def _costs(t: fitmod.Track, residual: fitmod.ResidualFn, where: dict[int, np.ndarray],
           grids: dict[int, np.ndarray], cost: dict[int, np.ndarray]) -> None:
    """Fill ``cost[i][k]`` for k in ``where[i]``: 0.5 |r|^2 with scalar i at ``grids[i][k]``
    (one batched evaluation; non-finite as nan)."""
    pts, keys = [], []
    for i, ks in where.items():
        for k in ks:
            u = np.array(t.u, float)
            u[i] = grids[i][k]
            pts.append((t.structure, t.structure.x(u)))
            keys.append((i, int(k)))
    if not pts:
        return
    for (i, k), r in zip(keys, residual(pts), strict=True):
        c = 0.5 * float(r @ r)
        cost[i][k] = c if math.isfinite(c) else math.nan


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
    half = fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r))
    scans = scan(t, residual, {i: delta(t, half, i) for i, f in enumerate(t.structure.free)
                               if (f.effect, f.param) == WIDTH})
    if not scans:
        return t
    u = np.array(t.u, float)
    for sc in scans:
        lo, hi = sc.valley(delta(t, half, sc.index), local=False)
        if not math.isfinite(lo):
            continue
        inside = (sc.grid >= lo) & (sc.grid <= hi) & np.isfinite(sc.cost)
        if not np.any(inside):
            continue
        j = int(np.flatnonzero(inside)[np.argmin(sc.cost[inside])])
        step = float(sc.grid[1] - sc.grid[0])  # the valley's resolution: one grid step
        if not lo - step <= t.u[sc.index] <= hi + step or sc.cost[j] < (1 - TIE) * t.cost:
            u[sc.index] = sc.grid[j]
    if np.array_equal(u, t.u):
        return t
    nt = fitmod.Track(t.structure, u, label=t.label + " width scan")
    fitmod.lockstep_lm([nt], residual, max_rounds, rtol=rtol)
    return nt if nt.r is not None and nt.cost < (1 - TIE) * t.cost else t
