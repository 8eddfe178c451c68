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
    assert c[0] == pytest.approx(t.u[0], abs=1e-12)
    assert h[0] == pytest.approx(half[0], rel=1e-9)


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
