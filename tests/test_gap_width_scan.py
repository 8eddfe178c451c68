"""A play's width on a jagged cost (``gap.width_scan``): the fit restarted in the cost's valley
and the width's interval holding that valley.

The truth is written out here: least-squares problems whose residual is a formula of the width
(no replay, no MuJoCo). The jagged one is a bowl with its minimum at W_TRUE plus a ripple of
1.5 mrad period (its phase drifting along the data), as the third truth simulator's srv_backlash_output cost is (the motor hunting
inside the play with the loop on the output shaft): Levenberg-Marquardt started at 0.037 stops
in a ripple's dip, as the analysis stopped at 0.0332 / 0.0382 for a true 0.05.
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance as sig
from lowcostdex.gap import width_scan
from lowcostdex.gap.diagnostics import effective_n

N = 400
W_TRUE = 0.050  # [rad]


def _structure() -> fitmod.Structure:
    free = [fitmod.Free("backlash", "width", 0, 0.0, 0.1, 0.01, False, 2e-4)]
    return fitmod.Structure(("backlash",), ("j",), free)


def _width(s, x) -> float:
    return float(s.to_effects(x)[0].values["width"][0])


def _residual(seed: int, ripple: float):
    y = np.random.default_rng(seed).normal(0.0, 0.01, N)
    y -= y.mean()
    phase = np.linspace(0.0, 2.0, N)  # the ripple's phase drifts along the data

    def fn(points):
        out = []
        for s, x in points:
            w = _width(s, x)
            out.append(y + 3.0 * (w - W_TRUE) + ripple * np.sin(2 * np.pi * w / 0.0015 + phase))
        return out

    return fn


def _fit(fn, start: float) -> fitmod.Track:
    s = _structure()
    t = fitmod.Track(s, s.u(np.array([start])))
    fitmod.lockstep_lm([t], fn, 60, rtol=1e-12)
    return t


def _half(t):
    return fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_width_stuck_in_a_ripple_is_restarted_in_the_valley(seed):
    fn = _residual(seed, 0.008)
    t = _fit(fn, 0.037)
    stuck = _width(t.structure, t.x)
    assert abs(stuck - W_TRUE) > 0.008, stuck  # the trap is real: LM alone stays in a dip
    nt = width_scan.restart(t, fn, 60)
    assert nt.cost < t.cost
    assert _width(nt.structure, nt.x) == pytest.approx(W_TRUE, abs=1.5e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_interval_of_a_width_stuck_in_a_ripple_holds_the_valley(seed):
    fn = _residual(seed, 0.008)
    t = _fit(fn, 0.037)
    half = _half(t)
    lo0, hi0 = t.u[0] - half[0], t.u[0] + half[0]
    assert not lo0 <= W_TRUE <= hi0  # the linearised interval misses the truth
    c, h = sig.profile_interval(t, lambda: fn, half, scan=True)
    lo, hi = c[0] - h[0], c[0] + h[0]
    assert lo <= W_TRUE <= hi, (lo, hi)
    assert lo <= _width(t.structure, t.x) <= hi
    assert hi - lo < 0.03  # the valley, not the whole range (0-0.1)


def test_a_smooth_width_keeps_its_fit_and_its_interval():
    fn = _residual(4, 0.0)
    t = _fit(fn, 0.037)
    assert _width(t.structure, t.x) == pytest.approx(W_TRUE, abs=1e-3)
    assert width_scan.restart(t, fn, 60) is t
    half = _half(t)
    c, h = sig.profile_interval(t, lambda: fn, half, scan=True)
    # the scan changes nothing on a smooth width: the same interval as the profile alone
    c0, h0 = sig.profile_interval(t, lambda: fn, half, scan=False)
    assert c[0] == pytest.approx(c0[0], abs=1e-15) and h[0] == pytest.approx(h0[0], abs=1e-15)
    # and the profile of a quadratic cost is the linearised interval, to the refits'
    # convergence (numpy 2.4.6 / scipy 1.17.1: the edge 7.1e-12 rad = 2.3e-8 of half beyond it)
    assert c[0] == pytest.approx(t.u[0], abs=1e-6 * half[0])
    assert h[0] == pytest.approx(half[0], rel=1e-6)


def test_the_jaggedness_of_a_bowl_a_kink_and_white_jitter():
    w = np.linspace(0.0, 0.1, 401)
    bowl = (w - 0.05) ** 2
    kinked = np.where(w > 0.03, (w - 0.03) ** 2, 0.01 * (w - 0.03) ** 2)
    assert width_scan.smooth(bowl)[1] == pytest.approx(0.0, abs=1e-15)
    assert width_scan.smooth(kinked)[1] == pytest.approx(0.0, abs=1e-15)
    jitter = np.random.default_rng(7).normal(0.0, 1e-4, len(w))
    assert width_scan.smooth(bowl + jitter)[1] == pytest.approx(1e-4, rel=0.25)


def test_a_smooth_or_kinked_cost_has_no_valley():
    w = np.linspace(0.0, 0.1, 81)
    for cost in ((w - 0.05) ** 2, np.where(w > 0.03, (w - 0.03) ** 2, 0.01 * (w - 0.03) ** 2)):
        sm, jag = width_scan.smooth(cost)
        sc = width_scan.Scan(0, w, cost, sm, jag)
        assert np.isnan(sc.valley(1e-6)[0])


def _counted(fn):
    seen = []

    def wrapped(points):
        seen.append(len(points))
        return fn(points)

    return wrapped, seen


def test_a_smooth_width_is_screened_on_the_coarse_grid_only():
    # the full scan (81 widths, 1.25 mrad apart) only where the 17-point screen (every 5th)
    # sees jaggedness near the threshold: a smooth cost costs 17 replays, not 81
    fn = _residual(4, 0.0)
    t = _fit(fn, 0.037)
    d = width_scan.delta(t, _half(t), 0)
    counted, seen = _counted(fn)
    (sc,) = width_scan.scan(t, counted, {0: d})
    assert seen == [17]
    assert np.allclose(sc.grid, np.linspace(0.0, 0.1, 81)[::5])
    assert np.isnan(sc.valley(d)[0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_jagged_width_gets_the_whole_grid_with_the_screen_reused(seed):
    fn = _residual(seed, 0.008)
    t = _fit(fn, 0.037)
    d = width_scan.delta(t, _half(t), 0)
    counted, seen = _counted(fn)
    (sc,) = width_scan.scan(t, counted, {0: d})
    assert seen == [17, 64]  # the screen's 17 widths are not replayed again
    grid = np.linspace(0.0, 0.1, 81)
    assert np.array_equal(sc.grid, grid)
    s = t.structure
    direct = [0.5 * float(r @ r) for r in fn([(s, s.x(np.array([w]))) for w in grid])]
    assert np.allclose(sc.cost, direct, rtol=1e-12, atol=0.0)
    assert np.isfinite(sc.valley(d)[0])


@pytest.mark.parametrize("ratio, most", [(1.0, 2), (1.5, 0)])
def test_the_screen_passes_white_jitter_at_the_threshold_to_the_whole_grid(ratio, most):
    # white jitter whose smoothed-cost uncertainty (1.96 sqrt(2/5) sigma) is ``ratio`` x the
    # threshold: at 1 the full scan's own verdict is a coin toss; the 17-point screen's
    # estimate of sigma is noisy (13 windows; its 1st percentile ~0.28 sigma), hence its margin
    # SCREEN: over 200 seeded draws at most ``most`` are screened out
    w = np.linspace(0.0, 0.1, 81)
    sigma = 1e-4
    d = 1.96 * np.sqrt(2.0 / width_scan.K) * sigma / ratio
    rng = np.random.default_rng(11)
    out = 0
    for _ in range(200):
        cost = (w - 0.05) ** 2 + rng.normal(0.0, sigma, len(w))
        _, jag = width_scan.smooth(cost[::width_scan.COARSE])
        out += not 1.96 * np.sqrt(2.0 / width_scan.K) * jag > d / width_scan.SCREEN
    assert out <= most


def _steep(seed: int):
    # a steep bowl (the main job's D'Claw widths: the cost rises ~1e-3 per 1.25 mrad grid step
    # off its minimum) with a faint ripple: jagged by the allowance, its valley one grid width
    y = np.random.default_rng(seed).normal(0.0, 0.01, N)
    y -= y.mean()
    phase = np.linspace(0.0, 2.0, N)

    def fn(points):
        return [y + 60.0 * (_width(s, x) - 0.0506) + 2e-5 * np.sin(2 * np.pi * _width(s, x)
                                                                    / 0.0015 + phase)
                for s, x in points]

    return fn


def test_a_fit_within_a_grid_step_of_a_one_width_valley_is_not_refitted():
    fn = _steep(3)
    t = _fit(fn, 0.037)
    assert _width(t.structure, t.x) == pytest.approx(0.0506, abs=2e-4)  # between grid widths
    half = _half(t)
    d = width_scan.delta(t, half, 0)
    (sc,) = width_scan.scan(t, fn, {0: d})
    lo, hi = sc.valley(d)
    assert lo == hi == pytest.approx(0.05, abs=1e-12)  # jagged, but the valley is one width
    width_scan._LAST.clear()
    counted, seen = _counted(fn)
    assert width_scan.restart(t, counted, 60) is t
    assert seen == [17, 64]  # the scan only: no Levenberg-Marquardt from 0.05


def test_the_interval_reuses_the_restart_scan_of_the_same_fit():
    fn = _steep(3)
    t = _fit(fn, 0.037)
    half = _half(t)
    width_scan._LAST.clear()
    fresh = sig.profile_interval(t, lambda: fn, half, scan=True)
    counted, seen = _counted(fn)
    assert width_scan.restart(t, counted, 60) is t
    n = len(seen)
    again = sig.profile_interval(t, lambda: counted, half, scan=True)
    assert 17 not in seen[n:] and 64 not in seen[n:]  # no second scan
    assert np.array_equal(fresh[0], again[0]) and np.array_equal(fresh[1], again[1])
    t.u = t.u + 1e-4  # moved (a polish): scanned again
    sig.profile_interval(t, lambda: counted, half, scan=True)
    assert 17 in seen


def _banded(amp_near: float, amp_far: float) -> tuple[np.ndarray, np.ndarray]:
    """A bowl with its minimum at 0.035 (0.02 + 20 (w - 0.035)^2) and a jitter (+-amp
    alternating along the 81-width grid) whose size depends on the width: none below 0.0125 (a
    play too narrow to hunt in), ``amp_near`` within 0.01 of the minimum, ``amp_far`` beyond: as
    sim5 backlash2deg_pendulum_500hz_us's cost is (smooth from 0.066 at no play down to ~0.045
    at 0.0125, jagged above; widths far from the play jitter most)."""
    w = np.linspace(0.0, 0.1, 81)
    amp = np.where(w < 0.0125, 0.0, np.where(abs(w - 0.035) <= 0.01, amp_near, amp_far))
    return w, 0.02 + 20.0 * (w - 0.035) ** 2 + (-1.0) ** np.arange(len(w)) * amp


def test_the_valley_judges_each_width_with_the_jaggedness_where_it_lies():
    w, cost = _banded(0.001, 0.02)
    sm, jag = width_scan.smooth(cost)
    sc = width_scan.Scan(0, w, cost, sm, jag)
    loc = width_scan.local_jaggedness(cost, jag)
    assert loc[0] < 1e-3 * jag  # smooth at the smallest widths ...
    assert sc.allowance() > 20.0 * 0.035 ** 2  # ... though one spread admits no play at all
    lo_g, hi_g = sc.valley(1e-3, local=False)
    assert lo_g == 0.0  # the defect: a valley reaching no play
    lo, hi = sc.valley(1e-3)
    assert 0.01 < lo <= 0.035 <= hi  # the minimum held, no play excluded
    assert lo_g <= lo and hi <= hi_g  # never wider than the one-spread valley


def test_a_uniform_jaggedness_gives_the_one_spread_valley():
    w, cost = _banded(0.02, 0.02)
    cost = np.where(w < 0.0125, cost + (-1.0) ** np.arange(len(w)) * 0.02, cost)
    sm, jag = width_scan.smooth(cost)
    sc = width_scan.Scan(0, w, cost, sm, jag)
    assert sc.valley(1e-3) == sc.valley(1e-3, local=False)
