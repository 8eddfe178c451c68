"""The final model's intervals (``analyze._intervals``), the step shift they hold
(``significance.step_shift``) and the plotted traces (``analyze._traces``), by hand.

A stand-in engine replays an offset as value x pattern (``test_gap_decisions_backward``: 1 s
episodes of 40 samples, orthogonal sinusoids). Its "finer physics step" replay is the same model
with a known bias ``DELTA`` added to every offset: refitted there, the offset moves by exactly
-DELTA, and the interval must then hold the Richardson-extrapolated zero-step value: half-width
|shift| / (1 - interval_step) + sqrt(data^2 + shift^2) around the fitted value
(``significance.step_interval``). A delay replays as the 1-cycle sine delayed by the delay
rounded *down* to the fine step (the piecewise-constant cost of a step phase), where
Levenberg-Marquardt's finite differences within one step see no slope: only the +-1 fine step
scan (``fit.polish``) moves it. No MuJoCo: milliseconds a test.
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, replace

import numpy as np
import pytest
from test_gap_decisions_backward import CTX, NOISE, P_A, N, T

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance
from lowcostdex.gap.dataset import Window
from lowcostdex.gap.diagnostics import effective_n
from lowcostdex.gap.results import GapConfig

AZ = importlib.import_module("lowcostdex.gap.analyze")
DELTA = 0.002  # the fine replay's bias of an offset [rad]
EPS = [Window(0, 0, N, 0), Window(1, 0, N, 0)]


@dataclass
class _Traj:
    qpos: np.ndarray
    time: np.ndarray
    name: str = "log"
    goal: np.ndarray | None = None


@dataclass
class _DS:
    trajectories: list
    joints: tuple = ("j0",)
    actuators: tuple = ("a0",)
    timestep: float = 0.002

    def with_timestep(self, factor):
        return replace(self, timestep=self.timestep * factor)


def _pred(effects, dt, lag=0.0):
    """The stand-in replay of one window at physics step ``dt``: offsets as value x pA (biased
    by DELTA at a step finer than 2 ms; goal timing plays no part in a reading offset), a delay
    d as sin(2 pi (t - floor((d + lag) / dt) dt)) (goals ``lag`` s late add to the delay)."""
    out = np.zeros(N)
    for e in effects:
        if e.name == "latency":
            d = float(e.values["delay"][0]) + lag
            out = out + np.sin(2 * np.pi * (T - math.floor(d / dt + 1e-9) * dt))
        else:
            bias = DELTA if dt < 0.002 else 0.0
            out = out + (float(e.values["offset"][0]) + bias) * P_A
    return out[:, None]


class _Engine:
    made: list = []

    def __init__(self, ds, cfg, names):
        self.ds = ds
        _Engine.made.append((ds.timestep, cfg, tuple(names)))

    def residual_fn(self, windows, goal_shift=0.0):  # the real engine's signature
        def fn(points):
            return [np.concatenate([(self.ds.trajectories[w.traj].qpos[w.score_from:w.stop]
                                     - _pred(s.to_effects(x), self.ds.timestep,
                                             goal_shift)).ravel()
                                    for w in windows]) for s, x in points]
        return fn


def _data(signal):
    return _DS([_Traj(signal[:, None].copy(), T.copy(), f"log{i}") for i in range(2)])


def _fitted(ds, names, x0):
    """A track of ``names`` fitted on ``ds`` at its own step (as the final fit leaves it)."""
    s = fitmod.Structure.build(names, ds.joints, CTX)
    t = fitmod.Track(s, s.u(np.asarray(x0, float)), label="final")
    fitmod.lockstep_lm([t], _Engine(ds, None, names).residual_fn(EPS), 40, rtol=1e-10)
    return t


def test_intervals_without_a_step_refit_are_the_widest_data_interval(monkeypatch):
    """interval_step 0: centre the fitted value, half-width the widest of the residual-noise
    interval, the block spread and the autocorrelation-consistent sandwich; no shift."""
    monkeypatch.setattr(AZ, "_Engine", _Engine)
    ds = _data(0.05 * P_A + 0.01 * NOISE)
    t = _fitted(ds, ("position_offset",), [0.0])
    assert t.x == pytest.approx([0.05], abs=1e-9)
    cfg = GapConfig(interval_step=0.0, interval_block=0.25)
    calls, timing = [], {}
    mid, half, noise, data, shift = AZ._intervals(ds, t, EPS, cfg,
                                                  lambda s, f: calls.append(s), timing)
    blocks = significance.residual_blocks(ds, EPS, 0.25)
    assert len(blocks) == 8  # four 0.25 s blocks of each 1 s episode
    want_noise = fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r))
    parts = [want_noise, fitmod.block_halfwidths(t.r, t.jac, blocks),
             significance.hac_halfwidths(t.r, t.jac, blocks)]
    np.testing.assert_allclose(noise, want_noise)
    np.testing.assert_allclose(data, np.maximum.reduce(parts))
    np.testing.assert_allclose(half, data)
    np.testing.assert_array_equal(mid, t.u)  # the fitted value, exactly (no goal-timing move:
    assert shift is None and calls == [] and timing == {}  # an offset is not goal-timed)
    # the residual is the 5-cycle pattern (0.01 rad) the offset cannot explain: an interval of
    # a few mrad around 0.05 rad, never zero
    assert 0 < data[0] < 0.01
    # a model wrong by +-10 mrad x pA by quarter (+, -, -, +: the quarters' sums of pA^2 are
    # S, S + 1, S, S + 1, so no net pull, the fit stays at 0.05 rad) leaves the residual-noise
    # interval a few mrad while the blocks disagree: the data interval is the block spread
    quarter = np.array([1.0, -1.0, -1.0, 1.0])[np.arange(N) // 10]
    ds = _data(0.05 * P_A + 0.01 * quarter * P_A)
    t = _fitted(ds, ("position_offset",), [0.0])
    assert t.x == pytest.approx([0.05], abs=1e-9)
    mid, half, noise, data, shift = AZ._intervals(ds, t, EPS, cfg, lambda s, f: None, {})
    np.testing.assert_allclose(noise, fitmod.interval_halfwidths(t.r, t.jac, effective_n(t.r)))
    assert data[0] > 1.5 * noise[0] and half[0] == data[0]  # 11.4 vs 6.5 mrad


def test_intervals_hold_the_zero_step_value_of_a_biased_replay(monkeypatch):
    """interval_step 0.5: the offset refitted at half the step moves by -DELTA (-2 mrad); its
    zero-step value is 2 DELTA away (Richardson), so the half-width is
    DELTA / 0.5 + sqrt(data^2 + DELTA^2) around the fitted 0.05 rad."""
    _Engine.made = []
    monkeypatch.setattr(AZ, "_Engine", _Engine)
    ds = _data(0.05 * P_A + 0.01 * NOISE)
    t = _fitted(ds, ("position_offset",), [0.0])
    cfg = GapConfig(interval_step=0.5, interval_block=0.25, max_rounds=30)
    calls, timing = [], {"interval_step": 5.0}
    mid, half, noise, data, shift = AZ._intervals(ds, t, EPS, cfg,
                                                  lambda s, f: calls.append((s, f)), timing)
    assert shift == pytest.approx([-DELTA], abs=1e-7)
    np.testing.assert_allclose(mid, t.u)
    assert half == pytest.approx(DELTA / 0.5 + np.hypot(data, DELTA), rel=1e-5)
    assert mid[0] - half[0] < 0.05 - 2 * DELTA < 0.05 + 2 * DELTA < mid[0] + half[0]
    # the fine engine: half the step, the caller's config, the final model's effects
    assert _Engine.made[-1] == (0.001, cfg, ("position_offset",))
    assert calls == [("interval: refit at a finer physics step", 0.97)]
    assert 5.0 < timing["interval_step"] < 5.0 + 60  # added to what earlier refits took
    # (noise, data: as without the step)
    _, h0, n0, d0, _ = AZ._intervals(ds, t, EPS, replace(cfg, interval_step=0.0),
                                     lambda s, f: None, {})
    np.testing.assert_allclose(noise, n0)
    np.testing.assert_allclose(data, d0)


def test_a_delay_is_scanned_over_one_fine_step_before_its_step_shift(monkeypatch):
    """The data lag by 30 ms; the coarse fit says 31.4 ms (at the fine step its rounding-down
    replays 31 ms). Within a 1 ms step the cost is flat (the finite-difference step is a quarter
    of the coarse 2 ms step, 0.5 ms: from 31.4 ms it reads 31.9 ms, the same 31 ms), so
    Levenberg-Marquardt alone reports no shift; the scan over +-1 fine step (31.4 -+ 1 ms in
    nine points) reaches 30.4 ms, which replays the truth: the shift is -1 ms."""
    # (+ 10 mrad of the 5-cycle pattern, orthogonal to every delay of the 1-cycle sine: the
    # cost at the truth is not zero, so "better" is strictly below the track's cost)
    ds = replace(_data(np.sin(2 * np.pi * (T - 0.030)) + 0.01 * NOISE), timestep=0.001)
    s = fitmod.Structure.build(("latency",), ds.joints, CTX)
    t = fitmod.Track(s, s.u(np.array([0.0314])), label="final")
    fine = _Engine(ds, None, ("latency",)).residual_fn(EPS)
    r = fine([(s, t.x)])[0]
    t.r, t.cost = r, 0.5 * float(r @ r)
    assert fitmod.step_shift(t, fine, 20) == pytest.approx([0.0], abs=1e-12)  # LM alone
    shift = significance.step_shift(t, fine, 20, 0.001)
    assert t.x + shift == pytest.approx([0.0304], abs=1e-9)
    assert shift == pytest.approx([-0.001], abs=1e-9)
    # already at the fine optimum: the scan finds nothing better, and nothing moves
    t2 = fitmod.Track(s, s.u(np.array([0.0304])), label="final")
    r = fine([(s, t2.x)])[0]
    t2.r, t2.cost = r, 0.5 * float(r @ r)
    assert significance.step_shift(t2, fine, 20, 0.001) == pytest.approx([0.0], abs=1e-12)
    # without a delay the shift is the plain refit's move (offsets: -DELTA, test above)
    ds2 = _data(0.05 * P_A)
    t3 = _fitted(ds2, ("position_offset",), [0.0])
    fine2 = _Engine(replace(ds2, timestep=0.001), None, ()).residual_fn(EPS)
    assert significance.step_shift(t3, fine2, 30, 0.001) == pytest.approx([-DELTA], abs=1e-7)


def test_traces_are_the_first_test_episodes_from_their_own_start():
    """Plots show at most ``n`` (2) test episodes: each one's own samples, its time from 0, the
    goal, measured, nominal and extended predictions, the joint and actuator names."""
    q = np.arange(40.0).reshape(20, 2)
    trs = [_Traj(q + 100 * i, np.linspace(2.0, 3.9, 20), f"log{i}", goal=-q - 100 * i)
           for i in range(3)]
    ds = _DS(trs, joints=("a", "b"), actuators=("m1", "m2"))
    eps = [Window(0, 5, 9, 5), Window(2, 0, 3, 0), Window(1, 10, 20, 10)]
    base = [np.full((w.stop - w.start, 2), float(k)) for k, w in enumerate(eps)]
    ext = [b + 0.5 for b in base]
    out = AZ._traces(ds, eps, base, ext)
    assert [o["name"] for o in out] == ["log0", "log2"]
    np.testing.assert_allclose(out[0]["time"], [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(out[1]["time"], [0.0, 0.1, 0.2], atol=1e-12)
    np.testing.assert_array_equal(out[0]["measured"], q[5:9])
    np.testing.assert_array_equal(out[1]["measured"], q[0:3] + 200)
    np.testing.assert_array_equal(out[0]["goal"], -q[5:9])
    np.testing.assert_array_equal(out[1]["goal"], -q[0:3] - 200)
    for o, b, e in zip(out, base, ext, strict=False):
        assert o["baseline"] is b and o["extended"] is e
        assert o["joints"] == ("a", "b") and o["actuators"] == ("m1", "m2")
    assert set(out[0]) == {"name", "time", "goal", "measured", "baseline", "extended",
                           "joints", "actuators"}
    assert [o["name"] for o in AZ._traces(ds, eps, base, ext, n=3)] == ["log0", "log2", "log1"]
    assert len(AZ._traces(ds, eps[:1], base[:1], ext[:1])) == 1


def test_the_final_fit_polishes_a_delay_stuck_on_a_flat_step_and_refreshes_its_residual():
    """``_final_fit``: the data lag by 34 ms; the screening left the delay at 31.4 ms, which the
    2 ms replay rounds down to 30 ms. LM's finite difference (0.5 ms) stays within the step: no
    slope, no move. The scan over +-1 step (29.4 .. 33.4 ms in 0.5 ms) finds 32.4 ms (replayed
    as 32 ms, the closest to 34 the scan reaches) and one more LM round re-evaluates the
    residual and Jacobian there, as the intervals need (without it the track has none)."""
    ds = _data(np.sin(2 * np.pi * (T - 0.034)) + 0.01 * NOISE)
    fn = _Engine(ds, None, ("latency",)).residual_fn(EPS)
    s = fitmod.Structure.build(("latency",), ds.joints, CTX)
    notes = {}
    t = AZ._final_fit(s, np.array([0.0314]), fn, GapConfig(), CTX, notes, 0.002)
    assert t.x == pytest.approx([0.0324], abs=1e-9)
    r = fn([(s, t.x)])[0]
    assert t.r is not None and t.jac is not None and t.jac.shape == (80, 1)
    np.testing.assert_allclose(t.r, r)
    assert t.cost == pytest.approx(0.5 * float(r @ r))
    assert notes == {} and t.label == "final"


def test_a_joint_fit_keeps_its_best_start():
    """``_joint_then_prune`` fits the effects together from every start and keeps the lowest
    cost: a delay's starts are 10, 30 and 60 ms (the catalogue's start and extra starts); on
    data lagging 30 ms with a 2 ms replay only the 30 ms start reaches it (the others sit on
    flat steps of their own)."""
    ds = _data(np.sin(2 * np.pi * (T - 0.030)) + 0.01 * NOISE)
    fn = _Engine(ds, None, ("latency",)).residual_fn(EPS)
    empty = fitmod.Structure((), ds.joints)
    s, x = AZ._joint_then_prune(None, ds, EPS[1:], ("latency",), empty, np.zeros(0),
                                GapConfig(), 0.001, CTX, fn, EPS[:1],
                                np.random.default_rng(0))
    assert s.effects == ("latency",)
    assert x == pytest.approx([0.03], abs=1e-9)
    starts = [x0[0] for x0 in fitmod.Structure.build(("latency",), ds.joints, CTX).starts()]
    assert starts == pytest.approx([0.01, 0.03, 0.06])
