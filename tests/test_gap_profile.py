"""The profile interval of a play's width (``significance.profile_interval``, issue 11 item 5).

The truth is written out here: small least-squares problems whose residual is a formula of the
parameters (no replay, no MuJoCo), with the answer computed by hand (a model linear in its
parameters: the profile interval IS the linearised one) or by brute force (a cost with a kink
at the true width, the shape of a play's cost: the Jacobian sees one slope, the data the other).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance as sig

N = 400
X = np.linspace(-1.0, 1.0, N)


def _structure(with_damping: bool) -> fitmod.Structure:
    free = [fitmod.Free("backlash", "width", 0, 0.0, 0.1, 0.01, False, 2e-4)]
    effects = ("backlash",)
    if with_damping:
        free.append(fitmod.Free("viscous_damping", "damping", 0, -0.2, 0.2, 0.0, False, 4e-4))
        effects += ("viscous_damping",)
    return fitmod.Structure(effects, ("j",), free)


def _values(structure, x) -> tuple[float, float]:
    by = {e.name: e for e in structure.to_effects(x)}
    w = float(by["backlash"].values["width"][0])
    c = float(by["viscous_damping"].values["damping"][0]) if "viscous_damping" in by else 0.0
    return w, c


def _fit(residual, structure, x0) -> fitmod.Track:
    t = fitmod.Track(structure, structure.u(np.asarray(x0, float)))
    fitmod.lockstep_lm([t], residual, 60, rtol=1e-12)
    return t


def test_a_linear_model_gets_its_linearised_interval_back():
    """y = 2 w + 0.5 c x + noise: the cost is exactly quadratic, so the profile over the width
    (the damping refitted at each held width) rises by Delta exactly at the linearised
    interval's edges and the hull is that interval (to the fit's tolerance)."""
    rng = np.random.default_rng(3)
    y = 2 * 0.03 + 0.5 * 0.05 * X + rng.normal(0, 0.01, N)

    def residual(points):
        out = []
        for s, x in points:
            w, c = _values(s, x)
            out.append(y - (2 * w + 0.5 * c * X))
        return out

    s = _structure(True)
    t = _fit(residual, s, [0.02, 0.0])
    half = fitmod.interval_halfwidths(t.r, t.jac, N)
    # by hand: w^ = mean(y) / 2 (X has zero mean), its variance s^2 / (4 N)
    assert t.x[0] == pytest.approx(np.mean(y) / 2, abs=1e-7)
    centre, h = sig.profile_interval(t, lambda: residual, half, 20)
    assert centre[0] == pytest.approx(t.u[0], abs=0.02 * half[0])
    assert h[0] == pytest.approx(half[0], rel=0.02)
    assert h[1] == half[1] and centre[1] == t.u[1]  # not a play's width: as given


def test_only_play_widths_are_profiled_and_the_residual_is_made_only_then():
    made = []
    t = fitmod.Track(fitmod.Structure(("viscous_damping",), ("j",), [fitmod.Free(
        "viscous_damping", "damping", 0, -0.2, 0.2, 0.0, False, 4e-4)]), np.zeros(1))
    t.r, t.jac = np.ones(3), np.ones((3, 1))
    c, h = sig.profile_interval(t, lambda: made.append(1), np.array([0.3]), 5)
    assert not made and c.tolist() == [0.0] and h.tolist() == [0.3]


def _kinked(y):
    """Residual of y = g(w) a_k: slope 1 above the true width 0.03, 0.1 below it (a play's cost:
    one side of the kink is gentle)."""
    a = 1.0 + 0.5 * X

    def g(w):
        d = w - 0.03
        return d if d >= 0 else 0.1 * d

    def residual(points):
        return [y - g(_values(s, x)[0]) * a for s, x in points]
    return residual, a, g


@pytest.mark.parametrize("seed", [0, 1, 2, 5])
def test_a_kinked_cost_gets_its_brute_force_profile(seed):
    """On either side of the kink (the fit lands on one side or the other with the noise), the
    interval is the hull of the linearised one and the brute-force profile set: every width on
    a fine grid (computed here) whose cost rises by at most the threshold the linearised
    interval stands for (its half-width squared over 2 (J^T J)^-1)."""
    rng = np.random.default_rng(seed)
    residual, a, g = _kinked(rng.normal(0, 0.01, N))
    s = _structure(False)
    t = _fit(residual, s, [0.035])
    half = fitmod.interval_halfwidths(t.r, t.jac, N)
    centre, h = sig.profile_interval(t, lambda: residual, half, 20)
    grid = np.linspace(0.0, 0.1, 20001)
    cost = np.array([0.5 * float(r @ r) for r in residual([(s, np.array([w])) for w in grid])])
    delta = 0.5 * half[0] ** 2 * float(t.jac[:, 0] @ t.jac[:, 0])
    ok = grid[cost - min(cost.min(), t.cost) <= delta]
    lo_x, hi_x = min(ok.min(), t.x[0] - half[0]), max(ok.max(), t.x[0] + half[0])
    tol = 0.1 * (hi_x - lo_x)
    assert centre[0] - h[0] == pytest.approx(lo_x, abs=tol)
    assert centre[0] + h[0] == pytest.approx(hi_x, abs=tol)
    assert h[0] >= half[0] - 1e-12  # never narrower than the linearised interval


def test_kinked_widths_are_covered_about_as_often_as_claimed():
    """Monte Carlo over 60 noise draws of the kinked model (truth 0.03 at the kink): the
    profile intervals hold the truth in >= 90 % of draws."""
    rng = np.random.default_rng(11)
    s = _structure(False)
    held = 0
    for _ in range(60):
        residual, *_ = _kinked(rng.normal(0, 0.02, N))
        t = _fit(residual, s, [0.04])
        half = fitmod.interval_halfwidths(t.r, t.jac, N)
        if not math.isfinite(half[0]):
            continue
        c, h = sig.profile_interval(t, lambda residual=residual: residual, half, 20)
        held += abs(0.03 - c[0]) <= h[0]
    assert held >= 54


def test_the_others_are_refitted_where_they_enter_nonlinearly():
    """y = g(w) a + exp(c) b (a kinked width and a scale factor in log form, the others' shape
    in the optimizer): the interval is the hull of the linearised one and the profile computed
    here by brute force (for each width on a fine grid, c refitted in closed form: the
    least-squares amplitude of b, then its log)."""
    rng = np.random.default_rng(1)
    b = np.cos(3 * X) + 1.5
    a = 1.0 + 0.5 * X

    def g(w):
        d = w - 0.03
        return d if d >= 0 else 0.1 * d

    y = g(0.03) * a + 0.8 * b + rng.normal(0, 0.002, N)
    free = [fitmod.Free("backlash", "width", 0, 0.0, 0.1, 0.01, False, 2e-4),
            fitmod.Free("viscous_damping", "damping", 0, 0.05, 5.0, 1.0, True, 1e-4)]
    s = fitmod.Structure(("backlash", "viscous_damping"), ("j",), free)

    def residual(points):
        return [y - g(w) * a - c * b for w, c in (_values(st, x) for st, x in points)]

    t = _fit(residual, s, [0.036, 1.0])
    assert t.jac is not None
    half = fitmod.interval_halfwidths(t.r, t.jac, N)
    centre, h = sig.profile_interval(t, lambda: residual, half)
    grid = np.linspace(0.0, 0.1, 20001)
    gw = np.array([g(w) for w in grid])
    amp = np.clip(((y[None, :] - gw[:, None] * a) @ b) / (b @ b), 0.05, 5.0)  # c's range
    cost = 0.5 * np.sum((y[None, :] - gw[:, None] * a - amp[:, None] * b) ** 2, axis=1)
    ainv = np.linalg.inv(t.jac.T @ t.jac)
    delta = 0.5 * half[0] ** 2 / ainv[0, 0]
    ok = grid[cost - min(cost.min(), t.cost) <= delta]
    assert ok.min() <= t.x[0] <= ok.max()  # the fit sits inside its own profile set
    lo_x, hi_x = min(ok.min(), t.x[0] - half[0]), max(ok.max(), t.x[0] + half[0])
    assert hi_x - lo_x > 1.5 * 2 * half[0]  # the kink makes this case: the profile is wider
    tol = 0.1 * (hi_x - lo_x)
    assert centre[0] - h[0] == pytest.approx(lo_x, abs=tol)
    assert centre[0] + h[0] == pytest.approx(hi_x, abs=tol)
    assert h[1] == half[1]


def test_each_side_stops_at_the_first_value_past_the_threshold():
    """A quadratic cost (y = 2 w + noise, no other scalar): the profile rises past Delta between
    one and two half-widths on both sides, so only the first step, +-1.25 half-widths, is
    replayed (one pass of two points), none further out; the interval is the linearised one
    (interpolated in sqrt(rise), exact for a quadratic)."""
    rng = np.random.default_rng(4)
    y = 2 * 0.03 + rng.normal(0, 0.01, N)
    calls = []

    def residual(points):
        calls.append([round(float(_values(st, x)[0]), 9) for st, x in points])
        return [y - 2 * _values(st, x)[0] for st, x in points]

    s = _structure(False)
    t = _fit(residual, s, [0.02])
    half = fitmod.interval_halfwidths(t.r, t.jac, N)
    calls.clear()
    centre, h = sig.profile_interval(t, lambda: residual, half)
    w, dw = float(t.x[0]), float(half[0])  # the width's coordinates are the width itself
    assert len(calls) == 1
    assert sorted(calls[0]) == pytest.approx([w - 1.25 * dw, w + 1.25 * dw], abs=1e-9)
    assert h[0] == pytest.approx(half[0], rel=1e-9) and centre[0] == pytest.approx(t.u[0])
