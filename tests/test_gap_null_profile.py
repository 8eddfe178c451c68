"""An effect whose interval reaches "no effect" is kept when its cost profiled there rises past
the data's threshold (``significance.null_profile_rise``, ``gates.profile_shown``; issue 11,
sim5 backlash2deg_pendulum_500hz_us: a 2 deg play chosen, then dropped on its interval).

The truth is written here: a play (backlash) operator in numpy - the output stays put until the
goal leaves a band of the play's width around it, then follows the goal at the band's edge - on
a goal that reverses a few times, plus seeded white read noise. Width 0 is the goal itself. The
costs at the null and at the fit, and the threshold (a linear model's cost rise at the edge of
the data's 95 % interval, half^2 / (2 [(J^T J)^-1]_ii)), are computed by hand from them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import gates, significance
from lowcostdex.gap.dataset import Window
from lowcostdex.gap.results import GapConfig

N = 2001
T = np.linspace(0.0, 4.0, N)
# a goal that sweeps and reverses (5 reversals of 0.3 rad, then small ones of 0.02 rad)
GOAL = 0.3 * np.sin(2 * np.pi * 0.6 * T) + 0.02 * np.sin(2 * np.pi * 3.0 * T)
NOISE = 0.0005  # rad, read noise
CTX = fitmod.Context(dt=0.002, peak_force=np.array([1.0]), stall=np.array([np.inf]),
                     damping=np.array([0.1]))


def play(goal: np.ndarray, width: float) -> np.ndarray:
    """The output of a play of total ``width`` [rad] driven by ``goal``, starting centred."""
    out = np.empty_like(goal)
    y, h = float(goal[0]), 0.5 * width
    for k, g in enumerate(goal):
        y = min(max(y, g - h), g + h)
        out[k] = y
    return out


@dataclass
class _Traj:
    time: np.ndarray


@dataclass
class _DS:
    trajectories: list
    joints: tuple = ("j",)


DS, SEGS = _DS([_Traj(T)]), [Window(0, 0, N, 0)]


def _fit(data: np.ndarray, model) -> tuple[fitmod.Track, fitmod.ResidualFn]:
    """The play's width fitted to ``data`` (``model(width)`` predicts; sensor held at 0)."""
    ctx = CTX.with_ranges({("backlash", "sensor", 0): (0.0, 0.0)})
    s = fitmod.Structure.build(("backlash",), ("j",), ctx)
    assert [(f.effect, f.param) for f in s.free] == [("backlash", "width")]

    def fn(points):
        return [data - model(float(x[0])) for _, x in points]
    t = fitmod.Track(s, s.u(np.array([0.02])))
    fitmod.lockstep_lm([t], fn, 30, rtol=1e-8)
    return t, fn


def _data_half(t: fitmod.Track) -> np.ndarray:
    return significance.data_halfwidths(t, significance.residual_blocks(DS, SEGS, 0.5))


def _by_hand(t: fitmod.Track, data: np.ndarray, null_pred: np.ndarray) -> float:
    """(cost at no play - cost at the fit) / the data threshold, written out."""
    c_null = 0.5 * float(np.sum((data - null_pred) ** 2))
    ainv = float(np.linalg.inv(t.jac.T @ t.jac)[0, 0])
    return (c_null - t.cost) / (0.5 * _data_half(t)[0] ** 2 / ainv)


def test_a_play_whose_removal_costs_far_more_than_the_data_allow_is_kept():
    rng = np.random.default_rng(0)
    data = play(GOAL, 0.035) + NOISE * rng.standard_normal(N)
    t, fn = _fit(data, lambda w: play(GOAL, w))
    assert t.x[0] == pytest.approx(0.035, abs=0.002)
    rise = significance.null_profile_rise(t, fn, _data_half(t), CTX, ["backlash"])
    # the only other scalar is held, so the profile at the null is the goal itself
    assert rise["backlash"] == pytest.approx(_by_hand(t, data, GOAL), rel=1e-9)
    assert rise["backlash"] > 100  # measured 22140
    # given as weak (an interval reaching 0, whatever its size), it is kept, with the reason
    weak, why = gates.profile_shown(["backlash"], t, fn, DS, SEGS, GapConfig(), CTX)
    assert weak == []
    assert why.startswith("; backlash kept although its 95 % interval reaches no effect: "
                          "without it the cost rises ")


def test_no_play_in_the_data_leaves_the_weak_play_weak():
    rng = np.random.default_rng(1)
    data = GOAL + NOISE * rng.standard_normal(N)  # no play: the output is the goal
    t, fn = _fit(data, lambda w: play(GOAL, w))
    assert t.x[0] < 0.002
    assert significance.null_profile_rise(t, fn, _data_half(t), CTX, ["backlash"])[
        "backlash"] == pytest.approx(_by_hand(t, data, GOAL), rel=1e-9)  # measured 0.27
    weak, why = gates.profile_shown(["backlash"], t, fn, DS, SEGS, GapConfig(), CTX)
    assert weak == ["backlash"] and why == ""


def test_for_a_model_linear_in_the_width_the_rise_is_the_interval_test_itself():
    """Residual linear in the scalar: the profile's rise at 0 over the threshold is (d / half)^2
    for a fit d from 0 with half-width ``half`` - exactly the margin rule (> 1 iff d > half)."""
    rng = np.random.default_rng(2)
    pattern = np.sin(2 * np.pi * 1.3 * T)
    data = 0.004 * pattern + NOISE * rng.standard_normal(N)
    t, fn = _fit(data, lambda w: w * pattern)
    half = _data_half(t)
    rise = significance.null_profile_rise(t, fn, half, CTX, ["backlash"])["backlash"]
    assert rise == pytest.approx((t.u[0] / half[0]) ** 2, rel=1e-6)
    # ... and at a half-width 1.5 times the fit's distance from 0: 1 / 1.5^2, below 1
    wide = half * 1.5 * t.u[0] / half[0]
    assert significance.null_profile_rise(t, fn, wide, CTX, ["backlash"])["backlash"] == \
        pytest.approx(1 / 1.5 ** 2, rel=1e-6)


def test_effects_without_a_profiled_scalar_are_not_judged_here():
    rng = np.random.default_rng(0)
    data = play(GOAL, 0.035) + NOISE * rng.standard_normal(N)
    t, fn = _fit(data, lambda w: play(GOAL, w))
    assert significance.null_profile_rise(t, fn, np.array([math.inf]), CTX, ["backlash"]) == {}
    assert significance.null_profile_rise(t, fn, np.array([0.01]), CTX, ["latency"]) == {}
    weak, why = gates.profile_shown(["latency"], t, fn, DS, SEGS, GapConfig(), CTX)
    assert weak == ["latency"] and why == ""
