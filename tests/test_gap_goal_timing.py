"""The goal-timing term of the parameter intervals (``stepsize.timing_move``, ``goal_timing``).

A servo acts on a goal at its next control tick, up to a physics step after the logged time,
and no replay at that step resolves the lag. The truth is written out here: a first-order
servo q' = k a0 (g - q) whose response to piecewise-constant goals is the closed form
g + (q0 - g) exp(-k a0 t) between switches (no replay, no MuJoCo), the data made with every
goal acting 0.6 ms late, the "replay" with goals at their logged times (or a given lag later).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import stepsize

A0 = 20.0  # 1/s, the nominal servo's rate constant
K_TRUE = 0.7  # the hidden gain scale
LAG = 0.0006  # s, how late the truth's servo acts on each goal
H = 0.001  # s, the replay's physics step
T = np.arange(0.0, 6.0, 0.005)  # sample times [s]


def _goals():
    rng = np.random.default_rng(0)
    times = np.arange(0.1, 6.0, 0.3) + rng.uniform(0.0, 0.005, 20)
    return times, rng.uniform(-1.0, 1.0, 20)


def _response(k: float, lag: float) -> np.ndarray:
    """q at ``T`` for goals acting ``lag`` s after their times, from q = 0 at t = 0."""
    times, levels = _goals()
    edges = np.concatenate([[0.0], times + lag, [math.inf]])
    goal = np.concatenate([[0.0], levels])
    q = np.empty_like(T)
    q0 = 0.0
    for i in range(len(goal)):
        seg = (T >= edges[i]) & (T < edges[i + 1])
        q[seg] = goal[i] + (q0 - goal[i]) * np.exp(-k * A0 * (T[seg] - edges[i]))
        end = min(edges[i + 1], T[-1])
        q0 = goal[i] + (q0 - goal[i]) * math.exp(-k * A0 * (end - edges[i]))
    return q


NOISE = np.random.default_rng(1).normal(0.0, 2e-5, len(T))
DATA = {"scale": _response(K_TRUE, LAG) + NOISE, "delay": _response(1.0, LAG) + NOISE}


def _gain_structure() -> fitmod.Structure:
    return fitmod.Structure(("gain_error",), ("j",),
                            [fitmod.Free("gain_error", "scale", 0, 0.2, 4.0, 1.0, True, 1e-4)])


def _delay_structure() -> fitmod.Structure:
    return fitmod.Structure(("latency",), ("j",),
                            [fitmod.Free("latency", "delay", 0, 0.0, 0.1, 0.01, False, 1e-5)])


def _residual(lag: float):
    def fn(points):
        out = []
        for s, x in points:
            v = s.to_effects(x)[0].values
            if "scale" in v:
                out.append(_response(float(v["scale"][0]), lag) - DATA["scale"])
            else:  # the same servo at its nominal gain, its goals delayed
                out.append(_response(1.0, lag + float(v["delay"][0])) - DATA["delay"])
        return out
    return fn


def _fit(s: fitmod.Structure, lag: float, u0: float) -> fitmod.Track:
    t = fitmod.Track(s, np.array([u0]))
    fitmod.lockstep_lm([t], _residual(lag), 60, rtol=1e-12)
    return t


def test_the_move_of_a_gain_over_one_step_of_goal_lag_is_the_refit_move():
    t = _fit(_gain_structure(), 0.0, 0.0)
    k0 = math.exp(t.u[0])
    assert k0 < K_TRUE - 0.003  # goals acting late look like a slower servo
    move = stepsize.timing_move(t, _residual(H / 2))[0]
    refit = _fit(_gain_structure(), H, t.u[0]).u[0] - t.u[0]
    assert move == pytest.approx(refit, rel=0.15)
    # the noise-only interval misses the truth; widened for lags in [0, H] it holds it
    half = fitmod.interval_halfwidths(t.r, t.jac, len(t.r))
    assert abs(t.u[0] - math.log(K_TRUE)) > half[0]
    mid, wide = stepsize.goal_timing(t, _residual(H / 2), t.u, half)
    assert abs(mid[0] - math.log(K_TRUE)) <= wide[0]
    assert wide[0] == pytest.approx(half[0] + abs(move) / 2)


def test_a_delay_takes_the_whole_lag():
    """A latency absorbs a goal lag exactly: one step later, the fitted delay is one step less."""
    t = _fit(_delay_structure(), 0.0, 0.0)
    assert t.x[0] == pytest.approx(LAG, abs=5e-5)
    assert stepsize.timing_move(t, _residual(H / 2))[0] == pytest.approx(-H, rel=0.05)


def test_no_jacobian_no_move():
    s = _gain_structure()
    t = fitmod.Track(s, np.array([0.0]))
    assert stepsize.timing_move(t, _residual(H / 2)).tolist() == [0.0]


def test_a_diverged_late_replay_moves_nothing():
    t = _fit(_gain_structure(), 0.0, 0.0)

    def diverged(points):
        return [np.full(len(T), np.nan) for _ in points]

    assert stepsize.timing_move(t, diverged).tolist() == [0.0]
    mid, half = stepsize.goal_timing(t, diverged, t.u, np.array([0.01]))
    assert mid.tolist() == t.u.tolist() and half.tolist() == [0.01]
