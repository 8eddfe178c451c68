"""The statistics behind the gap analysis' keep-or-drop decisions (``lowcostdex.gap.significance``)
checked against answers written out here: a linear-Gaussian regression with AR(1) errors whose
estimator variance is computed from the AR(1) covariance by hand, a paired comparison whose
true gain is set by construction, and "no effect" per catalogue parameter from the catalogue's
own nulls and the model's force range.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance as sg


def _ar1(rng: np.random.Generator, n: int, rho: float, sigma: float) -> np.ndarray:
    """AR(1) series e_t = rho e_(t-1) + sigma w_t, started in its stationary law."""
    w = sigma * rng.standard_normal(n)
    e = np.empty(n)
    e[0] = w[0] / math.sqrt(1 - rho ** 2)
    for t in range(1, n):
        e[t] = rho * e[t - 1] + w[t]
    return e


def test_hac_interval_covers_an_ar1_regression_where_independent_blocks_do_not():
    """y = b x + e, e AR(1) with rho 0.98 per sample (a misfit correlated over ~50 samples),
    x a slow sine, 4000 samples in 200 blocks of 20. The estimator's true standard deviation
    is written out from the AR(1) covariance sigma^2 rho^|i-j| / (1 - rho^2):
    sd(b_hat) = sqrt(x^T Sigma x) / x^T x. The HAC interval is close to 1.96 of it and covers
    the truth about 95 % of the time; the independent-block sandwich (neighbouring blocks
    assumed unrelated) is too narrow and covers far less."""
    rng = np.random.default_rng(3)
    n, rho, sigma = 4000, 0.98, 1e-3
    t = np.arange(n)
    x = np.sin(2 * np.pi * t / 700.0) + 0.3
    blocks = [slice(20 * b, 20 * (b + 1)) for b in range(n // 20)]
    # the written-out variance (Toeplitz covariance, computed by lags)
    c0 = sigma ** 2 / (1 - rho ** 2)
    xsx = c0 * float(x @ x) + 2 * sum(c0 * rho ** k * float(x[k:] @ x[:-k])
                                      for k in range(1, 600))
    sd_true = math.sqrt(xsx) / float(x @ x)
    hac_hits, blk_hits, ratio = [], [], []
    for _ in range(200):
        y = 1.0 * x + _ar1(rng, n, rho, sigma)
        b = float(x @ y / (x @ x))
        r, jac = y - b * x, -x[:, None]
        h = sg.hac_halfwidths(r, jac, blocks)[0]
        hb = fitmod.block_halfwidths(r, jac, blocks)[0]
        hac_hits.append(abs(b - 1.0) <= h)
        blk_hits.append(abs(b - 1.0) <= hb)
        ratio.append(h / (1.96 * sd_true))
    assert 0.90 <= np.mean(hac_hits) <= 0.995, np.mean(hac_hits)
    assert np.mean(blk_hits) < 0.85, np.mean(blk_hits)
    assert 0.8 <= np.median(ratio) <= 1.6, np.median(ratio)


def test_hac_interval_on_white_noise_is_the_block_sandwich_size():
    """White residuals: the scores of blocks are uncorrelated, the bandwidth is small and the
    HAC half-width is within a few % of the independent-block one (and of the i.i.d.
    formula 1.96 sigma / sqrt(x^T x) written out here)."""
    rng = np.random.default_rng(5)
    n = 4000
    x = np.linspace(-1, 1, n)
    blocks = [slice(20 * b, 20 * (b + 1)) for b in range(n // 20)]
    ratios = []
    for _ in range(50):
        y = 2.0 * x + 0.01 * rng.standard_normal(n)
        b = float(x @ y / (x @ x))
        r, jac = y - b * x, -x[:, None]
        ratios.append(sg.hac_halfwidths(r, jac, blocks)[0] / (1.96 * 0.01 / math.sqrt(x @ x)))
    assert 0.85 <= np.median(ratios) <= 1.2, np.median(ratios)
    # zero bandwidth is the block sandwich exactly
    y = 2.0 * x + 0.01 * rng.standard_normal(n)
    b = float(x @ y / (x @ x))
    r, jac = y - b * x, -x[:, None]
    np.testing.assert_allclose(sg.hac_halfwidths(r, jac, blocks, bandwidth=0),
                               fitmod.block_halfwidths(r, jac, blocks), rtol=1e-12)
    assert np.all(np.isinf(sg.hac_halfwidths(r, jac, blocks[:1])))


def test_andrews_bandwidth_grows_with_autocorrelation():
    rng = np.random.default_rng(1)
    white = rng.standard_normal((400, 1))
    ar = _ar1(rng, 400, 0.9, 1.0)[:, None]
    assert sg.andrews_bandwidth(white) < 5  # rho_hat ~ +-0.1 by chance: L ~ 2-4
    # Andrews' AR(1) formula with rho 0.9, n 400: 1.1447 (4 rho^2 / ((1-rho)^2 (1+rho)^2) n)^(1/3)
    want = 1.1447 * (4 * 0.81 / (0.01 * 3.61) * 400) ** (1 / 3)
    assert sg.andrews_bandwidth(ar) == pytest.approx(want, rel=0.35)


def test_paired_gain_bound_false_positive_rate_and_power():
    """Two models on the same 60 blocks. Null: new = cur with exchangeable noise (true gain 0):
    the 5 % lower bound is above 0 in about 5 % of trials (at most 12 %). A true 20 % gain
    with block-to-block spread is found every time. A gain of -10 % (the new model worse)
    never gets a positive bound."""
    rng = np.random.default_rng(11)
    null_pos, power, worse = [], [], []
    for _ in range(300):
        base = rng.gamma(4.0, 1.0, 60)
        cur = base * (1 + 0.1 * rng.standard_normal(60))
        new = base * (1 + 0.1 * rng.standard_normal(60))
        null_pos.append(sg.paired_gain_bound(cur, new, rng, 500) > 0)
        better = 0.8 * base * (1 + 0.1 * rng.standard_normal(60))
        power.append(sg.paired_gain_bound(base, better, rng, 500) > 0)
        worse.append(sg.paired_gain_bound(base, 1.1 * base, rng, 500) > 0)
    assert np.mean(null_pos) <= 0.12, np.mean(null_pos)
    assert np.mean(power) == 1.0
    assert not any(worse)
    assert sg.paired_gain_bound(np.ones(1), np.zeros(1), rng, 100) == -math.inf


def test_paired_gain_bound_of_an_effect_that_acts_in_one_block():
    """A torque limit acts only during a fast move: 11 blocks of 0.5 s, the new model removes a
    large error in block 4 and leaves the other 10 exactly as they were (the independent
    bench's torque-limit case: select gain 0.9999 in one block). With runs of 3 blocks (4 runs
    from 9 starts, 3 of which cover block 4) a resample misses it with probability
    (6/9)^4 = 0.198 > 5 %: those resamples show no change at all, and counted as "no gain" they
    set the bound to 0. They are ties (no evidence either way); the others all contain block 4.
    If the other blocks get 1 % WORSE instead, the missing-block resamples are real evidence
    against the change and the bound is negative."""
    rng = np.random.default_rng(3)
    cur = np.full(11, 20e-6)
    cur[4] = 3.5
    new = cur.copy()
    new[4] = 90e-6
    assert sg.paired_gain_bound(cur, new, rng, 2000) > 0.9
    worse = 1.01 * cur
    worse[4] = 90e-6
    assert sg.paired_gain_bound(cur, worse, rng, 2000) < 0
    assert sg.paired_gain_bound(cur, cur.copy(), rng, 2000) == 0.0  # all ties


def test_paired_gain_bound_keeps_block_correlation():
    """Null differences AR(1)-correlated over blocks (rho 0.6, 80 blocks): the moving-block
    bound (default run length ceil(80^(1/3)) = 5) gives a false positive in about 13 % of
    trials (a moving-block percentile bound is liberal on short series; measured 2026-11-26),
    where resampling single blocks, as if they were independent, is fooled in about 24 %."""
    rng = np.random.default_rng(2)
    mb, single = [], []
    for _ in range(300):
        d = _ar1(rng, 80, 0.6, 0.05)
        cur = np.ones(80)
        new = 1.0 - d
        mb.append(sg.paired_gain_bound(cur, new, rng, 500) > 0)
        single.append(sg.paired_gain_bound(cur, new, rng, 500, length=1) > 0)
    assert np.mean(mb) <= 0.16, np.mean(mb)
    assert np.mean(single) >= np.mean(mb) + 0.07, (np.mean(single), np.mean(mb))


def _ctx(peak):
    return fitmod.Context(dt=0.002, peak_force=np.array(peak, float), stall=np.full(2, np.inf),
                          damping=np.full(2, 0.05))


def test_null_margins_from_the_catalogue_nulls_and_the_force_range():
    """A backlash width 0.0016 with half-width 0.0017 (interval through 0) is not away from
    no effect; 0.0016 +- 0.0005 is. A torque limit at 0.596 N m where the model's largest force
    is its 0.6 N m force range does nothing (its interval reaches 0.6); 0.3 N m +- 5 % does.
    A gain of 0.98 +- 0.03 holds 1 (no effect); an infinite interval cannot show anything."""
    ctx = _ctx([0.6, 0.6])
    s = fitmod.Structure.build(("backlash", "torque_limit", "gain_error"), ("a", "b"), ctx)
    names = [(f.effect, f.param, f.joint) for f in s.free]
    # (backlash's sensor placement is a shape parameter: judged by the width, its amplitude)
    assert names == [("backlash", "width", 0), ("backlash", "width", 1),
                     ("backlash", "sensor", 0), ("backlash", "sensor", 1),
                     ("torque_limit", "torque", 0), ("torque_limit", "torque", 1),
                     ("gain_error", "scale", 0), ("gain_error", "scale", 1)]
    x = np.array([0.0016, 0.0, 1.0, 0.0, 0.596, 0.599, 0.98, 1.0])
    u = s.u(x)
    tl_log = s.free[4].log and s.free[6].log
    assert tl_log  # torque and gain scale are fitted in log coordinates
    half = np.array([0.0017, 0.001, 0.01, 0.01, 0.02, 0.02, math.log(1.03), 0.01])
    m = sg.null_margins(s, u, half, ctx)
    assert m["backlash"] < 1 and m["torque_limit"] < 1 and m["gain_error"] < 1
    half2 = np.array([0.0005, 0.001, 0.01, 0.01, 0.02, 0.02, math.log(1.01), 0.01])
    x2 = np.array([0.0016, 0.0, 1.0, 0.0, 0.3, 0.599, 0.98, 1.0])
    m2 = sg.null_margins(s, s.u(x2), half2, ctx)
    assert m2["backlash"] == pytest.approx(3.2)
    assert m2["torque_limit"] == pytest.approx(math.log(2) / 0.02)
    assert m2["gain_error"] > 1
    inf = sg.null_margins(s, u, np.full(8, np.inf), ctx)
    assert all(v == 0 for v in inf.values())
    # a torque limit above the largest force asked for is no effect, however narrow
    m3 = sg.null_margins(s, s.u(np.array([0.0, 0.0, 0.0, 0.0, 0.7, 0.7, 1.0, 1.0])),
                         np.full(8, 1e-6), ctx)
    assert m3["torque_limit"] < 0


def test_null_margins_judge_a_multi_parameter_effect_by_its_amplitude():
    """Stribeck friction is no effect when its static amplitude is 0, whatever its velocity
    (and its sliding level: a Stribeck without a breakaway is not named Stribeck)."""
    ctx = _ctx([1.0, 1.0])
    s = fitmod.Structure.build(("stribeck_friction",), ("a",), ctx)
    assert [f.param for f in s.free] == ["static", "velocity", "coulomb"]
    x = np.array([0.01, 0.2, 0.05])
    m = sg.null_margins(s, s.u(x), np.array([0.02, 1e-9, 1e-9]), ctx)
    assert m["stribeck_friction"] < 1
    m = sg.null_margins(s, s.u(x), np.array([0.002, 10.0, 10.0]), ctx)
    assert m["stribeck_friction"] == pytest.approx(5.0)


def test_step_interval_holds_a_first_order_discretisation_bias():
    """Exact decay x(t) = exp(-a t), a = 5 /s, fitted with forward Euler at step h: the
    Euler model x_(n+1) = (1 - a_h h) x_n reproduces the exact samples for
    a_h = (1 - exp(-a h)) / h, a first-order bias (a - a^2 h / 2 + ...). Refitted at h / 2,
    the move is a_(h/2) - a_h; the interval from it holds the true 5 /s for every h (the
    Richardson value a_h + 2 (a_(h/2) - a_h) is within a second-order term of it), while the
    fitted value +- the move does not. The interval is symmetric: a move of the same size the
    other way (a step error that is not monotone) is held as well."""
    a = 5.0
    for h in (0.002, 0.01, 0.02, 0.04):
        a_h = (1 - math.exp(-a * h)) / h
        a_half = (1 - math.exp(-a * h / 2)) / (h / 2)
        shift = np.array([a_half - a_h])
        mid, half = sg.step_interval(np.array([a_h]), np.array([1e-6]), shift, 0.5)
        assert mid[0] == a_h
        assert mid[0] - half[0] <= a <= mid[0] + half[0], h
        assert mid[0] - half[0] <= a_h - 2 * shift[0]  # the mirror image too
        assert not a_h - math.hypot(1e-6, shift[0]) <= a <= a_h + math.hypot(1e-6, shift[0])
        assert abs(a_h + 2 * shift[0] - a) <= (a * h) ** 2 * a
    # no move: the data's interval about the fitted value
    mid, half = sg.step_interval(np.array([1.0]), np.array([0.1]), np.zeros(1), 0.5)
    assert mid[0] == 1.0 and half[0] == pytest.approx(0.1)


def test_null_margins_at_a_zero_half_width_and_for_effects_without_a_null():
    """A zero-width interval (a parameter the data pin exactly) is infinitely far from "no
    effect" unless it sits on it (then 0: nothing shown). A velocity limit has no null of its
    own (no limit = an infinite speed): it cannot be judged (margin inf, never dropped), and a
    torque limit of a model that asks no force (peak 0) or an unbounded one (peak inf) has no
    "no effect" point either. (gap-pure mutation run of 2026-11-26: these edges survived.)"""
    ctx = _ctx([0.6, 0.6])
    s = fitmod.Structure.build(("gain_error",), ("a", "b"), ctx)
    zero = np.zeros(2)
    assert sg.null_margins(s, s.u(np.array([1.1, 1.0])), zero, ctx) == {"gain_error": math.inf}
    assert sg.null_margins(s, s.u(np.array([1.0, 1.0])), zero, ctx) == {"gain_error": 0.0}
    v = fitmod.Structure.build(("velocity_limit",), ("a",), ctx)
    assert sg.null_u(v.free[0], ctx) is None
    assert sg.null_margins(v, v.u(np.array([2.0])), np.array([0.1]), ctx) == {
        "velocity_limit": math.inf}
    for peak in (0.0, math.inf):
        t = fitmod.Structure.build(("torque_limit",), ("a",), _ctx([peak, peak]))
        assert sg.null_u(t.free[0], _ctx([peak, peak])) is None
    t = fitmod.Structure.build(("torque_limit",), ("a",), ctx)
    u0, side = sg.null_u(t.free[0], ctx)
    assert u0 == pytest.approx(math.log(0.6)) and side < 0
