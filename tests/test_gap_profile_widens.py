"""The profile interval must actually widen where the cost is flatter than its linearisation.

``tests/test_gap_profile.py`` passes with ``profile_interval`` returning the linearised interval
unchanged (checked by hand at efd6dcc: all 7 tests pass with the profile switched off; a mutmut
sample of 60 of its 201 surviving mutants at 38eba05 killed 39): its kinked costs mostly land
where the two agree. Here the truth sits just above the kink of a play's cost (slope 1 above the
true width 0.03, 0.1 below: the play's gentle side), so the fit's Jacobian sees the steep side
and the linearised interval is ~10x too short below the fit; the brute-force profile (every
width on a fine grid, the other parameter refitted by hand: here there is none) is written out
in the test. The interval must reach down to it, not stop at the linearised end.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_gap_profile import N, _fit, _kinked, _structure

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance as sig


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_fit_just_above_the_kink_gets_the_gentle_sides_profile(seed):
    rng = np.random.default_rng(100 + seed)
    _, a, g = _kinked(np.zeros(N))  # the kinked response g(w) and its pattern a
    y = g(0.0305) * a + rng.normal(0, 0.01, N)  # the truth 0.5 mrad above the kink
    residual, a, g = _kinked(y)
    s = _structure(False)
    t = _fit(residual, s, [0.035])
    half = fitmod.interval_halfwidths(t.r, t.jac, N)
    assert t.x[0] > 0.03  # the fit is on the steep side
    centre, h = sig.profile_interval(t, lambda: residual, half, 20)
    grid = np.linspace(0.0, 0.1, 20001)
    cost = np.array([0.5 * float(r @ r) for r in residual([(s, np.array([w])) for w in grid])])
    delta = 0.5 * half[0] ** 2 * float(t.jac[:, 0] @ t.jac[:, 0])
    ok = grid[cost - min(cost.min(), t.cost) <= delta]
    lin_lo = t.x[0] - half[0]
    assert ok.min() < lin_lo - 2 * half[0]  # by hand: the gentle side holds ~10x further
    lo = centre[0] - h[0]
    # the profile reaches the brute-force low end (to a quarter of the widening), far below
    # the linearised one; the high end stays the linearised one (the steep side agrees)
    assert lo == pytest.approx(ok.min(), abs=0.25 * (lin_lo - ok.min()))
    assert centre[0] + h[0] == pytest.approx(max(ok.max(), t.x[0] + half[0]), abs=0.2 * half[0])
